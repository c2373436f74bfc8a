"""Joint names and kinematic trees of the SMPL family, in each model's official joint order.

Names as the ``smplx`` package's ``joint_names.py`` (SMPL-X: body, jaw and eyes, then the
left and the right hand; SMPL-H: body, then the hands). SMPL's own 24 names live in
``sim.types.SMPL_JOINT_NAMES``; the first 22 are shared by all three models.
"""

from __future__ import annotations

from sim.types import SMPL_JOINT_NAMES, SMPL_PARENTS

#: joints 0-21, shared by SMPL, SMPL-H and SMPL-X (SMPL's ``left_hand``/``right_hand``, 22 and
#: 23, are replaced by the finger chains in SMPL-H and SMPL-X).
BODY_JOINT_NAMES: tuple[str, ...] = SMPL_JOINT_NAMES[:22]

#: finger joints of one hand, in MANO's order (15 = 5 fingers x 3 joints).
_FINGERS = ("index", "middle", "pinky", "ring", "thumb")
HAND_JOINT_NAMES: dict[str, tuple[str, ...]] = {
    side: tuple(f"{side}_{f}{k}" for f in _FINGERS for k in (1, 2, 3)) for side in ("left", "right")
}
FACE_JOINT_NAMES: tuple[str, ...] = ("jaw", "left_eye_smplhf", "right_eye_smplhf")

SMPLH_JOINT_NAMES: tuple[str, ...] = (
    BODY_JOINT_NAMES + HAND_JOINT_NAMES["left"] + HAND_JOINT_NAMES["right"])
SMPLX_JOINT_NAMES: tuple[str, ...] = (
    BODY_JOINT_NAMES + FACE_JOINT_NAMES + HAND_JOINT_NAMES["left"] + HAND_JOINT_NAMES["right"])

#: joint names per family (``BodyModel.kind``).
JOINT_NAMES: dict[str, tuple[str, ...]] = {
    "smpl": SMPL_JOINT_NAMES,
    "smplh": SMPLH_JOINT_NAMES,
    "smplx": SMPLX_JOINT_NAMES,
}
#: family by joint count (MANO, 16 joints, and FLAME, 5, are not bodies).
KIND_BY_JOINT_COUNT: dict[int, str] = {len(v): k for k, v in JOINT_NAMES.items()}

#: index of each hand's first joint (its 15 joints follow), per family.
HAND_START: dict[str, dict[str, int]] = {
    "smplh": {"left": 22, "right": 37},
    "smplx": {"left": 25, "right": 40},
}


def _hand_parents(first: int, wrist: int) -> list[int]:
    out = []
    for f in range(5):
        base = first + 3 * f
        out += [wrist, base, base + 1]
    return out


def official_parents(kind: str) -> tuple[int, ...]:
    """The kinematic tree of a family's official release (-1 for the root).

    Files carry their own ``kintree_table``, which the loader uses; this is for writing
    synthetic files and for checking a file against its family.
    """
    body = list(SMPL_PARENTS[:22])
    if kind == "smpl":
        return SMPL_PARENTS
    if kind == "smplh":
        return tuple(body + _hand_parents(22, 20) + _hand_parents(37, 21))
    if kind == "smplx":
        return tuple(body + [15, 15, 15] + _hand_parents(25, 20) + _hand_parents(40, 21))
    raise ValueError(f"unknown body kind {kind!r}: expected one of {sorted(JOINT_NAMES)}")
