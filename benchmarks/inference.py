"""InferenceModule training-step time on real VisualPrior proposals, for the settings that set
its cost: batch size, one or two encoders (``separate_param_net``) and ``max_neighbors`` of the
proposals' radius graphs.

    python benchmarks/inference.py --data data/standard \
        --dynamics checkpoints/standard/fluid_cube/dynamics/last.ckpt   # JSON lines on stdout
    python benchmarks/inference.py ... --preset --profile   # the standard preset's step, and where its time goes

A step is what Lightning runs: the module's loss (encoders, heads, the rollout through the frozen
DynamicsPrior), backward and Adam, under bf16 autocast as the standard preset trains. Median over
``--repeat`` steps after two warm-ups. ``--preset`` times, instead of VARIANTS, the module as the
prior's own run configured it (its saved config's ``model.inference``, every setting of its net: for
a standard prior the standard preset's two encoders, both starts and 5-frame tail, on its window
span), with ``--set key=value`` changing keys of that net (``--set training.tail_horizon=0``); ``--profile`` adds the operators that took
the most of those steps' CPU time (torch.profiler, self time) to its JSON line; its step_ms then
includes the profiler's overhead, so time without it. ``--compile`` wraps the message-passing parts
of the prior and of both encoders in ``torch.compile(dynamic=True)`` (edge counts change every step):
``propagator`` the propagation steps, ``per_edge`` also the edge and node encoders; the first step,
which compiles, is one of the warm-ups.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import yaml
from omegaconf import OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe  # noqa: E402

from vgpl.checkpoint import load_stage, scene_of  # noqa: E402
from vgpl.data.inference_windows import InferenceDataModule  # noqa: E402
from vgpl.models.dynamics_prior import DynamicsPrior  # noqa: E402
from vgpl.models.inference import InferenceModule  # noqa: E402

VARIANTS = [  # (batch, separate_param_net, max_neighbors)
    (4, True, 24),   # the first standard run
    (2, True, 24),   # the paper's batch
    (2, False, 24),  # one shared encoder (--preset: the standard preset's settings)
    (2, False, 16),
]
COMPILED = {  # --compile: the submodules of the prior and of each encoder that torch.compile wraps
    "none": (),
    "propagator": ("propagator",),
    "per_edge": ("propagator", "edge_encoder", "node_encoder"),
}


def measure(dm: InferenceDataModule, dynamics: DynamicsPrior, scene, radius: float, batch: int, settings: dict, repeat: int,
            bf16: bool = True, profile: int = 0, compile_parts: str = "none") -> dict:
    """The median step of the module built with ``settings`` (InferenceModule's keywords but the scene: a VARIANTS
    row's, or a run's whole ``model.inference.net`` and its horizon); with ``profile`` > 0, also the ``profile``
    operators of most self CPU time over the timed steps."""
    torch.manual_seed(0)
    scene_options = {"param_low": scene.param_low.tolist(), "param_high": scene.param_high.tolist(), "n_particles": scene.n_particles,
                     "n_instances": scene.n_instances, "radius": radius, "instance_types": list(scene.instance_types)}
    model = InferenceModule(scene_options, **settings)
    model.set_stats(dynamics)
    model.attach_dynamics(dynamics)
    owners = [m for m in (dynamics, model.encoder, model.param_encoder) if m is not None]
    for owner in owners:
        for name in COMPILED[compile_parts]:
            getattr(owner, name).compile(dynamic=True)
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-4)
    dm.batch_size = batch
    batches = iter(dm.train_dataloader())

    def step() -> float:
        b = next(batches)
        start = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            loss = model._losses(b)["loss"]
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        return time.perf_counter() - start

    step()
    step()
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) if profile else contextlib.nullcontext() as prof:
        times = [step() for _ in range(repeat)]
    ms = float(np.median(times)) * 1e3
    enc = model.encoder_options
    row = {"batch": batch, "width": enc.width, "separate_param_net": enc.separate_param_net, "max_neighbors": enc.max_neighbors,
           "trajectory_start": getattr(model.scheme, "start", "refined"), "training_scheme": model.scheme.name,
           "tail_horizon": model.training_runs.tail_horizon,
           "compile": compile_parts, "precision": "bf16-mixed" if bf16 else "32-true",
           "step_ms": round(ms, 1), "ms_per_window": round(ms / batch, 1)}
    if profile:
        ops = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)
        total = sum(e.self_cpu_time_total for e in ops)
        row["self_cpu_share"] = {e.key: round(e.self_cpu_time_total / total, 3) for e in ops[:profile]}
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default="data/standard", help="dataset root (holds <env>/proposals/train.h5)")
    parser.add_argument("--dynamics", default="checkpoints/standard/fluid_cube/dynamics/last.ckpt")
    parser.add_argument("--repeat", type=int, default=8)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--trajectory-start", default="refined", choices=["refined", "truth", "both"],
                        help="model.inference.net.scheme.start of the joint scheme the variants train by ('both' rolls two starts)")
    parser.add_argument("--window-span", type=int, default=20, help="model.inference.window_span the proposals were exported for (quick: 8; --preset reads the run's)")
    parser.add_argument("--fp32", action="store_true", help="no bf16 autocast (what fast_precision picks on a CPU without bf16 units)")
    parser.add_argument("--variants", type=int, nargs="*", help="indices into VARIANTS to run (default: all)")
    parser.add_argument("--preset", action="store_true",
                        help="time the module as the prior's run configured it (its config's model.inference, window span included) instead of VARIANTS")
    parser.add_argument("--compile", default="none", choices=list(COMPILED),
                        help="torch.compile(dynamic=True) these parts of the prior and the encoders (none: eager)")
    parser.add_argument("--profile", type=int, default=0, metavar="K", help="also record the K operators of most self CPU time (0: off)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="with --preset: change these keys of the run's model.inference.net (e.g. training.tail_horizon=0 horizon=0)")
    args = parser.parse_args()
    if args.set and not args.preset:
        parser.error("--set changes the run's model.inference.net: it needs --preset")
    torch.set_num_threads(args.threads)
    dynamics, cfg = load_stage(args.dynamics, DynamicsPrior)
    scene = scene_of(cfg)
    preset = cfg.model.inference
    net = None
    if args.preset:  # the run's module, every setting, with --set's changes
        net = OmegaConf.create({"horizon": preset.horizon, **{k: v for k, v in OmegaConf.to_container(preset.net, resolve=True).items() if k != "_target_"}})
        for item in args.set:
            key, _, value = item.partition("=")
            if OmegaConf.select(net, key, default=KeyError) is KeyError:
                parser.error(f"--set {item}: model.inference.net has no key {key!r} (keys: {', '.join(sorted(net))})")
            OmegaConf.update(net, key, yaml.safe_load(value))
        net = OmegaConf.to_container(net)
    horizon = net["horizon"] if net is not None else 5
    dm = InferenceDataModule(args.data, scene, 10, horizon, 2, cfg.env.get("start_frame", 0), 1, preset.window_span if args.preset else args.window_span)
    dm.setup()
    machine = describe()
    radius = float(cfg.env.graph_radius)
    runs = [(preset.batch_size, net)] if args.preset else [
        (batch, {"encoder": {"separate_param_net": separate, "max_neighbors": neighbors}, "horizon": 5,
                 "scheme": {"_target_": "vgpl.models.training_scheme.JointScheme", "start": args.trajectory_start},
                 "training": {"one_step_windows": 0, "refined_steps": None, "truth_steps": None}})
        for i, (batch, separate, neighbors) in enumerate(VARIANTS) if not args.variants or i in args.variants]
    for batch, settings in runs:
        row = measure(dm, dynamics, scene, radius, batch, settings, args.repeat, not args.fp32, args.profile, args.compile)
        extra = {"set": args.set} if args.set else {}
        print(json.dumps({"benchmark": "inference_train_step", "env": scene.name, **row, **extra, "machine": machine}), flush=True)


if __name__ == "__main__":
    main()
