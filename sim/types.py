"""Plain data types that flow between stages.

Arrays at module boundaries are numpy ``float32`` (positions), ``int32`` (indices).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from sim.errors import WrinklesInputError

if TYPE_CHECKING:  # pragma: no cover
    from sim.garments.types import Garment

#: SMPL's 24 joints, names and order as SMPL.
SMPL_JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar",
    "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_hand", "right_hand",
)
#: parent of each SMPL joint (-1 for the root).
SMPL_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
)
NUM_SMPL_JOINTS = 24


@dataclass(frozen=True)
class BodyFrames:
    """A posed body over time.

    Attributes:
        vertices: skinned vertex positions [m], shape (T, V, 3), float32.
        joints: joint positions [m], shape (T, J, 3), float32.
        transforms: world transform of each joint's frame [m for translation], shape
            (T, J, 4, 4), float32 (rotation = accumulated joint rotation, translation = joint
            position).
        faces: triangle indices, shape (F, 3), int32.
    """

    vertices: np.ndarray
    joints: np.ndarray
    transforms: np.ndarray
    faces: np.ndarray

    @property
    def num_frames(self) -> int:
        return int(self.vertices.shape[0])


@dataclass(frozen=True)
class BodyRig:
    """A shaped body as a skeleton and a skin: what a DCC needs to pose it as we do (LBS).

    Posed vertices (``sim.skinning.lbs``) are
    ``sum_k weight_values[v, k] * A[weight_indices[v, k]] @ (rest_vertices[v] + pose offsets)``
    with ``A_j = G_j @ inverse(bind_j)``, ``G_j`` the joint's world transform
    (``BodyFrames.transforms``) and ``bind_j`` the translation to ``rest_joints[j]``; the pose
    offsets are ``sum_p feature[p] * pose_blend_shapes[p]`` with
    ``feature[9 (j - 1) + 3 r + c] = R_j[r, c] - I[r, c]`` of each non-root joint's rotation
    relative to its parent (SMPL Eq. 9).

    Attributes:
        rest_vertices: shaped rest-pose vertices [m], shape (V, 3), float32.
        faces: triangles, shape (F, 3), int32.
        joint_names: J names.
        parents: parent joint index, shape (J,), int32, -1 for the root; parents[j] < j.
        rest_joints: rest joint positions [m], shape (J, 3), float32.
        weight_indices: the joints influencing each vertex, shape (V, K), int32 (padding 0).
        weight_values: their weights, shape (V, K), float32 (padding 0; rows sum to 1).
        pose_blend_shapes: pose-corrective offsets [m per unit feature], shape (9 (J - 1), V, 3),
            float32, or None for a body without them.
    """

    rest_vertices: np.ndarray
    faces: np.ndarray
    joint_names: tuple[str, ...]
    parents: np.ndarray
    rest_joints: np.ndarray
    weight_indices: np.ndarray
    weight_values: np.ndarray
    pose_blend_shapes: np.ndarray | None = None

    @property
    def num_joints(self) -> int:
        return int(self.parents.shape[0])

    @property
    def num_vertices(self) -> int:
        return int(self.rest_vertices.shape[0])


@dataclass(frozen=True)
class Motion:
    """A body motion in SMPL's convention.

    Attributes:
        poses: axis-angle joint rotations [rad] relative to the parent, shape (T, 24, 3),
            float32, SMPL joint order (``SMPL_JOINT_NAMES``); joint 0 is the global orientation.
        trans: root translation [m], shape (T, 3), float32 (Y up).
        fps: frames per second [1/s].
        name: a short label.
        betas: body shape coefficients the motion was captured with, shape (B,), or None.
        source: where it came from (file path, ``procedural:walk`` ...).
    """

    poses: np.ndarray
    trans: np.ndarray
    fps: float
    name: str = "motion"
    betas: np.ndarray | None = None
    source: str = ""
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        poses = np.asarray(self.poses, dtype=np.float32)
        trans = np.asarray(self.trans, dtype=np.float32)
        object.__setattr__(self, "poses", poses)
        object.__setattr__(self, "trans", trans)
        where = self.source or self.name
        if poses.ndim != 3 or poses.shape[1:] != (NUM_SMPL_JOINTS, 3):
            raise WrinklesInputError(f"motion poses must have shape (T, 24, 3), got {poses.shape}",
                                     path=where)
        if trans.shape != (poses.shape[0], 3):
            raise WrinklesInputError(
                f"motion trans must have shape ({poses.shape[0]}, 3) to match the poses, got "
                f"{trans.shape}", path=where)
        if poses.shape[0] < 1:
            raise WrinklesInputError("motion has no frames", path=where)
        if not (np.all(np.isfinite(poses)) and np.all(np.isfinite(trans))):
            bad = np.where(~(np.isfinite(poses).all(axis=(1, 2)) & np.isfinite(trans).all(axis=1)))[0]
            raise WrinklesInputError(f"motion has NaN/inf values at frame {int(bad[0])}", path=where)
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise WrinklesInputError(f"motion fps must be positive, got {self.fps}", path=where)

    @property
    def num_frames(self) -> int:
        return int(self.poses.shape[0])

    @property
    def duration(self) -> float:
        """Length [s]."""
        return self.num_frames / float(self.fps)


@dataclass(frozen=True)
class GarmentSequence:
    """A garment animated on a body: what simulation and inference produce.

    Attributes:
        vertices: garment positions [m], shape (T, V, 3), float32, V = ``garment.num_vertices``
            (same vertex order and faces as the garment).
        body: the body over the same T frames.
        garment: the garment (rest mesh, faces, UVs, material, attachments).
        motion: the motion of the T frames (``poses`` (T, 24, 3), ``trans`` (T, 3)).
        fps: frames per second [1/s].
        provenance: JSON-ready record of how it was made: resolved config, seed, device,
            package versions, frame bookkeeping (e.g. ``prelude_frames``).
    """

    vertices: np.ndarray
    body: BodyFrames
    garment: Garment
    motion: Motion
    fps: float
    provenance: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.vertices, dtype=np.float32)
        if v.ndim != 3 or v.shape[2] != 3 or v.shape[1] != self.garment.num_vertices:
            raise ValueError(f"GarmentSequence vertices must have shape (T, {self.garment.num_vertices}, 3), "
                             f"got {v.shape}")
        if self.body.num_frames != v.shape[0] or self.motion.num_frames != v.shape[0]:
            raise ValueError(f"GarmentSequence: {v.shape[0]} garment frames, {self.body.num_frames} body "
                             f"frames, {self.motion.num_frames} motion frames (must be equal)")
        object.__setattr__(self, "vertices", v)

    @property
    def num_frames(self) -> int:
        return int(self.vertices.shape[0])


def face_layers_array(face_layers, face_count: int, where: str) -> np.ndarray:
    """Fabric layers per face as float64 (F,): ones for None, else ``face_layers`` checked to be
    ``face_count`` finite numbers >= 1 (``ValueError`` naming ``where`` otherwise)."""
    if face_layers is None:
        return np.ones(face_count)
    layers = np.asarray(face_layers, dtype=np.float64).reshape(-1)
    if layers.shape != (face_count,) or not np.isfinite(layers).all() or layers.min() < 1.0:
        raise ValueError(f"{where}: face_layers must be ({face_count},) numbers >= 1, got shape "
                         f"{layers.shape}" + (f", min {layers.min():g}" if layers.size else ""))
    return layers
