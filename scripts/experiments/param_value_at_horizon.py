"""What is knowing the physical parameter worth at the evaluation's horizons? (session 61, a diagnostic)

"Full VGPL has the lowest T+20 of the four ablations" needs the parameter to matter at T+20. This
restarts the ENGINE from the recorded state of the last observed frame (start + observed - 1) of
each test video, and rolls the DYNAMICS PRIOR from the true last H observed frames (true grouping
and rigidness), each with several parameter sets: the truth, the range midpoint, and the parameters
of evaluations' ``params.csv`` (column ``inferred_<name>``: full VGPL's P, or w/o param. est.'s
uniform draws). Printed: future MSE x 1e4 at T+1/5/10/20 against the recording, and each set minus
the truth at the last horizon (paired bootstrap over videos). The engine's row is the most any
estimate of P can buy; the prior's what this prior gives for it from a perfect start.

Built in besides the truth and the midpoint: ``uniform``, one draw per video from the range (what
w/o param. est. feeds), and with ``--offsets 4.4 17.5`` the truth moved by that % of the range up or
down at random (clipped to the range): what an estimate with the tables' MAE costs. Without
``--prior`` only the engine runs, with the scene of ``--env`` (conf/env and ``--overrides``).

Usage: python scripts/experiments/param_value_at_horizon.py ROOT START (--prior DYNAMICS_CKPT | --env ENV) [LABEL=params.csv ...]
         [--offsets PCT ...] [--observed 10] [--steps 20] [--videos 100] [--json out.json]
e.g.   python scripts/experiments/param_value_at_horizon.py /tmp/r/data/standard 20 --prior /tmp/r/checkpoints/standard/fluid_cube/dynamics/last.ckpt \
         vgpl=/tmp/r/eval_full/params.csv uniform_eval=/tmp/r/ablate/1/params.csv
       python scripts/experiments/param_value_at_horizon.py /tmp/r/data/standard 0 --env rigid_fall --offsets 3.7 7.4
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir
from tqdm import tqdm

from vgpl.checkpoint import scene_of
from vgpl.data.trajectories import load_split, true_window
from vgpl.eval.error_breakdown import rollout_mse_x1e4
from vgpl.eval.metrics import param_error_pct
from vgpl.eval.paired import paired_bootstrap
from vgpl.eval.param_response import engine_from_frame
from vgpl.eval.rollout import future_mse, rollout
from vgpl.eval.tables import read_params_csv
from vgpl.tasks.train_dynamics import load_dynamics

CONF = Path(__file__).resolve().parents[2] / "conf"


def offset_params(truth: torch.Tensor, low: torch.Tensor, high: torch.Tensor, pct: float, generator: torch.Generator) -> torch.Tensor:
    """[R, P] the truth moved by ``pct`` % of the range, up or down at random, clipped to [low, high]."""
    sign = torch.randint(0, 2, truth.shape, generator=generator) * 2 - 1
    return (truth + sign * pct / 100 * (high - low)).clamp(low, high)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", help="dataset root with <env>/test shards")
    parser.add_argument("start", type=int, help="the evaluation's first observed frame (env.start_frame)")
    parser.add_argument("sets", nargs="*", help="LABEL=params.csv of an evaluation")
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--prior", help="the dynamics prior's checkpoint: roll it too (its config gives the scene)")
    which.add_argument("--env", help="engine only, with this env's scene (conf/env/ENV.yaml)")
    parser.add_argument("--overrides", nargs="*", default=[], help="with --env: Hydra overrides of the scene, as the data was generated")
    parser.add_argument("--offsets", nargs="*", type=float, default=[], help="%% of the range: the truth moved by it, up or down")
    parser.add_argument("--observed", type=int, default=10)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--videos", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0, help="of the uniform draws and the offsets' signs")
    parser.add_argument("--json", help="write the numbers here")
    args = parser.parse_args()
    if args.prior and args.overrides:
        parser.error("--overrides applies with --env only: with --prior the scene is the checkpoint's config")
    torch.set_grad_enabled(False)
    began = time.time()
    if args.prior:
        model, cfg = load_dynamics(args.prior)
        model.eval()
        h = model.hparams.history
    else:
        with initialize_config_dir(str(CONF), version_base=None):
            cfg = compose("config", overrides=[f"env={args.env}", *args.overrides])
        model, h = None, 1
    scene = scene_of(cfg)
    test = load_split(args.root, scene.name, "test", max_rollouts=args.videos, velocities=True)
    n = test.positions.shape[0]
    last_seen = args.start + args.observed - 1
    positions, grouping, rigidness, true_params, planes, kinematic = true_window(scene, test, last_seen - h + 1, h + args.steps, n)
    recorded = positions[:, h:]
    low, high = test.param_low, test.param_high
    g = torch.Generator().manual_seed(args.seed)
    sets = {"truth": true_params, "midpoint": ((low + high) / 2).expand(n, -1).clone(), "uniform": low + torch.rand(n, len(low), generator=g) * (high - low)}
    sets |= {f"truth {pct:+g}%": offset_params(true_params, low, high, pct, g) for pct in args.offsets}
    for item in args.sets:
        label, _, path = item.partition("=")
        if not path:
            raise ValueError(f"{item!r}: expected LABEL=path/to/params.csv")
        if label in sets:
            raise ValueError(f"{item!r}: the label {label!r} is taken (built in: {list(sets)}); give the file another")
        sets[label] = read_params_csv(path, list(scene.param_names)).select(test.rollout_ids[:n].tolist()).inferred
    results = {}
    for source in ("engine", "prior") if model is not None else ("engine",):
        errors = {}
        for label, p in tqdm(sets.items(), desc=source, total=len(sets)):
            if source == "engine":
                pred = engine_from_frame(scene, test, last_seen, args.steps, p)
            else:
                pred = rollout(model, positions, grouping, rigidness, p, planes, kinematic, args.steps)
            errors[label] = rollout_mse_x1e4(pred, recorded, args.steps)
            results[f"{source}/{label}"] = future_mse(pred, recorded) | {"per_video_last": errors[label].tolist(),
                                                                        "param_mae_pct": float(param_error_pct(p, true_params, low, high).mean())}
        print(f"\n{source} from the recorded frame {last_seen} ({n} {scene.name} videos, {time.time() - began:.0f} s): future MSE x 1e4")
        print(f"| P | its MAE % | T+1 | T+5 | T+10 | T+{args.steps} | T+{args.steps} minus truth [95%], truth lower on |")
        print("|---|---|---|---|---|---|---|")
        for label in sets:
            m = results[f"{source}/{label}"]
            cells = " | ".join(f"{m[f'future_mse_x1e4@{k}']:.3f}" for k in (1, 5, 10, args.steps))
            diff = ""
            if label != "truth":
                b = paired_bootstrap(errors["truth"], errors[label])
                results[f"{source}/{label}"]["minus_truth"] = b
                diff = f"{b['mean_diff']:+.3f} [{b['low']:+.3f}, {b['high']:+.3f}], {100 * b['reference_lower_share']:.0f}%"
            print(f"| {label} | {m['param_mae_pct']:.1f} | {cells} | {diff} |")
    if args.json:
        meta = {"prior": args.prior, "env": scene.name, "overrides": args.overrides, "root": args.root, "start": args.start, "observed": args.observed,
                "steps": args.steps, "videos": n, "sets": args.sets, "offsets": args.offsets, "seed": args.seed,
                "machine": platform.processor() or platform.machine(), "torch": torch.__version__, "seconds": time.time() - began}
        with open(args.json, "w") as f:
            json.dump(meta | {"results": results}, f, indent=1)


if __name__ == "__main__":
    main()
