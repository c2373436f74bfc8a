"""The coarse level's operators, assembled once per garment template in numpy/scipy: the
smoothed-aggregation prolongation, the membrane proxy's Galerkin stiffness, the lumped mass and
the stiffness's band in reverse Cuthill-McKee order (``sim.cloth.coarse``)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.cloth.coarse.aggregation import (
    AUTO_MAX_NODES,
    AUTO_MIN_SPACING,
    aggregate,
    aggregate_graph,
    auto_aggregate,
    mesh_edge_graph,
)


def cotangent_stiffness(rest: np.ndarray, faces: np.ndarray, modulus: np.ndarray, vertex_count: int):
    """Scalar P1 stiffness matrix ``K`` (scipy CSR, [N/m]) of ``sum_t modulus_t/2 int |grad u|^2``
    on the rest mesh: edge weights ``modulus/2 cot`` of the opposite corners, summed over the
    edge's triangles and clamped at zero (an obtuse pair would make it indefinite)."""
    import scipy.sparse as sp

    rows, cols, vals = [], [], []
    for k in range(3):
        a, b, c = faces[:, k], faces[:, (k + 1) % 3], faces[:, (k + 2) % 3]
        u, v = rest[b] - rest[a], rest[c] - rest[a]
        cot = np.einsum("ij,ij->i", u, v) / np.maximum(np.linalg.norm(np.cross(u, v), axis=1), 1e-20)
        rows.append(np.minimum(b, c))
        cols.append(np.maximum(b, c))
        vals.append(0.5 * modulus * cot)
    w = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(vertex_count, vertex_count)).tocsr()
    w.sum_duplicates()
    w.data = np.maximum(w.data, 0.0)
    w = w + w.T
    return (sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w).tocsr()


@dataclass
class CoarseTemplate:
    """One coarse level of a garment template (local indices), built on the level below it."""

    prolongation: Any  # scipy CSR (n, nc): rows of pinned particles are zero
    stiffness: Any  # scipy CSR (nc, nc): K_c = P^T K P [N/m]
    mass: np.ndarray  # (nc,) lumped P^T m [kg]
    order: np.ndarray  # (nc,) band row -> node (reverse Cuthill-McKee of K_c)
    band: np.ndarray  # (nc, b + 1) lower band of K_c in that order, band[r, t] = K_c[r, r - t]
    # a coarser level on this one's nodes (its ``prolongation`` maps them to its own): this
    # level's system is then smoothed around an exact solve of the inner one's (``CoarseLevel``)
    inner: CoarseTemplate | None = None


def lower_band(matrix, order: np.ndarray, pattern=None) -> np.ndarray:
    """The lower band ``(n, b + 1)`` of the symmetric ``matrix`` (scipy) with rows and columns in
    ``order``: ``band[r, t] = matrix[r, r - t]``; ``b`` the band width of ``pattern`` (default
    the matrix itself) in that order."""
    kp = matrix[order][:, order].tocoo()
    pp = pattern[order][:, order].tocoo() if pattern is not None else kp
    width = int((pp.row - pp.col).max()) if pp.nnz else 0
    lower = kp.row >= kp.col
    band = np.zeros((matrix.shape[0], width + 1))
    band[kp.row[lower], (kp.row - kp.col)[lower]] = kp.data[lower]
    return band


def galerkin_level(adjacency, stiffness, mass: np.ndarray, free: np.ndarray, agg: np.ndarray,
                   overlap: bool = False) -> CoarseTemplate:
    """The coarse level of the aggregates ``agg`` of a level with edge graph ``adjacency``,
    stiffness ``stiffness`` (scipy, [N/m]), lumped ``mass`` [kg] and ``free`` (bool) nodes:
    the prolongation ``P = S A`` (``A`` the aggregate indicator, smoothed once by ``S``: each node
    averages its own and its neighbours' aggregates, so the correction has no jumps at aggregate
    borders; rows of pinned nodes zero), the Galerkin stiffness ``P^T K P``, the lumped mass
    ``P^T m`` and the stiffness's lower band in reverse Cuthill-McKee order; ``overlap``: the band
    also covers every pair of nodes whose prolongations overlap (the pattern of ``P^T D P``, ``D``
    diagonal)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    n = adjacency.shape[0]
    nc = int(agg.max()) + 1
    indicator = sp.csr_matrix((np.ones(n), (np.arange(n), agg)), shape=(n, nc))
    smooth = adjacency + sp.identity(n, format="csr")
    smooth = sp.diags(1.0 / np.asarray(smooth.sum(axis=1)).ravel()) @ smooth
    p = (sp.diags(free.astype(float)) @ smooth @ indicator).tocsr()
    p.eliminate_zeros()
    kc = (p.T @ stiffness @ p).tocsr()
    kc.eliminate_zeros()
    mc = np.asarray(p.T @ mass.astype(np.float64)).ravel()
    pattern = (abs(kc) + abs(p.T @ p)).tocsr() if overlap else kc
    order = np.asarray(reverse_cuthill_mckee(pattern, symmetric_mode=True), dtype=np.int64)
    band = lower_band(kc, order, pattern if overlap else None)
    return CoarseTemplate(p, kc, mc, order, band)


def coarse_template(rest: np.ndarray, faces: np.ndarray, mass: np.ndarray, pinned: np.ndarray,
                    modulus: np.ndarray, spacing: int, levels: int = 0) -> CoarseTemplate:
    """The coarse level of one garment: ``rest`` (n, 3) [m], ``faces`` (F, 3), ``mass`` (n,)
    [kg], ``pinned`` (n,) bool, ``modulus`` (F,) ``lambda + 2 mu`` [N/m] (the membrane proxy's
    modulus, ``cotangent_stiffness``).

    ``spacing`` 0: ``AUTO_MIN_SPACING`` with ``levels`` 0 or 3, ``auto_aggregate`` with 2.
    ``levels``: 2 solves the coarse level exactly; 3 adds an inner level on its aggregate graph
    (``auto_aggregate`` from spacing 1, at most ``AUTO_MAX_NODES`` nodes) whose solve, between
    smoothing passes, solves this one; 0 picks 3 where the coarse level has more than
    ``AUTO_MAX_NODES`` nodes."""
    n = len(rest)
    adjacency = mesh_edge_graph(n, faces)
    if spacing == 0:
        agg, _ = auto_aggregate(adjacency) if levels == 2 else aggregate(adjacency, AUTO_MIN_SPACING)
    else:
        agg, _ = aggregate(adjacency, spacing)
    k = cotangent_stiffness(rest.astype(np.float64), faces, modulus.astype(np.float64), n)
    level = galerkin_level(adjacency, k, mass, ~pinned, agg)
    nc = len(level.mass)
    if levels == 3 or (levels == 0 and nc > AUTO_MAX_NODES):
        graph = aggregate_graph(adjacency, agg)
        inner, _ = auto_aggregate(graph, min_spacing=1)
        level.inner = galerkin_level(graph, level.stiffness, level.mass, np.ones(nc, dtype=bool), inner,
                                     overlap=True)
    return level


def template_key(*arrays: np.ndarray) -> str:
    """A digest of a garment's arrays: instances of one template share its coarse level."""
    h = hashlib.sha1()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
        h.update(str(a.shape).encode())
    return h.hexdigest()


def instance_templates(rest: np.ndarray, faces: np.ndarray, mass: np.ndarray, pinned: np.ndarray,
                       modulus: np.ndarray, instance_starts: np.ndarray, spacing: int,
                       levels: int) -> list[CoarseTemplate]:
    """Each instance's ``coarse_template`` (one object per distinct template, shared by its
    instances) of a model's particle arrays ``rest``, ``mass``, ``pinned`` and triangle arrays
    ``faces``, ``modulus``; ``instance_starts`` (instances + 1,) the instances' first particles.
    An instance's triangles are those whose first corner is its own."""
    starts = np.asarray(instance_starts)
    tri_inst = np.searchsorted(starts, faces[:, 0], side="right") - 1
    tri_starts = np.searchsorted(tri_inst, np.arange(len(starts)))
    templates: dict[str, CoarseTemplate] = {}
    blocks = []
    for k in range(len(starts) - 1):
        v0, v1 = int(starts[k]), int(starts[k + 1])
        tris = slice(tri_starts[k], tri_starts[k + 1])
        parts = (rest[v0:v1], faces[tris] - v0, mass[v0:v1], pinned[v0:v1], modulus[tris])
        key = template_key(*parts)
        if key not in templates:
            templates[key] = coarse_template(*parts, spacing=spacing, levels=levels)
        blocks.append(templates[key])
    return blocks


def template_slots(e: CoarseTemplate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(slot, coarse node ``J``, ``P2_Ja P2_Jb``) of every pair ``a > b`` of inner nodes that a
    coarse node's prolongation row ``J`` joins, in the inner template ``e``'s own band (slot
    ``a * (b_w + 1) + (a - b)`` in band order)."""
    n1, n2 = e.prolongation.shape
    w = e.band.shape[1]
    p2 = e.prolongation.tocsr()
    rank = np.empty(n2, dtype=np.int64)
    rank[e.order] = np.arange(n2)
    ls, ln, lv = [], [], []
    for j in range(n1):
        cols = rank[p2.indices[p2.indptr[j]:p2.indptr[j + 1]]]
        vals = p2.data[p2.indptr[j]:p2.indptr[j + 1]]
        ra, rb = np.meshgrid(cols, cols, indexing="ij")
        va = np.outer(vals, vals)
        low = ra > rb
        if np.any(ra[low] - rb[low] >= w):
            raise ValueError("galerkin_slots: a prolongation overlap lies outside the inner band")
        ls.append(ra[low] * w + (ra[low] - rb[low]))
        ln.append(np.full(int(low.sum()), j))
        lv.append(va[low])
    return np.concatenate(ls), np.concatenate(ln), np.concatenate(lv)


def galerkin_slots(exact: list[CoarseTemplate]) -> Any:
    """Where ``P2^T diag(d) P2`` adds to the inner levels' bands: a scipy CSR matrix with a row per
    slot of the flat band arrays (the instances' ``exact`` templates' bands, in order; diagonal
    slots stay empty) and a column per coarse node ``J`` of the instances, holding ``P2_Ja P2_Jb``
    for the slot of nodes ``a``, ``b``."""
    import scipy.sparse as sp

    slots, nodes, values = [], [], []
    node_off = band_off = 0
    local: dict[int, tuple] = {}
    for e in exact:
        n1, n2 = e.prolongation.shape
        if id(e) not in local:
            local[id(e)] = template_slots(e)
        ls, ln, lv = local[id(e)]
        slots.append(ls + band_off)
        nodes.append(ln + node_off)
        values.append(lv)
        node_off += n1
        band_off += n2 * e.band.shape[1]
    m = sp.coo_matrix((np.concatenate(values), (np.concatenate(slots), np.concatenate(nodes))),
                      shape=(band_off, node_off)).tocsr()
    m.sum_duplicates()
    return m
