"""How much gravity do RigidFall's proposals carry, read without any learned model? (session 30, a diagnostic)

The top cube falls freely through the observed frames, so a parabola fitted to its centroid's
height gives gravity exactly from the recorded particles. Fitted to the VisualPrior's exported
proposals instead, it shows how much of the fall the proposals keep: raw, and calibrated by a
least-squares line from the three cubes' fitted accelerations to gravity on the training split's
proposals. Also prints the observed frames' position MSE x 1e4 and the cube centroids' rms error.

Superseded by ``task=free_fall_gravity`` (session 34; vgpl.eval.free_fall): every scene starts
from rest, and a fit that knows it has one unknown a video instead of three a cube. On the same
proposals it reads gravity about twice as well (calibrated: 5.3% against 11.8% on the annealed
visual prior's, 6.3% against 13.4% on the 5,000-step one); this script stays as session 30 ran it.

Usage: python scripts/experiments/gravity_from_proposals.py DATA_ROOT [DATA_ROOT ...]
       (each with rigid_fall/{train,test} shards and rigid_fall/proposals/{train,test}.h5)
"""

from __future__ import annotations

import sys

import numpy as np

from vgpl.data.grounding import split_with_proposals

OBSERVED = 10
DT = 1 / 60


def fitted_accelerations(positions: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """positions [R, F, N, 3] -> the vertical acceleration of each cube's centroid over the first
    OBSERVED frames, lowest cube first [R, M] (m/s^2, a quadratic least-squares fit)."""
    t = np.arange(OBSERVED) * DT
    heights = np.stack([positions[:, :OBSERVED][:, :, instance == k, 1].mean(-1) for k in np.unique(instance)], -1)  # [R, F, M]
    order = np.argsort(heights[:, 0], axis=-1)  # by starting height
    accel = np.stack([np.polyfit(t, heights[r], 2)[0] * 2 for r in range(len(heights))])  # [R, M]
    return np.take_along_axis(accel, order, -1)


def split(root: str, name: str):
    """(proposals [R, F, N, 3], recorded positions of the same rollouts, gravity [R], instance [N], gravity's (low, high))."""
    rollouts, proposals = split_with_proposals(root, "rigid_fall", name)
    bounds = float(rollouts.param_low[0]), float(rollouts.param_high[0])
    return proposals.positions.numpy(), rollouts.positions.numpy(), rollouts.params[:, 0].numpy(), rollouts.instance.numpy(), bounds


def main(roots: list[str]) -> None:
    for root in roots:
        train_prop, _, train_g, instance, (low, high) = split(root, "train")
        test_prop, test_true, test_g, _, _ = split(root, "test")
        span = high - low
        pct = lambda err: float(np.abs(err).mean() / span * 100)  # noqa: E731  (% of gravity's range)
        truth = fitted_accelerations(test_true, instance)[:, -1]
        raw = fitted_accelerations(test_prop, instance)
        design = lambda a: np.c_[a, np.ones(len(a))]  # noqa: E731
        line = np.linalg.lstsq(design(fitted_accelerations(train_prop, instance)), train_g, rcond=None)[0]
        calibrated = design(raw) @ line
        mse = float(((test_prop[:, :OBSERVED] - test_true[:, :OBSERVED]) ** 2).mean() * 1e4)
        centroid = np.sqrt(np.mean([((test_prop[:, :OBSERVED][:, :, instance == k].mean(2) - test_true[:, :OBSERVED][:, :, instance == k].mean(2)) ** 2)
                                    .sum(-1).mean() for k in np.unique(instance)]))
        print(f"{root}: {len(test_g)} test videos; top cube's parabola from the recorded particles {pct(truth - test_g):.1f}%, "
              f"from the proposals {pct(raw[:, -1] - test_g):.1f}% (bias {(raw[:, -1] - test_g).mean() / span * 100:+.1f}%), "
              f"calibrated on {len(train_g)} training videos {pct(calibrated - test_g):.1f}%; range midpoint {pct(test_g - (low + high) / 2):.1f}%; "
              f"observed frames' MSE x 1e4 {mse:.2f}, cube centroid rms {centroid * 100:.1f} cm")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
