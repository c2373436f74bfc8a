"""Shorts and trousers: a hip tube (front, back) from the waist to just above the crotch, split
into two leg tubes at a bridge below the crotch."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from sim.easing import smoothstep
from sim.errors import WrinklesInputError
from sim.garments.measure import (
    BLEND,
    CLEARANCE,
    RING_SAMPLES,
    BodyMeasure,
    clip_half_plane,
    crotch_height,
    offset_hull,
    polar_hits,
    polar_ring,
    ring_center,
    row_center,
    waist_ease,
)
from sim.garments.panels import Panel, resample
from sim.garments.parameters import parameter


@dataclass(frozen=True)
class PantsParams:
    """Parameters of shorts and trousers (unit, range and meaning in each field)."""

    length: float = parameter(1.0, "m", 0.05, 1.6, "waist-to-hem length along the body axis (outseam); "
                              "trousers stop above the ankle joint")
    ease: float = parameter(0.015, "m", 0.0, 0.15, "looseness around the hips and the legs")
    waist_ease: float = parameter(0.004, "m", 0.0, 0.05, "looseness at the waistband")
    crotch_ease: float = parameter(0.02, "m", 0.0, 0.1, "extra gap below the body's crotch")
    waist_offset: float = parameter(0.0, "m", -0.15, 0.15, "waistband height above SMPL's spine1 joint")
    leg_gap: float = parameter(0.003, "m", 0.001, 0.05, "least distance between the two legs' inner walls: "
                               "where a leg's hull with its ease would reach within half of it of the "
                               "mid-sagittal plane (between the thighs), its inner wall is cut flat there")


@dataclass(frozen=True)
class _Crotch:
    """Where the hip tube splits into the legs."""

    quarters: list[np.ndarray]  # the split row cut at its left side, front centre F, right side and
    # back centre B
    front_half: np.ndarray  # the bridge from F down to C, the inseam point
    back_half: np.ndarray  # the bridge from C up to B
    depth: float  # of C below the split row [m]


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
    hv = h * np.sqrt(3) / 2
    margin = thickness + CLEARANCE
    y_waist = j[3, 1] + p.waist_offset
    y_cr = crotch_height(m)
    y_c = y_cr + 0.4 * hv  # the split row, just above the body's crotch
    y_lowest = j[7, 1] + 0.05  # trousers stop above the ankle joint (the foot is not a tube)
    y_hem = max(y_waist - p.length, y_lowest)
    if y_waist - y_c < 2 * hv:
        raise WrinklesInputError("waist is too close to the crotch for these pants")
    n_leg = int(round((y_c - y_hem) / hv))
    if n_leg < 3:
        raise WrinklesInputError(f"pants length {p.length} m leaves no leg at edge length {h} m "
                                 f"(the crotch is {y_waist - y_c:.3f} m below the waist)")
    ease_at = partial(waist_ease, y_waist=y_waist, y_hip=j[1, 1], margin=margin, waist=p.waist_ease,
                      ease=p.ease)
    front, back, ring = _hip_tube(m, h, y_waist, y_c, ease_at)
    crotch = _crotch(ring, y_c, (y_c - y_cr) + margin + p.crotch_ease, h)
    q = crotch.quarters
    front[-1] = np.concatenate([q[0], q[1][1:]])
    back[-1] = np.concatenate([q[2], q[3][1:]])
    panels = [Panel("front", tuple(front), bottom=None, local_spacing=True),
              Panel("back", tuple(back), bottom=None, local_spacing=True)]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        panels.append(_leg_panel(m, p, h, crotch, side, sign, y_c, n_leg, ease_at))
    return panels


def _hip_tube(m: BodyMeasure, h: float, y_waist: float, y_c: float, ease_at):
    """Front and back rows from the waist down to the split row at ``y_c``, and that row's
    dense ring (``polar_ring``)."""
    hv = h * np.sqrt(3) / 2
    half = max(hv, 0.01)
    n_up = max(2, int(round((y_waist - y_c) / hv))) + 1
    front, back = [], []
    ring = None
    for y in np.linspace(y_waist, y_c, n_up):
        hull = offset_hull(m.band(float(y) - half, float(y) + half, m.torso_mask), ease_at(float(y)))
        ring = polar_ring(hull, ring_center(hull), float(y))
        hn = RING_SAMPLES // 2
        front.append(resample(ring[: hn + 1], h, min_segments=2))
        back.append(resample(ring[hn:], h, min_segments=2))
    return front, back, ring


def _crotch(ring: np.ndarray, y_c: float, depth: float, h: float) -> _Crotch:
    """The split row's quarters and the bridge F -> C -> B in the plane of F and B, ``depth``
    [m] below the row at its lowest point C."""
    qn = RING_SAMPLES // 4
    q = [resample(ring[k * qn: (k + 1) * qn + 1], h, min_segments=1) for k in range(4)]
    f_pt, b_pt = ring[qn], ring[3 * qn]
    phi = np.linspace(0.0, np.pi, 201)
    t = phi / np.pi  # even in the plane: the ends of the bridge stay less steep than (1 - cos)/2
    bridge = f_pt[None] + t[:, None] * (b_pt - f_pt)[None]
    bridge[:, 1] = y_c - depth * np.sqrt(np.sin(phi).clip(0.0))
    bridge[0], bridge[-1] = f_pt, b_pt
    fh = resample(bridge[:101], h, min_segments=1)  # F -> C
    bh = resample(bridge[100:], h, min_segments=1)  # C -> B
    return _Crotch(q, fh, bh, depth)


def _leg_panel(m: BodyMeasure, p: PantsParams, h: float, crotch: _Crotch, side: str, sign: float,
               y_c: float, n_leg: int, ease_at) -> Panel:
    """One leg: its first row is the loop (half the split row + the bridge) opened at the
    inseam, its next rows blend into rings on the leg's hull, clipped off the mid-plane."""
    hv = h * np.sqrt(3) / 2
    half = max(hv, 0.01)
    q, fh, bh = crotch.quarters, crotch.front_half, crotch.back_half
    n_blend = max(2, int(round(BLEND / hv)))
    clip = 0.5 * p.leg_gap  # leg tubes stay at |x| >= clip so the two legs never cross
    n_fade = max(1, min(n_leg, max(n_blend, int(np.ceil(crotch.depth / (0.4 * hv))))))
    if sign > 0:  # counter-clockwise seen from above, starting at the inseam point C
        loop = np.concatenate([bh, q[3][1:], q[0][1:], fh[1:]])
        theta = np.pi + np.linspace(0.0, 2 * np.pi, RING_SAMPLES + 1)
    else:
        loop = np.concatenate([fh[::-1], q[1][1:], q[2][1:], bh[::-1][1:]])
        theta = np.linspace(0.0, 2 * np.pi, RING_SAMPLES + 1)
    leg_mask = m.torso_mask & (sign * m.vertices[:, 0] > 0)

    def leg_hull(y0: float, y1: float, off: float) -> np.ndarray:
        return clip_half_plane(offset_hull(m.band(y0 - half, y1 + half, leg_mask), off), sign, clip)

    h0 = leg_hull(y_c - hv, y_c - hv, ease_at(y_c - hv))
    c0 = h0.mean(axis=0)
    r_d, edge, s_d = polar_hits(loop[:, [0, 2]], c0, theta)
    y_d = loop[edge, 1] + s_d * (np.roll(loop[:, 1], -1)[edge] - loop[edge, 1])
    rows = [loop]
    for k in range(1, n_leg + 1):
        s = float(smoothstep(k / n_blend))
        s_y = min(1.0, k / n_fade)  # linear: the inner side rows stay >= 0.6 hv apart
        yk = (1 - s_y) * y_d + s_y * y_c - k * hv
        hull = leg_hull(float(yk.min()), float(yk.max()), ease_at(float(yk.mean())))
        c = row_center(c0, hull, k - max(n_blend, n_fade), n_blend)
        r_l = polar_hits(hull, c, theta)[0]
        r = np.maximum((1 - s) * r_d + s * r_l, r_l)
        row = np.stack([c[0] + r * np.cos(theta), yk, c[1] + r * np.sin(theta)], axis=1)
        # off the mid-plane, where the other leg's rows are: the blend from the loop's bridge
        # (x = 0) would leave both legs' first inner rows in the plane, the faces of one leg
        # on the other's
        row[:, 0] = sign * np.maximum(sign * row[:, 0], clip)
        row[-1] = row[0]
        rows.append(resample(row, h, min_segments=3))
    return Panel(f"{side}_leg", tuple(rows), top=None, local_spacing=True)
