"""Body cross-sections the garment templates are laid out on.

A template measures the body's rest mesh with horizontal slabs (or sagittal slices for a
strap), takes the convex hull of each slab grown by the cloth's ease and clearance, and lays
a ring of points on it at equal angles about the hull's centre. Branches that leave a loop (a
leg from the crotch loop, a sleeve from the armhole) blend their rows from the loop's radii to
their own hull's (``row_center``, ``BLEND``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from sim.easing import smoothstep
from sim.errors import WrinklesInputError

CLEARANCE = 0.005
"""Gap kept between the body and the cloth's mid-surface, on top of the cloth thickness [m]."""
ARM_JOINTS = tuple(range(16, 24))
"""SMPL shoulders, elbows, wrists, hands: their vertices are left out of torso slabs."""
RING_SAMPLES = 720
"""Angles a ring is sampled at before it is resampled at the edge length (0.5° apart)."""
BLEND = 0.06
"""Height over which a branch's rows (leg, sleeve) blend from the loop it leaves to its own
hull [m]."""


@dataclass(frozen=True)
class BodyMeasure:
    """Rest-pose body data the templates read."""

    vertices: np.ndarray  # (V, 3) [m]
    joints: np.ndarray  # (24, 3) [m]
    torso_mask: np.ndarray  # (V,) vertices not dominated by arm joints
    faces: np.ndarray | None = None  # (F, 3) body triangles

    @classmethod
    def of(cls, body, betas: np.ndarray | None) -> BodyMeasure:
        v = np.asarray(body.rest_mesh(betas), np.float64)
        j = np.asarray(body.rest_joints(betas), np.float64)
        w = np.asarray(body.weights)
        return cls(v, j, w[:, list(ARM_JOINTS)].sum(axis=1) < 0.5, np.asarray(body.faces, np.int64))

    def band(self, y0: float, y1: float, mask: np.ndarray, axis: int = 1) -> np.ndarray:
        """Masked vertices of every body triangle reaching into [y0, y1] along ``axis`` [m]:
        (x, z) for the vertical axis 1, (z, y) for axis 0 (sagittal slices).

        Conservative where body vertices are sparse: the triangles that cross the band bring
        their vertices on both sides of it.
        """
        fy = self.vertices[self.faces, axis]
        hit = (fy.min(axis=1) <= y1) & (fy.max(axis=1) >= y0)
        idx = np.unique(self.faces[hit])
        idx = idx[mask[idx]]
        return self.vertices[idx][:, [0, 2] if axis == 1 else [2, 1]]

    def slab(self, y: float, half: float, mask: np.ndarray | None = None) -> np.ndarray:
        """(x, z) of the body vertices with |vertex y − y| <= half [m]."""
        m = np.abs(self.vertices[:, 1] - y) <= half
        if mask is not None:
            m &= mask
        return self.vertices[m][:, [0, 2]]


def offset_hull(points_xz: np.ndarray, offset: float) -> np.ndarray:
    """Convex hull of 2D points grown by ``offset`` [m] (Minkowski sum with a 24-gon).

    Returns:
        hull vertices, shape (K, 2), counter-clockwise in (x, z).
    """
    ang = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    # circumscribed 24-gon so the grown hull is never closer than ``offset`` to the points
    disk = offset / np.cos(np.pi / 24) * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    pts = (points_xz[:, None, :] + disk[None]).reshape(-1, 2)
    hull = ConvexHull(pts)
    return pts[hull.vertices]


def waist_ease(y: float, y_waist: float, y_hip: float, margin: float, waist: float, ease: float) -> float:
    """Offset [m] of a hull at height ``y``: ``margin + waist`` at the waistband, blending
    (smoothstep) to ``margin + ease`` at the hip joints' height and below."""
    t = smoothstep((y_waist - y) / max(y_waist - y_hip, 1e-3))
    return margin + waist + (ease - waist) * float(t)


def centroid(poly: np.ndarray) -> np.ndarray:
    """Area centroid of a simple polygon (K, 2) (smooth in the polygon, unlike the vertex mean)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    cr = a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]
    return ((a + b) * cr[:, None]).sum(0) / (3.0 * cr.sum())


def ring_center(hull_xz: np.ndarray) -> np.ndarray:
    """(0, z) of a hull's area centroid in (x, z): the centre a ring's angles are taken about,
    on the body's mid-plane so both halves of a ring split there. The centroid moves
    continuously with the hull; the mean of the hull's vertices jumps as clusters of hull
    vertices come and go (by up to 16 mm at a ring's side points between rows 5 mm apart)."""
    return np.array([0.0, centroid(hull_xz)[1]])


def polar_ring(hull_xz: np.ndarray, center: np.ndarray, y: float, n: int = RING_SAMPLES) -> np.ndarray:
    """Points of a convex polygon at ``n + 1`` equal angles θ ∈ [0, 2π] around ``center``.

    x = cx + r cos θ, z = cz + r sin θ; θ = 0 is the body's left side (+x), π/2 the front.

    Returns:
        closed ring (n + 1, 3) [m] at height ``y``, last point == first point.
    """
    theta = np.linspace(0.0, 2 * np.pi, n + 1)
    d = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    a = hull_xz - center
    b = np.roll(a, -1, axis=0)
    # ray-segment intersection of every ray with every edge; keep the positive hit
    e = b - a
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (a[None, :, 0] * e[None, :, 1] - a[None, :, 1] * e[None, :, 0]) / den
        s = (a[None, :, 0] * d[:, None, 1] - a[None, :, 1] * d[:, None, 0]) / den
    ok = (s >= -1e-9) & (s <= 1 + 1e-9) & (t > 0)
    r = np.where(ok, t, np.inf).min(axis=1)
    ring = np.stack([center[0] + r * d[:, 0], np.full(n + 1, y), center[1] + r * d[:, 1]], axis=1)
    ring[-1] = ring[0]
    return ring


def polar_hits(poly_xz: np.ndarray, center: np.ndarray, theta: np.ndarray):
    """Ray casts from ``center`` at angles ``theta`` against the closed polygon ``poly_xz``.

    Returns:
        (r, edge, s): distance to the nearest hit, the polygon edge hit and the parameter
        along it (edge k runs from vertex k to k + 1, cyclically).
    """
    d = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    a = poly_xz - center
    e = np.roll(a, -1, axis=0) - a
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (a[None, :, 0] * e[None, :, 1] - a[None, :, 1] * e[None, :, 0]) / den
        s = (a[None, :, 0] * d[:, None, 1] - a[None, :, 1] * d[:, None, 0]) / den
    ok = (s >= -1e-9) & (s <= 1 + 1e-9) & (t > 0)
    tt = np.where(ok, t, np.inf)
    edge = tt.argmin(axis=1)
    rows = np.arange(len(theta))
    return tt[rows, edge], edge, np.clip(s[rows, edge], 0.0, 1.0)


def row_center(c0: np.ndarray, hull: np.ndarray, k: int, n: int) -> np.ndarray:
    """Polar centre of a branch row (leg, sleeve): the first rows (k < 0) share ``c0``, so their
    radii blend with the loop's; then the centre glides to the row hull's centroid over ``n``
    rows, so the seam at the row's start angle runs straight (a jump makes sliver triangles)."""
    if k < 0:
        return c0
    c = centroid(hull)
    return c0 + float(smoothstep((k + 1) / max(n, 1))) * (c - c0)


def clip_half_plane(poly: np.ndarray, sign: float, x0: float) -> np.ndarray:
    """Part of a convex polygon (K, 2) with sign * x >= x0 (Sutherland-Hodgman, one plane)."""
    out = []
    n = len(poly)
    for k in range(n):
        p, q = poly[k], poly[(k + 1) % n]
        fp, fq = sign * p[0] - x0, sign * q[0] - x0
        if fp >= 0:
            out.append(p)
        if fp * fq < 0:
            out.append(p + (q - p) * (fp / (fp - fq)))
    return np.asarray(out)


def midplane_crossings(vertices: np.ndarray, faces: np.ndarray,
                       y_range: tuple[float, float] | None = None) -> np.ndarray:
    """Points (K, 3) where the mesh's edges cross the mid-sagittal plane x = 0, interpolated
    along the edge; with ``y_range`` (lo, hi) only edges whose both ends lie strictly within it."""
    e = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    a, b = vertices[e[:, 0]], vertices[e[:, 1]]
    cross = a[:, 0] * b[:, 0] < 0
    if y_range is not None:
        cross &= (np.minimum(a[:, 1], b[:, 1]) > y_range[0]) & (np.maximum(a[:, 1], b[:, 1]) < y_range[1])
    a, b = a[cross], b[cross]
    t = a[:, 0] / (a[:, 0] - b[:, 0])
    return a + t[:, None] * (b - a)


def crotch_height(m: BodyMeasure) -> float:
    """Lowest point where the body surface crosses the mid-sagittal plane x = 0 between the
    hips and the knees [m] (edges crossing the plane, interpolated)."""
    j = m.joints
    p = midplane_crossings(m.vertices, m.faces, (j[4, 1], j[1, 1] + 0.05))
    if not len(p):
        raise WrinklesInputError("cannot find the crotch of this body (no surface crosses the "
                                 "mid-plane between hips and knees)")
    return float(p[:, 1].min())
