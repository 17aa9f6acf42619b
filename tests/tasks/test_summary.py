"""The terminal's view of a task's result: per-video lists are counted, the numbers stay."""

from __future__ import annotations

from vgpl.tasks.summary import terminal_summary


def test_long_lists_are_counted_and_everything_else_is_kept():
    result = {"env": "rigid_fall", "param_mae_pct": 7.5, "per_video": list(range(100)), "curve": [0.5, 0.7],
              "evaluate": {"full": {"errors": [[1.0] * 20] * 64, "steps": 531}}, "shards": ("a", "b")}
    assert terminal_summary(result) == {"env": "rigid_fall", "param_mae_pct": 7.5, "per_video": "<100 values>", "curve": [0.5, 0.7],
                                        "evaluate": {"full": {"errors": "<64 values>", "steps": 531}}, "shards": ["a", "b"]}
    assert terminal_summary([[1.0] * 20, 2.0], max_items=3) == ["<20 values>", 2.0]
