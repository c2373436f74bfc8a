"""Warp kernels for differentiable linear blend skinning (forward and hand-written adjoint).

Linear blend skinning (Loper et al. 2015, SMPL Eq. 3; Le & Deng 2012, SSDR Eq. 1) of the rest
point ``p_bv`` of vertex ``v`` in sample ``b`` with affine bone transforms ``A_bj = [R_bj | t_bj]``
(3x4, world from rest-pose bone space) and skinning weights ``w_vk`` of influence slot ``k``
(bone ``j = j_vk``)::

    x_bv = sum_k w_vk A_{b j_vk} [p_bv; 1] = M_bv p_bv + m_bv,
    M_bv = sum_k w_vk R_{b j_vk},   m_bv = sum_k w_vk t_{b j_vk}.                        (1)

The function is linear in each of ``p``, ``A`` and ``w``; with ``g_bv = dL/dx_bv`` its adjoint is::

    dL/dp_bv  = M_bv^T g_bv                              (summed over b for shared rest points) (2)
    dL/dw_vk  = sum_b g_bv . (A_{b j_vk} [p_bv; 1])                                             (3)
    dL/dA_bj  = sum_v sum_{k: j_vk = j} w_vk g_bv [p_bv; 1]^T                                   (4)

Weights come in one of two layouts, picked by the ``dense`` flag of each kernel:
``dense != 0``: ``weight_val`` is the dense (V, J) matrix and slot ``k`` is bone ``k``
(``weight_idx`` is ignored, pass a (1, 1) dummy); ``dense == 0``: fixed-width sparse form
``weight_idx`` (V, K) bone indices and ``weight_val`` (V, K) weights
(``sim.skinning.lbs.sparse_weights``). Rest points are per sample (``points_batched != 0``,
shape (B, V)) or shared by every sample (shape (1, V)).

Every reduction is a fixed-order loop in one thread, never an atomic add, so the gradients are
bitwise reproducible run to run on cpu and cuda. Eq. 4 is a scatter over vertices. On cuda it runs
as a two-stage gather: stage 1 (one thread per sample, vertex chunk and bone) sums a chunk of
vertices in registers, stage 2 (one thread per sample and bone) sums the chunk partials. On cpu
(threads of a launch run one after another) one thread per sample scatters into its own row.
Kernel arguments: inputs first, outputs with an ``_out`` suffix (STYLE.md 2). All kernels run on
``cpu`` and ``cuda``; float32 only.
"""

from __future__ import annotations

import warp as wp

mat34 = wp.types.matrix(shape=(3, 4), dtype=wp.float32)
"""Affine bone transform ``[R | t]`` (3x4), float32."""


@wp.func
def _apply(A: mat34, p: wp.vec3) -> wp.vec3:
    """A [p; 1]."""
    return wp.vec3(
        A[0, 0] * p[0] + A[0, 1] * p[1] + A[0, 2] * p[2] + A[0, 3],
        A[1, 0] * p[0] + A[1, 1] * p[1] + A[1, 2] * p[2] + A[1, 3],
        A[2, 0] * p[0] + A[2, 1] * p[1] + A[2, 2] * p[2] + A[2, 3],
    )


@wp.func
def _apply_rot_transpose(A: mat34, g: wp.vec3) -> wp.vec3:
    """R^T g, R the left 3x3 block of A."""
    return wp.vec3(
        A[0, 0] * g[0] + A[1, 0] * g[1] + A[2, 0] * g[2],
        A[0, 1] * g[0] + A[1, 1] * g[1] + A[2, 1] * g[2],
        A[0, 2] * g[0] + A[1, 2] * g[1] + A[2, 2] * g[2],
    )


@wp.func
def _outer_h(g: wp.vec3, p: wp.vec3) -> mat34:
    """g [p; 1]^T (3x4)."""
    return mat34(
        g[0] * p[0], g[0] * p[1], g[0] * p[2], g[0],
        g[1] * p[0], g[1] * p[1], g[1] * p[2], g[1],
        g[2] * p[0], g[2] * p[1], g[2] * p[2], g[2],
    )


@wp.func
def _bone(weight_idx: wp.array2d(dtype=int), dense: int, v: int, k: int) -> int:
    """Bone of influence slot k of vertex v."""
    if dense != 0:
        return k
    return weight_idx[v, k]


@wp.kernel
def lbs_forward_kernel(
    points: wp.array2d(dtype=wp.vec3),
    points_batched: int,
    transforms: wp.array2d(dtype=mat34),
    weight_idx: wp.array2d(dtype=int),
    weight_val: wp.array2d(dtype=float),
    dense: int,
    skinned_out: wp.array2d(dtype=wp.vec3),
):
    """Eq. 1, one thread per (sample b, vertex v).

    points: rest points [m], (B, V) or (1, V); transforms: (B, J) 3x4; weights as in the module
    docstring; skinned_out: (B, V) [m].
    """
    b, v = wp.tid()
    pb = b * points_batched
    M = mat34(0.0)
    for k in range(weight_val.shape[1]):
        w = weight_val[v, k]
        if w != 0.0:
            M = M + w * transforms[b, _bone(weight_idx, dense, v, k)]
    skinned_out[b, v] = _apply(M, points[pb, v])


@wp.kernel
def lbs_backward_points_weights_kernel(
    grad_skinned: wp.array2d(dtype=wp.vec3),
    points: wp.array2d(dtype=wp.vec3),
    points_batched: int,
    transforms: wp.array2d(dtype=mat34),
    weight_idx: wp.array2d(dtype=int),
    weight_val: wp.array2d(dtype=float),
    dense: int,
    compute_points: int,
    compute_weights: int,
    grad_points_out: wp.array2d(dtype=wp.vec3),
    grad_weights_out: wp.array2d(dtype=float),
):
    """Eq. 2 and Eq. 3, one thread per vertex v, looping over the samples in order.

    grad_skinned: dL/dx, (B, V) [1]. grad_points_out: (B, V) when points are batched, else
    (1, V) summed over samples; written only when ``compute_points != 0``. grad_weights_out:
    same shape as ``weight_val``, summed over samples; written only when
    ``compute_weights != 0`` (every slot, zero weights and sparse padding included).
    """
    v = wp.tid()
    num_samples = grad_skinned.shape[0]
    num_slots = weight_val.shape[1]
    if compute_points != 0:
        acc = wp.vec3(0.0)
        for b in range(num_samples):
            g = grad_skinned[b, v]
            gp = wp.vec3(0.0)
            for k in range(num_slots):
                w = weight_val[v, k]
                if w != 0.0:
                    gp = gp + w * _apply_rot_transpose(transforms[b, _bone(weight_idx, dense, v, k)], g)
            if points_batched != 0:
                grad_points_out[b, v] = gp
            else:
                acc = acc + gp
        if points_batched == 0:
            grad_points_out[0, v] = acc
    if compute_weights != 0:
        for k in range(num_slots):
            j = _bone(weight_idx, dense, v, k)
            s = float(0.0)
            for b in range(num_samples):
                s = s + wp.dot(grad_skinned[b, v], _apply(transforms[b, j], points[b * points_batched, v]))
            grad_weights_out[v, k] = s


@wp.kernel
def lbs_backward_transforms_scatter_kernel(
    grad_skinned: wp.array2d(dtype=wp.vec3),
    points: wp.array2d(dtype=wp.vec3),
    points_batched: int,
    weight_idx: wp.array2d(dtype=int),
    weight_val: wp.array2d(dtype=float),
    dense: int,
    grad_transforms_out: wp.array2d(dtype=mat34),
):
    """Eq. 4 as a scatter, one thread per sample b owning row b of the output (no atomics).

    For cpu, where a launch runs its threads one after another: it touches each (vertex, slot)
    once, where the gather below tests every (vertex, slot, bone). grad_transforms_out (B, J) is
    overwritten.
    """
    b = wp.tid()
    pb = b * points_batched
    for j in range(grad_transforms_out.shape[1]):
        grad_transforms_out[b, j] = mat34(0.0)
    for v in range(weight_val.shape[0]):
        G = _outer_h(grad_skinned[b, v], points[pb, v])
        for k in range(weight_val.shape[1]):
            w = weight_val[v, k]
            if w != 0.0:
                j = _bone(weight_idx, dense, v, k)
                grad_transforms_out[b, j] = grad_transforms_out[b, j] + w * G


@wp.kernel
def lbs_backward_transforms_partial_kernel(
    grad_skinned: wp.array2d(dtype=wp.vec3),
    points: wp.array2d(dtype=wp.vec3),
    points_batched: int,
    weight_idx: wp.array2d(dtype=int),
    weight_val: wp.array2d(dtype=float),
    dense: int,
    chunk: int,
    partial_out: wp.array3d(dtype=mat34),
):
    """Eq. 4 stage 1, one thread per (sample b, vertex chunk c, bone j).

    Sums vertices ``c * chunk .. (c + 1) * chunk - 1`` into ``partial_out[b, c, j]`` (B, C, J);
    with a single chunk (C = 1) this is already dL/dA.
    """
    b, c, j = wp.tid()
    num_vertices = weight_val.shape[0]
    pb = b * points_batched
    acc = mat34(0.0)
    v_end = wp.min((c + 1) * chunk, num_vertices)
    for v in range(c * chunk, v_end):
        w = float(0.0)
        if dense != 0:
            w = weight_val[v, j]
        else:
            for k in range(weight_val.shape[1]):
                if weight_idx[v, k] == j:
                    w = w + weight_val[v, k]
        if w != 0.0:
            acc = acc + w * _outer_h(grad_skinned[b, v], points[pb, v])
    partial_out[b, c, j] = acc


@wp.kernel
def lbs_backward_transforms_reduce_kernel(
    partial: wp.array3d(dtype=mat34),
    grad_transforms_out: wp.array2d(dtype=mat34),
):
    """Eq. 4 stage 2, one thread per (sample b, bone j): sum of the C chunk partials, in order."""
    b, j = wp.tid()
    acc = mat34(0.0)
    for c in range(partial.shape[1]):
        acc = acc + partial[b, c, j]
    grad_transforms_out[b, j] = acc
