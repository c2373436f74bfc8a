"""Hems: the folded, stitched bands along a garment's openings.

A sewn garment's free edges are not raw cloth: a t-shirt's neckline has a neckband, its sleeves
and bottom a folded hem, trousers a waistband and hems at the legs (typically 1.5-3 cm wide).
A double-fold hem (the raw edge turned under twice and stitched) is three layers of fabric:
they carry three times the load, weigh three times as much and bend three times as hard
(layers stitched side by side, not bonded: bending adds per layer). A template marks every face
within ``width`` of a boundary loop of its mesh with ``layers`` layers (``Garment.face_layers``);
the simulator scales the face's mass, membrane moduli and bending by it
(``ClothModelBuilder.add_cloth``).

Distance is measured along the mesh: Dijkstra over the edges from every boundary vertex
(``scipy.sparse.csgraph``), so a face near an opening in space but far from it on the cloth
(an armhole's neighbour across a fold) is not marked. A face belongs to the hem when the mean of
its corners' distances is below ``width``: a band of ``width`` whatever the mesh resolution,
rounded to a row of triangles.
"""

from __future__ import annotations

import numpy as np

HEM_WIDTH = 0.02
"""Default hem width [m] of the templates (a t-shirt's neckband and hems are 1.5-2.5 cm)."""
HEM_LAYERS = 3.0
"""Default layers of fabric in a hem: a double-fold hem's three (session 38: with 3, 12 substeps
pass the 5k t-shirt's population of random walks and runs 134 of 144 times, with 2 131)."""


def _edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's undirected edges (E, 2) and which of them lie on the boundary (one face)."""
    from sim.quality import unique_edges

    edges, uses = unique_edges(np.asarray(faces), counts=True)
    return edges, uses == 1


def boundary_vertices(faces: np.ndarray) -> np.ndarray:
    """Sorted indices of the vertices on an edge with one face."""
    edges, border = _edges(faces)
    return np.unique(edges[border])


def distance_to_boundary(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per vertex, the shortest path [m] along mesh edges to a boundary vertex (inf on a closed
    component)."""
    return _distance(vertices, *_edges(faces))


def _distance(vertices: np.ndarray, edges: np.ndarray, border: np.ndarray) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    v = np.asarray(vertices, dtype=np.float64)
    length = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
    n = len(v)
    sources = np.unique(edges[border])
    if len(sources) == 0:
        return np.full(n, np.inf)
    graph = coo_matrix((length, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    return dijkstra(graph, directed=False, indices=sources, min_only=True)


def hem_face_layers(vertices: np.ndarray, faces: np.ndarray, width: float = HEM_WIDTH,
                    layers: float = HEM_LAYERS) -> np.ndarray:
    """Layers of fabric per face (F,), float32: ``layers`` on the faces whose corners lie within
    ``width`` [m] of the mesh's boundary on average and on every face with an edge on the
    boundary (a mesh coarser than the hem keeps one row of it), 1 elsewhere (everywhere when
    ``width`` is 0)."""
    f = np.asarray(faces)
    out = np.ones(len(f), np.float32)
    if width <= 0.0 or layers == 1.0:
        return out
    edges, border = _edges(f)
    d = _distance(vertices, edges, border)
    key = np.array([len(d), 1], np.int64)
    sides = np.sort(np.stack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], axis=1), axis=2).astype(np.int64)
    on_opening = np.isin(sides @ key, edges[border].astype(np.int64) @ key).any(axis=1)
    out[(d[f].mean(axis=1) < width) | on_opening] = layers
    return out
