"""Hems: the folded, stitched bands along a garment's openings.

A sewn garment's free edges are not raw cloth: a t-shirt's neckline has a neckband, its sleeves
and bottom a folded hem, trousers a waistband and hems at the legs (typically 1.5-3 cm wide).
A double-fold hem (the raw edge turned under twice and stitched) is three layers of fabric:
they carry three times the load, weigh three times as much and bend three times as hard
(layers stitched side by side, not bonded: bending adds per layer). A template lays a band
``width`` wide along every boundary loop of its mesh and gives each face its share of the band's
``layers`` (``Garment.face_layers``); the simulator scales the face's mass, membrane moduli and
bending by it (``ClothModelBuilder.add_cloth``).

Distance is measured along the mesh: Dijkstra over the edges from every boundary vertex
(``scipy.sparse.csgraph``), so a face near an opening in space but far from it on the cloth
(an armhole's neighbour across a fold) is not marked. A face takes layers in proportion to the
share of its area within ``width`` of the boundary, the distance interpolated linearly over the
face from its corners (``band_fraction``): ``1 + (layers - 1) * share``. The hem's mass is then
``width`` times the openings' length at any mesh resolution (a face all hem or none by the mean
of its corners' distances gives 0.89-1.45 times that, depending on the resolution).
"""

from __future__ import annotations

import numpy as np

HEM_WIDTH = 0.02
"""Default hem width [m] of the templates (a t-shirt's neckband and hems are 1.5-2.5 cm)."""
HEM_RULE = "area share"
"""How a face's layers follow from the band (``hem_face_layers``): by the share of its area inside
it. Datasets record it (``sim.simulate.simulator_defaults``), so a dataset made under another rule
is not continued."""
HEM_LAYERS = 3.0
"""Default layers of fabric in a hem: a double-fold hem's three (with 3, 12 substeps pass the 5k
t-shirt's population of random walks and runs 134 of 144 times, with 2 layers 131 times;
docs/BENCHMARKS.md)."""


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


def band_fraction(d: np.ndarray, width: float) -> np.ndarray:
    """Share of each triangle's area where a function linear over it, ``d`` (F, 3) at its
    corners, is below ``width``: 0 where every corner is at or above it, 1 where every corner is
    below, between them the area of the corner triangle (one corner below) or its complement
    (two below) cut off by the level line ``d = width``."""
    d = np.sort(np.asarray(d, dtype=np.float64), axis=1)
    d0, d1, d2 = d[:, 0], d[:, 1], d[:, 2]
    w = float(width)
    out = np.zeros(len(d))
    out[d2 <= w] = 1.0
    one = (d0 < w) & (w <= d1)  # a corner triangle at corner 0 is inside
    with np.errstate(divide="ignore", invalid="ignore"):
        out[one] = ((w - d0[one]) ** 2 / ((d1[one] - d0[one]) * (d2[one] - d0[one])))
        two = (d1 < w) & (w < d2)  # all but a corner triangle at corner 2
        out[two] = 1.0 - (d2[two] - w) ** 2 / ((d2[two] - d0[two]) * (d2[two] - d1[two]))
    return np.clip(out, 0.0, 1.0)


def hem_face_layers(vertices: np.ndarray, faces: np.ndarray, width: float = HEM_WIDTH,
                    layers: float = HEM_LAYERS) -> np.ndarray:
    """Layers of fabric per face (F,), float32: ``1 + (layers - 1) * share``, ``share`` the part
    of the face's area within ``width`` [m] of the mesh's boundary along the cloth
    (``band_fraction`` of the corners' ``distance_to_boundary``): ``layers`` inside the band, 1
    beyond it and everywhere when ``width`` is 0, between them on the faces the band's edge
    crosses."""
    f = np.asarray(faces)
    out = np.ones(len(f), np.float32)
    if width <= 0.0 or layers == 1.0:
        return out
    d = _distance(vertices, *_edges(f))
    share = band_fraction(d[f], width)
    return (1.0 + (float(layers) - 1.0) * share).astype(np.float32)
