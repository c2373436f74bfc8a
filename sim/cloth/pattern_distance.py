"""Where each particle lies in its sewing pattern, for self-contact's "close at rest" test.

Self-contact gives a pair of one piece of cloth that is closer than the contact radius at rest a
reduced radius (``self_contact.lists.rest_radius_code``), so that neighbours along the cloth
do not push each other apart. "Close at rest" means close *along the cloth*. A sewn garment's
rest shape is draped: the two layers of a fold (a gathered sleeve cap, cloth bunched at the
waist) lie millimetres apart in it but a fold's width apart along the cloth, and their pair must
keep the full radius, or they pass through each other at the first push. So for a garment with a
flat pattern the rest distance of a pair is measured in the pattern:

- both inside one panel (no seam or dart vertex): their distance in the flat panel, the length
  of the straight path along the cloth;
- otherwise: the larger of their distance in the rest shape and the shortest way to a seam
  from each side (``seam distance``, in the panel): any path along the cloth between panels
  crosses a seam.

A garment without a pattern keeps the rest shape's distance (panel -1, seam distance 0).
"""

from __future__ import annotations

import numpy as np


def pattern_positions(vertex_count: int, faces: np.ndarray,
                      flat: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Per particle: its panel (int32 (V,); -1 where it has no single flat position: a seam or
    dart vertex, or no pattern) and (u, v, seam distance) [m] (float32 (V, 3)).

    Args:
        vertex_count: V; faces: int (F, 3).
        flat: each face's corners in its flat panel [m], (F, 3, 2), or None.
    """
    panel = np.full(vertex_count, -1, np.int32)
    out = np.zeros((vertex_count, 3), np.float32)
    if flat is None:
        return panel, out
    f = np.asarray(faces, np.int64).reshape(-1)
    uv = np.asarray(flat, np.float64).reshape(-1, 2)
    face_of = np.repeat(np.arange(len(faces)), 3)
    # a vertex with one flat position: every corner of it at the same point of one panel
    first = np.full(vertex_count, -1, np.int64)
    first[f[::-1]] = np.arange(len(f))[::-1]
    spread = np.zeros(vertex_count)
    np.maximum.at(spread, f, np.linalg.norm(uv - uv[first[f]], axis=1))
    comp = _face_components(faces, flat)
    one = np.zeros(vertex_count, bool)
    used = first >= 0
    one[used] = spread[used] < 1e-7
    same_piece = np.ones(vertex_count, bool)
    np.logical_and.at(same_piece, f, comp[face_of] == comp[face_of[first[f]]])
    one &= same_piece
    panel[one] = comp[face_of[first[one]]]
    out[used, :2] = uv[first[used]]
    _seam_distances(out, panel, f, uv, comp[face_of])
    return panel, out


def _face_components(faces: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """Pieces of the flat pattern: faces joined through edges whose two corners have the same
    flat positions in both faces (a panel, numbered from 0)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, np.int64)
    uv = np.asarray(flat, np.float64)
    n = len(f)
    a = f.reshape(-1)
    b = np.roll(f, -1, axis=1).reshape(-1)
    ua = uv.reshape(-1, 2)
    ub = np.roll(uv, -1, axis=1).reshape(-1, 2)
    face = np.repeat(np.arange(n), 3)
    m = int(f.max(initial=0)) + 1
    key = a * m + b
    order = np.argsort(key)
    twin_key = b * m + a
    pos = np.clip(np.searchsorted(key[order], twin_key), 0, len(key) - 1)
    j = order[pos]
    found = key[j] == twin_key
    same = (np.linalg.norm(ua - ub[j], axis=1) < 1e-7) & (np.linalg.norm(ub - ua[j], axis=1) < 1e-7)
    rows, cols = face[found & same], face[j[found & same]]
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int32)


def _seam_distances(out: np.ndarray, panel: np.ndarray, f: np.ndarray, uv: np.ndarray,
                    corner_piece: np.ndarray) -> None:
    """``out[:, 2]``: each single-panel particle's flat distance to the nearest seam or dart
    vertex of its panel (0 for those vertices; a panel with none: far)."""
    from scipy.spatial import cKDTree

    seam_corner = panel[f] < 0
    for k in np.unique(panel[panel >= 0]):
        mine = np.flatnonzero(panel == k)
        pts = uv[seam_corner & (corner_piece == k)]
        if len(pts) == 0:
            out[mine, 2] = 1.0e3
            continue
        out[mine, 2] = cKDTree(pts).query(out[mine, :2])[0]
