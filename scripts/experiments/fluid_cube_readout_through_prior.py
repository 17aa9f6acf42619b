"""Can the paper's loss teach even a linear readout of viscosity? (session 23; a diagnostic).

The supervised probe (fluid_cube_viscosity_probe.py) reads viscosity from the proposals' motion
statistics to 7.9% of the range. Here the same linear readout, P = tanh(w . x + b) with x the
standardised statistics of a window's 10 observed proposal frames, is trained the inference
module's way: only through the frozen dynamics prior's rollout L1 from the true first frames
(trajectory_start=truth, horizon 5, true grouping and rigidness), on windows starting anywhere in
frames 0..20 of the 300 training rollouts. The encoder is taken out of the question: if this
readout does not learn P, the loss is what fails, not the representation.

Usage: python scripts/experiments/fluid_cube_readout_through_prior.py [minutes, 25] [batch, 8] [lr, 1e-2] [out, outputs/fc_readout_through_prior]
Writes OUT/metrics.json (test MAE every 50 steps); a short trial should name its own OUT.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from fluid_cube_viscosity_probe import load_with_proposals, motion_statistics  # this folder
from vgpl.checkpoint import scene_of
from vgpl.data.trajectories import ground_truth_grouping
from vgpl.eval.linear_probe import Ridge
from vgpl.eval.identifiability import rollout_l1_per_scene
from vgpl.tasks.train_dynamics import load_dynamics

ROOT, PRIOR = "data/standard", "checkpoints/standard/fluid_cube/dynamics/last.ckpt"
OBSERVED, HORIZON, SPAN = 10, 5, 20


def window_features(positions: np.ndarray, container: np.ndarray, instance: np.ndarray, start: int) -> np.ndarray:
    frames = slice(start, start + OBSERVED)
    return motion_statistics(positions[:, frames], container[:, frames], instance)


def main(minutes: float = 25, batch: int = 8, lr: float = 1e-2, out: str = "outputs/fc_readout_through_prior") -> None:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    model, train_cfg = load_dynamics(PRIOR)
    scene = scene_of(train_cfg)
    data = {split: load_with_proposals(ROOT, split) for split in ("train", "test")}
    train, train_prop = data["train"]
    test, test_prop = data["test"]
    instance = train.instance.numpy()
    container = {s: r.actions[..., :3].numpy() for s, (r, _) in data.items()}
    # features of every training window (rollout, start) and of the test windows at frame 0 (the evaluation's)
    starts = range(SPAN + 1)
    x_train = np.stack([window_features(train_prop, container["train"], instance, s) for s in starts], 1)  # [R, S, F]
    x_test = window_features(test_prop, container["test"], instance, 0)
    mu, sd = x_train.reshape(-1, x_train.shape[-1]).mean(0), x_train.reshape(-1, x_train.shape[-1]).std(0) + 1e-12
    x_train, x_test = torch.as_tensor((x_train - mu) / sd, dtype=torch.float32), torch.as_tensor((x_test - mu) / sd, dtype=torch.float32)
    truth_test = model.normalise_params(test.params)[:, 0]
    supervised = Ridge.fit(x_train[:, 0], model.normalise_params(train.params), alpha=1.0).predict(x_test)[:, 0]
    readout = torch.nn.Linear(x_train.shape[-1], 1)
    torch.nn.init.zeros_(readout.weight), torch.nn.init.zeros_(readout.bias)  # starts at the midpoint
    optimiser = torch.optim.Adam(readout.parameters(), lr=lr)
    grouping, rigidness = ground_truth_grouping(train), train.rigid.float()
    kinematic = torch.as_tensor(scene.kinematic)
    n_steps = OBSERVED + HORIZON - model.hparams.history

    def test_mae() -> tuple[float, float]:
        with torch.no_grad():
            pred = torch.tanh(readout(x_test))[:, 0]
        return float(((pred - truth_test).abs() * 50).mean()), float(np.corrcoef(pred.numpy(), truth_test.numpy())[0, 1]) if pred.std() > 0 else 0.0

    log = {"supervised_ridge_mae_pct": float(((supervised.clamp(-1, 1) - truth_test).abs() * 50).mean()),
           "midpoint_mae_pct": float((truth_test.abs() * 50).mean()), "batch": batch, "lr": lr, "curve": []}
    print(f"midpoint {log['midpoint_mae_pct']:.1f}%, supervised ridge on the same features {log['supervised_ridge_mae_pct']:.1f}%")
    t0, step = time.time(), 0
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    while time.time() - t0 < minutes * 60:
        if step % 50 == 0:
            mae, r = test_mae()
            log["curve"].append({"step": step, "test_mae_pct": mae, "r": r, "minutes": (time.time() - t0) / 60})
            print(f"step {step:4d} ({(time.time() - t0) / 60:4.1f} min): test viscosity MAE {mae:.1f}%, r = {r:.2f}", flush=True)
            (out / "metrics.json").write_text(json.dumps(log, indent=1))
        rows = torch.randint(len(train.params), (batch,))
        start = torch.randint(SPAN + 1, (batch,))
        frames = start[:, None] + torch.arange(OBSERVED + HORIZON)
        positions = train.positions[rows[:, None], frames]  # [B, 15, N, 3]
        planes = scene.planes_at(train.actions[rows[:, None], frames])
        p = torch.tanh(readout(x_train[rows, start]))  # [B, 1] normalised
        loss = rollout_l1_per_scene(model, positions, grouping.expand(batch, -1, -1), rigidness.expand(batch, -1), model.to_physical(p),
                                    planes, kinematic, n_steps).mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        step += 1
    mae, r = test_mae()
    log["curve"].append({"step": step, "test_mae_pct": mae, "r": r, "minutes": (time.time() - t0) / 60})
    (out / "metrics.json").write_text(json.dumps(log, indent=1))
    print(f"step {step}: test viscosity MAE {mae:.1f}%, r = {r:.2f}")


if __name__ == "__main__":
    main(*(cast(a) for cast, a in zip((float, int, float, str), sys.argv[1:])))
