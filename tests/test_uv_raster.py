"""UV-image rasterisation and sample-back: pixel convention, exact answers on linear fields and
per-face constants, coverage area, convergence with resolution, seams, determinism, errors."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.geometry.uv_raster import UVRasterizer, lift_to_uvs, uv_coverage, uv_to_vertex


@pytest.fixture(scope="module")
def garment():
    """A coarse t-shirt on the default body: 2.9k vertices, 3.0k UV vertices, 4 panels."""
    from sim.bodies import load_body
    from sim.garments import make_garment

    return make_garment("t_shirt", load_body())


def _smooth(uv: np.ndarray) -> np.ndarray:
    """A smooth field of UV position, (U, 1)."""
    u, v = uv[:, 0].astype(np.float64), uv[:, 1].astype(np.float64)
    return (np.sin(3 * u) * np.cos(2 * v) + 0.5 * u - v)[:, None].astype(np.float32)


def _linear(uv: np.ndarray) -> np.ndarray:
    """Two linear fields of UV position, (U, 2)."""
    u, v = uv[:, 0].astype(np.float64), uv[:, 1].astype(np.float64)
    return np.stack([0.5 * u - v + 0.25, 2.0 * v + 1.0], 1).astype(np.float32)


def _boundary_uvs(uv_faces: np.ndarray, num_uvs: int) -> np.ndarray:
    e = np.sort(uv_faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, count = np.unique(e, axis=0, return_counts=True)
    out = np.zeros(num_uvs, bool)
    out[edges[count == 1].ravel()] = True
    return out


def test_pixel_convention_row0_is_the_top(device):
    # one triangle in the top-left corner of the square: (u, v) = (0, 1), (0.3, 1), (0, 0.7)
    uvs = np.array([[0.0, 1.0], [0.3, 1.0], [0.0, 0.7]], np.float32)
    r = UVRasterizer(uvs, np.array([[0, 1, 2]]), (8, 16), dilate=0.0, device=device)
    assert r.resolution == (8, 16)
    m = r.mask
    assert m[0, 0] and not m[0, -1] and not m[-1, 0] and not m[-1, -1]
    rows, cols = np.nonzero(m)
    assert rows.max() < 3 and cols.max() < 5  # v >= 0.7 is the top 2.4 rows, u <= 0.3 the left 4.8 cols
    np.testing.assert_array_equal(r.coverage.valid, m)  # no rim without dilation
    img = r.rasterize(uvs)  # the (u, v) field itself: every pixel shows its centre's coordinates
    assert img.shape == (8, 16, 2)
    centre_u = (cols + 0.5) / 16
    centre_v = 1.0 - (rows + 0.5) / 8
    np.testing.assert_allclose(img[rows, cols], np.stack([centre_u, centre_v], 1), atol=1e-6)
    np.testing.assert_array_equal(img[~m], 0.0)


def test_linear_fields_are_exact_inside_the_rim_and_sampled_back(device, garment):
    r = UVRasterizer.from_garment(garment, 256, device=device)
    lin = _linear(garment.uvs)
    img = r.rasterize(lin)
    # every valid pixel, rim included, shows the linear field at its centre (linear extrapolation)
    H, W = r.resolution
    rows, cols = np.nonzero(r.coverage.valid)
    uv_px = np.stack([(cols + 0.5) / W, 1.0 - (rows + 0.5) / H], 1)
    np.testing.assert_allclose(img[rows, cols], _linear(uv_px), atol=2e-5)
    assert r.coverage.valid.sum() > r.mask.sum() + 1000  # the rim is there
    # so bilinear sampling back is exact at every UV vertex, chart boundaries included
    np.testing.assert_allclose(r.sample(img), lin, atol=2e-5)


def test_smooth_field_sample_back_converges_with_resolution(device, garment):
    f = _smooth(garment.uvs)
    boundary = _boundary_uvs(garment.uv_faces, len(garment.uvs))
    err = {}
    for res in (256, 512):
        r = UVRasterizer.from_garment(garment, res, device=device)
        e = np.abs(r.sample(r.rasterize(f)) - f)[:, 0]
        err[res] = e.max()
        assert e[boundary].max() < 2.0 * e[~boundary].max()  # seams and hems as good as inside
    assert err[256] < 5e-4  # measured 1.6e-4
    assert err[512] < 0.7 * err[256]  # first order in the pixel size: measured 8.0e-5
    # a clamped rim (constant outward) still converges, but boundary vertices are worse
    r = UVRasterizer.from_garment(garment, 256, extrapolate=False, device=device)
    e = np.abs(r.sample(r.rasterize(f)) - f)[:, 0]
    assert err[256] < e[boundary].max() < 1e-2


@pytest.mark.parametrize("dilate", [0.0, 2.0])
def test_sampling_takes_no_taps_from_empty_pixels_or_other_charts(device, dilate):
    # two squares (two triangles each) 0.5 px apart at 32², each with its own constant
    x0, gap = 4.3 / 32, 0.5 / 32
    a = np.array([[x0, 0.2], [0.5, 0.2], [0.5, 0.8], [x0, 0.8]])
    b = a + [0.5 - x0 + gap, 0.0]
    uvs = np.concatenate([a, b]).astype(np.float32)
    uv_faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    r = UVRasterizer(uvs, uv_faces, 32, dilate=dilate, device=device)
    vals = np.repeat([[1.0], [100.0]], 4, axis=0).astype(np.float32)
    img = r.rasterize(vals)
    levels = np.array([0.0, 1.0, 100.0])
    np.testing.assert_allclose(levels[np.abs(img[..., None] - levels).argmin(-1)], img, rtol=1e-6)
    np.testing.assert_allclose(r.sample(img), vals, rtol=1e-6)  # bilinear taps of the own chart only


def test_per_face_constants_fill_their_triangles_exactly(device, garment):
    rng = np.random.default_rng(1)
    vals = rng.normal(size=(2, garment.num_faces, 3)).astype(np.float32)
    r = UVRasterizer.from_garment(garment, 256, device=device)
    img = r.rasterize(vals, per="face")
    face, valid = r.coverage.face, r.coverage.valid
    assert img.shape == (2, 256, 256, 3)
    np.testing.assert_array_equal(img[:, valid], vals[:, face[valid]])
    np.testing.assert_array_equal(img[:, ~valid], 0.0)
    # and the covering triangle really contains the pixel centre (barycentrics in [0, 1])
    b = r.coverage.barycentrics[r.mask]
    assert b.min() > -1e-5 and b.max() < 1 + 1e-5
    np.testing.assert_allclose(b.sum(axis=1), 1.0, atol=1e-5)


@pytest.mark.parametrize("res", [256, 1024])
def test_mask_area_matches_the_uv_triangles(device, garment, res):
    uv = garment.uvs.astype(np.float64)
    t = uv[garment.uv_faces]
    area = 0.5 * np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                        - (t[:, 1, 1] - t[:, 0, 1]) * (t[:, 2, 0] - t[:, 0, 0])).sum()
    boundary = _boundary_uvs(garment.uv_faces, len(uv))
    e = np.sort(garment.uv_faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, count = np.unique(e, axis=0, return_counts=True)
    perimeter = np.linalg.norm(np.diff(uv[edges[count == 1]], axis=1), axis=2).sum()
    assert boundary.sum() > 100
    cov = uv_coverage(garment.uvs, garment.uv_faces, res, device=device)
    mask_area = cov.mask.sum() / res**2
    # the flat pattern's straight hems and sides run along pixel rows and columns, where a row
    # of pixel centres on the outline is all in or all out: below half a pixel x perimeter
    # (measured 0.12 of it at 1024); a dilated mask would be ~2 px x perimeter too large
    assert abs(mask_area - area) < 0.5 * perimeter / res
    assert np.all(cov.valid[cov.mask])
    assert (cov.valid.sum() - cov.mask.sum()) / res**2 > perimeter / res  # rim ~2 px wide
    charts = cov.chart[cov.valid]
    assert charts.min() == 0 and charts.max() == len(garment.panel_names) - 1


def test_sample_vertices_is_single_valued_across_seams(device, garment):
    g = garment
    m = uv_to_vertex(g.faces, g.uv_faces, len(g.uvs))
    copies = np.bincount(m, minlength=g.num_vertices)
    seam = np.flatnonzero(copies >= 2)
    assert len(seam) > 50
    r = UVRasterizer.from_garment(g, 256, device=device)
    # an arbitrary image (a network's output, say): the UV copies of a seam vertex disagree ...
    rng = np.random.default_rng(2)
    img = rng.normal(size=(3, 256, 256, 2)).astype(np.float32)
    per_uv = r.sample(img)
    per_v = r.sample_vertices(img, g.faces)
    assert per_v.shape == (3, g.num_vertices, 2)
    lifted = lift_to_uvs(per_v, g.faces, g.uv_faces, len(g.uvs))
    assert np.abs(per_uv - lifted)[:, np.isin(m, seam)].max() > 0.1
    # ... sample_vertices takes their mean, so every copy of a vertex maps to one value
    mean = np.zeros((3, g.num_vertices, 2))
    np.add.at(mean, (slice(None), m), per_uv)
    np.testing.assert_allclose(per_v, mean / copies[:, None], atol=1e-5)
    # a field of the 3D rest position (values in [-1, 2]) round-trips to the vertices
    x = g.rest_vertices.astype(np.float64)
    f = np.stack([np.sin(4 * x[:, 0]) + x[:, 1] ** 2, np.cos(3 * x[:, 2])], 1).astype(np.float32)
    back = r.sample_vertices(r.rasterize_vertices(f, g.faces), g.faces)
    np.testing.assert_allclose(back, f, atol=1e-2)  # measured max 6.6e-3 on 21 of 5,818 values


def test_batched_frames_match_single_frames_and_runs_are_byte_identical(device, garment):
    rng = np.random.default_rng(3)
    vals = rng.normal(size=(2, 3, len(garment.uvs), 2)).astype(np.float32)
    runs = []
    for _ in range(2):
        r = UVRasterizer.from_garment(garment, 128, device=device)
        img = r.rasterize(vals)
        runs.append((r.coverage.face, r.coverage.barycentrics, img, r.sample(img),
                     r.sample_vertices(img, garment.faces)))
    for a, b in zip(*runs, strict=True):
        assert a.tobytes() == b.tobytes()
    img = runs[0][2]
    assert img.shape == (2, 3, 128, 128, 2)
    np.testing.assert_array_equal(img[1, 2], r.rasterize(vals[1, 2]))
    np.testing.assert_array_equal(runs[0][3][0, 1], r.sample(img[0, 1]))


def test_lift_to_uvs_copies_each_vertex_value(garment):
    g = garment
    vals = np.arange(g.num_vertices * 2, dtype=np.float32).reshape(-1, 2)
    lifted = lift_to_uvs(vals, g.faces, g.uv_faces, len(g.uvs))
    np.testing.assert_array_equal(lifted[g.uv_faces], vals[g.faces])


def test_bad_inputs_raise(garment):
    g = garment
    uvs, uf = g.uvs, g.uv_faces
    r = UVRasterizer.from_garment(g, 32, device="cpu")
    bad = [
        lambda: UVRasterizer(np.zeros((5, 3)), uf[:1]),
        lambda: UVRasterizer(uvs, uf.astype(np.float32)),
        lambda: UVRasterizer(uvs, uf + len(uvs)),
        lambda: UVRasterizer(np.full((3, 2), np.nan), [[0, 1, 2]]),
        lambda: UVRasterizer(uvs, uf, 0),
        lambda: UVRasterizer(uvs, uf, (16, 16, 3)),
        lambda: UVRasterizer(uvs, uf, "256"),
        lambda: UVRasterizer(uvs, uf, 32, dilate=-1.0),
        lambda: r.rasterize(np.zeros((len(uvs) + 1, 3))),
        lambda: r.rasterize(np.zeros(len(uvs))),
        lambda: r.rasterize(np.zeros((len(uvs), 3)), per="vertex"),
        lambda: r.rasterize(np.zeros((len(uvs), 3)), per="face"),
        lambda: r.sample(np.zeros((32, 31, 3))),
        lambda: r.sample(np.zeros((32, 32))),
        lambda: r.sample_vertices(np.zeros((32, 32, 1)), g.faces[:, :2]),
        lambda: r.rasterize_vertices(np.zeros((g.num_vertices - 1, 1)), g.faces),
        lambda: uv_to_vertex([[0, 1, 2], [3, 1, 2]], [[0, 1, 2], [0, 1, 2]], 3),  # UV 0 -> vertices 0 and 3
    ]
    for i, call in enumerate(bad):
        with pytest.raises(WrinklesInputError):
            call()
            pytest.fail(f"case {i} did not raise")
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    ambiguous = UVRasterizer(square[:3], [[0, 1, 2]] * 3, 8, device="cpu")  # U == F == 3
    with pytest.raises(WrinklesInputError, match="per="):
        ambiguous.rasterize(np.zeros((3, 1)))
    assert ambiguous.rasterize(np.ones((3, 1)), per="face").shape == (8, 8, 1)
