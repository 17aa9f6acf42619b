"""VisualPrior training-step time on real video windows, by architecture, precision and memory layout.

    python benchmarks/visual.py --data data/standard --env rigid_fall   # JSON lines on stdout
    python benchmarks/visual.py --data data/quick --channels 16 32 64 128 --hidden 512 --batch 16   # the quick preset's widths

A step is the model's part of what Lightning runs: the position and grouping losses, backward and
Adam, under autocast for ``bf16-mixed``, on batches of 32 windows streamed from the training shards
(the standard preset's setting); not the batch's loading (``benchmarks/video_loading.py``: 58 ms
streamed) or Lightning's own per-step overhead. The architectures: ``paper`` (global regression) and
``spatial`` (per-slot heatmaps through the camera), both channels-last; the layouts, for ``paper``:
``channels_last`` (the encoder and its input, what ``VisualPrior`` uses) and ``contiguous`` (NCHW). Median over
``--repeat`` steps after two warm-ups; four batches are drawn once and cycled, so every variant
sees the same.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe  # noqa: E402

from vgpl.data.video import VideoDataModule  # noqa: E402
from vgpl.models.visual_prior import VisualPrior  # noqa: E402
from vgpl.sim.envs import make_scene  # noqa: E402


class ContiguousVisualPrior(VisualPrior):
    """The same network with its encoder and input in the NCHW layout."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.encoder.to(memory_format=torch.contiguous_format)

    @staticmethod
    def to_input(frames: torch.Tensor) -> torch.Tensor:
        return VisualPrior.to_input(frames).contiguous()


def measure(batches: list[dict], scene, precision: str, layout: str, repeat: int, architecture: str = "paper", **net) -> float:
    """Median milliseconds of one training step."""
    torch.manual_seed(0)
    cls = VisualPrior if layout == "channels_last" else ContiguousVisualPrior
    model = cls(scene.n_particles, scene.n_instances, architecture=architecture, **net)
    model.set_camera(scene.camera)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
    times = []
    for i in range(repeat + 2):
        batch = batches[i % len(batches)]
        start = time.perf_counter()
        with torch.autocast("cpu", torch.bfloat16, enabled=precision == "bf16-mixed"):
            position, grouping = model._losses(batch)
            loss = position + grouping
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if i >= 2:
            times.append(time.perf_counter() - start)
    return float(np.median(times)) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default="data/standard", help="dataset root (holds <env>/train/shard_*.h5 with video)")
    parser.add_argument("--env", default="rigid_fall")
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--channels", type=int, nargs="+", default=[32, 64, 128, 256], help="the conv blocks' widths")
    parser.add_argument("--hidden", type=int, default=2048, help="the paper architecture's head width")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    dm = VideoDataModule(args.data, args.env, batch_size=args.batch, max_rollouts=100, max_test_rollouts=1, stream=True)
    dm.setup()
    loader = iter(dm.train_dataloader())
    batches = [next(loader) for _ in range(4)]
    scene = make_scene(args.env)
    variants = [("paper", "contiguous"), ("paper", "channels_last"), ("spatial", "channels_last")]
    for precision in ("32-true", "bf16-mixed"):
        for architecture, layout in variants:
            ms = measure(batches, scene, precision, layout, args.repeat, architecture, channels=args.channels, hidden=args.hidden)
            print(json.dumps({"benchmark": "visual_train_step", "env": args.env, "batch": args.batch, "architecture": architecture,
                              "channels": args.channels, "precision": precision, "layout": layout, "step_ms": round(ms, 1),
                              "machine": describe()}), flush=True)


if __name__ == "__main__":
    main()
