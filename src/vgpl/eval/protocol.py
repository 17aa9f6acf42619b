"""The paper's evaluation of visual grounding on test videos: parameters (Table 1), future
prediction (Table 2), rigidness against observation length, refinement before/after."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm.auto import tqdm

from vgpl.data.proposals import propose_windows, truth_proposals
from vgpl.data.trajectories import Rollouts
from vgpl.data.window_pool import check_window_pool, pool_windows
from vgpl.eval.error_sources import RolloutInputs, error_sources
from vgpl.eval.test_time_fit import TestTimeFit, refit_inferred
from vgpl.metrics import (
    correct_rigidness_prob,
    mean_abs_acceleration_mm,
    mean_per_type,
    midpoint_error_pct,
    param_signed_error_pct,
    per_video_per_type,
    position_mse_x1e4,
    rms_mm,
)
from vgpl.models.rollout import future_mse, rollout


@dataclass
class GroundingResult:
    metrics: dict  # flat, JSON-able
    rigidness_curve: dict = field(default_factory=dict)  # type -> [T_max] mean probability of the correct label
    truth: torch.Tensor | None = None  # [R, n_steps, N, 3]
    prediction: torch.Tensor | None = None  # [R, n_steps, N, 3]
    params: torch.Tensor | None = None  # [R, P] inferred (physical)
    param_error: torch.Tensor | None = None  # [R] each video's parameter error, % of range, mean over parameters
    sources: dict = field(default_factory=dict)  # error_sources' result, where asked for
    rigidness_correct: dict = field(default_factory=dict)  # type -> [R] each video's probability of the correct label at T = observed


@torch.no_grad()
def observed_proposals(visual, images: torch.Tensor, start: int, frames: int, progress: bool = False) -> tuple[torch.Tensor, ...]:
    """Proposals [R, frames, N, 3], logits and slots [R, frames, F, N, 3] of frames [start, start + frames)
    exactly as the whole-video sliding window gives them, computed from the fewest frames (slots
    of windows that end after the last of them are NaN). images uint8 [R, T, H, W, 3]."""
    first = max(0, start - visual.hparams.frames + 1)
    return tuple(x[:, start - first :] for x in propose_windows(visual, images[:, first : start + frames], progress=progress))


def proposed_frames(observed: int, max_observed: int, n_frames: int, start_frame: int = 0) -> int:
    """Frames from ``start_frame`` that the evaluation proposes: the observed ones, and the
    rigidness curve's up to ``max_observed``, within the ``n_frames``-frame videos."""
    return min(max(observed, max_observed), n_frames - start_frame)


def infer_in_chunks(inference, proposals, logits, kinematic, chunk: int, **flags) -> dict:
    """``inference.infer`` on ``chunk`` videos at a time, outputs concatenated along the batch."""
    parts = [inference.infer(proposals[i : i + chunk], logits[i : i + chunk], kinematic, **flags) for i in range(0, len(proposals), chunk)]
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


@torch.no_grad()
def evaluate_grounding(dynamics, visual, inference, scene, test: Rollouts, ablation, observed: int = 10, n_steps: int = 20,
                       max_observed: int = 20, start_frame: int = 0, seed: int = 0, chunk: int = 8,
                       curve_rollouts: int | None = None, truth_noise_std: float = 0.0,
                       rigidness_curve: dict | None = None, trace_sources: bool = False,
                       exported: tuple[torch.Tensor, ...] | None = None, progress: bool = False, window_pool: str = "last",
                       test_time_fit: TestTimeFit | None = None) -> GroundingResult:
    """Infer from ``observed`` frames of each test video (from ``start_frame``) and roll ``n_steps`` on;
    the inference module runs on ``chunk`` videos at a time (bounded memory; the same numbers).

    The proposals: ``exported`` (proposals [R, T, N, 3], logits [R, T, N, M] and, where kept, slots
    [R, T, F, N, 3] as task=export_proposals wrote them), else the recorded particles with
    ``truth_noise_std`` metres of noise when ``visual`` is None (a diagnostic), else ``visual``'s.
    ``window_pool`` reads each observed window from the visual prior's windows (``pool_windows``): the
    pool the module was trained on. ``test_time_fit`` with steps > 0 refits each video's P (and Q)
    to its own refined frames (vgpl.eval.test_time_fit). ``ablation`` has booleans rigidness,
    refinement, params. Where it infers rigidness, the rigidness curve over T = 1 .. ``max_observed``
    is measured on the first ``curve_rollouts`` videos (None: all), or ``rigidness_curve`` (type ->
    [T_max], measured for this module already) is reported. ``trace_sources`` adds ``error_sources``;
    ``progress`` shows bars over the long parts.
    """
    for m in (dynamics, visual, inference):
        if m is not None:
            m.eval()
    kinematic = torch.as_tensor(scene.kinematic)
    h = dynamics.hparams.history
    n_frames = test.positions.shape[1]
    check_protocol(start_frame, observed, n_steps, n_frames, h, curve_rollouts)
    check_window_pool(window_pool, "window_pool")
    t_max = proposed_frames(observed, max_observed, n_frames, start_frame)
    proposals, logits, slots = proposals_for_test(visual, test, start_frame, t_max, exported, window_pool, truth_noise_std, seed, progress)
    seen_proposals = pool_windows(proposals, slots, window_pool, np.s_[:, :observed])
    seen = slice(start_frame, start_frame + observed)
    gen = torch.Generator().manual_seed(seed)
    # a few videos at a time: all 100 FluidCube videos at T = 10 make ~5 GB per activation. The
    # generator is consumed in video order, so no_params' uniform draws do not depend on the chunk
    out = infer_in_chunks(inference, seen_proposals, logits[:, :observed], kinematic, chunk, refinement=bool(ablation.refinement),
                           rigidness=bool(ablation.rigidness), params=bool(ablation.params), generator=gen)
    x = torch.where(kinematic[None, None, :, None], test.positions[:, seen], out["positions"])  # the actuators' particles are known
    metrics = {}
    if test_time_fit is not None and test_time_fit.steps > 0 and ablation.params:
        metrics = fit_at_test_time(out, inference, dynamics, x, scene.planes_at(test.actions[:, seen]), kinematic, test_time_fit,
                                   bool(ablation.rigidness), chunk, progress)
    metrics |= parameter_metrics(out["params"], test)  # Table 1
    refined = out["positions"] if ablation.refinement else infer_in_chunks(inference, seen_proposals, logits[:, :observed], kinematic, chunk)["positions"]
    metrics |= perception_metrics(seen_proposals, refined, test.positions[:, seen], ~kinematic)
    metrics["grouping_accuracy"] = float((out["grouping"].argmax(-1) == test.instance[None]).float().mean())  # the visual prior's grouping
    pred, truth, sources = predict_future(dynamics, x, out, test, scene, start_frame + observed, n_steps, trace_sources)  # Table 2
    metrics |= future_mse(pred, truth)
    curve, per_video_rigidness = {}, {}
    if ablation.rigidness:  # rigidness against observation length, per object type
        per_video_rigidness = per_video_per_type(correct_rigidness_prob(out["rigidness_prob"], test.rigid), scene.instance_types)  # [R, M]
        metrics |= {f"rigidness_prob@{observed}/{name}": float(video.mean()) for name, video in per_video_rigidness.items()}
        curve = given_curve(rigidness_curve, scene.instance_types, t_max) if rigidness_curve is not None else rigidness_against_length(
            inference, proposals[:curve_rollouts], logits[:curve_rollouts], kinematic, test.rigid, scene.instance_types, chunk, progress,
            None if slots is None else slots[:curve_rollouts], window_pool)
    return GroundingResult(metrics, curve, truth, pred, out["params"], parameter_errors(out["params"], test), sources, per_video_rigidness)


def predict_future(dynamics, x: torch.Tensor, out: dict, test: Rollouts, scene, first: int, n_steps: int, trace_sources: bool):
    """The prior rolled ``n_steps`` from the last h frames of ``x`` [R, T, N, 3] (the refined observed
    frames) with the inferred G, Q, P: (prediction, truth [R, n_steps, N, 3] from frame ``first``,
    error sources: with ``trace_sources``, the prior rolled with each input taken from the truth in turn)."""
    h, kinematic = dynamics.hparams.history, torch.as_tensor(scene.kinematic)
    truth = test.positions[:, first : first + n_steps]
    driven = torch.cat([x[:, -h:], truth], 1)
    planes = scene.planes_at(test.actions[:, first - h : first + n_steps])
    pred = rollout(dynamics, driven, out["grouping"], out["rigidness"], out["params"], planes, kinematic, n_steps)
    if not trace_sources:
        return pred, truth, {}
    known = RolloutInputs(test.positions[:, first - h : first], torch.nn.functional.one_hot(test.instance.long(), int(test.rigid.shape[0])).to(x).expand(len(x), -1, -1),
                          test.rigid.to(x).expand(len(x), -1), test.params.to(x))
    inferred = RolloutInputs(x[:, -h:], out["grouping"], out["rigidness"], out["params"])
    return pred, truth, error_sources(dynamics, inferred, known, truth, planes, kinematic, truth)


def fit_at_test_time(out: dict, inference, dynamics, x, planes, kinematic, fit: TestTimeFit, rigidness: bool, chunk: int, progress: bool) -> dict:
    """``refit_inferred`` on ``out`` (changed in place), with its seconds per video and the own-frames error before and after."""
    started = time.perf_counter()
    fitted = refit_inferred(out, inference, dynamics, x, planes, kinematic, fit, rigidness, chunk, progress)
    return {"test_time_fit_seconds_per_video": (time.perf_counter() - started) / len(x),
            "own_frames_error_before_fit": float(fitted["error_before"].mean()), "own_frames_error_after_fit": float(fitted["error_after"].mean())}


def check_protocol(start_frame: int, observed: int, n_steps: int, n_frames: int, history: int, curve_rollouts: int | None) -> None:
    """ValueError naming the eval option when the protocol does not fit the test videos or the prior."""
    if start_frame + observed + n_steps > n_frames:
        raise ValueError(f"eval: {start_frame} skipped + {observed} observed + {n_steps} predicted frames exceed the {n_frames}-frame rollouts")
    if observed < history:
        raise ValueError(f"eval.observed={observed} is shorter than the dynamics prior's history of {history} frames")
    if curve_rollouts is not None and curve_rollouts < 1:
        raise ValueError(f"eval.curve_rollouts={curve_rollouts}: expected at least 1 test video, or null for all")


def proposals_for_test(visual, test: Rollouts, start_frame: int, t_max: int, exported, window_pool: str, truth_noise_std: float, seed: int,
                   progress: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """The proposals [R, t_max, N, 3], logits [R, t_max, N, M] and windows' slots (or None) of frames
    [start_frame, start_frame + t_max): the exported ones, the recorded particles with noise
    (``visual`` None), or the visual prior's."""
    if exported is not None:  # the visual prior's, exported elsewhere (eval.proposals=exported)
        if exported[0].shape[1] < start_frame + t_max:
            raise ValueError(f"eval.proposals=exported: proposals of {exported[0].shape[1]} frames, the evaluation reads {start_frame + t_max}")
        proposals, logits, *kept = (None if x is None else x[:, start_frame : start_frame + t_max] for x in exported)
        slots = kept[0] if kept else None
        if window_pool != "last" and slots is None:
            raise ValueError(f"eval.proposals=exported: window_pool={window_pool!r} needs the windows' slots, the exported proposals have none")
        return proposals, logits, slots
    if visual is None:  # a perfect visual prior, or a noisy one (eval.proposals=truth); the recorded particles have no windows to pool
        noise = torch.Generator().manual_seed(seed + 1)
        proposals, logits = truth_proposals(test.positions[:, start_frame : start_frame + t_max], test.instance, int(test.rigid.shape[0]),
                                            truth_noise_std, noise)
        return proposals, logits, None
    return observed_proposals(visual, test.images, start_frame, t_max, progress)


def parameter_errors(params: torch.Tensor, test: Rollouts) -> torch.Tensor:
    """[R] each video's parameter MAE, % of the range."""
    return param_signed_error_pct(params, test.params, test.param_low, test.param_high).abs().mean(1)


def parameter_metrics(params: torch.Tensor, test: Rollouts) -> dict:
    """Table 1: the parameter MAE (% of the range), its spread and bias over the videos, and the range midpoint's on the same videos."""
    signed = param_signed_error_pct(params, test.params, test.param_low, test.param_high)
    err = signed.abs().mean(1)
    floor = midpoint_error_pct(test.params, test.param_low, test.param_high).mean(1)  # the same videos, a constant guess
    return {"param_mae_pct": float(err.mean()), "param_mae_pct_std": float(err.std()),
            "param_bias_pct": float(signed.mean()),  # the global offset: > 0 reads too high on average
            "midpoint_param_mae_pct": float(floor.mean()), "midpoint_param_mae_pct_std": float(floor.std())}


def perception_metrics(proposals: torch.Tensor, refined: torch.Tensor, truth: torch.Tensor, movable: torch.Tensor) -> dict:
    """The observed frames' position error before and after refinement (MSE x 1e4, and RMS per coordinate
    in mm), and their acceleration error against the true motion's size (P's signal is in the acceleration).
    proposals, refined, truth [R, T, N, 3]; movable [N]."""
    metrics = {"refine_mse_x1e4_before": position_mse_x1e4(proposals, truth, movable), "refine_mse_x1e4_after": position_mse_x1e4(refined, truth, movable)}
    for when in ("before", "after"):
        metrics[f"refine_rms_mm_{when}"] = rms_mm(metrics[f"refine_mse_x1e4_{when}"])
    metrics["accel_error_mm_before"] = mean_abs_acceleration_mm(proposals - truth, movable)
    metrics["accel_error_mm_after"] = mean_abs_acceleration_mm(refined - truth, movable)
    metrics["accel_truth_mm"] = mean_abs_acceleration_mm(truth, movable)
    return metrics


def given_curve(rigidness_curve: dict, types, t_max: int) -> dict:
    """A rigidness curve measured already (type -> [t_max]), checked against the types and lengths."""
    curve = {name: list(values) for name, values in rigidness_curve.items()}
    if set(curve) != set(types) or any(len(v) != t_max for v in curve.values()):
        lengths = {k: len(v) for k, v in curve.items()}
        raise ValueError(f"the rigidness curve given has {lengths} values per type, expected {t_max} for each of {sorted(set(types))}")
    return curve


@torch.no_grad()
def rigidness_against_length(inference, proposals: torch.Tensor, logits: torch.Tensor, kinematic: torch.Tensor, rigid: torch.Tensor,
                             types, chunk: int = 8, progress: bool = False, slots: torch.Tensor | None = None,
                             window_pool: str = "last") -> dict:
    """The mean probability of the correct rigidness label per object type (``types`` names each
    instance) when the inference module sees the first T = 1 .. T_max frames: type -> [T_max].
    proposals [R, T_max, N, 3], logits [R, T_max, N, M], rigid [M] (bool); slots [R, T_max, F, N, 3]
    or None, pooled over the windows that end within each T (``pool_windows``)."""
    probs = []
    for t in tqdm(range(1, proposals.shape[1] + 1), desc="rigidness curve", unit="T", disable=not progress):
        # all 100 videos at T = 20 at once made 17M proposal edges, 10 GB per activation, and
        # ran memory-bound for over half an hour on 2 cores
        p, lg = pool_windows(proposals, slots, window_pool, np.s_[:, :t]), logits[:, :t]
        q = torch.cat([inference.rigidness(p[i : i + chunk], lg[i : i + chunk], kinematic) for i in range(0, len(p), chunk)])
        probs.append(correct_rigidness_prob(q, rigid))  # [R, M]
    probs = torch.stack(probs, -1)  # [R, M, T_max]
    return {name: curve.tolist() for name, curve in mean_per_type(probs, types).items()}

