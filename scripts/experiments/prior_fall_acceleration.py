"""How much of gravity a RigidFall dynamics prior reproduces in one step, from the true history.

Every RigidFall body starts at rest and falls freely until it lands; in free fall the engine moves
each particle by exactly g dt^2 more per frame than the frame before (y acceleration per frame^2).
For each frame this prints the prior's one-step y acceleration over the true one, pooled over the
particles that are in free fall there (true acceleration within 1% of g dt^2). A ratio under 1 is a
prior that falls too slowly for the true g: its rollout fits a stronger g best, and an inference
module trained through it reads gravity too strong (session 41: session 36's prior reads 0.95-0.97
once the bodies are moving, the oracle's -2.45 points of bias).

    python scripts/experiments/prior_fall_acceleration.py CKPT [CKPT ...] [--root data/standard] [--videos 20] [--frames 15]
"""

from __future__ import annotations

import argparse

import torch

from vgpl.checkpoint import scene_of
from vgpl.data.trajectories import load_split
from vgpl.eval.free_fall import UP
from vgpl.eval.one_step import one_step_accelerations
from vgpl.tasks.train_dynamics import load_dynamics


def fall_acceleration_ratio(model, scene, test, frames: int) -> list[tuple[int, int, float]]:
    """[(frame t, free-falling particles counted, predicted / true y acceleration)] for t = H..frames-1."""
    h = model.hparams.history
    pred, true = one_step_accelerations(model, scene, test, 0, frames)  # [V, F, N, 3], frames H..frames-1
    movable = ~torch.as_tensor(scene.kinematic)
    expected = (test.params[:, 0] * float(scene.dt) ** 2)[:, None]  # [V, 1] m / frame^2 of free fall
    rows = []
    for f in range(pred.shape[1]):
        true_acc, pred_acc = true[:, f, movable, UP], pred[:, f, movable, UP]  # [V, movable]
        falling = (true_acc / expected - 1).abs() < 0.01
        count = int(falling.sum())
        rows.append((h + f, count, float(pred_acc[falling].sum() / true_acc[falling].sum()) if count else float("nan")))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--root", default="data/standard", help="dataset root with <env>/test shards (true trajectories)")
    parser.add_argument("--videos", type=int, default=20, help="first test videos")
    parser.add_argument("--frames", type=int, default=15, help="frames from 0 (the oracle's window is 15)")
    args = parser.parse_args()
    torch.set_grad_enabled(False)
    for path in args.checkpoints:
        model, cfg = load_dynamics(path)
        model.eval()
        scene = scene_of(cfg)
        if scene.param_names != ("gravity",):
            raise SystemExit(f"{path}: a {scene.name} prior; this measures RigidFall's gravity only")
        test = load_split(args.root, scene.name, "test", max_rollouts=args.videos)
        rows = fall_acceleration_ratio(model, scene, test, args.frames)
        print(f"{path}: predicted / true y acceleration of free-falling particles, {test.positions.shape[0]} test videos")
        for t, count, ratio in rows:
            print(f"  frame {t:2d}: {count:5d} particles  ratio {ratio:.4f}")
        counted = [(c, r) for _, c, r in rows if c]
        print(f"  particle-weighted mean: {sum(c * r for c, r in counted) / sum(c for c, _ in counted):.4f}")


if __name__ == "__main__":
    main()
