"""Template parameters as data: each field of a template's params dataclass carries its unit,
accepted range and the description users read (``wrinkles garments --params``).

A template can still refuse a value inside the range that does not fit the body (e.g. a skirt
too short for the edge length); the range only bounds what is worth trying.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.hems import HEM_LAYERS, HEM_WIDTH


@dataclass(frozen=True)
class Parameter:
    """What a template parameter means.

    Attributes:
        unit: "m" for lengths, "-" for ratios and counts, "choice" for a named option.
        low, high: accepted range, both ends included (numbers).
        description: one sentence for users, without the unit.
        choices: the accepted names of a "choice" parameter.
    """

    unit: str
    low: float
    high: float
    description: str
    choices: tuple[str, ...] = ()


def parameter(default: float, unit: str, low: float, high: float, description: str):
    """A dataclass field with ``default`` whose metadata holds its ``Parameter``."""
    return field(default=default, metadata={"parameter": Parameter(unit, low, high, description)})


def choice(default: str, choices: tuple[str, ...], description: str):
    """A dataclass field with ``default`` that takes one of ``choices`` (names)."""
    return field(default=default, metadata={"parameter": Parameter("choice", 0.0, 0.0, description,
                                                                   tuple(choices))})


def parameter_specs(params_class: type) -> dict[str, Parameter]:
    """``{field name: Parameter}`` of a params dataclass, in field order."""
    return {f.name: f.metadata["parameter"] for f in fields(params_class)}


@dataclass(frozen=True)
class HemParams:
    """The hems every template and every garment file can have (``sim.garments.hems``)."""

    hem_width: float = parameter(HEM_WIDTH, "m", 0.0, 0.1,
                                 "width of the hems along every opening (0: none)")
    hem_layers: float = parameter(HEM_LAYERS, "-", 1.0, 4.0,
                                  "layers of fabric in a hem: its mass, stretch and bending scale")


HEM_SPECS = parameter_specs(HemParams)
"""``Parameter`` of ``hem_width`` and ``hem_layers``."""


def check_parameter(name: str, value, spec: Parameter, where: str, path=None) -> None:
    """Raise ``WrinklesInputError`` (prefixed ``where: ``, or naming ``path``) unless ``value``
    is a finite number within ``spec``'s range, or one of a choice parameter's names."""
    number = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
    prefix = f"{where}: " if path is None else ""
    if spec.choices:
        if value not in spec.choices:
            raise WrinklesInputError(f"{prefix}parameter {name} = {value!r} is not one of "
                                     f"{', '.join(spec.choices)}", path=path)
        return
    if not number or not np.isfinite(value):
        raise WrinklesInputError(f"{prefix}parameter {name} must be a number [{spec.unit}], got {value!r}",
                                 path=path)
    if not spec.low <= value <= spec.high:
        raise WrinklesInputError(f"{prefix}parameter {name} = {value:g} is outside its range "
                                 f"[{spec.low:g}, {spec.high:g}]", path=path)
