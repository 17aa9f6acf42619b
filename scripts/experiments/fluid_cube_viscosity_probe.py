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

import h5py
import numpy as np

from vgpl.data.grounding import proposals_path
from vgpl.data.trajectories import load_split

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


def ridge_fit_predict(x_train: np.ndarray, y_train: np.ndarray, x_test: np.ndarray, alpha: float) -> np.ndarray:
    """Standardised ridge regression: fitted on (x_train, y_train), evaluated at x_test."""
    mu, sd = x_train.mean(0), x_train.std(0) + 1e-12
    a, b = (x_train - mu) / sd, (x_test - mu) / sd
    w = np.linalg.solve(a.T @ a + alpha * np.eye(a.shape[1]), a.T @ (y_train - y_train.mean()))
    return b @ w + y_train.mean()


def main(root: str = "data/standard") -> None:
    splits = {}
    for split in ("train", "test"):
        with h5py.File(proposals_path(root, "fluid_cube", split)) as f:
            proposals, ids = f["positions"][:].astype(np.float64), f["rollout_ids"][:]
        rollouts = load_split(root, "fluid_cube", split, max_rollouts=len(ids))
        if not (rollouts.rollout_ids.numpy() == ids).all():
            raise ValueError(f"{proposals_path(root, 'fluid_cube', split)}: rollout_ids differ from the {split} split's first {len(ids)}")
        splits[split] = (rollouts, proposals)
    (train, _), (test, _) = splits["train"], splits["test"]
    low, high = float(train.param_low[0]), float(train.param_high[0])
    y_train, y_test = train.params[:, 0].numpy(), test.params[:, 0].numpy()
    pct = lambda pred: np.abs(np.clip(pred, low, high) - y_test).mean() / (high - low) * 100  # noqa: E731
    print(f"range midpoint: viscosity MAE {pct(np.full_like(y_test, (low + high) / 2)):.1f}% of the range")
    for frames in (10, 30):
        for source in ("truth", "proposals"):
            x = {}
            for split, (rollouts, proposals) in splits.items():
                pos = rollouts.positions.numpy().astype(np.float64) if source == "truth" else proposals
                x[split] = motion_statistics(pos[:, :frames], rollouts.actions[:, :frames, :3].numpy(), rollouts.instance.numpy())
            pred = ridge_fit_predict(x["train"], y_train, x["test"], alpha=1.0)
            print(f"first {frames:2d} frames of the {source:9s}: viscosity MAE {pct(pred):4.1f}% of the range, r = {np.corrcoef(pred, y_test)[0, 1]:.2f}")


if __name__ == "__main__":
    main(*sys.argv[1:])
