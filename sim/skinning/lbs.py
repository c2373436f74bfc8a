"""Skinning driver: holds a body model's arrays on a device and launches the kernels.

``Skinner`` uploads a ``BodyModel`` once per device; ``pose`` runs shape blend, joint
regression, forward kinematics and LBS, batched over frames (chunked to bound memory).
``lbs_reference`` is the plain-numpy reference the kernels are tested against.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sim.device import resolve_device, warp
from sim.rotations import axis_angle_to_matrix
from sim.types import BodyFrames

if TYPE_CHECKING:  # pragma: no cover
    from sim.bodies.model import BodyModel


def sparse_weights(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-width sparse form of skinning weights, exact (keeps every non-zero).

    Args:
        weights: (V, J) float.

    Returns:
        (idx int32 (V, K), val float32 (V, K)), K = max non-zeros of a vertex; padding has
        weight 0 and index 0.
    """
    nz = weights != 0
    k = max(1, int(nz.sum(axis=1).max()))
    order = np.argsort(-np.abs(weights), axis=1, kind="stable")[:, :k]
    val = np.take_along_axis(weights, order, axis=1).astype(np.float32)
    idx = np.where(val != 0, order, 0).astype(np.int32)
    return idx, val


def csr(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense (R, C) -> CSR (row_offsets int32 (R+1,), cols int32, vals float32)."""
    rows, cols = np.nonzero(matrix)
    offsets = np.zeros(matrix.shape[0] + 1, dtype=np.int32)
    np.add.at(offsets, rows + 1, 1)
    return np.cumsum(offsets).astype(np.int32), cols.astype(np.int32), matrix[rows, cols].astype(np.float32)


class Skinner:
    """A body model's skinning arrays on one Warp device.

    Args:
        model: the body model.
        device: Warp device (``None``: cuda when present, else cpu).
    """

    def __init__(self, model: BodyModel, device: str | None = None):
        wp = warp()
        from sim.skinning import lbs_kernels  # noqa: F401  (module load registers kernels)

        self.model = model
        self.device = resolve_device(device)
        d = self.device
        self._v_template = wp.array(model.v_template, dtype=wp.vec3, device=d)
        self._shapedirs = wp.array(model.shapedirs, dtype=float, device=d)
        off, cols, vals = csr(model.j_regressor)
        self._jr = (wp.array(off, dtype=int, device=d), wp.array(cols, dtype=int, device=d),
                    wp.array(vals, dtype=float, device=d))
        idx, val = sparse_weights(model.weights)
        self._w_idx = wp.array(idx, dtype=int, device=d)
        self._w_val = wp.array(val, dtype=float, device=d)
        self._parents = wp.array(model.parents.astype(np.int32), dtype=int, device=d)
        if model.posedirs is not None:
            pd = np.ascontiguousarray(np.transpose(model.posedirs, (2, 0, 1)))  # (P, V, 3)
            self._posedirs = wp.array(pd, dtype=wp.vec3, device=d)
            self.num_pose_basis = pd.shape[0]
        else:
            self._posedirs = wp.zeros((1, 1), dtype=wp.vec3, device=d)
            self.num_pose_basis = 0
        self._shape_cache: tuple[bytes, object, object] | None = None

    def shape(self, betas: np.ndarray):
        """Shaped rest vertices and rest joints on the device (cached for the last betas).

        Args:
            betas: shape coefficients, shape (B,) with B <= model.num_betas (zero-padded).

        Returns:
            (v_shaped wp.array (V,) vec3 [m], rest_joints wp.array (J,) vec3 [m]).
        """
        wp = warp()
        from sim.skinning.lbs_kernels import regress_joints_kernel, shape_blend_kernel

        b = self.model.full_betas(betas)
        key = b.tobytes()
        if self._shape_cache is not None and self._shape_cache[0] == key:
            return self._shape_cache[1], self._shape_cache[2]
        d = self.device
        v_shaped = wp.empty(self.model.num_vertices, dtype=wp.vec3, device=d)
        wp.launch(shape_blend_kernel, dim=self.model.num_vertices,
                  inputs=[self._v_template, self._shapedirs, wp.array(b, dtype=float, device=d)],
                  outputs=[v_shaped], device=d)
        joints = wp.empty(self.model.num_joints, dtype=wp.vec3, device=d)
        wp.launch(regress_joints_kernel, dim=self.model.num_joints,
                  inputs=[v_shaped, *self._jr], outputs=[joints], device=d)
        self._shape_cache = (key, v_shaped, joints)
        return v_shaped, joints

    def pose_device(self, betas: np.ndarray, full_poses: np.ndarray, trans: np.ndarray):
        """Skin on the device and return Warp arrays (no host copy).

        Args:
            betas: (B,).
            full_poses: axis-angle [rad] for every model joint, shape (T, J, 3).
            trans: root translation [m], shape (T, 3).

        Returns:
            (vertices (T, V) vec3, global transforms (T, J) mat44), Warp arrays on the device.
        """
        wp = warp()
        from sim.skinning.lbs_kernels import forward_kinematics_kernel, lbs_kernel

        d = self.device
        T = int(full_poses.shape[0])
        J = self.model.num_joints
        v_shaped, rest_joints = self.shape(betas)
        poses_d = wp.array(np.ascontiguousarray(full_poses, dtype=np.float32), dtype=wp.vec3, device=d)
        trans_d = wp.array(np.ascontiguousarray(trans, dtype=np.float32), dtype=wp.vec3, device=d)
        glob = wp.empty((T, J), dtype=wp.mat44, device=d)
        skin = wp.empty((T, J), dtype=wp.mat44, device=d)
        feat = wp.empty((T, max(self.num_pose_basis, 1)), dtype=float, device=d)
        wp.launch(forward_kinematics_kernel, dim=T,
                  inputs=[poses_d, rest_joints, self._parents, trans_d, int(self.num_pose_basis > 0)],
                  outputs=[glob, skin, feat], device=d)
        verts = wp.empty((T, self.model.num_vertices), dtype=wp.vec3, device=d)
        wp.launch(lbs_kernel, dim=(T, self.model.num_vertices),
                  inputs=[v_shaped, self._posedirs, feat, self._w_idx, self._w_val, skin, trans_d,
                          self.num_pose_basis],
                  outputs=[verts], device=d)
        return verts, glob

    def pose(self, betas: np.ndarray, full_poses: np.ndarray, trans: np.ndarray, *,
             chunk: int = 256, progress=None) -> BodyFrames:
        """Skin a sequence and copy it to the host.

        Args:
            betas: (B,).
            full_poses: axis-angle [rad], shape (T, J, 3).
            trans: root translation [m], shape (T, 3).
            chunk: frames per launch (bounds device memory).
            progress: optional callable ``progress(frames_done, frames_total)``.

        Returns:
            BodyFrames with vertices (T, V, 3), joints (T, J, 3), transforms (T, J, 4, 4).
        """
        T = int(full_poses.shape[0])
        V, J = self.model.num_vertices, self.model.num_joints
        verts = np.empty((T, V, 3), dtype=np.float32)
        transforms = np.empty((T, J, 4, 4), dtype=np.float32)
        for s in range(0, T, chunk):
            e = min(T, s + chunk)
            v_d, g_d = self.pose_device(betas, full_poses[s:e], trans[s:e])
            verts[s:e] = v_d.numpy()
            transforms[s:e] = g_d.numpy()
            if progress is not None:
                progress(e, T)
        joints = np.ascontiguousarray(transforms[:, :, :3, 3])
        return BodyFrames(vertices=verts, joints=joints, transforms=transforms,
                          faces=self.model.faces)


def lbs_reference(model: BodyModel, betas: np.ndarray, full_poses: np.ndarray,
                  trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plain-numpy SMPL forward pass (float64), the reference for the kernels.

    Args:
        model: body model.
        betas: (B,).
        full_poses: axis-angle [rad], shape (T, J, 3).
        trans: [m], shape (T, 3).

    Returns:
        (vertices (T, V, 3), joints (T, J, 3)) [m], float64.
    """
    b = model.full_betas(betas).astype(np.float64)
    v_shaped = model.v_template.astype(np.float64) + model.shapedirs.astype(np.float64) @ b
    rest_j = model.j_regressor.astype(np.float64) @ v_shaped
    R = axis_angle_to_matrix(full_poses)  # (T, J, 3, 3)
    T, J = R.shape[:2]
    G = np.zeros((T, J, 4, 4))
    for j in range(J):
        p = model.parents[j]
        L = np.zeros((T, 4, 4))
        L[:, :3, :3] = R[:, j]
        L[:, :3, 3] = rest_j[j] - (rest_j[p] if p >= 0 else 0.0)
        L[:, 3, 3] = 1.0
        G[:, j] = L if p < 0 else G[:, p] @ L
    A = G.copy()
    A[:, :, :3, 3] -= np.einsum("tjab,jb->tja", G[:, :, :3, :3], rest_j)
    v_posed = np.broadcast_to(v_shaped, (T, *v_shaped.shape)).copy()
    if model.posedirs is not None:
        feat = (R[:, 1:] - np.eye(3)).reshape(T, -1)
        v_posed += np.einsum("vkp,tp->tvk", model.posedirs.astype(np.float64), feat)
    M = np.einsum("vj,tjab->tvab", model.weights.astype(np.float64), A)
    verts = np.einsum("tvab,tvb->tva", M[:, :, :3, :3], v_posed) + M[:, :, :3, 3] + trans[:, None, :]
    joints = G[:, :, :3, 3] + trans[:, None, :]
    return verts, joints
