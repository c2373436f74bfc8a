"""Garment designs: a sewing pattern drafted from the body's measurements, meshed, sewn on the
rest body and turned into a ``Garment`` (``make_design_garment``).

The garment's UVs are its flat pattern (every panel one chart, one common scale, packed into
[0, 1]², ``sim.garments.uv.pack_uvs``); ``Garment.panel_ids`` names the panel of each face; its
attachment sets are the vertices along labelled pattern edges (``ATTACHMENT_LABELS``); its hems
are the ``hem_width`` bands along its openings, as for every garment (``sim.garments.hems``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.hems import HEM_LAYERS, HEM_WIDTH, hem_face_layers
from sim.garments.materials import Material, get_material
from sim.garments.parameters import HEM_SPECS
from sim.garments.pattern import Pattern
from sim.garments.sewing import SewnPattern, sew_pattern, sew_patterns
from sim.garments.types import Garment
from sim.garments.uv import pack_uvs
from sim.profiling import phase

ATTACHMENT_LABELS = {"hem": "hem", "cuff": "cuffs", "waistband": "waistband", "neckline": "neckline",
                     "shoulder": "shoulders"}
"""Pattern edge label -> the garment attachment set its vertices join."""
SIZES = {
    "t_shirt": (0.017, 0.0065, (2861, 19423)),
    "long_sleeve": (0.0195, 0.007, (2776, 21453)),
    "tank_top": (0.015, 0.006, (2840, 17515)),
    "hoodie": (0.02, 0.0075, (3507, 25070)),
    "dress": (0.02, 0.007, (2868, 23191)),
    "straight_skirt": (0.015, 0.006, (2897, 17786)),
    "flared_skirt": (0.016, 0.0065, (2991, 18129)),
    "shorts": (0.015, 0.006, (2803, 17429)),
    "trousers": (0.019, 0.007, (3109, 23100)),
}
"""Each design's edge lengths (coarse, fine) [m], chosen for about 3,000 and 20,000 vertices on the
default body, and the vertex counts they give there (``Template.vertices``)."""
PATTERN_VERTICES = {"coarse": 3000, "fine": 20000}
"""Vertex counts "coarse" and "fine" aim at for a pattern that is no design (a pattern file):
the designs' ``SIZES`` targets."""


@dataclass(frozen=True)
class BodyParts:
    """What drafting reads from a body at rest: measurements, vertices, joints, region masks."""

    measurements: object
    vertices: np.ndarray
    joints: np.ndarray
    faces: np.ndarray
    torso_mask: np.ndarray
    arm_masks: dict

    @classmethod
    def of(cls, body, betas: np.ndarray | None = None) -> BodyParts:
        from sim.garments.body_measurements import ARM_JOINTS, measure_body

        w = np.asarray(body.weights)
        left = [j for j in ARM_JOINTS if j % 2 == 0]
        right = [j for j in ARM_JOINTS if j % 2 == 1]
        return cls(measure_body(body, betas), np.asarray(body.rest_mesh(betas), np.float64),
                   np.asarray(body.rest_joints(betas), np.float64), np.asarray(body.faces, np.int32),
                   w[:, list(ARM_JOINTS)].sum(axis=1) < 0.5,
                   {"l": w[:, left].sum(axis=1) > 0.5, "r": w[:, right].sum(axis=1) > 0.5})


def edge_length(resolution: str | float, design: str) -> float:
    """Target edge length [m] of design ``design`` at "coarse", "fine" (``SIZES``) or a number of
    metres."""
    if isinstance(resolution, str):
        if resolution not in ("coarse", "fine"):
            raise ValueError(f"unknown resolution {resolution!r}; expected coarse, fine or metres")
        return SIZES[design][0 if resolution == "coarse" else 1]
    return float(resolution)


def attachments_of(pattern: Pattern, sewn: SewnPattern) -> dict[str, np.ndarray]:
    """Vertex sets of the garment along labelled edges (``ATTACHMENT_LABELS``)."""
    out: dict[str, list[np.ndarray]] = {}
    for label, name in ATTACHMENT_LABELS.items():
        for ref in pattern.labelled(label):
            out.setdefault(name, []).append(sewn.mesh.groups[sewn.mesh.edge_vertices[ref]])
    return {k: np.unique(np.concatenate(v)).astype(np.int32) for k, v in out.items()}


def garment_of(pattern: Pattern, sewn: SewnPattern, material: Material, *, category: str, name: str,
               hem_width: float = HEM_WIDTH, hem_layers: float = HEM_LAYERS) -> Garment:
    """The ``Garment`` of a sewn pattern: UVs = the flat pattern packed into [0, 1]²."""
    mesh = sewn.mesh
    uvs = pack_uvs(mesh.flat, mesh.vertex_panel)
    edges = mesh.triangles[:, [0, 1]]
    scale = float(np.median(np.linalg.norm(np.diff(mesh.flat[edges], axis=1)[:, 0], axis=1)
                            / np.linalg.norm(np.diff(uvs[edges].astype(np.float64), axis=1)[:, 0], axis=1)))
    return Garment(rest_vertices=sewn.vertices, faces=sewn.faces, uvs=uvs, uv_faces=mesh.triangles,
                   material=material, attachments=attachments_of(pattern, sewn), category=category,
                   name=name, panel_ids=mesh.face_panel, panel_names=tuple(p.name for p in pattern.panels),
                   face_layers=hem_face_layers(sewn.vertices, sewn.faces, hem_width, hem_layers),
                   uv_scale=scale)


@dataclass(frozen=True)
class Design:
    """A registry entry: a design's parameters (a frozen dataclass whose fields carry their
    ``Parameter``), this design's defaults over them, its drafting function
    ``draft(parts, params) -> Pattern``, one line for listings and the attachment sets its
    garments have (``ATTACHMENT_LABELS``)."""

    params: type
    defaults: dict
    draft: Callable
    description: str
    attachments: tuple[str, ...] = ()


def _top(parts: BodyParts, d, name: str) -> Pattern:
    from sim.garments.drafting.tops import draft_top

    return draft_top(parts.measurements, parts.vertices, parts.torso_mask, parts.arm_masks, parts.joints, d,
                     name, parts.faces)


def _tops() -> dict[str, Design]:
    from sim.garments.drafting.tops import TopDesign

    def top(name: str, description: str, **defaults) -> Design:
        sleeves = defaults.get("sleeve_length", 0.2) > 0
        sets = ("shoulders", "hem", "neckline") + (("cuffs",) if sleeves else ())
        return Design(TopDesign, defaults, lambda parts, d: _top(parts, d, name), description, sets)

    return {
        "t_shirt": top("t_shirt", "t-shirt: set-in short sleeves, round neck (neckline=v for a V neck)"),
        "long_sleeve": top("long_sleeve", "long-sleeved shirt, cuffs at the wrists", sleeve_length=0.8),
        "tank_top": top("tank_top", "sleeveless top with shoulder straps", sleeve_length=0.0,
                        strap_width=0.06, neck_depth=0.12),
        "hoodie": top("hoodie", "loose long-sleeved pullover with a two-piece hood", fit="loose",
                      sleeve_length=0.8, hood="yes", neck_depth=0.06, hem_drop=0.25),
        "dress": top("dress", "sleeveless fitted dress flaring below the hips to the knee", fit="tight",
                     sleeve_length=0.0, strap_width=0.05, hem_drop=0.6, flare=0.35),
    }


def _bottoms() -> dict[str, Design]:
    from sim.garments.drafting.bottoms import SkirtDesign, draft_skirt
    from sim.garments.drafting.trousers import PantsDesign, draft_pants

    def bottom(params: type, draft, name: str, description: str, **defaults) -> Design:
        return Design(params, defaults, lambda parts, d: draft(
            parts.measurements, parts.vertices, parts.torso_mask, parts.joints, d, name), description,
            ("waistband", "hem"))

    return {
        "straight_skirt": bottom(SkirtDesign, draft_skirt, "straight_skirt",
                                 "straight skirt with waist darts and a waistband, to the knee"),
        "flared_skirt": bottom(SkirtDesign, draft_skirt, "flared_skirt",
                               "A-line skirt flaring from the hips, waistband", flare=0.6, length=0.6),
        "shorts": bottom(PantsDesign, draft_pants, "shorts", "shorts: crotch curves, waistband, legs "
                         "above the knee", length=0.3),
        "trousers": bottom(PantsDesign, draft_pants, "trousers", "full-length trousers: crotch curves, "
                           "waistband, hem above the ankle"),
    }


@functools.lru_cache(maxsize=1)
def designs() -> dict[str, Design]:
    """Every design by name."""
    return {**_tops(), **_bottoms()}


def design_params(name: str, **params):
    """The frozen params of design ``name``: its defaults overridden by ``params`` (checked)."""
    from sim.garments.parameters import parameter_specs

    table = designs()
    if name not in table:
        raise WrinklesInputError(f"unknown design {name!r}; expected one of {', '.join(table)}")
    d = table[name]
    unknown = set(params) - set(parameter_specs(d.params))
    if unknown:
        raise WrinklesInputError(f"{name}: unknown parameter(s) {sorted(unknown)}; expected "
                                 f"{', '.join(parameter_specs(d.params))}")
    try:
        return d.params(**{**d.defaults, **params})
    except ValueError as e:
        raise WrinklesInputError(f"{name}: {e}") from None


def make_pattern(name: str, body, betas: np.ndarray | None = None, **params) -> Pattern:
    """Design ``name``'s pattern drafted for ``body`` with shape ``betas``."""
    p = design_params(name, **params)
    return designs()[name].draft(BodyParts.of(body, betas), p)


@dataclass(frozen=True)
class GarmentRequest:
    """One design garment to make (``make_design_garments``, ``templates.make_garments``):
    design ``name`` for ``body`` with shape ``betas`` at ``resolution`` of ``material``, called
    ``garment_name`` (None: the design's name); ``params`` the design's parameters and
    ``hem_width`` / ``hem_layers``."""

    name: str
    body: Any
    betas: np.ndarray | None = None
    resolution: str | float = "coarse"
    material: str | Material = "cotton"
    garment_name: str | None = None
    params: dict = field(default_factory=dict)


def make_design_garment(name: str, body, betas: np.ndarray | None = None, *,
                        resolution: str | float = "coarse", material: str | Material = "cotton",
                        garment_name: str | None = None, device: str | None = None,
                        hem_width: float = HEM_WIDTH, hem_layers: float = HEM_LAYERS, **params) -> Garment:
    """Design ``name`` drafted for ``body`` (shape ``betas``), sewn on it at ``resolution`` and
    kept in the garment cache (``sim.garments.garment_cache``)."""
    request = GarmentRequest(name, body, betas, resolution, material, garment_name,
                             {**params, "hem_width": hem_width, "hem_layers": hem_layers})
    return make_design_garments([request], device=device)[0]


def make_design_garments(requests: list[GarmentRequest], *, device: str | None = None) -> list[Garment]:
    """``make_design_garment`` of each request, those the garment cache does not hold drafted and
    then sewn together in one batch (``sew_patterns``: a batch costs about the solver launches of
    one garment)."""
    import dataclasses
    import hashlib

    from sim.device import resolve_device
    from sim.garments.garment_cache import cached_garments
    from sim.garments.sewing import SewingJob

    dev = resolve_device(device)
    made = []  # per request: (params, material, rest body, edge length)
    specs = []
    for r in requests:
        own = {k: v for k, v in r.params.items() if k not in HEM_SPECS}
        p, mat = design_params(r.name, **own), get_material(r.material)
        rest = np.ascontiguousarray(r.body.rest_mesh(r.betas), np.float32)
        h = edge_length(r.resolution, r.name)
        made.append((p, mat, rest, h))
        specs.append({"design": r.name, "params": dataclasses.asdict(p),
                      "body": hashlib.sha256(rest.tobytes()).hexdigest(), "resolution": h,
                      "material": dataclasses.asdict(mat),
                      "device": "cuda" if dev.startswith("cuda") else "cpu"})

    def build(todo: list[int]) -> list[Garment]:
        with phase("draft"):
            patterns = [designs()[requests[i].name].draft(BodyParts.of(requests[i].body, requests[i].betas),
                                                          made[i][0]) for i in todo]
        jobs = [SewingJob(pat, made[i][2], np.asarray(requests[i].body.faces), made[i][3], made[i][1])
                for pat, i in zip(patterns, todo, strict=True)]
        sewn = sew_patterns(jobs, device=dev)
        return [garment_of(pat, sw, made[i][1], category=requests[i].name, name=requests[i].name)
                for pat, sw, i in zip(patterns, sewn, todo, strict=True)]

    return [_hemmed(g, r.garment_name or r.name, float(r.params.get("hem_width", HEM_WIDTH)),
                    float(r.params.get("hem_layers", HEM_LAYERS)))
            for g, r in zip(cached_garments(specs, build), requests, strict=True)]


def _hemmed(g: Garment, name: str, hem_width: float, hem_layers: float) -> Garment:
    """A cached sewn garment with its name and hems: the cache keeps garments as sewn, with the
    default hems (``garment_of``), since hems only set the faces' layers after sewing, so one
    sewing serves every hem."""
    import dataclasses

    if (hem_width, hem_layers) != (HEM_WIDTH, HEM_LAYERS):
        layers = hem_face_layers(g.rest_vertices, g.faces, hem_width, hem_layers)
        g = dataclasses.replace(g, face_layers=layers)
    return g if g.name == name else dataclasses.replace(g, name=name)


def pattern_edge_length(pattern: Pattern, resolution: str | float) -> float:
    """Target edge length [m] of a pattern that is no design (a pattern file): for "coarse" and
    "fine" the one that gives ``PATTERN_VERTICES`` vertices over the panels' area A (a vertex of
    a mesh of equilateral triangles of side h owns √3/2 h², so h = sqrt(2 A / (√3 N)): the
    designs' ``SIZES`` give their vertex counts this way within 3 %), else ``resolution`` metres."""
    if isinstance(resolution, str):
        if resolution not in PATTERN_VERTICES:
            raise WrinklesInputError(f"unknown resolution {resolution!r}; expected coarse, fine or metres")
        area = sum(p.area() for p in pattern.panels)
        h = float(np.sqrt(2.0 * area / (np.sqrt(3.0) * PATTERN_VERTICES[resolution])))
        return float(np.clip(h, 0.003, 0.2))
    h = float(resolution)
    if not 0.003 <= h <= 0.2:
        raise WrinklesInputError(f"resolution {resolution} m is outside [0.003, 0.2] m")
    return h


def make_pattern_garment(pattern: Pattern, body, betas: np.ndarray | None = None, *,
                         resolution: str | float = "coarse", material: str | Material = "cotton",
                         category: str = "pattern", name: str | None = None, device: str | None = None,
                         hem_width: float = HEM_WIDTH, hem_layers: float = HEM_LAYERS) -> Garment:
    """Any sewing pattern (a pattern file's, its panels placed around the rest body of ``body``
    with shape ``betas``) sewn on that body at ``resolution`` (``pattern_edge_length``), as
    ``make_design_garment`` sews a design, and kept in the garment cache.

    Raises:
        WrinklesInputError: a panel that cannot be meshed (its outline crosses itself), or a
            pattern the solver does not sew (positions not finite).
    """
    import dataclasses
    import hashlib

    from sim.device import resolve_device
    from sim.garments.garment_cache import cached_garment
    from sim.garments.garmentcode import pattern_to_spec
    from sim.garments.pattern_mesh import mesh_pattern

    mat = get_material(material)
    dev = resolve_device(device)
    rest = np.ascontiguousarray(body.rest_mesh(betas), np.float32)
    h = pattern_edge_length(pattern, resolution)
    spec = {"pattern": pattern_to_spec(pattern), "body": hashlib.sha256(rest.tobytes()).hexdigest(),
            "resolution": h, "material": dataclasses.asdict(mat),
            "device": "cuda" if dev.startswith("cuda") else "cpu", "category": category}

    def build() -> Garment:
        try:
            mesh = mesh_pattern(pattern, h)  # an outline that cannot be meshed is the file's problem
        except ValueError as e:
            raise WrinklesInputError(str(e)) from None
        sewn = sew_pattern(pattern, rest, np.asarray(body.faces), h, mat, device=dev)
        if not np.all(np.isfinite(sewn.vertices)):
            apart = np.linalg.norm(np.diff(mesh.placed[mesh.pairs], axis=1), axis=2).max(initial=0.0)
            raise WrinklesInputError(f"pattern {pattern.name!r} did not sew: the cloth solver's positions "
                                     f"are not finite (its seams start up to {apart:.2f} m apart)")
        return garment_of(pattern, sewn, mat, category=category, name=pattern.name)
    return _hemmed(cached_garment(spec, build), name or pattern.name, hem_width, hem_layers)
