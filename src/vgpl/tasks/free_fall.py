"""task=free_fall_gravity: how well gravity can be read from the exported proposals of RigidFall
by a least-squares free-fall fit (vgpl.eval.free_fall), with the proposals' error as it is and
scaled down: the proposal error a parameter MAE needs, with no learned model in between but a
linear calibration g = a + b x fit, fitted on the training split's proposals (it removes a
systematic bias in the proposals' fall, which a learned reader of P would learn too)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import torch
from omegaconf import DictConfig

from vgpl.data.inference_windows import split_with_proposals
from vgpl.eval.free_fall import FreeFallSplit, calibration
from vgpl.eval.tables import markdown
from vgpl.metrics import param_signed_error_pct

log = logging.getLogger(__name__)


def free_fall_gravity(cfg: DictConfig) -> dict:
    env = cfg.env.name
    if env != "rigid_fall":
        raise ValueError(f"task=free_fall_gravity reads gravity from falling bodies: env=rigid_fall only (got env={env})")
    frames = int(cfg.task.frames)
    low, high = float(cfg.env.scene.param_low[0]), float(cfg.env.scene.param_high[0])
    splits = {}
    for split in ("train", "test"):
        rollouts, proposals = split_with_proposals(cfg.data.root, env, split)
        if not 3 <= frames <= proposals.positions.shape[1]:
            raise ValueError(f"task.frames={frames}: expected 3 to {proposals.positions.shape[1]} (the frames the {split} proposals cover)")
        splits[split] = FreeFallSplit.of(rollouts, proposals, frames)
    train, test = splits["train"], splits["test"]
    pct = lambda g: param_signed_error_pct(g.clamp(low, high), test.gravity, low, high)  # noqa: E731  (clipped to the range, as P is)
    rows = []
    for scale in [float(s) for s in cfg.task.error_scales]:
        a, b = calibration(train.fit(scale), train.gravity)
        fitted = test.fit(scale)
        raw, calibrated = pct(fitted), pct(a + b * fitted)
        rows.append({"error_scale": scale, "proposal_mse_x1e4": scale**2 * test.position_mse * 1e4,
                     "gravity_mae_pct": float(raw.abs().mean()), "gravity_bias_pct": float(raw.mean()),
                     "calibrated_gravity_mae_pct": float(calibrated.abs().mean()), "calibrated_gravity_mae_pct_std": float(calibrated.abs().std()),
                     "calibration": [a, b]})
    result = {"env": env, "proposals": str(Path(cfg.data.root) / env), "n_train": len(train.gravity), "n_test": len(test.gravity),
              "frames": frames, "profile": [float(s) for s in test.profile], "free_bodies": int(test.free.sum()), "bodies": test.free.numel(),
              "midpoint_gravity_mae_pct": float(pct(torch.full_like(test.gravity, (low + high) / 2)).abs().mean()), "fits": rows}
    out = Path(cfg.paths.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(result, indent=1))
    table = markdown(["proposals' error x", "proposal MSE x 1e4", "gravity MAE %, fit (bias)", "calibrated on train: MAE % (std)"],
                     [[f"{r['error_scale']:g}", f"{r['proposal_mse_x1e4']:.2f}", f"{r['gravity_mae_pct']:.1f} ({r['gravity_bias_pct']:+.1f})",
                       f"{r['calibrated_gravity_mae_pct']:.1f} ({r['calibrated_gravity_mae_pct_std']:.1f})"] for r in rows])
    text = (f"# Gravity from a free-fall fit to frames 0-{frames - 1}: {len(test.gravity)} test videos, calibrated on "
            f"{len(train.gravity)} training videos\n\n{table}\n\nThe range midpoint scores {result['midpoint_gravity_mae_pct']:.1f}%. "
            f"{result['free_bodies']} of the test videos' {result['bodies']} bodies fall freely from rest over these frames; the fit reads those.\n")
    (out / "free_fall_gravity.md").write_text(text)
    log.info("%s", text)
    return result
