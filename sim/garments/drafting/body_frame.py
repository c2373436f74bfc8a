"""Where panels go around the rest body before sewing: cylinders around the torso, arms and legs.

A torso panel wraps a vertical cylinder around the torso's centre at chest height, wide enough
that the panel's half width reaches the body's side and clears it (``torso_cylinder``). A sleeve
wraps a cylinder around the arm's axis (shoulder to elbow joint), a trouser leg one around the
leg's axis (hip to knee joint).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.garments.pattern import Placement

CLEARANCE = 0.02
"""Least gap [m] between a placed panel and the body it wraps (sewing pulls it in)."""
SMPL = {"pelvis": 0, "head": 15, "left_hip": 1, "right_hip": 2, "left_knee": 4, "right_knee": 5, "neck": 12,
        "left_shoulder": 16, "right_shoulder": 17, "left_elbow": 18, "right_elbow": 19,
        "left_wrist": 20, "right_wrist": 21}
"""SMPL joint indices the placements read."""


@dataclass(frozen=True)
class TorsoSection:
    """A horizontal section of the torso at one height [m]: centre (x, z), half width (x) and
    half depth (z) of the body there, arms left out."""

    y: float
    cx: float
    cz: float
    half_width: float
    half_depth: float


def torso_section(vertices: np.ndarray, torso_mask: np.ndarray, y: float, half: float = 0.02) -> TorsoSection:
    """The torso's extent within ``half`` [m] of height ``y``."""
    sel = torso_mask & (np.abs(vertices[:, 1] - y) <= half)
    xz = vertices[sel][:, [0, 2]]
    lo, hi = xz.min(axis=0), xz.max(axis=0)
    c = 0.5 * (lo + hi)
    half_w, half_d = 0.5 * (hi - lo)
    return TorsoSection(float(y), float(c[0]), float(c[1]), float(half_w), float(half_d))


def torso_cylinder(section: TorsoSection, panel_half_width: float, front: bool, hem_y: float,
                   hem_half_width: float | None = None) -> Placement:
    """Placement of a front (``front``) or back torso panel whose x = 0 is the centre line and
    y = 0 the hem at height ``hem_y``: a vertical cylinder around the section's centre, a
    quarter turn per ``panel_half_width`` unless the body needs a wider one. With
    ``hem_half_width`` (a skirt or dress widening below the section) it becomes a cone below the
    section's height, wide enough that the hem also turns at most a quarter."""
    r = max(2.0 * panel_half_width / np.pi, section.half_width + CLEARANCE,
            section.half_depth + CLEARANCE)
    sign = 1.0 if front else -1.0
    height = section.y - hem_y
    slope = 0.0
    if hem_half_width is not None and height > 0:
        slope = min(0.0, (r - 2.0 * hem_half_width / np.pi) / height)
    return Placement(anchor=(section.cx, section.y, section.cz + sign * r), u_dir=(sign, 0.0, 0.0),
                     v_dir=(0.0, 1.0, 0.0), curvature=1.0 / r, origin=(0.0, height), radius_slope=slope)


def limb_cylinder(root: np.ndarray, toward: np.ndarray, start: float, circumference: float,
                  limb_radius: float, top: tuple[float, float], up: np.ndarray,
                  bottom: tuple[float, float] | None = None) -> Placement:
    """Placement of a tube panel (sleeve, trouser leg) around the limb from joint ``root``
    toward joint ``toward``: the panel's y axis points back up the limb to the root, its point
    ``top`` lands ``start`` [m] from the root along the limb axis on the side ``up`` (the
    panel's centre line: the top of the arm, the front of the leg), and it wraps the axis at
    radius ``circumference`` / 2π (at least the limb's radius plus ``CLEARANCE``). With
    ``bottom`` = (circumference, limb radius) at the panel's y = 0 row (a cuff), it wraps a cone
    that narrows or widens to that row's own radius."""
    axis = np.asarray(toward, np.float64) - np.asarray(root, np.float64)
    axis /= np.linalg.norm(axis)
    v = -axis
    n = np.asarray(up, np.float64) - np.dot(up, v) * v
    n /= np.linalg.norm(n)
    u = np.cross(v, n)
    r = max(circumference / (2 * np.pi), limb_radius + CLEARANCE)
    slope = 0.0
    if bottom is not None and top[1] > 0:
        r_end = max(bottom[0] / (2 * np.pi), bottom[1] + CLEARANCE)
        slope = (r - r_end) / top[1]
    anchor = np.asarray(root, np.float64) + axis * start + n * r
    return Placement(anchor=tuple(anchor), u_dir=tuple(u), v_dir=tuple(v), curvature=1.0 / r,
                     origin=(float(top[0]), float(top[1])), radius_slope=slope)


def limb_radius(vertices: np.ndarray, mask: np.ndarray, root: np.ndarray, toward: np.ndarray,
                span: tuple[float, float] | None = None) -> float:
    """Largest distance [m] of the masked body vertices from the limb axis (``root`` to
    ``toward``) between distances ``span`` [m] from the root along it (default: from a tenth
    of the way to the end)."""
    axis = np.asarray(toward, np.float64) - np.asarray(root, np.float64)
    length = float(np.linalg.norm(axis))
    axis /= length
    lo, hi = span if span is not None else (0.1 * length, length)
    d = vertices[mask] - root
    t = d @ axis
    keep = (t >= lo) & (t <= hi)
    radial = d[keep] - np.outer(t[keep], axis)
    return float(np.linalg.norm(radial, axis=1).max()) if keep.any() else 0.05


class ShoulderTape:
    """Lengths a bodice panel needs over the shoulder, read off the body at rest: its torso faces
    are sliced by planes across x once per body (``body_measurements.Slicer``)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, torso_mask: np.ndarray,
                 chest_y: float) -> None:
        from sim.garments.body_measurements import Slicer

        keep = torso_mask[faces].all(axis=1)
        torso = np.asarray(faces, np.int64)[keep]
        self.slicer = Slicer(np.asarray(vertices, np.float64), torso, (1.0, 0.0, 0.0))
        self.chest_y = float(chest_y)

    def over(self, x: float, top_y: float, front: bool) -> float:
        """Length [m] a front (``front``) or back bodice panel needs above chest level beyond the
        rise ``top_y - chest_y`` to reach its shoulder seam at height ``top_y``, ``x`` [m] off the
        centre line: a taut tape in the body's section by the planes x = +-``x`` (torso faces,
        both sides pooled) from the front (back) of the chest up the body and over to the seam on
        top, midway between front and back; the section's crossings of the mesh's edges stand for
        the surface, so the tape may cut the corner where it turns over the top by up to an edge
        length (the body's ~1 cm: up to 9 mm short over a 0.2 m deep box with such edges). A
        panel only as tall as the rise reaches the seam stretched: over the default body the
        front and back fall 2.4 and 6.5 cm short at the side neck point, 6.6 and 0.7 cm at the
        shoulder point, which a sewn dress's straps carried as 85 % strain (fine, H200)."""
        from sim.garments.body_measurements import taut_length

        chest_y = self.chest_y
        p = np.concatenate([self.slicer.points(x), self.slicer.points(-x)])[:, 1:]  # (y, z) crossings
        if len(p) < 3:
            return 0.0
        s = 1.0 if front else -1.0
        band = p[np.abs(p[:, 0] - chest_y) < 0.012]
        if not len(band) or p[:, 0].max() <= chest_y:
            return 0.0
        top = p[p[:, 0] >= min(top_y, p[:, 0].max()) - 0.01]
        seam = 0.5 * (top[:, 1].max() + top[:, 1].min())
        mid = p[(p[:, 0] > chest_y) & (p[:, 0] < top_y)]
        ys = np.concatenate([[chest_y], mid[:, 0], [top_y]])
        out = np.concatenate([[(s * band[:, 1]).max()], s * mid[:, 1], [s * seam]])
        return max(0.0, taut_length(ys, out) - (top_y - chest_y))
