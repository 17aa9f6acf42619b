"""How the message passing sums its messages at the receivers: PyG's "sum" aggregation (a scatter,
whose backward gathers through an index as wide as the messages) against ``Propagator.aggregate``
(index_add, whose backward is an index_select). The InferenceModule training step, from nothing,
at each preset's settings, with the two alternated in one process so that a shared machine's drift
falls on both alike.

    python benchmarks/aggregation.py --env rigid_fall --presets quick paper   # JSON lines on stdout

A step is the module's loss, backward and Adam in fp32 on one window of engine-simulated rollouts
(``inference_parts.setup``, ``inference_device.make_step``). Each round times ``--steps`` steps of each variant after one warm-up
step; the line gives the median of ``--rounds`` rounds and the rounds in which index_add was faster.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch
from torch_geometric.nn import MessagePassing

sys.path.insert(0, str(Path(__file__).resolve().parent))
from inference_device import make_step  # noqa: E402
from inference_parts import setup  # noqa: E402
from machine import describe  # noqa: E402

import vgpl.nn.propagation as propagation  # noqa: E402

VARIANTS = {"scatter": MessagePassing.aggregate, "index_add": propagation.Propagator.aggregate}
PRESETS = ["quick", "paper"]


def step_ms(step, steps: int) -> float:
    """Mean milliseconds of ``steps`` calls of ``step``."""
    start = time.perf_counter()
    for _ in range(steps):
        step()
    return (time.perf_counter() - start) / steps * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="rigid_fall", choices=["rigid_fall", "fluid_cube", "mass_rope"])
    parser.add_argument("--presets", nargs="+", default=["quick", "paper"], choices=PRESETS)
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    for preset in args.presets:
        _, model, window = setup(args.env, None, 2, preset)
        step = make_step(model, window, torch.device("cpu"), bf16=False)
        rounds = {name: [] for name in VARIANTS}
        for _ in range(args.rounds):
            for name, aggregate in VARIANTS.items():
                propagation.Propagator.aggregate = aggregate
                step_ms(step, 1)
                rounds[name].append(step_ms(step, args.steps))
        propagation.Propagator.aggregate = VARIANTS["index_add"]
        median = {name: statistics.median(ms) for name, ms in rounds.items()}
        print(json.dumps({"benchmark": "aggregation", "env": args.env, "preset": preset, "width": model.hparams.width, "prior_width": model.dynamics.hparams.width, "batch": 2, "precision": "32-true",
                          "step_ms": {name: round(ms, 1) for name, ms in median.items()},
                          "rounds_ms": {name: [round(ms, 1) for ms in v] for name, v in rounds.items()},
                          "speedup": round(median["scatter"] / median["index_add"], 3),
                          "rounds_index_add_faster": sum(a < b for a, b in zip(rounds["index_add"], rounds["scatter"])),
                          "machine": describe()}), flush=True)


if __name__ == "__main__":
    main()
