from __future__ import annotations

import dataclasses

import pytest
import torch
from omegaconf import OmegaConf

from tests.models.inference_options import inference_module
from vgpl.data.trajectories import Rollouts
from vgpl.eval.protocol import evaluate_grounding
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.visual_prior import VisualPrior
from vgpl.sim.envs import make_scene


def _setup():
    torch.manual_seed(0)
    scene = make_scene("rigid_fall", n_steps=40)
    n, m, r, t = scene.n_particles, scene.n_instances, 5, 40
    dyn = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), m, radius=0.08, width=16)
    visual = VisualPrior(n, m, channels=[4, 4, 4, 4], hidden=16, downsample=2)
    inf = inference_module(scene.param_low.tolist(), scene.param_high.tolist(), n, m, radius=0.08, width=16)
    inf.set_stats(dyn)
    test = Rollouts(
        positions=torch.rand(r, t, n, 3) * 0.3, params=torch.full((r, 1), -10.0), actions=torch.zeros(r, t, 0),
        instance=torch.as_tensor(scene.instance), rigid=torch.as_tensor(scene.rigid), param_low=torch.as_tensor(scene.param_low),
        param_high=torch.as_tensor(scene.param_high), env=scene.name, images=torch.randint(0, 255, (r, t, 120, 160, 3), dtype=torch.uint8),
    )
    return (dyn, visual, inf, scene, test), r


def _ablation(**off):
    return OmegaConf.create({"rigidness": True, "refinement": True, "params": True, **{k: False for k in off}})


KWARGS = dict(observed=6, n_steps=5, max_observed=8)


def _assert_same_metrics(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert abs(a[k] - b[k]) <= 1e-5 * max(1.0, abs(a[k])), (k, a[k], b[k])


def test_numbers_are_the_same_whatever_the_chunk_of_videos():
    models, r = _setup()
    one = evaluate_grounding(*models, _ablation(), chunk=r, **KWARGS)
    split = evaluate_grounding(*models, _ablation(), chunk=2, **KWARGS)
    assert set(one.rigidness_curve) == {"cube"} and len(one.rigidness_curve["cube"]) == 8
    for name, curve in one.rigidness_curve.items():
        torch.testing.assert_close(torch.tensor(split.rigidness_curve[name]), torch.tensor(curve))
        assert one.metrics[f"rigidness_prob@6/{name}"] == pytest.approx(curve[5], rel=1e-5)  # T = observed, all videos
    _assert_same_metrics(split.metrics, one.metrics)
    torch.testing.assert_close(split.params, one.params)


def test_uniform_parameter_draws_do_not_depend_on_the_chunk():
    models, r = _setup()
    one = evaluate_grounding(*models, _ablation(), chunk=r, **KWARGS)
    draws = evaluate_grounding(*models, _ablation(params=False), chunk=r, **KWARGS)
    split = evaluate_grounding(*models, _ablation(params=False), chunk=2, **KWARGS)
    assert torch.equal(split.params, draws.params) and not torch.allclose(draws.params, one.params)


def test_rigidness_curve_on_a_subset_keeps_the_reported_point_on_all_videos():
    (dyn, visual, inf, scene, test), r = _setup()
    every = evaluate_grounding(dyn, visual, inf, scene, test, _ablation(), **KWARGS)
    first = evaluate_grounding(dyn, visual, inf, scene, test, _ablation(), curve_rollouts=2, **KWARGS)
    two = dataclasses.replace(test, positions=test.positions[:2], params=test.params[:2], actions=test.actions[:2], images=test.images[:2])
    only_two = evaluate_grounding(dyn, visual, inf, scene, two, _ablation(), **KWARGS)
    assert first.metrics["rigidness_prob@6/cube"] == pytest.approx(every.metrics["rigidness_prob@6/cube"], rel=1e-6)
    assert first.rigidness_curve["cube"] == pytest.approx(only_two.rigidness_curve["cube"], rel=1e-6)


def test_an_empty_curve_subset_is_refused():
    models, _ = _setup()
    with pytest.raises(ValueError, match="eval.curve_rollouts=0"):
        evaluate_grounding(*models, _ablation(), curve_rollouts=0, **KWARGS)


def test_the_record_holds_the_constant_guess_on_the_same_videos():
    (dyn, visual, inf, scene, test), r = _setup()
    test = dataclasses.replace(test, params=torch.tensor([[-15.0], [-12.5], [-10.0], [-7.5], [-5.0]]))
    metrics = evaluate_grounding(dyn, visual, inf, scene, test, _ablation(), **KWARGS).metrics
    assert metrics["midpoint_param_mae_pct"] == pytest.approx(30.0)  # 50, 25, 0, 25, 50 % of the range
    assert metrics["midpoint_param_mae_pct_std"] == pytest.approx(torch.tensor([50.0, 25, 0, 25, 50]).std().item())


def test_the_record_holds_the_signed_offset_of_the_inferred_parameters():
    (dyn, visual, inf, scene, test), r = _setup()
    test = dataclasses.replace(test, params=torch.tensor([[-15.0], [-12.5], [-10.0], [-7.5], [-5.0]]))
    result = evaluate_grounding(dyn, visual, inf, scene, test, _ablation(), **KWARGS)
    signed = (result.params - test.params) / 10.0 * 100  # gravity's range is 10
    assert result.metrics["param_bias_pct"] == pytest.approx(float(signed.mean()), rel=1e-5)
    assert result.metrics["param_mae_pct"] == pytest.approx(float(signed.abs().mean()), rel=1e-5)
    assert abs(result.metrics["param_bias_pct"]) <= result.metrics["param_mae_pct"]


def test_a_curve_measured_before_is_reported_as_given_and_the_rest_is_unchanged():
    """The pipeline measures the rigidness curve once for the ablations that share a module."""
    models, _ = _setup()
    full = evaluate_grounding(*models, _ablation(), **KWARGS)
    measured = evaluate_grounding(*models, _ablation(params=False), **KWARGS)
    reused = evaluate_grounding(*models, _ablation(params=False), rigidness_curve=full.rigidness_curve, **KWARGS)
    assert reused.rigidness_curve == full.rigidness_curve
    assert measured.rigidness_curve.keys() == full.rigidness_curve.keys() == {"cube"}
    torch.testing.assert_close(torch.tensor(measured.rigidness_curve["cube"]), torch.tensor(full.rigidness_curve["cube"]))
    _assert_same_metrics(reused.metrics, measured.metrics)
    with pytest.raises(ValueError, match=r"has \{'cube': 7\} values per type, expected 8 for each of \['cube'\]"):
        evaluate_grounding(*models, _ablation(), rigidness_curve={"cube": full.rigidness_curve["cube"][:7]}, **KWARGS)


def test_tracing_the_error_sources_rolls_the_same_inferred_rollout_and_changes_nothing_else():
    models, r = _setup()
    plain = evaluate_grounding(*models, _ablation(), **KWARGS)
    traced = evaluate_grounding(*models, _ablation(), trace_sources=True, chunk=2, **KWARGS)
    assert plain.sources == {} and list(traced.sources)[0] == "inferred" and "all true" in traced.sources
    _assert_same_metrics(traced.metrics, plain.metrics)
    for k in (1, 5):
        assert traced.sources["inferred"][f"future_mse_x1e4@{k}"] == pytest.approx(plain.metrics[f"future_mse_x1e4@{k}"], rel=1e-5)
    assert len(traced.sources["all true"]["per_video@5"]) == r


def test_exported_proposals_give_the_visual_priors_numbers_without_it():
    """``exported`` (eval.proposals=exported): the visual prior's proposals of the whole videos, as
    task=export_proposals writes them, give the numbers the visual prior gives, with no prior."""
    from vgpl.data.proposals import propose_videos

    (dyn, visual, inf, scene, test), _ = _setup()
    by_video = evaluate_grounding(dyn, visual, inf, scene, test, _ablation(), **KWARGS)
    exported = propose_videos(visual, test.images[:, :20])  # more frames than the evaluation reads (8)
    read = evaluate_grounding(dyn, None, inf, scene, dataclasses.replace(test, images=None), _ablation(), exported=exported, **KWARGS)
    _assert_same_metrics(read.metrics, by_video.metrics)
    torch.testing.assert_close(read.params, by_video.params)
    with pytest.raises(ValueError, match="eval.proposals=exported: proposals of 7 frames, the evaluation reads 8"):
        evaluate_grounding(dyn, None, inf, scene, test, _ablation(), exported=tuple(x[:, :7] for x in exported), **KWARGS)


def test_progress_bars_count_the_windows_and_the_curves_lengths_and_leave_the_numbers_alone(capsys):
    models, r = _setup()
    quiet = evaluate_grounding(*models, _ablation(), **KWARGS)
    assert capsys.readouterr().err == ""
    shown = evaluate_grounding(*models, _ablation(), progress=True, **KWARGS)
    err = capsys.readouterr().err
    assert "proposals" in err and "rigidness curve" in err and "8/8" in err  # T = 1 .. max_observed
    _assert_same_metrics(shown.metrics, quiet.metrics)


def test_pooled_windows_give_the_same_numbers_from_the_videos_and_from_the_exported_slots():
    """window_pool=mean: the observed frames (and every T of the rigidness curve) are read from
    the visual windows that end within them, whether the prior runs here or its export is read;
    the pooled proposals are what the refinement's 'before' is measured on."""
    from vgpl.data.proposals import propose_windows
    from vgpl.data.window_pool import pool_windows

    (dyn, visual, inf, scene, test), _ = _setup()
    paper = evaluate_grounding(dyn, visual, inf, scene, test, _ablation(), **KWARGS)
    by_video = evaluate_grounding(dyn, visual, inf, scene, test, _ablation(), window_pool="mean", **KWARGS)
    exported = propose_windows(visual, test.images[:, :20])
    read = evaluate_grounding(dyn, None, inf, scene, dataclasses.replace(test, images=None), _ablation(), exported=exported,
                              window_pool="mean", **KWARGS)
    _assert_same_metrics(read.metrics, by_video.metrics)
    assert by_video.rigidness_curve.keys() == read.rigidness_curve.keys()
    for name, curve in read.rigidness_curve.items():  # approx() compares flat dicts and sequences only
        assert by_video.rigidness_curve[name] == pytest.approx(curve)
    pooled = pool_windows(exported[0][:, :6], exported[2][:, :6], "mean")
    before = ((pooled - test.positions[:, :6]) ** 2).mean() * 1e4  # rigid_fall has no kinematic particles
    assert by_video.metrics["refine_mse_x1e4_before"] == pytest.approx(float(before), rel=1e-5)
    assert by_video.metrics["refine_rms_mm_before"] == pytest.approx(float(((pooled - test.positions[:, :6]) ** 2).mean().sqrt() * 1e3), rel=1e-5)
    assert by_video.metrics["refine_mse_x1e4_before"] != pytest.approx(paper.metrics["refine_mse_x1e4_before"], rel=1e-3)
    with pytest.raises(ValueError, match="window_pool='mean' needs the windows' slots, the exported proposals have none"):
        evaluate_grounding(dyn, None, inf, scene, test, _ablation(), exported=exported[:2], window_pool="mean", **KWARGS)
