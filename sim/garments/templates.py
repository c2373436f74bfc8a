"""Procedural garment templates fitted to a body's rest shape.

Skirts, shorts / trousers (hip tube split into two legs at a crotch bridge), tank top / dress /
t-shirt / long sleeve (body tube, bibs, shoulder straps, optional sleeves on the armholes).
Each template measures the body's rest mesh with horizontal slabs (cross-section hulls at the
height of every pattern row), adds ease and a clearance margin, and lays out sewing-pattern
panels as rows of arcs around the body (``sim.garments.panels``). The panels are sewn by
welding their shared seam points; each panel is flattened into its pattern piece (ARAP,
``sim.garments.uv``) and the pieces are packed into [0, 1]²: those are the UVs.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from scipy.spatial import ConvexHull

from sim.errors import WrinklesInputError
from sim.garments.hems import HEM_LAYERS, HEM_WIDTH, hem_face_layers
from sim.garments.materials import Material, get_material
from sim.garments.panels import Panel, arc_length, resample, sew
from sim.garments.types import Garment
from sim.garments.uv import flatten_panels, pack_uvs

RESOLUTIONS = ("coarse", "fine")
"""Named resolutions: each template's ``coarse`` / ``fine`` edge length (``Template``)."""
CLEARANCE = 0.005
"""Gap kept between the body and the cloth's mid-surface, on top of the cloth thickness [m]."""
ARM_JOINTS = tuple(range(16, 24))
"""SMPL shoulders, elbows, wrists, hands: their vertices are left out of torso slabs."""
_RING_SAMPLES = 720


@dataclass(frozen=True)
class SkirtParams:
    """Parameters of the straight and flared skirts.

    Attributes:
        length: waist-to-hem length along the body axis [m].
        ease: looseness added around the hips and below [m] (distance from the hull of the
            body to the cloth).
        waist_ease: looseness at the waistband [m].
        flare: extra radius at the hem relative to the hips [-] (0 = straight, 0.6 = A-line).
        waist_offset: waistband height above SMPL's spine1 joint [m].
    """

    length: float = 0.55
    ease: float = 0.015
    waist_ease: float = 0.004
    flare: float = 0.0
    waist_offset: float = 0.0


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


def _ring_center(hull_xz: np.ndarray) -> np.ndarray:
    """(0, z) of a hull's area centroid in (x, z): the centre a ring's angles are taken about,
    on the body's mid-plane so both halves of a ring split there. The mean of the hull's
    vertices moved a ring's side points by up to 16 mm between rows 5 mm apart, as clusters of
    hull vertices came and went; the centroid moves continuously with the hull."""
    return np.array([0.0, _centroid(hull_xz)[1]])


def polar_ring(hull_xz: np.ndarray, center: np.ndarray, y: float, n: int = _RING_SAMPLES) -> np.ndarray:
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


def _smoothstep(x: np.ndarray | float) -> np.ndarray | float:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def skirt_panels(m: BodyMeasure, p: SkirtParams, h: float, thickness: float) -> list[Panel]:
    """Front and back panels of a skirt: one tube from the waist down, hanging from the hull
    of everything above each row (a skirt bridges the legs), widened by ``flare``.

    Args:
        m: body measurements; p: parameters; h: target edge length [m];
        thickness: cloth thickness [m] (kept clear of the body with ``CLEARANCE``).
    """
    j = m.joints
    y_waist = j[3, 1] + p.waist_offset
    y_floor = m.vertices[:, 1].min() + 0.03
    length = min(p.length, y_waist - y_floor)
    if length < 4 * h:
        raise WrinklesInputError(f"skirt length {p.length} m is too short for edge length {h} m")
    hv = h * np.sqrt(3) / 2
    n_rows = max(3, int(round(length / hv)) + 1)
    ys = y_waist - np.linspace(0.0, length, n_rows)
    half = max(hv, 0.01)
    margin = thickness + CLEARANCE
    acc = m.slab(y_waist + half, half, m.torso_mask)  # what the waistband must clear
    y_hip = j[1, 1]
    front, back = [], []
    for y in ys:
        acc = np.concatenate([acc, m.slab(y, half, m.torso_mask)])
        acc = acc[ConvexHull(acc).vertices]  # hanging cloth: hull of all that is above
        below_waist = (y_waist - y) / max(y_waist - y_hip, 1e-3)
        off = margin + p.waist_ease + (p.ease - p.waist_ease) * _smoothstep(below_waist)
        hull = offset_hull(acc, off)
        center = _ring_center(hull)
        if p.flare:
            k = 1.0 + p.flare * float(_smoothstep((j[1, 1] - y) / max(length - (y_waist - y_hip), 1e-3)))
            hull = center + (hull - center) * k
        ring = polar_ring(hull, center, float(y))
        half_n = _RING_SAMPLES // 2
        front.append(resample(ring[: half_n + 1], h, min_segments=2))
        back.append(resample(ring[half_n:], h, min_segments=2))
    return [Panel("front", tuple(front)), Panel("back", tuple(back))]


@dataclass(frozen=True)
class PantsParams:
    """Parameters of shorts and trousers.

    Attributes:
        length: waist-to-hem length along the body axis (outseam) [m]; trousers stop above
            the ankle joint.
        ease: looseness around the hips and the legs [m].
        waist_ease: looseness at the waistband [m].
        crotch_ease: extra gap below the body's crotch [m].
        waist_offset: waistband height above SMPL's spine1 joint [m].
        leg_gap: least distance between the two legs' inner walls [m]: where a leg's hull with
            its ease would reach within half of it of the mid-sagittal plane (between the thighs),
            its inner wall is cut flat there.
    """

    length: float = 1.0
    ease: float = 0.015
    waist_ease: float = 0.004
    crotch_ease: float = 0.02
    waist_offset: float = 0.0
    leg_gap: float = 0.003


BLEND = 0.06
"""Height over which a leg's rows blend from the crotch loop to the leg's own hull [m]."""

SLEEVE_STEP = 1.0
"""Most a sleeve row's radius (about the arm) changes from the previous row's, in row spacings:
where the armhole loop lies inside the arm's hull (under the arm, whose hull takes in the
torso's side) the rows reach the hull over a few rows instead of in one jump."""


def _polar(poly_xz: np.ndarray, center: np.ndarray, theta: np.ndarray):
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


def _centroid(poly: np.ndarray) -> np.ndarray:
    """Area centroid of a simple polygon (K, 2) (smooth in the polygon, unlike the vertex mean)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    cr = a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]
    return ((a + b) * cr[:, None]).sum(0) / (3.0 * cr.sum())


def _row_center(c0: np.ndarray, hull: np.ndarray, k: int, n: int) -> np.ndarray:
    """Polar centre of a branch row (leg, sleeve): the first rows (k < 0) share ``c0``, so their
    radii blend with the loop's; then the centre glides to the row hull's centroid over ``n``
    rows, so the seam at the row's start angle runs straight (a jump makes sliver triangles)."""
    if k < 0:
        return c0
    c = _centroid(hull)
    return c0 + float(_smoothstep((k + 1) / max(n, 1))) * (c - c0)


def _clip_half_plane(poly: np.ndarray, sign: float, x0: float) -> np.ndarray:
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


def _crotch_height(m: BodyMeasure) -> float:
    """Lowest point where the body surface crosses the mid-sagittal plane x = 0 between the
    hips and the knees [m] (edges crossing the plane, interpolated)."""
    j = m.joints
    p = midplane_crossings(m.vertices, m.faces, (j[4, 1], j[1, 1] + 0.05))
    if not len(p):
        raise WrinklesInputError("cannot find the crotch of this body (no surface crosses the "
                                 "mid-plane between hips and knees)")
    return float(p[:, 1].min())


def pants_panels(m: BodyMeasure, p: PantsParams, h: float, thickness: float) -> list[Panel]:
    """Shorts / trousers: a hip tube (front, back) from the waist to just above the crotch,
    split into two leg tubes.

    The hip ring at the split height is cut at the sides, the front centre F and the back
    centre B. A bridge curve in the mid-sagittal plane runs F → C → B below the crotch; each
    leg's first row is the closed loop (half hip ring + bridge), opened at C (the inseam).
    The next leg rows blend from that loop to the offset hull of the leg (their inner points
    dip with the bridge and rise back), so every strip has near-uniform height.
    """
    j = m.joints
    v = m.vertices
    hv = h * np.sqrt(3) / 2
    half = max(hv, 0.01)
    margin = thickness + CLEARANCE
    y_waist = j[3, 1] + p.waist_offset
    y_cr = _crotch_height(m)
    y_c = y_cr + 0.4 * hv  # the split row, just above the body's crotch
    y_lowest = j[7, 1] + 0.05  # trousers stop above the ankle joint (the foot is not a tube)
    y_hem = max(y_waist - p.length, y_lowest)
    if y_waist - y_c < 2 * hv:
        raise WrinklesInputError("waist is too close to the crotch for these pants")
    n_leg = int(round((y_c - y_hem) / hv))
    if n_leg < 3:
        raise WrinklesInputError(f"pants length {p.length} m leaves no leg at edge length {h} m "
                                 f"(the crotch is {y_waist - y_c:.3f} m below the waist)")
    y_hip = j[1, 1]

    def ease_at(y: float) -> float:
        t = _smoothstep((y_waist - y) / max(y_waist - y_hip, 1e-3))
        return margin + p.waist_ease + (p.ease - p.waist_ease) * float(t)

    # hip tube
    n_up = max(2, int(round((y_waist - y_c) / hv))) + 1
    front, back = [], []
    ring = None
    for y in np.linspace(y_waist, y_c, n_up):
        hull = offset_hull(m.band(float(y) - half, float(y) + half, m.torso_mask), ease_at(float(y)))
        ring = polar_ring(hull, _ring_center(hull), float(y))
        hn = _RING_SAMPLES // 2
        front.append(resample(ring[: hn + 1], h, min_segments=2))
        back.append(resample(ring[hn:], h, min_segments=2))
    qn = _RING_SAMPLES // 4
    q = [resample(ring[k * qn: (k + 1) * qn + 1], h, min_segments=1) for k in range(4)]
    front[-1] = np.concatenate([q[0], q[1][1:]])
    back[-1] = np.concatenate([q[2], q[3][1:]])
    f_pt, b_pt = ring[qn], ring[3 * qn]
    # bridge F -> C -> B in the plane of F and B, below the crotch
    depth = (y_c - y_cr) + margin + p.crotch_ease
    phi = np.linspace(0.0, np.pi, 201)
    t = phi / np.pi  # even in the plane: the ends of the bridge stay less steep than (1 - cos)/2
    bridge = f_pt[None] + t[:, None] * (b_pt - f_pt)[None]
    bridge[:, 1] = y_c - depth * np.sqrt(np.sin(phi).clip(0.0))
    bridge[0], bridge[-1] = f_pt, b_pt
    fh = resample(bridge[:101], h, min_segments=1)  # F -> C
    bh = resample(bridge[100:], h, min_segments=1)  # C -> B
    panels = [Panel("front", tuple(front), bottom=None, local_spacing=True),
              Panel("back", tuple(back), bottom=None, local_spacing=True)]
    n_blend = max(2, int(round(BLEND / hv)))
    clip = 0.5 * p.leg_gap  # leg tubes stay at |x| >= clip so the two legs never cross
    n_fade = max(1, min(n_leg, max(n_blend, int(np.ceil(depth / (0.4 * hv))))))
    for side, sign in (("left", 1.0), ("right", -1.0)):
        if sign > 0:  # counter-clockwise seen from above, starting at the inseam point C
            loop = np.concatenate([bh, q[3][1:], q[0][1:], fh[1:]])
            theta = np.pi + np.linspace(0.0, 2 * np.pi, _RING_SAMPLES + 1)
        else:
            loop = np.concatenate([fh[::-1], q[1][1:], q[2][1:], bh[::-1][1:]])
            theta = np.linspace(0.0, 2 * np.pi, _RING_SAMPLES + 1)
        leg_mask = m.torso_mask & (sign * v[:, 0] > 0)

        def leg_hull(y0: float, y1: float, off: float, leg_mask=leg_mask, sign=sign) -> np.ndarray:
            return _clip_half_plane(offset_hull(m.band(y0 - half, y1 + half, leg_mask), off), sign, clip)

        h0 = leg_hull(y_c - hv, y_c - hv, ease_at(y_c - hv))
        c0 = h0.mean(axis=0)
        r_d, edge, s_d = _polar(loop[:, [0, 2]], c0, theta)
        y_d = loop[edge, 1] + s_d * (np.roll(loop[:, 1], -1)[edge] - loop[edge, 1])
        rows = [loop]
        for k in range(1, n_leg + 1):
            s = float(_smoothstep(k / n_blend))
            s_y = min(1.0, k / n_fade)  # linear: the inner side rows stay >= 0.6 hv apart
            yk = (1 - s_y) * y_d + s_y * y_c - k * hv
            hull = leg_hull(float(yk.min()), float(yk.max()), ease_at(float(yk.mean())))
            c = _row_center(c0, hull, k - max(n_blend, n_fade), n_blend)
            r_l = _polar(hull, c, theta)[0]
            r = np.maximum((1 - s) * r_d + s * r_l, r_l)
            row = np.stack([c[0] + r * np.cos(theta), yk, c[1] + r * np.sin(theta)], axis=1)
            # off the mid-plane, where the other leg's rows are: the blend from the loop's bridge
            # (x = 0) left both legs' first inner rows in the plane, the two legs' faces one on
            # the other (session 42)
            row[:, 0] = sign * np.maximum(sign * row[:, 0], clip)
            row[-1] = row[0]
            rows.append(resample(row, h, min_segments=3))
        panels.append(Panel(f"{side}_leg", tuple(rows), top=None, local_spacing=True))
    return panels


@dataclass(frozen=True)
class TopParams:
    """Parameters of the tank top, t-shirt, long sleeve and dress.

    Attributes:
        length: from the top of the body tube (below the armpit) down to the hem [m].
        ease: looseness around the torso [m].
        armhole_depth: how far below the armpit the armhole's lowest point lies [m]. The
            necklines' rises and the length are measured from that point, so a deeper armhole
            also lowers the necklines and the hem and lengthens the straps. The tank top's is
            5 cm (session 49: its fine walks passed on 7 of 11 bodies against 4 of 11 at 3 cm,
            docs/BENCHMARKS.md), the shirts' and the dress's 3 cm.
        strap_width: shoulder strap width [m].
        neck_ease: gap between the neck and the inner edge of a strap [m].
        front_rise, back_rise: neckline heights above the armhole's lowest point [m].
        neck_fillet: radius of the rounded corners where the neckline meets the straps [m], at
            most what leaves a neckline four edges wide; 0: square corners, where stress
            concentrates in the cloth (a re-entrant corner) and the largest edge strain grows as
            the mesh is refined.
        armhole_fillet: radius [m] of the arcs that round the corners where a bib's side meets
            the body tube's top row (the armhole's bottom): tangent to the side, meeting the row
            at 45° (``armhole_inset``; they reach 0.29 x the radius out from the side and 0.71 x
            up it), capped at 3/4 of the lower rise up the side and where the armhole's bottom
            would keep less than two edges; 0: square corners (about 270 degrees of cloth), the
            default of the shirts and the dress. The tank top's is 8 cm (session 44: every worst
            edge of its fine walks sat at the square corners, docs/BENCHMARKS.md).
        flare: extra radius at the hem relative to the hips [-] (dresses).
        sleeve_length: sleeve length from the shoulder joint along the arm [m]; 0 = none
            (the armholes stay open); sleeves stop 3 cm before the wrist.
    """

    length: float = 0.4
    ease: float = 0.02
    armhole_depth: float = 0.03
    strap_width: float = 0.06
    neck_ease: float = 0.02
    front_rise: float = 0.08
    back_rise: float = 0.10
    neck_fillet: float = 0.02
    armhole_fillet: float = 0.0
    flare: float = 0.0
    sleeve_length: float = 0.0


def _cut_indices(half_ring: np.ndarray, xs: list[float]) -> list[int]:
    """Indices of the samples of a half ring (x monotonic) nearest to each x in ``xs``."""
    return [int(np.argmin(np.abs(half_ring[:, 0] - x))) for x in xs]


def _pieces(row: np.ndarray, cuts: list[int], h: float) -> list[np.ndarray]:
    """A dense polyline cut at sample indices, each piece resampled at ``h`` (ends exact)."""
    idx = [0, *cuts, len(row) - 1]
    if np.any(np.diff(idx) < 1):
        raise WrinklesInputError("strap edges fall outside the body's cross-section; reduce "
                                 "strap_width or neck_ease")
    return [resample(row[a: b + 1], h, min_segments=1) for a, b in zip(idx[:-1], idx[1:], strict=True)]


def _join(pieces: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([pieces[0]] + [q[1:] for q in pieces[1:]])


def fillet_inset(s: np.ndarray | float, radius: float) -> np.ndarray:
    """How far [m] a quarter-circle fillet of ``radius`` [m] reaches beyond a strap's straight
    inner edge at distance ``s`` [m] along the strap from the neckline: ``radius`` at the
    neckline (where the fillet meets it tangentially), 0 from ``radius`` on (where it meets the
    strap's edge tangentially)."""
    d = np.clip(radius - np.asarray(s, dtype=float), 0.0, radius)
    return radius - np.sqrt(np.maximum(radius * radius - d * d, 0.0))


ARMHOLE_FILLET_ANGLE = np.pi / 4
"""Angle [rad] from the horizontal at which an armhole fillet meets the tube's top row (a square
corner meets it at 90°). A quarter circle tangent to the row would cross the bib's last rows at
a glancing angle and leave slivers (2.9° at the fine size with 4 cm, session 44); at 45° the
cloth around the corner is 225° instead of 270°."""


def armhole_inset(dy: np.ndarray | float, radius: float,
                  angle: float = ARMHOLE_FILLET_ANGLE) -> np.ndarray:
    """How far [m] an armhole fillet of ``radius`` [m] reaches beyond a bib's straight side at
    height ``dy`` [m] above the tube's top row: an arc of the circle of ``radius`` tangent to the
    side at ``radius * sin(angle)`` above the row, meeting the row at ``angle`` from the
    horizontal (``radius * (1 - cos(angle))`` out from the side there), 0 above its top."""
    top = radius * np.sin(angle)
    t = np.clip((top - np.asarray(dy, dtype=float)) / max(radius, 1e-12), 0.0, np.sin(angle))
    return radius * (1.0 - np.sqrt(1.0 - t * t))


def _extend_inner(row: np.ndarray, inner: int, inset: float, h: float) -> np.ndarray:
    """A strap row extended at its ``inner`` end (0 or -1) by ``inset`` [m] in |x|, straight on
    along the row's last segment, then resampled at ``h``."""
    if inset <= 1e-9:
        return row
    a, b = (row[0], row[1]) if inner == 0 else (row[-1], row[-2])
    t = (a - b) / max(abs(a[0] - b[0]), 1e-9)  # unit step in |x|
    tip = a + inset * t
    ext = np.vstack([tip, row]) if inner == 0 else np.vstack([row, tip])
    return resample(ext, h, min_segments=2)


def tank_top_panels(m: BodyMeasure, p: TopParams, h: float, thickness: float) -> list[Panel]:
    """Tank top: a body tube (front, back) hanging from below the armpits to the hem, a front
    and a back bib between the armholes up to the necklines, and two shoulder straps.

    Every row is an arc of the body's offset cross-section hull. The bibs' bottom rows are
    the middle of the tube's top row, their top rows carry the straps' ends as exact sample
    points. A strap's rows run across its width and follow the shoulder's sagittal section
    (offset hull of the body in the (z, y) plane at that x) from the front neckline, over the
    shoulder, to the back neckline; its middle row is the ``shoulders`` attachment.
    """
    j = m.joints
    v = m.vertices
    hv = h * np.sqrt(3) / 2
    half = max(hv, 0.01)
    margin = thickness + CLEARANCE
    every = np.ones(len(v), bool)
    arm = ~m.torso_mask & (np.abs(v[:, 0]) < abs(j[16, 0]) + 0.06)
    y_top = float(v[arm, 1].min()) - p.armhole_depth
    y_floor = v[:, 1].min() + 0.03
    length = min(p.length, y_top - y_floor)
    if length < 4 * h:
        raise WrinklesInputError(f"top length {p.length} m is too short for edge length {h} m")
    # the neck's half width halfway up the neck fixes where the straps start
    y_neck = 0.5 * (j[12, 1] + j[15, 1])
    neck = m.torso_mask & (np.abs(v[:, 1] - y_neck) < 0.015) & (np.abs(v[:, 0]) < abs(j[16, 0]))
    x_in = float(np.abs(v[neck, 0]).max()) + margin + p.neck_ease
    x_out = min(x_in + p.strap_width, 0.93 * abs(j[16, 0]))  # stays inside the shoulder joint
    if x_out - x_in < 0.03:
        raise WrinklesInputError(f"strap_width {p.strap_width} m: the shoulder is too narrow for a strap")
    # the rounded corners take the neckline's ends: it runs between -x_neck and x_neck, at least
    # four edges wide (a coarse mesh gets smaller corners)
    fillet = min(p.neck_fillet, max(x_in - 2 * h, 0.0))
    x_neck = x_in - fillet
    # the armholes' rounded bottom corners: the bibs' sides curve out into the tube's top row
    arm_r = min(p.armhole_fillet, 0.75 * min(p.front_rise, p.back_rise) / np.sin(ARMHOLE_FILLET_ANGLE))
    hn = _RING_SAMPLES // 2
    n_rows = max(3, int(round(length / hv)) + 1)
    y_hip, y_hem = j[1, 1], y_top - length
    front, back = [], []
    acc = m.band(y_top, y_top + half, m.torso_mask)
    for k, y in enumerate(y_top - np.linspace(0.0, length, n_rows)):
        acc = np.concatenate([acc, m.band(float(y) - half, float(y) + half, m.torso_mask)])
        acc = acc[ConvexHull(acc).vertices]  # hanging cloth: hull of all that is above
        hull = offset_hull(acc, margin + p.ease)
        center = _ring_center(hull)
        if p.flare and y < y_hip:
            grow = p.flare * float(_smoothstep((y_hip - y) / (y_hip - y_hem)))
            hull = center + (hull - center) * (1.0 + grow)
        ring = polar_ring(hull, center, float(y))
        if k > 0:
            front.append(resample(ring[: hn + 1], h, min_segments=2))
            back.append(resample(ring[hn:], h, min_segments=2))
            continue
        # the fillet leaves the armhole's bottom at least two edges before the tube's side (a
        # slim body gets smaller corners)
        room = float(np.abs(ring[:, 0]).max()) - x_out - 2 * h
        arm_r = max(0.0, min(arm_r, room / float(armhole_inset(0.0, 1.0))))
        x_arm = x_out + float(armhole_inset(0.0, arm_r))
        fp = _pieces(ring[: hn + 1], _cut_indices(ring[: hn + 1], [x_arm, -x_arm]), h)
        bp = _pieces(ring[hn:], _cut_indices(ring[hn:], [-x_arm, x_arm]), h)
        front.append(_join(fp))
        back.append(_join(bp))
        bib_bottom = {"front": fp[1], "back": bp[1]}
        tube_top = (fp, bp)
    panels = [Panel("front", tuple(front), top=None), Panel("back", tuple(back), top=None)]
    # bibs between the armholes, from the necklines down to the tube
    ends, cores, bibs, strap_rows = {}, {}, {}, {}
    for name, rise, xs in (("front", p.front_rise, [x_out, x_neck, -x_neck, -x_out]),
                           ("back", p.back_rise, [-x_out, -x_neck, x_neck, x_out])):
        n_bib = max(1, int(round(rise / hv)))
        rows = []
        for y in y_top + rise * np.linspace(1.0, 0.0, n_bib + 1)[:-1]:
            # below the fillet's top the row reaches out along its arc (``armhole_inset``)
            wide = float(armhole_inset(float(y) - y_top, arm_r)) if arm_r > 0.0 else 0.0
            mask = np.abs(v[:, 0]) <= x_out + wide + 0.03  # the body within 3 cm of the row's ends
            hull = offset_hull(m.band(float(y) - half, float(y) + half, mask), margin + p.ease)
            ring = polar_ring(hull, _ring_center(hull), float(y))
            hr = ring[: hn + 1] if name == "front" else ring[hn:]
            cuts = _cut_indices(hr, [xs[0] + np.sign(xs[0]) * wide, xs[1], xs[2],
                                     xs[3] + np.sign(xs[3]) * wide])
            if not rows:  # the neckline row: strap ends as exact pieces
                tp = _pieces(hr[cuts[0]: cuts[3] + 1], [c - cuts[0] for c in cuts[1:3]], h)
                rows.append(_join(tp))
                ends[name] = tp
                # the straps' straight parts (|x| from x_in), which their columns follow
                c_in = _cut_indices(hr, [xs[0], np.sign(xs[0]) * x_in, -np.sign(xs[0]) * x_in, xs[3]])
                cores[name] = (resample(hr[c_in[0]: c_in[1] + 1], h, min_segments=1),
                               resample(hr[c_in[2]: c_in[3] + 1], h, min_segments=1))
            else:
                rows.append(resample(hr[cuts[0]: cuts[3] + 1], h, min_segments=2))
        rows.append(bib_bottom[name])
        panels.append(Panel(f"{name}_bib", tuple(rows), top=None, bottom=None, local_spacing=True))
        bibs[name] = rows
    # straps, rows running towards +x: (front end reversed, back end); their columns follow the
    # straight parts (from x_in), the rows near either end reach on into the rounded corners
    straps = {
        "left": (ends["front"][0][::-1], ends["back"][2], cores["front"][0][::-1], cores["back"][1], 0),
        "right": (ends["front"][2][::-1], ends["back"][0], cores["front"][1][::-1], cores["back"][0], -1),
    }
    for side, (fe_row, be_row, fe, be, inner) in straps.items():
        n_u = max(len(fe), len(be), 3)
        u = np.linspace(0.0, 1.0, n_u)
        sf, sb = arc_length(fe), arc_length(be)
        fe_u = np.stack([np.interp(u * sf[-1], sf, fe[:, c]) for c in range(3)], axis=1)
        be_u = np.stack([np.interp(u * sb[-1], sb, be[:, c]) for c in range(3)], axis=1)
        half_x = 0.6 * p.strap_width / (n_u - 1) + 0.003  # the columns' slices overlap
        paths = []
        t = np.linspace(0.0, 1.0, 181)
        for a, b in zip(fe_u, be_u, strict=True):
            x = 0.5 * (a[0] + b[0])
            pts = m.band(x - half_x, x + half_x, every, axis=0)
            pts = pts[(pts[:, 1] >= min(a[1], b[1]) - 0.02) & (pts[:, 1] <= j[12, 1] + 0.04)]
            hull = offset_hull(pts, margin + 0.005)
            c = np.array([0.5 * (a[2] + b[2]), min(a[1], b[1])])
            phi_a = np.arctan2(a[1] - c[1], a[2] - c[0])
            phi_b = np.arctan2(b[1] - c[1], b[2] - c[0])
            phi = phi_a + t * (phi_b - phi_a)
            r = _polar(hull, c, phi)[0]
            path = np.stack([a[0] + t * (b[0] - a[0]), c[1] + r * np.sin(phi), c[0] + r * np.cos(phi)],
                            axis=1)
            path[0], path[-1] = a, b
            paths.append(path)
        s_mid = arc_length(paths[len(paths) // 2])
        n_k = max(4, int(round(s_mid[-1] / hv)))
        n_k += n_k % 2  # even: a middle row on the shoulder line
        s_k = np.linspace(0.0, s_mid[-1], n_k + 1)
        if 2.0 * fillet > s_mid[-1]:
            raise WrinklesInputError(f"neck_fillet {p.neck_fillet} m is more than half the strap's length "
                                     f"over the shoulder ({s_mid[-1]:.3f} m)")
        t_k = np.interp(s_k, s_mid, t)
        rows = [fe_row]
        for sk, tk in zip(s_k[1:-1], t_k[1:-1], strict=True):
            row = np.stack([[np.interp(tk, t, pa[:, c]) for c in range(3)] for pa in paths])
            inset = float(fillet_inset(min(sk, s_mid[-1] - sk), fillet))
            rows.append(_extend_inner(resample(row, h, min_segments=2), inner, inset, h))
        rows.append(be_row)
        panels.append(Panel(f"{side}_strap", tuple(rows), top=None, bottom=None,
                            local_spacing=True, marks=((n_k // 2, "shoulders"),)))
        strap_rows[side] = rows
    if p.sleeve_length <= 0:
        return panels
    fp, bp = tube_top
    outer = {"left": (lambda r: r[-1]), "right": (lambda r: r[0])}
    for side, sign in (("left", 1.0), ("right", -1.0)):
        # armhole loop, starting at the side point S of the tube's top row
        f_edge = np.stack([r[0] if sign > 0 else r[-1] for r in bibs["front"]])  # top -> bottom
        b_edge = np.stack([r[-1] if sign > 0 else r[0] for r in bibs["back"]])
        s_edge = np.stack([outer[side](r) for r in strap_rows[side]])  # front -> back
        if sign > 0:
            loop = np.concatenate([fp[0], f_edge[::-1][1:], s_edge[1:], b_edge[1:], bp[2][1:]])
        else:
            loop = np.concatenate([fp[2][::-1], f_edge[::-1][1:], s_edge[1:], b_edge[1:], bp[0][::-1][1:]])
        panels.append(_sleeve_panel(m, p, h, margin, loop, sign, y_top, side))
    return panels


def _sleeve_panel(m: BodyMeasure, p: TopParams, h: float, margin: float, loop: np.ndarray, sign: float,
                  y_top: float, side: str) -> Panel:
    """A sleeve: its first row is the armhole loop; rows blend into rings around the arm
    (planes x = const, the T-pose arm runs along ±x) and end at ``sleeve_length`` from the
    shoulder joint (at most just before the wrist)."""
    j, v = m.joints, m.vertices
    hv = h * np.sqrt(3) / 2
    half = max(hv, 0.01)
    js, jw = (16, 20) if sign > 0 else (17, 21)
    x_ref = float((sign * loop[:, 0]).max())
    x_end = min(sign * j[js, 0] + p.sleeve_length, sign * j[jw, 0] - 0.03)
    n_sl = int(round((x_end - x_ref) / hv))
    if n_sl < 2:
        raise WrinklesInputError(f"sleeve_length {p.sleeve_length} m is too short for edge length {h} m")
    x_d = sign * loop[:, 0]
    n_fade = max(2, min(n_sl, int(np.ceil((x_ref - x_d.min()) / (0.4 * hv)))))
    n_blend = max(2, int(round(BLEND / hv)))
    mask = (sign * v[:, 0] > 0) & (v[:, 1] >= y_top - 0.005)

    def arm_hull(x0: float, x1: float) -> np.ndarray:
        pts = m.band(sign * x0 if sign > 0 else -x1, sign * x1 if sign > 0 else -x0, mask, axis=0)
        return offset_hull(pts, margin + p.ease)  # (z, y)

    h0 = arm_hull(x_ref, x_ref + hv)
    c0 = h0.mean(axis=0)
    # the left loop is walked backwards (mirror image), so both sleeves' windings match the body
    if sign > 0:
        loop = loop[::-1].copy()
        x_d = x_d[::-1]  # indexed like the loop (``_polar`` returns the loop's segments)
    theta = np.arctan2(*(loop[0, [1, 2]] - c0[::-1])) - sign * np.linspace(0.0, 2 * np.pi, _RING_SAMPLES + 1)
    qz = loop[:, [2, 1]]
    r_d, edge, s_d = _polar(qz, c0, theta)
    xd = x_d[edge] + s_d * (np.roll(x_d, -1)[edge] - x_d[edge])
    rows = [loop]
    r_prev = r_d
    for k in range(1, n_sl + 1):
        s = float(_smoothstep(k / n_blend))
        s_x = min(1.0, k / n_fade)
        xk = (1 - s_x) * xd + s_x * x_ref + k * hv
        hull = arm_hull(float(xk.min()) - half, float(xk.max()) + half)
        c = _row_center(c0, hull, k - max(n_blend, n_fade), n_blend)
        r_a = _polar(hull, c, theta)[0]
        # outside the arm's hull, moving at most SLEEVE_STEP row spacings radially per row (a jump
        # to the hull under the arm left a gap of 4 rows between the loop and a fine sleeve's first)
        r = np.clip(np.maximum((1 - s) * r_d + s * r_a, r_a), r_prev - SLEEVE_STEP * hv,
                    r_prev + SLEEVE_STEP * hv)
        r_prev = r
        row = np.stack([sign * xk, c[1] + r * np.sin(theta), c[0] + r * np.cos(theta)], axis=1)
        row[-1] = row[0]
        rows.append(resample(row, h, min_segments=3))
    return Panel(f"{side}_sleeve", tuple(rows), top=None, bottom="cuffs", local_spacing=True)


@dataclass(frozen=True)
class Template:
    """A registry entry.

    Attributes:
        params: the frozen parameter dataclass; defaults: this template's overrides of it.
        build: ``build(measure, params, h, thickness) -> list[Panel]``.
        attachments: the attachment sets every garment of this template has.
        description: one line for listings.
        coarse, fine: edge lengths [m] of the named resolutions, chosen so that the garment on
            the default (mean) body has about 3,000 and 20,000 vertices; the edge length, not
            the count, stays fixed across body shapes and parameters.
        vertices: (coarse, fine) vertex counts on the default body with the defaults, as
            measured (listed by ``wrinkles garments``; tests/test_garments.py keeps them true).
    """

    params: type
    defaults: dict
    build: object
    attachments: tuple[str, ...]
    description: str
    coarse: float
    fine: float
    vertices: tuple[int, int]


_SLEEVED = {"length": 0.42, "strap_width": 0.1, "front_rise": 0.11, "back_rise": 0.13}
"""Shirts: wide shoulder panels (up to the shoulder joint) and higher necklines than a tank top."""

TEMPLATES: dict[str, Template] = {
    "straight_skirt": Template(SkirtParams, {}, skirt_panels, ("waistband", "hem"),
                               "knee-length straight skirt hanging from the waist", 0.0155, 0.006,
                               (3004, 19634)),
    "flared_skirt": Template(SkirtParams, {"flare": 0.6, "length": 0.6, "ease": 0.02}, skirt_panels,
                             ("waistband", "hem"), "A-line skirt widening below the hips", 0.018, 0.007,
                             (3009, 19668)),
    "shorts": Template(PantsParams, {"length": 0.45, "ease": 0.02}, pants_panels, ("waistband", "hem"),
                       "shorts: hip tube split into two legs at the crotch", 0.0145, 0.0055, (3146, 21272)),
    "trousers": Template(PantsParams, {}, pants_panels, ("waistband", "hem"),
                         "full-length trousers, hem above the ankle", 0.02, 0.0075, (3099, 21558)),
    "tank_top": Template(TopParams, {"armhole_fillet": 0.08, "armhole_depth": 0.05}, tank_top_panels,
                         ("shoulders", "hem"),
                         "sleeveless top with shoulder straps", 0.015, 0.006, (3160, 18900)),
    "t_shirt": Template(TopParams, {**_SLEEVED, "sleeve_length": 0.2}, tank_top_panels,
                        ("shoulders", "hem", "cuffs"), "short-sleeved shirt", 0.018, 0.007, (3061, 19542)),
    "long_sleeve": Template(TopParams, {**_SLEEVED, "sleeve_length": 1.0}, tank_top_panels,
                            ("shoulders", "hem", "cuffs"), "long-sleeved shirt, cuffs before the wrists",
                            0.02, 0.0075, (3079, 21438)),
    "dress": Template(TopParams, {"length": 0.95, "flare": 0.35, "ease": 0.025}, tank_top_panels,
                      ("shoulders", "hem"), "sleeveless strap dress flaring below the hips", 0.0235, 0.009,
                      (3193, 20786)),
}

GARMENT_ALIASES: dict[str, str] = {
    "tshirt": "t_shirt", "tee": "t_shirt", "shirt": "t_shirt", "skirt": "straight_skirt",
    "pants": "trousers", "jeans": "trousers", "tank": "tank_top", "longsleeve": "long_sleeve",
}
"""Other names of templates (hyphens, underscores, spaces and case are ignored anyway)."""


def template_name(name: str) -> str | None:
    """The template category a name or alias refers to (case, '-', '_' and ' ' ignored); None
    when it names none."""
    key = name.strip().lower().replace("-", "_").replace(" ", "_")
    compact = key.replace("_", "")
    for t in TEMPLATES:
        if key == t or compact == t.replace("_", ""):
            return t
    return GARMENT_ALIASES.get(compact)
"""Garment categories (registry) → template."""


def resolve_resolution(resolution: str | float, category: str) -> float:
    """Target mean edge length [m] of ``category`` for "coarse", "fine" or a number of metres."""
    if isinstance(resolution, str):
        if resolution not in RESOLUTIONS:
            raise WrinklesInputError(f"unknown resolution {resolution!r}; expected one of "
                                     f"{', '.join(RESOLUTIONS)} or an edge length in metres")
        return getattr(TEMPLATES[category], resolution)
    h = float(resolution)
    if not 0.003 <= h <= 0.2:
        raise WrinklesInputError(f"resolution {resolution} m is outside [0.003, 0.2] m")
    return h


def template_parameters(category: str) -> list[tuple[str, float, str, str]]:
    """A template's parameters as ``(name, default, unit, meaning)``, from its params class's
    ``Attributes:`` docstring (entries ``name: text [unit] more text``)."""
    import re

    if category not in TEMPLATES:
        raise WrinklesInputError(f"unknown garment category {category!r}; expected one of "
                                 f"{', '.join(TEMPLATES)}")
    t = TEMPLATES[category]
    doc = (t.params.__doc__ or "").split("Attributes:", 1)[-1]
    docs: dict[str, str] = {}
    names: list[str] = []
    for line in doc.splitlines():
        m = re.match(r"\s{8}([a-z_0-9]+(?:, [a-z_0-9]+)*): (.*)", line)
        if m:
            names = m.group(1).split(", ")
            for n in names:
                docs[n] = m.group(2).strip()
        elif line.strip() and names:
            for n in names:
                docs[n] += " " + line.strip()
    p = make_params(category)
    out = []
    for f in fields(t.params):
        text = docs.get(f.name, "")
        unit = re.search(r"\[([^\]]*)\]", text)
        meaning = re.sub(r"\s*\[[^\]]*\]", "", text, count=1).strip()
        out.append((f.name, getattr(p, f.name), unit.group(1) if unit else "", user_text(meaning)))
    return out + list(HEM_PARAMETERS)


def user_text(text: str) -> str:
    """A parameter's docstring as users read it (``wrinkles garments --params``, its JSON): the
    developers' asides, "(session 49: ... docs/BENCHMARKS.md)" and a function's name opening a
    parenthesis, left out, ``code`` marks dropped."""
    import re

    text = re.sub(r"\s*\(session \d+[^()]*\)", "", text)
    text = re.sub(r"\(``[a-z_0-9]+``; ", "(", text)  # "(``armhole_inset``; they reach ...": a function name
    text = re.sub(r"[,;]?\s*docs/BENCHMARKS\.md", "", text)
    return re.sub(r"``([^`]*)``", r"\1", text).strip()


# Accepted range of every template parameter ([m], flare [-]); a template can still refuse a value
# inside it that does not fit the body (e.g. a skirt too short for the edge length).
PARAM_RANGES: dict[str, tuple[float, float]] = {
    "length": (0.05, 1.6),
    "ease": (0.0, 0.15),
    "waist_ease": (0.0, 0.05),
    "flare": (0.0, 2.0),
    "waist_offset": (-0.15, 0.15),
    "crotch_ease": (0.0, 0.1),
    "leg_gap": (0.001, 0.05),
    "armhole_depth": (0.0, 0.15),
    "strap_width": (0.02, 0.2),
    "neck_ease": (0.0, 0.1),
    "front_rise": (0.0, 0.3),
    "neck_fillet": (0.0, 0.08),
    "armhole_fillet": (0.0, 0.1),
    "back_rise": (0.0, 0.3),
    "sleeve_length": (0.0, 1.0),
    "hem_width": (0.0, 0.1),
    "hem_layers": (1.0, 4.0),
}

HEM_PARAMETERS: tuple[tuple[str, float, str, str], ...] = (
    ("hem_width", HEM_WIDTH, "m", "width of the hems along every opening (0: none; sim.garments.hems)"),
    ("hem_layers", HEM_LAYERS, "-", "layers of fabric in a hem: its mass, stretch and bending scale"),
)
"""Parameters every template takes besides its params class's: the hems."""
_HEM_NAMES = frozenset(name for name, *_ in HEM_PARAMETERS)


def check_parameter(name: str, value, where: str, path=None) -> None:
    """Raise ``WrinklesInputError`` (``where``: ..., or naming ``path``) unless ``value`` is a
    finite number inside ``PARAM_RANGES[name]``."""
    lo, hi = PARAM_RANGES[name]
    number = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
    prefix = f"{where}: " if path is None else ""
    if not number or not np.isfinite(value):
        raise WrinklesInputError(f"{prefix}parameter {name} must be a number [m or -], got {value!r}",
                                 path=path)
    if not lo <= value <= hi:
        raise WrinklesInputError(f"{prefix}parameter {name} = {value:g} is outside its range "
                                 f"[{lo:g}, {hi:g}]", path=path)


def make_params(category: str, **params: float):
    """Frozen params of ``category`` with the template's defaults, overridden by ``params``."""
    if category not in TEMPLATES:
        raise WrinklesInputError(f"unknown garment category {category!r}; expected one of "
                                 f"{', '.join(TEMPLATES)}")
    t = TEMPLATES[category]
    allowed = {f.name for f in fields(t.params)}
    unknown = set(params) - allowed - _HEM_NAMES
    if unknown:
        raise WrinklesInputError(f"{category}: unknown parameter(s) {sorted(unknown)}; expected "
                                 f"{', '.join(sorted(allowed | _HEM_NAMES))}")
    for k, v in params.items():
        check_parameter(k, v, category)
    return t.params(**{**t.defaults, **{k: v for k, v in params.items() if k in allowed}})


def _untangle(v: np.ndarray, faces: np.ndarray, panel_ids: np.ndarray, names: list[str],
              max_iterations: int = 200) -> np.ndarray:
    """Remove rest-shape self-intersections (a sleeve's first rows can dip through the body
    panel under the arm for some body shapes): Laplacian smoothing of the interior vertices
    within two rings of the crossing edges, sleeve panels first (their rows are the ones that
    fold), until no edge crosses a face. Seams and panel borders stay put. Returns ``v`` itself
    when nothing crosses; when smoothing cannot clear them, the least-crossed shape found."""
    from sim.quality import crossing_edges, unique_edges

    bad = crossing_edges(v, faces, device="cpu")
    if not bad.any():
        return v
    edges, uses = unique_edges(faces, counts=True)
    V = len(v)
    deg = np.bincount(edges.ravel(), minlength=V)
    # interior: every incident face in one panel, and no incident edge with a single face
    fp = np.repeat(np.asarray(panel_ids), 3)
    pmin, pmax = np.full(V, np.iinfo(np.int64).max), np.full(V, -1)
    np.minimum.at(pmin, faces.ravel(), fp)
    np.maximum.at(pmax, faces.ravel(), fp)
    border = np.zeros(V, bool)
    border[edges[uses == 1].ravel()] = True
    interior = (pmin == pmax) & ~border
    sleeve = np.array(["sleeve" in n for n in names])[np.maximum(pmax, 0)] & (pmax >= 0)
    near = np.zeros(V, bool)
    near[edges[bad].ravel()] = True
    for _ in range(2):  # two rings around the crossing edges
        ring = near.copy()
        ring[edges[near[edges[:, 0]], 1]] = True
        ring[edges[near[edges[:, 1]], 0]] = True
        near = ring
    x = v.astype(np.float64)
    best, best_n = v, int(bad.sum())
    for only_sleeves in (True, False):
        move = near & interior & (sleeve | (not only_sleeves))
        if not move.any():
            continue
        for it in range(1, max_iterations + 1):
            avg = np.zeros_like(x)
            np.add.at(avg, edges[:, 0], x[edges[:, 1]])
            np.add.at(avg, edges[:, 1], x[edges[:, 0]])
            x[move] += 0.5 * (avg[move] / deg[move, None] - x[move])
            if it % 5 == 0:
                n = int(crossing_edges(x, faces, device="cpu").sum())
                if n < best_n:
                    best, best_n = x.astype(v.dtype), n
                if best_n == 0:
                    return best
    return best


def make_garment(category: str, body, betas: np.ndarray | None = None, *,
                 resolution: str | float = "coarse", material: str | Material = "cotton",
                 name: str | None = None, **params: float) -> Garment:
    """Generate a garment of ``category`` fitted to ``body`` (shape ``betas``) in rest pose.

    Args:
        category: a key of ``TEMPLATES``.
        body: a ``BodyModel`` (``rest_mesh``, ``rest_joints``, ``weights``).
        betas: shape coefficients, shape (B,); None = mean shape.
        resolution: "coarse" (~3k vertices on the default body), "fine" (~20k) or a target
            edge length [m] (``Template.coarse`` / ``fine`` give each template's edge lengths).
        material: preset name or a ``Material``.
        name: garment name (default: the category).
        **params: fields of the category's params dataclass (e.g. ``length``, ``ease``), and
            ``hem_width`` / ``hem_layers`` (``HEM_PARAMETERS``): the bands of ``face_layers``
            layers along every opening.

    Returns:
        The garment; deterministic for equal arguments.
    """
    p = make_params(category, **params)
    hem_width = float(params.get("hem_width", HEM_WIDTH))
    hem_layers = float(params.get("hem_layers", HEM_LAYERS))
    h = resolve_resolution(resolution, category)
    mat = get_material(material)
    meas = BodyMeasure.of(body, betas)
    panels = TEMPLATES[category].build(meas, p, h, mat.thickness)
    sewn = sew(panels)
    faces = sewn.faces
    v = _untangle(sewn.vertices, faces, sewn.panel_ids, [pn.name for pn in panels])
    # outward orientation: normals should point away from the vertical body axis
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    radial = tri.mean(axis=1) - np.array([0.0, 0.0, meas.joints[0, 2]])
    radial[:, 1] = 0.0
    flip = np.sum(n * radial) < 0
    uv_faces = sewn.uv_faces
    if flip:
        faces, uv_faces = faces[:, ::-1], uv_faces[:, ::-1]
    att: dict[str, list[np.ndarray]] = {}
    for pn, rows in zip(panels, sewn.row_vertices, strict=True):
        if pn.top:
            att.setdefault(pn.top, []).append(rows[0])
        if pn.bottom:
            att.setdefault(pn.bottom, []).append(rows[-1])
        for k, mark in pn.marks:
            att.setdefault(mark, []).append(rows[k])
    att = {k: np.unique(np.concatenate(a)) for k, a in att.items()}
    uv_points = np.empty((len(sewn.uvs_m), 3))
    uv_points[sewn.uv_faces] = v[sewn.faces]
    uvs_m = flatten_panels(uv_points, sewn.uv_faces, sewn.uvs_m, sewn.uv_panel)
    return Garment(rest_vertices=v.astype(np.float32), faces=faces.astype(np.int32),
                   uvs=pack_uvs(uvs_m, sewn.uv_panel), uv_faces=uv_faces.astype(np.int32),
                   material=mat, attachments=att, category=category, name=name or category,
                   panel_ids=sewn.panel_ids.astype(np.int32),
                   panel_names=tuple(pn.name for pn in panels),
                   face_layers=hem_face_layers(v, faces, hem_width, hem_layers))
