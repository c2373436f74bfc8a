"""Kernels of the three-level solve: a symmetric two-grid cycle on the coarse system ``A_c x =
rhs`` around an exact solve of the inner level (``CoarseLevel.solve``): l1-Jacobi passes, the
restriction to the inner level with its Galerkin operator ``P2^T A_c P2``, and the inner
solution's prolongation."""

from __future__ import annotations

import warp as wp

# what ``level_pass_kernel`` writes
PASS_FIRST = wp.constant(0)  # an l1-Jacobi pass from x = 0
PASS_SMOOTH = wp.constant(1)  # an l1-Jacobi pass from x
PASS_RESIDUAL = wp.constant(2)  # the residual rhs - A_c x


@wp.func
def level_product(i: int, x: wp.array(dtype=wp.vec3), diag: wp.array(dtype=float),
                  offsets: wp.array(dtype=wp.int32), ids: wp.array(dtype=wp.int32),
                  weights: wp.array(dtype=float)) -> wp.vec3:
    """Row ``i`` of ``A_c x``: ``diag`` (mass, stiffness and contact) times ``x_i`` plus the
    stiffness's off-diagonal row (CSR ``offsets, ids, weights``)."""
    s = diag[i] * x[i]
    for k in range(offsets[i], offsets[i + 1]):
        s = s + weights[k] * x[ids[k]]
    return s


@wp.kernel
def level_pass_kernel(
    x: wp.array(dtype=wp.vec3),
    rhs: wp.array(dtype=wp.vec3),
    diag: wp.array(dtype=float),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    l1: wp.array(dtype=float),
    mode: int,
    x_out: wp.array(dtype=wp.vec3),
):
    """Coarse node ``i`` of the coarse system ``A_c x = rhs``: an l1-Jacobi pass ``x + (rhs - A_c
    x) / (diag + l1)`` (``PASS_SMOOTH``; ``l1`` the off-diagonal's absolute row sum, a convergent
    smoother for any symmetric positive definite matrix), the same from ``x = 0``
    (``PASS_FIRST``, ``x`` not read), or the residual ``rhs - A_c x`` (``PASS_RESIDUAL``)."""
    i = wp.tid()
    if mode == PASS_FIRST:
        x_out[i] = rhs[i] / (diag[i] + l1[i])
    else:
        r = rhs[i] - level_product(i, x, diag, offsets, ids, weights)
        if mode == PASS_RESIDUAL:
            x_out[i] = r
        else:
            x_out[i] = x[i] + r / (diag[i] + l1[i])


@wp.kernel
def restrict_level_kernel(
    res: wp.array(dtype=wp.vec3),
    diag: wp.array(dtype=float),
    node_stiffness: wp.array(dtype=float),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    inner_stiffness: wp.array(dtype=float),
    rhs_out: wp.array(dtype=wp.vec3),
    diag_out: wp.array(dtype=float),
):
    """Inner node ``c``: ``rhs = P2^T res`` and the Galerkin diagonal ``K_2,cc + sum_J P2_Jc^2
    d_J``, ``d = diag - node_stiffness`` the coarse diagonal's mass and contact part
    (``offsets, ids, weights``: ``P2^T`` as CSR)."""
    c = wp.tid()
    s = wp.vec3(0.0)
    dc = float(0.0)
    for k in range(offsets[c], offsets[c + 1]):
        j = ids[k]
        w = weights[k]
        s = s + w * res[j]
        dc = dc + w * w * (diag[j] - node_stiffness[j])
    rhs_out[c] = s
    diag_out[c] = inner_stiffness[c] + dc


@wp.kernel
def galerkin_band_kernel(
    band_k: wp.array(dtype=float),
    diag: wp.array(dtype=float),
    node_stiffness: wp.array(dtype=float),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    band_out: wp.array(dtype=float),
):
    """Slot ``s`` of the inner levels' bands: ``K_2``'s value plus ``sum P2_Ja P2_Jb d_J`` over
    the slot's coarse nodes ``J`` (``operators.galerkin_slots``; ``d = diag - node_stiffness``),
    the off-diagonal of ``P2^T diag(d) P2``."""
    s = wp.tid()
    v = band_k[s]
    for k in range(offsets[s], offsets[s + 1]):
        j = ids[k]
        v = v + weights[k] * (diag[j] - node_stiffness[j])
    band_out[s] = v


@wp.kernel
def prolong_level_kernel(
    dx: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    x_inout: wp.array(dtype=wp.vec3),
):
    """``x += P2 dx`` at coarse node ``i`` (``P2`` as CSR)."""
    i = wp.tid()
    s = wp.vec3(0.0)
    for k in range(offsets[i], offsets[i + 1]):
        s = s + weights[k] * dx[ids[k]]
    x_inout[i] = x_inout[i] + s
