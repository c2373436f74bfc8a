"""Vertex graph colouring for Gauss-Seidel Vertex Block Descent.

Two vertices that share an energy term (a triangle, or a bending hinge) must get different
colours, so all vertices of one colour can be updated in parallel without races
(Chen et al. 2024, Sec. 3.5). Host-side numpy, run once when a model is built.
"""

from __future__ import annotations

import numpy as np


def vertex_adjacency(num_vertices: int, faces: np.ndarray, hinges: np.ndarray) -> list[np.ndarray]:
    """Neighbours of each vertex in the VBD dependency graph.

    Args:
        num_vertices: V.
        faces: int (F, 3).
        hinges: int (E, 4) as (o0, o1, a, b); only the pair (o0, o1) adds to the triangle edges.

    Returns:
        V sorted int arrays of neighbour indices.
    """
    pairs = [faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]
    if len(hinges):
        pairs.append(hinges[:, [0, 1]])
    p = np.concatenate(pairs, axis=0).astype(np.int64)
    p = np.concatenate([p, p[:, ::-1]], axis=0)
    p = np.unique(p, axis=0)
    starts = np.searchsorted(p[:, 0], np.arange(num_vertices + 1))
    return [p[starts[v]:starts[v + 1], 1] for v in range(num_vertices)]


def greedy_coloring(neighbours: list[np.ndarray]) -> np.ndarray:
    """Greedy colouring, vertices by decreasing degree (ties by index): deterministic.

    Args:
        neighbours: per-vertex neighbour index arrays.

    Returns:
        int32 (V,) colour per vertex, colours 0..C-1.
    """
    n = len(neighbours)
    degree = np.array([len(nb) for nb in neighbours], dtype=np.int64)
    order = np.lexsort((np.arange(n), -degree))
    colors = np.full(n, -1, dtype=np.int32)
    for v in order:
        used = colors[neighbours[v]]
        used = used[used >= 0]
        c = 0
        if len(used):
            taken = np.zeros(len(used) + 1, dtype=bool)
            taken[used[used <= len(used)]] = True
            c = int(np.argmin(taken))
        colors[v] = c
    return colors


def validate_coloring(neighbours: list[np.ndarray], colors: np.ndarray) -> bool:
    """True when no two neighbours share a colour."""
    return all(not np.any(colors[nb] == colors[v]) for v, nb in enumerate(neighbours))
