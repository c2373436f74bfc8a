"""UV functions: distortion measures on exact cases, packing charts into the unit square."""

from __future__ import annotations

import numpy as np
import pytest

from sim.garments.uv import pack_uvs, uv_stats


def _grid(n: int, m: int):
    """Faces of an n x m vertex grid (row-major), shape (2 (n-1) (m-1), 3)."""
    f = []
    for i in range(n - 1):
        for j in range(m - 1):
            a = i * m + j
            f += [(a, a + 1, a + m + 1), (a, a + m + 1, a + m)]
    return np.array(f)


def test_uv_stats_exact_on_an_affine_map():
    s, t = np.meshgrid(np.linspace(0, 0.3, 7), np.linspace(0, 0.2, 5))
    v = np.stack([s.ravel(), t.ravel(), np.zeros(s.size)], 1)
    f = _grid(5, 7)
    iso = uv_stats(v, f, v[:, :2] + 0.1, f)
    assert iso.angle_mean == pytest.approx(1.0) and iso.angle_max == pytest.approx(1.0)
    assert iso.area_p5 == pytest.approx(1.0) and iso.area_p95 == pytest.approx(1.0) and iso.flipped == 0
    assert iso.texels_per_metre_256 == pytest.approx(256.0)  # 1 UV unit per metre
    assert iso.fill == pytest.approx(0.06)
    stretched = uv_stats(v, f, v[:, :2] * [2.0, 1.0], f)  # u doubled: σ1/σ2 = 2, areas uniform
    np.testing.assert_allclose([stretched.angle_mean, stretched.angle_p95, stretched.angle_max], 2.0)
    np.testing.assert_allclose([stretched.area_p5, stretched.area_p95], 1.0)
    uv = v[:, :2].copy()
    uv[s.ravel() > 0.15, 0] *= 3.0  # right part stretched: area ratio differs between parts
    uneven = uv_stats(v, f, uv, f)
    assert uneven.area_p95 / uneven.area_p5 > 2.0
    flip = v[:, :2].copy()
    flip[f[0, 0]] = [0.2, 0.2]  # folds the first triangle over its neighbours
    assert uv_stats(v, f, flip, f).flipped >= 1


def test_pack_keeps_one_scale_margins_and_no_box_overlap():
    rng = np.random.default_rng(3)
    sizes = rng.uniform(0.05, 1.0, size=(7, 2))
    uvs, panel = [], []
    for i, (w, h) in enumerate(sizes):
        pts = rng.uniform(0, 1, size=(30, 2)) * [w, h] - 5.0 + i
        pts[:2] = [[-5.0 + i, -5.0 + i], [w - 5.0 + i, h - 5.0 + i]]  # the box's corners
        uvs.append(pts)
        panel.append(np.full(30, i))
    uvs, panel = np.concatenate(uvs), np.concatenate(panel)
    out = pack_uvs(uvs, panel, margin=0.02).astype(np.float64)
    assert out.min() >= 0.02 - 1e-6 and out.max() <= 0.98 + 1e-6
    scale = [np.ptp(out[panel == i], axis=0) / sizes[i] for i in range(7)]
    np.testing.assert_allclose(np.concatenate(scale), scale[0][0], rtol=1e-5)  # one common scale
    lo = np.array([out[panel == i].min(0) for i in range(7)])
    hi = np.array([out[panel == i].max(0) for i in range(7)])
    for i in range(7):
        for j in range(i + 1, 7):
            assert np.maximum(lo[j] - hi[i], lo[i] - hi[j]).max() >= 0.02 - 1e-6
    # the square is used well: the boxes fill a fair share of it
    assert (sizes.prod(1).sum() * scale[0][0] ** 2) > 0.45
