"""Does a dynamics prior respond to its physical parameter as the engine does? Any env.

From the recorded state of each test video (the oracle's window: the env's start_frame, the
prior's H true frames, then ``--frames`` - H rolled), the engine is restarted at the parameter
+-delta about the truth and the prior rolled at the same two values (vgpl.eval.param_response).
Printed per checkpoint: the slope and cosine of the prior's response on the engine's, their sizes,
the prior's residual at the truth, and the oracle's error linearised about the truth (-<e, r> /
<r, r>) with the prior's response and with the engine's: what the prior's residual would cost if
it responded as the engine does. ``--json`` writes the numbers.

    python scripts/experiments/prior_param_response.py CKPT [CKPT ...] [--root data/standard] [--videos 100] [--start F] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import torch

from vgpl.checkpoint import scene_of
from vgpl.data.trajectories import load_split
from vgpl.eval.param_response import param_response
from vgpl.tasks.train_dynamics import load_dynamics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--root", default="data/standard", help="dataset root with <env>/test shards (true trajectories and velocities)")
    parser.add_argument("--videos", type=int, default=100, help="first test videos")
    parser.add_argument("--start", type=int, help="first frame of the window (default: the checkpoint's env.start_frame)")
    parser.add_argument("--frames", type=int, default=15, help="window length from the env's start_frame (the oracle's: observed 10 + horizon 5)")
    parser.add_argument("--delta", type=float, default=0.1, help="half-step of the central difference, normalised units (range [-1, 1])")
    parser.add_argument("--json", help="write every checkpoint's numbers here")
    args = parser.parse_args()
    torch.set_grad_enabled(False)
    rows = []
    for path in args.checkpoints:
        began = time.time()
        model, cfg = load_dynamics(path)
        model.eval()
        scene = scene_of(cfg)
        start = int(cfg.env.get("start_frame", 0)) if args.start is None else args.start
        test = load_split(args.root, scene.name, "test", max_rollouts=args.videos, velocities=True)
        n = test.positions.shape[0]
        # every movable particle (what the oracle's L1 sums), then each object alone
        subsets = [("all", None)] + [(f"object {m} ({scene.instance_types[m]})", test.instance == m) for m in range(int(test.rigid.shape[0]))]
        for j, name in enumerate(scene.param_names):
            response = param_response(model, scene, test, start, args.frames, n, j, args.delta)
            for label, members in subsets:
                s = response.summary(members)
                rows.append({"checkpoint": path, "env": scene.name, "param": name, "particles": label, "videos": n, "history": model.hparams.history,
                             "frames": [start, start + args.frames - 1], "delta": args.delta, **s})
                print(f"{path} ({scene.name}, H={model.hparams.history}, {n} videos, {time.time() - began:.0f} s): {name}, {label}: "
                      f"slope {s['pooled_slope']:.3f} (median {s['median_slope']:.3f}), cosine {s['median_cosine']:.2f}, "
                      f"|r_E| {s['median_engine_response']:.1f}, |r_P| {s['median_prior_response']:.1f}, residual {s['median_residual']:.1f}; "
                      f"linearised oracle {s['linear_mae_pct_prior_response']:.1f}% (with the engine's response {s['linear_mae_pct_engine_response']:.1f}%); "
                      f"restart error {s['restart_error_m']:.1e} m")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": platform.processor() or platform.machine(), "torch": torch.__version__, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
