"""VisualPrior: a stack of RGB frames -> particle positions and grouping logits of each frame.

The perception stage of VGPL (docs/paper.md). Particle slots are in simulator order, so the
heads regress every particle directly (no matching). Positions are predicted in normalised
units (training-split mean and std, stored with the checkpoint) and returned in metres by
``propose``. Two architectures (``architecture``):
- ``paper``: the paper's global regression, the encoder pooled to one vector and fully connected
  heads emitting every slot's position and grouping;
- ``spatial``: every slot attends over the encoder's last two maps (vgpl.nn.slot_heatmaps), and its
  pixel position and depth are back-projected through the dataset's camera (``set_camera``), so a
  slot is placed where the image shows it instead of being regressed from a pooled vector.
"""

from __future__ import annotations

import lightning as L
import torch
from torch import nn
from torch.nn import functional as F

from vgpl.models.step_learning_rate import AnnealedLearningRate
from vgpl.nn.rigid import quaternion_to_matrix
from vgpl.nn.slot_heatmaps import SlotHeatmaps
from vgpl.sim.camera import Camera, unproject
from vgpl.sim.shape_matching import shape_match


def conv_block(c_in: int, c_out: int) -> nn.Sequential:
    """3x3 conv + BN + ReLU, then a stride-2 3x3 conv + BN + ReLU (halves H and W)."""
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, stride=2, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
    )


class VisualPrior(AnnealedLearningRate, L.LightningModule):
    anneal_stage = "visual"

    def __init__(
        self,
        n_particles: int,
        n_instances: int,
        frames: int = 4,
        channels: list[int] = (32, 64, 128, 256),
        pooled: list[int] = (4, 5),
        hidden: int = 2048,
        lr: float = 1e-4,
        group_weight: float = 1.0,
        downsample: int = 1,
        lr_anneal_steps: int = 0,
        architecture: str = "paper",
        head_width: int = 64,
        head_level: int = -2,
        rigid_fit: bool = False,
        rigid_pose: bool = False,
    ) -> None:
        """channels: the conv blocks' widths; pooled, hidden: the paper architecture's pooled grid and
        head width; head_width: the spatial architecture's feature-pyramid width; head_level: the
        block whose map the slots attend over (-2: the second to last, merged with the last; -3 halves
        the cells' size at four times the heatmaps' cost); rigid_fit: ``propose`` replaces each rigid
        instance's slots by the best rigid motion of its rest layout (``set_structure``); rigid_pose
        (spatial): each rigid instance is a slot of its own per frame, whose attended centroid and
        rotation (an identity-offset quaternion read from its features) place its rest layout;
        average-pool the frames by this factor first."""
        super().__init__()
        if architecture not in ("paper", "spatial"):
            raise ValueError(f"model.visual.net.architecture={architecture!r}: expected paper or spatial")
        if architecture == "spatial" and not -len(channels) <= head_level <= -2:
            raise ValueError(f"model.visual.net.head_level={head_level}: expected -2 to -{len(channels)} with {len(channels)} conv blocks "
                             "(the slots attend over that block's map merged with the next one's)")
        self.save_hyperparameters()
        self.register_buffer("pos_mean", torch.zeros(3))
        self.register_buffer("pos_std", torch.ones(3))
        if rigid_pose and architecture != "spatial":
            raise ValueError("model.visual.net.rigid_pose=true needs model.visual.net.architecture=spatial")
        if rigid_fit or rigid_pose:
            self.register_buffer("rest_offsets", torch.zeros(n_particles, 3))
            self.register_buffer("instance", torch.zeros(n_particles, dtype=torch.long))
            self.register_buffer("rigid_particle", torch.zeros(n_particles, dtype=torch.bool))
        blocks, c_in = [nn.AvgPool2d(downsample)] if downsample > 1 else [], 3 * frames
        for c in channels:
            blocks.append(conv_block(c_in, c))
            c_in = c
        if architecture == "spatial":
            self._build_spatial(blocks)
            return
        # channels-last: the layout oneDNN's and cuDNN's fast convolutions use (this CPU: 1.42x a step in fp32, 1.23x
        # in bf16; benchmarks/results_visual.jsonl). Module.to keeps it; a checkpoint saved either way loads into it.
        self.encoder = nn.Sequential(*blocks, nn.AdaptiveAvgPool2d(tuple(pooled)), nn.Flatten()).to(memory_format=torch.channels_last)
        features = c_in * pooled[0] * pooled[1]
        self.position_head = nn.Sequential(nn.Linear(features, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, frames * n_particles * 3))
        self.group_head = nn.Sequential(nn.Linear(features, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, frames * n_particles * n_instances))

    def _build_spatial(self, blocks: list[nn.Module]) -> None:
        """The spatial architecture's trunk, its per-slot heatmaps over ``head_level``'s map, the camera's
        buffers (``set_camera``) and, with ``rigid_pose``, one pose slot per rigid instance and frame."""
        hp = self.hparams
        self.register_buffer("intrinsics", torch.eye(3))
        self.register_buffer("world_to_camera", torch.eye(4))
        self.register_buffer("image_size", torch.tensor([120, 160]))
        self.trunk = nn.ModuleList(blocks).to(memory_format=torch.channels_last)
        level, above = hp.channels[hp.head_level], hp.channels[hp.head_level + 1]
        self.slots = SlotHeatmaps(level, above, hp.head_width, hp.frames * hp.n_particles, hp.n_instances)
        if hp.rigid_pose:
            self.poses = SlotHeatmaps(level, above, hp.head_width, hp.frames * hp.n_instances, 4)
            with torch.no_grad():  # start at the identity rotation
                self.poses.readout.weight.mul_(0.01)
                self.poses.readout.bias.copy_(torch.tensor([1.0, 0.0, 0.0, 0.0]))

    def set_stats(self, stats) -> None:
        self.pos_mean.copy_(stats.pos_mean)
        self.pos_std.copy_(stats.pos_std)

    def set_camera(self, camera: Camera) -> None:
        """The dataset's camera, through which the spatial architecture back-projects its slots
        (saved with the checkpoint; the paper architecture does not use it)."""
        if self.hparams.architecture == "spatial":
            self.intrinsics.copy_(torch.as_tensor(camera.intrinsics, dtype=torch.float32))
            self.world_to_camera.copy_(torch.as_tensor(camera.world_to_camera, dtype=torch.float32))
            self.image_size.copy_(torch.tensor([camera.height, camera.width]))

    @staticmethod
    def to_input(frames: torch.Tensor) -> torch.Tensor:
        """uint8 frames [B, F, H, W, 3] -> float [B, 3F, H, W] in [-1, 1], channel f * 3 + c, stored channels-last."""
        b, f, h, w, _ = frames.shape
        return (frames.permute(0, 2, 3, 1, 4).reshape(b, h, w, f * 3).permute(0, 3, 1, 2).float() / 127.5) - 1.0

    def forward(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """uint8 frames [B, F, H, W, 3] -> (normalised positions [B, F, N, 3], grouping logits [B, F, N, M])."""
        b = frames.shape[0]
        f, n, m = self.hparams.frames, self.hparams.n_particles, self.hparams.n_instances
        if self.hparams.architecture == "spatial":
            return self._spatial(frames)
        z = self.encoder(self.to_input(frames))
        return self.position_head(z).view(b, f, n, 3), self.group_head(z).view(b, f, n, m)

    def _spatial(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Each slot's attended pixel and depth, back-projected through the camera. The depth maps
        are in units of the positions' spread about the mean's depth, so an untrained head sits at
        the training split's mean depth."""
        b = frames.shape[0]
        f, n, m = self.hparams.frames, self.hparams.n_particles, self.hparams.n_instances
        maps, x = [], self.to_input(frames)
        for block in self.trunk:
            x = block(x)
            maps.append(x)
        size = (int(self.image_size[0]), int(self.image_size[1]))
        level = self.hparams.head_level
        uv, depth, logits = self.slots(maps[level], maps[level + 1], size)
        mean_depth = (self.world_to_camera[2, :3] * self.pos_mean).sum() + self.world_to_camera[2, 3]
        scale = self.pos_std.norm()
        world = unproject(uv, mean_depth + scale * depth, self.intrinsics, self.world_to_camera).view(b, f, n, 3)
        if self.hparams.rigid_pose:
            centre_uv, centre_depth, quaternion = self.poses(maps[level], maps[level + 1], size)
            centre = unproject(centre_uv, mean_depth + scale * centre_depth, self.intrinsics, self.world_to_camera).view(b, f, m, 3)
            rotation = quaternion_to_matrix(quaternion).view(b, f, m, 3, 3)
            placed = centre[:, :, self.instance] + torch.einsum("bfnij,nj->bfni", rotation[:, :, self.instance], self.rest_offsets)
            world = torch.where(self.rigid_particle[:, None], placed, world)
        return ((world - self.pos_mean) / self.pos_std), logits.view(b, f, n, m)

    def set_structure(self, scene) -> None:
        """The scene's particle layout: each particle's instance, its instance's rigidness and its rest
        offset from the instance's centroid (saved with the checkpoint; used by ``rigid_fit``)."""
        if self.hparams.rigid_fit or self.hparams.rigid_pose:
            self.rest_offsets.copy_(torch.as_tensor(scene.rest_offsets, dtype=torch.float32))
            self.instance.copy_(torch.as_tensor(scene.instance))
            self.rigid_particle.copy_(torch.as_tensor(scene.rigid[scene.instance]))

    def propose(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Positions in metres [B, F, N, 3] and grouping logits [B, F, N, M]; with ``rigid_fit`` each
        rigid instance's positions are the best rigid motion of its rest layout onto its slots."""
        pos, logits = self(frames)
        pos = pos * self.pos_std + self.pos_mean
        if self.hparams.rigid_fit:
            b, f, n, _ = pos.shape
            fitted = shape_match(pos.reshape(b * f, n, 3).float(), self.rest_offsets, self.instance, self.rigid_particle.nonzero().squeeze(1),
                                 self.hparams.n_instances)[0]
            pos = fitted.view(b, f, n, 3)
        return pos, logits

    def _losses(self, batch) -> tuple[torch.Tensor, torch.Tensor]:
        pos, logits = self(batch["frames"])
        target = (batch["positions"] - self.pos_mean) / self.pos_std
        position = ((pos - target) ** 2).sum(-1).mean()
        labels = batch["instance"][:, None, :].expand(-1, logits.shape[1], -1)
        grouping = F.cross_entropy(logits.reshape(-1, logits.shape[-1]), labels.reshape(-1))
        return position, grouping

    def training_step(self, batch, batch_idx):
        position, grouping = self._losses(batch)
        loss = position + self.hparams.group_weight * grouping
        b = batch["frames"].shape[0]
        self.log_dict({"train/loss": loss, "train/position": position, "train/grouping": grouping}, batch_size=b, prog_bar=True)
        return loss

    def validation_step(self, batch, batch_idx):
        position, grouping = self._losses(batch)
        b = batch["frames"].shape[0]
        self.log_dict({"val/loss": position + self.hparams.group_weight * grouping, "val/position": position, "val/grouping": grouping}, batch_size=b)

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.hparams.lr)
