"""Joint limits for SMPL's 24 joints, in SMPL's local joint axes.

Each joint has a range per component of its axis-angle rotation ``(x, y, z)`` [rad]. For the
moderate angles of everyday motion an axis-angle component is close to the Euler angle about
the same axis, so the table reads as anatomical ranges; for large combined rotations it is an
approximation (a box in axis-angle space), which is what ``random`` motion samples from and
what :func:`within_limits` checks.

Signs follow SMPL's axes (Y up, the rest T-pose faces +Z, the left arm points +X), checked
by forward kinematics in ``tests/test_motions.py``:

- hip flexion (thigh forward) is a rotation about -X; knee flexion about +X; ankle
  dorsiflexion (toes up) about -X; spine / neck flexion (bend forward) about +X.
- left shoulder: raising the arm above the horizontal is +Z, lowering it to the side is -Z,
  moving it forward is -Y; left elbow flexion is -Y. The right side mirrors: Y and Z flip sign.
- left hip abduction (leg outward) is +Z; right hip abduction is -Z.

Ranges are rounded normal ranges of motion for healthy adults (after the AAOS / Kapandji
tables of active range of motion), narrowed where SMPL's skinning degrades; they are not a
clinical reference.
"""

from __future__ import annotations

import numpy as np

from sim.types import NUM_SMPL_JOINTS, SMPL_JOINT_NAMES

_D = np.pi / 180.0

#: Ranges [deg] for central and left joints, ``name -> ((xlo, xhi), (ylo, yhi), (zlo, zhi))``.
#: Right joints mirror their left counterpart (X kept, Y and Z negated and swapped).
_LIMITS_DEG: dict[str, tuple[tuple[float, float], ...]] = {
    "pelvis": ((-30, 30), (-60, 60), (-20, 20)),  # global orientation, for random motion
    "left_hip": ((-120, 30), (-40, 45), (-30, 45)),
    "left_knee": ((0, 140), (-15, 15), (-3, 3)),
    "left_ankle": ((-20, 50), (-20, 20), (-20, 20)),
    "left_foot": ((-60, 30), (-5, 5), (-5, 5)),
    "spine1": ((-15, 30), (-15, 15), (-15, 15)),
    "spine2": ((-10, 20), (-15, 15), (-10, 10)),
    "spine3": ((-10, 20), (-15, 15), (-10, 10)),
    "neck": ((-30, 35), (-35, 35), (-25, 25)),
    "head": ((-20, 25), (-25, 25), (-20, 20)),
    "left_collar": ((-10, 10), (-20, 15), (-10, 30)),
    "left_shoulder": ((-60, 60), (-90, 45), (-85, 80)),
    "left_elbow": ((-60, 60), (-145, 0), (-5, 5)),
    "left_wrist": ((-40, 40), (-30, 20), (-70, 60)),
    "left_hand": ((-10, 10), (-10, 10), (-10, 10)),
}


def _build_table() -> np.ndarray:
    table = np.zeros((NUM_SMPL_JOINTS, 3, 2), dtype=np.float64)
    for j, name in enumerate(SMPL_JOINT_NAMES):
        if name in _LIMITS_DEG:
            table[j] = np.asarray(_LIMITS_DEG[name], dtype=np.float64) * _D
        elif name.startswith("right_"):
            left = np.asarray(_LIMITS_DEG["left_" + name[6:]], dtype=np.float64) * _D
            table[j, 0] = left[0]
            table[j, 1:] = -left[1:, ::-1]
        else:  # pragma: no cover - the table covers every joint
            raise KeyError(name)
    return table


#: Joint limits [rad], shape (24, 3, 2): ``[joint, axis, (low, high)]``, axis-angle components.
JOINT_LIMITS: np.ndarray = _build_table()
JOINT_LIMITS.setflags(write=False)


def joint_limits() -> np.ndarray:
    """The joint-limit table [rad], shape (24, 3, 2) (a writable copy of ``JOINT_LIMITS``)."""
    return JOINT_LIMITS.copy()


def clamp_to_limits(poses: np.ndarray) -> np.ndarray:
    """Clamp each axis-angle component into its range.

    Args:
        poses: axis-angle [rad], shape (..., 24, 3).

    Returns:
        clamped poses, same shape, float32.
    """
    p = np.asarray(poses, dtype=np.float64)
    return np.clip(p, JOINT_LIMITS[..., 0], JOINT_LIMITS[..., 1]).astype(np.float32)


def limit_violation(poses: np.ndarray) -> np.ndarray:
    """How far each component lies outside its range [rad] (0 inside), shape (..., 24, 3)."""
    p = np.asarray(poses, dtype=np.float64)
    return np.maximum(JOINT_LIMITS[..., 0] - p, 0.0) + np.maximum(p - JOINT_LIMITS[..., 1], 0.0)


def within_limits(poses: np.ndarray, *, tol: float = 1e-6) -> bool:
    """True when every component of every frame lies within the table (``tol`` [rad] slack)."""
    return bool(np.all(limit_violation(poses) <= tol))
