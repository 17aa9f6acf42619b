"""task=compare's pairing: evaluations of one test set compared video by video."""

from __future__ import annotations

import json

import pytest
import torch

from vgpl.eval.compare import PER_VIDEO_PARAM, PER_VIDEO_RIGIDNESS, compare_rows, paired_comparisons, read_record, short_names


def record(param_errors, t10, env="rigid_fall", ids=None) -> dict:
    ids = ids or list(range(len(param_errors)))
    return {"env": env, PER_VIDEO_PARAM: {str(i): float(v) for i, v in zip(ids, param_errors)},
            "per_video_future_mse_x1e4@10": {str(i): float(v) for i, v in zip(ids, t10)}}


def test_each_metric_is_paired_on_the_videos_both_evaluated():
    g = torch.Generator().manual_seed(0)
    base = torch.rand(40, generator=g) * 10
    worse = base + 2.0 + 0.5 * torch.randn(40, generator=g)  # 2 points higher on every video, give or take
    reference, other = record(base, base * 3), record(worse, base * 3)
    other[PER_VIDEO_PARAM]["999"] = 50.0  # a video the reference did not evaluate: not paired
    found = {c["metric"]: c for c in paired_comparisons(reference, {"worse": other})}
    param, t10 = found["parameter MAE %"], found["T+10 MSE x 1e4"]
    assert param["videos"] == 40 and param["reference_mean"] == pytest.approx(float(base.mean()))
    assert param["mean_diff"] == pytest.approx(float((worse - base).mean())) and param["low"] > 1.5 and param["high"] < 2.5
    assert param["verdict"] == "higher" and param["reference_lower_share"] == 1.0
    assert t10["mean_diff"] == 0.0 and t10["verdict"] == "not distinguishable"  # the same future on every video
    header, rows = compare_rows(list(found.values()))
    assert len(header) == len(rows[0]) and rows[0][:3] == ["worse", "parameter MAE %", "40"]


def test_each_object_types_rigidness_is_paired_where_both_carry_it():
    g = torch.Generator().manual_seed(1)
    sure = 0.9 + 0.1 * torch.rand(30, generator=g)
    reference, other = record(sure * 10, sure), record(sure * 10, sure)
    reference[PER_VIDEO_RIGIDNESS.format(10, "cube")] = {str(i): float(v) for i, v in enumerate(sure)}
    other[PER_VIDEO_RIGIDNESS.format(10, "cube")] = {str(i): float(v) - 0.2 for i, v in enumerate(sure)}  # 0.2 less sure of every cube
    found = {c["metric"]: c for c in paired_comparisons(reference, {"unsure": other})}
    cube = found["P(correct rigidness) of cube, T = 10"]
    assert cube["videos"] == 30 and cube["mean_diff"] == pytest.approx(-0.2, abs=1e-6) and cube["verdict"] == "lower"
    del other[PER_VIDEO_RIGIDNESS.format(10, "cube")]  # an evaluation without it (w/o rigidness): that row is left out
    assert "P(correct rigidness) of cube, T = 10" not in {c["metric"] for c in paired_comparisons(reference, {"unsure": other})}


def test_an_env_with_two_object_types_pairs_each_in_order_of_t_then_type():
    """MassRope carries a sphere and a rope: both are paired, ordered by T and then by type."""
    reference, other = record([1.0] * 5, [1.0] * 5, env="mass_rope"), record([1.0] * 5, [1.0] * 5, env="mass_rope")
    for t, kind, drop in ((10, "sphere", 0.1), (10, "rope", 0.3), (2, "rope", 0.0)):
        reference[PER_VIDEO_RIGIDNESS.format(t, kind)] = {str(i): 0.9 for i in range(5)}
        other[PER_VIDEO_RIGIDNESS.format(t, kind)] = {str(i): 0.9 - drop for i in range(5)}
    found = [c for c in paired_comparisons(reference, {"other": other}) if "rigidness" in c["metric"]]
    assert [c["metric"] for c in found] == ["P(correct rigidness) of rope, T = 2", "P(correct rigidness) of rope, T = 10",
                                             "P(correct rigidness) of sphere, T = 10"]
    assert [round(c["mean_diff"], 6) for c in found] == [0.0, -0.3, -0.1]


def test_other_envs_disjoint_videos_and_old_records_are_refused(tmp_path):
    reference = record([1.0, 2.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="an evaluation on 'mass_rope'"):
        paired_comparisons(reference, {"rope": record([1.0], [1.0], env="mass_rope")})
    with pytest.raises(ValueError, match="no test video in common"):
        paired_comparisons(reference, {"other split": record([1.0], [1.0], ids=[7])})
    (tmp_path / "metrics.json").write_text(json.dumps({"env": "rigid_fall", "param_mae_pct": 3.0}))
    with pytest.raises(ValueError, match="no per-video parameter errors"):
        read_record(tmp_path)
    with pytest.raises(ValueError, match="no metrics.json"):
        read_record(tmp_path / "missing")


def test_runs_are_labelled_by_what_their_paths_do_not_share(tmp_path):
    assert short_names(["/a/b/paper/eval", "/a/b/joint/eval", "/a/b/joint/eval_fit"]) == ["paper/eval", "joint/eval", "joint/eval_fit"]
    assert short_names(["/a/b", "/a/b/c"]) == ["b", "c"]  # the shared folder itself keeps its name
    assert short_names([str(tmp_path / "only")]) == ["only"]
