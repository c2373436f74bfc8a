"""Mesh topology of cloth instances (sim.cloth.topology): a batch's new meshes coloured side by
side in child processes give exactly the colourings made one at a time, cached or not."""

from __future__ import annotations

import numpy as np

from sim.cloth import topology as T
from sim.cloth.coloring import vertex_adjacency
from tests.test_cloth_solver import grid


def _perturbed(nx: int, ny: int, seed: int) -> np.ndarray:
    """A grid's faces with some quads split along the other diagonal (odd valences: a 3-colouring
    has conflicts, so the TabuCol search runs its whole budget)."""
    _, f = grid(nx, ny, 1.0, 1.0)
    rng = np.random.default_rng(seed)
    f = f.copy()
    for q in rng.choice(len(f) // 2, size=len(f) // 8, replace=False):
        a, b = f[2 * q], f[2 * q + 1]
        quad = list(dict.fromkeys([*a.tolist(), *b.tolist()]))
        shared = set(a.tolist()) & set(b.tolist())
        p, r = [v for v in quad if v not in shared]
        s0, s1 = [v for v in a.tolist() if v in shared]
        f[2 * q], f[2 * q + 1] = (p, s0, r), (r, s1, p)  # the other diagonal, orientation kept
    return f


def test_parallel_batch_gives_the_serial_topologies(monkeypatch):
    meshes = [(12 * 10, _perturbed(12, 10, s)) for s in range(3)]
    meshes.append(meshes[0])  # a garment twice in one batch: coloured once
    serial = [T._compute(n, f, 3) for n, f in meshes]
    T._TOPOLOGY.clear()
    monkeypatch.setattr(T, "PARALLEL_VERTICES", 1)  # these small meshes through the child processes
    calls = []
    real = T._in_child
    monkeypatch.setattr(T, "_in_child", lambda *a: calls.append(a[0]) or real(*a))
    batch = T.mesh_topologies(meshes, 3)
    assert len(calls) == 3
    for (h, c), (hs, cs) in zip(batch, serial, strict=True):
        np.testing.assert_array_equal(h, hs)
        np.testing.assert_array_equal(c, cs)
    assert max(c.max() for _, c in batch) == 2  # three colours, as asked
    nb = vertex_adjacency(120, meshes[0][1], np.zeros((0, 4), np.int64))
    conflicts = sum(int(np.sum(batch[0][1][n] == batch[0][1][v])) for v, n in enumerate(nb)) // 2
    assert conflicts > 0  # the odd valences leave some same-coloured neighbours
    again = T.mesh_topologies(meshes, 3)  # cached now: no child
    assert len(calls) == 3
    np.testing.assert_array_equal(again[2][1], serial[2][1])
    np.testing.assert_array_equal(T.mesh_topology(*meshes[1], 3)[1], serial[1][1])
