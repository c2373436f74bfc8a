"""Warp kernels for per-frame surface geometry (see ``sim/geometry/strain.py`` and ``frames.py``).

Kernel arguments: inputs first, outputs with an ``_out`` suffix. Per-vertex sums gather over
CSR incidence lists built once on the host (no atomics), so results are deterministic on every
device.
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def green_lagrange_kernel(
    x: wp.array2d(dtype=wp.vec3),
    faces: wp.array2d(dtype=int),
    dm_inv: wp.array(dtype=wp.mat22),
    strain_out: wp.array2d(dtype=wp.vec3),
    norm_out: wp.array2d(dtype=float),
):
    """Green-Lagrange strain of each face in each frame (Guo et al. 2024, Eq. 3).

    F = Ds Dm⁻¹ (3×2): Ds = [x1 − x0, x2 − x0] deformed edges, Dm the rest edges in the
    face's 2D orthonormal frame; E = ½ (FᵀF − I). x: (T, V); out: (E11, E22, E12) and ‖E‖_F,
    (T, F).
    """
    t, f = wp.tid()
    x0 = x[t, faces[f, 0]]
    e1 = x[t, faces[f, 1]] - x0
    e2 = x[t, faces[f, 2]] - x0
    D = dm_inv[f]
    f1 = e1 * D[0, 0] + e2 * D[1, 0]  # columns of F
    f2 = e1 * D[0, 1] + e2 * D[1, 1]
    e11 = 0.5 * (wp.dot(f1, f1) - 1.0)
    e22 = 0.5 * (wp.dot(f2, f2) - 1.0)
    e12 = 0.5 * wp.dot(f1, f2)
    strain_out[t, f] = wp.vec3(e11, e22, e12)
    norm_out[t, f] = wp.sqrt(e11 * e11 + e22 * e22 + 2.0 * e12 * e12)


@wp.kernel
def csr_mean_vec3_kernel(
    values: wp.array2d(dtype=wp.vec3),
    offsets: wp.array(dtype=int),
    index: wp.array(dtype=int),
    weight: wp.array(dtype=float),
    mean_out: wp.array2d(dtype=wp.vec3),
):
    """Weighted sum over a CSR list (weights normalised on the host): values (T, N) ->
    out (T, M), out[t, i] = Σ_k weight[k] values[t, index[k]], k in offsets[i]:offsets[i+1]."""
    t, i = wp.tid()
    acc = wp.vec3(0.0)
    for k in range(offsets[i], offsets[i + 1]):
        acc += weight[k] * values[t, index[k]]
    mean_out[t, i] = acc


@wp.kernel
def csr_mean_float_kernel(
    values: wp.array2d(dtype=float),
    offsets: wp.array(dtype=int),
    index: wp.array(dtype=int),
    weight: wp.array(dtype=float),
    mean_out: wp.array2d(dtype=float),
):
    """Scalar version of :func:`csr_mean_vec3_kernel`."""
    t, i = wp.tid()
    acc = float(0.0)
    for k in range(offsets[i], offsets[i + 1]):
        acc += weight[k] * values[t, index[k]]
    mean_out[t, i] = acc


@wp.kernel
def vertex_normals_kernel(
    x: wp.array2d(dtype=wp.vec3),
    faces: wp.array2d(dtype=int),
    v_offsets: wp.array(dtype=int),
    v_faces: wp.array(dtype=int),
    normals_out: wp.array2d(dtype=wp.vec3),
):
    """Unit area-weighted vertex normals, (T, V): Σ (x1 − x0) × (x2 − x0) over the faces of the
    vertex, normalised; zero where the incident faces cancel."""
    t, v = wp.tid()
    n = wp.vec3(0.0)
    for k in range(v_offsets[v], v_offsets[v + 1]):
        f = v_faces[k]
        x0 = x[t, faces[f, 0]]
        n += wp.cross(x[t, faces[f, 1]] - x0, x[t, faces[f, 2]] - x0)
    ln = wp.length(n)
    if ln > 0.0:
        n = n / ln
    normals_out[t, v] = n


@wp.func
def orthonormal_frame(t1: wp.vec3, t2: wp.vec3, n: wp.vec3) -> wp.mat33:
    """Fallback frame [e1, e2, n] for a degenerate one: n unit, e1 the part of t1 (else t2,
    else any direction) orthogonal to n, e2 = ±n × e1 on the side of t2."""
    a = t1 - wp.dot(t1, n) * n
    if wp.length(a) < 1.0e-6:
        a = t2 - wp.dot(t2, n) * n
    if wp.length(a) < 1.0e-6:  # no usable tangent: any direction orthogonal to n
        a = wp.cross(n, wp.vec3(1.0, 0.0, 0.0))
        if wp.length(a) < 0.5:
            a = wp.cross(n, wp.vec3(0.0, 1.0, 0.0))
    e1 = wp.normalize(a)
    e2 = wp.cross(n, e1)
    if wp.dot(e2, t2) < 0.0:
        e2 = -e2
    return wp.matrix_from_cols(e1, e2, n)


@wp.func
def base_frame(
    x: wp.array2d(dtype=wp.vec3),
    t: int,
    u: int,
    faces: wp.array2d(dtype=int),
    uv_vertex: wp.array(dtype=int),
    uv_offsets: wp.array(dtype=int),
    uv_faces: wp.array(dtype=int),
    uv_weight: wp.array(dtype=float),
    grad_inv: wp.array(dtype=wp.mat22),
    min_tangent: float,
    min_volume: float,
) -> wp.mat33:
    """Local frame [∂f_b/∂u1, ∂f_b/∂u2, n̂_b] (columns) at UV vertex u (Guo et al. 2024, Eq. 2).

    Over the faces of this UV vertex (its own chart): tangents, the per-face gradient of the
    base positions with respect to UV, Ds Q⁻¹ with Q = [q1 − q0, q2 − q0] (``grad_inv`` holds
    Q⁻¹ / scale), averaged with UV-area weights; normal, the unit area-weighted face normal. A
    frame with a tangent shorter than ``min_tangent`` or with |det| < ``min_volume`` |t1| |t2|
    is replaced by :func:`orthonormal_frame`.
    """
    if uv_vertex[u] < 0:  # a UV vertex no face uses
        return wp.identity(n=3, dtype=float)
    t1 = wp.vec3(0.0)
    t2 = wp.vec3(0.0)
    n = wp.vec3(0.0)
    for k in range(uv_offsets[u], uv_offsets[u + 1]):
        f = uv_faces[k]
        x0 = x[t, faces[f, 0]]
        e1 = x[t, faces[f, 1]] - x0
        e2 = x[t, faces[f, 2]] - x0
        Q = grad_inv[f]
        w = uv_weight[k]
        t1 += w * (e1 * Q[0, 0] + e2 * Q[1, 0])
        t2 += w * (e1 * Q[0, 1] + e2 * Q[1, 1])
        n += wp.cross(e1, e2)
    if wp.length(n) <= 0.0:
        n = wp.cross(t1, t2)
    if wp.length(n) <= 0.0:
        n = wp.vec3(0.0, 0.0, 1.0)
    n = wp.normalize(n)
    l1 = wp.length(t1)
    l2 = wp.length(t2)
    frame = wp.matrix_from_cols(t1, t2, n)
    if l1 < min_tangent or l2 < min_tangent or wp.abs(wp.determinant(frame)) < min_volume * l1 * l2:
        frame = orthonormal_frame(t1, t2, n)
    return frame


@wp.kernel
def uv_frames_kernel(
    x: wp.array2d(dtype=wp.vec3),
    faces: wp.array2d(dtype=int),
    uv_vertex: wp.array(dtype=int),
    uv_offsets: wp.array(dtype=int),
    uv_faces: wp.array(dtype=int),
    uv_weight: wp.array(dtype=float),
    grad_inv: wp.array(dtype=wp.mat22),
    min_tangent: float,
    min_volume: float,
    frames_out: wp.array2d(dtype=wp.mat33),
):
    """Local frame of every UV vertex in every frame (T, U), see :func:`base_frame`."""
    t, u = wp.tid()
    frames_out[t, u] = base_frame(x, t, u, faces, uv_vertex, uv_offsets, uv_faces, uv_weight, grad_inv,
                                  min_tangent, min_volume)


@wp.kernel
def encode_wrinkles_kernel(
    fine: wp.array2d(dtype=wp.vec3),
    base: wp.array2d(dtype=wp.vec3),
    faces: wp.array2d(dtype=int),
    uv_vertex: wp.array(dtype=int),
    uv_offsets: wp.array(dtype=int),
    uv_faces: wp.array(dtype=int),
    uv_weight: wp.array(dtype=float),
    grad_inv: wp.array(dtype=wp.mat22),
    min_tangent: float,
    min_volume: float,
    w_out: wp.array2d(dtype=wp.vec3),
):
    """Wrinkle field w̃ at every UV vertex: solve [t1 t2 n̂] w̃ = fine − base of its 3D vertex
    (inverse of Guo et al. 2024, Eq. 2). (T, V) in, (T, U) out."""
    t, u = wp.tid()
    v = uv_vertex[u]
    if v < 0:
        w_out[t, u] = wp.vec3(0.0)
        return
    A = base_frame(base, t, u, faces, uv_vertex, uv_offsets, uv_faces, uv_weight, grad_inv,
                   min_tangent, min_volume)
    w_out[t, u] = wp.inverse(A) * (fine[t, v] - base[t, v])


@wp.kernel
def decode_wrinkles_kernel(
    w: wp.array2d(dtype=wp.vec3),
    base: wp.array2d(dtype=wp.vec3),
    faces: wp.array2d(dtype=int),
    uv_vertex: wp.array(dtype=int),
    uv_offsets: wp.array(dtype=int),
    uv_faces: wp.array(dtype=int),
    uv_weight: wp.array(dtype=float),
    grad_inv: wp.array(dtype=wp.mat22),
    min_tangent: float,
    min_volume: float,
    displacement_out: wp.array2d(dtype=wp.vec3),
):
    """Displacement w̃1 t1 + w̃2 t2 + w̃3 n̂ at every UV vertex (Guo et al. 2024, Eq. 2), (T, U)."""
    t, u = wp.tid()
    A = base_frame(base, t, u, faces, uv_vertex, uv_offsets, uv_faces, uv_weight, grad_inv,
                   min_tangent, min_volume)
    displacement_out[t, u] = A * w[t, u]
