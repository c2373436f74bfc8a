"""Sewing-pattern panels built from rows of 3D arcs, sewn into one mesh with UVs.

A panel is a stack of *rows*: open polylines in 3D, ordered from the top of the panel to the
bottom, all running the same way (counter-clockwise seen from above for a body tube). Rows are
resampled at a target edge length ``h`` and consecutive rows are stitched into a triangle
strip. Rows of neighbouring panels share their end points exactly (the same floats), so
welding coincident points sews the seams. Each panel also gets a first flattening from its
rows: u = arc length along the row (centred), v = accumulated distance between rows (in
metres); ``sim.garments.uv`` relaxes it (ARAP) into the panel's pattern piece and packs the UVs.
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
        stagger: move the inner points of every odd inner row half a spacing along it
            (``stagger``), so consecutive rows interleave and the strips triangulate into
            near-equilateral triangles instead of split quads (diagonals 1.32 h; folds of a
            split-quad mesh prefer its diagonals). The first and last rows, which seams and
            attachments share, keep their points.
    """

    name: str
    rows: tuple[np.ndarray, ...]
    top: str | None = "waistband"
    bottom: str | None = "hem"
    local_spacing: bool = False
    marks: tuple[tuple[int, str], ...] = ()
    stagger: bool = True


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


def stagger(row: np.ndarray) -> np.ndarray:
    """A resampled row (n + 1, 3) with its inner points replaced by the n mid-points between
    consecutive points, on the curve: the 4-point subdivision rule (-p0 + 9 p1 + 9 p2 - p3) / 16,
    exact for cubics (a closed row, first point == last, wraps around; an open one mirrors its
    end points). Returns (n + 2, 3): the end points, then half, full, ..., full, half spacings."""
    r = np.asarray(row, np.float64)
    n = len(r) - 1
    if n < 2:
        return r.copy()
    closed = bool(np.array_equal(r[0], r[-1]))
    if closed:
        ext = np.concatenate([r[-2:-1], r, r[1:2]])
    else:
        ext = np.concatenate([2 * r[:1] - r[1:2], r, 2 * r[-1:] - r[-2:-1]])
    mid = (-ext[:-3] + 9 * ext[1:-2] + 9 * ext[2:-1] - ext[3:]) / 16.0
    out = np.concatenate([r[:1], mid, r[-1:]])
    out[0], out[-1] = row[0], row[-1]
    return out


STAGGER_MIN_ANGLE = 20.0
"""[deg] A row is staggered unless that makes its strips' smallest corner angle worse than the
unstaggered row's and below this (where a seam's end points shift sideways from row to row, a
half segment at the row's end would make a sliver)."""


def corner_angles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Corner angles [deg] of every triangle, shape (F, 3) (corner k at ``faces[:, k]``)."""
    t = np.asarray(vertices, np.float64)[faces]
    out = []
    for k in range(3):
        u, w = t[:, (k + 1) % 3] - t[:, k], t[:, (k + 2) % 3] - t[:, k]
        c = (u * w).sum(1) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-30)
        out.append(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
    return np.stack(out, axis=1)


def _strip_min_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest corner angle [deg] of ``stitch(a, b)``."""
    return float(corner_angles(np.concatenate([a, b]), stitch(a, b)).min())


def _staggered(rows: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """``rows`` with every odd inner row staggered (``stagger``) where that makes no sliver
    (``STAGGER_MIN_ANGLE``); the first and last rows are kept."""
    out = list(rows)
    for k in range(1, len(rows) - 1, 2):
        cand = stagger(rows[k])
        new = min(_strip_min_angle(rows[k - 1], cand), _strip_min_angle(cand, rows[k + 1]))
        if new >= STAGGER_MIN_ANGLE or new >= min(_strip_min_angle(rows[k - 1], rows[k]),
                                                  _strip_min_angle(rows[k], rows[k + 1])):
            out[k] = cand
    return tuple(out)


def _distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance [m] of every point (N, 3) to an open polyline (M, 3)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.einsum("nmk,mk->nm", points[:, None] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-18)
    q = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.linalg.norm(points[:, None] - q, axis=2).min(axis=1)


def stitch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Triangulate the strip between two open rows, shortest diagonal first.

    Row A (upper) has local indices 0..n_a-1, row B (lower) n_a..n_a+n_b-1. Every triangle is
    (A_i, B_j, next), which keeps a consistent orientation. At each step the strip advances on
    the row whose new diagonal is shorter (|A_i B_j+1| vs |A_i+1 B_j|; Fuchs, Kedem & Uselton
    1977, greedy form): where the rows' samples do not line up (a sleeve cap against an arm
    ring) this avoids the fans of slivers that matching by arc length makes.

    Args:
        a, b: the rows' points [m], shapes (n_a, 3), (n_b, 3), both running the same way.

    Returns:
        faces (n_a + n_b - 2, 3), int64, local indices.
    """
    n_a, n_b = len(a), len(b)
    i = j = 0
    faces = []
    while i < n_a - 1 or j < n_b - 1:
        if i == n_a - 1:
            advance_b = True
        elif j == n_b - 1:
            advance_b = False
        else:
            advance_b = float(np.sum((a[i] - b[j + 1]) ** 2)) <= float(np.sum((a[i + 1] - b[j]) ** 2))
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
        if panel.stagger:
            rows = _staggered(rows)
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
                f = stitch(a, r)
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
