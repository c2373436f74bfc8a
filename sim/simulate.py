"""The sequence driver: dress a garment on a body, settle it, blend the body in from rest, play
the motion, and return a ``GarmentSequence`` with its quality report (issue 3, "Dressing" and
"Quality gates").

Timeline of one run at ``fps`` (one solver step of ``1/fps`` per frame, ``substeps`` inside)::

    frame 0            the garment placed on the body in rest pose (``sim.dressing``)
    settle_seconds     body static at rest; garment falls onto it and comes to rest (a garment
                       built on another shape: the body morphs to the job's shape first)
    blend_seconds      body slerped from rest into the motion's first pose (``blend_from_rest``)
    motion             the motion, frame by frame

The settle and blend frames are the *prelude*; by default they are dropped, so a sequence
starts at the motion's first frame with the garment at rest and collision-free
(``SimulationConfig.keep_prelude`` keeps them). Attachment sets named in
``SimulationConfig.pinned`` follow the skin (``sim.dressing.AttachmentPins``); the rest is
free. Every frame is checked for NaN and explosion (``SimulationError`` naming the frame and
the cause); every sequence gets a ``QualityReport`` judged against ``SimulationConfig.gates``.

Reference-shape dressing: a garment built on one shape (``SimulationJob.garment_betas``, e.g.
the mean shape) worn by a body of another (``betas``) keeps its topology; the body morphs from
the garment's rest mesh to the target rest mesh over the first ``MORPH_FRACTION`` of the settle
(smoothstep) and holds the target shape for the rest of it (``morph_settle``). Blend shapes are
linear in the betas and the settle is in rest pose, so the interpolated frames are exactly the
rest meshes of the interpolated shapes. This gives the per-garment models of Guo et al. 2024
(Sec. 3.3) one garment mesh over many body shapes.

Several garments / sequences run batched in one ``ClothModel`` (``simulate_batch``): one
launch advances all of them; instances never interact. The body of each sequence is uploaded
to the device once; per frame the host copies two frames device-to-device into the collider,
launches the step (replayed from a CUDA graph on CUDA, plain launches on CPU), and reads the
positions back for the checks and the output. Nothing runs on the host per substep.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.types import Garment
from sim.quality import (
    QualityGates,
    QualityReport,
    SimulationError,
    check_frame,
    evaluate_sequence,
    unique_edges,
)
from sim.types import BodyFrames, GarmentSequence, Motion

DEFAULT_PINNED: tuple[str, ...] = ("waistband",)
"""Attachment sets pinned to the body by default: an elastic waistband grips the waist. Tops
hang on the shoulders by contact and friction: pinning their shoulder line to the skin drags
it with the deltoid, whose skin stretches and folds as the arm moves (edge strain up to 0.9 on
the walk's T-pose-to-arms-down ramp against 0.6 free). Hems and cuffs stay free."""

ProgressFn = Callable[[int, int], None]

MORPH_FRACTION = 0.6
"""Share of the settle frames over which the body morphs from the garment's shape to the job's;
the cloth comes to rest on the target shape during the remainder."""


FINE_GARMENT_VERTICES = 10_000
"""Garments with more vertices than this take ``FINE_SUBSTEPS`` substeps by default."""
DEFAULT_SUBSTEPS, FINE_SUBSTEPS = 12, 14
"""Default substeps per frame (``SimulationConfig.substeps`` 0) of a garment up to
``FINE_GARMENT_VERTICES`` vertices, and of a finer one. Session 38 (H100, populations of random
walks and runs, docs/BENCHMARKS.md): the 5k t-shirt passes 134 of 144 at 12 (133 at 14 before the
templates' hems); the 19k t-shirt 7 of 16 at 14 and 2 of 16 at 12."""


CUDA_COLORS = 3
"""Colours of the vertex colouring (``VBDConfig.max_colors``) of a run on CUDA; the CPU keeps a
proper colouring (0). H100, docs/BENCHMARKS.md: on the 5k t-shirt with the cluster broadphase
4.24 / 4.30 ms per walk / run frame against 4.46 / 4.52 with a proper colouring (session 41, the
same code; one launch fewer per sweep, ~2 % of the edges same-coloured and coupled by a Jacobi
step); 135 of 144 random walks and runs passing against 134 (sessions 40 and 41); batches of
1-256 t-shirts 2-6 % more garment-frames/s. On the CPU it bought nothing (1k t-shirt 125.3 /
123.3 against 118.1 / 126.8 ms, strain 0.16 / 0.18 against 0.14 / 0.14; session 40)."""


CUDA_COARSE_EARLY = True
"""Whether a run on CUDA prepares the coarse system beside the self-contact detection
(``VBDConfig.coarse_early``: its diagonal's self-contact stiffness at the particles with pairs at
the previous substep's end). H100, docs/BENCHMARKS.md (session 42): the 5k t-shirt 3.76 / 3.82 ms
per walk / run frame against 3.95 / 4.00 (the coarse factor was on the critical path: doubling it
added 0.75 ms per frame), populations of random walks and runs 46 / 46 / 47 = 139 of 144 passing
against 135 (session 41). The CPU runs in order on one stream: nothing to gain there, so its
floats stay as before."""


RETRY_FACTORS = (5.0 / 3.0, 2.0)
"""Substeps of the retries of a sequence that fails its quality gates or stops (NaN, explosion), as
multiples of its run's substeps (``SimulationConfig.retry_factors``): 12 -> 20 -> 24 (a fine
garment: 14 -> 23 -> 28 and a third rung, ``FINE_RETRY_FACTORS``). A step too long for a fast
motion, not the physics, fails most fast sequences that fail (session 43: at the fine size more
sweeps or coarse corrections per substep did not pass the runs, more substeps did). H100,
docs/BENCHMARKS.md (session 43), the templates' runs: at the coarse size 2 of 8 pass at 12
substeps, 3 at 16, 5 at 20 and 5 at 24 (not the same 5), so 6 of 8 pass within the ladder; at the
fine size (~20k) none at 14, 1 at 23 and 2 at 28. Walks pass at the default (8 of 8, coarse). The
trousers' and the straight skirt's runs pass at no count: the skinned body's own skin within 5 cm
of the trousers' worst edge is stretched by 48 % (90th percentile) and up to 78 % (linear blend
skinning at the crotch), and a straight skirt's hem cannot span a running stride."""


FINE_RETRY_FACTORS = (5.0 / 3.0, 2.0, 3.0)
"""The retries of a garment over ``FINE_GARMENT_VERTICES`` vertices (``SimulationConfig.retry_factors``
None, automatic): ``RETRY_FACTORS`` and a third rung at 3x, 14 -> 23 -> 28 -> 42. H100,
docs/BENCHMARKS.md (session 45): a fine dataset of 8 sampled walks and runs (every template)
accepts 6 with the rung against 4 without, in 160 s against session 44's 113 s (27 s per accepted
sequence against 28): the dress's and the straight skirt's runs pass at 42; the trousers' runs
fail at every count. On the default body (session 44) 42 substeps pass the fine tank-top and
long-sleeve runs. At the coarse size the rung adds nothing: session 43's dataset of 32 accepts
28 either way, in 16 % more time (the trousers' runs and a straight skirt's fail at 36 too), so
coarse garments keep ``RETRY_FACTORS``."""


DEFAULT_ITERATIONS, FINE_ITERATIONS = 5, 8
"""Default sweeps per substep (``SimulationConfig.iterations`` 0) of a garment up to
``FINE_GARMENT_VERTICES`` vertices, and of a finer one. A finer mesh at the same substeps needs
more sweeps: its particles are lighter against the same membrane stiffness, so a sweep carries
less of a substep's correction. H100, docs/BENCHMARKS.md (session 44), every template at ~20k
vertices on the default body: the walks pass 4 of 8 at 14x5, 6 of 8 at 14x8 (18 % more time per
frame: 15.2-20.6 ms against 12.7-17.2) and 6 of 8 at 23x5 (60 % more); the runs 0 of 8 at both
14x5 and 14x8 (max strain lower at 14x8 for 6 of 8: tank top 0.84 -> 0.60, dress 0.76 -> 0.60);
the 19k t-shirt's population of random walks and runs 8 of 16 against 7; a fine dataset of 16
sampled walks and runs accepts 5 without retries against 2. Until session 44 every garment ran
5 sweeps."""

FINE_COARSE_EXCLUSION = 0.006
"""``VBDConfig.self_contact_coarse_exclusion`` of the job default for fine garments (more than
``FINE_GARMENT_VERTICES``; 0 for the others): self-contact pairs closer than 6 mm at rest leave
the coarse correction alone (session 50, H100, docs/BENCHMARKS.md). On the fine shorts the
crotch point sank 98 mm by the blend's end and the whole garment 12 mm in the settle; with it,
22 mm and 3 mm (as without self-contact), and the walk's largest strain fell from 0.546 to 0.391
(the fine trousers': 0.297 to 0.235). Coarse garments keep 0: there the exclusion frees only the
pants' inner walls, and the coarse trousers' walk crossed itself."""


def default_substeps(vertices: int) -> int:
    """Substeps per frame of the job default for a garment of ``vertices`` vertices."""
    return FINE_SUBSTEPS if vertices > FINE_GARMENT_VERTICES else DEFAULT_SUBSTEPS


def default_iterations(vertices: int) -> int:
    """Sweeps per substep of the job default for a garment of ``vertices`` vertices."""
    return FINE_ITERATIONS if vertices > FINE_GARMENT_VERTICES else DEFAULT_ITERATIONS


def default_retry_factors(vertices: int) -> tuple[float, ...]:
    """Retry factors of the job default for a garment of ``vertices`` vertices."""
    return FINE_RETRY_FACTORS if vertices > FINE_GARMENT_VERTICES else RETRY_FACTORS


JOB_COARSE_GUARD = False
"""``VBDConfig.coarse_guard`` of the job (the CLI, datasets): off, though a bare ``VBDConfig``
has the coarse system's overshoot guard on since session 51. On the GPU the guard was even with
the old coarse system (fine gates: walks 7 of 8 against 6, runs 2 and 2; the fine dataset 13 of
16 against 14, 10 at the first rung against 7; the 5k t-shirt 3.76 / 3.84 ms); on the CPU it
raised every fine walk's strain (t-shirt 0.203 -> 0.262, dress 0.241 -> 0.318, the long sleeve on
two bodies 0.199 / 0.205 -> 0.427 / 0.557 with crossings). The job's defaults were measured on
the old system over many sessions, so they keep it until a proxy that does not need the guard
(docs/BENCHMARKS.md, session 51)."""


def simulator_defaults(cuda: bool = False) -> dict:
    """The defaults that shape a simulation without being written in its config: the automatic
    substeps, the templates' hems and, on CUDA (``cuda``), the colouring (``CUDA_COLORS``; the
    CPU's proper colouring is recorded by its absence, as before session 41). A dataset records
    them beside its config, so that it is not continued under other physics
    (``sim.datasets.generate``): neither one begun on the other kind of device nor one begun on
    CUDA before the colouring changed, or before the early coarse diagonal (``coarse_early``,
    session 42), nor one begun before sequences that fail their gates were retried
    (``RETRY_FACTORS``, session 43; a dataset's own ``[simulation] retry_factors`` is in its
    config), nor one begun before fine garments took 8 sweeps (``FINE_ITERATIONS``, session 44)
    or a third retry rung (``FINE_RETRY_FACTORS``, session 45), before fine garments' near-rest
    pairs left the coarse correction alone (``FINE_COARSE_EXCLUSION``, session 50) or before the
    coarse system's overshoot guard (``JOB_COARSE_GUARD``; recorded since session 51),
    nor one begun under other template defaults (every template's default parameters, recorded
    since session 44, when the tank top's armholes were rounded), nor one begun before the
    procedural gaits' cadence rose to keep the hips inside their joint limits (``gait``,
    ``sim.motions.gait.limited_cadence``, session 52: the run's motion changed)."""
    from sim.garments.hems import HEM_LAYERS, HEM_RULE, HEM_WIDTH
    from sim.garments.templates import TEMPLATES, make_params
    from sim.motions.gait import gait_record

    out = {"substeps": {"default": DEFAULT_SUBSTEPS, "fine": FINE_SUBSTEPS,
                        "fine_over_vertices": FINE_GARMENT_VERTICES},
           "iterations": {"default": DEFAULT_ITERATIONS, "fine": FINE_ITERATIONS},
           "coarse_exclusion": {"default": 0.0, "fine": FINE_COARSE_EXCLUSION},
           "coarse_guard": JOB_COARSE_GUARD,
           "hems": {"width_m": HEM_WIDTH, "layers": HEM_LAYERS, "rule": HEM_RULE},
           "retry_factors": {"default": list(RETRY_FACTORS), "fine": list(FINE_RETRY_FACTORS)},
           "templates": {name: dataclasses.asdict(make_params(name)) for name in TEMPLATES},
           "gait": gait_record()}
    if cuda:
        out["max_colors"] = CUDA_COLORS
        out["coarse_early"] = CUDA_COARSE_EARLY
    return out


@dataclass(frozen=True)
class SimulationConfig:
    """Settings of a simulation run (saved with every output; ``from_dict`` refuses unknown keys).

    The solver defaults, 12 substeps x 5 sweeps with one coarse-level correction before sweep 2
    (14 substeps x 8 sweeps for garments over 10k vertices: ``default_substeps``,
    ``default_iterations``; 14 x 5 until session 44), are the issue benchmark's
    setting (docs/BENCHMARKS.md, sessions 23-25; 14 substeps everywhere until session 38, when the
    templates' hems (``sim.garments.hems``) let the 5k t-shirt pass the population of random
    walks and runs as often at 12: 134 of 144 against 133 at 14 without hems). On the 5k t-shirt
    (H100): 0.30x Newton's time per frame, max strain 0.20 / 0.27 on the walk / run, and 43 of
    48 random walks and runs passing every gate against 38 at 16 x 10 without corrections; on
    the CPU as cheap per frame as the former default, 10 x 10 without corrections. On CUDA the
    solve kernel is compiled with fast math (``VBDConfig.fast_math``; session 33, 8.00 -> 7.04 ms
    per 5k t-shirt frame with raw loads and fast math, 134 of 144 sequences passing against
    133), and the coarse system is factored beside the first sweeps
    (``VBDConfig.coarse_prefactor``; session 34, 7.05 -> 6.25 ms, 133 of 144 sequences
    passing); ``solver={"fast_math": false, "coarse_prefactor": false}`` turns them off. The
    self-contact detection searches clusters instead of trees on CUDA for up to four 5k garments
    (``VBDConfig.self_contact_broadphase`` "auto"; session 40, 5.33 -> 4.54 ms per 5k t-shirt
    frame, 134 of 144 sequences passing as before; the same pairs, in another order), and the
    vertices are coloured in 3 colours there (``CUDA_COLORS``; session 41), and the coarse system
    is prepared beside the detection (``CUDA_COARSE_EARLY``; session 42).

    Attributes:
        fps: output frame rate [1/s]; the solver takes one step of ``1/fps`` per frame and the
            motion is resampled to it.
        substeps: implicit-Euler substeps per frame; 0, the default: ``default_substeps`` of
            the run's largest garment (12, or 14 over 10k vertices).
        iterations: VBD Gauss-Seidel sweeps per substep; 0, the default:
            ``default_iterations`` of the run's largest garment (5, or 8 over 10k vertices;
            5 everywhere until session 44).
        coarse_sweeps: sweeps (0 .. iterations - 1) before which a coarse-level correction runs
            (``VBDConfig.coarse_sweeps``; empty: none; None, the default: before sweep 2 where
            there are 3 or more sweeps, else none).
        coarse_spacing: the coarse level's aggregate spacing [edges] (``VBDConfig``; 0: 4, with
            a third level for a garment whose coarse level has more than 256 nodes,
            ``VBDConfig.coarse_levels``).
        settle_seconds: time [s] the garment settles on the static rest body before the body
            moves.
        blend_seconds: time [s] of the eased transition from rest into the motion's first pose.
        settle_relax: zero the garment's velocities after every settle frame (kinetic damping:
            the settle converges to static equilibrium instead of swinging).
        keep_prelude: keep the settle and blend frames in the output (default: the sequence
            starts at the motion's first frame).
        pinned: attachment sets pinned to the body (names a garment does not define are
            skipped; an imported garment has none).
        ground: stand the body on the floor (y = 0) at the motion's first frame.
        self_contact: cloth self-contact on/off in the solver (default on: without it every
            fine garment folds through itself and fails the self-intersection gate); None
            keeps the solver's own default (off, for solver-level use).
        solver: further ``VBDConfig`` fields by name (``contact_stiffness`` [N/m] ...).
        gates: quality thresholds a sequence must meet.
        max_speed: explosion test: a garment vertex faster than this over one frame [m/s].
        max_stretch: explosion test: an edge longer than this many times its rest length [-].
        max_distance: explosion test: a garment vertex farther than this from the body's root
            joint [m].
        retry_factors: a sequence that fails its gates or stops is simulated again at these
            multiples of its substeps (``retry_substeps``), in turn, until it passes (None:
            automatic, ``RETRY_FACTORS`` up to ``FINE_GARMENT_VERTICES`` garment vertices,
            ``FINE_RETRY_FACTORS`` above; empty: no retries). ``wrinkles simulate`` and the
            dataset generator retry; ``simulate`` and ``simulate_batch`` run once.
        device: Warp device ("auto": cuda when present, else cpu).
    """

    fps: float = 30.0
    substeps: int = 0
    iterations: int = 0
    coarse_sweeps: tuple[int, ...] | None = None
    coarse_spacing: int = 0
    settle_seconds: float = 1.0
    blend_seconds: float = 1.0
    settle_relax: bool = True
    keep_prelude: bool = False
    pinned: tuple[str, ...] = DEFAULT_PINNED
    ground: bool = True
    self_contact: bool | None = True
    solver: dict = field(default_factory=dict)
    gates: QualityGates = field(default_factory=QualityGates)
    max_speed: float = 50.0
    max_stretch: float = 3.0
    max_distance: float = 3.0
    retry_factors: tuple[float, ...] | None = None
    device: str = "auto"

    def __post_init__(self) -> None:
        object.__setattr__(self, "pinned", tuple(str(p) for p in self.pinned))
        f = self.retry_factors
        if f is not None and not (isinstance(f, (list, tuple)) and all(
                isinstance(k, (int, float)) and not isinstance(k, bool) and np.isfinite(k) for k in f)
                and all(b > a for a, b in zip((1.0, *f), f, strict=False))):
            raise WrinklesInputError("simulation config: retry_factors must be a list of increasing numbers "
                                     f"above 1 (empty: no retries), got {f!r}")
        if f is not None:
            object.__setattr__(self, "retry_factors", tuple(float(k) for k in f))
        if self.coarse_sweeps is not None:
            if not isinstance(self.coarse_sweeps, (list, tuple)) or not all(
                    isinstance(k, int) and not isinstance(k, bool) for k in self.coarse_sweeps):
                raise WrinklesInputError("simulation config: coarse_sweeps must be a list of sweep indices "
                                         f"or null (automatic), got {self.coarse_sweeps!r}")
            object.__setattr__(self, "coarse_sweeps", tuple(self.coarse_sweeps))
        object.__setattr__(self, "solver", dict(self.solver))
        if isinstance(self.gates, dict):
            object.__setattr__(self, "gates", _from_fields(QualityGates, self.gates, "gates"))

        def bad(name: str, rule: str) -> WrinklesInputError:
            return WrinklesInputError(f"simulation config: {name} must be {rule}, "
                                      f"got {getattr(self, name)!r}")

        for name in ("fps", "max_speed", "max_stretch", "max_distance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise bad(name, "a positive number")
        for name in ("substeps", "iterations"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 0):
                raise bad(name, "an integer >= 0 (0: automatic)")
        for name in ("settle_seconds", "blend_seconds"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise bad(name, "a number of seconds >= 0")
        if self.max_stretch <= 1.0:
            raise bad("max_stretch", "> 1")
        self.vbd_config()  # validates solver / self_contact

    @property
    def settle_frames(self) -> int:
        """Frames of the settle phase (as ``blend_from_rest`` rounds its ``hold``)."""
        return int(round(self.settle_seconds * self.fps))

    @property
    def blend_frames(self) -> int:
        """Frames of the blend from rest (as ``blend_from_rest`` rounds them)."""
        return int(round(self.blend_seconds * self.fps))

    def solver_steps(self, motion_frames: int) -> int:
        """Solver steps (one per frame) of a run over a motion of ``motion_frames`` frames."""
        return self.settle_frames + self.blend_frames + int(motion_frames) - 1

    # --- solver settings -----------------------------------------------------------------
    def substeps_for(self, vertices: int) -> int:
        """Substeps per frame for a run whose largest garment has ``vertices`` vertices."""
        return self.substeps or default_substeps(vertices)

    def iterations_for(self, vertices: int) -> int:
        """Sweeps per substep for a run whose largest garment has ``vertices`` vertices."""
        return self.iterations or default_iterations(vertices)

    def retry_factors_for(self, vertices: int) -> tuple[float, ...]:
        """Retry factors for a run whose largest garment has ``vertices`` vertices."""
        return self.retry_factors if self.retry_factors is not None else default_retry_factors(vertices)

    def retry_substeps(self, vertices: int) -> tuple[int, ...]:
        """Substeps of the retries (``retry_factors_for``) of a run whose largest garment has
        ``vertices`` vertices, in order: each factor times ``substeps_for``, rounded, counts not
        above the one before dropped."""
        base = self.substeps_for(vertices)
        out: list[int] = []
        for f in self.retry_factors_for(vertices):
            n = int(round(f * base))
            if n > (out[-1] if out else base):
                out.append(n)
        return tuple(out)

    def vbd_config(self, vertices: int = 0, cuda: bool = False):
        """The ``VBDConfig`` of these settings (``substeps`` and ``iterations`` for a largest
        garment of ``vertices`` vertices, ``self_contact`` and ``solver`` overrides) for a run on CUDA
        (``cuda``: the colouring of ``CUDA_COLORS``) or on the CPU.

        Raises:
            WrinklesInputError: an unknown solver field, or self-contact requested from a
                solver that has no ``self_contact`` option.
        """
        from sim.cloth import VBDConfig

        allowed = {f.name for f in dataclasses.fields(VBDConfig)}
        iterations = self.iterations_for(vertices)
        sweeps = self.coarse_sweeps
        if sweeps is None:
            sweeps = (2,) if iterations > 2 else ()
        # fast math in the CUDA solve kernel (session 33): 8 % faster per 5k t-shirt frame, the
        # population passing as often (docs/BENCHMARKS.md); the CPU is unaffected. The coarse
        # factor beside the first sweeps (session 34): 11 % faster, the population within noise
        kw: dict[str, Any] = {"substeps": self.substeps_for(vertices), "iterations": iterations,
                              "coarse_sweeps": sweeps, "coarse_spacing": self.coarse_spacing,
                              "fast_math": True, "coarse_prefactor": True,
                              "max_colors": CUDA_COLORS if cuda else 0,
                              "coarse_early": CUDA_COARSE_EARLY and cuda,
                              "self_contact_coarse_exclusion":
                                  FINE_COARSE_EXCLUSION if vertices > FINE_GARMENT_VERTICES else 0.0,
                              "coarse_guard": JOB_COARSE_GUARD}
        unknown = sorted(set(self.solver) - allowed)
        if unknown:
            raise WrinklesInputError(f"simulation config: unknown solver option(s) {unknown}; "
                                     f"expected {', '.join(sorted(allowed))}")
        kw.update(self.solver)
        if self.self_contact is not None:
            if "self_contact" in allowed:
                kw["self_contact"] = bool(self.self_contact)
            elif self.self_contact:
                raise WrinklesInputError("self-contact was requested but this build's VBD solver has no "
                                         "'self_contact' option yet")
        try:
            return VBDConfig(**kw)
        except (TypeError, ValueError) as e:
            raise WrinklesInputError(f"simulation config: {e}") from None

    # --- (de)serialisation ---------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready dict (``from_dict`` inverts it)."""
        d = dataclasses.asdict(self)
        d["pinned"] = list(self.pinned)
        d["retry_factors"] = None if self.retry_factors is None else list(self.retry_factors)
        if self.coarse_sweeps is not None:
            d["coarse_sweeps"] = list(self.coarse_sweeps)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> SimulationConfig:
        """Build from a dict; unknown keys are an error (they list the known ones)."""
        d = dict(d)
        if "pinned" in d:
            d["pinned"] = tuple(d["pinned"])
        return _from_fields(cls, d, "simulation config")


def _from_fields(cls, d: dict, what: str):
    allowed = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        raise WrinklesInputError(f"{what}: unknown key(s) {unknown}; expected {', '.join(allowed)}")
    return cls(**d)


@dataclass(frozen=True)
class SimulationJob:
    """One sequence to simulate.

    Attributes:
        garment: the garment, at rest around ``body``'s rest mesh with ``betas``.
        body: a ``sim.bodies.BodyModel``.
        motion: the motion (resampled to the config's fps when it differs).
        betas: body shape (B,); None: the motion's own betas, else the mean shape.
        name: label used in error messages (default: garment name and motion name).
        garment_betas: the body shape (B,) the garment was built on; None: ``betas`` (the
            resolved shape). When it differs, the body morphs from this shape's rest mesh to
            the target shape's during the settle (``morph_settle``) and the attachments are
            bound on this shape's surface.
    """

    garment: Garment
    body: Any
    motion: Motion
    betas: np.ndarray | None = None
    name: str = ""
    garment_betas: np.ndarray | None = None

    @property
    def label(self) -> str:
        return self.name or f"{self.garment.name}/{self.motion.name}"


@dataclass(frozen=True)
class SimulationResult:
    """A simulated sequence with its quality report.

    Attributes:
        sequence: the garment sequence (provenance holds the resolved config).
        quality: quality statistics of every output frame.
        failed_gates: human-readable reasons the sequence fails ``config.gates`` (empty: passes).
        step_ms: wall time [ms] of each solver frame of the output (launch to device
            synchronisation; the host copy and checks excluded), shared by a batch.
    """

    sequence: GarmentSequence
    quality: QualityReport
    failed_gates: tuple[str, ...]
    step_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def passed(self) -> bool:
        return not self.failed_gates


def resolve_betas(body, motion: Motion, betas: np.ndarray | None) -> np.ndarray:
    """The shape a run uses: ``betas`` if given, else the motion's own (AMASS files carry the
    subject's), else the mean shape; zero-padded / cut to the body's ``num_betas``, float32 (B,)."""
    b = betas if betas is not None else motion.betas
    if b is None:
        return body.full_betas(None)
    b = np.asarray(b, np.float32).reshape(-1)
    if betas is None and b.size > body.num_betas:  # a file's betas beyond the model's basis
        b = b[: body.num_betas]
    return body.full_betas(b)


def package_versions() -> dict[str, str]:
    """Installed versions of the packages a result depends on."""
    import importlib.metadata as md

    out = {}
    for pkg in ("wrinkles", "warp-lang", "numpy"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out


# ------------------------------------------------------------------------------- the driver


@dataclass
class _Track:
    """Host-side bookkeeping of one job."""

    job: SimulationJob
    motion: Motion  # the input motion at the config's fps
    timeline: Motion  # prelude + motion
    frames: BodyFrames  # the body over the timeline (grounded)
    betas: np.ndarray
    n_settle: int
    n_blend: int
    first_out: int  # timeline index of output frame 0
    placement: np.ndarray  # (3,) garment translation from its rest mesh
    ground_dy: float
    pinned: np.ndarray  # garment-local pinned vertex ids
    body_key: tuple = ()  # shared skinning / collider key
    garment_betas: np.ndarray | None = None  # (B,) the garment's shape when it differs from betas
    span: slice = field(default_factory=lambda: slice(0, 0))  # particle range in the model
    out: np.ndarray | None = None  # (T_out, V, 3)
    collider: Any = None
    body_points: Any = None  # Warp (T, V_body) body positions on the device

    @property
    def length(self) -> int:
        return self.frames.num_frames


def smoothstep(t: np.ndarray) -> np.ndarray:
    """C1 ease 3t^2 - 2t^3 of t clipped to [0, 1]."""
    t = np.clip(np.asarray(t, np.float64), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def morph_frames(n_settle: int, *, fraction: float = MORPH_FRACTION) -> int:
    """Frames over which the body morphs in a settle of ``n_settle`` frames (>= 1)."""
    return max(1, int(round(fraction * n_settle)))


def morph_settle(frames_ref: BodyFrames, frames_target: BodyFrames, n_settle: int, *,
                 fraction: float = MORPH_FRACTION) -> BodyFrames:
    """Morph a body from a reference shape to the target shape over the settle.

    Timeline frame t <= ``n_settle`` is ``(1 - w) ref[t] + w target[t]`` with
    ``w = smoothstep(t / m)``, ``m = morph_frames(n_settle)``: frame 0 is the reference body,
    frames m.. the target; frames after the settle are the target's unchanged. Exact for rest
    pose (blend shapes and the joint regressor are linear in the betas).

    Args:
        frames_ref: the body with the garment's shape, at least ``n_settle + 1`` frames, in
            rest pose over them; vertices (T_ref, V, 3) [m].
        frames_target: the body with the job's shape over the whole timeline (T, V, 3) [m].
        n_settle: settle frames (timeline frames 0..n_settle are at rest), >= 1.
        fraction: share of the settle spent morphing.

    Returns:
        BodyFrames like ``frames_target`` (float32) with the settle frames morphed; joint
        transforms keep the target's rotations (identity at rest) and interpolate translations.
    """
    n = int(n_settle)
    if n < 1:
        raise ValueError(f"morph_settle: n_settle must be >= 1, got {n_settle}")
    if frames_ref.num_frames < n + 1 or frames_target.num_frames < n + 1:
        raise ValueError(f"morph_settle: need {n + 1} frames, got {frames_ref.num_frames} (reference) and "
                         f"{frames_target.num_frames} (target)")
    if frames_ref.vertices.shape[1:] != frames_target.vertices.shape[1:]:
        raise ValueError("morph_settle: reference and target bodies differ in vertex count")
    w = smoothstep(np.arange(n + 1) / morph_frames(n, fraction=fraction))

    def lerp(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        ww = w.reshape(-1, *([1] * (a.ndim - 1)))
        return ((1.0 - ww) * a.astype(np.float64) + ww * b.astype(np.float64)).astype(np.float32)

    s = slice(0, n + 1)
    vertices = np.array(frames_target.vertices, np.float32, copy=True)
    joints = np.array(frames_target.joints, np.float32, copy=True)
    transforms = np.array(frames_target.transforms, np.float32, copy=True)
    vertices[s] = lerp(frames_ref.vertices[s], frames_target.vertices[s])
    joints[s] = lerp(frames_ref.joints[s], frames_target.joints[s])
    transforms[s, :, :3, 3] = lerp(frames_ref.transforms[s, :, :3, 3], frames_target.transforms[s, :, :3, 3])
    return BodyFrames(vertices=vertices, joints=joints, transforms=transforms, faces=frames_target.faces)


def _prepare(job: SimulationJob, cfg: SimulationConfig, device: str, cache: dict) -> _Track:
    from sim.bodies.placement import floor_offset, translate_frames
    from sim.dressing import attachment_vertices, place_garment
    from sim.motions.blend import blend_from_rest
    from sim.motions.resample import resample_motion

    motion = job.motion
    if abs(float(motion.fps) - float(cfg.fps)) > 1e-9:
        motion = resample_motion(motion, cfg.fps)
    betas = resolve_betas(job.body, motion, job.betas)
    timeline, n_prelude = blend_from_rest(motion, cfg.blend_seconds, hold=cfg.settle_seconds)
    n_settle = cfg.settle_frames
    gbetas = None
    if job.garment_betas is not None:
        gbetas = job.body.full_betas(job.garment_betas)
        if np.array_equal(gbetas, betas):
            gbetas = None
        elif n_settle < 2:
            raise WrinklesInputError(f"{job.label}: the garment was built on another body shape; the body "
                                     f"morphs to this one during the settle, which needs >= 2 frames "
                                     f"(settle_seconds {cfg.settle_seconds:g} s at {cfg.fps:g} fps)")
    key = _body_key(job, betas, gbetas)
    if key not in cache:  # garments sharing a body, shape and motion share its skinning
        frames = job.body.pose(betas, timeline.poses, timeline.trans, device=device)
        dy = floor_offset(frames, frame=n_prelude) if cfg.ground else 0.0  # on the target shape
        if gbetas is not None:  # the garment's shape at frame 0, morphing to the target's
            ref = job.body.pose(gbetas, timeline.poses[:n_settle + 1], timeline.trans[:n_settle + 1],
                                device=device)
            frames = morph_settle(ref, frames, n_settle)
        if dy:
            frames = translate_frames(frames, np.array([0.0, dy, 0.0]))
        cache[key] = (frames, dy)
    frames, dy = cache[key]
    # timeline frame 0 is the rest pose at the motion's first root translation (pose() of zero
    # rotations is rest_mesh + trans), so the garment built on the rest mesh moves by the same;
    # with a garment shape, frame 0 is that shape's rest mesh (morph_settle)
    placement = timeline.trans[0].astype(np.float64) + np.array([0.0, dy, 0.0])
    x0 = place_garment(job.garment.rest_vertices, placement)
    pinned = attachment_vertices(job.garment.attachments, cfg.pinned)
    tr = _Track(job=job, motion=motion, timeline=timeline, frames=frames, betas=betas, n_settle=n_settle,
                n_blend=n_prelude - n_settle, first_out=0 if cfg.keep_prelude else n_prelude,
                placement=placement, ground_dy=float(dy), pinned=pinned, body_key=key, garment_betas=gbetas)
    tr.out = np.empty((tr.length - tr.first_out, job.garment.num_vertices, 3), np.float32)
    if tr.first_out == 0:
        tr.out[0] = x0
    return tr


def _body_key(job: SimulationJob, betas: np.ndarray, garment_betas: np.ndarray | None = None) -> tuple:
    key = (id(job.body), id(job.motion), betas.tobytes())
    return key if garment_betas is None else (*key, garment_betas.tobytes())


class _FrameChecker:
    """Per-frame NaN / explosion tests of one garment (host, on the frame's positions)."""

    def __init__(self, garment: Garment, cfg: SimulationConfig):
        self.edges = unique_edges(garment.faces)
        rest = garment.rest_vertices
        self.rest_len = np.linalg.norm(rest[self.edges[:, 1]] - rest[self.edges[:, 0]], axis=1)
        self.mean_edge = float(self.rest_len.mean())
        self.cfg = cfg

    def __call__(self, x: np.ndarray, x_prev: np.ndarray, root: np.ndarray, frame: int, phase: str) -> None:
        cfg = self.cfg
        try:
            check_frame(x, frame, rest_edge_length=self.mean_edge, bound=1.0e4)
        except SimulationError as e:
            raise SimulationError(frame, phase + e.cause) from None
        dist = np.linalg.norm(x - root, axis=1)
        if dist.max() > cfg.max_distance:
            i = int(np.argmax(dist))
            raise SimulationError(frame, f"{phase}explosion: vertex {i} is {dist[i]:.2f} m from the body's "
                                         f"root joint (limit {cfg.max_distance:g} m)")
        speed = np.linalg.norm(x - x_prev, axis=1) * cfg.fps
        if speed.max() > cfg.max_speed:
            i = int(np.argmax(speed))
            raise SimulationError(frame, f"{phase}explosion: vertex {i} moved at {speed[i]:.1f} m/s "
                                         f"(limit {cfg.max_speed:g} m/s)")
        length = np.linalg.norm(x[self.edges[:, 1]] - x[self.edges[:, 0]], axis=1)
        ratio = length / self.rest_len
        if ratio.max() > cfg.max_stretch:
            e = int(np.argmax(ratio))
            a, b = (int(v) for v in self.edges[e])
            raise SimulationError(frame, f"{phase}explosion: edge {a}-{b} stretched to {ratio[e]:.1f}x its "
                                         f"rest length (limit {cfg.max_stretch:g}x)")


class _BatchScreen:
    """The ``_FrameChecker`` tests vectorised over every instance of a batch at once; the
    per-garment checker runs only on an instance the screen flags, to word the error."""

    def __init__(self, tracks: list[_Track], checkers: list[_FrameChecker], cfg: SimulationConfig):
        self.cfg = cfg
        self.count = len(tracks)
        self.inst = np.concatenate([np.full(tr.span.stop - tr.span.start, k) for k, tr in enumerate(tracks)])
        self.edges = np.concatenate([c.edges + tr.span.start for c, tr in zip(checkers, tracks, strict=True)])
        self.edge_inst = self.inst[self.edges[:, 0]]
        self.rest_len = np.concatenate([c.rest_len for c in checkers])

    def __call__(self, x: np.ndarray, x_prev: np.ndarray, roots: np.ndarray) -> np.ndarray:
        """Instances (bool (I,)) with a non-finite, too distant, too fast vertex or a too long edge."""
        cfg = self.cfg
        with np.errstate(invalid="ignore", over="ignore"):
            bad = ~np.isfinite(x).all(axis=1)
            bad |= ~(np.linalg.norm(x - roots[self.inst], axis=1) <= cfg.max_distance)
            bad |= ~(np.linalg.norm(x - x_prev, axis=1) * cfg.fps <= cfg.max_speed)
            ratio = np.linalg.norm(x[self.edges[:, 1]] - x[self.edges[:, 0]], axis=1) / self.rest_len
            bad_edge = ~(ratio <= cfg.max_stretch)
        flags = np.zeros(self.count, bool)
        flags[self.inst[bad]] = True
        flags[self.edge_inst[bad_edge]] = True
        return flags


def simulate(garment: Garment, body, motion: Motion, *, betas: np.ndarray | None = None,
             config: SimulationConfig | None = None, solver=None, seed: int = 0,
             progress: ProgressFn | None = None, garment_betas: np.ndarray | None = None) -> SimulationResult:
    """Dress ``garment`` on ``body``, play ``motion``, and judge the result.

    Args:
        garment: the garment at rest around the body's rest mesh (shape ``garment_betas``).
        body: a ``sim.bodies.BodyModel``.
        motion: the motion.
        betas: body shape (B,); None: the motion's own, else the mean shape.
        config: settings (default ``SimulationConfig()``).
        solver: a ``VBDConfig`` used instead of ``config.vbd_config()``.
        seed: recorded in the provenance (the simulation itself is deterministic).
        progress: ``progress(frames_done, frames_total)`` over solver frames.
        garment_betas: the shape (B,) the garment was built on; None: ``betas``. When it
            differs, the body morphs from it to ``betas`` during the settle
            (``SimulationJob.garment_betas``).

    Returns:
        The sequence (vertices (T, V, 3) [m], T = the motion's frames, or prelude + motion
        with ``keep_prelude``) and its quality report.

    Raises:
        SimulationError: NaN or explosion; names the output frame (negative inside a dropped
            prelude) and the cause.
        WrinklesInputError: bad config.
    """
    job = SimulationJob(garment, body, motion, betas, garment_betas=garment_betas)
    return simulate_batch([job], config=config, solver=solver, seed=seed, progress=progress)[0]


def simulate_batch(jobs: Sequence[SimulationJob], *, config: SimulationConfig | None = None, solver=None,
                   seed: int = 0, progress: ProgressFn | None = None,
                   failures: str = "raise") -> list[SimulationResult | SimulationError]:
    """Simulate several sequences in one batched cloth model (see ``simulate``).

    Sequences may differ in garment, body, shape and motion length; a shorter one holds its
    body's last frame until the longest ends (its output stops at its own end). Jobs with the
    same body model, motion object and betas (and garment betas) share one body collider.

    Args:
        failures: "raise": the first sequence that blows up raises. "return": a sequence that
            blows up is frozen at its last good frame (its particles pinned in place, but for
            attachments, which keep following the body; instances of a batch never interact)
            and its slot of the result holds the ``SimulationError``; the others run on
            unchanged, so one bad sequence costs a batch nothing.

    Raises:
        SimulationError: with ``failures="raise"``, the first sequence that blows up, named in
            the cause.
    """
    if failures not in ("raise", "return"):
        raise ValueError(f"simulate_batch: failures must be 'raise' or 'return', got {failures!r}")
    from sim.cloth import BodyCollider, ClothModelBuilder, SolverVBD
    from sim.device import resolve_device, warp
    from sim.dressing import AttachmentPins, bind_to_surface, place_garment

    if not jobs:
        raise ValueError("simulate_batch: no jobs")
    wp = warp()
    cfg = config or SimulationConfig()
    device = resolve_device(cfg.device)
    vbd = solver if solver is not None else cfg.vbd_config(max(j.garment.num_vertices for j in jobs),
                                                           cuda=wp.get_device(device).is_cuda)
    skinned: dict = {}
    tracks = [_prepare(j, cfg, device, skinned) for j in jobs]
    n_prelude = tracks[0].n_settle + tracks[0].n_blend

    builder = ClothModelBuilder(max_colors=vbd.max_colors)
    bindings = []
    for tr in tracks:
        g = tr.job.garment
        x0 = place_garment(g.rest_vertices, tr.placement)
        builder.add_cloth(x0, g.faces, g.material, pinned=tr.pinned, rest_vertices=g.rest_vertices,
                          face_layers=g.face_layers)
        try:
            bindings.append(bind_to_surface(x0, tr.frames.vertices[0], tr.job.body.faces, vertices=tr.pinned,
                                            device=device))
        except ValueError as e:
            raise WrinklesInputError(f"{tr.job.label}: {e}") from None
    model = builder.finalize(device)
    control = model.control()
    colliders: dict[tuple, tuple[Any, Any, int]] = {}
    pins = []
    for k, (tr, binding) in enumerate(zip(tracks, bindings, strict=True)):
        tr.span = model.instance_slice(k)
        key = tr.body_key
        if key not in colliders:
            c = BodyCollider(tr.frames.vertices[0], tr.job.body.faces, device=device)
            seq = wp.array(np.ascontiguousarray(tr.frames.vertices), dtype=wp.vec3, device=device)
            colliders[key] = (c, seq, tr.length)
        tr.collider, tr.body_points, _ = colliders[key]
        control.set_body(k, tr.collider)
        pins.append(AttachmentPins(binding, tr.span.start, tr.collider.points_end, device=device))
    solver_vbd = SolverVBD(model, vbd)
    state = model.state()
    dt = 1.0 / cfg.fps
    checkers = [_FrameChecker(tr.job.garment, cfg) for tr in tracks]
    screen = _BatchScreen(tracks, checkers, cfg)

    def step() -> None:
        for p in pins:
            p.launch(control.pin_targets)
        solver_vbd.step(state, state, control, dt)

    graph = None
    use_graph = wp.get_device(device).is_cuda
    total = max(tr.length for tr in tracks) - 1
    # each instance's reference velocity per step (self-contact searches in its frame): the mean
    # velocity of its body
    means: dict[tuple, np.ndarray] = {}
    reference = np.zeros((max(total, 1), len(tracks), 3), np.float32)
    for k, tr in enumerate(tracks):
        if tr.body_key not in means:
            means[tr.body_key] = body_mean_velocities(tr.frames.vertices, max(total, 1), cfg.fps)
        reference[:, k] = means[tr.body_key]
    reference_d = wp.array(reference, dtype=wp.vec3, device=device)
    x_prev = state.positions.numpy().copy()  # on CPU .numpy() is a view of the live buffer
    step_ms = np.zeros(total)
    errors: dict[int, SimulationError] = {}  # failures="return": frozen instances
    for t in range(total):
        for c, seq, length in colliders.values():
            c.set_frame(seq[min(t, length - 1)], seq[min(t + 1, length - 1)])
        wp.copy(control.instance_velocity, reference_d[t])
        if use_graph and graph is None:
            try:
                with wp.ScopedCapture(device=device) as cap:
                    step()
                graph = cap.graph
            except Exception:  # capture unsupported here (driver, mempool): plain launches
                use_graph = False
        t_start = time.perf_counter()
        if graph is not None:
            wp.capture_launch(graph)
        else:
            step()
        wp.synchronize_device(device)
        step_ms[t] = 1000.0 * (time.perf_counter() - t_start)
        if cfg.settle_relax and t + 1 <= tracks[0].n_settle:
            state.velocities.zero_()
        x = state.positions.numpy().copy()
        frame = t + 1
        roots = np.stack([tr.frames.joints[min(frame, tr.length - 1), 0] for tr in tracks])
        flagged = screen(x, x_prev, roots)
        for k, (tr, check) in enumerate(zip(tracks, checkers, strict=True)):
            if frame >= tr.length or not flagged[k] or k in errors:
                continue
            phase = ""
            if frame <= n_prelude:
                phase = "while settling: " if frame <= tr.n_settle else "while blending from rest: "
            if len(tracks) > 1:
                phase = f"{tr.job.label}: {phase}"
            try:
                check(x[tr.span], x_prev[tr.span], roots[k], frame - tr.first_out, phase)
            except SimulationError as e:
                if failures == "raise":
                    raise
                errors[k] = e
                x[tr.span] = x_prev[tr.span]
                _freeze(model, state, control, tr.span, x)
        for k, tr in enumerate(tracks):
            if frame < tr.length and frame >= tr.first_out and k not in errors:
                tr.out[frame - tr.first_out] = x[tr.span]
        x_prev = x
        if progress is not None:
            progress(t + 1, total)
        if len(errors) == len(tracks):
            break

    results: list[SimulationResult | SimulationError] = []
    for k, tr in enumerate(tracks):
        if k in errors:
            results.append(errors[k])
            continue
        res = _finish(tr, cfg, vbd, device, seed, graph is not None)
        # frame k of the output is solver step k - 1 + first_out (the first is the captured one)
        results.append(replace(res, step_ms=step_ms[max(tr.first_out, 1):tr.length - 1]))
    return results


def body_mean_velocities(vertices: np.ndarray, steps: int, fps: float) -> np.ndarray:
    """The mean velocity [m/s] of a body's vertices over each solver step, shape (steps, 3):
    step ``t`` moves the body from frame ``min(t, L - 1)`` to ``min(t + 1, L - 1)`` of its ``L``
    frames ``vertices`` (L, B, 3) [m] (a shorter sequence holds its last frame). The body
    moves linearly within a step, so this is the velocity of its centroid over the step."""
    c = np.asarray(vertices).mean(axis=1, dtype=np.float64)
    t = np.arange(steps)
    last = len(c) - 1
    return ((c[np.minimum(t + 1, last)] - c[np.minimum(t, last)]) * fps).astype(np.float32)


def _freeze(model, state, control, span: slice, x: np.ndarray) -> None:
    """Stop one instance of a batched model where it is: its positions become ``x[span]`` (the
    rest of ``x`` is the live state), its particles pinned to them with zero velocity; its
    attachment particles keep following the body (their pins are rewritten every step), which
    nothing reads. Only array contents change, so a captured CUDA graph stays valid."""
    from sim.cloth.vbd_kernels import PINNED

    state.positions.assign(x)
    for a in (state.velocities, state.accelerations):
        z = a.numpy().copy()
        z[span] = 0.0
        a.assign(z)
    flags = model.particle_flags.numpy().copy()
    flags[span] = PINNED
    model.particle_flags.assign(flags)
    targets = control.pin_targets.numpy().copy()
    targets[span] = x[span]
    control.pin_targets.assign(targets)


def _finish(tr: _Track, cfg: SimulationConfig, vbd, device: str, seed: int, graph: bool) -> SimulationResult:
    g = tr.job.garment
    body = tr.job.body
    f0 = tr.first_out
    fr = tr.frames
    frames = BodyFrames(vertices=fr.vertices[f0:], joints=fr.joints[f0:], transforms=fr.transforms[f0:],
                        faces=fr.faces)
    motion = tr.motion if f0 == tr.n_settle + tr.n_blend else replace(
        tr.timeline, poses=tr.timeline.poses[f0:], trans=tr.timeline.trans[f0:])
    quality = evaluate_sequence(tr.out, g.rest_vertices, g.faces, frames.vertices, body.faces, device=device)
    provenance = {
        "config": cfg.to_dict(),
        "solver": dataclasses.asdict(vbd),
        "seed": int(seed),
        "device": device,
        "cuda_graph": bool(graph),
        "versions": package_versions(),
        "garment": {"name": g.name, "category": g.category, "vertices": g.num_vertices, "faces": g.num_faces,
                    "material": g.material.name, "hem_faces": int((g.face_layers > 1.0).sum()),
                    "pinned_sets": [n for n in cfg.pinned if n in g.attachments],
                    "pinned_vertices": int(tr.pinned.size)},
        "body": {"name": getattr(body, "name", "body"), "source": getattr(body, "source", ""),
                 "betas": [float(b) for b in tr.betas]},
        "motion": {"name": tr.motion.name, "source": tr.motion.source, "frames": tr.motion.num_frames},
        "frames": {"output": int(tr.out.shape[0]), "settle": tr.n_settle, "blend": tr.n_blend,
                   "prelude_kept": bool(cfg.keep_prelude), "first_output_timeline_frame": f0},
        "ground_offset_m": tr.ground_dy,
        "placement_m": [float(v) for v in tr.placement],
    }
    if tr.job.garment_betas is not None:  # the shape the garment was built on (morphed from)
        gb = tr.betas if tr.garment_betas is None else tr.garment_betas
        provenance["garment"]["betas"] = [float(b) for b in gb]
    seq = GarmentSequence(vertices=tr.out, body=frames, garment=g, motion=motion, fps=float(cfg.fps),
                          provenance=provenance)
    return SimulationResult(seq, quality, tuple(quality.failures(cfg.gates)))
