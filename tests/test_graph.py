from __future__ import annotations

import pytest
import torch

from vgpl import graph
from vgpl.graph import edge_features, max_degree, own_radius_graph, plane_ghosts, radius_graph


def brute_force(pos, r, batch):
    d = torch.cdist(pos, pos)
    close = (d < r) & (batch[:, None] == batch[None]) & ~torch.eye(len(pos), dtype=torch.bool)
    i, j = close.nonzero(as_tuple=True)  # sorted by i then j
    return torch.stack([j, i])


@pytest.mark.parametrize("sizes", [(10,), (7, 20, 3), (1, 5)])
def test_own_radius_graph_matches_brute_force(sizes):
    torch.manual_seed(0)
    batch = torch.cat([torch.full((s,), k) for k, s in enumerate(sizes)])
    pos = torch.rand(len(batch), 3)
    assert torch.equal(own_radius_graph(pos, 0.45, batch), brute_force(pos, 0.45, batch))


@pytest.mark.parametrize("max_neighbors", [None, 4])
def test_equal_size_graphs_give_the_same_edges_without_the_batch_vector(max_neighbors):
    """graph_size replaces the batch vector (and its read-backs) when every graph has the same size."""
    torch.manual_seed(2)
    pos, batch = torch.rand(3 * 17, 3), torch.arange(3).repeat_interleave(17)
    assert torch.equal(own_radius_graph(pos, 0.4, None, max_neighbors, graph_size=17), own_radius_graph(pos, 0.4, batch, max_neighbors))
    with pytest.raises(ValueError, match="graph_size=16"):
        own_radius_graph(pos, 0.4, graph_size=16)


def test_library_backend_agrees_when_available():
    torch.manual_seed(1)
    pos, batch = torch.rand(50, 3), torch.tensor([0] * 20 + [1] * 30)
    ours = radius_graph(pos, 0.3, batch, backend="vgpl")
    assert torch.equal(radius_graph(pos, 0.3, batch), ours)  # library (if importable) or ours
    assert graph.BACKEND in (None, "torch_geometric", "torch_cluster")


def test_no_neighbour_is_dropped_in_a_dense_cluster():
    pos = torch.rand(200, 3) * 0.01  # all within radius of each other
    ei = radius_graph(pos, 0.1)
    assert ei.shape[1] == 200 * 199 and max_degree(ei, 200) == 199


def test_plane_ghosts_project_onto_the_plane():
    pos = torch.tensor([[0.1, 0.05, 0.0], [0.2, 0.5, 0.0], [0.3, 0.02, 0.1]])
    planes = torch.tensor([[[0.0, 1.0, 0.0, 0.0]]])
    ghost, owner, plane = plane_ghosts(pos, planes, torch.zeros(3, dtype=torch.long), r=0.08)
    assert owner.tolist() == [0, 2] and plane.tolist() == [0, 0]
    assert torch.allclose(ghost, torch.tensor([[0.1, 0.0, 0.0], [0.3, 0.0, 0.1]]))


def test_edge_features():
    pos = torch.tensor([[0.0, 0.0, 0.0], [0.3, 0.4, 0.0]])
    g = torch.tensor([[1.0, 0.0], [0.25, 0.75]])
    f = edge_features(pos, torch.tensor([[0], [1]]), g)  # 0 -> 1
    assert torch.allclose(f, torch.tensor([[0.3, 0.4, 0.0, 0.5, 0.25]]))
