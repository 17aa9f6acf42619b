"""DensePhysNet (Xu et al., RSS 2019), the paper's parameter-estimation baseline.

Five modules, as in the original: an image encoder, a multi-step information aggregator (a
convolutional GRU whose state is the dense physical representation), an action encoder, a
cross-convolution (kernels generated from the representation, applied to the image features)
and a motion predictor that decodes the next optical flow. The parameter is read from the
representation by a linear (ridge) decoder fitted afterwards on frozen features
(:mod:`vgpl.eval.linear_probe`).
"""

from __future__ import annotations

import lightning as L
import torch
from torch import nn
from torch.nn import functional as F


def conv(c_in: int, c_out: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, 1), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True))


class ConvGRUCell(nn.Module):
    """h' = (1 - z) h + z tanh(W [x; r h]), gates from 3x3 convolutions. x [B, Cx, H, W], h [B, C, H, W]."""

    def __init__(self, c_in: int, c_hidden: int) -> None:
        super().__init__()
        self.gates = nn.Conv2d(c_in + c_hidden, 2 * c_hidden, 3, padding=1)
        self.candidate = nn.Conv2d(c_in + c_hidden, c_hidden, 3, padding=1)

    def forward(self, x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        z, r = torch.sigmoid(self.gates(torch.cat([x, h], 1))).chunk(2, 1)
        return (1 - z) * h + z * torch.tanh(self.candidate(torch.cat([x, r * h], 1)))


class DensePhysNet(L.LightningModule):
    def __init__(self, action_dim: int, channels: int = 32, latent: int = 32, kernel: int = 5, lr: float = 1e-3, flow_scale: float = 1.0) -> None:
        super().__init__()
        self.save_hyperparameters()
        c = channels
        self.image_encoder = nn.Sequential(conv(3, c, 2), conv(c, c), conv(c, 2 * c, 2), conv(2 * c, 2 * c))  # [B, 2c, H/4, W/4]
        self.aggregator = ConvGRUCell(2 * c + 2 * c, latent)  # inputs: features of frames t and t+1
        self.action_encoder = nn.Sequential(nn.Linear(max(action_dim, 1), c), nn.ReLU(), nn.Linear(c, c))
        self.kernel_generator = nn.Linear(latent, 2 * c * kernel * kernel)
        self.motion_predictor = nn.Sequential(
            conv(2 * c + latent + c, 2 * c), nn.Upsample(scale_factor=2, mode="bilinear"), conv(2 * c, c),
            nn.Upsample(scale_factor=2, mode="bilinear"), nn.Conv2d(c, 2, 3, padding=1),
        )

    @staticmethod
    def to_input(frames: torch.Tensor) -> torch.Tensor:
        """uint8 [..., H, W, 3] -> float [..., 3, H, W] in [-1, 1]."""
        return frames.movedim(-1, -3).float() / 127.5 - 1.0

    def cross_convolution(self, features: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """Per-scene depthwise kernels generated from the pooled representation, applied to the features."""
        b, c, h, w = features.shape
        k = self.hparams.kernel
        kernels = self.kernel_generator(state.mean((2, 3))).view(b * c, 1, k, k)
        out = F.conv2d(features.reshape(1, b * c, h, w), kernels, padding=k // 2, groups=b * c)
        return out.view(b, c, h, w)

    def forward(self, frames: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """frames uint8 [B, T + 1, H, W, 3], actions [B, T, A] -> (flow [B, T, H, W, 2] in pixels per
        frame, representation [B, latent, H/4, W/4] after the T steps)."""
        b, t1, h, w, _ = frames.shape
        feats = self.image_encoder(self.to_input(frames).reshape(b * t1, 3, h, w))
        feats = feats.view(b, t1, *feats.shape[1:])
        state = feats.new_zeros(b, self.hparams.latent, *feats.shape[-2:])
        if actions.shape[-1] == 0:
            actions = actions.new_zeros(*actions.shape[:-1], 1)
        flows = []
        for s in range(t1 - 1):
            crossed = self.cross_convolution(feats[:, s], state)
            act = self.action_encoder(actions[:, s])[..., None, None].expand(-1, -1, *feats.shape[-2:])
            flow = self.motion_predictor(torch.cat([crossed, state, act], 1))
            flows.append(flow[..., :h, :w].permute(0, 2, 3, 1) * self.hparams.flow_scale)
            state = self.aggregator(torch.cat([feats[:, s], feats[:, s + 1]], 1), state)
        return torch.stack(flows, 1), state

    def representation(self, frames: torch.Tensor, actions: torch.Tensor, pool: tuple[int, int] = (3, 4)) -> torch.Tensor:
        """Dense representation after the observed frames, pooled to a feature vector [B, latent x 12]."""
        _, state = self(frames, actions)
        return F.adaptive_avg_pool2d(state, pool).flatten(1)

    def _loss(self, batch) -> torch.Tensor:
        """L1 over all pixels plus L1 over moving ones: most pixels are static background, and
        the all-pixel term alone is minimised by predicting no motion at all."""
        flow, _ = self(batch["frames"], batch["actions"])
        error = (flow - batch["flow"]).abs().sum(-1)
        moving = batch["flow"].abs().sum(-1) > 0
        return error.mean() / 2 + (error[moving].mean() / 2 if moving.any() else 0.0)

    def training_step(self, batch, batch_idx):
        loss = self._loss(batch)
        self.log("train/flow_l1", loss, prog_bar=True, batch_size=batch["frames"].shape[0])
        return loss

    def validation_step(self, batch, batch_idx):
        self.log("val/loss", self._loss(batch), batch_size=batch["frames"].shape[0])

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.hparams.lr)
