"""Settings of the VBD cloth solver (``SolverVBD``): small frozen sections gathered in
``VBDConfig``, whose defaults are the job's (``wrinkles simulate``, ``wrinkles dataset
generate``) for a garment of up to ``FINE_GARMENT_VERTICES`` vertices on the CPU.
``job_config`` adds what depends on the garment's size and the device. Figures are H100
measurements from docs/BENCHMARKS.md unless a line says otherwise.

Overrides are flat ``"section.field"`` keys (``--solver-param self_contact.radius=0.004``, a
dataset config's ``[simulation] solver`` table): ``apply_overrides``.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from sim.errors import WrinklesInputError

FINE_GARMENT_VERTICES = 10_000
"""Garments with more vertices than this take the fine defaults (``FINE_SUBSTEPS``,
``FINE_ITERATIONS``, ``FINE_COARSE_EXCLUSION``)."""
DEFAULT_SUBSTEPS = 12
"""Substeps per frame: the 5k t-shirt passes 134 of 144 random walks and runs at 12."""
FINE_SUBSTEPS = 14
"""Substeps per frame of a fine garment: the 19k t-shirt passes 7 of 16 random walks and runs at
14 against 2 of 16 at 12."""
DEFAULT_ITERATIONS = 5
"""Sweeps per substep: with one coarse correction the 5k t-shirt passes 43 of 48 random walks and
runs at 14 x 5 against 38 of 48 at 16 x 10 without it."""
FINE_ITERATIONS = 8
"""Sweeps per substep of a fine garment (lighter particles against the same membrane stiffness:
a sweep carries less of a substep's correction): every template at ~20k vertices passes 6 of 8
walks at 14 x 8 against 4 of 8 at 14 x 5, for 18 % more time per frame."""
DEFAULT_COARSE_SWEEPS = (2,)
"""One coarse-level correction, before sweep 2, where a substep has more than 2 sweeps: the
load travels across the garment in one substep instead of about one ring of edges per sweep."""
CUDA_COLORS = 3
"""Colours of a run on CUDA (the CPU keeps a proper colouring, 0): one launch fewer per sweep,
~2 % of the t-shirt's edges coupled by a Jacobi step; 5k t-shirt 4.24 / 4.30 ms per walk / run
frame against 4.46 / 4.52, 135 of 144 random walks and runs passing against 134."""
CUDA_COARSE_EARLY = True
"""A run on CUDA prepares the coarse system beside the self-contact detection: 5k t-shirt 3.76 /
3.82 ms per walk / run frame against 3.95 / 4.00, 139 of 144 random walks and runs passing
against 135. The CPU runs in order on one stream: nothing to gain there."""
FINE_COARSE_EXCLUSION = 0.006
"""``SelfContactConfig.coarse_exclusion`` [m] of a fine garment (coarse garments keep 0): the fine
shorts' crotch sinks 22 mm by the blend's end against 98 mm, their walk's largest strain is 0.391
against 0.546; on coarse garments it frees only the pants' inner walls, and the coarse trousers'
walk crossed itself."""
JOB_COARSE_GUARD = False
"""What a dataset records as ``coarse_guard`` among its simulator defaults: the coarse system has
no overshoot guard (on the CPU a guard raised every fine walk's strain, the t-shirt's from 0.203
to 0.262)."""

def default_substeps(vertices: int) -> int:
    """Substeps per frame of the job default for a garment of ``vertices`` vertices."""
    return FINE_SUBSTEPS if vertices > FINE_GARMENT_VERTICES else DEFAULT_SUBSTEPS


def default_iterations(vertices: int) -> int:
    """Sweeps per substep of the job default for a garment of ``vertices`` vertices."""
    return FINE_ITERATIONS if vertices > FINE_GARMENT_VERTICES else DEFAULT_ITERATIONS


def _require(section: str, name: str, value: Any, ok: bool, rule: str) -> None:
    if not ok:
        raise ValueError(f"VBDConfig.{section}.{name} must be {rule}, got {value!r}")


@dataclass(frozen=True)
class Stepping:
    """Time stepping.

    Attributes:
        substeps: implicit-Euler substeps per ``SolverVBD.step`` (``DEFAULT_SUBSTEPS``).
        iterations: Gauss-Seidel sweeps over all colours per substep (``DEFAULT_ITERATIONS``).
        air_damping: mass-proportional Rayleigh damping alpha [1/s] (force ``-alpha m v``): the
            linear drag of still air that lets garments come to rest; the material's damping
            [s] acts on strain and bending rates only and leaves rigid motion undamped.
    """

    substeps: int = DEFAULT_SUBSTEPS
    iterations: int = DEFAULT_ITERATIONS
    air_damping: float = 0.5

    def __post_init__(self) -> None:
        for name in ("substeps", "iterations"):
            v = getattr(self, name)
            _require("stepping", name, v, v >= 1, ">= 1")
        _require("stepping", "air_damping", self.air_damping, self.air_damping >= 0.0, ">= 0 1/s")


@dataclass(frozen=True)
class BodyContact:
    """Cloth-body contact (a half-space penalty per particle, with lazy IPC friction).

    Attributes:
        stiffness: penalty stiffness [N/m].
        margin: distance [m] within which body contacts are detected; it must exceed the cloth
            thickness plus the relative cloth/body motion of one substep. 15 mm covers 4.5 m/s
            of relative motion at 10 substeps of a 30 fps frame; the closest-point query's cost
            grows with it (5 % of the t-shirt's frame).
        friction_epsilon: tangential speed [m/s] below which friction is smoothed (static), for
            body and self-contact friction alike.
        offset: distance [m] kept between the cloth's particles and the body on top of the
            cloth's thickness (``ClothModelBuilder(contact_offset=)``): the body's surface bulges
            between the particles (a 2 cm triangle over a 5 cm arm is 1 mm deep at its middle), and
            the body's vertices stand up to 0.4 mm above its faces between a fine garment's
            particles: at the bare thickness (0.3 mm for a shirting) the skin shows through the
            cloth in grey specks. 1 mm: the CPU fine t-shirt (19.2k vertices) walk has no body
            vertex under it outside it in any frame (5 % of them at 0, 0.09 mm deep at the
            median) and passes its gates (sewing keeps 3 mm, ``SewingConfig.contact_offset``).
    """

    stiffness: float = 1.0e5
    margin: float = 0.015
    friction_epsilon: float = 1.0e-2
    offset: float = 0.001

    def __post_init__(self) -> None:
        for name in ("stiffness", "margin", "friction_epsilon"):
            v = getattr(self, name)
            _require("body_contact", name, v, v > 0.0, "> 0")
        _require("body_contact", "offset", self.offset, 0.0 <= self.offset < self.margin,
                 ">= 0 m and below the margin")


@dataclass(frozen=True)
class SelfContactConfig:
    """Cloth-cloth contact: vertex-triangle and edge-edge pairs (``sim.cloth.self_contact``).

    Attributes:
        enabled: self-contact on (without it every fine garment folds through itself).
        radius: distance [m] kept between cloth surfaces.
        margin: smallest query radius [m] of the pair detection: pairs beyond the 3 mm contact
            radius plus the substep's motion never act, and storing them costs solve time
            (10 mm: 1.5x the step at batch 64); faster pairs are found by the relative-speed
            term (``speed_factor``).
        stiffness: penalty stiffness [N/m] of a pair: repeated t-shirt runs at 20 x 10 pass the
            gates in walk 5 of 8, run 8 of 8 at 3e4 against 2 of 5, 0 of 5 at 1e4, where body
            contact (1e5) squeezes sleeve layers through each other.
        friction: Coulomb friction coefficient of a pair.
        speed_factor: query radius at least this times a primitive's relative speed times
            ``h`` [-].
        capacity: pairs stored per vertex, triangle and edge.
        pool: gather records per vertex, on average over the model, of the solve's pairs; a
            vertex whose records do not fit is gathered from the pair lists, with the same
            forces but a chain of dependent loads per pair (a solve launch 24 us against 10 us
            without self-contact). 0: always the lists.
        heavy_cap: vertices per colour launch that get a whole thread block each when they have
            more gather records than the solve has lanes per particle: a dense fold gives a few
            vertices 50-160 records (mean 2-6), and the slowest vertex sets a launch's length.
            0: off; -1: ``solver_vbd.AUTO_HEAVY_CAP`` per instance in the 16-lane layout on
            CUDA, else off.
        weight_floor: smallest weight of a vertex in a pair that the pair's Hessian block takes
            (0: the exact ``w^2``): with the exact Hessian a vertex with a small weight moves
            ``1/w`` times the penetration in its own Newton step, and a hairpin thrown onto
            itself at 1.1 m/s flipped over its fold. The forces, so the converged state, are
            the same.
        coarse_exclusion: pairs of one piece closer than this [m] at rest leave the coarse
            correction alone: they stay in contact, but do not cap their particles'
            prolongated moves nor add their stiffness to the coarse diagonal
            (``FINE_COARSE_EXCLUSION`` for fine garments).
        broadphase: how the detection finds its candidates: ``"bvh"`` (three trees, refitted
            every detection and rebuilt at a step's first), ``"clusters"`` (the primitives in
            fixed clusters, culled cluster by cluster, ``sim.cloth.clusters``) or ``"auto"``
            (``SolverVBD.broadphase``). The same pairs either way.
        cluster_size: primitives per cluster of the ``"clusters"`` broadphase (a multiple of 8
            in 8..64).
        cluster_split: threads per primitive of the cluster query (0: automatic).
    """

    enabled: bool = True
    radius: float = 0.003
    margin: float = 0.004
    stiffness: float = 3.0e4
    friction: float = 0.2
    speed_factor: float = 2.5
    capacity: int = 16
    pool: int = 16
    heavy_cap: int = -1
    weight_floor: float = 0.5
    coarse_exclusion: float = 0.0
    broadphase: str = "auto"
    cluster_size: int = 32
    cluster_split: int = 0

    def __post_init__(self) -> None:
        from sim.cloth.clusters import CLUSTER_SIZES

        def req(name: str, ok: bool, rule: str) -> None:
            _require("self_contact", name, getattr(self, name), ok, rule)

        for name in ("radius", "margin", "stiffness", "speed_factor", "capacity"):
            req(name, getattr(self, name) > 0, "> 0")
        req("margin", self.margin >= self.radius, f">= radius ({self.radius})")
        req("friction", self.friction >= 0.0, ">= 0")
        req("pool", self.pool >= 0, ">= 0")
        req("heavy_cap", self.heavy_cap >= -1, ">= -1 (-1: auto)")
        req("weight_floor", 0.0 <= self.weight_floor <= 1.0, "in [0, 1]")
        req("coarse_exclusion", self.coarse_exclusion >= 0.0, ">= 0")
        req("broadphase", self.broadphase in ("auto", "bvh", "clusters"), "'auto', 'bvh' or 'clusters'")
        req("cluster_size", self.cluster_size in CLUSTER_SIZES, "a multiple of 8 in [8, 64]")
        req("cluster_split", self.cluster_split >= 0, ">= 0 (0: automatic)")


@dataclass(frozen=True)
class CoarseConfig:
    """The coarse-level correction (``sim.cloth.coarse``): the residual at every particle,
    restricted to about one node per 15 vertices, solved exactly on that level and prolongated:
    the long reach the sweeps lack (~1 ring of edges each).

    Attributes:
        sweeps: sweep indices (0 .. iterations - 1) before which a correction runs (empty:
            none; ``DEFAULT_COARSE_SWEEPS``).
        spacing: seed spacing of the aggregates [edges]; 0: per garment, 4, or with two
            coarse levels the least from 4 that gives at most 256 coarse nodes (the 5k
            t-shirt takes 4, a 20k-vertex garment 8).
        levels: 2 solves the coarse level exactly; 3 adds an inner level of at most 256 nodes
            and solves the coarse level by a two-grid cycle around the inner one's exact solve;
            0: 3 for a garment whose coarse level has more than 256 nodes, else 2.
        smoothing: l1-Jacobi passes on the coarse level before and after the inner solve (three
            levels only).
        early: prepare the coarse system at the substep start beside the self-contact detection
            instead of after it, its self-contact stiffness at the particles with pairs at the
            previous substep's end (``CUDA_COARSE_EARLY``; two levels only).
    """

    sweeps: tuple[int, ...] = DEFAULT_COARSE_SWEEPS
    spacing: int = 0
    levels: int = 0
    smoothing: int = 2
    early: bool = False

    def __post_init__(self) -> None:
        sweeps = self.sweeps
        _require("coarse", "sweeps", sweeps, isinstance(sweeps, (list, tuple)) and all(
            isinstance(k, int) and not isinstance(k, bool) for k in sweeps), "a list of sweep indices")
        object.__setattr__(self, "sweeps", tuple(int(k) for k in sweeps))
        _require("coarse", "spacing", self.spacing, self.spacing >= 0, ">= 1 (0: automatic)")
        _require("coarse", "levels", self.levels, self.levels in (0, 2, 3), "2, 3 or 0 (automatic)")
        _require("coarse", "smoothing", self.smoothing, self.smoothing >= 1, ">= 1")


@dataclass(frozen=True)
class KernelLayout:
    """How the solve runs on the device; the CPU runs one thread per particle whatever these say,
    so only ``max_colors`` changes its floats.

    Attributes:
        lanes: GPU threads that share one particle's solve; 0: by the model's size
            (``solver_vbd.auto_lanes``).
        particles_per_block: particles solved by one GPU thread block (``particles x lanes``
            threads); with ``lanes`` 0 it is chosen with them.
        gather: how a solve thread gathers its share of a particle's triangles, hinges and
            self-contact records: ``"fused"`` (item ``r`` of every kind loaded together:
            latency-bound single garments), ``"split"`` (one kind after the other: batches,
            throughput-bound) or ``"auto"`` (fused from ``solve_kernel.FUSED_LANES`` lanes per
            particle).
        max_registers: CUDA registers per thread of the solve kernel (the compiler spills what
            does not fit); 0: the compiler's choice; -1: ``solver_vbd.AUTO_BATCH_MAX_REGISTERS``
            in the automatic batch layout, else the compiler's choice.
        fast_math: compile the CUDA solve kernel with fast math (approximate division, square
            root and transcendentals, denormals flushed): 5k t-shirt 7.04 / 7.07 against 7.69 /
            7.70 ms per walk / run frame, 134 of 144 random walks and runs passing against 133.
        max_colors: colours of the model's vertex colouring (``ClothModelBuilder(max_colors)``;
            0: a proper colouring, the t-shirt's 4; ``CUDA_COLORS`` on CUDA).
    """

    lanes: int = 0
    particles_per_block: int = 8
    gather: str = "auto"
    max_registers: int = -1
    fast_math: bool = True
    max_colors: int = 0

    def __post_init__(self) -> None:
        def req(name: str, ok: bool, rule: str) -> None:
            _require("layout", name, getattr(self, name), ok, rule)

        req("lanes", 0 <= self.lanes <= 256, "in 0..256 (0: auto)")
        req("particles_per_block", self.particles_per_block >= 1
            and self.lanes * self.particles_per_block <= 1024, f">= 1 with lanes ({self.lanes}) x "
            "particles_per_block <= 1024")
        req("gather", self.gather in ("auto", "fused", "split"), "'auto', 'fused' or 'split'")
        req("max_registers", self.max_registers in (-1, 0) or 24 <= self.max_registers <= 255,
            "-1 (auto), 0 (compiler's choice) or in 24..255")
        req("max_colors", self.max_colors == 0 or self.max_colors >= 2, "0 (proper colouring) or >= 2")


SECTION_TYPES: dict[str, type] = {"stepping": Stepping, "body_contact": BodyContact,
                                  "self_contact": SelfContactConfig, "coarse": CoarseConfig,
                                  "layout": KernelLayout}
"""The dataclass of each section."""

SECTIONS = tuple(SECTION_TYPES)
"""The sections of a ``VBDConfig``, as they are named in override keys and in ``to_dict``."""


@dataclass(frozen=True)
class VBDConfig:
    """Solver settings, by section (each validates its own fields; ``ValueError`` names the field).

    Attributes:
        stepping: substeps, sweeps, air damping.
        body_contact: cloth-body contact.
        self_contact: cloth-cloth contact.
        coarse: the coarse-level correction.
        layout: the solve's GPU layout and the model's colouring.
    """

    stepping: Stepping = field(default_factory=Stepping)
    body_contact: BodyContact = field(default_factory=BodyContact)
    self_contact: SelfContactConfig = field(default_factory=SelfContactConfig)
    coarse: CoarseConfig = field(default_factory=CoarseConfig)
    layout: KernelLayout = field(default_factory=KernelLayout)

    def __post_init__(self) -> None:
        for name, cls in SECTION_TYPES.items():
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f"VBDConfig.{name} must be a {cls.__name__}, got {getattr(self, name)!r}")
        sweeps = self.coarse.sweeps
        iterations = self.stepping.iterations
        if any(not 0 <= k < iterations for k in sweeps) or len(set(sweeps)) != len(sweeps):
            last = iterations - 1
            raise ValueError(f"VBDConfig.coarse.sweeps must hold distinct sweep indices in 0..{last} "
                             f"(stepping.iterations {iterations}), got {sweeps} (or none: [])")

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """JSON-ready nested dict (``from_dict`` inverts it)."""
        out = dataclasses.asdict(self)
        out["coarse"]["sweeps"] = list(self.coarse.sweeps)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Mapping[str, Any]]) -> VBDConfig:
        """The config of a ``to_dict`` dict; a missing section or field takes its default.

        Raises:
            ValueError: an unknown section or field, or an invalid value.
        """
        unknown = sorted(set(data) - set(SECTIONS))
        if unknown:
            raise ValueError(f"VBDConfig: unknown section(s) {unknown}; expected {', '.join(SECTIONS)}")
        sections = {}
        for name, values in data.items():
            sections[name] = _section(name, {k: _coerce(name, k, v) for k, v in values.items()})
        return cls(**sections)


def _section(name: str, values: Mapping[str, Any], base: Any = None) -> Any:
    """Section ``name`` with ``values`` over ``base`` (None: the defaults)."""
    cls = SECTION_TYPES[name]
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - fields)
    if unknown:
        raise ValueError(f"VBDConfig.{name}: unknown field(s) {unknown}; expected "
                         f"{', '.join(sorted(fields))}")
    return dataclasses.replace(base, **values) if base is not None else cls(**values)


def _coerce(section: str, name: str, value: Any) -> Any:
    """``value`` as the type of field ``section.name`` (an integral float as an int, 0/1 as a
    bool, a list as a tuple: what a command line or a TOML table gives)."""
    hints = typing.get_type_hints(SECTION_TYPES[section])
    kind = hints.get(name)
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind is bool and number and value in (0, 1):
        return bool(value)
    if kind is int and isinstance(value, float) and value.is_integer():
        return int(value)
    if kind is float and number:
        return float(value)
    if kind is not None and typing.get_origin(kind) is tuple and isinstance(value, (list, tuple)):
        return tuple(int(k) if isinstance(k, float) and k.is_integer() else k for k in value)
    wrong_int = kind is int and isinstance(value, bool)
    if kind in _TYPE_NAMES and (not isinstance(value, kind) or wrong_int):
        raise ValueError(f"VBDConfig.{section}.{name} must be {_TYPE_NAMES[kind]}, got {value!r}")
    return value


_TYPE_NAMES = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def override_keys() -> list[str]:
    """Every ``"section.field"`` key ``apply_overrides`` takes."""
    return [f"{s}.{f.name}" for s in SECTIONS for f in dataclasses.fields(SECTION_TYPES[s])]


def parse_overrides(overrides: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Flat ``"section.field": value`` overrides grouped by section, each value as its field's
    type (``"self_contact.radius": 0.004`` -> ``{"self_contact": {"radius": 0.004}}``). A section
    may also come as a table of its fields (``{"self_contact": {"radius": 0.004}}``: what a TOML
    ``self_contact.radius = 0.004`` reads as).

    Raises:
        WrinklesInputError: an unknown key or a value of the wrong type, in one line.
    """
    flat: dict[str, Any] = {}
    for key, value in overrides.items():
        if key in SECTION_TYPES and isinstance(value, Mapping):
            flat.update({f"{key}.{name}": v for name, v in value.items()})
        else:
            flat[key] = value
    grouped: dict[str, dict[str, Any]] = {}
    for key, value in flat.items():
        section, _, name = str(key).partition(".")
        if section not in SECTION_TYPES or not name:
            raise WrinklesInputError(f"solver option {key!r}: expected section.field with a section of "
                                     f"{', '.join(SECTIONS)} (e.g. self_contact.radius)")
        names = [f.name for f in dataclasses.fields(SECTION_TYPES[section])]
        if name not in names:
            raise WrinklesInputError(f"solver option {key!r}: unknown; {section} has {', '.join(names)}")
        try:
            grouped.setdefault(section, {})[name] = _coerce(section, name, value)
        except ValueError as e:
            raise WrinklesInputError(f"solver option {key}={value!r}: {e}") from None
    return grouped


def _build(values: Mapping[str, Mapping[str, Any]], base: VBDConfig | None = None) -> VBDConfig:
    """``base`` (None: the defaults) with the sections' ``values``, validated once."""
    base = base or VBDConfig()
    try:
        return dataclasses.replace(base, **{s: _section(s, v, getattr(base, s)) for s, v in values.items()})
    except ValueError as e:
        raise WrinklesInputError(f"solver settings: {e}") from None


def apply_overrides(config: VBDConfig, overrides: Mapping[str, Any]) -> VBDConfig:
    """``config`` with flat ``"section.field": value`` overrides (``parse_overrides``).

    Raises:
        WrinklesInputError: an unknown key or an invalid value, in one line.
    """
    return _build(parse_overrides(overrides), config)


def job_config(vertices: int, cuda: bool, *, substeps: int = 0, iterations: int = 0,
               coarse_sweeps: Sequence[int] | None = None, coarse_spacing: int = 0,
               self_contact: bool | None = True,
               overrides: Mapping[str, Any] = types.MappingProxyType({})) -> VBDConfig:
    """The job's solver settings for a run whose largest garment has ``vertices`` vertices, on
    CUDA (``cuda``) or the CPU.

    Args:
        vertices: vertices of the run's largest garment: over ``FINE_GARMENT_VERTICES`` the
            fine defaults apply.
        cuda: a run on CUDA (``CUDA_COLORS``, ``CUDA_COARSE_EARLY``).
        substeps: substeps per frame (0: ``DEFAULT_SUBSTEPS`` or ``FINE_SUBSTEPS``).
        iterations: sweeps per substep (0: ``DEFAULT_ITERATIONS`` or ``FINE_ITERATIONS``).
        coarse_sweeps: sweeps before which a coarse correction runs (None:
            ``DEFAULT_COARSE_SWEEPS`` where there are more than 2 sweeps, else none).
        coarse_spacing: the coarse aggregates' spacing [edges] (0: automatic).
        self_contact: self-contact on or off, over ``overrides`` (None: as ``overrides`` leave it).
        overrides: ``"section.field": value`` settings over the job's (``parse_overrides``).

    Raises:
        WrinklesInputError: an unknown override key or an invalid value, in one line.
    """
    fine = vertices > FINE_GARMENT_VERTICES
    iterations = iterations or default_iterations(vertices)
    if coarse_sweeps is None:
        coarse_sweeps = DEFAULT_COARSE_SWEEPS if iterations > 2 else ()
    values: dict[str, dict[str, Any]] = {
        "stepping": {"substeps": substeps or default_substeps(vertices),
                     "iterations": iterations},
        "self_contact": {"coarse_exclusion": FINE_COARSE_EXCLUSION if fine else 0.0},
        "coarse": {"sweeps": tuple(coarse_sweeps), "spacing": coarse_spacing,
                   "early": CUDA_COARSE_EARLY and cuda},
        "layout": {"max_colors": CUDA_COLORS if cuda else 0},
    }
    for section, changes in parse_overrides(overrides).items():
        values.setdefault(section, {}).update(changes)
    if self_contact is not None:
        values["self_contact"]["enabled"] = bool(self_contact)
    return _build(values)
