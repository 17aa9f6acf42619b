"""Data-generation speed: scene-steps per second per environment, batch size and rendering, and
the time to make the paper-size datasets, measured end to end through the generate task.

    python benchmarks/generate.py                      # all envs, JSON lines on stdout
    python benchmarks/generate.py --envs fluid_cube --batch-sizes 1 64 --e2e-rollouts 0

Throughput rows use short rollouts (``--frames``); the end-to-end row runs ``task=generate`` with
full-length rollouts, worker processes and HDF5 writing, and extrapolates linearly.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe  # noqa: E402

from vgpl.sim.envs import make_scene  # noqa: E402
from vgpl.tasks.generate import generate  # noqa: E402

PAPER = {"rigid_fall": (5000, 120), "fluid_cube": (2000, 300), "mass_rope": (3000, 200)}
TARGET_MINUTES = {"rigid_fall": 15, "fluid_cube": 30, "mass_rope": 10}
CONF = Path(__file__).resolve().parents[1] / "conf"


def throughput(env: str, batch: int, frames: int, render: bool) -> float:
    scene = make_scene(env, n_steps=frames)
    samples = [scene.sample(np.random.default_rng(s)) for s in range(batch)]
    renderer = scene.renderer()
    scene.simulate(samples[:1])  # warm-up
    start = time.perf_counter()
    traj = scene.simulate(samples)
    if render:
        renderer.render(traj.positions.reshape(-1, scene.n_particles, 3))
    return batch * frames / (time.perf_counter() - start)


def end_to_end(env: str, rollouts: int, batch: int, processes: int) -> dict:
    with tempfile.TemporaryDirectory() as root, initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose(
            "config",
            overrides=[
                "task=generate", f"env={env}", f"data.root={root}", f"data.n_rollouts={rollouts}",
                f"data.shard_size={batch}", f"data.batch_size={batch}", f"data.processes={processes}",
                "data.progress=false", f"paths.output_dir={root}",
            ],
        )
        summary = generate(cfg)
        size = sum(p.stat().st_size for p in Path(root).rglob("*.h5"))
    n, steps = PAPER[env]
    rate = rollouts * steps / summary["seconds"]
    return {
        "env": env, "kind": "end_to_end", "rollouts": rollouts, "frames": steps, "batch": batch,
        "processes": processes, "seconds": round(summary["seconds"], 2), "scene_steps_per_s": round(rate, 1),
        "bytes_per_rollout": size // rollouts,
        "paper_size": f"{n} x {steps}", "paper_minutes": round(n * steps / rate / 60, 1),
        "target_minutes": TARGET_MINUTES[env], "paper_gigabytes": round(size / rollouts * n / 1e9, 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--envs", nargs="+", default=list(PAPER))
    ap.add_argument("--batch-sizes", nargs="+", type=int, default=[1, 16, 64])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--e2e-rollouts", type=int, default=128, help="0 skips the end-to-end run")
    ap.add_argument("--e2e-batch", type=int, default=64)
    ap.add_argument("--processes", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    print(json.dumps({"machine": describe()}), flush=True)
    for env in args.envs:
        for batch in args.batch_sizes:
            for render in (False, True):
                rate = throughput(env, batch, args.frames, render)
                print(json.dumps({"env": env, "kind": "throughput", "batch": batch, "render": render, "threads": args.threads, "scene_steps_per_s": round(rate, 1)}), flush=True)
        if args.e2e_rollouts:
            print(json.dumps(end_to_end(env, args.e2e_rollouts, args.e2e_batch, args.processes)), flush=True)


if __name__ == "__main__":
    main()
