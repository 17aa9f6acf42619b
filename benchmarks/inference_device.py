"""The InferenceModule training step on an accelerator: steps per second at several batch sizes,
eager and with the message passing compiled, and where the step's time goes.

    python benchmarks/inference_device.py --env rigid_fall --batches 2 16     # JSON lines on stdout

From nothing, like ``inference_parts.py``: engine-simulated windows (proposals = true positions +
5 mm noise), an untrained prior and module of the preset's shapes (the step's cost does not
depend on the weights). A step is the module's loss at the preset's settings (``--preset``, the
paper's by default), backward and Adam, under bf16 autocast unless ``--fp32``; the device is
synchronised before each clock read. Median of ``--repeat`` steps after ``--warmup`` steps (the
compiled variant compiles in its warm-ups).

Variants (``--modes``): ``eager``; ``compile``: the propagation steps, edge encoder and node encoder
of the prior and of both encoders wrapped in ``torch.compile(dynamic=True)`` (edge counts change
every step, so a static-shape CUDA graph cannot be captured). ``--profile N`` adds, for the eager
step at the first batch size, the N operators of most device time and the count of host-device
synchronisations (each ``nonzero`` of a graph build waits for the device).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from inference_parts import setup  # noqa: E402
from machine import describe  # noqa: E402

COMPILED = ("propagator", "edge_encoder", "node_encoder")  # the per-edge work of each message-passing network
SYNC_EVENTS = ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize", "cudaMemcpyAsync")


def to_device(window: dict, device: torch.device) -> dict:
    return {key: value.to(device) for key, value in window.items()}


def make_step(model, window: dict, device: torch.device, bf16: bool):
    """One training step (loss, backward, Adam) on ``window``; returns the callable."""
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-4)

    def step() -> None:
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
            loss = model._losses(window)["loss"]
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()

    return step


def synchronise(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def median_ms(step, device: torch.device, warmup: int, repeat: int) -> tuple[float, float]:
    """(median step ms over ``repeat`` steps, seconds the ``warmup`` steps took)."""
    synchronise(device)
    start = time.perf_counter()
    for _ in range(warmup):
        step()
    synchronise(device)
    warm_s = time.perf_counter() - start
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        step()
        synchronise(device)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3, warm_s


def profile(step, device: torch.device, top: int) -> dict:
    """The ``top`` operators of most self device time over three steps, and the synchronisations per step."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with torch_profile(activities=activities) as prof:
        for _ in range(3):
            step()
        synchronise(device)
    events = prof.key_averages()

    def device_us(e) -> float:
        return float(getattr(e, "self_device_time_total", getattr(e, "self_cuda_time_total", 0.0)))

    ranked = sorted(events, key=device_us if device.type == "cuda" else (lambda e: e.self_cpu_time_total), reverse=True)
    return {
        "top_ops": [{"op": e.key, "calls_per_step": e.count / 3, "self_device_ms_per_step": round(device_us(e) / 3e3, 2),
                     "self_cpu_ms_per_step": round(e.self_cpu_time_total / 3e3, 2)} for e in ranked[:top]],
        "device_ms_per_step": round(sum(device_us(e) for e in events) / 3e3, 1),
        "kernel_launches_per_step": sum(e.count for e in events if e.key in ("cudaLaunchKernel", "cuLaunchKernel", "cudaLaunchKernelExC")) / 3,
        "syncs_per_step": {e.key: e.count / 3 for e in events if e.key in SYNC_EVENTS},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="rigid_fall", choices=["rigid_fall", "fluid_cube", "mass_rope"])
    parser.add_argument("--preset", default="paper", help="experiment preset whose model.inference settings are timed")
    parser.add_argument("--batches", type=int, nargs="+", default=[2, 16])
    parser.add_argument("--modes", nargs="+", default=["eager", "compile"], choices=["eager", "compile"])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--fp32", action="store_true", help="no bf16 autocast")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--profile", type=int, default=0, metavar="N", help="also the N operators of most device time (0: off)")
    args = parser.parse_args()
    device = torch.device(args.device)
    machine = describe()
    for batch in args.batches:
        for mode in args.modes:
            _, model, window = setup(args.env, 150, batch, args.preset)
            model.to(device), model.dynamics.to(device)
            if mode == "compile":
                for owner in (model.dynamics, model.encoder, model.param_encoder):
                    for name in COMPILED if owner is not None else ():
                        getattr(owner, name).compile(dynamic=True)
            step = make_step(model, to_device(window, device), device, not args.fp32)
            ms, warm_s = median_ms(step, device, args.warmup, args.repeat)
            row = {"benchmark": "inference_step_device", "env": args.env, "preset": args.preset, "batch": batch, "mode": mode,
                   "precision": "32-true" if args.fp32 else "bf16-mixed", "device": str(device), "step_ms": round(ms, 1),
                   "steps_per_s": round(1e3 / ms, 2), "warmup_s": round(warm_s, 1), "machine": machine}
            if args.profile and mode == "eager" and batch == args.batches[0]:
                row["profile"] = profile(step, device, args.profile)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
