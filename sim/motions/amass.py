"""AMASS ``.npz`` motions (SMPL, SMPL-H, SMPL-X layouts) -> ``Motion``.

Layouts, by the width of ``poses`` (axis-angle, 3 numbers per joint):

- 72  SMPL: 24 joints, SMPL's order (joints 22/23 are SMPL's ``left_hand/right_hand``).
- 66  body only: SMPL joints 0-21.
- 156 SMPL-H: 22 body joints + 15 left-hand + 15 right-hand finger joints.
- 165 SMPL-X: 22 body joints + jaw + left eye + right eye + 15 + 15 finger joints.

SMPL-H and SMPL-X have no ``left_hand/right_hand`` joints (the fingers replace them), so SMPL's
joints 22 and 23 are set to zero rotation; the finger, jaw and eye rotations are kept in
``Motion.extra`` (``hand_pose`` (T, 30, 3), ``jaw_pose`` (T, 1, 3), ``eye_pose`` (T, 2, 3)) for
body models that have those joints. Split keys are accepted too: ``root_orient`` (T, 3) +
``pose_body`` (T, 63) [+ ``pose_hand`` (T, 90), ``pose_jaw`` (T, 3), ``pose_eye`` (T, 6)].

AMASS is Z up; the project is Y up. The conversion rotates the world by ``A = Rx(-90 deg)``
(Z -> Y, Y -> -Z): root orientation ``R' = A R``. SMPL rotates the body about the pelvis
joint ``J0`` (which depends on the body shape) before adding ``trans``, so the exact new
translation is ``trans' = A (trans + J0) - J0``. With ``pelvis_offset=None`` the loader uses
``trans' = A trans``: the body then lacks the constant ``(A - I) J0`` (it stands 0.27 m
too low and 0.21 m too far back for ``SMPL_REST_JOINTS``' pelvis, 0.25 m and 0.19 m for the
default body's), and ``Motion.extra["pelvis_exact"]`` is False; :func:`place_pelvis` adds
the offset once the body is known (the pipelines do, with the shape they pose). Pass the
pelvis rest position of the body you will skin with (``body.rest_joints(betas)[0]``) to make
it exact at load time.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from sim.errors import NEVER_UNPICKLED, WrinklesInputError
from sim.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from sim.types import NUM_SMPL_JOINTS, Motion

#: pose width -> layout name
LAYOUTS = {72: "smpl", 66: "body", 156: "smplh", 165: "smplx"}

#: world rotation taking AMASS's Z-up frame to the project's Y-up frame (Rx(-90 deg)).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

_FPS_KEYS = ("mocap_frame_rate", "mocap_framerate", "frame_rate", "fps")


def z_up_to_y_up(poses: np.ndarray, trans: np.ndarray,
                 pelvis_offset: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rotate a Z-up SMPL motion into the Y-up frame.

    Args:
        poses: axis-angle [rad], shape (T, J, 3); only joint 0 (global orientation) changes.
        trans: root translation [m], shape (T, 3).
        pelvis_offset: the pelvis rest position ``J0`` [m] (3,) of the body model, or None for
            the approximation ``trans' = A trans`` (see the module docstring).

    Returns:
        ``(poses, trans)`` in Y-up, float64.
    """
    A = Z_UP_TO_Y_UP
    poses = np.array(poses, dtype=np.float64)
    trans = np.asarray(trans, dtype=np.float64)
    poses[:, 0] = matrix_to_axis_angle(A @ axis_angle_to_matrix(poses[:, 0]))
    if pelvis_offset is None:
        new_trans = trans @ A.T
    else:
        j0 = np.asarray(pelvis_offset, dtype=np.float64).reshape(3)
        new_trans = (trans + j0) @ A.T - j0
    return poses, new_trans


def place_pelvis(motion: Motion, pelvis_offset: np.ndarray) -> Motion:
    """Make a motion loaded with ``pelvis_offset=None`` from a Z-up file exact for a body whose
    pelvis rest position is ``pelvis_offset`` [m] (3,): ``trans' = A trans + (A - I) J0``.

    Returns ``motion`` itself when its translation is exact already (``extra["pelvis_exact"]``
    True or absent: a Y-up file, an offset given at load time, a motion from elsewhere).
    """
    if motion.extra.get("pelvis_exact", True):
        return motion
    j0 = np.asarray(pelvis_offset, dtype=np.float64).reshape(3)
    shift = Z_UP_TO_Y_UP @ j0 - j0
    return replace(motion, trans=(motion.trans + shift).astype(np.float32),
                   extra={**motion.extra, "pelvis_exact": True})


def _read_npz(path: str) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as data:
            out = {}
            for key in data.files:
                try:
                    out[key] = data[key]
                except ValueError:  # object arrays (pickled): not read, never executed
                    continue
            return out
    except FileNotFoundError:
        raise WrinklesInputError("file not found", path=path) from None
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
        if "pickle" in str(e):  # numpy's text advises loading the file with allow_pickle
            raise WrinklesInputError("cannot read as an .npz archive: it is a pickle (Python objects), not "
                                     f"arrays; {NEVER_UNPICKLED}", path=path) from None
        raise WrinklesInputError(f"cannot read as an .npz archive ({e.__class__.__name__}: {e})",
                                 path=path) from None


def _as_str(x: np.ndarray | None) -> str | None:
    if x is None:
        return None
    try:
        v = np.asarray(x).reshape(-1)[0]
        return v.decode() if isinstance(v, bytes) else str(v)
    except (IndexError, UnicodeDecodeError):
        return None


def _float_array(data: dict, key: str, path: str) -> np.ndarray:
    try:
        return np.asarray(data[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise WrinklesInputError(f"'{key}' is not numeric (dtype {data[key].dtype})",
                                 path=path) from None


def _assemble_split(data: dict, path: str) -> np.ndarray:
    """``root_orient`` + ``pose_body`` [+ hands, jaw, eyes] -> a (T, 156/165/66) pose array."""
    root = _float_array(data, "root_orient", path).reshape(-1, 3)
    body = _float_array(data, "pose_body", path)
    T = root.shape[0]
    if T == 0 or body.size != T * 63:
        raise WrinklesInputError(
            f"'pose_body' must have shape ({T}, 63) to match 'root_orient', got {body.shape}",
            path=path)
    parts = {"root_orient": root, "pose_body": body.reshape(T, 63)}
    for key in ("pose_hand", "pose_jaw", "pose_eye"):
        if key in data:
            a = _float_array(data, key, path)
            if a.size % T != 0:
                raise WrinklesInputError(f"'{key}' has {a.shape[0]} frames, 'root_orient' has {T}",
                                         path=path)
            parts[key] = a.reshape(T, -1)
    cols = [parts["root_orient"], parts["pose_body"]]
    if "pose_jaw" in parts or "pose_eye" in parts:
        cols += [parts.get("pose_jaw", np.zeros((T, 3))), parts.get("pose_eye", np.zeros((T, 6)))]
    if "pose_hand" in parts:
        cols.append(parts["pose_hand"])
    elif len(cols) > 2:
        cols.append(np.zeros((T, 90)))
    return np.concatenate(cols, axis=1)


def load_amass(path: str | os.PathLike, *, pelvis_offset: np.ndarray | None = None,
               up_axis: str = "z", source_fps: float | None = None,
               name: str | None = None) -> Motion:
    """Load an AMASS-style ``.npz`` as a Y-up ``Motion`` at the file's own frame rate.

    Args:
        path: the ``.npz`` file.
        pelvis_offset: pelvis rest position [m] (3,) of the body model, for an exact Z-up ->
            Y-up translation (see the module docstring); None for the approximation.
        up_axis: ``"z"`` (AMASS) converts to Y up; ``"y"`` takes the file as already Y up.
        source_fps: frame rate [1/s] to use when the file has none.
        name: label; default the file's stem.

    Returns:
        ``Motion`` with poses (T, 24, 3) [rad], trans (T, 3) [m], the file's fps, betas when
        present; ``extra`` holds ``layout``, ``gender``, hand/jaw/eye rotations and
        ``pelvis_exact`` (False: the translation waits for :func:`place_pelvis`).

    Raises:
        WrinklesInputError: unreadable archive, missing keys, wrong shapes, NaN/inf, no frames.
    """
    path = os.fspath(path)
    if up_axis not in ("z", "y"):
        raise WrinklesInputError(f"up_axis must be 'z' or 'y', got {up_axis!r}", path=path)
    data = _read_npz(path)
    poses = _read_poses(data, path)
    T, D = poses.shape
    if "trans" not in data:
        raise WrinklesInputError(f"no 'trans' array; keys present: {', '.join(sorted(data))}",
                                 path=path)
    trans = _float_array(data, "trans", path)
    if trans.shape != (T, 3):
        raise WrinklesInputError(f"'trans' must have shape ({T}, 3) to match 'poses', got "
                                 f"{trans.shape}", path=path)
    bad = ~(np.isfinite(poses).all(axis=1) & np.isfinite(trans).all(axis=1))
    if bad.any():
        raise WrinklesInputError(f"NaN/inf in 'poses' or 'trans' at frame {int(np.argmax(bad))}",
                                 path=path)
    fps = _frame_rate(data, source_fps, path)
    body, extra = _smpl_joints(poses)
    if up_axis == "z":
        body, trans = z_up_to_y_up(body, trans, pelvis_offset)
    extra["pelvis_exact"] = up_axis == "y" or pelvis_offset is not None
    betas = None
    if "betas" in data:
        b = _float_array(data, "betas", path)
        b = b.reshape(-1) if b.ndim <= 1 else b.reshape(b.shape[0], -1)[0]
        if not np.all(np.isfinite(b)):
            raise WrinklesInputError("NaN/inf in 'betas'", path=path)
        betas = b.astype(np.float32)
    gender = _as_str(data.get("gender"))
    if gender is not None:
        extra["gender"] = gender
    return Motion(poses=body.astype(np.float32), trans=trans.astype(np.float32), fps=fps,
                  name=name or Path(path).stem, betas=betas, source=path, extra=extra)


def _read_poses(data: dict, path: str) -> np.ndarray:
    """The file's poses as (T, D), D one of ``LAYOUTS`` (from ``poses`` or the split keys)."""
    if "poses" in data:
        poses = _float_array(data, "poses", path)
    elif "root_orient" in data and "pose_body" in data:
        poses = _assemble_split(data, path)
    else:
        raise WrinklesInputError(
            "no 'poses' array (nor 'root_orient' + 'pose_body'); keys present: "
            f"{', '.join(sorted(data)) or 'none'}", path=path)
    if poses.ndim == 3 and poses.shape[2] == 3:
        poses = poses.reshape(poses.shape[0], -1)
    if poses.ndim != 2:
        raise WrinklesInputError(f"'poses' must be 2-D (T, D), got shape {poses.shape}", path=path)
    T, D = poses.shape
    if T == 0:
        raise WrinklesInputError("'poses' has zero frames", path=path)
    if D not in LAYOUTS:
        raise WrinklesInputError(
            f"'poses' has {D} numbers per frame; expected 72 (SMPL), 66 (body), 156 (SMPL-H) "
            "or 165 (SMPL-X)", path=path)
    return poses


def _frame_rate(data: dict, source_fps: float | None, path: str) -> float:
    """The file's frame rate [1/s] (the first of ``_FPS_KEYS`` present), else ``source_fps``."""
    fps = None
    for key in _FPS_KEYS:
        if key in data:
            try:
                fps = float(np.asarray(data[key]).reshape(-1)[0])
            except (TypeError, ValueError, IndexError):
                raise WrinklesInputError(f"'{key}' is not a number", path=path) from None
            break
    if fps is None:
        fps = source_fps
    if fps is None:
        raise WrinklesInputError("no frame rate ('mocap_frame_rate' / 'mocap_framerate'); pass "
                                 "source_fps", path=path)
    if not (np.isfinite(fps) and fps > 0):
        raise WrinklesInputError(f"frame rate must be positive, got {fps}", path=path)
    return fps


def _smpl_joints(poses: np.ndarray) -> tuple[np.ndarray, dict]:
    """SMPL's 24 joint rotations (T, 24, 3) from a (T, D) pose array, and ``extra`` with the
    layout and the hand / jaw / eye rotations SMPL has no joints for."""
    T, D = poses.shape
    layout = LAYOUTS[D]
    joints = poses.reshape(T, D // 3, 3)
    body = np.zeros((T, NUM_SMPL_JOINTS, 3))
    extra: dict = {"layout": layout}
    if layout == "smpl":
        body[:] = joints
    else:
        body[:, :22] = joints[:, :22]  # SMPL 22/23 (left/right_hand) stay zero
        if layout == "smplh":
            extra["hand_pose"] = joints[:, 22:52].astype(np.float32)
        elif layout == "smplx":
            extra["jaw_pose"] = joints[:, 22:23].astype(np.float32)
            extra["eye_pose"] = joints[:, 23:25].astype(np.float32)
            extra["hand_pose"] = joints[:, 25:55].astype(np.float32)
    return body, extra
