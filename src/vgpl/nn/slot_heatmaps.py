"""Per-slot heatmaps: where in the image each slot (a particle, or a rigid instance) is, how far
from the camera, and a linear readout of what the image shows there, read from a feature map.

Each of the S slots has its own heatmap over the feature map; its softmax is the slot's attention
over the image. The slot's pixel position is the attention-weighted mean of the cells' centres (a
soft-argmax, precise to a fraction of a cell), its depth the attention-weighted mean of its own
depth map, and its readout (grouping logits, or a rotation) a linear map of the attended features. Two
encoder maps are merged first, the coarser one upsampled onto the finer (a two-level feature
pyramid), so the heatmaps see the coarse map's context at the fine map's resolution.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


class SlotHeatmaps(nn.Module):
    """fine [B, C_f, h, w] and coarse [B, C_c, h', w'] features -> (pixel positions [B, S, 2],
    depths [B, S] in the units of the depth maps, readouts [B, S, outputs]).

    Pixel positions are in the image's pixels (u right, v down, ``image_size`` = (H, W)).
    """

    def __init__(self, fine_channels: int, coarse_channels: int, width: int, slots: int, outputs: int) -> None:
        super().__init__()
        self.fine = nn.Conv2d(fine_channels, width, 1)
        self.coarse = nn.Conv2d(coarse_channels, width, 1)
        self.mix = nn.Sequential(nn.Conv2d(width, width, 3, padding=1, bias=False), nn.BatchNorm2d(width), nn.ReLU(inplace=True))
        self.heat = nn.Conv2d(width, slots, 1)
        self.depth = nn.Conv2d(width, slots, 1)
        self.readout = nn.Linear(width, outputs)

    def forward(self, fine: torch.Tensor, coarse: torch.Tensor, image_size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.fine(fine) + F.interpolate(self.coarse(coarse), size=fine.shape[-2:], mode="bilinear", align_corners=False)
        x = self.mix(x)
        h, w = x.shape[-2:]
        attention = self.heat(x).flatten(2).float().softmax(-1)  # [B, S, h w]
        rows = (torch.arange(h, device=x.device, dtype=torch.float32) + 0.5) * (image_size[0] / h)
        cols = (torch.arange(w, device=x.device, dtype=torch.float32) + 0.5) * (image_size[1] / w)
        grid = torch.stack(torch.meshgrid(cols, rows, indexing="xy"), -1).reshape(h * w, 2)  # (u, v) of each cell's centre
        uv = attention @ grid
        depth = (attention * self.depth(x).flatten(2).float()).sum(-1)
        features = attention @ x.flatten(2).transpose(1, 2).float()  # [B, S, width]
        return uv, depth, self.readout(features)
