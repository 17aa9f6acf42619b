"""What a task's result looks like on the terminal: the numbers, not the per-video lists.

A pipeline's result holds every evaluation's per-video numbers (thousands of lines as JSON), which
its files keep (``metrics.json``, ``report.md``, the CSV tables); the terminal gets the result with
each list longer than ``max_items``, and each per-video map ({rollout id: value}), replaced by a
count, then, for a task that wrote a report, its Table 1 and Table 2 and the report's path last,
so they are the last screen.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

CLOSING_SECTIONS = ("## Table 1", "## Table 2")


def terminal_summary(result: Any, max_items: int = 8) -> Any:
    """``result`` with every list or tuple longer than ``max_items`` replaced by ``"<n values>"`` and
    every dict keyed by more than ``max_items`` rollout ids (digit strings) by ``"<n videos>"``, in
    nested dicts and lists too."""
    if isinstance(result, dict):
        if len(result) > max_items and all(isinstance(k, str) and k.isdigit() for k in result):
            return f"<{len(result)} videos>"
        return {key: terminal_summary(value, max_items) for key, value in result.items()}
    if isinstance(result, (list, tuple)):
        if len(result) > max_items:
            return f"<{len(result)} values>"
        return [terminal_summary(value, max_items) for value in result]
    return result


def closing_tables(report: str | Path) -> str:
    """The sections of the Markdown report at ``report`` whose headings start with Table 1 and Table 2,
    then the report's path: what the terminal ends with."""
    text = Path(report).read_text()
    sections = [s.strip() for s in re.split(r"(?m)^(?=## )", text) if s.startswith(CLOSING_SECTIONS)]
    return "\n\n".join(sections + [f"The full report (refinement, rigidness, paired ablations, training steps): {report}"])
