"""Warp kernels for SMPL-style skinning (Loper et al. 2015, Eq. 2-4; smplx ``lbs.py``).

Kernel arguments: inputs first, then outputs with an ``_out`` suffix (STYLE.md 2).
All kernels run on ``cpu`` and ``cuda``.
"""

from __future__ import annotations

import warp as wp


@wp.func
def rodrigues(r: wp.vec3) -> wp.mat33:
    """Axis-angle [rad] -> rotation matrix, with smplx's epsilon (norm of r + 1e-8)."""
    angle = wp.length(r + wp.vec3(1.0e-8))
    d = r / angle
    s = wp.sin(angle)
    c = wp.cos(angle)
    K = wp.mat33(0.0, -d[2], d[1], d[2], 0.0, -d[0], -d[1], d[0], 0.0)
    return wp.identity(n=3, dtype=float) + s * K + (1.0 - c) * (K @ K)


@wp.kernel
def shape_blend_kernel(
    v_template: wp.array(dtype=wp.vec3),
    shapedirs: wp.array3d(dtype=float),
    betas: wp.array(dtype=float),
    v_shaped_out: wp.array(dtype=wp.vec3),
):
    """v_shaped = T + sum_b beta_b S_b (SMPL Eq. 2, B_S). shapedirs: (V, 3, B)."""
    v = wp.tid()
    p = v_template[v]
    for b in range(betas.shape[0]):
        p = p + wp.vec3(shapedirs[v, 0, b], shapedirs[v, 1, b], shapedirs[v, 2, b]) * betas[b]
    v_shaped_out[v] = p


@wp.kernel
def regress_joints_kernel(
    v_shaped: wp.array(dtype=wp.vec3),
    row_offsets: wp.array(dtype=int),
    cols: wp.array(dtype=int),
    vals: wp.array(dtype=float),
    joints_out: wp.array(dtype=wp.vec3),
):
    """J = J_regressor @ v_shaped with the regressor in CSR form (one thread per joint)."""
    j = wp.tid()
    acc = wp.vec3(0.0)
    for k in range(row_offsets[j], row_offsets[j + 1]):
        acc = acc + vals[k] * v_shaped[cols[k]]
    joints_out[j] = acc


@wp.kernel
def forward_kinematics_kernel(
    poses: wp.array2d(dtype=wp.vec3),
    rest_joints: wp.array(dtype=wp.vec3),
    parents: wp.array(dtype=int),
    trans: wp.array(dtype=wp.vec3),
    write_pose_feature: int,
    global_out: wp.array2d(dtype=wp.mat44),
    skin_out: wp.array2d(dtype=wp.mat44),
    pose_feature_out: wp.array2d(dtype=float),
):
    """Kinematic chain for one frame per thread (parents[j] < j).

    global_out[t, j]: world frame of joint j (translation = joint position + root trans).
    skin_out[t, j]:   G_j with the rest joint removed, G_j [I | -J_j] (SMPL Eq. 4), without
                      the root translation (added after blending, as smplx does).
    pose_feature_out[t, 9 (j-1) + 3 r + c] = R_j[r, c] - I[r, c] for j >= 1 (SMPL Eq. 9).
    """
    t = wp.tid()
    num_joints = rest_joints.shape[0]
    for j in range(num_joints):
        R = rodrigues(poses[t, j])
        p = parents[j]
        Jj = rest_joints[j]
        local_t = Jj
        if p >= 0:
            local_t = Jj - rest_joints[p]
        L = wp.mat44(
            R[0, 0], R[0, 1], R[0, 2], local_t[0],
            R[1, 0], R[1, 1], R[1, 2], local_t[1],
            R[2, 0], R[2, 1], R[2, 2], local_t[2],
            0.0, 0.0, 0.0, 1.0,
        )
        G = L
        if p >= 0:
            G = global_out[t, p] @ L
        global_out[t, j] = G
        if write_pose_feature != 0 and j > 0:
            base = 9 * (j - 1)
            for r in range(3):
                for c in range(3):
                    eye = float(0.0)
                    if r == c:
                        eye = 1.0
                    pose_feature_out[t, base + 3 * r + c] = R[r, c] - eye
    # second pass: skinning transforms and world translation
    tr = trans[t]
    for j in range(num_joints):
        G = global_out[t, j]
        Jj = rest_joints[j]
        gj = wp.vec3(G[0, 3], G[1, 3], G[2, 3])
        rj = wp.vec3(
            G[0, 0] * Jj[0] + G[0, 1] * Jj[1] + G[0, 2] * Jj[2],
            G[1, 0] * Jj[0] + G[1, 1] * Jj[1] + G[1, 2] * Jj[2],
            G[2, 0] * Jj[0] + G[2, 1] * Jj[1] + G[2, 2] * Jj[2],
        )
        A = G
        A[0, 3] = gj[0] - rj[0]
        A[1, 3] = gj[1] - rj[1]
        A[2, 3] = gj[2] - rj[2]
        skin_out[t, j] = A
        G[0, 3] = gj[0] + tr[0]
        G[1, 3] = gj[1] + tr[1]
        G[2, 3] = gj[2] + tr[2]
        global_out[t, j] = G


@wp.kernel
def lbs_kernel(
    v_shaped: wp.array(dtype=wp.vec3),
    posedirs: wp.array2d(dtype=wp.vec3),
    pose_feature: wp.array2d(dtype=float),
    weight_idx: wp.array2d(dtype=int),
    weight_val: wp.array2d(dtype=float),
    skin: wp.array2d(dtype=wp.mat44),
    trans: wp.array(dtype=wp.vec3),
    num_pose_basis: int,
    vertices_out: wp.array2d(dtype=wp.vec3),
):
    """One thread per (frame, vertex): pose blend shapes, then linear blend skinning.

    v_posed = v_shaped + sum_p posedirs[p, v] * feature[t, p]             (SMPL Eq. 2, B_P)
    v_out   = (sum_k w_vk A_{t, j_vk}) [v_posed; 1] + trans_t              (SMPL Eq. 3)
    posedirs: (P, V) vec3; weights in fixed-width sparse form (V, K), K = max influences.
    """
    t, v = wp.tid()
    p = v_shaped[v]
    for i in range(num_pose_basis):
        p = p + posedirs[i, v] * pose_feature[t, i]
    M = wp.mat44(0.0)
    for k in range(weight_idx.shape[1]):
        w = weight_val[v, k]
        if w != 0.0:
            M = M + w * skin[t, weight_idx[v, k]]
    vertices_out[t, v] = wp.transform_point(M, p) + trans[t]
