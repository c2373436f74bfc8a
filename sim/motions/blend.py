"""The way into a motion from the rest pose.

A garment is dressed on the body in its rest pose and settled; then the body must move from
rest into the motion before the motion plays, so every sequence starts at rest and
collision-free. ``enter_from_rest`` prepends that way in: the motion's own lead-in where it has
one (procedural motions: the motion evaluated before t = 0, from the T-pose up to full motion,
``extra["lead_in"]``), else ``blend_from_rest``, a slerp from rest into the first frame (motion
files). Either way the prepended frames are a prefix (``extra["prefix_frames"]``) that
outputs drop, and the motion itself starts after them unchanged.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sim.easing import smootherstep
from sim.errors import WrinklesInputError
from sim.motions.resample import LEAD_IN, slerp_axis_angle
from sim.types import Motion


def _check_times(motion: Motion, seconds: float, hold: float) -> None:
    if not (np.isfinite(seconds) and seconds >= 0 and np.isfinite(hold) and hold >= 0):
        raise WrinklesInputError(f"blend time must be >= 0 s, got {seconds} (hold {hold})",
                                 path=motion.source or motion.name)


def _prefixed(motion: Motion, poses: np.ndarray, trans: np.ndarray) -> tuple[Motion, int]:
    """``motion`` with ``poses`` / ``trans`` prepended, counted in ``extra["prefix_frames"]``; the
    lead-in, now in the frames, leaves ``extra``."""
    n = int(poses.shape[0])
    extra = {k: v for k, v in motion.extra.items() if k != LEAD_IN}
    extra["prefix_frames"] = int(extra.get("prefix_frames", 0)) + n
    return replace(motion, poses=np.concatenate([poses.astype(np.float32), motion.poses]),
                   trans=np.concatenate([trans.astype(np.float32), motion.trans]), extra=extra), n


def blend_from_rest(motion: Motion, seconds: float, *, hold: float = 0.0) -> tuple[Motion, int]:
    """Prepend a transition from the rest pose to the motion's first frame.

    Joint rotations (the root's included) are slerped from identity to frame 0 with a C2 ease
    curve (``smootherstep``); the root translation stays at frame 0's. ``hold`` seconds of rest
    come first.

    Args:
        motion: the motion.
        seconds: length of the transition [s] (>= 0).
        hold: time [s] at rest before the transition starts.

    Returns:
        (the longer motion, number of frames prepended). Its ``extra["prefix_frames"]`` holds the
        count, so consumers can drop the prefix from outputs.
    """
    _check_times(motion, seconds, hold)
    n_hold = int(round(hold * motion.fps))
    n_blend = int(round(seconds * motion.fps))
    n = n_hold + n_blend
    if n == 0:
        return motion, 0
    t = np.concatenate([np.zeros(n_hold), (np.arange(n_blend) / max(n_blend, 1))])
    w = smootherstep(t)
    p0 = motion.poses[0].astype(np.float64)
    rest = np.zeros_like(p0)
    pre = slerp_axis_angle(np.broadcast_to(rest, (n, *p0.shape)), np.broadcast_to(p0, (n, *p0.shape)),
                           np.broadcast_to(w[:, None], (n, p0.shape[0])))
    return _prefixed(motion, pre, np.repeat(motion.trans[:1], n, axis=0))


def lead_in(motion: Motion) -> Motion | None:
    """The motion's own lead-in from the rest pose (``extra["lead_in"]``), None where it has none."""
    lead = motion.extra.get(LEAD_IN)
    return lead if isinstance(lead, Motion) else None


def entry_frames(motion: Motion, seconds: float) -> int:
    """Frames between rest and the motion's first frame in ``enter_from_rest``: the lead-in's, or
    the blend's ``round(seconds * fps)``."""
    lead = lead_in(motion)
    return lead.num_frames if lead is not None else int(round(seconds * motion.fps))


def enter_from_rest(motion: Motion, seconds: float, *, hold: float = 0.0) -> tuple[Motion, int]:
    """Prepend the way in from the rest pose: ``hold`` seconds at rest, then the motion's own
    lead-in (``extra["lead_in"]``: it starts at rest and ends one frame before the motion's
    first, in step with it) or, for a motion without one, ``blend_from_rest`` over ``seconds``.

    The hold stands at the lead-in's first root translation (a gait's lead-in walks up to the
    motion's start from behind it).

    Args:
        motion: the motion.
        seconds: the blend [s] (>= 0) of a motion without a lead-in.
        hold: time [s] at rest before the way in.

    Returns:
        (the longer motion, number of frames prepended), as ``blend_from_rest``.
    """
    lead = lead_in(motion)
    if lead is None:
        return blend_from_rest(motion, seconds, hold=hold)
    _check_times(motion, seconds, hold)
    if abs(float(lead.fps) - float(motion.fps)) > 1e-9:
        raise ValueError(f"enter_from_rest: the lead-in of {motion.name} is at {lead.fps:g} fps, the "
                         f"motion at {motion.fps:g} (resample_motion resamples both)")
    n_hold = int(round(hold * motion.fps))
    poses = np.concatenate([np.zeros((n_hold, *lead.poses.shape[1:]), np.float32), lead.poses])
    trans = np.concatenate([np.repeat(lead.trans[:1], n_hold, axis=0), lead.trans])
    return _prefixed(motion, poses, trans)
