"""Sewing-pattern panels built from rows of 3D arcs, sewn into one mesh with UVs.

A panel is a stack of *rows*: open polylines in 3D, ordered from the top of the panel to the
bottom, all running the same way (counter-clockwise seen from above for a body tube). Rows are
resampled at a target edge length ``h`` and consecutive rows are stitched into a triangle
strip. Rows of neighbouring panels share their end points exactly (the same floats), so
welding coincident points sews the seams. The panel's flattening is the pattern: u = arc length
along the row (centred), v = accumulated distance between row mid-points; these are the UVs
(in metres before packing), so UV distortion is only the small shear between rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WELD_TOL = 1e-7
"""Seam points are produced from identical floats; 0.1 µm only absorbs rounding [m]."""


@dataclass(frozen=True)
class Panel:
    """One pattern piece.

    Attributes:
        name: e.g. "front", "back".
        rows: open polylines [m], each shape (n_i, 3) with n_i >= 2, top to bottom.
        top: attachment set the first row belongs to (None: an inner row, e.g. a crotch loop).
        bottom: attachment set the last row belongs to (None: sewn to another panel).
        local_spacing: UV v of each point is its distance to the previous row (accumulated),
            instead of one v per row from the rows' mid-points: rows stay straight in UV only
            when they are parallel in 3D. For rows that converge (a crotch loop blending into
            a leg ring).
        marks: (row index, attachment name) pairs for inner rows, e.g. the shoulder line.
    """

    name: str
    rows: tuple[np.ndarray, ...]
    top: str | None = "waistband"
    bottom: str | None = "hem"
    local_spacing: bool = False
    marks: tuple[tuple[int, str], ...] = ()


def arc_length(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length [m] of a polyline (N, 3) → (N,), starting at 0."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def resample(points: np.ndarray, h: float, *, min_segments: int = 1) -> np.ndarray:
    """Resample an open polyline at near-uniform spacing ``h`` [m], keeping both end points.

    Args:
        points: polyline (N, 3) [m].
        h: target spacing [m].
        min_segments: lower bound on the number of segments.

    Returns:
        (n + 1, 3) points, n = max(min_segments, round(length / h)); end points are the
        exact input end points (so seams weld).
    """
    s = arc_length(points)
    n = max(min_segments, int(round(s[-1] / h)))
    t = np.linspace(0.0, s[-1], n + 1)
    out = np.stack([np.interp(t, s, points[:, k]) for k in range(3)], axis=1)
    out[0], out[-1] = points[0], points[-1]
    return out


def _distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance [m] of every point (N, 3) to an open polyline (M, 3)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.einsum("nmk,mk->nm", points[:, None] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-18)
    q = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.linalg.norm(points[:, None] - q, axis=2).min(axis=1)


def stitch(n_a: int, s_a: np.ndarray, n_b: int, s_b: np.ndarray) -> np.ndarray:
    """Triangulate the strip between two open rows by advancing along normalised arc length.

    Row A (upper) has local indices 0..n_a-1, row B (lower) n_a..n_a+n_b-1. Every triangle is
    (A_i, B_j, next), which keeps a consistent orientation.

    Args:
        n_a, n_b: numbers of points.
        s_a, s_b: normalised arc-length parameters in [0, 1], shapes (n_a,), (n_b,).

    Returns:
        faces (n_a + n_b - 2, 3), int64, local indices.
    """
    i = j = 0
    faces = []
    while i < n_a - 1 or j < n_b - 1:
        advance_b = i == n_a - 1 or (j < n_b - 1 and s_b[j + 1] <= s_a[i + 1])
        if advance_b:
            faces.append((i, n_a + j, n_a + j + 1))
            j += 1
        else:
            faces.append((i, n_a + j, i + 1))
            i += 1
    return np.asarray(faces, dtype=np.int64)


@dataclass(frozen=True)
class SewnMesh:
    """Output of ``sew``: welded mesh, per-panel UVs in metres."""

    vertices: np.ndarray  # (V, 3) float64 [m]
    faces: np.ndarray  # (F, 3) int64
    uvs_m: np.ndarray  # (U, 2) float64 [m], panel-local
    uv_faces: np.ndarray  # (F, 3) int64
    panel_ids: np.ndarray  # (F,) int64
    uv_panel: np.ndarray  # (U,) panel of each UV vertex
    row_vertices: tuple[tuple[np.ndarray, ...], ...]  # per panel, per row: welded vertex ids


def sew(panels: list[Panel]) -> SewnMesh:
    """Stitch every panel's rows, weld shared seam points, and unroll each panel into UVs.

    Args:
        panels: rows already resampled (use ``resample``).

    Returns:
        The welded mesh with seam-split UVs.
    """
    pts, faces, uvs, pids, uv_panel, offsets = [], [], [], [], [], []
    base = 0
    for p_id, panel in enumerate(panels):
        rows = panel.rows
        starts = np.cumsum([0] + [len(r) for r in rows])
        v = 0.0
        prev_mid = None
        prev_v = np.zeros(0)
        row_offsets = []
        for k, r in enumerate(rows):
            s = arc_length(r)
            mid = np.array([np.interp(s[-1] / 2, s, r[:, c]) for c in range(3)])
            if prev_mid is not None:
                v -= float(np.linalg.norm(mid - prev_mid))
            prev_mid = mid
            vs = np.full_like(s, v)
            if panel.local_spacing and k > 0:
                # v follows the local distance to the previous row (rows not parallel)
                sp = arc_length(rows[k - 1])
                d = _distance_to_polyline(r, rows[k - 1])
                w = np.ones(min(7, len(d) // 2 * 2 - 1)) / min(7, len(d) // 2 * 2 - 1)
                d = np.convolve(np.pad(d, len(w) // 2, mode="edge"), w, mode="valid")  # denoise
                vs = np.interp(s / s[-1], sp / sp[-1], prev_v) - d
            prev_v = vs
            uvs.append(np.stack([s - s[-1] / 2, vs], axis=1))
            pts.append(r)
            uv_panel.append(np.full(len(r), p_id))
            row_offsets.append(base + starts[k])
            if k > 0:
                a = rows[k - 1]
                sa = arc_length(a)
                f = stitch(len(a), sa / sa[-1], len(r), s / s[-1])
                local = np.where(f < len(a), f + base + starts[k - 1], f - len(a) + base + starts[k])
                faces.append(local)
                pids.append(np.full(len(f), p_id))
        offsets.append((row_offsets, [len(r) for r in rows]))
        base += starts[-1]
    allp = np.concatenate(pts)
    key = np.round(allp / WELD_TOL).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    # renumber welded vertices in order of first appearance (deterministic, cache friendly)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    vid = rank[inverse]
    vertices = allp[first[order]]
    corner = np.concatenate(faces)
    row_vertices = tuple(tuple(vid[o:o + n] for o, n in zip(ro, ns, strict=True)) for ro, ns in offsets)
    return SewnMesh(vertices=vertices, faces=vid[corner], uvs_m=np.concatenate(uvs), uv_faces=corner,
                    panel_ids=np.concatenate(pids), uv_panel=np.concatenate(uv_panel),
                    row_vertices=row_vertices)


def pack_uvs(uvs_m: np.ndarray, uv_panel: np.ndarray, *, margin: float = 0.02) -> np.ndarray:
    """Pack panel-local UVs [m] into [0, 1]² with one common scale (shelf packing).

    Panels keep their relative sizes (one texel covers the same cloth area everywhere).

    Args:
        uvs_m: (U, 2) [m]; uv_panel: (U,) panel id of each UV vertex.
        margin: gap between panels and around the border, as a fraction of the unit square
            (0.02 = 5 px at 256²).

    Returns:
        (U, 2) float32 in [margin, 1 − margin].
    """
    ids = np.unique(uv_panel)
    lo = np.array([uvs_m[uv_panel == i].min(0) for i in ids])
    size = np.array([uvs_m[uv_panel == i].max(0) for i in ids]) - lo
    gap = margin * max(size[:, 0].sum(), size[:, 1].max())
    target_w = max(size[:, 0].max(), np.sqrt((size + gap).prod(axis=1).sum()) * 1.1)
    order = np.argsort(-size[:, 1], kind="stable")
    place = np.zeros_like(size)
    x = y = shelf_h = 0.0
    for i in order:
        if x > 0 and x + size[i, 0] > target_w:
            x, y, shelf_h = 0.0, y + shelf_h + gap, 0.0
        place[i] = (x, y)
        x += size[i, 0] + gap
        shelf_h = max(shelf_h, size[i, 1])
    total = max((place + size).max(axis=0).max(), 1e-9)
    scale = (1.0 - 2.0 * margin) / total
    out = np.empty_like(uvs_m)
    for k, i in enumerate(ids):
        m = uv_panel == i
        out[m] = (uvs_m[m] - lo[k] + place[k]) * scale + margin
    return out.astype(np.float32)
