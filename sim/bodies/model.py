"""``BodyModel``: an SMPL-structured parametric body.

One class serves the embedded default body and user SMPL / SMPL-H / SMPL-X files: all are a
template mesh, linear shape blend shapes, optional pose blend shapes, a joint regressor,
skinning weights and a kinematic tree. ``pose`` skins a whole sequence with Warp kernels.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.errors import WrinklesInputError
from sim.types import NUM_SMPL_JOINTS, SMPL_JOINT_NAMES, BodyFrames, BodyRig, Motion


@dataclass(frozen=True, eq=False)
class BodyModel:
    """A parametric body model in SMPL's structure.

    Attributes:
        v_template: rest vertices [m], shape (V, 3), float32 (T-pose, Y up).
        faces: triangles, shape (F, 3), int32.
        shapedirs: shape blend shapes [m per unit beta], shape (V, 3, B), float32.
        posedirs: pose blend shapes [m], shape (V, 3, 9 (J-1)), float32, or None.
        j_regressor: joint regressor, shape (J, V), float32 (rows sum to 1).
        weights: skinning weights, shape (V, J), float32 (rows sum to 1).
        parents: parent joint index, shape (J,), int32, -1 for the root; parents[j] < j.
        joint_names: J names.
        kind: ``default``, ``smpl``, ``smplh`` or ``smplx``.
        body_joint_map: for each of SMPL's 24 joints, its index among this model's joints, or
            -1 where the model has no such joint (SMPL-H/X hands: the fingers replace them).
        rest_pose: axis-angle [rad] of joints a motion does not address, shape (J, 3)
            (SMPL-X's mean hand pose, as smplx's default ``flat_hand_mean=False``).
        shape_names: a name per shape coefficient, where the basis has named directions.
        name: label; source: file it came from.
    """

    v_template: np.ndarray
    faces: np.ndarray
    shapedirs: np.ndarray
    posedirs: np.ndarray | None
    j_regressor: np.ndarray
    weights: np.ndarray
    parents: np.ndarray
    joint_names: tuple[str, ...]
    kind: str = "smpl"
    body_joint_map: np.ndarray | None = None
    rest_pose: np.ndarray | None = None
    shape_names: tuple[str, ...] | None = None
    name: str = "body"
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = self.source or self.name
        f32 = {k: np.ascontiguousarray(getattr(self, k), dtype=np.float32)
               for k in ("v_template", "shapedirs", "j_regressor", "weights")}
        for k, v in f32.items():
            object.__setattr__(self, k, v)
        object.__setattr__(self, "faces", np.ascontiguousarray(self.faces, dtype=np.int32))
        object.__setattr__(self, "parents", np.asarray(self.parents, dtype=np.int32).reshape(-1))
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        V, J = self.v_template.shape[0], self.parents.shape[0]

        def bad(msg: str) -> WrinklesInputError:
            return WrinklesInputError(msg, path=where)

        if self.v_template.ndim != 2 or self.v_template.shape[1] != 3:
            raise bad(f"v_template must have shape (V, 3), got {self.v_template.shape}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise bad(f"f (faces) must have shape (F, 3), got {self.faces.shape}")
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= V):
            raise bad(f"faces index vertices outside 0..{V - 1}")
        if self.shapedirs.ndim != 3 or self.shapedirs.shape[:2] != (V, 3):
            raise bad(f"shapedirs must have shape ({V}, 3, B), got {self.shapedirs.shape}")
        if self.j_regressor.shape != (J, V):
            raise bad(f"J_regressor must have shape ({J}, {V}), got {self.j_regressor.shape}")
        if self.weights.shape != (V, J):
            raise bad(f"weights must have shape ({V}, {J}), got {self.weights.shape}")
        if len(self.joint_names) != J:
            raise bad(f"{len(self.joint_names)} joint names for {J} joints")
        par = self.parents
        if par[0] != -1 or np.any(par[1:] >= np.arange(1, J)) or np.any(par[1:] < 0):
            raise bad("kintree parents must have the root first and each parent before its child")
        if self.posedirs is not None:
            pd = np.ascontiguousarray(self.posedirs, dtype=np.float32)
            if pd.shape != (V, 3, 9 * (J - 1)):
                raise bad(f"posedirs must have shape ({V}, 3, {9 * (J - 1)}), got {pd.shape}")
            object.__setattr__(self, "posedirs", pd)
        for k in ("v_template", "shapedirs", "j_regressor", "weights"):
            if not np.all(np.isfinite(getattr(self, k))):
                raise bad(f"{k} contains NaN or inf")
        if self.body_joint_map is None:
            idx = {n: i for i, n in enumerate(self.joint_names)}
            m = np.array([idx.get(n, -1) for n in SMPL_JOINT_NAMES], dtype=np.int32)
        else:
            m = np.asarray(self.body_joint_map, dtype=np.int32)
        if m.shape != (NUM_SMPL_JOINTS,):
            raise bad(f"body_joint_map must have 24 entries, got {m.shape}")
        object.__setattr__(self, "body_joint_map", m)
        rp = np.zeros((J, 3), np.float32)
        if self.rest_pose is not None:
            rp = np.asarray(self.rest_pose, np.float32)
        if rp.shape != (J, 3):
            raise bad(f"rest_pose must have shape ({J}, 3), got {rp.shape}")
        object.__setattr__(self, "rest_pose", rp)
        object.__setattr__(self, "_skinners", {})

    # --- sizes -------------------------------------------------------------------------
    @property
    def num_vertices(self) -> int:
        return int(self.v_template.shape[0])

    @property
    def num_joints(self) -> int:
        return int(self.parents.shape[0])

    @property
    def num_betas(self) -> int:
        return int(self.shapedirs.shape[2])

    # --- parameters ----------------------------------------------------------------------
    def full_betas(self, betas: np.ndarray | None) -> np.ndarray:
        """Shape coefficients zero-padded to ``num_betas``, float32 (B,)."""
        out = np.zeros(self.num_betas, dtype=np.float32)
        if betas is None:
            return out
        b = np.asarray(betas, dtype=np.float32).reshape(-1)
        if b.shape[0] > self.num_betas:
            raise WrinklesInputError(
                f"{b.shape[0]} shape coefficients given, the body model has {self.num_betas}",
                path=self.source or self.name)
        if not np.all(np.isfinite(b)):
            raise WrinklesInputError("shape coefficients contain NaN or inf", path=self.source or self.name)
        out[: b.shape[0]] = b
        return out

    def full_poses(self, poses: np.ndarray) -> np.ndarray:
        """Expand motion poses to every model joint.

        Args:
            poses: axis-angle [rad], (T, 24, 3) in SMPL's joint order, or (T, J, 3) for all of
                this model's joints.

        Returns:
            (T, J, 3) float32: SMPL joints placed by ``body_joint_map``; others at ``rest_pose``.
        """
        poses = np.asarray(poses, dtype=np.float32)
        J = self.num_joints
        if poses.ndim != 3 or poses.shape[2] != 3 or poses.shape[1] not in (NUM_SMPL_JOINTS, J):
            raise WrinklesInputError(
                f"poses must have shape (T, 24, 3) or (T, {J}, 3), got {poses.shape}",
                path=self.source or self.name)
        if poses.shape[1] == J and (J != NUM_SMPL_JOINTS or self.kind == "smpl"):
            return poses
        out = np.broadcast_to(self.rest_pose, (poses.shape[0], J, 3)).copy()
        m = self.body_joint_map
        ok = m >= 0
        out[:, m[ok]] = poses[:, np.nonzero(ok)[0]]
        return out

    # --- forward -------------------------------------------------------------------------
    def skinner(self, device: str | None = None):
        """The (cached) ``Skinner`` holding this model's arrays on ``device``."""
        from sim.device import resolve_device
        from sim.skinning.lbs import Skinner

        d = resolve_device(device)
        cache = self._skinners  # type: ignore[attr-defined]
        if d not in cache:
            cache[d] = Skinner(self, d)
        return cache[d]

    def pose(self, betas: np.ndarray | None, poses: np.ndarray, trans: np.ndarray | None = None,
             *, device: str | None = None, progress=None) -> BodyFrames:
        """Skin a sequence (Warp kernels, batched over frames).

        Args:
            betas: shape coefficients (B,) or None for the mean shape.
            poses: axis-angle [rad], (T, 24, 3) SMPL order or (T, J, 3).
            trans: root translation [m], (T, 3); None for zeros.
            device: Warp device.
            progress: optional callable ``progress(frames_done, frames_total)``.

        Returns:
            BodyFrames (vertices (T, V, 3) [m], joints (T, J, 3) [m], transforms (T, J, 4, 4)).
        """
        full = self.full_poses(poses)
        T = full.shape[0]
        tr = np.zeros((T, 3), np.float32) if trans is None else np.asarray(trans, np.float32)
        if tr.shape != (T, 3):
            raise WrinklesInputError(f"trans must have shape ({T}, 3), got {tr.shape}",
                                     path=self.source or self.name)
        if not (np.all(np.isfinite(full)) and np.all(np.isfinite(tr))):
            raise WrinklesInputError("poses or trans contain NaN or inf", path=self.source or self.name)
        return self.skinner(device).pose(betas, full, tr, progress=progress)

    def pose_motion(self, motion: Motion, betas: np.ndarray | None = None, *,
                    device: str | None = None, progress=None) -> BodyFrames:
        """Skin a ``Motion`` (betas default to the motion's own, else the mean shape)."""
        b = motion.betas if betas is None else betas
        if b is not None and np.asarray(b).size > self.num_betas:
            b = np.asarray(b).reshape(-1)[: self.num_betas]
        return self.pose(b, motion.poses, motion.trans, device=device, progress=progress)

    def rest_mesh(self, betas: np.ndarray | None = None) -> np.ndarray:
        """Shaped rest-pose vertices [m], (V, 3), float32 (numpy, no kernels)."""
        return (self.v_template + self.shapedirs @ self.full_betas(betas)).astype(np.float32)

    def rest_joints(self, betas: np.ndarray | None = None) -> np.ndarray:
        """Rest joint positions [m], (J, 3), float32."""
        return (self.j_regressor @ self.rest_mesh(betas)).astype(np.float32)

    def rig(self, betas: np.ndarray | None = None) -> BodyRig:
        """The body shaped by ``betas`` as a skeleton and skin (``BodyRig``): what ``pose``
        skins, for writing the body as a ``UsdSkel`` rig. Weights keep every non-zero
        (``sparse_weights``); the pose blend shapes are ``posedirs`` per pose-feature entry."""
        from sim.skinning.lbs import sparse_weights

        idx, val = sparse_weights(self.weights)
        shapes = None
        if self.posedirs is not None:
            shapes = np.ascontiguousarray(np.transpose(self.posedirs, (2, 0, 1)), dtype=np.float32)
        return BodyRig(rest_vertices=self.rest_mesh(betas), faces=self.faces,
                       joint_names=self.joint_names, parents=self.parents.copy(),
                       rest_joints=self.rest_joints(betas), weight_indices=idx, weight_values=val,
                       pose_blend_shapes=shapes)
