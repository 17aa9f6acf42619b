"""Where a visual-grounding rollout's future error comes from. VGPL rolls the dynamics prior from
what the inference module gives: the last ``history`` refined frames (their last frame is the
start position, their differences the start velocities), the grouping G, the rigidness Q and the
parameters P. Replacing one of them at a time by the truth, and rolling the same prior again on
the same videos, says how much of the error at T+k each carries; replacing all of them gives the
prior's own error. The swaps do not add up (the rollout is not linear in its inputs), so each is
reported as it is, with a paired bootstrap interval of its difference from the inferred rollout.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from vgpl.eval.error_breakdown import rollout_mse_x1e4
from vgpl.eval.paired import paired_bootstrap
from vgpl.models.rollout import FUTURE, future_mse, rollout

SOURCES = ("start_positions", "start_velocities", "grouping", "rigidness", "params")
# name -> the inputs taken from the truth; "inferred" is VGPL's rollout, "all true" the prior's own error
VARIANTS: dict[str, tuple[str, ...]] = {
    "inferred": (),
    "true start positions": ("start_positions",),
    "true start velocities": ("start_velocities",),
    "true start": ("start_positions", "start_velocities"),
    "true grouping": ("grouping",),
    "true rigidness": ("rigidness",),
    "true parameters": ("params",),
    "all true": SOURCES,
}


@dataclass(frozen=True)
class RolloutInputs:
    """What a rollout starts from: window [R, H, N, 3] (the last H frames), grouping [R, N, M],
    rigidness [R, M], params [R, P] (physical units)."""

    window: torch.Tensor
    grouping: torch.Tensor
    rigidness: torch.Tensor
    params: torch.Tensor


def with_truth(inferred: RolloutInputs, true: RolloutInputs, swapped: tuple[str, ...]) -> RolloutInputs:
    """``inferred`` with the inputs named in ``swapped`` (of SOURCES) taken from ``true``. The start
    position is the window's last frame and the start velocities its frame-to-frame differences:
    taking one from the truth shifts the other's window rigidly onto it."""
    unknown = set(swapped) - set(SOURCES)
    if unknown:
        raise ValueError(f"with_truth: unknown inputs {sorted(unknown)}, expected some of {SOURCES}")
    positions, velocities = "start_positions" in swapped, "start_velocities" in swapped
    if positions and velocities:
        window = true.window
    elif positions:  # the inferred motion, ending where the truth ends
        window = inferred.window - inferred.window[:, -1:] + true.window[:, -1:]
    elif velocities:  # the true motion, ending where the inference ends
        window = true.window - true.window[:, -1:] + inferred.window[:, -1:]
    else:
        window = inferred.window
    return replace(inferred, window=window, **{k: getattr(true, k) for k in ("grouping", "rigidness", "params") if k in swapped})


@torch.no_grad()
def error_sources(dynamics, inferred: RolloutInputs, true: RolloutInputs, driven: torch.Tensor, planes: torch.Tensor,
                  kinematic: torch.Tensor, truth: torch.Tensor, horizons=(1, 5, 10, 20), chunk: int = 25) -> dict:
    """Future MSE x 1e4 of the prior rolled from each of VARIANTS' inputs.

    Args: driven [R, n_steps, N, 3] the frames after the window (they drive only the kinematic
    particles); planes [R, H + n_steps, K, 4]; kinematic [N] bool; truth [R, n_steps, N, 3];
    ``chunk`` videos are rolled at a time (bounded memory, the same numbers).
    Returns {variant: {"future_mse_x1e4@k": mean, ..., "per_video@<last>": [R],
    "vs_inferred@<last>": paired bootstrap of (variant - inferred) at the last horizon}}.
    """
    n_steps = truth.shape[1]
    last = max(k for k in horizons if k <= n_steps)
    out, reference = {}, None
    for name, swapped in VARIANTS.items():
        x = with_truth(inferred, true, swapped)
        pred = torch.cat([
            rollout(dynamics, torch.cat([x.window[i : i + chunk], driven[i : i + chunk]], 1), x.grouping[i : i + chunk],
                    x.rigidness[i : i + chunk], x.params[i : i + chunk], planes[i : i + chunk], kinematic, n_steps)
            for i in range(0, len(truth), chunk)
        ])
        per_video = rollout_mse_x1e4(pred, truth, last)  # [R]
        row = future_mse(pred, truth, horizons)
        row[f"per_video@{last}"] = per_video.tolist()
        if reference is None:
            reference = per_video
        else:
            row[f"vs_inferred@{last}"] = paired_bootstrap(reference, per_video)
        out[name] = row
    return out


def error_sources_rows(sources: dict) -> tuple[list[str], list[list[str]]]:
    """The table of ``error_sources``' result: one row per variant, the MSE at each horizon and the
    paired difference from the inferred rollout at the last one (mean [95% interval])."""
    horizons = [k.split("@")[1] for k in next(iter(sources.values())) if k.startswith(FUTURE.format(""))]
    last = horizons[-1]
    header = ["inputs from the truth", *[f"T+{k}" for k in horizons], f"T+{last} minus inferred [95% CI]"]
    rows = []
    for name, row in sources.items():
        d = row.get(f"vs_inferred@{last}")
        paired = "" if d is None else f"{d['mean_diff']:+.1f} [{d['low']:+.1f}, {d['high']:+.1f}]"
        rows.append([name, *[f"{row[FUTURE.format(k)]:.2f}" for k in horizons], paired])
    return header, rows
