"""DPI-Net's encoders and propagation step as torch-geometric modules.

Work per edge is what makes the original slow, so every per-edge MLP's first layer is split:
W [x_i; x_j; e] = W_r x_i + W_s x_j + W_e e. The node terms are computed once per node and only
gathered per edge; the edge code's term is computed once per forward pass, because the edge code
does not change between propagation steps. Same function as DPI-Net, far fewer multiply-adds.

The per-edge activations are computed ``ALIGNMENT``-aligned: at width 150 they are 152 columns
wide, the last two exactly zero (the layers' weights and biases padded with zeros when applied;
the parameters keep their shapes). MKL's float32 product of [E, 150] by [150, 150] runs 1.5x
slower than the same product padded to 152 on AVX2 CPUs (docs/benchmarks.md); the function is
the same to float rounding. ``ALIGNMENT = 1`` computes at the exact width.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from torch_geometric.nn import MLP, MessagePassing

ALIGNMENT = 8  # columns the per-edge activations are padded to a multiple of (1: none)


def aligned(width: int) -> int:
    """``width`` rounded up to a multiple of ALIGNMENT."""
    return -(-width // ALIGNMENT) * ALIGNMENT


def padded_linear(x: torch.Tensor, layer: nn.Module, width: int) -> torch.Tensor:
    """``layer`` (torch's or torch-geometric's Linear, weight [out, in]) on x [..., K] (K >= in, the
    columns past in zero), its output padded with zero columns to ``width`` >= out: [..., width]."""
    out, into = layer.weight.shape
    if x.shape[-1] == into and width == out:  # nothing to pad: the parameters themselves, which autocast casts once
        return F.linear(x, layer.weight, layer.bias)
    weight = F.pad(layer.weight, (0, x.shape[-1] - into, 0, width - out))
    bias = None if layer.bias is None else F.pad(layer.bias, (0, width - out))
    return F.linear(x, weight, bias)


class EdgeEncoder(nn.Module):
    """3-layer MLP on [receiver input; sender input; edge features] with the first layer split.

    forward(node_in [V, Fn], edge_attr [E, Fe], edge_index [2, E], term) -> [E, aligned(width)], the
    columns past width zero; ``term`` (a Linear, width -> width) is applied last when given.
    """

    def __init__(self, node_dim: int, edge_dim: int, width: int) -> None:
        super().__init__()
        self.receiver = nn.Linear(node_dim, width)
        self.sender = nn.Linear(node_dim, width, bias=False)
        self.edge = nn.Linear(edge_dim, width, bias=False)
        self.rest = MLP([width, width, width], norm=None, plain_last=False)

    def forward(self, node_in: torch.Tensor, edge_attr: torch.Tensor, edge_index: torch.Tensor, term: nn.Linear | None = None) -> torch.Tensor:
        src, dst = edge_index
        width = aligned(self.receiver.weight.shape[0])
        # index_select, not x[idx]: its backward is a fast index_add instead of an accumulating index_put
        first = (padded_linear(node_in, self.receiver, width).index_select(0, dst) + padded_linear(node_in, self.sender, width).index_select(0, src)
                 + padded_linear(edge_attr, self.edge, width))
        code = torch.relu(first)
        for layer in self.rest.lins:  # the MLP's layers (norm None, plain_last False: a ReLU after each)
            code = torch.relu(padded_linear(code, layer, width))
        return code if term is None else padded_linear(code, term, width)


class Propagator(MessagePassing):
    """One propagation step: edge effect relu(T_e + U_r h_i + U_s h_j), summed at the receiver i;
    node effect h_i <- relu(V [c_i; sum]) + h_i, with c the node code and T_e precomputed.

    forward(effect [V, W], node_code [V, W], edge_term [E, W'], edge_index [2, E]) -> [V, W]; W' >= W
    (EdgeEncoder's aligned width, the columns past W zero): the messages are computed that wide.
    """

    def __init__(self, width: int) -> None:
        super().__init__(aggr="sum")
        self.receiver = nn.Linear(width, width, bias=False)
        self.sender = nn.Linear(width, width, bias=False)
        self.node = nn.Linear(2 * width, width)

    def forward(self, effect: torch.Tensor, node_code: torch.Tensor, edge_term: torch.Tensor, edge_index: torch.Tensor) -> torch.Tensor:
        width = edge_term.shape[-1]
        summed = self.propagate(edge_index, x=(padded_linear(effect, self.sender, width), padded_linear(effect, self.receiver, width)), edge_term=edge_term)
        return torch.relu(self.node(torch.cat([node_code, summed[:, : effect.shape[-1]]], -1))) + effect

    def message(self, x_i: torch.Tensor, x_j: torch.Tensor, edge_term: torch.Tensor) -> torch.Tensor:
        return torch.relu(edge_term + x_i + x_j)

    def aggregate(self, inputs: torch.Tensor, index: torch.Tensor, ptr: torch.Tensor | None = None, dim_size: int | None = None) -> torch.Tensor:
        """The messages [E, W'] summed at their receivers ``index`` [E] -> [dim_size, W']. The same sum
        as the "sum" aggregation's scatter, whose backward gathers through an index as wide as the
        messages; index_add's backward is an index_select of the receivers' gradients."""
        return inputs.new_zeros(dim_size, inputs.shape[-1]).index_add_(0, index, inputs)
