"""SMPL skeleton reference, forward kinematics and retargeting by global rotations.

Retargeting a source skeleton (BVH) onto SMPL's 24 joints works on *global* joint rotations:

1. every source joint's global rotation ``G_src(t)`` is the product of the local rotations
   down its chain (the source's rest pose, all channels zero, has ``G_src = I``);
2. a *rest alignment* ``C_j`` per mapped SMPL joint says which SMPL orientation the source's
   rest stands for: SMPL's global rotation is ``G_j(t) = G_src(t) C_j``, so at the source's
   rest SMPL's joint has the global rotation ``C_j``;
3. SMPL local rotations follow down SMPL's tree, ``L_j = G_parent(j)^T G_j``; an unmapped SMPL
   joint gets the identity local rotation (it follows its parent).

Rest alignments (:func:`rest_alignment`):

- *limbs* (``limbs_only=True``, what BVH's ``rest="auto"`` uses): the thighs, shins, upper
  arms and forearms (``LIMB_JOINTS``) get the smallest rotation turning SMPL's rest bone
  direction into the source's (``C_j d_smpl = d_src``), so the limbs point where the source's
  point, at rest too (an A-pose rest lowers SMPL's arms, CMU's rest spreads its legs by 20
  degrees). The hands take their forearm's alignment (a hand at rest continues its forearm,
  as in SMPL's T-pose). The pelvis, spine, neck, head, collars and feet keep
  ``C_j = I``: a standing rest is upright with the head level and the feet flat whatever the
  directions between its joints, which follow where each convention places the joints, not a
  posture (from the neck joint to the head joint, ``SMPL_REST_JOINTS`` leans 36 degrees
  forward and a CMU subject's skeleton 11 degrees back; the ankle-to-toe bone descends 26 and
  13 degrees).
- *every bone* (``limbs_only=False``, BVH's ``rest="file"``): every joint with a bone
  direction is aligned that way; a joint without one takes its parent's alignment.
- none (BVH's ``rest="tpose"``): ``C_j = I``, the source's rest is SMPL's T-pose as it is.

The smallest rotation from one bone direction to another leaves the twist about the bone
undetermined; it is right for rests that differ from the T-pose by swings (A-pose arms,
spread legs) and keeps the source's own twist convention otherwise.
"""

from __future__ import annotations

import numpy as np

from sim.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from sim.types import NUM_SMPL_JOINTS, SMPL_JOINT_NAMES, SMPL_PARENTS

#: Approximate rest joint positions [m] of SMPL's neutral body at mean shape, T-pose, Y up,
#: facing +Z, shape (24, 3). Rounded from the published model's regressed joints; use the
#: actual body model's ``rest_joints(betas)`` where exact positions matter.
SMPL_REST_JOINTS: np.ndarray = np.array([
    [-0.002, -0.241, 0.029],  # pelvis
    [0.059, -0.323, 0.015],   # left_hip
    [-0.060, -0.331, 0.020],  # right_hip
    [0.004, -0.120, 0.004],   # spine1
    [0.043, -0.704, 0.015],   # left_knee
    [-0.045, -0.712, 0.010],  # right_knee
    [0.004, 0.018, -0.001],   # spine2
    [0.037, -1.113, -0.022],  # left_ankle
    [-0.035, -1.114, -0.021],  # right_ankle
    [-0.002, 0.072, 0.025],   # spine3
    [0.056, -1.172, 0.099],   # left_foot
    [-0.061, -1.171, 0.101],  # right_foot
    [-0.013, 0.287, -0.032],  # neck
    [0.071, 0.194, -0.019],   # left_collar
    [-0.083, 0.194, -0.020],  # right_collar
    [0.011, 0.352, 0.016],    # head
    [0.162, 0.242, -0.020],   # left_shoulder
    [-0.152, 0.242, -0.025],  # right_shoulder
    [0.415, 0.229, -0.038],   # left_elbow
    [-0.410, 0.232, -0.042],  # right_elbow
    [0.653, 0.236, -0.038],   # left_wrist
    [-0.655, 0.235, -0.044],  # right_wrist
    [0.735, 0.228, -0.049],   # left_hand
    [-0.742, 0.227, -0.050],  # right_hand
], dtype=np.float64)
SMPL_REST_JOINTS.setflags(write=False)

_PARENTS = np.asarray(SMPL_PARENTS, dtype=np.int64)
_INDEX = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}

#: For each SMPL joint, the child that defines its bone direction (-1: none, e.g. the hands).
BONE_CHILD: tuple[int, ...] = tuple(
    _INDEX[c] if c else -1 for c in (
        "spine1", "left_knee", "right_knee", "spine2", "left_ankle", "right_ankle", "spine3",
        "left_foot", "right_foot", "neck", "", "", "head", "left_shoulder", "right_shoulder", "",
        "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand", "", "",
    ))

#: The limb segments (thighs, shins, upper arms, forearms), by the SMPL joint that drives each:
#: their rest directions are a posture (A-pose or T-pose arms, spread legs) that the limb
#: alignment turns into SMPL's T-pose.
LIMB_JOINTS: tuple[int, ...] = tuple(_INDEX[n] for n in (
    "left_hip", "right_hip", "left_knee", "right_knee",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow"))
#: The hands (wrist and hand joints): under the limb alignment they continue their forearm.
HAND_JOINTS: tuple[int, ...] = tuple(_INDEX[n] for n in (
    "left_wrist", "right_wrist", "left_hand", "right_hand"))


def forward_kinematics(poses: np.ndarray, trans: np.ndarray | None = None,
                       rest_joints: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Global joint rotations and positions of SMPL's skeleton (no mesh).

    SMPL rotates the root about the pelvis joint and adds ``trans`` afterwards.

    Args:
        poses: axis-angle [rad], shape (..., 24, 3).
        trans: root translation [m], shape (..., 3), or None for zero.
        rest_joints: rest joint positions [m], shape (24, 3); default ``SMPL_REST_JOINTS``.

    Returns:
        ``(G, P)``: global rotations (..., 24, 3, 3) and joint positions [m] (..., 24, 3),
        float64.
    """
    R = axis_angle_to_matrix(np.asarray(poses, dtype=np.float64))
    J = SMPL_REST_JOINTS if rest_joints is None else np.asarray(rest_joints, dtype=np.float64)
    G = np.empty_like(R)
    P = np.empty(R.shape[:-1], dtype=np.float64)
    G[..., 0, :, :] = R[..., 0, :, :]
    P[..., 0, :] = J[0] if trans is None else J[0] + np.asarray(trans, dtype=np.float64)
    for j in range(1, NUM_SMPL_JOINTS):
        p = _PARENTS[j]
        G[..., j, :, :] = G[..., p, :, :] @ R[..., j, :, :]
        P[..., j, :] = P[..., p, :] + np.einsum("...ab,b->...a", G[..., p, :, :], J[j] - J[p])
    return G, P


def global_to_local(G: np.ndarray) -> np.ndarray:
    """Local rotations along SMPL's tree from global ones.

    Args:
        G: global rotations, shape (..., 24, 3, 3).

    Returns:
        local rotation matrices, shape (..., 24, 3, 3): ``L_j = G_parent^T G_j``.
    """
    G = np.asarray(G, dtype=np.float64)
    L = np.empty_like(G)
    L[..., 0, :, :] = G[..., 0, :, :]
    par = G[..., _PARENTS[1:], :, :]
    L[..., 1:, :, :] = np.swapaxes(par, -1, -2) @ G[..., 1:, :, :]
    return L


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking direction ``a`` to direction ``b``.

    Args:
        a, b: directions, shape (..., 3) (need not be unit length).

    Returns:
        rotation matrices, shape (..., 3, 3), with ``R a/|a| = b/|b|``.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=-1, keepdims=True)
    c = np.sum(a * b, axis=-1, keepdims=True)
    angle = np.arctan2(s, c)
    # antiparallel: any axis perpendicular to a
    perp = np.cross(a, np.where(np.abs(a[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
    axis = np.where(s > 1e-9, axis, perp)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    return axis_angle_to_matrix(axis * angle)


def rest_alignment(src_bone_dirs: dict[int, np.ndarray], rest_joints: np.ndarray | None = None,
                   *, limbs_only: bool = False) -> np.ndarray:
    """Per-joint rest alignment ``C_j`` (see the module docstring).

    Args:
        src_bone_dirs: SMPL joint index -> the source skeleton's rest direction of the bone
            that SMPL joint drives (3,), in the source's world frame (Y up, facing +Z).
        rest_joints: SMPL rest joints [m] (24, 3) of the body the motion will pose; default
            ``SMPL_REST_JOINTS``.
        limbs_only: align the limbs only (``LIMB_JOINTS``; the hands follow their forearm, every
            other joint keeps SMPL's rest orientation); False aligns every bone.

    Returns:
        rotations (24, 3, 3) with ``C_j d_smpl = d_src`` for each aligned bone; the root's is
        the identity (its orientation is copied as is); an aligned joint without a direction or
        a bone child takes its parent's (so a source leaf at rest stays at identity local
        rotation).
    """
    J = SMPL_REST_JOINTS if rest_joints is None else np.asarray(rest_joints, dtype=np.float64)
    C = np.tile(np.eye(3), (NUM_SMPL_JOINTS, 1, 1))
    for j in range(1, NUM_SMPL_JOINTS):  # parents first
        if limbs_only and j not in LIMB_JOINTS:
            if j in HAND_JOINTS:
                C[j] = C[_PARENTS[j]]  # a hand continues its forearm
            continue  # torso, head, collars, feet: SMPL's rest orientation
        d = src_bone_dirs.get(j)
        child = BONE_CHILD[j]
        if child < 0 or d is None or np.linalg.norm(d) < 1e-9:
            C[j] = C[_PARENTS[j]]  # no bone of its own (hands, feet tips): parent's frame
        else:
            C[j] = rotation_between(J[child] - J[j], d)
    return C


def retarget_global_rotations(src_global: np.ndarray, mapping: dict[int, int],
                              alignment: np.ndarray | None = None) -> np.ndarray:
    """SMPL axis-angle poses from a source skeleton's global rotations.

    Args:
        src_global: source global rotations, shape (T, S, 3, 3) (rest = identity).
        mapping: SMPL joint index -> source joint index; joint 0 (pelvis) should be mapped.
        alignment: rest alignment per SMPL joint (24, 3, 3), see :func:`rest_alignment`;
            None for identity (source rest = SMPL T-pose).

    Returns:
        axis-angle [rad], shape (T, 24, 3), float64; unmapped joints have identity local
        rotation.
    """
    T = src_global.shape[0]
    G = np.empty((T, NUM_SMPL_JOINTS, 3, 3))
    for j in range(NUM_SMPL_JOINTS):
        if j in mapping:
            g = src_global[:, mapping[j]]
            G[:, j] = g if alignment is None else g @ alignment[j]
        elif j == 0:
            G[:, j] = np.eye(3)
        else:
            G[:, j] = G[:, _PARENTS[j]]
    return matrix_to_axis_angle(global_to_local(G))


def bone_directions(G: np.ndarray, rest_joints: np.ndarray | None = None) -> np.ndarray:
    """World direction of each SMPL bone (joint -> ``BONE_CHILD``), unit, (..., 24, 3).

    Joints without a bone child get zeros.
    """
    J = SMPL_REST_JOINTS if rest_joints is None else np.asarray(rest_joints, dtype=np.float64)
    out = np.zeros(G.shape[:-1])
    for j, c in enumerate(BONE_CHILD):
        if c < 0:
            continue
        d = J[c] - J[j]
        v = G[..., j, :, :] @ d
        out[..., j, :] = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return out
