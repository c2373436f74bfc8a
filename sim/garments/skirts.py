"""Skirts: one tube from the waist down, front and back panels, straight or flared."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from sim.easing import smoothstep
from sim.errors import WrinklesInputError
from sim.garments.measure import (
    CLEARANCE,
    RING_SAMPLES,
    BodyMeasure,
    offset_hull,
    polar_ring,
    ring_center,
    waist_ease,
)
from sim.garments.panels import Panel, resample
from sim.garments.parameters import parameter


@dataclass(frozen=True)
class SkirtParams:
    """Parameters of the straight and flared skirts (unit, range and meaning in each field)."""

    length: float = parameter(0.55, "m", 0.05, 1.6, "waist-to-hem length along the body axis")
    ease: float = parameter(0.015, "m", 0.0, 0.15, "looseness added around the hips and below "
                            "(distance from the hull of the body to the cloth)")
    waist_ease: float = parameter(0.004, "m", 0.0, 0.05, "looseness at the waistband")
    flare: float = parameter(0.0, "-", 0.0, 2.0, "extra radius at the hem relative to the hips "
                             "(0 = straight, 0.6 = A-line)")
    waist_offset: float = parameter(0.0, "m", -0.15, 0.15, "waistband height above SMPL's spine1 joint")


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
        hull = offset_hull(acc, waist_ease(y, y_waist, y_hip, margin, p.waist_ease, p.ease))
        center = ring_center(hull)
        if p.flare:
            k = 1.0 + p.flare * float(smoothstep((j[1, 1] - y) / max(length - (y_waist - y_hip), 1e-3)))
            hull = center + (hull - center) * k
        ring = polar_ring(hull, center, float(y))
        half_n = RING_SAMPLES // 2
        front.append(resample(ring[: half_n + 1], h, min_segments=2))
        back.append(resample(ring[half_n:], h, min_segments=2))
    return [Panel("front", tuple(front)), Panel("back", tuple(back))]
