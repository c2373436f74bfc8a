"""Procedural garment templates fitted to a body's rest shape.

Each template measures the body's rest mesh with horizontal slabs (cross-section hulls at the
height of every pattern row), adds ease and a clearance margin, and lays out sewing-pattern
panels as rows of arcs around the body (``sim.garments.panels``). The panels are sewn by
welding their shared side-seam points; the pattern coordinates are the UVs.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from scipy.spatial import ConvexHull

from sim.errors import WrinklesInputError
from sim.garments.materials import Material, get_material
from sim.garments.panels import Panel, pack_uvs, resample, sew
from sim.garments.types import Garment

RESOLUTIONS = {"coarse": 0.025, "fine": 0.009}
"""Named target mean edge lengths [m]."""
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

    @classmethod
    def of(cls, body, betas: np.ndarray | None) -> BodyMeasure:
        v = np.asarray(body.rest_mesh(betas), np.float64)
        j = np.asarray(body.rest_joints(betas), np.float64)
        w = np.asarray(body.weights)
        return cls(v, j, w[:, list(ARM_JOINTS)].sum(axis=1) < 0.5)

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
        center = np.array([0.0, hull[:, 1].mean()])
        if p.flare:
            k = 1.0 + p.flare * float(_smoothstep((j[1, 1] - y) / max(length - (y_waist - y_hip), 1e-3)))
            hull = center + (hull - center) * k
        ring = polar_ring(hull, center, float(y))
        half_n = _RING_SAMPLES // 2
        front.append(resample(ring[: half_n + 1], h, min_segments=2))
        back.append(resample(ring[half_n:], h, min_segments=2))
    return [Panel("front", tuple(front)), Panel("back", tuple(back))]


@dataclass(frozen=True)
class Template:
    """A registry entry: parameter class, defaults and the panel builder."""

    params: type
    defaults: dict
    build: object
    attachments: tuple[str, ...]


TEMPLATES: dict[str, Template] = {
    "straight_skirt": Template(SkirtParams, {}, skirt_panels, ("waistband",)),
    "flared_skirt": Template(SkirtParams, {"flare": 0.6, "length": 0.6, "ease": 0.02}, skirt_panels,
                             ("waistband",)),
}
"""Garment categories (registry) → template."""


def resolve_resolution(resolution: str | float) -> float:
    """Target mean edge length [m] for "coarse", "fine" or a number of metres."""
    if isinstance(resolution, str):
        if resolution not in RESOLUTIONS:
            raise WrinklesInputError(f"unknown resolution {resolution!r}; expected one of "
                                     f"{', '.join(RESOLUTIONS)} or an edge length in metres")
        return RESOLUTIONS[resolution]
    h = float(resolution)
    if not 0.003 <= h <= 0.2:
        raise WrinklesInputError(f"resolution {resolution} m is outside [0.003, 0.2] m")
    return h


def make_params(category: str, **params: float):
    """Frozen params of ``category`` with the template's defaults, overridden by ``params``."""
    if category not in TEMPLATES:
        raise WrinklesInputError(f"unknown garment category {category!r}; expected one of "
                                 f"{', '.join(TEMPLATES)}")
    t = TEMPLATES[category]
    allowed = {f.name for f in fields(t.params)}
    unknown = set(params) - allowed
    if unknown:
        raise WrinklesInputError(f"{category}: unknown parameter(s) {sorted(unknown)}; expected "
                                 f"{', '.join(sorted(allowed))}")
    return t.params(**{**t.defaults, **params})


def make_garment(category: str, body, betas: np.ndarray | None = None, *,
                 resolution: str | float = "coarse", material: str | Material = "cotton",
                 name: str | None = None, **params: float) -> Garment:
    """Generate a garment of ``category`` fitted to ``body`` (shape ``betas``) in rest pose.

    Args:
        category: a key of ``TEMPLATES``.
        body: a ``BodyModel`` (``rest_mesh``, ``rest_joints``, ``weights``).
        betas: shape coefficients, shape (B,); None = mean shape.
        resolution: "coarse" (25 mm edges), "fine" (9 mm) or a target edge length [m].
        material: preset name or a ``Material``.
        name: garment name (default: the category).
        **params: fields of the category's params dataclass (e.g. ``length``, ``ease``).

    Returns:
        The garment; deterministic for equal arguments.
    """
    p = make_params(category, **params)
    h = resolve_resolution(resolution)
    mat = get_material(material)
    meas = BodyMeasure.of(body, betas)
    panels = TEMPLATES[category].build(meas, p, h, mat.thickness)
    sewn = sew(panels)
    faces = sewn.faces
    # outward orientation: normals should point away from the vertical body axis
    v = sewn.vertices
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    radial = tri.mean(axis=1) - np.array([0.0, 0.0, meas.joints[0, 2]])
    radial[:, 1] = 0.0
    flip = np.sum(n * radial) < 0
    uv_faces = sewn.uv_faces
    if flip:
        faces, uv_faces = faces[:, ::-1], uv_faces[:, ::-1]
    top = np.unique(np.concatenate([rows[0] for rows in sewn.row_vertices]))
    hem = np.unique(np.concatenate([rows[-1] for rows in sewn.row_vertices]))
    att = {"waistband": top, "hem": hem}
    return Garment(rest_vertices=v.astype(np.float32), faces=faces.astype(np.int32),
                   uvs=pack_uvs(sewn.uvs_m, sewn.uv_panel), uv_faces=uv_faces.astype(np.int32),
                   material=mat, attachments=att, category=category, name=name or category,
                   panel_ids=sewn.panel_ids.astype(np.int32),
                   panel_names=tuple(pn.name for pn in panels))
