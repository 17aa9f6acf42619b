"""DynamicsPrior: DPI-Net (Li et al. 2019) as used by VGPL, on radius graphs with message passing.

Input: the last ``history`` positions of every particle [B, H, N, 3] (metres), soft grouping
G [B, N, M], rigidness Q [B, M], physical parameters P [B, P] (physical units; all may be
estimates, gradients flow to them), boundary planes and which particles are kinematic. Output: the
normalised displacement of every particle to the next frame [B, N, 3]: a per-particle (non-rigid)
head and a per-instance rigid head (rotation about the instance centroid + translation), blended by
each particle's rigidness q_i = sum_m G_im Q_m. ``rigid_head``: ``pooled`` (the paper: an MLP on the
instance's mean embedding gives a quaternion and a translation), ``projected`` (per-particle
displacements, moved by their momentum as one rigid body) or ``none`` (no rigid-body constraint:
every particle free, Q ignored).

Options beyond the paper, each off in ``experiment=paper`` (docs/paper.md, Departures):
``action_lookahead`` feeds the actuators' (planes', kinematic particles') motion up to the predicted
frame; ``rollout_steps`` k > 1 rolls the training loss k steps on the model's own predictions (the
mean position error over them, in units of the displacement std; k = 1 is the one-step loss);
``noise_free_steps`` K > 0 trains the last K of trainer.max_steps (or the same share of a
trainer.max_time) without history noise, which otherwise biases the one-step prediction towards
too little motion; ``history_noise`` is ``random_walk`` (learning_to_simulate) or ``independent``
(the authors' code); ``rigid_dropout`` shows an instance as non-rigid in training with this chance.
"""

from __future__ import annotations

import logging

import lightning as L
import torch
from torch import nn
from torch_geometric.nn import MLP

from vgpl.graph import edge_features, max_degree, plane_ghosts, radius_graph
from vgpl.models.rollout import rollout
from vgpl.models.step_learning_rate import annealed_fraction, set_learning_rate, training_clock
from vgpl.nn.normalisation import NormalisationBuffers
from vgpl.nn.propagation import EdgeEncoder, Propagator
from vgpl.nn.rigid import momentum_projection, quaternion_to_matrix, rigid_displacement, soft_centroids

log = logging.getLogger(__name__)

PARTICLE, KINEMATIC, GHOST = 0, 1, 2


HISTORY_NOISE = ("random_walk", "independent")


def add_history_noise(history: torch.Tensor, std: torch.Tensor, movable: torch.Tensor, kind: str = "random_walk") -> torch.Tensor:
    """Noise on a position history [B, H, N, 3]; only ``movable`` [N] particles are perturbed.

    ``random_walk`` (learning_to_simulate): the noise of frame k is the sum of k Gaussian
    increments, scaled so that the last frame's std is ``std`` [3]; the first frame is left exact.
    ``independent`` (the authors' code): every frame gets its own Gaussian of std ``std``."""
    if kind == "independent":
        return history + torch.randn_like(history) * std * movable[None, None, :, None]
    steps = torch.randn_like(history[:, 1:]) * std / (history.shape[1] - 1) ** 0.5
    walk = torch.cat([torch.zeros_like(history[:, :1]), steps.cumsum(1)], 1)
    return history + walk * movable[None, None, :, None]


class DynamicsPrior(NormalisationBuffers, L.LightningModule):
    def __init__(
        self,
        param_low: list[float],
        param_high: list[float],
        n_instances: int,
        radius: float,
        history: int = 4,
        width: int = 150,
        propagation_steps: int = 2,
        lr: float = 1e-4,
        noise: float = 0.05,
        lr_decay: float = 1.0,
        rigid_dropout: float = 0.0,
        action_lookahead: bool = False,
        rollout_steps: int = 1,
        rigid_head: str = "pooled",
        noise_free_steps: int = 0,
        history_noise: str = "random_walk",
    ) -> None:
        super().__init__()
        if rigid_head not in ("pooled", "projected", "none"):
            raise ValueError(f"DynamicsPrior: rigid_head={rigid_head!r} (model.dynamics.net.rigid_head), expected 'pooled' (the paper), "
                             "'projected' or 'none' (no rigid-body constraint: every particle free, Q ignored)")
        if history_noise not in HISTORY_NOISE:
            raise ValueError(f"DynamicsPrior: history_noise={history_noise!r} (model.dynamics.net.history_noise), expected one of {HISTORY_NOISE}")
        if rollout_steps < 1:
            raise ValueError(f"DynamicsPrior: rollout_steps={rollout_steps}, expected at least 1 (steps rolled in the training loss)")
        if noise_free_steps < 0:
            raise ValueError(f"DynamicsPrior: noise_free_steps={noise_free_steps} (model.dynamics.net.noise_free_steps), expected >= 0 (0: noise to the end)")
        self.save_hyperparameters()
        n_params = len(param_low)
        self.register_normalisation(param_low, param_high)
        node_dim = 3 * (history - 1) + 3 + 3 + n_params + 3
        self.node_encoder = MLP([node_dim, width, width, width], norm=None, plain_last=False)
        self.edge_encoder = EdgeEncoder(node_dim, 5, width)
        self.edge_term = nn.Linear(width, width)
        self.propagator = Propagator(width)
        self.nonrigid_head = MLP([width, width, width, 3], norm=None)
        self.rigid_head = None if rigid_head == "none" else MLP([width, width, width, 7 if rigid_head == "pooled" else 3], norm=None)
        self.max_degree_seen = 0

    # ---- normalisation (physics outside the network; set_stats, normalise_params: the mixin) -----
    def to_displacement(self, normalised: torch.Tensor) -> torch.Tensor:
        return normalised * self.disp_std + self.disp_mean

    def to_normalised(self, displacement: torch.Tensor) -> torch.Tensor:
        return (displacement - self.disp_mean) / self.disp_std

    # ---- graph and features ---------------------------------------------------------------------
    def actuator_frames(self, history, planes, kinematic, kinematic_next):
        """The frames whose motion the actuators show: (kinematic particle positions [B, H, N, 3]
        shifted one frame ahead, or None where the history's serve; planes [B, H, K, 4]): the
        history's, or with ``action_lookahead`` shifted one frame ahead."""
        h = history.shape[1]
        if not self.hparams.action_lookahead:
            return None, planes[:, :h]
        if planes.shape[1] < h + 1:
            raise ValueError(f"DynamicsPrior(action_lookahead=True): planes need {h + 1} frames (history + the predicted one), got {planes.shape[1]}")
        if kinematic.any() and kinematic_next is None:
            raise ValueError("DynamicsPrior(action_lookahead=True): kinematic particles need kinematic_next [B, N, 3], their positions at the predicted frame")
        if kinematic_next is None:
            return None, planes[:, 1 : h + 1]
        return torch.cat([history[:, 1:], kinematic_next[:, None]], 1), planes[:, 1 : h + 1]

    def build_inputs(self, history, grouping, rigidness, params, planes, kinematic, kinematic_next=None):
        """Node features, edge index and edge features for particles plus boundary ghosts."""
        b, h, n, _ = history.shape
        x = history[:, -1]
        driven, motion = self.actuator_frames(history, planes, kinematic, kinematic_next)
        disp = self.to_normalised(history[:, 1:] - history[:, :-1])
        if driven is not None:
            disp = torch.where(kinematic[None, None, :, None], self.to_normalised(driven[:, 1:] - driven[:, :-1]), disp)
        disp = disp.permute(0, 2, 1, 3).reshape(b, n, -1)
        q = (grouping * rigidness[:, None, :]).sum(-1)  # [B, N]
        centre = torch.einsum("bnm,bmc->bnc", grouping, soft_centroids(x, grouping))
        offset = q[..., None] * (x - centre) / self.pos_std
        ptype = torch.zeros(b, n, 3, device=x.device)
        ptype[..., PARTICLE] = (~kinematic).float()
        ptype[..., KINEMATIC] = kinematic.float()
        pnorm = self.normalise_params(params)[:, None, :].expand(b, n, -1)
        nodes = torch.cat([disp, (x - self.pos_mean) / self.pos_std, ptype, pnorm, offset], -1).reshape(b * n, -1)
        batch = torch.arange(b, device=x.device).repeat_interleave(n)
        flat = x.reshape(b * n, 3)
        edge_index = radius_graph(flat, self.hparams.radius, batch, graph_size=n)
        group_flat = grouping.reshape(b * n, -1)
        if planes.shape[2] > 0:
            ghost, owner, plane = plane_ghosts(flat, planes[:, h - 1], batch, self.hparams.radius)
            gb = batch[owner]
            normal = motion[gb, :, plane, :3]  # [G, H, 3]
            offsets = motion[gb, :, plane, 3]  # [G, H]
            gdisp = (offsets[:, 1:] - offsets[:, :-1])[..., None] * normal[:, 1:]  # plane motion along its normal
            gtype = torch.zeros(len(ghost), 3, device=x.device)
            gtype[:, GHOST] = 1.0
            gnodes = torch.cat(
                [self.to_normalised(gdisp).reshape(len(ghost), 3 * (h - 1)), (ghost - self.pos_mean) / self.pos_std, gtype,
                 self.normalise_params(params)[gb], torch.zeros_like(ghost)], -1)
            nodes = torch.cat([nodes, gnodes])
            ids = b * n + torch.arange(len(ghost), device=x.device)
            edge_index = torch.cat([edge_index, torch.stack([ids, owner])], 1)
            flat = torch.cat([flat, ghost])
            group_flat = torch.cat([group_flat, group_flat.new_zeros(len(ghost), group_flat.shape[1])])
        if self.training:  # logged by training; frozen rollouts skip the read-back
            self.max_degree_seen = max(self.max_degree_seen, max_degree(edge_index, nodes.shape[0]))
        return nodes, edge_index, edge_features(flat, edge_index, group_flat) / torch.cat([self.pos_std, self.pos_std.norm()[None], torch.ones(1, device=x.device)])

    def forward(self, history, grouping, rigidness, params, planes, kinematic, kinematic_next=None) -> torch.Tensor:
        """Normalised displacement to the next frame [B, N, 3].

        Args: history [B, H, N, 3]; grouping [B, N, M]; rigidness [B, M]; params [B, P] physical
        units; planes [B, H(+1), K, 4] (frame H, the predicted one, is needed with
        ``action_lookahead``); kinematic [N] bool; kinematic_next [B, N, 3] positions at the
        predicted frame (only the kinematic particles' are read; needed with ``action_lookahead``).
        """
        b, _, n, _ = history.shape
        if self.rigid_head is None:  # no rigid-body constraint: Q reaches neither the input nor the output
            rigidness = torch.zeros_like(rigidness)
        nodes, edge_index, edge_attr = self.build_inputs(history, grouping, rigidness, params, planes, kinematic, kinematic_next)
        code = self.node_encoder(nodes)
        term = self.edge_encoder(nodes, edge_attr, edge_index, self.edge_term)
        effect = torch.zeros_like(code)
        for _ in range(self.hparams.propagation_steps):
            effect = self.propagator(effect, code, term, edge_index)
        particle = effect[: b * n].reshape(b, n, -1)
        nonrigid = self.nonrigid_head(particle)
        if self.rigid_head is None:
            return nonrigid
        rotation, translation = self.rigid_motion(history[:, -1], grouping, particle)
        rigid = self.to_normalised(rigid_displacement(history[:, -1], grouping, rotation, translation))
        q = (grouping * rigidness[:, None, :]).sum(-1, keepdim=True)
        return (1.0 - q) * nonrigid + q * rigid

    def rigid_motion(self, pos, grouping, particle) -> tuple[torch.Tensor, torch.Tensor]:
        """Each instance's rigid step (rotation [B, M, 3, 3] about its centroid, translation [B, M, 3])
        from the particles' embeddings [B, N, W]; pos [B, N, 3], grouping [B, N, M].

        ``pooled`` (the paper): an MLP on the instance's mean embedding gives a quaternion and a
        translation. ``projected``: an MLP gives every particle a displacement, and the instance moves
        with their linear and angular momentum (nn.rigid.momentum_projection; docs/design.md).
        """
        if self.hparams.rigid_head == "projected":
            return momentum_projection(pos, grouping, self.to_displacement(self.rigid_head(particle)))
        pooled = torch.einsum("bnm,bnw->bmw", grouping, particle) / grouping.sum(1).clamp_min(1e-8)[..., None]
        out = self.rigid_head(pooled)  # [B, M, 7]
        identity = torch.tensor([1.0, 0.0, 0.0, 0.0], device=out.device)
        return quaternion_to_matrix(identity + out[..., :4]), self.to_displacement(out[..., 4:])

    def step(self, history, grouping, rigidness, params, planes, kinematic, kinematic_next=None) -> torch.Tensor:
        """Next positions [B, N, 3]; kinematic particles take ``kinematic_next`` [B, N, 3] when given.
        planes [B, H(+1), K, 4] as in forward()."""
        nxt = history[:, -1] + self.to_displacement(self(history, grouping, rigidness, params, planes, kinematic, kinematic_next))
        if kinematic_next is not None:
            nxt = torch.where(kinematic[None, :, None], kinematic_next, nxt)
        return nxt

    # ---- training -------------------------------------------------------------------------------
    def _loss(self, batch, noise: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean L1 over the ``rollout_steps`` rolled steps, L1 of the first step), normalised.
        batch["positions"] [B, H + k, N, 3]: frames after the history are the targets and drive
        the kinematic particles."""
        h, k = self.hparams.history, self.hparams.rollout_steps
        kinematic = batch["kinematic"][0]
        positions = batch["positions"]
        if positions.shape[1] < h + k:
            raise ValueError(f"DynamicsPrior(rollout_steps={k}): windows of {positions.shape[1]} frames, expected history {h} + {k}")
        history = positions[:, :h]
        rigidness = batch["rigidness"]
        if noise and self.hparams.noise > 0 and not self.in_noise_free_finish():
            history = add_history_noise(history, self.hparams.noise * self.disp_std, ~kinematic, self.hparams.history_noise)
        if noise and self.hparams.rigid_dropout > 0:
            # a rigid body is also a (stiff) non-rigid one: teaching the per-particle head rigid motion
            # makes q = 0 a usable input (the no-rigidness ablation) and q's estimate a real choice
            rigidness = rigidness * (torch.rand_like(rigidness) >= self.hparams.rigid_dropout)
        if k == 1:
            target = self.to_normalised(positions[:, h] - history[:, -1])
            pred = self(history, batch["grouping"], rigidness, batch["params"], batch["planes"][:, : h + 1], kinematic, positions[:, h])
            loss = (pred - target).abs()[:, ~kinematic].mean()
            return loss, loss
        start = torch.cat([history, positions[:, h : h + k]], 1)  # the future frames only drive the kinematic parts
        pred = rollout(self, start, batch["grouping"], rigidness, batch["params"], batch["planes"][:, : h + k], kinematic, k)
        error = ((pred - positions[:, h : h + k]) / self.disp_std).abs()[:, :, ~kinematic]  # [B, k, movable, 3]
        return error.mean(), error[:, 0].mean()

    def in_noise_free_finish(self, steps_done: int | None = None) -> bool:
        """Whether the training step after ``steps_done`` (default: global_step, the step about to be
        taken) is in the last ``noise_free_steps``, by step or by the clock."""
        k = self.hparams.noise_free_steps
        if k <= 0:
            return False
        steps_done = self.global_step if steps_done is None else steps_done
        # that step is number steps_done + 1 of max_steps: steps max_steps - K .. max_steps - 1 are the last K
        return annealed_fraction(steps_done + 1, self.trainer.max_steps, k, *training_clock(self.trainer), stage="dynamics",
                                 option="noise_free_steps") < 1.0

    def on_train_end(self) -> None:
        """Warn when a fit with ``noise_free_steps`` stopped (on max_epochs) before its noise-free
        finish began: its last.ckpt then carries the history noise's bias."""
        steps = self.global_step
        if self.hparams.noise_free_steps > 0 and steps > 0 and not self.in_noise_free_finish(steps - 1):
            log.warning("dynamics: stopped at step %d of trainer.max_steps=%d before its noise-free finish began "
                        "(model.dynamics.net.noise_free_steps=%d): the last step still trained with history noise; raise "
                        "trainer.max_epochs, or resume with ckpt_path=last trainer.max_epochs=<more>", steps, self.trainer.max_steps,
                        self.hparams.noise_free_steps)

    def training_step(self, batch, batch_idx):
        loss, first = self._loss(batch, noise=True)
        b = batch["positions"].shape[0]
        self.log("train/loss", loss, prog_bar=True, batch_size=b)
        if self.hparams.rollout_steps > 1:
            self.log("train/one_step", first, batch_size=b)
        self.log("train/max_degree", float(self.max_degree_seen), batch_size=b)
        return loss

    def validation_step(self, batch, batch_idx):
        loss, first = self._loss(batch, noise=False)
        b = batch["positions"].shape[0]
        self.log("val/loss", first, prog_bar=True, batch_size=b)  # the one-step loss: comparable across rollout_steps
        if self.hparams.rollout_steps > 1:
            self.log("val/rollout_loss", loss, batch_size=b)
        return first

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.hparams.lr)

    def on_train_batch_start(self, batch, batch_idx) -> None:
        """The learning rate is lr x lr_decay ** (epochs completed, counted in optimiser steps): a
        function of global_step alone, so a fit stopped by trainer.max_time and resumed decays at the
        same steps as an uninterrupted one (a per-epoch scheduler does not step when max_time cuts an
        epoch, and where it stepped after a resume depended on how the resumed fit counted batches)."""
        if self.hparams.lr_decay == 1.0:
            return
        set_learning_rate(self, self.hparams.lr * self.hparams.lr_decay ** (self.global_step // self.trainer.num_training_batches))
