"""Is FluidCube's viscosity in the proposals at all? A supervised linear probe, as a ceiling for
what the inference module could read from the same frames (session 23; not part of the method).

Ridge regression on a few motion statistics of the fluid and of the cube, relative to the
container (mean |relative displacement|, its RMS and its change, the spread of the displacements
and of the positions, the share of the container's motion followed), fitted on the 300 training
rollouts with exported proposals and scored on the 100 test rollouts, from the first T frames of
the recorded particles or of the visual prior's proposals.

Usage: python scripts/experiments/fluid_cube_viscosity_probe.py [data root, data/standard]
Needs data/<root>/fluid_cube/{train,test} and its proposals (task=export_proposals).
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from vgpl.data.grounding import split_with_proposals
from vgpl.eval.linear_probe import Ridge
from vgpl.eval.metrics import midpoint_error_pct, param_error_pct

FLUID, CUBE = 1, 0  # FluidCube's instance ids


def motion_statistics(positions: np.ndarray, container: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """positions [R, T, N, 3], container position [R, T, 3], instance [N] -> features [R, 35] (per axis where
    the statistic has one)."""
    disp = positions[:, 1:] - positions[:, :-1]
    shake = (container[:, 1:] - container[:, :-1])[:, :, None]  # [R, T-1, 1, 3]
    rel = disp - shake
    out = []
    for part in (instance == FLUID, instance == CUBE):
        r = rel[:, :, part]
        out += [np.abs(r).mean((1, 2)), (r ** 2).mean((1, 2)) ** 0.5, disp[:, :, part].std(2).mean(1),
                positions[:, :, part].std(2).mean(1), np.abs(r[:, 1:] - r[:, :-1]).mean((1, 2)),
                (r * shake).sum(-1).mean((1, 2)) / ((shake ** 2).sum(-1).mean((1, 2)) + 1e-12)]
    out.append(np.abs(shake).mean((1, 2)))
    return np.concatenate([f.reshape(len(positions), -1) for f in out], 1)


def load_with_proposals(root: str, split: str):
    """(the split's first rollouts as Rollouts, their exported proposals [R, T, N, 3] as float64)."""
    rollouts, proposals = split_with_proposals(root, "fluid_cube", split)
    return rollouts, proposals.positions.double().numpy()


def main(root: str = "data/standard") -> None:
    splits = {split: load_with_proposals(root, split) for split in ("train", "test")}
    (train, _), (test, _) = splits["train"], splits["test"]
    low, high, truth = train.param_low, train.param_high, test.params
    pct = lambda pred: float(param_error_pct(pred.clamp(low, high), truth, low, high).mean())  # noqa: E731
    print(f"range midpoint: viscosity MAE {float(midpoint_error_pct(truth, low, high).mean()):.1f}% of the range")
    for frames in (10, 30):
        for source in ("truth", "proposals"):
            x = {}
            for split, (rollouts, proposals) in splits.items():
                pos = rollouts.positions.double().numpy() if source == "truth" else proposals
                x[split] = torch.as_tensor(motion_statistics(pos[:, :frames], rollouts.actions[:, :frames, :3].numpy(), rollouts.instance.numpy()))
            pred = Ridge.fit(x["train"], train.params, alpha=1.0).predict(x["test"].float())
            r = np.corrcoef(pred[:, 0].numpy(), truth[:, 0].numpy())[0, 1]
            print(f"first {frames:2d} frames of the {source:9s}: viscosity MAE {pct(pred):4.1f}% of the range, r = {r:.2f}")


if __name__ == "__main__":
    main(*sys.argv[1:])
