"""Blending a motion in from the rest pose.

A garment is dressed on the body in its rest pose and settled; then the body must move from
rest into the motion's first frame before the motion plays, so every sequence starts at rest
and collision-free. ``blend_from_rest`` prepends that transition.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sim.easing import smootherstep
from sim.errors import WrinklesInputError
from sim.motions.resample import slerp_axis_angle
from sim.types import Motion


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
    if not (np.isfinite(seconds) and seconds >= 0 and np.isfinite(hold) and hold >= 0):
        raise WrinklesInputError(f"blend time must be >= 0 s, got {seconds} (hold {hold})",
                                 path=motion.source or motion.name)
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
    poses = np.concatenate([pre.astype(np.float32), motion.poses])
    trans = np.concatenate([np.repeat(motion.trans[:1], n, axis=0), motion.trans])
    extra = dict(motion.extra)
    extra["prefix_frames"] = int(extra.get("prefix_frames", 0)) + n
    return replace(motion, poses=poses, trans=trans, extra=extra), n
