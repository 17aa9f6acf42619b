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
    """Infer from ``observed`` frames of each test video (from ``start_frame``), roll ``n_steps`` on.
    The inference module runs on ``chunk`` videos at a time (bounded memory; same numbers).
    ``visual=None`` replaces the visual prior by the recorded particles plus ``truth_noise_std``
    metres of Gaussian noise (``truth_proposals``, a diagnostic: no video is read). ``exported``:
    the visual prior's proposals [R, T, N, 3], logits [R, T, N, M] and, where kept, slots
    [R, T, F, N, 3] of frames [0, T) as task=export_proposals wrote them (``exported_proposals``),
    used instead of ``visual``. ``window_pool`` reads every observed window (the T = ``observed``
    one and the rigidness curve's) from the visual prior's windows as ``pool_windows`` does; it
    must be the pool the inference module was trained on. ``test_time_fit`` with steps > 0 refines
    each video's P (and Q, where the ablation infers it) against its own refined frames after the
    inference module's estimate (vgpl.eval.test_time_fit); the rigidness curve stays the module's.

    ``ablation`` has booleans rigidness, refinement, params. The rigidness curve is measured for
    T = 1 .. ``max_observed`` when the ablation infers rigidness, on the first ``curve_rollouts``
    test videos (None: all); the probability at T = ``observed`` is reported on all of them.
    ``rigidness_curve`` (type -> [T_max]) is a curve already measured for this inference module on
    these proposals (the three ablations that infer rigidness share it): it is reported instead of
    measured again. ``trace_sources`` also rolls the prior with each input taken from the truth in
    turn (``error_sources``: start positions, velocities, G, Q, P), a diagnostic of the future error.
    ``progress`` shows bars over the long parts: the visual prior's windows, the test-time fit's
    videos and the rigidness curve's lengths.
    """
    for m in (dynamics, visual, inference):
        if m is not None:
            m.eval()
    kinematic = torch.as_tensor(scene.kinematic)
    movable = ~kinematic
    h = dynamics.hparams.history
    n_frames = test.positions.shape[1]
    if start_frame + observed + n_steps > n_frames:
        raise ValueError(f"eval: {start_frame} skipped + {observed} observed + {n_steps} predicted frames exceed the {n_frames}-frame rollouts")
    if observed < h:
        raise ValueError(f"eval.observed={observed} is shorter than the dynamics prior's history of {h} frames")
    if curve_rollouts is not None and curve_rollouts < 1:
        raise ValueError(f"eval.curve_rollouts={curve_rollouts}: expected at least 1 test video, or null for all")
    check_window_pool(window_pool, "window_pool")
    t_max = proposed_frames(observed, max_observed, n_frames, start_frame)
    slots = None  # the recorded particles have no windows to pool
    if exported is not None:  # the visual prior's, exported elsewhere (eval.proposals=exported)
        if exported[0].shape[1] < start_frame + t_max:
            raise ValueError(f"eval.proposals=exported: proposals of {exported[0].shape[1]} frames, the evaluation reads {start_frame + t_max}")
        proposals, logits, *kept = (None if x is None else x[:, start_frame : start_frame + t_max] for x in exported)
        slots = kept[0] if kept else None
        if window_pool != "last" and slots is None:
            raise ValueError(f"eval.proposals=exported: window_pool={window_pool!r} needs the windows' slots, the exported proposals have none")
    elif visual is None:  # a perfect visual prior, or a noisy one (eval.proposals=truth)
        noise = torch.Generator().manual_seed(seed + 1)
        proposals, logits = truth_proposals(test.positions[:, start_frame : start_frame + t_max], test.instance, int(test.rigid.shape[0]),
                                            truth_noise_std, noise)
    else:
        proposals, logits, slots = observed_proposals(visual, test.images, start_frame, t_max, progress)
    seen_proposals = pool_windows(proposals, slots, window_pool, np.s_[:, :observed])
    seen = slice(start_frame, start_frame + observed)
    truth_seen = test.positions[:, seen]
    gen = torch.Generator().manual_seed(seed)
    # a few videos at a time: all 100 FluidCube videos at T = 10 make ~5 GB per activation. The
    # generator is consumed in video order, so no_params' uniform draws do not depend on the chunk
    out = infer_in_chunks(inference, seen_proposals, logits[:, :observed], kinematic, chunk, refinement=bool(ablation.refinement),
                           rigidness=bool(ablation.rigidness), params=bool(ablation.params), generator=gen)
    metrics = {}
    x = torch.where(kinematic[None, None, :, None], truth_seen, out["positions"])  # the actuators' particles are known
    if test_time_fit is not None and test_time_fit.steps > 0 and ablation.params:
        started = time.perf_counter()
        fitted = refit_inferred(out, inference, dynamics, x, scene.planes_at(test.actions[:, seen]), kinematic, test_time_fit,
                                bool(ablation.rigidness), chunk, progress)
        metrics["test_time_fit_seconds_per_video"] = (time.perf_counter() - started) / len(x)
        metrics["own_frames_error_before_fit"] = float(fitted["error_before"].mean())
        metrics["own_frames_error_after_fit"] = float(fitted["error_after"].mean())
    # Table 1: parameters
    signed = param_signed_error_pct(out["params"], test.params, test.param_low, test.param_high)
    err = signed.abs().mean(1)
    metrics["param_mae_pct"], metrics["param_mae_pct_std"] = float(err.mean()), float(err.std())
    metrics["param_bias_pct"] = float(signed.mean())  # the global offset: > 0 reads too high on average
    floor = midpoint_error_pct(test.params, test.param_low, test.param_high).mean(1)  # the same videos, a constant guess
    metrics["midpoint_param_mae_pct"], metrics["midpoint_param_mae_pct_std"] = float(floor.mean()), float(floor.std())
    # refinement
    metrics["refine_mse_x1e4_before"] = position_mse_x1e4(seen_proposals, truth_seen, movable)
    refined = out["positions"] if ablation.refinement else infer_in_chunks(inference, seen_proposals, logits[:, :observed], kinematic, chunk)["positions"]
    metrics["refine_mse_x1e4_after"] = position_mse_x1e4(refined, truth_seen, movable)
    for when in ("before", "after"):  # the same error as people read it: RMS per coordinate, mm
        metrics[f"refine_rms_mm_{when}"] = rms_mm(metrics[f"refine_mse_x1e4_{when}"])
    # motion: the frames' acceleration error against the true motion's size (P's signal is in the acceleration)
    metrics["accel_error_mm_before"] = mean_abs_acceleration_mm(seen_proposals - truth_seen, movable)
    metrics["accel_error_mm_after"] = mean_abs_acceleration_mm(refined - truth_seen, movable)
    metrics["accel_truth_mm"] = mean_abs_acceleration_mm(truth_seen, movable)
    # grouping accuracy of the visual prior
    metrics["grouping_accuracy"] = float((out["grouping"].argmax(-1) == test.instance[None]).float().mean())
    # Table 2: future prediction from the last h refined frames
    frames = slice(start_frame + observed - h, start_frame + observed + n_steps)
    driven = torch.cat([x[:, -h:], test.positions[:, start_frame + observed : frames.stop]], 1)
    planes = scene.planes_at(test.actions[:, frames])
    pred = rollout(dynamics, driven, out["grouping"], out["rigidness"], out["params"], planes, kinematic, n_steps)
    truth = test.positions[:, start_frame + observed : frames.stop]
    metrics.update(future_mse(pred, truth))
    sources = {}
    if trace_sources:
        m = int(test.rigid.shape[0])
        r = truth.shape[0]
        known = RolloutInputs(test.positions[:, frames.start : start_frame + observed],
                              torch.nn.functional.one_hot(test.instance.long(), m).to(x).expand(r, -1, -1),
                              test.rigid.to(x).expand(r, -1), test.params.to(x))
        inferred = RolloutInputs(x[:, -h:], out["grouping"], out["rigidness"], out["params"])
        sources = error_sources(dynamics, inferred, known, driven[:, h:], planes, kinematic, truth)
    # rigidness against observation length, per object type
    curve, per_video_rigidness = {}, {}
    if ablation.rigidness:
        types = scene.instance_types
        at_observed = correct_rigidness_prob(out["rigidness_prob"], test.rigid)  # [R, M]
        per_video_rigidness = per_video_per_type(at_observed, types)
        for name, video in per_video_rigidness.items():
            metrics[f"rigidness_prob@{observed}/{name}"] = float(video.mean())
        if rigidness_curve is None:
            curve = rigidness_against_length(inference, proposals[:curve_rollouts], logits[:curve_rollouts], kinematic, test.rigid, types, chunk,
                                             progress, None if slots is None else slots[:curve_rollouts], window_pool)
        else:
            curve = {name: list(values) for name, values in rigidness_curve.items()}
            if set(curve) != set(types) or any(len(v) != t_max for v in curve.values()):
                lengths = {k: len(v) for k, v in curve.items()}
                raise ValueError(f"the rigidness curve given has {lengths} values per type, expected {t_max} for each of {sorted(set(types))}")
    return GroundingResult(metrics, curve, truth, pred, out["params"], err, sources, per_video_rigidness)


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

