"""vgpl's engine against the authors' FleX rollouts, started from the same frame 0.

    python benchmarks/flex_fidelity.py --demo <packed .h5, or a folder of <rollout>/<frame>.h5>
    python benchmarks/flex_fidelity.py --demo <path> --fit      # also search the fitted settings
    python benchmarks/flex_fidelity.py --env mass_rope --demo <path> [--fit]

For the env's default world (conf/env/<env>.yaml), and on RigidFall also the same world without
its floor pass (``contacts.floor_pass``) and with hard rigid-body contacts
(vgpl.sim.particle_contacts.BodyContacts), on the calibration rollouts and on
the held-out ones: position MSE x 1e4 (per coordinate) at frames 5, 10, 20, 50, 100 and the last;
the chaos floor (the same engine from a start with 1 mm of jitter); and the outcome statistics
beside FleX's (RigidFall: the cubes' landing; MassRope: the rope's stretch, the mass's turn and
drop). MassRope's pin follows FleX's recorded path. ``--fit`` searches the fitted settings on the
calibration rollouts only: RigidFall's relaxation, plane_relaxation and friction by the MSE at frames
15 to 50; MassRope's relaxation and contact distance by the MSE at frames 10 to 200. A table on
stderr, one JSON line per world and split on stdout.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe  # noqa: E402

from vgpl.data.flex_rollouts import read_flex_rollouts  # noqa: E402
from vgpl.eval.flex_fidelity import mass_rope_outcomes, position_mse_x1e4, replay, rigid_fall_outcomes  # noqa: E402
from vgpl.sim.particle_contacts import BodyContacts  # noqa: E402

CONF = Path(__file__).resolve().parents[1] / "conf"
FRAMES = (5, 10, 20, 50, 100)
# the settings --fit searches per env, and the frames whose mean log MSE it minimises (RigidFall: past
# frame 50 its chaos floor grows to the size of the error)
GRID = {
    "rigid_fall": {"relaxation": (1.0, 1.1, 1.25, 1.4), "plane_relaxation": (0.5, 0.75, 1.0), "friction": (0.1, 0.15, 0.2, 0.3)},
    "mass_rope": {"relaxation": (1.0, 1.1, 1.2, 1.3, 1.4), "contact_distance": (0.05, 0.055, 0.06)},
}
FIT_FRAMES = {"rigid_fall": [15, 20, 30, 50], "mass_rope": [10, 20, 50, 100, 200]}


def default_scene(env: str):
    with initialize_config_dir(str(CONF), version_base="1.3"):
        return instantiate(compose("config", overrides=[f"env={env}"]).env.scene)


def outcomes(scene, rollouts, positions: np.ndarray) -> dict:
    if scene.name == "mass_rope":
        return mass_rope_outcomes(positions, scene.n_mass, float(scene.spring_rest[: scene.n_rope + 1].sum()))
    return rigid_fall_outcomes(positions, scene.instance, np.array([float(r.params[0]) for r in rollouts]), scene.dt)


def measure(scene, rollouts, truth) -> dict:
    ours = replay(scene, rollouts)
    mse = position_mse_x1e4(ours, truth)
    chaos = position_mse_x1e4(replay(scene, rollouts, jitter=1e-3), ours)
    frames = [*FRAMES, truth.shape[1] - 1]
    return {"mse_x1e4": {f: round(float(mse[f]), 3) for f in frames}, "chaos_floor_x1e4": {f: round(float(chaos[f]), 3) for f in frames},
            "outcomes": outcomes(scene, rollouts, ours)}


def settings(scene) -> dict:
    """The world's settings that --fit can change, as a JSON-able dict."""
    if scene.name == "mass_rope":
        return {"type": type(scene).__name__, **{k: getattr(scene, k) for k in GRID["mass_rope"]}}
    return {"type": type(scene.contacts).__name__, **dataclasses.asdict(scene.contacts)}


def apply(scene, values: dict):
    """The scene with ``values`` of GRID set (RigidFall's on its contacts)."""
    if scene.name == "mass_rope":
        for key, value in values.items():
            setattr(scene, key, value)
    else:
        scene.contacts = dataclasses.replace(scene.contacts, **values)
    return scene


def fit(scene, rollouts, truth) -> dict:
    """The point of the env's GRID with the lowest mean log MSE at its FIT_FRAMES."""
    grid, frames, best = GRID[scene.name], FIT_FRAMES[scene.name], None
    for values in itertools.product(*grid.values()):
        mse = position_mse_x1e4(replay(apply(scene, dict(zip(grid, values))), rollouts), truth)
        score = float(np.mean(np.log(mse[frames])))
        print(f"  fit {dict(zip(grid, values))}: score {score:.3f}", file=sys.stderr)
        if best is None or score < best[0]:
            best = (score, dict(zip(grid, values)))
    return {"score": round(best[0], 4), **best[1]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--demo", required=True, help="the authors' rollouts of --env: a packed .h5 or a folder of <rollout>/<frame>.h5")
    parser.add_argument("--env", default="rigid_fall", choices=sorted(GRID), help="the env the rollouts are of")
    parser.add_argument("--calibration", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="rollout positions the settings were fitted on")
    parser.add_argument("--fit", action="store_true", help="search the fitted settings on the calibration rollouts")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rollouts = read_flex_rollouts(args.demo, args.env)
    held_out = [k for k in range(len(rollouts)) if k not in args.calibration]
    splits = {"calibration": args.calibration, "held_out": held_out}
    scene = default_scene(args.env)  # FleX's frame step is the scene's, 1/60 s
    flex = {name: outcomes(scene, [rollouts[k] for k in ids], np.stack([rollouts[k].positions for k in ids])) for name, ids in splits.items()}
    worlds = {"default": settings(scene)}
    if args.env == "rigid_fall":
        worlds = {"default (particle contacts)": settings(scene),
                  "no floor pass (contacts.floor_pass=false)": {**settings(scene), "floor_pass": False},
                  "hard contacts (BodyContacts)": {"type": "BodyContacts", **dataclasses.asdict(BodyContacts())}}
    default = {k: v for k, v in settings(scene).items() if k != "type"}
    if args.fit:
        cal = [rollouts[k] for k in args.calibration]
        found = fit(scene, cal, np.stack([r.positions for r in cal]))
        worlds["fitted here"] = {**settings(apply(scene, {k: v for k, v in found.items() if k != "score"})), "score": found["score"]}
        apply(scene, {k: default[k] for k in GRID[args.env]})
    for world, setting in worlds.items():
        if setting["type"] == "BodyContacts":
            scene.contacts = BodyContacts()
        else:
            apply(scene, {k: v for k, v in setting.items() if k not in ("type", "score")})
        for split, ids in splits.items():
            subset = [rollouts[k] for k in ids]
            row = {"benchmark": "flex_fidelity", "env": args.env, "world": world, "settings": setting,
                   "split": split, "rollouts": [rollouts[k].name for k in ids], **measure(scene, subset, np.stack([r.positions for r in subset])),
                   "flex_outcomes": flex[split], "machine": describe()}
            print(json.dumps(row), flush=True)
            mse, chaos = row["mse_x1e4"], row["chaos_floor_x1e4"]
            print(f"{world:30s} {split:11s} MSE " + " ".join(f"{mse[f]:8.2f}" for f in mse) + " | chaos " + " ".join(f"{chaos[f]:7.2f}" for f in chaos)
                  + f" | {row['outcomes']} | FleX {row['flex_outcomes']}", file=sys.stderr)
        if setting["type"] == "BodyContacts":
            scene = default_scene(args.env)


if __name__ == "__main__":
    main()
