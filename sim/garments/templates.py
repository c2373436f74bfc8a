"""The garment catalogue: every design by name, its resolutions and parameters, and ``make_garment``.

A template is a design (``sim.garments.designs``): a sewing pattern drafted from the body's
measurements (``sim.garments.body_measurements``), meshed flat at the template's edge length
(``sim.garments.flat_mesh``), sewn on the rest body with the cloth solver
(``sim.garments.sewing``) and cached (``sim.garments.garment_cache``). Its UVs are the flat
pattern and its rest shape for simulation is the pattern (``Garment.uv_scale``).

Every parameter's unit, range (or choices) and description are data on its params field
(``sim.garments.parameters``); ``template_parameters`` lists them for users.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.designs import SIZES, GarmentRequest, designs, make_design_garments
from sim.garments.materials import Material
from sim.garments.parameters import HEM_SPECS, HemParams, check_parameter, parameter_specs
from sim.garments.types import Garment

__all__ = [
    "GARMENT_ALIASES", "RESOLUTIONS", "TEMPLATES", "Template", "check_parameter", "make_garment",
    "make_params", "resolve_resolution", "template_name", "template_parameters",
]

RESOLUTIONS = ("coarse", "fine")
"""Named resolutions: each template's ``coarse`` / ``fine`` edge length (``Template``)."""


@dataclass(frozen=True)
class Template:
    """A catalogue entry.

    Attributes:
        params: the frozen parameter dataclass; defaults: this template's overrides of it.
        attachments: the attachment sets every garment of this template has.
        description: one line for listings.
        coarse, fine: edge lengths [m] of the named resolutions (coarse 15-20 mm, fine 6-7.5 mm),
            chosen so that the garment on the default (mean) body has about 3,000 and 20,000
            vertices; the edge length, not the count, stays fixed across bodies and parameters.
        vertices: (coarse, fine) vertex counts on the default body with the defaults (listed by
            ``wrinkles garments``; tests/test_garments.py keeps them true).
    """

    params: type
    defaults: dict
    attachments: tuple[str, ...]
    description: str
    coarse: float
    fine: float
    vertices: tuple[int, int]


def _catalogue() -> dict[str, Template]:
    out = {}
    for name, d in designs().items():
        coarse, fine, counts = SIZES[name]
        out[name] = Template(d.params, d.defaults, d.attachments, d.description, coarse, fine, counts)
    return out


TEMPLATES: dict[str, Template] = _catalogue()
"""Garment categories -> template."""

GARMENT_ALIASES: dict[str, str] = {
    "tshirt": "t_shirt", "tee": "t_shirt", "shirt": "t_shirt", "skirt": "straight_skirt",
    "pants": "trousers", "jeans": "trousers", "tank": "tank_top", "longsleeve": "long_sleeve",
    "hoody": "hoodie", "sweatshirt": "hoodie",
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
    target = GARMENT_ALIASES.get(compact)
    return target if target in TEMPLATES else None


def resolve_resolution(resolution: str | float, category: str) -> float:
    """Target mean edge length [m] of ``category`` for "coarse", "fine" or a number of metres."""
    if isinstance(resolution, str):
        if resolution not in RESOLUTIONS:
            raise WrinklesInputError(f"unknown resolution {resolution!r}; expected one of "
                                     f"{', '.join(RESOLUTIONS)} or an edge length in metres")
        return getattr(_template(category), resolution)
    h = float(resolution)
    if not 0.003 <= h <= 0.2:
        raise WrinklesInputError(f"resolution {resolution} m is outside [0.003, 0.2] m")
    return h


def _template(category: str) -> Template:
    if category not in TEMPLATES:
        raise WrinklesInputError(f"unknown garment category {category!r}; expected one of "
                                 f"{', '.join(TEMPLATES)}")
    return TEMPLATES[category]


def template_parameters(category: str) -> list[tuple[str, object, str, str]]:
    """A template's parameters as ``(name, default, unit, description)``: its params class's
    fields with this template's defaults, then the hems'. A choice parameter's unit is
    "choice" and its description ends with its choices."""
    params = make_params(category)
    out = []
    for name, spec in parameter_specs(_template(category).params).items():
        text = spec.description + (f" ({' | '.join(spec.choices)})" if spec.choices else "")
        out.append((name, getattr(params, name), spec.unit, text))
    hems = HemParams()
    return out + [(name, getattr(hems, name), spec.unit, spec.description)
                  for name, spec in HEM_SPECS.items()]


def make_params(category: str, **params):
    """Frozen params of ``category`` with the template's defaults, overridden by ``params``
    (its params class's fields and the hems', each checked against its range or choices)."""
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


def make_garment(category: str, body, betas: np.ndarray | None = None, *,
                 resolution: str | float = "coarse", material: str | Material = "cotton",
                 name: str | None = None, device: str | None = None, **params) -> Garment:
    """Draft, sew and return a garment of ``category`` for ``body`` (shape ``betas``) at rest.

    Args:
        category: a key of ``TEMPLATES``.
        body: a ``BodyModel`` (``rest_mesh``, ``rest_joints``, ``weights``, ``faces``).
        betas: shape coefficients, shape (B,); None = mean shape.
        resolution: "coarse" (~3k vertices on the default body), "fine" (~20k) or a target
            edge length [m].
        material: preset name or a ``Material``.
        name: garment name (default: the category).
        device: Warp device sewing runs on (None: cuda when present, else cpu).
        **params: fields of the category's params dataclass (e.g. ``fit``, ``sleeve_length``),
            and ``hem_width`` / ``hem_layers`` (``HemParams``).

    Returns:
        The garment; deterministic for equal arguments on one kind of device.
    """
    return make_garments([GarmentRequest(category, body, betas, resolution, material, name, params)],
                         device=device)[0]


def make_garments(requests: list[GarmentRequest], *, device: str | None = None) -> list[Garment]:
    """``make_garment`` of each request (``name`` a category, ``params`` its parameters and
    hems), checked; those the garment cache does not hold are sewn together in one batch
    (``make_design_garments``), e.g. a dataset batch's garments on their bodies."""
    import dataclasses

    for r in requests:
        make_params(r.name, **r.params)
    return make_design_garments([dataclasses.replace(r, resolution=resolve_resolution(r.resolution, r.name))
                                 for r in requests], device=device)
