"""VisualPrior: a stack of RGB frames -> particle positions and grouping logits of each frame.

The perception stage of VGPL (docs/paper.md). Particle slots are in simulator order, so the
heads regress every particle directly (no matching). Positions are predicted in normalised
units (training-split mean and std, stored with the checkpoint) and returned in metres by
``propose``.
"""

from __future__ import annotations

import lightning as L
import torch
from torch import nn
from torch.nn import functional as F

from vgpl.models.step_learning_rate import AnnealedLearningRate


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
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.register_buffer("pos_mean", torch.zeros(3))
        self.register_buffer("pos_std", torch.ones(3))
        blocks, c_in = [nn.AvgPool2d(downsample)] if downsample > 1 else [], 3 * frames
        for c in channels:
            blocks.append(conv_block(c_in, c))
            c_in = c
        # channels-last: the layout oneDNN's and cuDNN's fast convolutions use (this CPU: 1.42x a step in fp32, 1.23x
        # in bf16; benchmarks/results_visual.jsonl). Module.to keeps it; a checkpoint saved either way loads into it.
        self.encoder = nn.Sequential(*blocks, nn.AdaptiveAvgPool2d(tuple(pooled)), nn.Flatten()).to(memory_format=torch.channels_last)
        features = c_in * pooled[0] * pooled[1]
        self.position_head = nn.Sequential(nn.Linear(features, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, frames * n_particles * 3))
        self.group_head = nn.Sequential(nn.Linear(features, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, frames * n_particles * n_instances))

    def set_stats(self, stats) -> None:
        self.pos_mean.copy_(stats.pos_mean)
        self.pos_std.copy_(stats.pos_std)

    @staticmethod
    def to_input(frames: torch.Tensor) -> torch.Tensor:
        """uint8 frames [B, F, H, W, 3] -> float [B, 3F, H, W] in [-1, 1], channel f * 3 + c, stored channels-last."""
        b, f, h, w, _ = frames.shape
        return (frames.permute(0, 2, 3, 1, 4).reshape(b, h, w, f * 3).permute(0, 3, 1, 2).float() / 127.5) - 1.0

    def forward(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """uint8 frames [B, F, H, W, 3] -> (normalised positions [B, F, N, 3], grouping logits [B, F, N, M])."""
        b = frames.shape[0]
        z = self.encoder(self.to_input(frames))
        f, n, m = self.hparams.frames, self.hparams.n_particles, self.hparams.n_instances
        return self.position_head(z).view(b, f, n, 3), self.group_head(z).view(b, f, n, m)

    def propose(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Positions in metres [B, F, N, 3] and grouping logits [B, F, N, M]."""
        pos, logits = self(frames)
        return pos * self.pos_std + self.pos_mean, logits

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
