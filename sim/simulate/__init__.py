"""The sequence driver: dress a garment on a body, settle it, bring the body from rest into the
motion, play it, and return a ``GarmentSequence`` with its quality report.

Timeline of one run at ``fps`` (one solver step of ``1/fps`` per frame, ``substeps`` inside)::

    frame 0            the garment placed on the body in rest pose (``sim.dressing``)
    settle_seconds     body static at rest; garment falls onto it and comes to rest (a garment
                       built on another shape: the body morphs to the job's shape first)
    way in             body from rest into the motion: a procedural motion's lead-in (its
                       ``ramp`` before t = 0, up to full motion), else ``blend_seconds`` slerped
                       from rest into the motion's first pose (``enter_from_rest``)
    motion             the motion, frame by frame

The settle and the way in are the *prelude*; by default they are dropped, so a sequence
starts at the motion's first frame (a procedural motion already in full motion) with the
garment settled on the body and carried into the motion (``SimulationConfig.keep_prelude`` keeps
them). Attachment sets named in
``SimulationConfig.pinned`` follow the skin (``sim.dressing.AttachmentPins``); the rest is
free. Every frame is checked for NaN and explosion (``SimulationError`` naming the frame and
the cause); every sequence gets a ``QualityReport`` judged against ``SimulationConfig.gates``.

Several garments / sequences run batched in one ``ClothModel`` (``simulate_batch``): one
launch advances all of them; instances never interact. The body of each sequence is uploaded
to the device once.

Modules:
    config: ``SimulationConfig``, the job's solver defaults (``vbd_config``), the retry ladder
        and ``simulator_defaults``.
    jobs: ``SimulationJob``, the shape a job resolves to, the driver's per-job ``Track``.
    prelude: the settle / morph / way-in timeline and the garment's placement (``prepare_track``).
    screening: per-frame NaN / explosion tests (``SimulationError``).
    results: ``SimulationResult`` and the sequence's provenance.
    driver: ``simulate``, ``simulate_batch`` and the per-frame loop.
"""

from sim.simulate.config import (
    DEFAULT_PINNED,
    FINE_RETRY_FACTORS,
    RETRY_FACTORS,
    SimulationConfig,
    default_retry_factors,
    retry_substeps,
    simulator_defaults,
)
from sim.simulate.driver import ProgressFn, body_mean_velocities, simulate, simulate_batch
from sim.simulate.jobs import SimulationJob, resolve_betas
from sim.simulate.prelude import MORPH_FRACTION, morph_frames, morph_settle, prepare_track
from sim.simulate.results import SimulationResult

__all__ = [
    "DEFAULT_PINNED",
    "FINE_RETRY_FACTORS",
    "MORPH_FRACTION",
    "RETRY_FACTORS",
    "ProgressFn",
    "SimulationConfig",
    "SimulationJob",
    "SimulationResult",
    "body_mean_velocities",
    "default_retry_factors",
    "morph_frames",
    "morph_settle",
    "prepare_track",
    "resolve_betas",
    "retry_substeps",
    "simulate",
    "simulate_batch",
    "simulator_defaults",
]
