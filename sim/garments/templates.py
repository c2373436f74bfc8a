"""Procedural garment templates fitted to a body's rest shape: the registry and ``make_garment``.

Skirts (``sim.garments.skirts``), shorts / trousers (``pants``: hip tube split into two legs at
a crotch bridge), tank top / t-shirt / long sleeve / dress (``tops``: body tube, bibs, shoulder
straps, optional ``sleeves`` on the armholes). Each template measures the body's rest mesh with
horizontal slabs (``sim.garments.measure``: cross-section hulls at the height of every pattern
row), adds ease and a clearance margin, and lays out sewing-pattern panels as rows of arcs
around the body (``sim.garments.panels``). The panels are sewn by welding their shared seam
points; each panel is flattened into its pattern piece (ARAP, ``sim.garments.uv``) and the
pieces are packed into [0, 1]²: those are the UVs.

Every parameter's unit, range and description are data on its params field
(``sim.garments.parameters``); ``template_parameters`` lists them for users.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.hems import HEM_LAYERS, HEM_WIDTH, hem_face_layers
from sim.garments.materials import Material, get_material
from sim.garments.measure import BodyMeasure, midplane_crossings
from sim.garments.panels import sew
from sim.garments.pants import PantsParams, pants_panels
from sim.garments.parameters import HEM_SPECS, HemParams, check_parameter, parameter_specs
from sim.garments.skirts import SkirtParams, skirt_panels
from sim.garments.tops import TopParams, tank_top_panels
from sim.garments.types import Garment
from sim.garments.uv import flatten_panels, pack_uvs

__all__ = [
    "GARMENT_ALIASES", "RESOLUTIONS", "TEMPLATES", "Template", "check_parameter", "make_garment",
    "make_params", "midplane_crossings", "resolve_resolution", "template_name", "template_parameters",
]

RESOLUTIONS = ("coarse", "fine")
"""Named resolutions: each template's ``coarse`` / ``fine`` edge length (``Template``)."""


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

_TANK_TOP = {"armhole_fillet": 0.08, "armhole_depth": 0.05}
"""The tank top's armholes, from its fine walks' largest edge strain (CUDA, docs/BENCHMARKS.md):
with square corners every worst edge sits at the armholes' bottom corners, with 8 cm fillets
the default body's walk passes (0.282 against 0.353); 5 cm deep, 7 of 11 bodies' walks pass,
3 cm deep 4 of 11."""

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
    "tank_top": Template(TopParams, _TANK_TOP, tank_top_panels, ("shoulders", "hem"),
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
"""Garment categories → template."""

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


def _template(category: str) -> Template:
    if category not in TEMPLATES:
        raise WrinklesInputError(f"unknown garment category {category!r}; expected one of "
                                 f"{', '.join(TEMPLATES)}")
    return TEMPLATES[category]


def template_parameters(category: str) -> list[tuple[str, float, str, str]]:
    """A template's parameters as ``(name, default, unit, description)``: its params class's
    fields with this template's defaults, then the hems'."""
    params = make_params(category)
    out = [(name, getattr(params, name), spec.unit, spec.description)
           for name, spec in parameter_specs(_template(category).params).items()]
    hems = HemParams()
    return out + [(name, getattr(hems, name), spec.unit, spec.description)
                  for name, spec in HEM_SPECS.items()]


def make_params(category: str, **params: float):
    """Frozen params of ``category`` with the template's defaults, overridden by ``params``
    (its params class's fields and the hems', each checked against its range)."""
    t = _template(category)
    specs = {**parameter_specs(t.params), **HEM_SPECS}
    allowed = {f.name for f in fields(t.params)}
    unknown = set(params) - set(specs)
    if unknown:
        raise WrinklesInputError(f"{category}: unknown parameter(s) {sorted(unknown)}; expected "
                                 f"{', '.join(sorted(specs))}")
    for k, v in params.items():
        check_parameter(k, v, specs[k], category)
    return t.params(**{**t.defaults, **{k: v for k, v in params.items() if k in allowed}})


def untangle(v: np.ndarray, faces: np.ndarray, panel_ids: np.ndarray, names: list[str],
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
            ``hem_width`` / ``hem_layers`` (``HemParams``): the bands of ``face_layers``
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
    v = untangle(sewn.vertices, faces, sewn.panel_ids, [pn.name for pn in panels])
    # outward orientation: normals should point away from the vertical body axis
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    radial = tri.mean(axis=1) - np.array([0.0, 0.0, meas.joints[0, 2]])
    radial[:, 1] = 0.0
    flip = np.sum(n * radial) < 0
    uv_faces = sewn.uv_faces
    if flip:
        faces, uv_faces = faces[:, ::-1], uv_faces[:, ::-1]
    uv_points = np.empty((len(sewn.uvs_m), 3))
    uv_points[sewn.uv_faces] = v[sewn.faces]
    uvs_m = flatten_panels(uv_points, sewn.uv_faces, sewn.uvs_m, sewn.uv_panel)
    return Garment(rest_vertices=v.astype(np.float32), faces=faces.astype(np.int32),
                   uvs=pack_uvs(uvs_m, sewn.uv_panel), uv_faces=uv_faces.astype(np.int32),
                   material=mat, attachments=_attachments(panels, sewn.row_vertices),
                   category=category, name=name or category,
                   panel_ids=sewn.panel_ids.astype(np.int32),
                   panel_names=tuple(pn.name for pn in panels),
                   face_layers=hem_face_layers(v, faces, hem_width, hem_layers))


def _attachments(panels, row_vertices) -> dict[str, np.ndarray]:
    """Vertex sets named by the panels' ``top``, ``bottom`` and ``marks`` rows."""
    att: dict[str, list[np.ndarray]] = {}
    for pn, rows in zip(panels, row_vertices, strict=True):
        if pn.top:
            att.setdefault(pn.top, []).append(rows[0])
        if pn.bottom:
            att.setdefault(pn.bottom, []).append(rows[-1])
        for k, mark in pn.marks:
            att.setdefault(mark, []).append(rows[k])
    return {k: np.unique(np.concatenate(a)) for k, a in att.items()}
