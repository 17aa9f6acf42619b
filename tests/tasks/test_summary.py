"""The terminal's view of a task's result: per-video lists are counted, the numbers stay."""

from __future__ import annotations

from vgpl.tasks.summary import closing_tables, terminal_summary


def test_long_lists_are_counted_and_everything_else_is_kept():
    result = {"env": "rigid_fall", "param_mae_pct": 7.5, "per_video": list(range(100)), "curve": [0.5, 0.7],
              "evaluate": {"full": {"errors": [[1.0] * 20] * 64, "steps": 531}}, "shards": ("a", "b")}
    assert terminal_summary(result) == {"env": "rigid_fall", "param_mae_pct": 7.5, "per_video": "<100 values>", "curve": [0.5, 0.7],
                                        "evaluate": {"full": {"errors": "<64 values>", "steps": 531}}, "shards": ["a", "b"]}
    assert terminal_summary([[1.0] * 20, 2.0], max_items=3) == ["<20 values>", 2.0]


def test_per_video_maps_are_counted_and_short_maps_kept():
    result = {"per_video_future_mse_x1e4@20": {str(900 + i): float(i) for i in range(64)}, "by_type": {"0": 1.0, "1": 2.0}}
    assert terminal_summary(result) == {"per_video_future_mse_x1e4@20": "<64 videos>", "by_type": {"0": 1.0, "1": 2.0}}


def test_the_terminal_closes_with_table_1_table_2_and_the_reports_path(tmp_path):
    report = tmp_path / "report.md"
    report.write_text("## Table 1: parameters\n| a |\n|---|\n| 1 |\n\n## Table 2: future\n| b |\n\n"
                      "## Refinement: observed frames\n| c |\n\n## Is VGPL lower than each ablation?\n| d |\n\nTraining steps run: 3\n")
    closing = closing_tables(report)
    assert closing == f"## Table 1: parameters\n| a |\n|---|\n| 1 |\n\n## Table 2: future\n| b |\n\nThe full report (refinement, rigidness, paired ablations, training steps): {report}"
