"""Grounder: physics from frames alone. RGB frames of one video (and, where the scene has an
actuator, its actions) -> particles per frame, grouping, rigidness per instance, physical
parameters in physical units, and a predicted future; no ground truth is read.

    grounder = Grounder.from_checkpoints("checkpoints/quick/rigid_fall")
    g = grounder.ground(frames)                      # frames: uint8 [T, H, W, 3]
    g.params, g.rigidness, g.future                  # {"gravity": -9.7}, [M], [F, N, 3]

The three trained stages are those of ``<ckpt_dir>/{visual,inference,dynamics}/last.ckpt``; the
scene (camera, particle layout, parameter ranges) is rebuilt from the dynamics prior's saved
config. The frames are those of the dataset's camera and size, from the video's first frame: the
module observes frames [start_frame, start_frame + observed) as task=evaluate does, with the
visual prior's sliding window over the frames before them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from vgpl.checkpoint import load_stage, saved_config, scene_of
from vgpl.data.window_pool import pool_windows
from vgpl.eval.protocol import observed_proposals
from vgpl.eval.test_time_fit import TestTimeFit, refit_inferred
from vgpl.models.dynamics_prior import DynamicsPrior
from vgpl.models.inference import InferenceModule
from vgpl.models.rollout import rollout
from vgpl.models.visual_prior import VisualPrior


class GroundingInputError(ValueError):
    """Frames or actions that do not fit what the checkpoints were trained on."""


@dataclass
class Grounding:
    """One video grounded. T observed frames, N particles, M instances, F predicted frames; metres,
    in the world frame of the dataset's camera."""

    env: str
    start_frame: int  # the video's frame the observation starts at
    proposals: torch.Tensor  # [T, N, 3] the visual prior's particles
    positions: torch.Tensor  # [T, N, 3] refined by the inference module
    grouping: torch.Tensor  # [N, M] probability of each particle belonging to each instance
    rigidness: torch.Tensor  # [M] probability that each instance is rigid (Q)
    params: dict[str, float]  # physical parameters, physical units
    future: torch.Tensor  # [F, N, 3] the dynamics prior's rollout after the observed frames
    instance_types: list[str]  # what each of the M instances is (scene's names)

    def to_json(self) -> dict:
        """The estimates as JSON-able lists (positions rounded to 0.1 mm)."""
        rounded = lambda x: np.round(x.numpy().astype(np.float64), 4).tolist()  # noqa: E731
        return {"env": self.env, "start_frame": self.start_frame, "observed": int(self.positions.shape[0]),
                "n_future": int(self.future.shape[0]), "params": self.params,
                "rigidness": {f"{k}:{name}": float(q) for k, (name, q) in enumerate(zip(self.instance_types, self.rigidness))},
                "instance": self.grouping.argmax(-1).tolist(), "positions": rounded(self.positions), "future": rounded(self.future)}


class Grounder:
    """The visual prior, inference module and dynamics prior of one trained pipeline, as one call
    on frames. ``observed``: frames the module sees (the evaluation's, ``eval.observed``);
    ``window_pool``: how each frame is read from the visual prior's windows (the module's own)."""

    def __init__(self, visual: VisualPrior, inference: InferenceModule, dynamics: DynamicsPrior, scene, observed: int = 10,
                 start_frame: int = 0, window_pool: str = "last") -> None:
        h = dynamics.hparams.history
        if observed < h:
            raise GroundingInputError(f"observed={observed}: the dynamics prior needs at least its history of {h} frames")
        self.visual, self.inference, self.dynamics = visual.eval(), inference.eval(), dynamics.eval()
        self.scene, self.observed, self.start_frame, self.window_pool = scene, observed, start_frame, window_pool

    @classmethod
    def from_checkpoints(cls, ckpt_dir: str | Path, observed: int | None = None, dynamics: str | Path | None = None) -> Grounder:
        """The stages under ``ckpt_dir`` (``<paths.ckpt_dir>`` of a trained pipeline): ``visual/``,
        ``inference/`` and the prior the module was trained through (``dynamics/``, or the path
        ``dynamics``). ``observed`` None: the evaluation's length the pipeline was configured with."""
        ckpt_dir = Path(ckpt_dir)
        paths = {"dynamics": Path(dynamics) if dynamics else ckpt_dir / "dynamics" / "last.ckpt", "visual": ckpt_dir / "visual" / "last.ckpt",
                 "inference": ckpt_dir / "inference" / "last.ckpt"}
        envs = {path: OmegaConf.select(saved_config(path, cls, None), "env.name")
                for path, cls in zip(paths.values(), (DynamicsPrior, VisualPrior, InferenceModule))}
        if len(set(envs.values())) > 1:
            trained = ", ".join(f"{path} on '{env}'" for path, env in envs.items())
            raise GroundingInputError(f"{ckpt_dir}: its stages were trained on different envs ({trained}); a Grounder takes the "
                                      "three stages of one pipeline")
        prior, cfg = load_stage(paths["dynamics"], DynamicsPrior)
        scene = scene_of(cfg)
        visual, _ = load_stage(paths["visual"], VisualPrior, env=scene.name, n_particles=scene.n_particles)
        inference, inference_cfg = load_stage(paths["inference"], InferenceModule, env=scene.name, n_particles=scene.n_particles)
        seen = observed if observed is not None else int(inference_cfg.eval.get("observed") or inference_cfg.model.inference.observed)
        pool = inference_cfg.model.inference.get("window_pool", "last")
        return cls(visual, inference, prior, scene, seen, int(cfg.env.get("start_frame", 0)), pool)

    @property
    def frames_needed(self) -> int:
        """Frames a video must have: those skipped at the start and the observed ones."""
        return self.start_frame + self.observed

    def check(self, frames: torch.Tensor, actions: torch.Tensor | None, n_future: int) -> None:
        """One GroundingInputError saying what was expected when frames [T, H, W, 3] uint8 or
        actions [T + n_future, A] do not fit the scene the checkpoints were trained on."""
        cam = self.scene.camera
        expected = f"uint8 [T >= {self.frames_needed}, {cam.height}, {cam.width}, 3] (the dataset's camera)"
        if frames.dtype != torch.uint8 or frames.dim() != 4 or tuple(frames.shape[1:]) != (cam.height, cam.width, 3):
            raise GroundingInputError(f"frames: {str(frames.dtype).replace('torch.', '')} {list(frames.shape)}, expected {expected}")
        if frames.shape[0] < self.frames_needed:
            raise GroundingInputError(f"frames: {frames.shape[0]} frames, expected at least {self.frames_needed} "
                                      f"({self.start_frame} skipped + {self.observed} observed)")
        a = self.scene.action_dim
        if a == 0:
            if actions is not None:
                raise GroundingInputError(f"actions: given, but {self.scene.name} has no actuator; pass none")
            return
        needed = self.frames_needed + n_future
        if actions is None:
            raise GroundingInputError(f"actions: missing; {self.scene.name} is driven by an actuator: expected [{needed}, {a}] "
                                      "(its position and velocity per frame, for the observed and the predicted frames)")
        if actions.dim() != 2 or actions.shape[1] != a or actions.shape[0] < needed:
            raise GroundingInputError(f"actions: {list(actions.shape)}, expected [>= {needed}, {a}] "
                                      f"({self.frames_needed} observed and skipped + {n_future} predicted frames)")

    @torch.no_grad()
    def ground(self, frames, actions=None, n_future: int = 20, test_time_fit: TestTimeFit | None = None) -> Grounding:
        """Ground one video: frames uint8 [T, H, W, 3] (numpy or torch), actions [T', A] where the
        scene has an actuator (None otherwise); ``n_future`` frames predicted after the observed ones.
        ``test_time_fit`` (steps > 0) refines P and Q against the video's own refined frames
        (vgpl.eval.test_time_fit) before the future is rolled."""
        frames = torch.as_tensor(np.asarray(frames))
        actions = None if actions is None else torch.as_tensor(np.asarray(actions), dtype=torch.float32)
        if not isinstance(n_future, int) or n_future < 1:
            raise GroundingInputError(f"n_future={n_future!r}: expected a number of predicted frames >= 1")
        self.check(frames, actions, n_future)
        s, t, h = self.start_frame, self.observed, self.dynamics.hparams.history
        proposals, logits, slots = observed_proposals(self.visual, frames[None, : self.frames_needed], s, t)
        seen = pool_windows(proposals, slots, self.window_pool, np.s_[:, :t])
        kinematic = torch.as_tensor(self.scene.kinematic)
        out = self.inference.infer(seen, logits[:, :t], kinematic)
        n_actions = s + t + n_future
        acts = (actions[None, :n_actions] if actions is not None else torch.zeros(1, n_actions, 0))
        refined = self.scene.kinematic_positions(out["positions"], acts[:, s : s + t])  # the actuator's particles where it drives them
        if test_time_fit is not None and test_time_fit.steps > 0:
            refit_inferred(out, self.inference, self.dynamics, refined, self.scene.planes_at(acts[:, s : s + t]), kinematic, test_time_fit)
        driven = self.scene.kinematic_positions(torch.zeros(1, n_future, *refined.shape[2:]), acts[:, s + t :])
        future = rollout(self.dynamics, torch.cat([refined[:, -h:], driven], 1), out["grouping"], out["rigidness"], out["params"],
                         self.scene.planes_at(acts[:, s + t - h :]), kinematic, n_future)
        names = list(self.scene.param_names)
        return Grounding(self.scene.name, s, seen[0], refined[0], out["grouping"][0], out["rigidness_prob"][0],
                         {name: float(v) for name, v in zip(names, out["params"][0])}, future[0], list(self.scene.instance_types))
