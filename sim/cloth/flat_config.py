"""``VBDConfig``'s flat keyword spelling: ``VBDConfig(substeps=12, self_contact_radius=0.004)``
and ``config.max_colors``, for the callers that build a config field by field (``sim.simulate``'s
``SimulationConfig.vbd_config``, tests of the self-contact and coarse-level areas). A flat name
maps onto one section field (``FLAT_FIELDS``); ``self_contact`` given a bool is
``self_contact.enabled``. New code uses the sections, ``job_config`` and ``apply_overrides``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

_SECTION_PREFIXES = {
    "stepping": ("", ("substeps", "iterations", "air_damping")),
    "body_contact": ("contact_", ("stiffness", "margin")),
    "self_contact": ("self_contact_", ("radius", "margin", "stiffness", "friction",
                                       "speed_factor", "capacity", "pool", "heavy_cap", "weight_floor",
                                       "coarse_exclusion", "broadphase", "cluster_size", "cluster_split")),
    "coarse": ("coarse_", ("sweeps", "spacing", "levels", "smoothing", "early")),
    "layout": ("", ("lanes", "particles_per_block", "gather", "max_registers", "fast_math", "max_colors")),
}
FLAT_FIELDS: dict[str, tuple[str, str]] = {
    prefix + name: (section, name) for section, (prefix, names) in _SECTION_PREFIXES.items() for name in names
}
"""Flat name -> (section, field)."""
FLAT_FIELDS["friction_epsilon"] = ("body_contact", "friction_epsilon")

FIXED_FIELDS: dict[str, Any] = {"coarse_prefactor": True, "coarse_guard": False}
"""Flat names of behaviour the solver has fixed, accepted only at that value: the coarse system
is factored at the substep start and has no overshoot guard."""


def accept_flat_fields(cls: type) -> type:
    """Let the dataclass ``cls`` (``VBDConfig``) take flat keywords and read flat attributes
    (on the class: the defaults)."""
    init = cls.__init__

    def __init__(self, *args: Any, **kw: Any) -> None:
        flat = {k: kw.pop(k) for k in list(kw) if k in FLAT_FIELDS or k in FIXED_FIELDS}
        if isinstance(kw.get("self_contact"), bool):
            flat["self_contact_enabled"] = kw.pop("self_contact")
        init(self, *args, **kw)
        if not flat:
            return
        grouped: dict[str, dict[str, Any]] = {}
        for key, value in flat.items():
            if key in FIXED_FIELDS:
                if value != FIXED_FIELDS[key]:
                    raise ValueError(f"VBDConfig.{key} is always {FIXED_FIELDS[key]}, got {value!r}")
                continue
            section, name = ("self_contact", "enabled") if key == "self_contact_enabled" else FLAT_FIELDS[key]
            grouped.setdefault(section, {})[name] = value
        sections = {s: dataclasses.replace(getattr(self, s), **v) for s, v in grouped.items()}
        for s, value in sections.items():
            object.__setattr__(self, s, value)
        self.__post_init__()

    cls.__init__ = __init__
    for key, (section, name) in FLAT_FIELDS.items():
        setattr(cls, key, _FlatField(section, name))
    return cls


class _FlatField:
    """A flat attribute: the section field of an instance, the field's default on the class."""

    def __init__(self, section: str, name: str):
        self.section, self.name = section, name

    def __get__(self, obj: Any, owner: type) -> Any:
        if obj is None:
            return getattr(owner.__dataclass_fields__[self.section].default_factory(), self.name)
        return getattr(getattr(obj, self.section), self.name)
