"""What a task's result looks like on the terminal: the numbers, not the per-video lists.

A pipeline's result holds every evaluation's per-video numbers (thousands of lines as JSON), which
its files keep (``metrics.json``, ``report.md``, the CSV tables); the terminal gets the result with
each list longer than ``max_items`` replaced by a count, so the tables above it do not scroll away.
"""

from __future__ import annotations

from typing import Any


def terminal_summary(result: Any, max_items: int = 8) -> Any:
    """``result`` with every list or tuple longer than ``max_items`` replaced by ``"<n values>"``, in
    nested dicts and lists too."""
    if isinstance(result, dict):
        return {key: terminal_summary(value, max_items) for key, value in result.items()}
    if isinstance(result, (list, tuple)):
        if len(result) > max_items:
            return f"<{len(result)} values>"
        return [terminal_summary(value, max_items) for value in result]
    return result
