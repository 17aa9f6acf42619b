"""The InferenceModule's encoder: message passing on each frame's radius graph of the proposals,
then a bidirectional GRU over time per particle."""

from __future__ import annotations

import torch
from torch import nn
from torch_geometric.nn import MLP

from vgpl.graph import edge_features, radius_graph
from vgpl.nn.propagation import EdgeEncoder, Propagator


class SpatioTemporalEncoder(nn.Module):
    """Message passing on each frame's radius graph, then a bidirectional GRU over time per particle.

    forward(nodes [B, T, N, F], positions [B, T, N, 3], grouping [B, N, M]) -> [B, T, N, 2 W]
    """

    def __init__(self, node_dim: int, width: int, propagation_steps: int, radius: float, max_neighbors: int | None, gru_layers: int = 2) -> None:
        super().__init__()
        self.radius, self.steps, self.max_neighbors = radius, propagation_steps, max_neighbors
        self.node_encoder = MLP([node_dim, width, width, width], norm=None, plain_last=False)
        self.edge_encoder = EdgeEncoder(node_dim, 5, width)
        self.edge_term = nn.Linear(width, width)
        self.propagator = Propagator(width)
        self.gru = nn.GRU(width, width, num_layers=gru_layers, batch_first=True, bidirectional=True)

    def forward(self, nodes: torch.Tensor, positions: torch.Tensor, grouping: torch.Tensor, pos_scale: torch.Tensor) -> torch.Tensor:
        b, t, n, _ = nodes.shape
        flat_nodes = nodes.reshape(b * t * n, -1)
        flat_pos = positions.reshape(b * t * n, 3)
        graph = torch.arange(b * t, device=nodes.device).repeat_interleave(n)
        with torch.no_grad():
            # proposals can be far denser than real particles (an untrained prior collapses them):
            # the nearest max_neighbors keep the cost bounded
            edge_index = radius_graph(flat_pos.detach(), self.radius, graph, max_neighbors=self.max_neighbors, graph_size=n)
        group = grouping[:, None].expand(b, t, n, -1).reshape(b * t * n, -1)
        scale = torch.cat([pos_scale, pos_scale.norm()[None], torch.ones(1, device=nodes.device)])
        edge_attr = edge_features(flat_pos, edge_index, group) / scale
        code = self.node_encoder(flat_nodes)
        term = self.edge_encoder(flat_nodes, edge_attr, edge_index, self.edge_term)
        effect = torch.zeros_like(code)
        for _ in range(self.steps):
            effect = self.propagator(effect, code, term, edge_index)
        seq = effect.reshape(b, t, n, -1).permute(0, 2, 1, 3).reshape(b * n, t, -1)
        out, _ = self.gru(seq)
        return out.reshape(b, n, t, -1).permute(0, 2, 1, 3)
