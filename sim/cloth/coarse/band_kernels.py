"""The banded Cholesky solve of each instance's exactly solved coarse system, one thread per
instance: the CPU's solve, and the CUDA fallback for a band too large for a thread block's shared
memory (``sim.cloth.coarse.block`` solves the rest on CUDA)."""

from __future__ import annotations

import warp as wp


@wp.kernel
def band_solve_kernel(
    rhs: wp.array(dtype=wp.vec3),
    diag: wp.array(dtype=float),
    inst_start: wp.array(dtype=wp.int32),
    inst_count: wp.array(dtype=wp.int32),
    inst_width: wp.array(dtype=wp.int32),
    inst_band: wp.array(dtype=wp.int64),
    order: wp.array(dtype=wp.int32),
    band_k: wp.array(dtype=float),
    band_out: wp.array(dtype=float),
    y_out: wp.array(dtype=wp.vec3),
    dx_out: wp.array(dtype=wp.vec3),
):
    """Solve one instance's coarse system ``A dx = rhs`` exactly (one thread per instance):
    assemble the lower band of ``A`` in ``band_out`` (``band_k``'s off-diagonal band, ``diag`` on
    the diagonal, which holds ``K_c``'s own diagonal), factor it in place (banded Cholesky,
    ``L[r, t] = L_{r, r-t}``), then forward and back substitution through ``y_out``; rows are in
    the template's RCM order (``order``: row -> node)."""
    k = wp.tid()
    start = inst_start[k]
    n = inst_count[k]
    b = inst_width[k]
    w = wp.int64(b + 1)
    base = inst_band[k]
    for r in range(n):
        row = base + wp.int64(r) * w
        band_out[row] = diag[start + order[start + r]]
        for t in range(1, b + 1):
            band_out[row + wp.int64(t)] = band_k[row + wp.int64(t)]
    # factor: column j, then the rows i = j + 1 .. j + b below it
    for j in range(n):
        rj = base + wp.int64(j) * w
        s = band_out[rj]
        for t in range(1, wp.min(b, j) + 1):
            v = band_out[rj + wp.int64(t)]
            s = s - v * v
        d = wp.sqrt(wp.max(s, 1.0e-30))
        band_out[rj] = d
        for i in range(j + 1, wp.min(n, j + b + 1)):
            ri = base + wp.int64(i) * w
            ti = i - j
            s = band_out[ri + wp.int64(ti)]
            # sum over columns c < j inside both rows' bands: c >= i - b
            for c in range(wp.max(0, i - b), j):
                s = s - band_out[ri + wp.int64(i - c)] * band_out[rj + wp.int64(j - c)]
            band_out[ri + wp.int64(ti)] = s / d
    # L y = rhs
    for r in range(n):
        rr = base + wp.int64(r) * w
        u = rhs[start + order[start + r]]
        for t in range(1, wp.min(b, r) + 1):
            u = u - band_out[rr + wp.int64(t)] * y_out[start + r - t]
        y_out[start + r] = u / band_out[rr]
    # L^T x = y (x kept in y, last row first)
    for q in range(n):
        r = n - 1 - q
        u = y_out[start + r]
        for t in range(1, wp.min(b, n - 1 - r) + 1):
            u = u - band_out[base + wp.int64(r + t) * w + wp.int64(t)] * y_out[start + r + t]
        y_out[start + r] = u / band_out[base + wp.int64(r) * w]
        dx_out[start + order[start + r]] = y_out[start + r]
