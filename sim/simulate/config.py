"""The job's settings: ``SimulationConfig``, the solver defaults it resolves for a garment's size
(``vbd_config``), the retry ladder, and the record of the defaults a config does not spell out
(``simulator_defaults``).

Figures are from docs/BENCHMARKS.md; "the population" there is 144 random walks and runs (48 of
each of three motion families) of the 5k t-shirt on one H100, judged by every quality gate.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from sim.cloth.config import (
    CUDA_COARSE_EARLY,
    CUDA_COLORS,
    DEFAULT_ITERATIONS,
    DEFAULT_SUBSTEPS,
    FINE_COARSE_EXCLUSION,
    FINE_GARMENT_VERTICES,
    FINE_ITERATIONS,
    FINE_SUBSTEPS,
    JOB_COARSE_GUARD,
    VBDConfig,
    default_iterations,
    default_substeps,
    job_config,
)
from sim.errors import WrinklesInputError
from sim.quality import QualityGates
from sim.types import Motion

DEFAULT_PINNED: tuple[str, ...] = ("waistband",)
"""Attachment sets pinned to the body by default: an elastic waistband grips the waist. Tops
hang on the shoulders by contact and friction: pinning their shoulder line to the skin drags
it with the deltoid, whose skin stretches and folds as the arm moves (edge strain up to 0.9 while
the walk's arms come down from the T-pose against 0.6 free). Hems and cuffs stay free."""

# ---------------------------------------------------------------------------------- retries

RETRY_FACTORS = (5.0 / 3.0, 2.0)
"""Substeps of the retries of a sequence that fails its quality gates or stops (NaN, explosion), as
multiples of its run's substeps (``SimulationConfig.retry_factors``): 12 -> 20 -> 24 (a fine
garment: none, ``FINE_RETRY_FACTORS``). A step too long for a fast motion, not the physics,
fails most fast coarse sequences that fail. H100, the templates' runs (hull-fitted garments): at
the coarse size 2 of 8 pass at 12 substeps, 3 at 16, 5 at 20 and 5 at 24 (not the same 5), so 6
of 8 pass within the ladder. Walks pass at the default (8 of 8, coarse). The trousers' and the
straight skirt's runs pass at no count: the skinned body's own skin within 5 cm of the trousers'
worst edge is stretched by 48 % (90th percentile) and up to 78 % (linear blend skinning at the
crotch), and a straight skirt's hem cannot span a running stride."""

FINE_RETRY_FACTORS: tuple[float, ...] = ()
"""The retries of a garment over ``FINE_GARMENT_VERTICES`` vertices (``SimulationConfig.retry_factors``
None, automatic): none. Sewn fine garments that fail do so for reasons more substeps do not
change (cloth pinched between body parts, sleeves tangling under the arm, a reference-fit
t-shirt torn at the start of the motion): on an H200, a dataset of 32 sampled 4 s t-shirts and
skirts (``bench_dataset --fit reference``) rescued 0 of 27 failing sequences at 23 substeps and 0
of 26 at 28, and one of 8 1 s clips (body fit) rescued 1 of 6 over 23, 28 and 42, for 61 s
against 122 s of first rung. A dataset that wants them sets ``[simulation] retry_factors``."""


def default_retry_factors(vertices: int) -> tuple[float, ...]:
    """Retry factors of the job default for a garment of ``vertices`` vertices."""
    return FINE_RETRY_FACTORS if vertices > FINE_GARMENT_VERTICES else RETRY_FACTORS


def retry_substeps(base: int, factors: tuple[float, ...]) -> tuple[int, ...]:
    """Substeps of the retries of a run at ``base`` substeps: each factor times ``base``, rounded,
    counts not above the one before dropped."""
    out: list[int] = []
    for f in factors:
        n = int(round(f * base))
        if n > (out[-1] if out else base):
            out.append(n)
    return tuple(out)


def simulator_defaults(cuda: bool = False) -> dict:
    """The defaults that shape a simulation without being written in its config.

    A dataset records them beside its config (``sim.datasets.generate``) and is not continued
    under other physics: a dataset is resumed only where the record it began with is equal to
    this one. Recorded: the automatic substeps and sweeps, the fine garments' coarse exclusion,
    the job's coarse guard, the retry ladders (a dataset's own ``[simulation] retry_factors`` is
    in its config), the templates' hems and every template's default parameters, the
    procedural gaits' rule (``sim.motions.gait.gait_record``) and how procedural motions begin
    (``procedural_start``: ``"lead_in"``, in full motion at t = 0 after a lead-in played in the
    prelude, ``sim.motions.procedural``) and the separation of the body's parts
    (``body_separation``: whether ``SimulationConfig.separate_body_parts`` is on by default, and
    ``sim.bodies.intersections.separation_record``). On CUDA (``cuda``) also the
    colouring (``CUDA_COLORS``) and the early coarse system (``CUDA_COARSE_EARLY``); the CPU uses
    neither and records neither, so a dataset begun on one kind of device is not continued on
    the other.
    """
    from sim.bodies.intersections import separation_record
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
           "gait": gait_record(), "procedural_start": "lead_in",
           "body_separation": {"on": SimulationConfig.__dataclass_fields__["separate_body_parts"].default,
                               **separation_record()}}
    if cuda:
        out["max_colors"] = CUDA_COLORS
        out["coarse_early"] = CUDA_COARSE_EARLY
    return out


# ---------------------------------------------------------------------------------- the config


@dataclass(frozen=True)
class SimulationConfig:
    """Settings of a simulation run (saved with every output; ``from_dict`` refuses unknown keys).

    The solver runs 12 substeps x 5 sweeps with one coarse-level correction before sweep 2 (14
    substeps x 8 sweeps for garments over 10k vertices: ``default_substeps``,
    ``default_iterations``), with the job's settings of ``vbd_config``. The coarse correction:
    H100, the 5k t-shirt at 14 x 5 with it passes 43 of 48 random walks and runs against 38 at
    16 x 10 without, at 0.30x Newton's time per frame (max strain 0.20 / 0.27 on the walk / run).

    Attributes:
        fps: output frame rate [1/s]; the solver takes one step of ``1/fps`` per frame and the
            motion is resampled to it.
        substeps: implicit-Euler substeps per frame; 0, the default: ``default_substeps`` of
            the run's largest garment (12, or 14 over 10k vertices).
        iterations: VBD Gauss-Seidel sweeps per substep; 0, the default:
            ``default_iterations`` of the run's largest garment (5, or 8 over 10k vertices).
        coarse_sweeps: sweeps (0 .. iterations - 1) before which a coarse-level correction runs
            (``VBDConfig.coarse.sweeps``; empty: none; None, the default: before sweep 2 where
            there are 3 or more sweeps, else none).
        coarse_spacing: the coarse level's aggregate spacing [edges] (``VBDConfig.coarse.spacing``;
            0: 4, with a third level for a garment whose coarse level has more than 256 nodes,
            ``VBDConfig.coarse.levels``).
        settle_seconds: time [s] the garment settles on the static rest body before the body
            moves.
        blend_seconds: time [s] of the eased transition from rest into the first pose of a
            motion without a lead-in of its own (motion files); a procedural motion enters
            through its lead-in instead, its ``ramp`` parameter long
            (``sim.motions.blend.enter_from_rest``).
        settle_relax: zero the garment's velocities after every settle frame (kinetic damping:
            the settle converges to static equilibrium instead of swinging).
        keep_prelude: keep the settle and blend (or lead-in) frames in the output (default: the
            sequence starts at the motion's first frame).
        pinned: attachment sets pinned to the body (names a garment does not define are
            skipped; an imported garment has none).
        ground: stand the body on the floor (y = 0) at the motion's first frame.
        separate_body_parts: move the skinned body's parts out of each other, frame by frame,
            before the cloth meets it (``sim.bodies.intersections``): linear blend skinning
            sinks the upper arms into the chest, the thighs into the belly and the calves into
            the thighs at deep flexion, and cloth caught there is crushed and overstretched.
        self_contact: cloth self-contact on/off in the solver (default on: without it every
            fine garment folds through itself and fails the self-intersection gate); None: as the
            ``solver`` overrides leave it (on).
        solver: solver settings over the job's, as ``"section.field": value`` (``sim.cloth.config``:
            ``"body_contact.stiffness"`` [N/m], ``"self_contact.radius"`` [m] ...).
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
    separate_body_parts: bool = True
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
        self._check_numbers()
        self.vbd_config()  # validates solver / self_contact

    def _check_numbers(self) -> None:
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

    @property
    def settle_frames(self) -> int:
        """Frames of the settle phase (as ``blend_from_rest`` rounds its ``hold``)."""
        return int(round(self.settle_seconds * self.fps))

    @property
    def blend_frames(self) -> int:
        """Frames of the blend from rest of a motion without a lead-in (as ``blend_from_rest``
        rounds them)."""
        return int(round(self.blend_seconds * self.fps))

    def entry_frames(self, motion: Motion) -> int:
        """Frames between the settle and ``motion``'s first frame at this config's fps: its
        lead-in's (resampled to ``fps``, ``resample_lead_in``), else ``blend_frames``."""
        from sim.motions.blend import lead_in
        from sim.motions.resample import lead_in_frames

        lead = lead_in(motion)
        if lead is None:
            return self.blend_frames
        if abs(float(lead.fps) - float(self.fps)) <= 1e-9:
            return lead.num_frames
        return lead_in_frames(lead.num_frames, lead.fps, self.fps)

    def solver_steps(self, motion: Motion | int) -> int:
        """Solver steps (one per frame) of a run over ``motion`` at this config's fps, or over a
        motion of that many frames without a lead-in."""
        if isinstance(motion, Motion):
            frames = motion.num_frames
            if abs(float(motion.fps) - float(self.fps)) > 1e-9:
                frames = max(1, int(round(frames * self.fps / motion.fps)))
            return self.settle_frames + self.entry_frames(motion) + frames - 1
        return self.settle_frames + self.blend_frames + int(motion) - 1

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
        return retry_substeps(self.substeps_for(vertices), self.retry_factors_for(vertices))

    def vbd_config(self, vertices: int = 0, cuda: bool = False) -> VBDConfig:
        """The solver settings of this run whose largest garment has ``vertices`` vertices, on
        CUDA (``cuda``) or the CPU: the job's (``sim.cloth.job_config``) with ``substeps``,
        ``iterations``, the coarse settings, ``self_contact`` and the ``solver`` overrides.

        Raises:
            WrinklesInputError: an unknown solver option or an invalid value.
        """
        return job_config(vertices, cuda, substeps=self.substeps, iterations=self.iterations,
                          coarse_sweeps=self.coarse_sweeps, coarse_spacing=self.coarse_spacing,
                          self_contact=self.self_contact, overrides=self.solver)

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
