"""Triangulating a flat panel: near-equilateral triangles of a given edge length inside a closed
outline whose sampled points are kept as the mesh boundary (``mesh_polygon``).

Interior points start on a hexagonal lattice of spacing ``h`` (the density of equilateral
triangles of edge ``h``: one point per ``sqrt(3)/2 h^2``), minus the points closer than
``BOUNDARY_CLEARANCE * h`` to the outline. The points are triangulated by Delaunay
(``scipy.spatial.Delaunay``); boundary segments that Delaunay misses are recovered by edge flips
(Sloan 1993, "A fast algorithm for generating constrained Delaunay triangulations", Comput.
Struct. 47(3)), then restored to constrained Delaunay by Lawson flips; triangles outside the
outline are dropped. Smoothing moves each interior point to the area-weighted mean of its
triangles' circumcentres (optimal Delaunay triangulation smoothing, Chen 2004, "Mesh smoothing
schemes based on optimal Delaunay triangulations", 13th International Meshing Roundtable),
undoing moves that would flatten a triangle, and flips edges back to constrained Delaunay;
boundary points never move. The result is checked to be a manifold disk bounded by the
outline (``verify_disk``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

# Interior lattice points closer than this many ``h`` to the outline are dropped: a boundary
# row of spacing ``h`` and the first lattice row then sit about an equilateral triangle's
# height (0.87 h) apart once smoothing has spread them.
BOUNDARY_CLEARANCE = 0.55
# An interior point's smoothing move is undone when it would leave one of its triangles with
# less than this fraction of the area of an equilateral triangle of edge ``h`` (sqrt(3)/4 h^2).
MIN_AREA_FRACTION = 0.1
# Relative tolerance of the final area check (sum of triangle areas against the outline's).
AREA_RTOL = 1e-9


@dataclass(frozen=True)
class FlatMesh:
    """A triangulated flat panel.

    Attributes:
        points: (M, 2) float64 [m]; ``points[:N]`` are the given boundary points, bit for bit,
            in the same order; the rest are interior points.
        triangles: (T, 3) int32 indices into ``points``, counter-clockwise in (x, y).
    """

    points: np.ndarray
    triangles: np.ndarray


def polygon_area(points: np.ndarray) -> float:
    """Signed area [m^2] of the closed polygon ``points`` (N, 2): positive when counter-clockwise."""
    p = np.asarray(points, np.float64)
    q = np.roll(p, -1, axis=0)
    return 0.5 * float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))


def mesh_polygon(boundary: np.ndarray, h: float, *, smoothing_iterations: int = 6) -> FlatMesh:
    """Triangulate the inside of a closed outline with triangles of edge length about ``h``.

    Args:
        boundary: (N, 2) [m] points of a closed loop, counter-clockwise, last point != first.
            Segment lengths of about ``h`` (0.5 h to 1.5 h) give near-equilateral triangles;
            longer segments give triangles elongated along them.
        h: target edge length [m].
        smoothing_iterations: rounds of interior-point smoothing, each followed by edge flips
            back to the constrained Delaunay triangulation.

    Returns:
        The mesh: every boundary segment ``(i, i + 1 mod N)`` is an edge of exactly one
        triangle, the triangles cover the outline's inside exactly once (a manifold disk).

    Raises:
        ValueError: ``h`` is not positive, the outline has fewer than 3 points, repeated
            points, crosses or touches itself, or is clockwise.
    """
    boundary = np.asarray(boundary, np.float64)
    check_outline(boundary, h)
    n = len(boundary)
    points = np.concatenate([boundary, lattice_points(boundary, h)])
    mesh = constrained_delaunay(points, n)
    min_area = MIN_AREA_FRACTION * np.sqrt(3.0) / 4.0 * h * h
    for _ in range(smoothing_iterations):
        inside = mesh.triangles[mesh.inside]
        moved = odt_positions(mesh.points, inside, n)
        mesh.points = keep_valid_moves(mesh.points, moved, inside, n, min_area)
        lawson_flips(mesh.points, mesh.triangles, mesh.neighbors, n)
    points, triangles = mesh.points[:len(points)].copy(), mesh.triangles[mesh.inside]
    verify_disk(points, triangles, n)
    return FlatMesh(points=points, triangles=triangles.astype(np.int32))


# ----------------------------------------------------------------------------------------------
# input checks


def check_outline(boundary: np.ndarray, h: float) -> None:
    """Raise ``ValueError`` unless ``boundary`` (N, 2) is a simple counter-clockwise loop."""
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"edge length h must be a positive number, got {h!r}")
    if boundary.ndim != 2 or boundary.shape[1] != 2 or len(boundary) < 3:
        raise ValueError(f"boundary must be an (N, 2) array with N >= 3, got shape {boundary.shape}")
    if not np.all(np.isfinite(boundary)):
        raise ValueError("boundary has non-finite coordinates")
    seg = np.roll(boundary, -1, axis=0) - boundary
    length = np.hypot(seg[:, 0], seg[:, 1])
    if np.any(length == 0):
        i = int(np.argmin(length))
        raise ValueError(f"boundary point {i} repeats point {(i + 1) % len(boundary)}")
    crossing = first_crossing(boundary)
    if crossing is not None:
        i, j = crossing
        nb = len(boundary)
        raise ValueError(f"boundary crosses or touches itself: segments {i}-{(i + 1) % nb} "
                         f"and {j}-{(j + 1) % nb}")
    area = polygon_area(boundary)
    if area <= 0:
        raise ValueError(f"boundary is clockwise or encloses no area (signed area {area:.6g} m^2); "
                         "pass the outline counter-clockwise")


def _orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Twice the signed area of triangles (a, b, c), rows of (K, 2) arrays: > 0 counter-clockwise."""
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def first_crossing(boundary: np.ndarray) -> tuple[int, int] | None:
    """First pair of segments ``(i, j)`` of the loop that cross or touch, or None if it is simple.

    Neighbouring segments count only when they fold back onto each other (a zero angle).
    """
    nb = len(boundary)
    a, b = boundary, np.roll(boundary, -1, axis=0)
    # Candidate pairs: segments whose midpoints are within the longest segment length.
    length = np.hypot(*(b - a).T)
    pairs = cKDTree(0.5 * (a + b)).query_pairs(float(length.max()) * (1 + 1e-9), output_type="ndarray")
    pairs = np.sort(pairs, axis=1)
    i, j = pairs[:, 0], pairs[:, 1]
    adjacent = (j - i == 1) | ((i == 0) & (j == nb - 1))
    d1, d2 = _orient(a[i], b[i], a[j]), _orient(a[i], b[i], b[j])
    d3, d4 = _orient(a[j], b[j], a[i]), _orient(a[j], b[j], b[i])
    proper = (d1 * d2 < 0) & (d3 * d4 < 0)
    touch = np.zeros(len(i), bool)
    for d, p, s, e in ((d1, a[j], a[i], b[i]), (d2, b[j], a[i], b[i]),
                       (d3, a[i], a[j], b[j]), (d4, b[i], a[j], b[j])):
        on = (d == 0) & np.all((p >= np.minimum(s, e)) & (p <= np.maximum(s, e)), axis=1)
        touch |= on
    # Neighbours share a point; they cross only if collinear and pointing back (a spike).
    ii = np.where(j - i == 1, i, j)  # the first of the two consecutive segments
    u, v = b[ii] - a[ii], b[(ii + 1) % nb] - a[(ii + 1) % nb]
    spike = (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0] == 0) & (np.sum(u * v, axis=1) < 0)
    bad = np.where(adjacent, spike, proper | touch)
    if not np.any(bad):
        return None
    k = np.flatnonzero(bad)
    k = k[np.lexsort((j[k], i[k]))[0]]
    return int(i[k]), int(j[k])


# ----------------------------------------------------------------------------------------------
# interior seeds


def lattice_points(boundary: np.ndarray, h: float) -> np.ndarray:
    """Hexagonal lattice points (K, 2) of spacing ``h`` inside the outline, away from its edge.

    Rows run along x, ``sqrt(3)/2 h`` apart, every other row shifted by ``h/2``; the lattice is
    anchored at the outline's lower-left bounding-box corner, so it is deterministic.
    """
    lo, hi = boundary.min(axis=0), boundary.max(axis=0)
    dy = np.sqrt(3.0) / 2.0 * h
    ys = lo[1] + dy * (1.0 + np.arange(int(np.ceil((hi[1] - lo[1]) / dy))))
    a, b = boundary, np.roll(boundary, -1, axis=0)
    # Scanline: where each row crosses each segment (half-open in y, so a vertex counts once).
    ylo, yhi = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
    crosses = (ys[:, None] >= ylo[None]) & (ys[:, None] < yhi[None])
    rows, segs = np.nonzero(crosses)
    t = (ys[rows] - a[segs, 1]) / (b[segs, 1] - a[segs, 1])
    xs = a[segs, 0] + t * (b[segs, 0] - a[segs, 0])
    order = np.lexsort((xs, rows))
    rows, xs = rows[order], xs[order]
    out = []
    starts = np.searchsorted(rows, np.arange(len(ys) + 1))
    for r in range(len(ys)):
        x = xs[starts[r]:starts[r + 1]]
        shift = 0.5 * h * ((r + 1) % 2)
        for x0, x1 in zip(x[0::2], x[1::2], strict=True):
            k0, k1 = np.ceil((x0 - lo[0] - shift) / h), np.floor((x1 - lo[0] - shift) / h)
            k = np.arange(k0, k1 + 1)
            out.append(np.stack([lo[0] + shift + h * k, np.full(len(k), ys[r])], axis=1))
    if not out:
        return np.zeros((0, 2))
    pts = np.concatenate(out)
    return pts[clear_of_boundary(pts, boundary, BOUNDARY_CLEARANCE * h)]


def clear_of_boundary(points: np.ndarray, boundary: np.ndarray, r: float) -> np.ndarray:
    """Bool (K,): which of ``points`` (K, 2) are at least ``r`` [m] from the closed polyline."""
    a, b = boundary, np.roll(boundary, -1, axis=0)
    half = 0.5 * float(np.hypot(*(b - a).T).max())
    tree = cKDTree(0.5 * (a + b))
    d_mid, _ = tree.query(points)
    # Every point of a segment is within half the longest segment of that segment's midpoint.
    clear = d_mid >= r + half
    near = np.flatnonzero(~clear)
    p = points[near]
    # The nearest segment's midpoint is within ``d_mid + half``: look at all midpoints that close.
    radius = d_mid[near] + half
    k = min(len(a), 8)
    while len(near):
        dist, idx = tree.query(p, k=k)
        dist, idx = dist.reshape(len(p), -1), idx.reshape(len(p), -1)
        ab = b[idx] - a[idx]
        t = np.einsum("pkc,pkc->pk", p[:, None] - a[idx], ab) / np.einsum("pkc,pkc->pk", ab, ab)
        foot = a[idx] + np.clip(t, 0.0, 1.0)[..., None] * ab
        d = np.hypot(*(p[:, None] - foot).transpose(2, 0, 1)).min(axis=1)
        if k == len(a) or np.all(dist[:, -1] > radius):
            clear[near] = d >= r
            break
        k = min(len(a), 2 * k)
    return clear


# ----------------------------------------------------------------------------------------------
# constrained triangulation


@dataclass
class FramedTriangulation:
    """A triangulation of a panel's points and four far frame points around them.

    Attributes:
        points: (M + 4, 2) [m]: the panel's points, then the frame's corners.
        triangles: (T, 3) counter-clockwise vertex indices.
        neighbors: (T, 3): the triangle across the edge opposite each vertex, -1 on the hull.
        inside: bool (T,): triangles inside the outline. Flipping an edge that is no boundary
            segment keeps both of its triangles on their side, so this holds across flips.
    """

    points: np.ndarray
    triangles: np.ndarray
    neighbors: np.ndarray
    inside: np.ndarray


def constrained_delaunay(points: np.ndarray, n: int) -> FramedTriangulation:
    """The constrained Delaunay triangulation of ``points`` (M, 2) whose first ``n`` form the loop.

    Delaunay, then every boundary segment Delaunay lacks is recovered by flips and the
    triangulation made constrained-Delaunay again by Lawson flips.
    """
    # Four far corners put the outline inside the convex hull: Qhull leaves flat triangles
    # between collinear points on the hull (a straight, sampled panel edge).
    lo, hi = points.min(axis=0), points.max(axis=0)
    c, r = 0.5 * (lo + hi), float(np.max(hi - lo))
    frame = c + 2.0 * r * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    full = np.concatenate([points, frame])
    tri = Delaunay(full)
    if len(tri.coplanar):
        i = int(tri.coplanar[0, 0])
        raise ValueError(f"point {i} at {full[i].tolist()} coincides with another point")
    tris = tri.simplices.astype(np.int64)
    nbr = tri.neighbors.astype(np.int64)
    cw = _orient(full[tris[:, 0]], full[tris[:, 1]], full[tris[:, 2]]) < 0
    tris[cw] = tris[cw][:, [0, 2, 1]]
    nbr[cw] = nbr[cw][:, [0, 2, 1]]
    xy = full.tolist()
    for a in missing_segments(tris, n):
        recover_segment(xy, tris, nbr, int(a), int((a + 1) % n))
    lawson_flips(full, tris, nbr, n)
    return FramedTriangulation(full, tris, nbr, inside_triangles(tris, nbr, n))


def _edge_keys(u: np.ndarray, v: np.ndarray, m: int) -> np.ndarray:
    return np.minimum(u, v) * m + np.maximum(u, v)


def missing_segments(tris: np.ndarray, n: int) -> np.ndarray:
    """Boundary segments ``(a, a + 1 mod n)`` that are no edge of ``tris``, by their first point."""
    m = int(tris.max()) + 1
    keys = _edge_keys(tris, np.roll(tris, -1, axis=1), m).ravel()
    a = np.arange(n)
    return a[~np.isin(_edge_keys(a, (a + 1) % n, m), keys)]


def is_segment(u, v, n: int):
    """Whether the edge ``(u, v)`` is a boundary segment of the loop of ``n`` points."""
    return (u < n) & (v < n) & (((u - v) % n == 1) | ((v - u) % n == 1))


def _orient_xy(xy: list, i: int, j: int, k: int) -> float:
    (ax, ay), (bx, by), (cx, cy) = xy[i], xy[j], xy[k]
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


def flip(tris: np.ndarray, nbr: np.ndarray, t: int, k: int) -> int:
    """Flip the edge of triangle ``t`` opposite its vertex ``k``; returns the other triangle.

    ``t = (p, q, r)`` and its neighbour ``u = (s, r, q)`` become ``t = (p, q, s)`` and
    ``u = (p, s, r)``; neighbours are opposite vertices, as in ``scipy.spatial.Delaunay``.
    """
    u = int(nbr[t, k])
    j = int(np.flatnonzero(nbr[u] == t)[0])
    p, q, r = tris[t, k], tris[t, (k + 1) % 3], tris[t, (k + 2) % 3]
    s = tris[u, j]
    na, nb_ = nbr[t, (k + 1) % 3], nbr[t, (k + 2) % 3]  # across (r, p) and (p, q)
    nc, nd = nbr[u, (j + 1) % 3], nbr[u, (j + 2) % 3]  # across (q, s) and (s, r)
    tris[t], nbr[t] = (p, q, s), (nc, u, nb_)
    tris[u], nbr[u] = (p, s, r), (nd, na, t)
    if nc >= 0:
        nbr[nc][nbr[nc] == u] = t
    if na >= 0:
        nbr[na][nbr[na] == t] = u
    return u


def _find_edge(tris: np.ndarray, cand: np.ndarray, q: int, r: int) -> tuple[int, int]:
    """(t, k): a triangle among ``cand`` with edge (q, r) and the local index opposite the edge."""
    rows = tris[cand]
    hit = np.flatnonzero((rows == q).any(1) & (rows == r).any(1))
    t = int(cand[hit[0]])
    k = int(np.flatnonzero((tris[t] != q) & (tris[t] != r))[0])
    return t, k


def _crossed_edges(xy: list, tris: np.ndarray, nbr: np.ndarray, a: int, b: int):
    """Edges (q, r) that the segment a-b crosses, walking from ``a``, and the triangles passed."""
    for t in np.flatnonzero((tris == a).any(1)):
        k = int(np.flatnonzero(tris[t] == a)[0])
        q, r = int(tris[t, (k + 1) % 3]), int(tris[t, (k + 2) % 3])
        if _orient_xy(xy, a, q, b) > 0 and _orient_xy(xy, a, b, r) > 0:
            break
    else:
        raise ValueError(f"boundary segment {a}-{b}: no triangle at point {a} points along it")
    edges, passed = [(q, r)], [int(t)]
    while True:
        u = int(nbr[t, k])
        if u < 0:
            raise ValueError(f"boundary segment {a}-{b} leaves the convex hull")
        s = int(tris[u][(tris[u] != q) & (tris[u] != r)][0])
        passed.append(u)
        if s == b:
            return edges, np.array(passed)
        side = _orient_xy(xy, a, b, s)
        if side == 0:
            raise ValueError(f"point {s} at {xy[s]} lies on boundary segment {a}-{b}")
        q, r = (q, s) if side > 0 else (s, r)
        edges.append((q, r))
        t, k = u, int(np.flatnonzero((tris[u] != q) & (tris[u] != r))[0])


def recover_segment(xy: list, tris: np.ndarray, nbr: np.ndarray, a: int, b: int) -> None:
    """Make a-b an edge by flipping the edges it crosses (Sloan 1993)."""
    queue, cand = _crossed_edges(xy, tris, nbr, a, b)
    budget = 50 * len(queue) ** 2 + 100
    while queue:
        budget -= 1
        if budget < 0:
            raise ValueError(f"boundary segment {a}-{b} could not be recovered by edge flips")
        q, r = queue.pop(0)
        t, k = _find_edge(tris, cand, q, r)
        p, q1, r1 = (int(tris[t, (k + i) % 3]) for i in range(3))
        u = int(nbr[t, k])
        s = int(tris[u][(tris[u] != q1) & (tris[u] != r1)][0])
        if _orient_xy(xy, p, q1, s) <= 0 or _orient_xy(xy, s, r1, p) <= 0:
            queue.append((q, r))  # not a convex quadrilateral: come back after other flips
            continue
        flip(tris, nbr, t, k)
        if {p, s} & {a, b}:
            continue
        if (_orient_xy(xy, a, b, p) > 0) != (_orient_xy(xy, a, b, s) > 0) and \
                (_orient_xy(xy, p, s, a) > 0) != (_orient_xy(xy, p, s, b) > 0):
            queue.append((p, s))


def _incircle(pa: np.ndarray, pb: np.ndarray, pc: np.ndarray, pd: np.ndarray) -> np.ndarray:
    """> 0 where ``pd`` lies inside the circumcircle of counter-clockwise (pa, pb, pc), scaled
    by the squared edge lengths so that it reads as a relative measure."""
    a, b, c = pa - pd, pb - pd, pc - pd
    la, lb, lc = (np.einsum("...i,...i->...", v, v) for v in (a, b, c))
    det = (la * (b[..., 0] * c[..., 1] - b[..., 1] * c[..., 0])
           - lb * (a[..., 0] * c[..., 1] - a[..., 1] * c[..., 0])
           + lc * (a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]))
    return det / ((la + lb + lc) ** 2 + 1e-300)


def lawson_flips(points: np.ndarray, tris: np.ndarray, nbr: np.ndarray, n: int) -> None:
    """Flip non-boundary edges whose quadrilateral is not Delaunay until none is left."""
    for _ in range(100):
        t, k = np.nonzero(nbr >= 0)
        u = nbr[t, k]
        keep = t < u
        t, k, u = t[keep], k[keep], u[keep]
        q, r = tris[t, (k + 1) % 3], tris[t, (k + 2) % 3]
        s = tris[u].sum(axis=1) - q - r
        bad = (_incircle(points[tris[t, k]], points[q], points[r], points[s]) > 1e-12) \
            & ~is_segment(q, r, n)
        if not np.any(bad):
            return
        for t0, k0, q0, r0 in zip(t[bad], k[bad], q[bad], r[bad], strict=True):
            row = tris[t0]
            if {int(row[(k0 + 1) % 3]), int(row[(k0 + 2) % 3])} != {int(q0), int(r0)}:
                continue  # an earlier flip in this round changed the triangle
            q0, r0 = row[(k0 + 1) % 3], row[(k0 + 2) % 3]
            u0 = nbr[t0, k0]
            s0 = tris[u0].sum() - q0 - r0
            quad = points[[row[k0], q0, r0, s0]]
            if _incircle(*quad[:, None])[0] > 1e-12 and \
                    _orient(quad[[0]], quad[[1]], quad[[3]])[0] > 0 and \
                    _orient(quad[[3]], quad[[2]], quad[[0]])[0] > 0:
                flip(tris, nbr, int(t0), int(k0))
    raise ValueError("Lawson edge flips did not converge")


def inside_triangles(tris: np.ndarray, nbr: np.ndarray, n: int) -> np.ndarray:
    """Bool (T,): triangles on the left of the boundary loop, found by flooding across edges that
    are no boundary segments from the triangles that hold a segment counter-clockwise."""
    t, k = np.nonzero(nbr >= 0)
    q, r = tris[t, (k + 1) % 3], tris[t, (k + 2) % 3]
    open_ = ~is_segment(q, r, n)
    graph = coo_matrix((np.ones(int(open_.sum())), (t[open_], nbr[t, k][open_])),
                       shape=(len(tris),) * 2)
    _, label = connected_components(graph, directed=False)
    a, b = tris, np.roll(tris, -1, axis=1)
    forward = ((a < n) & (b < n) & ((b - a) % n == 1)).any(axis=1)
    backward = ((a < n) & (b < n) & ((a - b) % n == 1)).any(axis=1)
    inside_label = np.zeros(label.max() + 1, bool)
    inside_label[label[forward]] = True
    if np.any(inside_label[label[backward]]):
        raise ValueError("the triangulation does not separate the outline's inside from outside")
    return inside_label[label]


# ----------------------------------------------------------------------------------------------
# smoothing and checks


def triangle_areas(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Signed areas [m^2] of triangles ``tris`` (T, 3) of ``points`` (M, 2)."""
    return 0.5 * _orient(points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]])


def odt_positions(points: np.ndarray, tris: np.ndarray, n: int) -> np.ndarray:
    """Each interior point moved to the area-weighted mean of its triangles' circumcentres
    (Chen 2004, ODT smoothing); the first ``n`` (boundary) points and points of no triangle stay."""
    a, b, c = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    ab, ac = b - a, c - a
    d = 2.0 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    lab, lac = np.sum(ab * ab, axis=1), np.sum(ac * ac, axis=1)
    centre = a + np.stack([ac[:, 1] * lab - ab[:, 1] * lac, ab[:, 0] * lac - ac[:, 0] * lab], 1) / d[:, None]
    area = 0.25 * d
    v = tris.ravel()
    w = np.repeat(area, 3)
    total = np.bincount(v, w, minlength=len(points))
    out = points.copy()
    move = np.flatnonzero(total > 0)
    move = move[move >= n]
    for axis in range(2):
        s = np.bincount(v, w * np.repeat(centre[:, axis], 3), minlength=len(points))
        out[move, axis] = s[move] / total[move]
    return out


def keep_valid_moves(old: np.ndarray, new: np.ndarray, tris: np.ndarray, n: int,
                     min_area: float) -> np.ndarray:
    """``new`` positions, except that interior points of any triangle that would fall below
    ``min_area`` [m^2] (or below its old area when already smaller) keep their ``old`` place.

    With every triangle of the boundary-fixed disk keeping a positive area, the moved points
    stay inside the outline."""
    floor = np.minimum(triangle_areas(old, tris), min_area)
    out = new.copy()
    for _ in range(50):
        bad = triangle_areas(out, tris) < floor
        if not np.any(bad):
            return out
        v = np.unique(tris[bad])
        v = v[v >= n]
        out[v] = old[v]
    return old


def verify_disk(points: np.ndarray, tris: np.ndarray, n: int) -> None:
    """Raise ``ValueError`` unless ``tris`` is a manifold disk bounded by the loop ``points[:n]``:
    positive areas, every point used, every boundary segment one triangle's counter-clockwise
    edge, every other edge two triangles' (opposite ways), Euler characteristic 1, and the
    outline's area covered."""
    m = len(points)
    area = triangle_areas(points, tris)
    if len(tris) == 0 or area.min() <= 0:
        raise ValueError("meshing produced a degenerate or inverted triangle")
    if len(np.unique(tris)) != m:
        raise ValueError("meshing left points outside every triangle")
    u, v = tris.ravel(), np.roll(tris, -1, axis=1).ravel()
    directed = np.unique(u * m + v)
    if len(directed) != len(u):
        raise ValueError("meshing produced an edge used twice the same way (not a manifold)")
    a = np.arange(n)
    if not np.all(np.isin(a * m + (a + 1) % n, directed)):
        raise ValueError("meshing lost a boundary segment")
    undirected, count = np.unique(_edge_keys(u, v, m), return_counts=True)
    single = undirected[count == 1]
    if len(single) != n or not np.all(np.isin(single, _edge_keys(a, (a + 1) % n, m))):
        raise ValueError("meshing produced an open edge that is no boundary segment")
    if m - len(undirected) + len(tris) != 1:
        raise ValueError("meshing produced a surface that is not a disk")
    target = polygon_area(points[:n])
    if abs(area.sum() - target) > AREA_RTOL * target:
        raise ValueError(f"triangles cover {area.sum():.9g} m^2 of the outline's {target:.9g} m^2")
