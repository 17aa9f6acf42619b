"""Reference for benchmarking only: DPI-Net the way the original code computes it, with dense
one-hot relation matrices Rr, Rs [E, V] and full MLPs on every edge. Same width, depth and
propagation steps as vgpl's DynamicsPrior; used to measure the speed-up, never for training."""

from __future__ import annotations

import torch
from torch import nn


def mlp(sizes):
    layers = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        layers += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*layers)


class DenseDPINet(nn.Module):
    def __init__(self, node_dim: int, edge_dim: int, width: int = 150, steps: int = 2) -> None:
        super().__init__()
        self.steps = steps
        self.node_encoder = mlp([node_dim, width, width, width])
        self.edge_encoder = mlp([2 * node_dim + edge_dim, width, width, width])
        self.edge_propagator = mlp([3 * width, width])
        self.node_propagator = mlp([2 * width, width])
        self.head = nn.Sequential(mlp([width, width, width]), nn.Linear(width, 3))

    def forward(self, nodes, edge_attr, rr, rs):
        """nodes [B, V, Fn]; edge_attr [B, E, Fe]; rr, rs [B, E, V] one-hot receiver/sender matrices."""
        code = self.node_encoder(nodes)
        edge_code = self.edge_encoder(torch.cat([rr @ nodes, rs @ nodes, edge_attr], -1))
        effect = torch.zeros_like(code)
        for _ in range(self.steps):
            edge_effect = self.edge_propagator(torch.cat([edge_code, rr @ effect, rs @ effect], -1))
            effect = self.node_propagator(torch.cat([code, rr.transpose(1, 2) @ edge_effect], -1)) + effect
        return self.head(effect)
