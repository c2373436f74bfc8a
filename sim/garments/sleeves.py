"""Sleeves: a branch off a top's armhole loop, blending into rings around the arm."""

from __future__ import annotations

import numpy as np

from sim.easing import smoothstep
from sim.errors import WrinklesInputError
from sim.garments.measure import BLEND, RING_SAMPLES, BodyMeasure, offset_hull, polar_hits, row_center
from sim.garments.panels import Panel, resample

SLEEVE_STEP = 1.0
"""Most a sleeve row's radius (about the arm) changes from the previous row's, in row spacings:
where the armhole loop lies inside the arm's hull (under the arm, whose hull takes in the
torso's side) the rows reach the hull over a few rows instead of in one jump, which would leave
a gap of 4 row spacings between the loop and a fine sleeve's first row."""


def sleeve_panel(m: BodyMeasure, ease: float, sleeve_length: float, h: float, margin: float,
                 loop: np.ndarray, sign: float, y_top: float, side: str) -> Panel:
    """A sleeve: its first row is the armhole loop; rows blend into rings around the arm
    (planes x = const, the T-pose arm runs along ±x) and end at ``sleeve_length`` [m] from the
    shoulder joint (at most just before the wrist).

    Args:
        m: the body; ease: looseness around the arm [m]; h: edge length [m];
        margin: cloth thickness + clearance [m]; loop: the armhole loop (L, 3), starting at
        the tube's side point; sign: +1 for the left arm (+x), -1 for the right;
        y_top: the armhole's bottom [m] (the arm's slices keep the body above it); side: name.
    """
    j, v = m.joints, m.vertices
    hv = h * np.sqrt(3) / 2
    half = max(hv, 0.01)
    js, jw = (16, 20) if sign > 0 else (17, 21)
    x_ref = float((sign * loop[:, 0]).max())
    x_end = min(sign * j[js, 0] + sleeve_length, sign * j[jw, 0] - 0.03)
    n_sl = int(round((x_end - x_ref) / hv))
    if n_sl < 2:
        raise WrinklesInputError(f"sleeve_length {sleeve_length} m is too short for edge length {h} m")
    x_d = sign * loop[:, 0]
    n_fade = max(2, min(n_sl, int(np.ceil((x_ref - x_d.min()) / (0.4 * hv)))))
    n_blend = max(2, int(round(BLEND / hv)))
    mask = (sign * v[:, 0] > 0) & (v[:, 1] >= y_top - 0.005)

    def arm_hull(x0: float, x1: float) -> np.ndarray:
        pts = m.band(sign * x0 if sign > 0 else -x1, sign * x1 if sign > 0 else -x0, mask, axis=0)
        return offset_hull(pts, margin + ease)  # (z, y)

    h0 = arm_hull(x_ref, x_ref + hv)
    c0 = h0.mean(axis=0)
    # the left loop is walked backwards (mirror image), so both sleeves' windings match the body
    if sign > 0:
        loop = loop[::-1].copy()
        x_d = x_d[::-1]  # indexed like the loop (``polar_hits`` returns the loop's segments)
    theta = np.arctan2(*(loop[0, [1, 2]] - c0[::-1])) - sign * np.linspace(0.0, 2 * np.pi, RING_SAMPLES + 1)
    qz = loop[:, [2, 1]]
    r_d, edge, s_d = polar_hits(qz, c0, theta)
    xd = x_d[edge] + s_d * (np.roll(x_d, -1)[edge] - x_d[edge])
    rows = [loop]
    r_prev = r_d
    for k in range(1, n_sl + 1):
        s = float(smoothstep(k / n_blend))
        s_x = min(1.0, k / n_fade)
        xk = (1 - s_x) * xd + s_x * x_ref + k * hv
        hull = arm_hull(float(xk.min()) - half, float(xk.max()) + half)
        c = row_center(c0, hull, k - max(n_blend, n_fade), n_blend)
        r_a = polar_hits(hull, c, theta)[0]
        # outside the arm's hull, moving at most SLEEVE_STEP row spacings radially per row
        r = np.clip(np.maximum((1 - s) * r_d + s * r_a, r_a), r_prev - SLEEVE_STEP * hv,
                    r_prev + SLEEVE_STEP * hv)
        r_prev = r
        row = np.stack([sign * xk, c[1] + r * np.sin(theta), c[0] + r * np.cos(theta)], axis=1)
        row[-1] = row[0]
        rows.append(resample(row, h, min_segments=3))
    return Panel(f"{side}_sleeve", tuple(rows), top=None, bottom="cuffs", local_spacing=True)
