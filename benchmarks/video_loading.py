"""VisualPrior training data: videos held in memory against streamed from their shard files
(``model.visual.stream_video``). For each: the setup time and resident memory it adds, and the
time to assemble one training batch (32 random 4-frame windows, the DataLoader in the main
process as the presets run it), next to the measured training step it has to hide behind.

    python benchmarks/video_loading.py --data data/standard --env rigid_fall --rollouts 900   # JSON lines on stdout

Each variant runs in a fresh process, so one's memory does not count in the other's. Median
over ``--repeat`` batches after two warm-ups.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe  # noqa: E402

from vgpl.data.video import VideoDataModule  # noqa: E402


def rss_mb() -> float:
    """Peak resident memory of this process so far, MB (Linux reports KB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def measure(data: str, env: str, rollouts: int | None, stream: bool, batch: int, repeat: int) -> dict:
    torch.manual_seed(0)
    before = rss_mb()
    start = time.perf_counter()
    dm = VideoDataModule(data, env, batch_size=batch, max_rollouts=rollouts, max_test_rollouts=1, stream=stream)
    dm.setup()
    setup_s = time.perf_counter() - start
    memory = rss_mb() - before
    batches = iter(dm.train_dataloader())
    times = []
    for i in range(repeat + 2):
        start = time.perf_counter()
        next(batches)
        if i >= 2:
            times.append(time.perf_counter() - start)
    return {"videos": len(dm.train.images), "stream_video": stream, "batch": batch, "setup_s": round(setup_s, 1),
            "added_peak_rss_mb": round(memory), "batch_ms": round(float(np.median(times)) * 1e3, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default="data/standard", help="dataset root (holds <env>/train/shard_*.h5 with video)")
    parser.add_argument("--env", default="rigid_fall")
    parser.add_argument("--rollouts", type=int, default=None, help="training videos (default: all)")
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--variant", choices=["memory", "stream"], help="run one variant here (the parent runs each in a child)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.variant:
        row = measure(args.data, args.env, args.rollouts, args.variant == "stream", args.batch, args.repeat)
        print(json.dumps({"benchmark": "visual_video_loading", "env": args.env, **row, "machine": describe()}), flush=True)
        return
    for variant in ("stream", "memory"):
        command = [sys.executable, __file__, "--data", args.data, "--env", args.env, "--batch", str(args.batch),
                   "--repeat", str(args.repeat), "--variant", variant]
        if args.rollouts is not None:
            command += ["--rollouts", str(args.rollouts)]
        subprocess.run(command, check=True)


if __name__ == "__main__":
    main()
