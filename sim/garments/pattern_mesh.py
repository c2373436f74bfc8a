"""A sewing pattern's flat mesh: every panel triangulated in its own plane, seams sampled so that
both sides match vertex for vertex (``mesh_pattern``), and the vertex groups sewing joins.

Each edge of a panel gets ``n`` equal arc-length segments, ``n`` about its length over the edge
length ``h``; both edges of a seam (or dart) get the same ``n`` (the longer one's), so a sleeve
cap eased into a shorter armhole has slightly shorter segments on the armhole side. The panel's
outline samples are the boundary of its triangulation (``sim.garments.flat_mesh``); the flat
coordinates are the pattern itself, so the UVs have no distortion by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.garments.flat_mesh import mesh_polygon
from sim.garments.pattern import Pattern


@dataclass(frozen=True)
class PatternMesh:
    """The unsewn mesh of a pattern: panels side by side, nothing joined.

    Attributes:
        flat: panel coordinates [m] of every vertex, shape (N, 2).
        placed: positions around the rest body before sewing [m], shape (N, 3).
        triangles: int32 (F, 3) into the N vertices, counter-clockwise in the panel plane.
        vertex_panel: panel index of each vertex, (N,); face_panel: of each face, (F,).
        edge_vertices: ``{(panel name, edge index): vertex indices along the edge, start to end}``.
        pairs: int (P, 2) vertex pairs that sewing joins (both sides of every seam and dart).
        groups: sewn vertex of each vertex, (N,): vertices joined by ``pairs`` (transitively)
            share a group; groups are numbered by first appearance.
    """

    flat: np.ndarray
    placed: np.ndarray
    triangles: np.ndarray
    vertex_panel: np.ndarray
    face_panel: np.ndarray
    edge_vertices: dict
    pairs: np.ndarray
    groups: np.ndarray

    @property
    def group_count(self) -> int:
        return int(self.groups.max()) + 1

    def sewn_faces(self) -> np.ndarray:
        """Faces of the sewn mesh: ``groups[triangles]``, int32 (F, 3)."""
        return self.groups[self.triangles].astype(np.int32)

    def merge(self, x: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        """Per-group mean of per-vertex values ``x`` (N, k): the sewn mesh's (G, k); with
        ``weights`` (N,) >= 0 the weighted mean (a group of zero weights: the plain mean)."""
        x = np.asarray(x, np.float64)
        w = np.ones(len(x)) if weights is None else np.asarray(weights, np.float64)
        total = np.bincount(self.groups, weights=w, minlength=self.group_count)
        w = np.where(total[self.groups] > 0, w, 1.0)
        out = np.zeros((self.group_count, x.shape[1]))
        np.add.at(out, self.groups, x * w[:, None])
        return out / np.bincount(self.groups, weights=w, minlength=self.group_count)[:, None]


def edge_segments(pattern: Pattern, h: float) -> dict[tuple[str, int], int]:
    """Segments of every edge at edge length ``h`` [m]; both edges of a seam get the larger count."""
    length = {(p.name, i): p.edge_length(i) for p in pattern.panels for i in range(len(p.edges))}
    n = {k: max(1, int(round(L / h))) for k, L in length.items()}
    for s in pattern.seams:
        n[s.a] = n[s.b] = max(n[s.a], n[s.b])
    return n


def mesh_pattern(pattern: Pattern, h: float) -> PatternMesh:
    """Triangulate every panel of ``pattern`` at edge length ``h`` [m] and find the seams' pairs.

    Raises:
        ValueError: a panel that cannot be meshed (its outline crosses itself).
    """
    counts = edge_segments(pattern, h)
    flats, placed, tris, vpanel, fpanel = [], [], [], [], []
    edge_vertices: dict[tuple[str, int], np.ndarray] = {}
    offset = 0
    for k, p in enumerate(pattern.panels):
        pieces, starts = [], []
        for i in range(len(p.edges)):
            starts.append(sum(len(q) for q in pieces))
            pieces.append(p.edge_curve(i, counts[(p.name, i)])[:-1])
        boundary = np.concatenate(pieces)
        nb = len(boundary)
        try:
            m = mesh_polygon(boundary, h)
        except ValueError as e:
            raise ValueError(f"pattern {pattern.name!r}, panel {p.name!r}: {e}") from None
        for i in range(len(p.edges)):
            idx = starts[i] + np.arange(counts[(p.name, i)] + 1)
            edge_vertices[(p.name, i)] = offset + idx % nb
        flats.append(m.points)
        placed.append(p.placement.place(m.points))
        tris.append(m.triangles + offset)
        vpanel.append(np.full(len(m.points), k, np.int32))
        fpanel.append(np.full(len(m.triangles), k, np.int32))
        offset += len(m.points)
    pairs = []
    for s in pattern.seams:
        a, b = edge_vertices[s.a], edge_vertices[s.b]
        pairs.append(np.stack([a, b[::-1] if s.reverse else b], axis=1))
    pairs_arr = np.concatenate(pairs) if pairs else np.zeros((0, 2), np.int64)
    return PatternMesh(flat=np.concatenate(flats), placed=np.concatenate(placed),
                       triangles=np.concatenate(tris).astype(np.int32),
                       vertex_panel=np.concatenate(vpanel), face_panel=np.concatenate(fpanel),
                       edge_vertices=edge_vertices, pairs=pairs_arr,
                       groups=join_groups(offset, pairs_arr))


def join_groups(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected components of ``n`` vertices joined by ``pairs``, numbered by first vertex."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    p = np.asarray(pairs, np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(p)), (p[:, 0], p[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))  # number groups by their first vertex
    return order[inverse].astype(np.int64)

