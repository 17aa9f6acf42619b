"""Radius graphs and edge features shared by the learned modules (torch-geometric conventions).

``edge_index`` is [2, E] with row 0 the source j and row 1 the target i (PyG's
``source_to_target`` flow); messages flow j -> i. A library backend is used when one is importable
(torch-geometric's own op needs pyg-lib >= 0.6, or torch-cluster); otherwise ours, with the same
semantics. Neighbours are never truncated: callers get the maximum degree to log.
"""

from __future__ import annotations

import logging

import torch
from torch_geometric.utils import degree, to_dense_batch

log = logging.getLogger(__name__)


def _library_backend():
    try:
        from torch_geometric import typing as pyg_typing

        if getattr(pyg_typing, "WITH_RADIUS", False):
            from torch_geometric.nn import radius_graph as fn

            return "torch_geometric", fn
    except ImportError:
        pass
    try:
        from torch_cluster import radius_graph as fn

        return "torch_cluster", fn
    except ImportError:
        return None, None


BACKEND, _LIBRARY_RADIUS_GRAPH = _library_backend()


def own_radius_graph(pos: torch.Tensor, r: float, batch: torch.Tensor | None = None, max_neighbors: int | None = None,
                     graph_size: int | None = None) -> torch.Tensor:
    """All pairs (j -> i), i != j, of the same graph closer than ``r``; with ``max_neighbors``,
    only the nearest ``max_neighbors`` sources of each target (ties: lower index first).

    Args: pos [N, 3]; batch [N] graph id of each node, sorted (None: one graph); graph_size: every
    graph has this many nodes, one after another (then ``batch`` is not read, and the graph is built
    without reading sizes back from the device: only the final ``nonzero`` waits for it).
    Returns: edge_index [2, E] sorted by target, then source.
    """
    if graph_size is not None:
        if pos.shape[0] % graph_size:
            raise ValueError(f"own_radius_graph: {pos.shape[0]} nodes are not graphs of graph_size={graph_size}")
        dense = pos.reshape(-1, graph_size, 3)
        mask = torch.ones(dense.shape[:2], dtype=torch.bool, device=pos.device)
    else:
        if batch is None:
            batch = torch.zeros(pos.shape[0], dtype=torch.long, device=pos.device)
        dense, mask = to_dense_batch(pos, batch)  # [B, Nmax, 3], [B, Nmax]
    b, nmax, _ = dense.shape
    dist = torch.cdist(dense, dense, compute_mode="donot_use_mm_for_euclid_dist")
    close = (dist < r) & mask[:, :, None] & mask[:, None, :]
    close &= ~torch.eye(nmax, dtype=torch.bool, device=pos.device)
    if max_neighbors is not None and max_neighbors < nmax - 1:
        ranked = torch.where(close, dist, torch.full_like(dist, float("inf")))
        nearest = ranked.topk(max_neighbors, dim=-1, largest=False, sorted=False).indices
        keep = torch.zeros_like(close).scatter_(-1, nearest, True)
        close &= keep
    scene, i, j = close.nonzero(as_tuple=True)
    ptr = torch.cumsum(mask.sum(1), 0) - mask.sum(1)  # first node of each graph
    return torch.stack([ptr[scene] + j, ptr[scene] + i])


def radius_graph(pos: torch.Tensor, r: float, batch: torch.Tensor | None = None, backend: str | None = None,
                 max_neighbors: int | None = None, graph_size: int | None = None) -> torch.Tensor:
    """Radius graph with no self loops (see :func:`own_radius_graph`); no neighbour cap unless
    ``max_neighbors`` is given (then ours, which keeps the nearest: the libraries keep arbitrary ones).

    ``backend``: None picks the library when importable, "vgpl" forces ours. ``graph_size``: every
    graph has this many nodes (ours then reads no sizes back from the device).
    """
    if max_neighbors is not None:
        return own_radius_graph(pos, r, batch, max_neighbors, graph_size)
    if backend != "vgpl" and _LIBRARY_RADIUS_GRAPH is not None:
        edge_index = _LIBRARY_RADIUS_GRAPH(pos, r, batch, loop=False, max_num_neighbors=pos.shape[0])
        order = torch.argsort(edge_index[1] * pos.shape[0] + edge_index[0])
        return edge_index[:, order]
    return own_radius_graph(pos, r, batch, graph_size=graph_size)


def max_degree(edge_index: torch.Tensor, num_nodes: int) -> int:
    """Largest number of incoming edges of a node (log it: nothing is truncated)."""
    if edge_index.numel() == 0:
        return 0
    return int(degree(edge_index[1], num_nodes).max())


def plane_ghosts(pos: torch.Tensor, planes: torch.Tensor, batch: torch.Tensor, r: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Kinematic "ghost" nodes for half-space boundaries (floor, container walls).

    Every particle closer than ``r`` to a plane gets a ghost node at its projection on the plane,
    with an edge ghost -> particle, so boundaries enter the graph as nodes like the pin does.

    Args: pos [N, 3]; planes [B, K, 4] rows (n, d) with n . x >= d inside; batch [N].
    Returns: ghost positions [G, 3], the particle each ghost belongs to [G], its plane id [G].
    """
    normals, offsets = planes[batch, :, :3], planes[batch, :, 3]  # [N, K, 3], [N, K]
    dist = (pos[:, None, :] * normals).sum(-1) - offsets  # [N, K]
    particle, plane = (dist < r).nonzero(as_tuple=True)
    ghost = pos[particle] - dist[particle, plane, None] * normals[particle, plane]
    return ghost, particle, plane


def edge_features(pos: torch.Tensor, edge_index: torch.Tensor, grouping: torch.Tensor | None = None) -> torch.Tensor:
    """[E, 5]: displacement x_i - x_j (3), distance (1), probability that i and j share an instance (1).

    Args: pos [N, 3]; edge_index [2, E]; grouping [N, M] soft instance assignment (None: zeros).
    """
    src, dst = edge_index
    rel = pos[dst] - pos[src]
    same = (grouping[dst] * grouping[src]).sum(-1, keepdim=True) if grouping is not None else rel.new_zeros(rel.shape[0], 1)
    return torch.cat([rel, rel.norm(dim=-1, keepdim=True), same], -1)
