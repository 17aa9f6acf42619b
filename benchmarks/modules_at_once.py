"""Two InferenceModules trained side by side, one thread each, against one trained alone on all the
threads (``task.modules_at_once``): training steps per second, from nothing, at a preset's settings.

    python benchmarks/modules_at_once.py --presets quick paper   # JSON lines on stdout

A step is the module's loss, backward and Adam on one window of engine-simulated rollouts
(``inference_parts.setup``, ``inference_device.make_step``), at the preset's widths and at the
precision the preset's modules train in on this machine (``--precision`` to choose another). "alone" runs one process with
``--threads`` threads for ``--seconds``; "side_by_side" two spawned processes with half the threads
each, started together for the same seconds. ``gain`` is the pair's steps per second over the lone
one's: what running the pipeline's two modules at once buys each of them in the same minutes.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # also in the spawned processes, which import this file
from inference_device import make_step  # noqa: E402
from inference_parts import preset_config, setup  # noqa: E402
from machine import describe  # noqa: E402

from vgpl.tasks.at_once import threads_each  # noqa: E402

PRESETS = ["quick", "paper"]


def module_precision(cfg) -> str:
    """The precision the config's inference module trains in (its stage's trainer, else the shared one), resolved."""
    return str(cfg.model.inference.get("trainer", {}).get("precision", cfg.trainer.precision))


def steps_per_second(env: str, preset: str, threads: int, seconds: float, precision: str | None = None, start=None, results=None) -> float:
    """Steps per second of the module's training step on ``threads`` threads over ``seconds`` (after
    one warm-up step and, with ``start``, once every process is ready); also put on ``results``.
    ``precision`` "32-true" or "bf16-mixed"; None: the preset's on this machine."""
    torch.set_num_threads(threads)
    cfg, model, window = setup(env, None, 2, preset)
    step = make_step(model, window, torch.device("cpu"), bf16="bf16" in (precision or module_precision(cfg)))
    step()
    if start is not None:
        start.wait()
    begin, n = time.perf_counter(), 0
    while time.perf_counter() - begin < seconds:
        step()
        n += 1
    rate = n / (time.perf_counter() - begin)
    if results is not None:
        results.put(rate)
    return rate


def side_by_side(env: str, preset: str, threads: int, seconds: float, precision: str | None = None, jobs: int = 2) -> list[float]:
    """Each of ``jobs`` spawned processes' steps per second, all stepping at once."""
    context = multiprocessing.get_context("spawn")
    start, results = context.Barrier(jobs), context.Queue()
    procs = [context.Process(target=steps_per_second, args=(env, preset, threads_each(threads, jobs), seconds, precision, start, results)) for _ in range(jobs)]
    for p in procs:
        p.start()
    rates = [results.get() for _ in procs]
    for p in procs:
        p.join()
    return rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="rigid_fall", choices=["rigid_fall", "fluid_cube", "mass_rope"])
    parser.add_argument("--presets", nargs="+", default=["quick"], choices=PRESETS)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=40.0)
    parser.add_argument("--precision", choices=["32-true", "bf16-mixed"], default=None, help="default: the preset's on this machine")
    args = parser.parse_args()
    for preset in args.presets:
        cfg = preset_config(args.env, preset)
        precision = args.precision or module_precision(cfg)
        alone = steps_per_second(args.env, preset, args.threads, args.seconds, precision)
        pair = side_by_side(args.env, preset, args.threads, args.seconds, precision)
        print(json.dumps({"benchmark": "modules_at_once", "env": args.env, "preset": preset, "width": cfg.model.inference.net.encoder.width,
                          "prior_width": cfg.model.dynamics.net.width, "batch": 2, "precision": precision, "threads": args.threads, "seconds": args.seconds,
                          "steps_per_s": {"alone": round(alone, 2), "side_by_side": [round(r, 2) for r in pair]},
                          "gain": round(sum(pair) / alone, 3), "machine": describe()}), flush=True)


if __name__ == "__main__":
    main()
