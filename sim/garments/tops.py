"""Tops: tank top, t-shirt, long sleeve and dress, one pattern.

A body tube (front, back) hangs from below the armpits to the hem; a front and a back bib rise
between the armholes to the necklines; two shoulder straps run over the shoulders from one bib
to the other; sleeves, when asked for, leave the armhole loops (``sim.garments.sleeves``). The
shirts are a tank top with wide straps and sleeves, the dress a long flared tank top.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import ConvexHull

from sim.easing import smoothstep
from sim.errors import WrinklesInputError
from sim.garments.measure import (
    CLEARANCE,
    RING_SAMPLES,
    BodyMeasure,
    offset_hull,
    polar_hits,
    polar_ring,
    ring_center,
)
from sim.garments.panels import Panel, arc_length, resample
from sim.garments.parameters import parameter
from sim.garments.sleeves import sleeve_panel


@dataclass(frozen=True)
class TopParams:
    """Parameters of the tank top, t-shirt, long sleeve and dress (unit, range and meaning in
    each field)."""

    length: float = parameter(0.4, "m", 0.05, 1.6,
                              "from the top of the body tube (below the armpit) down to the hem")
    ease: float = parameter(0.02, "m", 0.0, 0.15, "looseness around the torso")
    armhole_depth: float = parameter(
        0.03, "m", 0.0, 0.15, "how far below the armpit the armhole's lowest point lies. The "
        "necklines' rises and the length are measured from that point, so a deeper armhole also "
        "lowers the necklines and the hem and lengthens the straps")
    strap_width: float = parameter(0.06, "m", 0.02, 0.2, "shoulder strap width")
    neck_ease: float = parameter(0.02, "m", 0.0, 0.1, "gap between the neck and the inner edge of a strap")
    front_rise: float = parameter(0.08, "m", 0.0, 0.3,
                                  "front neckline's height above the armhole's lowest point")
    back_rise: float = parameter(0.10, "m", 0.0, 0.3,
                                 "back neckline's height above the armhole's lowest point")
    neck_fillet: float = parameter(
        0.02, "m", 0.0, 0.08, "radius of the rounded corners where the neckline meets the straps, at "
        "most what leaves a neckline four edges wide; 0: square corners, where stress concentrates in "
        "the cloth (a re-entrant corner) and the largest edge strain grows as the mesh is refined")
    armhole_fillet: float = parameter(
        0.0, "m", 0.0, 0.1, "radius of the arcs that round the corners where a bib's side meets the "
        "body tube's top row (the armhole's bottom): tangent to the side, meeting the row at 45° (they "
        "reach 0.29 x the radius out from the side and 0.71 x up it), capped at 3/4 of the lower rise "
        "up the side and where the armhole's bottom would keep less than two edges; 0: square corners "
        "(about 270 degrees of cloth)")
    flare: float = parameter(0.0, "-", 0.0, 2.0, "extra radius at the hem relative to the hips (dresses)")
    sleeve_length: float = parameter(0.0, "m", 0.0, 1.0, "sleeve length from the shoulder joint along "
                                     "the arm; 0 = none (the armholes stay open); sleeves stop 3 cm "
                                     "before the wrist")


ARMHOLE_FILLET_ANGLE = np.pi / 4
"""Angle [rad] from the horizontal at which an armhole fillet meets the tube's top row (a square
corner meets it at 90°). A quarter circle tangent to the row crosses the bib's last rows at a
glancing angle and leaves slivers (2.9° at the fine size with a 4 cm radius); at 45° the cloth
around the corner is 225° instead of 270°."""


def fillet_inset(s: np.ndarray | float, radius: float) -> np.ndarray:
    """How far [m] a quarter-circle fillet of ``radius`` [m] reaches beyond a strap's straight
    inner edge at distance ``s`` [m] along the strap from the neckline: ``radius`` at the
    neckline (where the fillet meets it tangentially), 0 from ``radius`` on (where it meets the
    strap's edge tangentially)."""
    d = np.clip(radius - np.asarray(s, dtype=float), 0.0, radius)
    return radius - np.sqrt(np.maximum(radius * radius - d * d, 0.0))


def armhole_inset(dy: np.ndarray | float, radius: float,
                  angle: float = ARMHOLE_FILLET_ANGLE) -> np.ndarray:
    """How far [m] an armhole fillet of ``radius`` [m] reaches beyond a bib's straight side at
    height ``dy`` [m] above the tube's top row: an arc of the circle of ``radius`` tangent to the
    side at ``radius * sin(angle)`` above the row, meeting the row at ``angle`` from the
    horizontal (``radius * (1 - cos(angle))`` out from the side there), 0 above its top."""
    top = radius * np.sin(angle)
    t = np.clip((top - np.asarray(dy, dtype=float)) / max(radius, 1e-12), 0.0, np.sin(angle))
    return radius * (1.0 - np.sqrt(1.0 - t * t))


@dataclass(frozen=True)
class _TopFrame:
    """Heights and widths a top's panels share [m]."""

    margin: float  # cloth thickness + clearance
    y_top: float  # the body tube's top row, the armholes' bottom
    length: float  # of the body tube
    x_in: float  # |x| of a strap's straight inner edge
    x_out: float  # |x| of a strap's outer edge, the bibs' sides
    fillet: float  # radius of the neckline's rounded corners
    x_neck: float  # |x| of the neckline's ends, where the rounded corners start
    arm_r: float  # radius of the armholes' rounded bottom corners


def tank_top_panels(m: BodyMeasure, p: TopParams, h: float, thickness: float) -> list[Panel]:
    """Tank top: a body tube (front, back) hanging from below the armpits to the hem, a front
    and a back bib between the armholes up to the necklines, and two shoulder straps.

    Every row is an arc of the body's offset cross-section hull. The bibs' bottom rows are
    the middle of the tube's top row, their top rows carry the straps' ends as exact sample
    points. A strap's rows run across its width and follow the shoulder's sagittal section
    (offset hull of the body in the (z, y) plane at that x) from the front neckline, over the
    shoulder, to the back neckline; its middle row is the ``shoulders`` attachment.
    """
    f = _top_frame(m, p, h, thickness)
    front, back, fp, bp, f = _body_tube(m, p, h, f)
    panels = [Panel("front", tuple(front), top=None), Panel("back", tuple(back), top=None)]
    # bibs between the armholes, from the necklines down to the tube
    ends, cores, bibs = {}, {}, {}
    for name, rise, xs, bottom in (("front", p.front_rise, [f.x_out, f.x_neck, -f.x_neck, -f.x_out], fp[1]),
                                   ("back", p.back_rise, [-f.x_out, -f.x_neck, f.x_neck, f.x_out], bp[1])):
        rows, ends[name], cores[name] = _bib_rows(m, p, h, f, name, rise, xs)
        rows.append(bottom)
        panels.append(Panel(f"{name}_bib", tuple(rows), top=None, bottom=None, local_spacing=True))
        bibs[name] = rows
    # straps, rows running towards +x: (front end reversed, back end); their columns follow the
    # straight parts (from x_in), the rows near either end reach on into the rounded corners
    straps = {
        "left": (ends["front"][0][::-1], ends["back"][2], cores["front"][0][::-1], cores["back"][1], 0),
        "right": (ends["front"][2][::-1], ends["back"][0], cores["front"][1][::-1], cores["back"][0], -1),
    }
    strap_rows = {}
    for side, (fe_row, be_row, fe, be, inner) in straps.items():
        rows, n_k = _strap_rows(m, p, h, f, fe_row, be_row, fe, be, inner)
        panels.append(Panel(f"{side}_strap", tuple(rows), top=None, bottom=None,
                            local_spacing=True, marks=((n_k // 2, "shoulders"),)))
        strap_rows[side] = rows
    if p.sleeve_length <= 0:
        return panels
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
        panels.append(sleeve_panel(m, p.ease, p.sleeve_length, h, f.margin, loop, sign, f.y_top, side))
    return panels


def _top_frame(m: BodyMeasure, p: TopParams, h: float, thickness: float) -> _TopFrame:
    """The armholes' height, the tube's length and the straps' and neckline's widths on this
    body (``WrinklesInputError`` where the body leaves no room for them)."""
    j = m.joints
    v = m.vertices
    margin = thickness + CLEARANCE
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
    # the armholes' rounded bottom corners: the bibs' sides curve out into the tube's top row
    arm_r = min(p.armhole_fillet, 0.75 * min(p.front_rise, p.back_rise) / np.sin(ARMHOLE_FILLET_ANGLE))
    return _TopFrame(margin, y_top, length, x_in, x_out, fillet, x_in - fillet, arm_r)


def _body_tube(m: BodyMeasure, p: TopParams, h: float, f: _TopFrame):
    """Front and back rows of the tube, hanging from the hull of all that is above each row;
    the top row's front and back cut into (side, middle, side) pieces at the armholes, the
    middle pieces the bibs' bottom rows; and the frame with the armhole fillet capped so the
    armhole's bottom keeps two edges before the tube's side (a slim body gets smaller corners).

    Returns:
        (front rows, back rows, front top pieces, back top pieces, frame).
    """
    j = m.joints
    hv = h * np.sqrt(3) / 2
    half = max(hv, 0.01)
    hn = RING_SAMPLES // 2
    n_rows = max(3, int(round(f.length / hv)) + 1)
    y_hip, y_hem = j[1, 1], f.y_top - f.length
    front, back = [], []
    acc = m.band(f.y_top, f.y_top + half, m.torso_mask)
    for k, y in enumerate(f.y_top - np.linspace(0.0, f.length, n_rows)):
        acc = np.concatenate([acc, m.band(float(y) - half, float(y) + half, m.torso_mask)])
        acc = acc[ConvexHull(acc).vertices]  # hanging cloth: hull of all that is above
        hull = offset_hull(acc, f.margin + p.ease)
        center = ring_center(hull)
        if p.flare and y < y_hip:
            grow = p.flare * float(smoothstep((y_hip - y) / (y_hip - y_hem)))
            hull = center + (hull - center) * (1.0 + grow)
        ring = polar_ring(hull, center, float(y))
        if k > 0:
            front.append(resample(ring[: hn + 1], h, min_segments=2))
            back.append(resample(ring[hn:], h, min_segments=2))
            continue
        room = float(np.abs(ring[:, 0]).max()) - f.x_out - 2 * h
        arm_r = max(0.0, min(f.arm_r, room / float(armhole_inset(0.0, 1.0))))
        x_arm = f.x_out + float(armhole_inset(0.0, arm_r))
        fp = _pieces(ring[: hn + 1], _cut_indices(ring[: hn + 1], [x_arm, -x_arm]), h)
        bp = _pieces(ring[hn:], _cut_indices(ring[hn:], [-x_arm, x_arm]), h)
        front.append(_join(fp))
        back.append(_join(bp))
    return front, back, fp, bp, replace(f, arm_r=arm_r)


def _bib_rows(m: BodyMeasure, p: TopParams, h: float, f: _TopFrame, name: str, rise: float,
              xs: list[float]):
    """A bib's rows from its neckline down to (not including) the tube's top row, each cut
    between the armholes at ``xs`` = (outer, neckline end, neckline end, outer) [m].

    Returns:
        (rows, the neckline row's pieces (strap end, neckline, strap end), the straps'
        straight parts on the neckline row (from ``x_in`` out)).
    """
    v = m.vertices
    hv = h * np.sqrt(3) / 2
    half = max(hv, 0.01)
    hn = RING_SAMPLES // 2
    n_bib = max(1, int(round(rise / hv)))
    rows = []
    for y in f.y_top + rise * np.linspace(1.0, 0.0, n_bib + 1)[:-1]:
        # below the fillet's top the row reaches out along its arc (``armhole_inset``)
        wide = float(armhole_inset(float(y) - f.y_top, f.arm_r)) if f.arm_r > 0.0 else 0.0
        mask = np.abs(v[:, 0]) <= f.x_out + wide + 0.03  # the body within 3 cm of the row's ends
        hull = offset_hull(m.band(float(y) - half, float(y) + half, mask), f.margin + p.ease)
        ring = polar_ring(hull, ring_center(hull), float(y))
        hr = ring[: hn + 1] if name == "front" else ring[hn:]
        cuts = _cut_indices(hr, [xs[0] + np.sign(xs[0]) * wide, xs[1], xs[2],
                                 xs[3] + np.sign(xs[3]) * wide])
        if not rows:  # the neckline row: strap ends as exact pieces
            tp = _pieces(hr[cuts[0]: cuts[3] + 1], [c - cuts[0] for c in cuts[1:3]], h)
            rows.append(_join(tp))
            ends = tp
            # the straps' straight parts (|x| from x_in), which their columns follow
            c_in = _cut_indices(hr, [xs[0], np.sign(xs[0]) * f.x_in, -np.sign(xs[0]) * f.x_in, xs[3]])
            cores = (resample(hr[c_in[0]: c_in[1] + 1], h, min_segments=1),
                     resample(hr[c_in[2]: c_in[3] + 1], h, min_segments=1))
        else:
            rows.append(resample(hr[cuts[0]: cuts[3] + 1], h, min_segments=2))
    return rows, ends, cores


def _strap_rows(m: BodyMeasure, p: TopParams, h: float, f: _TopFrame, fe_row: np.ndarray,
                be_row: np.ndarray, fe: np.ndarray, be: np.ndarray, inner: int):
    """A strap's rows from the front neckline row's end piece ``fe_row`` over the shoulder to
    the back's ``be_row``, across the strap at even arc length along its middle column; rows
    near either end reach on into the neckline's rounded corners at their ``inner`` end.

    Returns:
        (rows, number of row spacings ``n_k``, even: row ``n_k // 2`` lies on the shoulder line).
    """
    hv = h * np.sqrt(3) / 2
    n_u = max(len(fe), len(be), 3)
    u = np.linspace(0.0, 1.0, n_u)
    sf, sb = arc_length(fe), arc_length(be)
    fe_u = np.stack([np.interp(u * sf[-1], sf, fe[:, c]) for c in range(3)], axis=1)
    be_u = np.stack([np.interp(u * sb[-1], sb, be[:, c]) for c in range(3)], axis=1)
    t = np.linspace(0.0, 1.0, 181)
    paths = _strap_columns(m, p, f, fe_u, be_u, t)
    s_mid = arc_length(paths[len(paths) // 2])
    n_k = max(4, int(round(s_mid[-1] / hv)))
    n_k += n_k % 2  # even: a middle row on the shoulder line
    s_k = np.linspace(0.0, s_mid[-1], n_k + 1)
    if 2.0 * f.fillet > s_mid[-1]:
        raise WrinklesInputError(f"neck_fillet {p.neck_fillet} m is more than half the strap's length "
                                 f"over the shoulder ({s_mid[-1]:.3f} m)")
    t_k = np.interp(s_k, s_mid, t)
    rows = [fe_row]
    for sk, tk in zip(s_k[1:-1], t_k[1:-1], strict=True):
        row = np.stack([[np.interp(tk, t, pa[:, c]) for c in range(3)] for pa in paths])
        inset = float(fillet_inset(min(sk, s_mid[-1] - sk), f.fillet))
        rows.append(_extend_inner(resample(row, h, min_segments=2), inner, inset, h))
    rows.append(be_row)
    return rows, n_k


def _strap_columns(m: BodyMeasure, p: TopParams, f: _TopFrame, fe_u: np.ndarray, be_u: np.ndarray,
                   t: np.ndarray) -> list[np.ndarray]:
    """One dense path per strap column from its front end to its back end over the shoulder,
    on the offset hull of the body's sagittal slice at the column's x, sampled at the
    parameters ``t`` of the angle about a centre below the ends."""
    j = m.joints
    every = np.ones(len(m.vertices), bool)
    half_x = 0.6 * p.strap_width / (len(fe_u) - 1) + 0.003  # the columns' slices overlap
    paths = []
    for a, b in zip(fe_u, be_u, strict=True):
        x = 0.5 * (a[0] + b[0])
        pts = m.band(x - half_x, x + half_x, every, axis=0)
        pts = pts[(pts[:, 1] >= min(a[1], b[1]) - 0.02) & (pts[:, 1] <= j[12, 1] + 0.04)]
        hull = offset_hull(pts, f.margin + 0.005)
        c = np.array([0.5 * (a[2] + b[2]), min(a[1], b[1])])
        phi_a = np.arctan2(a[1] - c[1], a[2] - c[0])
        phi_b = np.arctan2(b[1] - c[1], b[2] - c[0])
        phi = phi_a + t * (phi_b - phi_a)
        r = polar_hits(hull, c, phi)[0]
        path = np.stack([a[0] + t * (b[0] - a[0]), c[1] + r * np.sin(phi), c[0] + r * np.cos(phi)],
                        axis=1)
        path[0], path[-1] = a, b
        paths.append(path)
    return paths


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
