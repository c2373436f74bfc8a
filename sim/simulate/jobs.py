"""What a run simulates: ``SimulationJob`` (one sequence: garment, body, shape, motion), the
shape it resolves to, and ``Track``, the driver's host-side bookkeeping of one job in a batch."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim.garments.types import Garment
from sim.types import BodyFrames, Motion


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


def shared_body_key(job: SimulationJob, betas: np.ndarray, garment_betas: np.ndarray | None = None) -> tuple:
    """Jobs with equal keys (the same body model, motion object, shape and garment shape) share
    one skinning and one body collider."""
    key = (id(job.body), id(job.motion), betas.tobytes())
    return key if garment_betas is None else (*key, garment_betas.tobytes())


@dataclass
class Track:
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
