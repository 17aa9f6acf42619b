"""Where an InferenceModule training step spends its time, at a preset's settings (--preset, the paper's by default),
from nothing: windows of engine-simulated rollouts (proposals = true positions + 5 mm noise,
as dense as a trained visual prior's), an untrained prior and module of the preset's shapes
(the step's cost does not depend on the weights). No dataset or checkpoint is needed.

    python benchmarks/inference_parts.py --env rigid_fall            # JSON lines: exact width, then aligned
    python benchmarks/inference_parts.py --env rigid_fall --width 152

Each run times the step twice, with the per-edge activations at the exact width (``alignment``
1: how vgpl computed them before) and aligned to 8 columns (the default; vgpl.nn.propagation).

Parts, each forward + backward, median of --repeat after two warm-ups: the whole step (loss,
backward, Adam); one spatio-temporal encoder's radius graph, node MLP, per-edge MLP (edge encoder
and its edge term), the propagation steps and the bidirectional GRU; the rollouts through the frozen
prior (the preset's starts, B scenes each, observed - history + horizon steps) and the tail.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import hydra
import numpy as np
import torch
from hydra import compose, initialize_config_dir

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dynamics import timed  # noqa: E402
from machine import describe  # noqa: E402

import vgpl.nn.propagation as propagation  # noqa: E402
from vgpl.data.trajectories import NormStats, Rollouts, ground_truth_grouping  # noqa: E402
from vgpl.graph import edge_features, radius_graph  # noqa: E402
from vgpl.models.dynamics_prior import DynamicsPrior  # noqa: E402
from vgpl.models.rollout import rollout  # noqa: E402
from vgpl.tasks.train_inference import inference_module  # noqa: E402

CONF = Path(__file__).resolve().parents[1] / "conf"


def median_ms(fn, repeat: int) -> float:
    return round(timed(fn, repeat), 1)


def preset_config(env: str, preset: str):
    """The composed config of ``experiment=<preset> env=<env>``."""
    with initialize_config_dir(str(CONF), version_base="1.3"):
        return compose("config", overrides=[f"experiment={preset}", f"env={env}"])


def setup(env: str, width: int | None, batch: int, preset: str):
    """(config, module with its prior attached, one training batch) at the preset's settings;
    ``width`` both networks' width, or None for the preset's own (module and prior may differ)."""
    cfg = preset_config(env, preset)
    scene = hydra.utils.instantiate(cfg.env.scene)
    spec = cfg.model.inference
    t, k = spec.observed, spec.horizon
    traj = scene.simulate([scene.sample(np.random.default_rng(s)) for s in range(batch)])
    pos, kinematic = traj.positions.float(), torch.as_tensor(scene.kinematic)
    rollouts = Rollouts(pos, traj.params.float(), traj.actions.float(), torch.as_tensor(scene.instance).long(), torch.as_tensor(scene.rigid),
                        torch.as_tensor(scene.param_low), torch.as_tensor(scene.param_high), scene.name)
    net = {key: v for key, v in cfg.model.dynamics.net.items() if key != "_target_"} | ({} if width is None else {"width": width})
    prior = DynamicsPrior(scene.param_low.tolist(), scene.param_high.tolist(), scene.n_instances, cfg.env.graph_radius, **net)
    prior.set_stats(NormStats.from_rollouts(rollouts, kinematic))
    torch.manual_seed(0)
    if width is not None:
        cfg.model.inference.net.encoder.width = width
    model = inference_module(cfg, scene)
    model.set_stats(prior)
    model.attach_dynamics(prior)
    grouping = ground_truth_grouping(rollouts)
    noise = torch.Generator().manual_seed(0)
    seen = pos[:, :t]
    window = {"proposals": seen + 0.005 * torch.randn(seen.shape, generator=noise), "logits": (10 * grouping)[None, None].expand(batch, t, -1, -1).clone(),
              "positions": pos[:, : t + k], "planes": scene.planes_at(rollouts.actions)[:, : t + k], "params": rollouts.params,
              "kinematic": kinematic[None].expand(batch, -1), "rigid": rollouts.rigid[None].expand(batch, -1), "grouping": grouping[None].expand(batch, -1, -1)}
    return cfg, model, window


def parts(model, window, repeat: int) -> dict:
    """Milliseconds of the whole step and of each part (forward + backward)."""
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-4)

    def step():
        loss = model._losses(window)["loss"]
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()

    enc, prior = model.encoder, model.dynamics
    kinematic = window["kinematic"][0]
    grouping = torch.softmax(window["logits"], -1).mean(1)
    nodes = model._nodes(window["proposals"], grouping, kinematic)
    b, t, n, _ = nodes.shape
    flat = nodes.reshape(b * t * n, -1).requires_grad_(True)
    where = window["proposals"].reshape(-1, 3)
    frames = torch.arange(b * t).repeat_interleave(n)
    edges = radius_graph(where, enc.radius, frames, max_neighbors=enc.max_neighbors)
    attr = edge_features(where, edges, grouping[:, None].expand(b, t, n, -1).reshape(b * t * n, -1))
    code = enc.node_encoder(flat).detach().requires_grad_(True)
    term = enc.edge_encoder(flat, attr, edges, enc.edge_term).detach().requires_grad_(True)

    def propagate():
        effect = torch.zeros_like(code)
        for _ in range(enc.steps):
            effect = enc.propagator(effect, code, term, edges)
        effect.sum().backward()

    sequence = torch.randn(b * n, t, code.shape[1], requires_grad=True)
    h, k = prior.hparams.history, model.hparams.horizon
    starts = 2 if getattr(model.scheme, "start", "refined") == "both" else 1
    start = window["positions"][:, :h].repeat(starts, 1, 1, 1).clone().requires_grad_(True)
    params = window["params"].repeat(starts, 1).clone().requires_grad_(True)
    rigid = torch.full((starts * b, grouping.shape[-1]), 0.5, requires_grad=True)
    target = window["positions"][:, h:].repeat(starts, 1, 1, 1)
    planes = window["planes"].repeat(starts, 1, 1, 1)
    n_roll = t - h + k
    g = grouping.repeat(starts, 1, 1)
    encoders = 1 + (model.param_encoder is not None)
    return {
        "step_ms": median_ms(step, repeat),
        "encoders": encoders,
        "encoder_edges": int(edges.shape[1]),
        "per_encoder_ms": {
            "radius_graph": median_ms(lambda: radius_graph(where, enc.radius, frames, max_neighbors=enc.max_neighbors), repeat),
            "node_mlp": median_ms(lambda: enc.node_encoder(flat).sum().backward(), repeat),
            "edge_mlp": median_ms(lambda: enc.edge_encoder(flat, attr, edges, enc.edge_term).sum().backward(), repeat),
            "propagation": median_ms(propagate, repeat),
            "gru": median_ms(lambda: enc.gru(sequence)[0].sum().backward(), repeat),
        },
        "rollout_scenes": starts * b,
        "rollout_steps": n_roll,
        "rollout_ms": median_ms(lambda: rollout(prior, torch.cat([start, target], 1), g, rigid, params, planes, kinematic, n_roll).sum().backward(), repeat),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="rigid_fall", choices=["rigid_fall", "fluid_cube", "mass_rope"])
    parser.add_argument("--preset", default="paper", help="experiment preset whose model.inference settings are timed")
    parser.add_argument("--width", type=int, default=150, help="both networks' width (the paper's: 150)")
    parser.add_argument("--batch", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    _, model, window = setup(args.env, args.width, args.batch, args.preset)
    for alignment in (1, 8):
        propagation.ALIGNMENT = alignment
        row = {"benchmark": "inference_step_parts", "env": args.env, "preset": args.preset, "width": args.width, "alignment": alignment,
               "batch": args.batch, "precision": "32-true", **parts(model, window, args.repeat), "machine": describe()}
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
