"""Does a dynamics prior shrink accelerations? One step from the true history, any env.

For each test video and each frame of the evaluation's window (from the env's start_frame), the
prior predicts the next frame from the true history (kinematic particles driven by the truth).
Its acceleration (next - 2 x last + the one before, per frame^2) is compared with the truth's:
per object, on the object's centroid, as the least-squares slope sum(pred . true) / sum(true .
true) over videos and frames, and over every movable particle. A slope under 1 is a prior whose
one-step motion reacts too little to the forces: history noise teaches that (a noisy history's
best guess of a fast velocity is a smaller one; session 41), and it biases the parameters a
rollout through the prior fits. RigidFall's free-fall ratio (prior_fall_acceleration.py) is the
special case of gravity alone.

    python scripts/experiments/prior_acceleration_slope.py CKPT [CKPT ...] [--root data/standard] [--videos 20] [--frames 15]
"""

from __future__ import annotations

import argparse

import torch

from vgpl.checkpoint import scene_of
from vgpl.data.trajectories import load_split
from vgpl.eval.one_step import one_step_accelerations, slope
from vgpl.tasks.train_dynamics import load_dynamics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--root", default="data/standard", help="dataset root with <env>/test shards (true trajectories)")
    parser.add_argument("--videos", type=int, default=20, help="first test videos")
    parser.add_argument("--frames", type=int, default=15, help="frames from the env's start_frame (the oracle's window is 15)")
    args = parser.parse_args()
    torch.set_grad_enabled(False)
    for path in args.checkpoints:
        model, cfg = load_dynamics(path)
        model.eval()
        scene = scene_of(cfg)
        start = int(cfg.env.get("start_frame", 0))
        test = load_split(args.root, scene.name, "test", max_rollouts=args.videos)
        pred, true = one_step_accelerations(model, scene, test, start, args.frames)
        movable = ~torch.as_tensor(scene.kinematic)
        print(f"{path}: {scene.name}, {test.positions.shape[0]} test videos, frames {start + model.hparams.history}-{start + args.frames - 1}")
        for m in range(int(test.rigid.shape[0])):
            members = (test.instance == m) & movable
            if members.any():
                kind = "rigid" if bool(test.rigid[m]) else "non-rigid"
                print(f"  object {m} ({kind}, {int(members.sum())} particles): centroid slope "
                      f"{slope(pred[:, :, members].mean(2), true[:, :, members].mean(2)):.4f}, "
                      f"particle slope {slope(pred[:, :, members], true[:, :, members]):.4f}")
        print(f"  every movable particle: slope {slope(pred[:, :, movable], true[:, :, movable]):.4f}")


if __name__ == "__main__":
    main()
