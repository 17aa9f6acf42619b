"""DynamicsPrior speed and memory against the original dense design, at batch 4.

    python benchmarks/dynamics.py            # JSON lines on stdout

For graphs of RigidFall, FluidCube and MassRope size (real simulated windows spread over a
rollout, the env's radius):
training step (forward + backward + Adam, graph construction included for vgpl; in float32 and in
bf16 mixed precision: fast only where the CPU has avx512_bf16 or amx, see the machine's `isa`), forward, and
one rollout step at batch 1 (median of repeated calls); growth of the peak resident set; and the multiply-adds
each design needs per forward pass, counted from the layer shapes. vgpl is timed as run.py runs it
(malloc keeping freed memory, vgpl.allocator) and with glibc's default settings
(``vgpl_default_allocator``); the dense reference with the default, as the authors' code ran.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dense_dpinet import DenseDPINet  # noqa: E402
from machine import describe  # noqa: E402

import vgpl.nn.propagation as propagation  # noqa: E402
from vgpl.allocator import keep_freed_memory  # noqa: E402
from vgpl.models.dynamics_prior import DynamicsPrior  # noqa: E402
from vgpl.sim.envs import make_scene  # noqa: E402

RADIUS = {"rigid_fall": 0.08, "fluid_cube": 0.08, "mass_rope": 0.25}
W = 150
# The authors' own DPI-Net (the DynamicsPredictor of their release's models.py, op for op): one training
# step at batch 4, width 150, 2 propagation steps, float32, 2 threads, at each env's node and edge counts
# below, on the machine given (docs/benchmarks.md). Ratios against figures from another machine say as
# much about the machines as about the code, so a run uses the figures of its own CPU generation where
# there are some.
AUTHORS_REFERENCE = [
    {"machine": {"cpu": "AMD EPYC", "cpu_generation": None, "isa": ["avx2", "avx512f", "avx512_bf16", "avx512_vnni"],
                 "cores": 2, "torch": "2.13.0+cpu"},
     "train_step_ms": {"rigid_fall": 304.0, "mass_rope": 888.0, "fluid_cube": 579.0}},
    {"machine": {"cpu": "AMD EPYC", "cpu_generation": "family 26 model 2", "isa": ["avx2", "avx512f", "avx512_bf16", "avx512_vnni"],
                 "cores": 2, "torch": "2.14.1+cu130"},
     "train_step_ms": {"rigid_fall": 159.6, "mass_rope": 410.4, "fluid_cube": 504.1}},
]


def authors_reference(machine: dict) -> dict:
    """The authors' figures measured on ``machine``'s CPU generation, else the first ones."""
    generation = machine.get("cpu_generation")
    same = [ref for ref in AUTHORS_REFERENCE if generation is not None and ref["machine"]["cpu_generation"] == generation]
    return {**(same or AUTHORS_REFERENCE)[0], "same_cpu_generation": bool(same)}


def timed(fn, repeat: int) -> float:
    """Median wall time in ms over ``repeat`` calls after two warm-ups (robust to other load)."""
    fn()
    fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times)) * 1e3


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def macs(v: int, e: int, fn: int, fe: int, m: int, steps: int = 2) -> dict:
    """Multiply-adds per forward pass, from the layer shapes."""
    ours = (
        v * (fn * W + 2 * W * W)  # node encoder
        + v * 2 * fn * W + e * fe * W + e * 2 * W * W  # edge encoder, first layer split per node
        + e * W * W  # edge term, once
        + steps * v * (2 * W * W + 2 * W * W)  # receiver/sender projections + node update
        + v * (2 * W * W + 3 * W) + m * (2 * W * W + 7 * W)  # heads
    )
    dense = (
        v * (fn * W + 2 * W * W)
        + 2 * e * v * fn + e * ((2 * fn + fe) * W + 2 * W * W)  # one-hot gathers + full edge MLP
        + steps * (3 * e * v * W + e * 3 * W * W + v * 2 * W * W)  # Rr@, Rs@, Rr^T@ + edge/node MLPs
        + v * (2 * W * W + 3 * W)
    )
    return {"macs_vgpl": ours, "macs_dense": dense}


def measure(env: str, impl: str, batch: int = 4) -> dict:
    """Timings and peak-RSS growth of one implementation (run in a fresh process: the peak
    resident set is per process)."""
    scene = make_scene(env)
    tr = scene.simulate([scene.sample(np.random.default_rng(s)) for s in range(batch)])
    # one window per scene, spread over the rollout (early falls have fewer contacts than late rests)
    ends = np.linspace(scene.start_frame if hasattr(scene, "start_frame") else 10, scene.n_steps - 2, batch).astype(int)
    pick = lambda x, a, b: torch.stack([x[k, e + a : e + b] for k, e in enumerate(ends)])  # noqa: E731
    g = torch.nn.functional.one_hot(torch.as_tensor(scene.instance), scene.n_instances).float().expand(batch, -1, -1)
    q = torch.as_tensor(scene.rigid).float().expand(batch, -1)
    planes = pick(scene.planes_at(tr.actions), -3, 1)
    kin = torch.as_tensor(scene.kinematic)
    hist, target = pick(tr.positions, -3, 1), pick(tr.positions, 1, 2)[:, 0]
    model = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, RADIUS[env])
    opt = torch.optim.Adam(model.parameters(), 1e-4)
    nodes, edge_index, edge_attr = model.build_inputs(hist, g, q, tr.params, planes, kin)
    v, e = nodes.shape[0] // batch, edge_index.shape[1] // batch

    def train_step(dtype=None):
        opt.zero_grad()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=dtype is not None):
            pred = model(hist, g, q, tr.params, planes, kin)
        (pred.float() - model.to_normalised(target - hist[:, -1])).abs().mean().backward()
        opt.step()

    def forward():
        with torch.no_grad():
            model(hist, g, q, tr.params, planes, kin)

    def rollout_step():
        with torch.no_grad():
            model.step(hist[:1], g[:1], q[:1], tr.params[:1], planes[:1], kin)

    if impl == "vgpl":
        base = peak_mb()
        propagation.ALIGNMENT = 1
        exact = timed(train_step, 20)  # the per-edge activations at the exact width, as before they were aligned
        propagation.ALIGNMENT = 8
        ours = {
            "train_step_ms_exact_width": exact,
            "train_step_ms": timed(train_step, 20),
            "train_step_ms_bf16_mixed": timed(lambda: train_step(torch.bfloat16), 20),
            "forward_ms": timed(forward, 20),
            "rollout_step_ms_batch1": timed(rollout_step, 20),
        }
        ours["peak_rss_growth_mb"] = round(peak_mb() - base, 1)
        counts = macs(v, e, nodes.shape[1], edge_attr.shape[1], scene.n_instances)
        return {"nodes_per_scene": v, "edges_per_scene": e, "forward_gmacs_vgpl": round(counts["macs_vgpl"] * batch / 1e9, 3),
                "forward_gmacs_dense": round(counts["macs_dense"] * batch / 1e9, 3), **{k: round(x, 2) for k, x in ours.items()}}

    dense = DenseDPINet(nodes.shape[1], edge_attr.shape[1])
    dopt = torch.optim.Adam(dense.parameters(), 1e-4)
    dn = nodes[: batch * v].reshape(batch, v, -1) if nodes.shape[0] == batch * v else torch.randn(batch, v, nodes.shape[1])
    da = torch.randn(batch, e, edge_attr.shape[1])
    idx = torch.randint(0, v, (batch, e, 2))
    rr = torch.nn.functional.one_hot(idx[..., 0], v).float()
    rs = torch.nn.functional.one_hot(idx[..., 1], v).float()
    dtarget = torch.randn(batch, v, 3)

    def dense_train():
        dopt.zero_grad()
        (dense(dn, da, rr, rs) - dtarget).abs().mean().backward()
        dopt.step()

    def dense_forward():
        with torch.no_grad():
            dense(dn, da, rr, rs)

    def dense_rollout():
        with torch.no_grad():
            dense(dn[:1], da[:1], rr[:1], rs[:1])

    base = peak_mb()
    ref = {"train_step_ms": timed(dense_train, 10), "forward_ms": timed(dense_forward, 10), "rollout_step_ms_batch1": timed(dense_rollout, 20)}
    ref["peak_rss_growth_mb"] = round(peak_mb() - base, 1)
    return {k: round(x, 2) for k, x in ref.items()}


def run_child(env: str, impl: str, allocator: str = "default") -> dict:
    """``measure`` in a fresh process; ``allocator`` "keep": with vgpl.allocator.keep_freed_memory, as
    run.py's tasks run (``keep_freed_memory: true``), "default": glibc's own settings."""
    out = subprocess.run([sys.executable, __file__, "--child", env, impl, allocator], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    torch.set_num_threads(2)
    torch.manual_seed(0)
    if sys.argv[1:2] == ["--child"]:
        if sys.argv[4] == "keep":
            keep_freed_memory()
        print(json.dumps(measure(sys.argv[2], sys.argv[3])))
        return
    machine = describe()
    authors = authors_reference(machine)
    print(json.dumps({"machine": machine}), flush=True)
    for env in sys.argv[1:] or ["rigid_fall", "fluid_cube", "mass_rope"]:
        ours, ref = run_child(env, "vgpl", "keep"), run_child(env, "dense")
        plain = run_child(env, "vgpl", "default")
        counts = {k: ours.pop(k) for k in ("nodes_per_scene", "edges_per_scene", "forward_gmacs_vgpl", "forward_gmacs_dense")}
        print(json.dumps({
            "env": env, "batch": 4, "width": W, "propagation_steps": 2, **counts, "vgpl": ours,
            "vgpl_default_allocator": {k: plain[k] for k in ("train_step_ms", "train_step_ms_bf16_mixed", "forward_ms", "peak_rss_growth_mb")},
            "dense_reference": ref,
            "train_step_speedup": round(ref["train_step_ms"] / ours["train_step_ms"], 2),
            "train_step_speedup_bf16_mixed": round(ref["train_step_ms"] / ours["train_step_ms_bf16_mixed"], 2),
            "authors_train_step_ms": authors["train_step_ms"][env], "authors_machine": authors["machine"],
            "authors_same_cpu_generation": authors["same_cpu_generation"],
            "train_step_speedup_vs_authors": round(authors["train_step_ms"][env] / ours["train_step_ms"], 2),
            "train_step_speedup_vs_authors_bf16_mixed": round(authors["train_step_ms"][env] / ours["train_step_ms_bf16_mixed"], 2),
        }), flush=True)


if __name__ == "__main__":
    main()
