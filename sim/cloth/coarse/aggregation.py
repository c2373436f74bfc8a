"""Aggregates of the coarse level: seeds spread over a mesh's edge graph, each vertex joined to
its nearest seed (a graph Voronoi cell, connected). Pure scipy functions."""

from __future__ import annotations

import numpy as np

from sim.cloth.model import mesh_edges

AUTO_MIN_SPACING = 4
"""Least seed spacing [edges] of the automatic aggregation: the 5k t-shirt's 4,925 vertices take
spacing 4 (202 nodes, band 37). A finer garment keeps spacing 4 and gets a third level instead
(``coarse_template``): its 20k vertices give 808 nodes, whose band (87) would not fit a CUDA
block's shared memory (``sim.cloth.coarse.block``), and the spacing that would fit (8) gives
higher worst strains than three levels (H100 19k t-shirt 14 x 5: population worst 1.25 against
0.86, docs/DECISIONS.md)."""
AUTO_MAX_NODES = 256
"""Most nodes of a coarse level solved exactly on an automatic setting (its band fits a block)."""


def mesh_edge_graph(vertex_count: int, faces: np.ndarray):
    """Symmetric CSR adjacency (scipy) of the mesh's edge graph (``model.mesh_edges``)."""
    import scipy.sparse as sp

    e = mesh_edges(faces)
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(vertex_count, vertex_count))
    return (g + g.T).tocsr()


def spaced_seeds(adjacency, spacing: int) -> np.ndarray:
    """Seeds chosen greedily in index order at graph distance ``> spacing`` from each other: each
    seed blocks its ball of radius ``spacing`` (breadth-first). Every component gets one."""
    n = adjacency.shape[0]
    indptr, indices = adjacency.indptr, adjacency.indices
    blocked = np.zeros(n, dtype=bool)
    seeds = []
    for v in range(n):
        if blocked[v]:
            continue
        seeds.append(v)
        frontier = [v]
        blocked[v] = True
        for _ in range(spacing):
            nxt = []
            for u in frontier:
                for w in indices[indptr[u]:indptr[u + 1]]:
                    if not blocked[w]:
                        blocked[w] = True
                        nxt.append(w)
            frontier = nxt
    return np.asarray(seeds, dtype=np.int64)


def aggregate(adjacency, spacing: int) -> tuple[np.ndarray, np.ndarray]:
    """(aggregate index of every vertex, the aggregates' seed vertices): ``spaced_seeds``, each
    vertex joined to its nearest seed (ties: the seed found first by
    ``scipy.sparse.csgraph.dijkstra``). Every aggregate is connected."""
    from scipy.sparse.csgraph import dijkstra

    n = adjacency.shape[0]
    seeds = spaced_seeds(adjacency, spacing)
    _, _, sources = dijkstra(adjacency, directed=False, indices=seeds, unweighted=True, min_only=True,
                             return_predecessors=True)
    lookup = np.full(n, -1, dtype=np.int64)
    lookup[seeds] = np.arange(len(seeds))
    return lookup[sources], seeds


def auto_aggregate(adjacency, min_spacing: int = AUTO_MIN_SPACING,
                   max_nodes: int = AUTO_MAX_NODES) -> tuple[np.ndarray, np.ndarray]:
    """``aggregate`` at the least spacing from ``min_spacing`` that gives at most ``max_nodes``
    seeds. An aggregate of spacing ``s`` holds about ``1.5 s^2`` vertices of a near-uniform
    triangle mesh, so the search starts there and grows the spacing until the seeds fit."""
    n = adjacency.shape[0]
    spacing = max(min_spacing, int(np.sqrt(n / (1.5 * max_nodes))))
    while True:
        agg, seeds = aggregate(adjacency, spacing)
        if len(seeds) <= max_nodes:
            return agg, seeds
        spacing += 1


def aggregate_graph(adjacency, agg: np.ndarray):
    """Symmetric CSR adjacency of the aggregates: two are neighbours where an edge of
    ``adjacency`` joins their members (the coarse level's own mesh graph)."""
    import scipy.sparse as sp

    n, nc = adjacency.shape[0], int(agg.max()) + 1
    indicator = sp.csr_matrix((np.ones(n), (np.arange(n), agg)), shape=(n, nc))
    g = (indicator.T @ adjacency @ indicator).tocsr()
    g.setdiag(0.0)
    g.eliminate_zeros()
    g.data[:] = 1.0
    return g
