"""Raw element loads (``sim.cloth.spans.load_*``) against Warp's array indexing."""

from __future__ import annotations

import numpy as np
import warp as wp

from sim.cloth.spans import (
    Span,
    ints,
    load_float,
    load_int,
    load_mat22,
    load_vec2i,
    load_vec3,
    load_vec3i,
    load_vec4i,
    span,
    vec3s,
)


@wp.kernel
def _loads_kernel(a: wp.array(dtype=wp.int32), b: wp.array(dtype=float), c: wp.array(dtype=wp.vec3),
                  d: wp.array(dtype=wp.vec3i), e: wp.array(dtype=wp.vec4i), f: wp.array(dtype=wp.mat22),
                  g: wp.array(dtype=wp.vec2i), sa: Span, sc: Span, order: wp.array(dtype=wp.int32),
                  raw_out: wp.array(dtype=float, ndim=2), ref_out: wp.array(dtype=float, ndim=2)):
    k = wp.tid()
    j = order[k]
    vi = load_vec3i(d, j)
    vq = load_vec4i(e, j)
    m = load_mat22(f, j)
    v = load_vec3(c, j)
    w = load_vec3(vec3s(sc), j)
    raw_out[k, 0] = float(load_int(a, j))
    raw_out[k, 1] = load_float(b, j)
    raw_out[k, 2] = v[0] + 2.0 * v[1] + 4.0 * v[2]
    raw_out[k, 3] = float(vi[0] + 3 * vi[1] + 9 * vi[2])
    raw_out[k, 4] = float(vq[0] + 5 * vq[1] + 25 * vq[2] + 125 * vq[3])
    raw_out[k, 5] = m[0, 0] + 2.0 * m[0, 1] + 4.0 * m[1, 0] + 8.0 * m[1, 1]
    raw_out[k, 6] = float(load_int(ints(sa), j)) + w[2]
    raw_out[k, 7] = float(load_vec2i(g, j)[0] - 7 * load_vec2i(g, j)[1])
    vi = d[j]
    vq = e[j]
    m = f[j]
    v = c[j]
    w = vec3s(sc)[j]
    ref_out[k, 0] = float(a[j])
    ref_out[k, 1] = b[j]
    ref_out[k, 2] = v[0] + 2.0 * v[1] + 4.0 * v[2]
    ref_out[k, 3] = float(vi[0] + 3 * vi[1] + 9 * vi[2])
    ref_out[k, 4] = float(vq[0] + 5 * vq[1] + 25 * vq[2] + 125 * vq[3])
    ref_out[k, 5] = m[0, 0] + 2.0 * m[0, 1] + 4.0 * m[1, 0] + 8.0 * m[1, 1]
    ref_out[k, 6] = float(ints(sa)[j]) + w[2]
    ref_out[k, 7] = float(g[j][0] - 7 * g[j][1])


def test_raw_loads_read_the_element_warp_indexing_reads(device):
    """Every loader returns, at shuffled indices including the first and last element, what
    ``a[i]`` returns (on a plain array argument and on an array rebuilt from a ``Span``)."""
    rng = np.random.default_rng(3)
    n = 37
    arrays = [
        wp.array(rng.integers(-1000, 1000, n).astype(np.int32), dtype=wp.int32, device=device),
        wp.array(rng.normal(size=n).astype(np.float32), dtype=float, device=device),
        wp.array(rng.normal(size=(n, 3)).astype(np.float32), dtype=wp.vec3, device=device),
        wp.array(rng.integers(-9, 9, (n, 3)).astype(np.int32), dtype=wp.vec3i, device=device),
        wp.array(rng.integers(-9, 9, (n, 4)).astype(np.int32), dtype=wp.vec4i, device=device),
        wp.array(rng.normal(size=(n, 2, 2)).astype(np.float32), dtype=wp.mat22, device=device),
        wp.array(rng.integers(-9, 9, (n, 2)).astype(np.int32), dtype=wp.vec2i, device=device),
    ]
    order = wp.array(rng.permutation(n).astype(np.int32), dtype=wp.int32, device=device)
    raw = wp.zeros((n, 8), dtype=float, device=device)
    ref = wp.zeros((n, 8), dtype=float, device=device)
    wp.launch(_loads_kernel, dim=n, inputs=[*arrays, span(arrays[0]), span(arrays[2]), order],
              outputs=[raw, ref], device=device)
    np.testing.assert_array_equal(raw.numpy(), ref.numpy())
    a = arrays[0].numpy()[order.numpy()]
    np.testing.assert_array_equal(raw.numpy()[:, 0], a.astype(np.float32))
    assert len(set(raw.numpy()[:, 4].tolist())) > n // 2  # the loads read different elements
