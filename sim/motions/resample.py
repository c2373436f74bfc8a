"""Resampling motions in time: slerp for rotations, linear for translations.

A motion of ``T`` frames at ``fps`` covers ``T / fps`` seconds (each frame owns one interval,
``Motion.duration``). Resampling to ``fps_new`` keeps that duration: it gives
``round(T * fps_new / fps)`` frames at times ``k / fps_new``; a time past the last source frame
holds the last frame. Where a new time coincides with a source frame, the source values are
copied exactly (no round trip through quaternions). A procedural motion's lead-in
(``extra["lead_in"]``, the frames before t = 0) is resampled with it at times ``-k / fps_new``,
interpolated up to the clip's first frame, from the rest pose on.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from sim.errors import WrinklesInputError
from sim.rotations import (
    axis_angle_to_matrix,
    matrix_to_quaternion,
    quaternion_slerp,
    quaternion_to_axis_angle,
)
from sim.types import Motion

LEAD_IN = "lead_in"
"""The key of ``Motion.extra`` holding a procedural motion's lead-in, a ``Motion`` of the frames
before its t = 0 (``sim.motions.procedural``)."""

#: a new time closer than this to a source frame [frames] counts as that frame (float noise).
_SHARED_TIME_TOL = 1e-6


def resample_times(num_frames: int, fps: float, fps_new: float) -> tuple[np.ndarray, np.ndarray]:
    """Source frame index and fraction for each new frame.

    Args:
        num_frames: source frame count T (>= 1).
        fps: source rate [1/s].
        fps_new: target rate [1/s].

    Returns:
        ``(index, frac)``: int64 (N,) lower source frame and float64 (N,) weight of the next
        one in [0, 1), N = max(1, round(T * fps_new / fps)).
    """
    n_new = max(1, int(round(num_frames * fps_new / fps)))
    u = np.arange(n_new, dtype=np.float64) * (fps / fps_new)  # position in source frames
    u = np.minimum(u, num_frames - 1)
    idx = np.floor(u + _SHARED_TIME_TOL).astype(np.int64)
    frac = u - idx
    frac[np.abs(frac) < _SHARED_TIME_TOL] = 0.0
    frac = np.clip(frac, 0.0, 1.0)
    idx = np.minimum(idx, num_frames - 1)
    return idx, frac


def slerp_axis_angle(aa0: np.ndarray, aa1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Slerp between axis-angle rotations (shortest arc, through unit quaternions).

    Args:
        aa0, aa1: axis-angle [rad], shape (..., 3).
        t: weights in [0, 1], broadcastable to (...,).

    Returns:
        axis-angle [rad], shape (..., 3), float64.
    """
    q0 = matrix_to_quaternion(axis_angle_to_matrix(aa0))
    q1 = matrix_to_quaternion(axis_angle_to_matrix(aa1))
    return quaternion_to_axis_angle(quaternion_slerp(q0, q1, t))


def resample_rotations(aa: np.ndarray, idx: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """Resample an axis-angle sequence at fractional frames (see :func:`resample_times`).

    Args:
        aa: axis-angle [rad], shape (T, ..., 3).
        idx: lower source frame per new frame, int (N,).
        frac: weight of frame ``idx + 1``, (N,) in [0, 1).

    Returns:
        axis-angle [rad], shape (N, ..., 3), float64; exact copies where ``frac == 0``.
    """
    aa = np.asarray(aa, dtype=np.float64)
    nxt = np.minimum(idx + 1, aa.shape[0] - 1)
    w = np.asarray(frac, dtype=np.float64).reshape((-1,) + (1,) * (aa.ndim - 2))
    out = slerp_axis_angle(aa[idx], aa[nxt], np.broadcast_to(w, aa[idx].shape[:-1]))
    exact = frac == 0.0
    out[exact] = aa[idx[exact]]
    return out


def resample_linear(x: np.ndarray, idx: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """Linear interpolation of a (T, ...) array at fractional frames, float64 (N, ...)."""
    x = np.asarray(x, dtype=np.float64)
    nxt = np.minimum(idx + 1, x.shape[0] - 1)
    w = np.asarray(frac, dtype=np.float64).reshape((-1,) + (1,) * (x.ndim - 1))
    return (1.0 - w) * x[idx] + w * x[nxt]


#: keys of ``Motion.extra`` that hold per-frame axis-angle arrays (T, K, 3), resampled too.
ROTATION_EXTRAS = ("hand_pose", "jaw_pose", "eye_pose")


def resample_motion(motion: Motion, fps: float) -> Motion:
    """The same motion at another frame rate, same duration.

    Rotations (``poses`` and the per-frame rotation extras: hands, jaw, eyes) are slerped
    through quaternions; ``trans`` and other per-frame float arrays in ``extra`` are
    interpolated linearly.

    Args:
        motion: source motion (T frames at ``motion.fps``).
        fps: target rate [1/s], > 0.

    Returns:
        a new ``Motion`` with ``round(T * fps / motion.fps)`` frames at ``fps``.
    """
    if not (np.isfinite(fps) and fps > 0):
        raise WrinklesInputError(f"fps must be a positive number, got {fps}",
                                 path=motion.source or motion.name)
    if abs(float(fps) - float(motion.fps)) < 1e-9:
        return motion
    idx, frac = resample_times(motion.num_frames, motion.fps, fps)
    poses = resample_rotations(motion.poses, idx, frac).astype(np.float32)
    trans = resample_linear(motion.trans, idx, frac).astype(np.float32)
    extra = dict(motion.extra)
    for key, val in motion.extra.items():
        if not (isinstance(val, np.ndarray) and val.ndim >= 1
                and val.shape[0] == motion.num_frames and val.dtype.kind == "f"):
            continue
        if key in ROTATION_EXTRAS and val.ndim == 3:
            extra[key] = resample_rotations(val, idx, frac).astype(val.dtype)
        else:  # other per-frame numbers (e.g. a gait phase): linear
            extra[key] = resample_linear(val, idx, frac).astype(val.dtype)
    if isinstance(motion.extra.get(LEAD_IN), Motion):
        extra[LEAD_IN] = resample_lead_in(motion, fps)
    return dataclasses.replace(motion, poses=poses, trans=trans, fps=float(fps), extra=extra)


def lead_in_frames(num_frames: int, fps: float, fps_new: float) -> int:
    """Frames of a lead-in of ``num_frames`` frames at ``fps`` resampled to ``fps_new``
    (``resample_lead_in``): ``ceil(num_frames * fps_new / fps)``, at least one."""
    return max(1, int(np.ceil(num_frames * fps_new / fps - _SHARED_TIME_TOL)))


def resample_lead_in(motion: Motion, fps: float) -> Motion:
    """The lead-in of ``motion`` (``extra["lead_in"]``, N frames at times ``(k - N) / motion.fps``)
    at ``fps``: ``M = ceil(N * fps / motion.fps)`` frames at times ``(k - M) / fps``, interpolated
    over the lead-in and the clip's first frame (t = 0). A time before the lead-in's first frame
    (the rest pose) holds it, so the resampled lead-in starts at rest too. Its per-frame extras
    are not carried."""
    lead = motion.extra[LEAD_IN]
    n = lead.num_frames
    m = lead_in_frames(n, motion.fps, fps)
    u = np.maximum(n + (np.arange(m) - m) * (motion.fps / fps), 0.0)  # in frames of lead + clip
    idx = np.floor(u + _SHARED_TIME_TOL).astype(np.int64)
    frac = u - idx
    frac[np.abs(frac) < _SHARED_TIME_TOL] = 0.0
    frac = np.clip(frac, 0.0, 1.0)
    poses = np.concatenate([lead.poses, motion.poses[:1]])
    trans = np.concatenate([lead.trans, motion.trans[:1]])
    return dataclasses.replace(lead, poses=resample_rotations(poses, idx, frac).astype(np.float32),
                               trans=resample_linear(trans, idx, frac).astype(np.float32), fps=float(fps),
                               extra={})


def trim_motion(motion: Motion, duration: float) -> Motion:
    """The first ``duration`` seconds of a motion (``round(duration * fps)`` frames).

    Raises:
        WrinklesInputError: when the motion is shorter than ``duration`` or it is not positive.
    """
    where = motion.source or motion.name
    if not (np.isfinite(duration) and duration > 0):
        raise WrinklesInputError(f"duration must be a positive number of seconds, got {duration}",
                                 path=where)
    n = max(1, int(round(duration * motion.fps)))
    if n > motion.num_frames:
        raise WrinklesInputError(
            f"duration {duration:g} s asked, the motion lasts only {motion.duration:.3f} s "
            f"({motion.num_frames} frames at {motion.fps:g} fps)", path=where)
    extra = {k: (v[:n] if isinstance(v, np.ndarray) and v.ndim >= 1
                 and v.shape[0] == motion.num_frames else v) for k, v in motion.extra.items()}
    return dataclasses.replace(motion, poses=motion.poses[:n], trans=motion.trans[:n], extra=extra)
