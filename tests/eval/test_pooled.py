"""Several runs of one variant in one report (vgpl.eval.pooled): pooled, never silently dropped."""

from __future__ import annotations

import pytest

from vgpl.eval.pooled import pool_runs
from vgpl.eval.tables import PER_VIDEO, paired_rows, report_markdown, table1_rows, table2_rows


def _run(ablation: str, mae: float, std: float, errors: dict[str, float], inference: str) -> dict:
    return {"env": "rigid_fall", "method": "vgpl", "ablation": ablation, "n_test": len(errors), "observed": 10,
            "param_mae_pct": mae, "param_mae_pct_std": std, "midpoint_param_mae_pct": 25.6, "midpoint_param_mae_pct_std": 12.5,
            "future_mse_x1e4@20": sum(errors.values()) / len(errors), "rigidness_prob@10/cube": 0.9 if ablation == "full" else 0.0,
            "rigidness_curve": {"cube": [mae]}, "refine_mse_x1e4_before": 9.0, "refine_mse_x1e4_after": mae,
            PER_VIDEO.format(20): errors, "checkpoints": {"inference": inference}}


def test_two_seeds_of_a_variant_give_their_mean_and_each_run():
    seed0 = _run("full", 7.0, 5.4, {"900": 100.0, "901": 50.0}, "seed0/inference/last.ckpt")
    seed1 = _run("full", 8.0, 6.0, {"900": 60.0, "901": 70.0}, "seed1/inference/last.ckpt")
    other = _run("no_rigidness", 9.0, 7.0, {"900": 90.0, "901": 90.0}, "seed0/inference_no_rigidness/last.ckpt")
    pooled = pool_runs([seed0, other, seed1])
    assert [(r["ablation"], r.get("runs", 1)) for r in pooled] == [("full", 2), ("no_rigidness", 1)]
    full = pooled[0]
    assert pooled[1] is other  # a single run is left as it was
    assert full["param_mae_pct"] == pytest.approx(7.5) and full["run_values"]["param_mae_pct"] == [7.0, 8.0]
    assert full["future_mse_x1e4@20"] == pytest.approx(70.0) and full[PER_VIDEO.format(20)] == {"900": 80.0, "901": 60.0}
    assert "param_mae_pct_std" not in full  # a mean of two spreads over videos is no spread
    assert full["midpoint_param_mae_pct_std"] == 12.5 and full["observed"] == 10  # the same in every run: kept
    assert "rigidness_curve" not in full and full["rigidness_prob@10/cube"] == pytest.approx(0.9)
    assert full["checkpoints"] == [{"inference": "seed0/inference/last.ckpt"}, {"inference": "seed1/inference/last.ckpt"}]

    records = [seed0, other, seed1]
    assert table1_rows(records)[1][-1] == ["VGPL", "7.5 ± 0.7% (runs 7.0, 8.0)"]
    assert table2_rows(records)[1][-1][-1] == "70.000 ± 7.071"  # runs 75 and 65
    header, rows = paired_rows(records, 20)  # videos 900, 901: VGPL 80, 60 against 90, 90
    row = dict(zip(header, rows[0]))
    assert row["VGPL T+20"] == "70.000" and row["mean difference (ablation - VGPL) [95% bootstrap]"].startswith("+20.000 [")
    text = report_markdown(records)
    assert "## Runs pooled" in text and "| rigid_fall | VGPL | 2 | 7.0, 8.0 | 75.0, 65.0 |" in text
    assert text.count("| rigid_fall | cube |") == 1 and "| rigid_fall | 9.000 (30.0 mm) | 7.500 (27.4 mm) |" in text  # one row for the pooled runs, not one each
    assert "## Runs pooled" not in report_markdown([seed0, other])


def test_runs_on_different_test_videos_are_refused_with_their_checkpoints():
    seed0 = _run("full", 7.0, 5.4, {"900": 100.0, "901": 50.0}, "seed0/inference/last.ckpt")
    elsewhere = _run("full", 8.0, 6.0, {"900": 60.0, "902": 70.0}, "seed1/inference/last.ckpt")
    with pytest.raises(ValueError, match=r"vgpl full on rigid_fall: 2 runs to pool were evaluated on different test videos.*seed1/inference/last.ckpt"):
        pool_runs([seed0, elsewhere])
    fewer = {k: v for k, v in _run("full", 8.0, 6.0, {"900": 60.0}, "seed1").items() if k != PER_VIDEO.format(20)}  # older records
    with pytest.raises(ValueError, match=r"n_test \[2, 1\]"):
        pool_runs([seed0, fewer])
