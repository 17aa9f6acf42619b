"""InferenceModule: from particle proposals over T observed frames, infer a refinement dX of
every particle in every frame [B, T, N, 3] (metres), the rigidness Q of every instance [B, M] and
the physical parameters P [B, P].

It is trained through the frozen DynamicsPrior: the loss is the L1 between the trajectory the prior
predicts and the frames it rolls into, plus a direct L1 of the refined positions (the authors' code
adds it). It is composed of parts, each a config group or a dict of ``model.inference.net``:

- ``encoder``: the spatio-temporal encoders (``width``, ``propagation_steps``, ``max_neighbors``),
  one for dX and Q and, with ``separate_param_net`` (the paper's two networks), one for P;
  ``param_rotation`` shows P's encoder each training scene turned about the vertical axis
  (RigidFall's symmetry; not the paper);
- ``scheme``: what each rollout is fed (``vgpl.models.training_scheme``; group ``inference_scheme``);
- ``target``: what the rollouts are compared with (``vgpl.models.rollout_target``; group ``rollout_target``);
- ``rigidness_estimator``: what Q is to the prior (``vgpl.models.rigidness_estimator``; group ``rigidness_estimator``);
- ``training``: the loss's other runs and their lengths (``vgpl.models.loss_runs.LossRuns``);
- ``optimizer``: a partial of a torch optimiser, given the weights.

Nothing supervises Q or P directly unless the target's ``param_weight`` > 0: ``rigid_correct/<type>``
and ``param_mae_pct`` are logged against the truth, never trained on.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import lightning as L
import torch
from hydra.errors import InstantiationException
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torch import nn
from torch_geometric.nn import MLP

from vgpl.data.vertical_symmetry import random_about_vertical
from vgpl.metrics import correct_rigidness_prob, mean_per_type
from vgpl.models.loss_runs import LossRuns
from vgpl.models.rigidness_estimator import BlendRigidness
from vgpl.models.rollout import rollout_runs
from vgpl.models.rollout_target import ProposalsTarget, TruthTarget
from vgpl.models.spatiotemporal_encoder import SpatioTemporalEncoder
from vgpl.models.training_scheme import PaperScheme
from vgpl.nn.normalisation import NormalisationBuffers

ADAM = {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1.0e-4}


@dataclass(frozen=True)
class Encoder:
    """The encoders' options (``model.inference.net.encoder``)."""

    width: int = 150
    propagation_steps: int = 2
    max_neighbors: int | None = 24
    separate_param_net: bool = True
    param_rotation: bool = False


def add_proposal_jitter(proposals: torch.Tensor, max_std: float) -> torch.Tensor:
    """proposals [B, T, N, 3] plus independent Gaussian noise of a std drawn per window uniformly
    in [0, ``max_std``] (metres): every frame and particle its own draw, so it shows as motion."""
    std = torch.rand(proposals.shape[0], 1, 1, 1, device=proposals.device, dtype=proposals.dtype) * max_std
    return proposals + torch.randn_like(proposals) * std


def instantiated(config, **kwargs):
    """``hydra.utils.instantiate(config, **kwargs)``; a class that refuses its options raises its own
    ValueError, not Hydra's wrapper of it."""
    try:
        return instantiate(config, **kwargs)
    except InstantiationException as error:
        if isinstance(error.__cause__, ValueError):
            raise error.__cause__ from None
        raise


def built(part):
    """A part as given (an object), or built from its config (a mapping with ``_target_``)."""
    if isinstance(part, DictConfig):
        part = OmegaConf.to_container(part, resolve=True)
    return instantiated(part) if isinstance(part, Mapping) else part


def check_parts(scene: dict, encoder: Encoder, scheme, target, estimator, training: LossRuns, horizon: int) -> None:
    """ValueError naming the option, and what it needs, for parts that do not fit together."""
    net = "model.inference.net"
    if encoder.param_rotation and not encoder.separate_param_net:
        raise ValueError(f"{net}.encoder.param_rotation=true rotates what the parameter encoder sees, and needs "
                         f"{net}.encoder.separate_param_net=true (a shared encoder would rotate dX and Q's input too)")
    if isinstance(scheme, PaperScheme) and (not encoder.separate_param_net or estimator.name != "blend" or target.name != "truth"):
        raise ValueError(f"{net}: inference_scheme=paper trains the paper's two networks, each rolled with the true values of the other's "
                         "outputs; it needs encoder.separate_param_net=true, rigidness_estimator=blend and rollout_target=truth (got "
                         f"{encoder.separate_param_net}, {estimator.name}, {target.name})")
    if isinstance(target, ProposalsTarget) and target.rigid_fit_start and getattr(scheme, "start", None) not in ("truth", "both"):
        raise ValueError(f"{net}.target.rigid_fit_start=true fits the rigid instances of the proposals' start that P rolls from; it needs "
                         f"inference_scheme=joint with {net}.scheme.start truth or both (got {scheme.name}, start {scheme.start!r})")
    if estimator.name == "bernoulli" and (training.refined_steps is not None or training.truth_steps is not None):
        raise ValueError(f"{net}.training.refined_steps / truth_steps: rigidness_estimator=bernoulli flips labels on one rollout "
                         "length, the window and horizon; it needs both null")
    if not 0 <= training.tail_horizon <= horizon:
        raise ValueError(f"{net}.training.tail_horizon={training.tail_horizon}, expected 0 (off) to "
                         f"model.inference.horizon={horizon} (the future frames a window holds)")
    types = scene.get("instance_types")
    if types is not None and len(types) != scene["n_instances"]:
        raise ValueError(f"InferenceModule: instance_types={types} names {len(types)} instances, expected n_instances={scene['n_instances']}")


class InferenceModule(NormalisationBuffers, L.LightningModule):
    def __init__(self, scene: dict, encoder: dict | None = None, scheme=None, target=None, rigidness_estimator=None,
                 training: dict | None = None, optimizer=None, horizon: int = 5, rigidness: bool = True) -> None:
        """scene: the task's param_low, param_high [P] (physical), n_particles, n_instances, radius (m), instance_types;
        encoder, training: ``Encoder``'s and ``LossRuns``' options; scheme, target, rigidness_estimator: parts,
        or their configs (default: the paper's, the truth, the blend); optimizer: a partial taking the weights
        (default: Adam at 1e-4); horizon: frames past the window the training windows hold; rigidness: false
        for the module of the w/o-rigidness ablation (Q = 0)."""
        super().__init__()
        self.save_hyperparameters()
        self.encoder_options = Encoder(**(encoder or {}))
        self.training_runs = LossRuns(**(training or {}))
        self.scheme = PaperScheme() if scheme is None else built(scheme)
        self.target = TruthTarget() if target is None else built(target)
        self.estimator = BlendRigidness() if rigidness_estimator is None else built(rigidness_estimator)
        check_parts(scene, self.encoder_options, self.scheme, self.target, self.estimator, self.training_runs, horizon)
        self.register_normalisation(scene["param_low"], scene["param_high"])
        width, n_params = self.encoder_options.width, len(scene["param_low"])
        node_dim = 3 + 3 + scene["n_instances"] + 1
        make = lambda: SpatioTemporalEncoder(node_dim, width, self.encoder_options.propagation_steps, scene["radius"], self.encoder_options.max_neighbors)  # noqa: E731
        self.encoder = make()
        self.param_encoder = make() if self.encoder_options.separate_param_net else None
        self.refine_head = MLP([2 * width, width, 3], norm=None)
        self.rigid_head = MLP([2 * width, width, 1], norm=None)
        self.param_head = MLP([2 * width, width, n_params], norm=None)
        self.dynamics = None  # the frozen DynamicsPrior (attach_dynamics); not part of this checkpoint

    def attach_dynamics(self, dynamics) -> None:
        """Use ``dynamics`` (frozen, eval mode) in the training loss; it is not saved with this module."""
        dynamics.eval().requires_grad_(False)
        object.__setattr__(self, "dynamics", dynamics)  # plain attribute: not a registered submodule

    # ---- inference ------------------------------------------------------------------------------
    def forward(self, proposals: torch.Tensor, grouping: torch.Tensor, kinematic: torch.Tensor) -> dict:
        """proposals [B, T, N, 3] (metres), grouping [B, N, M] (probabilities), kinematic [N] ->
        refine [B, T, N, 3] (metres), rigidness [B, M] in (0, 1), params [B, P] in (-1, 1)."""
        nodes = self._nodes(proposals, grouping, kinematic)
        h = self.encoder(nodes, proposals, grouping, self.pos_std)  # [B, T, N, 2W]
        refine = self.refine_head(h) * self.disp_std
        hp = h if self.param_encoder is None else self._param_code(nodes, proposals, grouping, kinematic)
        params = torch.tanh(self.param_head(hp.mean((1, 2))))
        return {"refine": refine, "rigidness": self._rigidness(h, grouping), "params": params}

    def rigidness(self, proposals: torch.Tensor, logits: torch.Tensor, kinematic: torch.Tensor) -> torch.Tensor:
        """Only Q [B, M], as ``infer`` gives it: without the refinement head and the parameter
        encoder (the rigidness curve runs this for every T = 1 .. 20)."""
        grouping = torch.softmax(logits, -1).mean(1)
        h = self.encoder(self._nodes(proposals, grouping, kinematic), proposals, grouping, self.pos_std)
        return self._rigidness(h, grouping)

    def _nodes(self, proposals: torch.Tensor, grouping: torch.Tensor, kinematic: torch.Tensor) -> torch.Tensor:
        """Encoder input [B, T, N, 3 + 3 + M + 1]: normalised position, displacement from the
        previous frame (zero in the first), grouping, kinematic flag."""
        b, t, n, _ = proposals.shape
        disp = torch.cat([torch.zeros_like(proposals[:, :1]), proposals[:, 1:] - proposals[:, :-1]], 1)
        disp = torch.where(torch.arange(t, device=proposals.device)[None, :, None, None] > 0, (disp - self.disp_mean) / self.disp_std, disp)
        return torch.cat([
            (proposals - self.pos_mean) / self.pos_std, disp, grouping[:, None].expand(b, t, n, -1),
            kinematic[None, None, :, None].expand(b, t, n, 1).float(),
        ], -1)

    def _param_code(self, nodes, proposals, grouping, kinematic) -> torch.Tensor:
        """The parameter encoder's [B, T, N, 2W]; in training with ``param_rotation``, of each scene
        turned about the vertical axis at random (``random_about_vertical``): P cannot then read the
        training videos' layouts, only their motion (not the paper; the scene must be symmetric so)."""
        if self.training and self.encoder_options.param_rotation:
            proposals = random_about_vertical(proposals)
            nodes = self._nodes(proposals, grouping, kinematic)
        return self.param_encoder(nodes, proposals, grouping, self.pos_std)

    def _rigidness(self, h: torch.Tensor, grouping: torch.Tensor) -> torch.Tensor:
        """Encoder output [B, T, N, 2W] pooled per instance (grouping [B, N, M]) -> Q [B, M]."""
        weights = grouping / grouping.sum(1, keepdim=True).clamp_min(1e-8)  # [B, N, M]
        per_instance = torch.einsum("bnm,bnw->bmw", weights, h.mean(1))
        return torch.sigmoid(self.rigid_head(per_instance).squeeze(-1))

    def infer(self, proposals, logits, kinematic, refinement: bool = True, rigidness: bool | None = None,
              params: bool = True, generator: torch.Generator | None = None) -> dict:
        """Everything the dynamics prior needs, in its units, with the ablations applied.

        Args: proposals [B, T, N, 3]; logits [B, T, N, M] (the visual prior's grouping logits).
        Returns positions [B, T, N, 3] (refined, or X' when ``refinement`` is off), grouping
        [B, N, M], rigidness [B, M] what the prior takes (Q, or the label Q > 0.5 with the
        ``bernoulli`` estimator; zeros when off), rigidness_prob [B, M] Q itself (zeros when off),
        params [B, P] physical (uniform draws when off), params_normalised [B, P].
        """
        rigidness = self.hparams.rigidness if rigidness is None else rigidness
        grouping = torch.softmax(logits, -1).mean(1)
        out = self(proposals, grouping, kinematic)
        positions = proposals + out["refine"] if refinement else proposals
        prob = out["rigidness"] if rigidness else torch.zeros_like(out["rigidness"])
        p = out["params"]
        if not params:
            p = torch.rand(p.shape, generator=generator, device="cpu").to(p.device) * 2.0 - 1.0
        return {"positions": positions, "grouping": grouping, "rigidness": self.prior_rigidness(prob), "rigidness_prob": prob,
                "params": self.to_physical(p), "params_normalised": p}

    def prior_rigidness(self, prob: torch.Tensor) -> torch.Tensor:
        """Q [B, M] -> the rigidness the dynamics prior is given (``rigidness_estimator``)."""
        return self.estimator.prior_input(prob)

    # ---- training through the frozen dynamics prior ---------------------------------------------
    def _losses(self, batch, noise: bool = False) -> dict:
        """The loss terms of a batch; ``noise``: the training step's, with ``proposal_noise`` added to the proposals."""
        if self.dynamics is None:
            raise RuntimeError("InferenceModule: attach_dynamics(model) before training; the loss runs through the frozen DynamicsPrior")
        kinematic = batch["kinematic"][0]
        proposals = batch["proposals"]
        if noise and self.training_runs.proposal_noise > 0:
            proposals = add_proposal_jitter(proposals, self.training_runs.proposal_noise)
        frames = self.target.frames(batch, kinematic)  # [B, T + horizon, N, 3] what the rollouts are compared with
        out = self.infer(proposals, batch["logits"], kinematic)
        t, h = proposals.shape[1], self.dynamics.hparams.history
        refined = torch.where(kinematic[None, None, :, None], frames[:, :t], out["positions"])  # kinematic parts are known
        trajectories = self._trajectories(batch, frames, refined, out, kinematic)
        runs = self.training_runs.runs(refined, out["grouping"], out["rigidness"], self.scheme.dx_params(batch, out["params"]), trajectories, h,
                                       self.hparams.horizon)
        errors = self._run_errors(runs, frames, batch["planes"], kinematic)
        losses = {name: torch.cat(found).mean() for name, found in errors.items()}  # runs of one loss have one length
        if self.hparams.rigidness and trajectories:
            # Q's own loss (bernoulli): the label of each instance flipped on the trajectory that trains P;
            # the bernoulli estimator keeps every run at the window's length (check_parts)
            name = "rollout_from_truth" if "rollout_from_truth" in trajectories else next(iter(trajectories))
            losses |= self.estimator.loss(self.dynamics, trajectories[name], frames[:, h:], out["rigidness_prob"],
                                          errors[name][0].mean((1, 2, 3)), batch["planes"], kinematic)
        return losses | self._supervision(batch, out, losses, kinematic, t)

    def _trajectories(self, batch, frames, refined, out, kinematic) -> dict[str, tuple]:
        """The scheme's trajectory runs (name -> start, G, Q, P) when the window holds frames past the prior's history."""
        t, h = refined.shape[1], self.dynamics.hparams.history
        if t - h + self.hparams.horizon <= 0:
            return {}
        g, q = out["grouping"], out["rigidness"]
        true_start = self.target.true_start(frames[:, :h], g, q, kinematic)
        return self.scheme.trajectories(refined[:, :h], true_start, g, q, out["params"], batch, self.hparams.rigidness)

    def _run_errors(self, runs, frames, planes, kinematic) -> dict[str, list[torch.Tensor]]:
        """Each run's normalised L1 [B, L, movable, 3] against the frames it rolls into, by loss name. All
        runs roll as one batch through the prior (rollout_runs: one call a step for the runs still
        rolling; scenes never share edges)."""
        h = self.dynamics.hparams.history
        pieces = [(torch.cat([start, frames[:, first + h : first + h + length]], 1), g, q, p, planes[:, first : first + h + length], length)
                  for _, first, (start, g, q, p), length in runs]
        errors: dict[str, list[torch.Tensor]] = {}
        for (name, *_), piece, pred in zip(runs, pieces, rollout_runs(self.dynamics, pieces, kinematic) if pieces else []):
            errors.setdefault(name, []).append(((pred - piece[0][:, h:]) / self.dynamics.disp_std).abs()[:, :, ~kinematic])
        return errors

    def _supervision(self, batch, out, losses, kinematic, t) -> dict:
        """The refinement's L1 against the true frames (logged; trained on with the target's ``refine_weight``),
        P's error (logged as param_mae_pct; trained on with its ``param_weight``), the total ``loss``, and
        Q's reading per object type (rigid_correct/<type>, logged, as task=evaluate reports it)."""
        refine_weight, param_weight = self.target.refine_weight, self.target.param_weight
        refine = ((out["positions"] - batch["positions"][:, :t]) / self.dynamics.disp_std).abs()[:, :, ~kinematic].mean()
        p_error = (out["params_normalised"] - self.normalise_params(batch["params"])).abs()
        total = (losses.get("one_step", 0.0) + losses.get("rollout", 0.0) + losses.get("rollout_from_truth", 0.0)
                 + losses.get("tail", 0.0) + losses.get("rigidness", 0.0) + (refine_weight * refine if refine_weight else 0.0))
        if param_weight > 0:  # not the paper: a supervised shortcut for CPU-minute presets
            total = total + param_weight * p_error.mean()
        out_losses = {"refine": refine, "loss": total, "param_mae_pct": (p_error * 50.0).mean()}
        if self.hparams.rigidness and "rigid" in batch:
            types = self.hparams.scene.get("instance_types") or [f"instance{m}" for m in range(out["rigidness"].shape[1])]
            for name, prob in mean_per_type(correct_rigidness_prob(out["rigidness_prob"].detach(), batch["rigid"][0]), types).items():
                out_losses[f"rigid_correct/{name}"] = prob
        return out_losses

    def training_step(self, batch, batch_idx):
        losses = self._losses(batch, noise=True)
        self.log_dict({f"train/{k}": v for k, v in losses.items()}, batch_size=batch["proposals"].shape[0], prog_bar=False)
        self.log("train/loss_bar", losses["loss"], prog_bar=True, logger=False, batch_size=batch["proposals"].shape[0])
        return losses["loss"]

    def validation_step(self, batch, batch_idx):
        losses = self._losses(batch)
        self.log_dict({f"val/{k}": v for k, v in losses.items()}, batch_size=batch["proposals"].shape[0], prog_bar=False)

    def on_fit_start(self) -> None:
        if self.dynamics is not None:
            self.dynamics.to(self.device)

    def param_pathway(self) -> list[nn.Parameter]:
        """The weights only P's loss reaches: the parameter head, and the parameter encoder when separate."""
        modules = [self.param_head] + ([self.param_encoder] if self.param_encoder is not None else [])
        return [w for m in modules for w in m.parameters()]

    def configure_gradient_clipping(self, optimizer, gradient_clip_val=None, gradient_clip_algorithm=None) -> None:
        """The trainer's norm clipping applied to each network on its own when P has its own
        (``separate_param_net``): the parameter pathway's gradient norm and the rest's are each
        clipped to ``gradient_clip_val``. One global norm would scale P's small gradients by the
        refinement network's norm, a factor that changes from step to step and has nothing to do
        with P. Value clipping, or one shared encoder, clips as Lightning does."""
        if not gradient_clip_val or self.param_encoder is None or (gradient_clip_algorithm or "norm") != "norm":
            self.clip_gradients(optimizer, gradient_clip_val, gradient_clip_algorithm)
            return
        for weights in self.pathway_and_rest():
            torch.nn.utils.clip_grad_norm_([w for w in weights if w.grad is not None], gradient_clip_val)

    def pathway_and_rest(self) -> tuple[list[nn.Parameter], list[nn.Parameter]]:
        """(``param_pathway()``, every other weight): each weight in exactly one."""
        pathway = self.param_pathway()
        in_pathway = {id(w) for w in pathway}
        return pathway, [w for w in self.parameters() if id(w) not in in_pathway]

    def configure_optimizers(self):
        """The optimiser the ``optimizer`` partial makes of every weight."""
        return built(self.hparams.optimizer or ADAM)(self.parameters())
