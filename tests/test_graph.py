"""Graph operators of GSNet's encoder (learn.graph) against dense numpy/torch references."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learn.graph import (
    Graph,
    GraphConv,
    batch_graphs,
    mesh_edges,
    mesh_operator,
    normalised_operator,
    propagate,
    segment_max,
    symmetric,
)


def grid_faces(nx: int, ny: int) -> np.ndarray:
    """Triangles of an nx x ny vertex grid."""
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    return np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])


def dense_adjacency(faces: np.ndarray, n: int) -> np.ndarray:
    a = np.zeros((n, n))
    for f in faces:
        for i in range(3):
            p, q = f[i], f[(i + 1) % 3]
            a[p, q] = a[q, p] = 1.0
    return a


def test_mesh_edges_are_unique_and_sorted():
    faces = np.array([[0, 1, 2], [2, 1, 3]])
    e = mesh_edges(faces)
    np.testing.assert_array_equal(e, [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]])


@pytest.mark.parametrize("kind", ["laplacian", "adjacency"])
def test_mesh_operator_matches_the_dense_formula(kind):
    faces = grid_faces(5, 4)
    n = 20
    a = dense_adjacency(faces, n)
    if kind == "laplacian":  # GSNet Eq. 2-3: I - D^-1/2 A D^-1/2
        d = a.sum(1)
        ref = np.eye(n) - a / np.sqrt(np.outer(d, d))
    else:  # Kipf & Welling: D~^-1/2 (A + I) D~^-1/2
        at = a + np.eye(n)
        d = at.sum(1)
        ref = at / np.sqrt(np.outer(d, d))
    got = mesh_operator(faces, n, kind).dense().double().numpy()
    np.testing.assert_allclose(got, ref, atol=1e-6)


def test_laplacian_of_a_regular_graph_kills_constants():
    # a ring: every degree 2, so L_n 1 = 0 exactly
    n = 7
    edges = torch.tensor([[i, (i + 1) % n] for i in range(n)])
    g = normalised_operator(*symmetric(edges, torch.ones(n, dtype=torch.float64)), n, "laplacian")
    out = propagate(g, torch.ones(n, 3, dtype=torch.float64))
    assert out.abs().max() < 1e-12


@pytest.mark.parametrize("grad", [True, False])
def test_propagate_matches_dense_product(grad):
    """Both paths, the edge list's (autograd on) and the CSR product's (inference), with repeated
    and unsorted edges."""
    rng = np.random.default_rng(0)
    g = Graph(torch.from_numpy(rng.integers(0, 9, 40)), torch.from_numpy(rng.integers(0, 9, 40)),
              torch.from_numpy(rng.normal(size=40)), 9)
    x = torch.from_numpy(rng.normal(size=(9, 5)))
    with torch.set_grad_enabled(grad):
        torch.testing.assert_close(propagate(g, x), g.dense() @ x)
        torch.testing.assert_close(propagate(g, x.float()), (g.dense() @ x).float())


def test_batched_graphs_are_block_diagonal():
    f1, f2 = grid_faces(3, 3), grid_faces(4, 2)
    g1, g2 = mesh_operator(f1, 9), mesh_operator(f2, 8)
    g, seg = batch_graphs([g1, g2])
    d = g.dense()
    torch.testing.assert_close(d[:9, :9], g1.dense())
    torch.testing.assert_close(d[9:, 9:], g2.dense())
    assert d[:9, 9:].abs().max() == 0 and d[9:, :9].abs().max() == 0
    assert seg.tolist() == [0] * 9 + [1] * 8


def test_segment_max_is_the_per_graph_maximum():
    rng = np.random.default_rng(1)
    x = torch.from_numpy(rng.normal(size=(10, 4)))
    seg = torch.tensor([0, 0, 1, 1, 1, 2, 2, 2, 2, 2])
    got = segment_max(x, seg, 3)
    for s in range(3):
        torch.testing.assert_close(got[s], x[seg == s].max(0).values)


@pytest.mark.parametrize("cin,cout", [(3, 8), (8, 3)])
def test_graph_conv_is_act_of_m_x_w_plus_b(cin, cout):
    torch.manual_seed(0)
    g = mesh_operator(grid_faces(4, 4), 16)
    conv = GraphConv(cin, cout, torch.nn.Tanh()).double()
    x = torch.randn(16, cin, dtype=torch.float64)
    ref = torch.tanh(g.dense().double() @ x @ conv.linear.weight.T + conv.linear.bias)
    torch.testing.assert_close(conv(Graph(g.src, g.dst, g.weight.double(), 16), x), ref)


@pytest.mark.parametrize("kind", ["laplacian", "adjacency"])
def test_operator_gradient_in_the_edge_weights_matches_finite_differences(kind):
    faces = grid_faces(3, 3)
    src, dst, _ = symmetric(torch.from_numpy(mesh_edges(faces)))
    e = src.shape[0] // 2
    w = torch.rand(e, dtype=torch.float64, generator=torch.Generator().manual_seed(3)) + 0.5
    x = torch.randn(9, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(4))

    def f(wh):
        return propagate(normalised_operator(src, dst, torch.cat([wh, wh]), 9, kind), x)

    assert torch.autograd.gradcheck(f, (w.requires_grad_(),))
