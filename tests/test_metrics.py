"""Metrics (learn/metrics): every metric on exact cases, on cpu and cuda (torch)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from learn import metrics as M

CUBE_VERTICES = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)],
                         np.float32)
CUBE_FACES = np.array([[1, 3, 0], [4, 1, 0], [0, 3, 2], [2, 4, 0], [1, 7, 3], [5, 1, 4], [5, 7, 1],
                       [3, 7, 2], [6, 4, 2], [2, 7, 6], [6, 5, 4], [7, 5, 6]], np.int32)  # outward


@pytest.fixture(params=["cpu", "cuda"])
def tdev(request) -> str:
    """Torch device: cpu, and cuda where torch sees one."""
    if request.param == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device for torch here")
    return request.param


def _t(x, dev):
    return torch.as_tensor(np.asarray(x), dtype=torch.float64, device=dev)


def grid_mesh(n: int = 3, size: float = 1.0):
    """(n+1)² vertices in the z=0 plane, 2n² counter-clockwise triangles (normals +z)."""
    g = np.linspace(0.0, size, n + 1)
    xx, yy = np.meshgrid(g, g, indexing="xy")
    v = np.stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)], 1)
    f = []
    for r in range(n):
        for c in range(n):
            i = r * (n + 1) + c
            f += [[i, i + 1, i + n + 2], [i, i + n + 2, i + n + 1]]
    return v, np.asarray(f, np.int32)


def hinge(phi: float) -> np.ndarray:
    """Two unit-height triangles on the edge v0-v1 (x axis), the second folded by ``phi`` out of plane.

    Faces [[0, 1, 2], [1, 0, 3]]: normals (0, 0, 1) and (0, sin phi, cos phi).
    """
    return np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -math.cos(phi), math.sin(phi)]])


HINGE_FACES = np.array([[0, 1, 2], [1, 0, 3]], np.int32)


# ---------------------------------------------------------------- Ev, Ecd


def test_vertex_error_translation_and_per_vertex(tdev):
    v, _ = grid_mesh(4)
    t = np.array([0.03, -0.04, 0.12])  # |t| = 0.13
    np.testing.assert_allclose(M.vertex_error(_t(v + t, tdev), _t(v, tdev)).cpu(), 0.13, rtol=1e-12)
    d = np.zeros_like(v)
    d[:, 2] = np.arange(len(v))  # distances 0, 1, 2, ...
    batch = np.stack([v + d, v + t])
    got = M.vertex_error(_t(batch, tdev), _t(v, tdev))
    assert got.shape == (2,) and got.dtype == torch.float64
    np.testing.assert_allclose(got.cpu(), [np.arange(len(v)).mean(), 0.13], rtol=1e-12)
    np.testing.assert_allclose(M.vertex_error(v.astype(np.float32), v + t).item(), 0.13, rtol=1e-6)
    with pytest.raises(ValueError):
        M.vertex_error(v[:-1], v)


@pytest.mark.parametrize("method", ["kdtree", "blocked"])
def test_chamfer_exact_cases(tdev, method):
    if method == "kdtree" and tdev != "cpu":
        pytest.skip("kdtree runs on the cpu")
    v, _ = grid_mesh(4)  # spacing 0.25
    cd = lambda a, b: M.chamfer_distance(_t(a, tdev), _t(b, tdev), method=method).item()  # noqa: E731
    assert cd(v, v) == 0.0
    t = np.array([0.05, 0.02, 0.0])  # < half the spacing: every nearest neighbour is the partner
    np.testing.assert_allclose(cd(v, v + t), 2 * (t ** 2).sum(), rtol=1e-12)
    # asymmetric: A -> B all zero, B -> A mean(0, 1)
    A = np.zeros((1, 3))
    B = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    np.testing.assert_allclose(cd(A, B), 0.5, rtol=1e-12)
    np.testing.assert_allclose(cd(B, A), 0.5, rtol=1e-12)
    A2 = np.array([[0.0, 0, 0], [3.0, 0, 0]])
    B2 = np.array([[1.0, 0, 0]])
    np.testing.assert_allclose(cd(A2, B2), (1 + 4) / 2 + 1, rtol=1e-12)
    # 1 mm shift of a cloud 1 km from the origin: no cancellation loss
    np.testing.assert_allclose(cd(v + 1000.0, v + 1000.0 + [0.001, 0, 0]), 2e-6, rtol=1e-9)


def test_chamfer_chunked_equals_unchunked_and_brute_force(tdev):
    rng = np.random.default_rng(1)
    a = _t(rng.random((2, 300, 3)), tdev)
    b = _t(rng.random((2, 410, 3)) * 1.3, tdev)
    d = torch.cdist(a, b) ** 2
    ref = d.min(-1).values.mean(-1) + d.min(-2).values.mean(-1)
    whole = M.chamfer_distance(a, b, method="blocked")
    assert whole.shape == (2,)
    for chunk in (13, 64, 299):
        np.testing.assert_allclose(M.chamfer_distance(a, b, chunk=chunk, method="blocked").cpu(),
                                   whole.cpu(), rtol=1e-14)
    np.testing.assert_allclose(whole.cpu(), ref.cpu(), rtol=1e-12)
    np.testing.assert_allclose(M.chamfer_distance(a.cpu(), b.cpu()), ref.cpu(), rtol=1e-12)  # kdtree


# ---------------------------------------------------------------- edges


def test_edges_helpers():
    v, f = grid_mesh(3)
    e = M.mesh_edges(f)
    assert e.shape == (3 * 9 + 2 * 3, 2) and (e[:, 0] < e[:, 1]).all()
    np.testing.assert_allclose(M.edge_lengths(v, e).min().item(), 1 / 3, rtol=1e-12)
    np.testing.assert_allclose(M.edge_lengths(v, e).max().item(), math.sqrt(2) / 3, rtol=1e-12)


@pytest.mark.parametrize("s", [1.25, 0.8])
def test_edge_elongation_uniform_scale(tdev, s):
    v, f = grid_mesh(3)
    e = M.mesh_edges(f)
    st = M.edge_elongation(_t(v * s, tdev), _t(v, tdev), e)
    np.testing.assert_allclose(st.elongation_mean.item(), max(s - 1, 0), atol=1e-14)
    np.testing.assert_allclose(st.compression_mean.item(), max(1 - s, 0), atol=1e-14)
    np.testing.assert_allclose(st.abs_mean.item(), abs(s - 1), rtol=1e-12)
    np.testing.assert_allclose(st.max_abs.item(), abs(s - 1), rtol=1e-12)
    l0 = M.edge_lengths(v, e).mean().item()
    np.testing.assert_allclose(st.abs_length_mean.item(), abs(s - 1) * l0, rtol=1e-12)


def test_edge_elongation_mixed_and_batched(tdev):
    rest = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    e = M.mesh_edges([[0, 1, 2]])  # (0,1) (0,2) (1,2)
    x = rest * [1.5, 0.5, 1.0]  # r = 1.5, 0.5, sqrt(1.5² + .5²)/sqrt(2)
    r = np.array([1.5, 0.5, math.sqrt(2.5) / math.sqrt(2)])
    st = M.edge_elongation(_t(np.stack([x, rest]), tdev), _t(rest, tdev), e)
    np.testing.assert_allclose(st.elongation_mean.cpu(), [np.clip(r - 1, 0, None).mean(), 0], atol=1e-14)
    np.testing.assert_allclose(st.compression_mean.cpu(), [np.clip(1 - r, 0, None).mean(), 0], atol=1e-14)
    np.testing.assert_allclose(st.abs_mean.cpu(), [np.abs(r - 1).mean(), 0], atol=1e-14)
    np.testing.assert_allclose(st.max_abs.cpu(), [0.5, 0], atol=1e-14)


# ---------------------------------------------------------------- bending


def test_face_normals_and_interior_edges():
    v, f = grid_mesh(3)
    np.testing.assert_allclose(M.face_normals(v, f).numpy(), np.tile([0.0, 0, 1], (len(f), 1)), atol=1e-15)
    p = M.interior_edges(f)
    assert p.shape == (3 * 9 - 2 * 3, 2)  # 3n² - 2n interior edges of an n x n split-quad grid
    assert (p[:, 0] < p[:, 1]).all()
    shared = [len(set(f[a]) & set(f[b])) for a, b in p]
    assert shared == [2] * len(p)
    assert M.interior_edges(np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])).shape == (0, 2)  # non-manifold


def test_bending_angles_of_folded_hinge(tdev):
    phis = [0.0, 0.3, 1.0, 2.5, math.pi - 0.01]
    x = _t(np.stack([hinge(p) for p in phis]), tdev)
    ang = M.bending_angles(x, HINGE_FACES)
    assert ang.shape == (5, 1)
    np.testing.assert_allclose(ang[:, 0].cpu(), phis, atol=1e-12)
    err = M.bending_error(x, _t(hinge(0.2), tdev), HINGE_FACES, pairs=M.interior_edges(HINGE_FACES))
    np.testing.assert_allclose(err.cpu(), np.abs(np.array(phis) - 0.2), atol=1e-12)
    v, f = grid_mesh(3)
    np.testing.assert_allclose(M.bending_angles(v * 2.0 + 1.0, f).numpy(), 0.0, atol=1e-7)  # flat


def test_vertex_normal_angles_of_hinge(tdev):
    phi = 0.8
    ang = M.vertex_normal_angles(_t(hinge(phi), tdev), HINGE_FACES)
    e = M.mesh_edges(HINGE_FACES)  # (0,1) (0,2) (0,3) (1,2) (1,3)
    np.testing.assert_array_equal(e, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3]])
    # v0, v1 share both (equal-area) faces: their normals bisect, v2 / v3 carry their face's normal
    np.testing.assert_allclose(ang.cpu(), [0, phi / 2, phi / 2, phi / 2, phi / 2], atol=1e-12)


# ---------------------------------------------------------------- collision


def test_collision_rate_unit_cube(device):
    inside = [[0, 0, 0], [0.3, 0.2, -0.4], [-0.45, 0.45, 0.1]]
    outside = [[0.6, 0, 0], [2, 2, 2], [0, -0.7, 0.1], [0.3, 0.2, 0.55], [-1, 0, 0]]
    pts = np.array(inside + outside, np.float32)
    rate = M.collision_rate(np.stack([pts, pts]), CUBE_VERTICES, CUBE_FACES, device=device)
    np.testing.assert_allclose(rate, [3 / 8, 3 / 8])
    moved = np.stack([CUBE_VERTICES, CUBE_VERTICES + [1.5, 0, 0]])  # frame 1: cube centred at x = 1.5
    pts2 = np.array([[0, 0, 0], [1.5, 0.1, 0], [1.2, 0, 0.3], [5, 5, 5]], np.float32)
    rate2 = M.collision_rate(torch.from_numpy(np.stack([pts2, pts2])), moved, CUBE_FACES, device=device)
    np.testing.assert_allclose(rate2, [1 / 4, 2 / 4])
    assert rate2.dtype == np.float64


# ---------------------------------------------------------------- temporal


def test_flicker_exact(tdev):
    rng = np.random.default_rng(2)
    T, V, dt = 7, 5, 1 / 30
    t = np.arange(T)[:, None, None] * dt
    x0, v0 = rng.normal(size=(V, 3)), rng.normal(size=(V, 3))
    a = np.array([0.0, -9.81, 3.0])
    const_v = x0 + v0 * t
    accel = x0 + v0 * t + 0.5 * a * t ** 2
    f = M.flicker(_t(np.stack([const_v, accel]), tdev))
    assert f.shape == (2,)
    np.testing.assert_allclose(f[0].item(), 0.0, atol=1e-13)
    np.testing.assert_allclose(f[1].item(), np.linalg.norm(a) * dt ** 2, rtol=1e-9)
    np.testing.assert_allclose(M.flicker_ratio(_t(x0 + 0.5 * 2 * a * t ** 2, tdev), _t(accel, tdev)).item(),
                               2.0, rtol=1e-9)
    with pytest.raises(ValueError):
        M.flicker(accel[:2])


def test_image_flicker_exact(tdev):
    T, H, W = 4, 6, 5
    c = np.array([0.3, 0.0, 0.4])  # |c| = 0.5 per frame
    maps = np.arange(T)[:, None, None, None] * c * np.ones((T, H, W, 3))
    np.testing.assert_allclose(M.image_flicker(_t(maps, tdev)).item(), 0.5, rtol=1e-12)
    mask = np.zeros((H, W), bool)
    mask[1:4, 2:] = True
    noisy = maps.copy()
    noisy[:, ~mask] = np.random.default_rng(0).normal(size=(T, (~mask).sum(), 3))  # outside: ignored
    np.testing.assert_allclose(M.image_flicker(_t(noisy, tdev), _t(mask, tdev)).item(), 0.5, rtol=1e-12)
    per_frame = np.broadcast_to(mask, (T, H, W))
    np.testing.assert_allclose(M.image_flicker(noisy[None], per_frame[None]).numpy(), [0.5], rtol=1e-12)


# ---------------------------------------------------------------- spectrum


def _sinusoid(H, W, kx, ky, amp=1.0):
    yy, xx = np.mgrid[0:H, 0:W]
    return amp * np.sin(2 * np.pi * (kx * xx / W + ky * yy / H) + 0.4)


def test_spectrum_sinusoid_peak(tdev):
    H = W = 64
    img = np.stack([_sinusoid(H, W, 5, 3), _sinusoid(H, W, 12, 0)])[..., None]
    sp = M.radial_power_spectrum(_t(img, tdev))
    assert sp.power.shape == (2, 32) and sp.frequency.shape == (32,)
    np.testing.assert_allclose(sp.frequency.cpu(), np.arange(1, 33) / 64)
    peak = sp.frequency[sp.power.argmax(dim=1)].cpu().numpy()
    np.testing.assert_allclose(peak, [6 / 64, 12 / 64])  # |k| = sqrt(34) = 5.83 lies in the bin of 6
    np.testing.assert_allclose(M.dominant_wavelength(sp).cpu(), [64 / math.sqrt(34), 64 / 12], rtol=0.03)
    # masked: the sinusoid only inside a disc, garbage outside the mask is ignored
    yy, xx = np.mgrid[0:H, 0:W]
    mask = (yy - 30) ** 2 + (xx - 34) ** 2 < 26 ** 2
    junk = img.copy()
    junk[:, ~mask] = 100.0 * np.random.default_rng(0).normal(size=(2, (~mask).sum(), 1))
    spm = M.radial_power_spectrum(_t(junk, tdev), mask=_t(mask, tdev))
    np.testing.assert_allclose(spm.frequency[spm.power.argmax(dim=1)].cpu(), [6 / 64, 12 / 64])


def test_spectrum_white_noise_is_flat():
    x = np.random.default_rng(3).normal(scale=0.5, size=(32, 64, 64, 2))
    sp = M.radial_power_spectrum(x)
    p = sp.mean_power().numpy()
    # E[P(f)] = variance at every f (normalisation by sum w²); bin 1 loses a little to mean removal
    np.testing.assert_allclose(p[1:], 0.25, rtol=0.15)
    slope = np.polyfit(np.log10(sp.frequency.numpy()[1:]), np.log10(p[1:]), 1)[0]
    assert abs(slope) < 0.05


def test_spectrum_scaling_and_distance(tdev):
    rng = np.random.default_rng(4)
    x = _t(rng.normal(size=(3, 48, 40, 3)), tdev)
    s = 3.7
    a, b = M.radial_power_spectrum(x), M.radial_power_spectrum(s * x)
    np.testing.assert_allclose((b.power.log10() - a.power.log10()).cpu(), 2 * math.log10(s), atol=1e-10)
    assert M.spectrum_profile_distance(a, a).item() == 0.0
    np.testing.assert_allclose(M.spectrum_profile_distance(b, a).item(), 2 * math.log10(s), rtol=1e-10)
    np.testing.assert_allclose(M.spectrum_profile_distance(a.power, b.power).cpu(), [2 * math.log10(s)] * 3,
                               rtol=1e-10)
    c = M.radial_power_spectrum(x, bins=8)
    assert c.power.shape == (3, 8) and int(c.count.sum()) > 0
    with pytest.raises(ValueError):
        M.spectrum_profile_distance(a, c)


# ---------------------------------------------------------------- Fréchet distance


def test_frechet_closed_forms():
    rng = np.random.default_rng(5)
    mu_a, mu_b = rng.normal(size=6), rng.normal(size=6)
    va, vb = rng.random(6) + 0.1, rng.random(6) + 0.1
    want = ((mu_a - mu_b) ** 2).sum() + ((np.sqrt(va) - np.sqrt(vb)) ** 2).sum()
    got = M.frechet_distance_from_stats(mu_a, np.diag(va), mu_b, np.diag(vb))
    np.testing.assert_allclose(got, want, rtol=1e-12)
    # general (non-commuting) covariances against scipy's sqrtm of the product
    from scipy.linalg import sqrtm

    ga, gb = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    ca, cb = ga @ ga.T, gb @ gb.T
    ref = ((mu_a - mu_b) ** 2).sum() + np.trace(ca + cb - 2 * np.real(sqrtm(ca @ cb)))
    np.testing.assert_allclose(M.frechet_distance_from_stats(mu_a, ca, mu_b, cb), ref, rtol=1e-9)
    # 1-D: N(0, 1) vs N(1, 4): 1 + (1 - 2)²
    np.testing.assert_allclose(M.frechet_distance_from_stats([0.0], [[1.0]], [1.0], [[4.0]]), 2.0, rtol=1e-14)


def test_frechet_from_samples():
    rng = np.random.default_rng(6)
    for n, d in ((300, 20), (10, 40)):  # well-sampled, and singular covariance (N < D)
        x = rng.normal(size=(n, d)) @ rng.normal(size=(d, d))
        fd = M.frechet_distance(x, x)
        assert fd <= 1e-6 * np.trace(np.cov(x, rowvar=False))
    a = rng.normal(size=(200, 5))
    b = rng.normal(size=(150, 5)) * 2 + 1
    mu_a, ca = a.mean(0), np.cov(a, rowvar=False)
    mu_b, cb = b.mean(0), np.cov(b, rowvar=False)
    np.testing.assert_allclose(M.frechet_distance(torch.from_numpy(a), b),
                               M.frechet_distance_from_stats(mu_a, ca, mu_b, cb), rtol=1e-12)


def wrinkle_normals(n: int, res: int, *, seed: int, freq=(8.0, 30.0)) -> np.ndarray:
    """Normal maps (n, res, res, 3) of random oriented sinusoidal height fields (freq in cycles/UV)."""
    rng = np.random.default_rng(seed)
    c = (np.arange(res) + 0.5) / res
    u, v = np.meshgrid(c, c, indexing="xy")
    out = []
    for _ in range(n):
        hu, hv = np.zeros_like(u), np.zeros_like(u)
        for _ in range(5):
            f, th, ph = rng.uniform(*freq), rng.uniform(0, np.pi), rng.uniform(0, 2 * np.pi)
            k = 2 * np.pi * f
            slope = rng.uniform(0.1, 0.3)  # max |grad h|
            arg = k * (np.cos(th) * u + np.sin(th) * v) + ph
            hu += slope * np.cos(th) * np.cos(arg)
            hv += slope * np.sin(th) * np.cos(arg)
        nrm = np.stack([-hu, -hv, np.ones_like(u)], -1)
        out.append(nrm / np.linalg.norm(nrm, axis=-1, keepdims=True))
    return np.asarray(out, np.float32)


@pytest.fixture(scope="module")
def extractor():
    return M.NormalMapFeatures(device="cpu")


def test_features_shape_determinism_mask(extractor):
    x = wrinkle_normals(3, 96, seed=7)
    f1, f2 = extractor(x), extractor(torch.from_numpy(x))
    assert f1.shape == (3, M.FEATURE_DIM) and f1.dtype == torch.float64 and M.FEATURE_DIM == 150
    assert torch.equal(f1, f2)
    assert isinstance(M.VERSION, str) and M.NormalMapFeatures.VERSION == M.VERSION
    mask = np.zeros((96, 96), bool)
    mask[10:80, 20:90] = True
    junk = x.copy()
    junk[:, ~mask] = np.random.default_rng(0).normal(size=(3, (~mask).sum(), 3))
    np.testing.assert_array_equal(extractor(x, mask).numpy(), extractor(junk, mask).numpy())
    assert not torch.equal(extractor(x, mask), f1)
    assert M.normal_map_fd(x, x, extractor=extractor) == 0.0


def test_features_resolution_invariant(extractor):
    lo, hi = (wrinkle_normals(1, r, seed=8, freq=(3.0, 10.0)) for r in (64, 256))
    other = wrinkle_normals(1, 256, seed=9, freq=(3.0, 10.0))
    f_lo, f_hi, f_other = extractor(lo)[0], extractor(hi)[0], extractor(other)[0]
    d_res = torch.linalg.vector_norm(f_lo - f_hi)
    assert d_res < 0.03 * torch.linalg.vector_norm(f_hi)
    assert d_res < 0.1 * torch.linalg.vector_norm(f_other - f_hi)


def test_fd_grows_with_blur_and_noise(extractor):
    from scipy.ndimage import gaussian_filter

    ref = wrinkle_normals(8, 96, seed=10)
    f_ref = extractor(ref)

    def fd(maps):
        return M.frechet_distance(extractor(maps), f_ref)

    def blur(s):
        b = gaussian_filter(ref, sigma=(0, s, s, 0), mode="wrap")
        return b / np.linalg.norm(b, axis=-1, keepdims=True)

    blurred = [fd(blur(s)) for s in (1.0, 2.0, 4.0)]
    assert 0.0 < blurred[0] < blurred[1] < blurred[2], blurred
    rng = np.random.default_rng(11)
    noisy = []
    for s in (0.02, 0.08, 0.3):
        nz = ref + s * rng.normal(size=ref.shape).astype(np.float32)
        noisy.append(fd(nz / np.linalg.norm(nz, axis=-1, keepdims=True)))
    assert 0.0 < noisy[0] < noisy[1] < noisy[2], noisy


def test_features_on_device(tdev):
    x = wrinkle_normals(2, 64, seed=12)
    f_cpu = M.NormalMapFeatures(device="cpu")(x)
    f_dev = M.NormalMapFeatures(device=tdev)(torch.from_numpy(x).to(tdev))
    assert f_dev.device.type == "cpu"
    np.testing.assert_allclose(f_dev.numpy(), f_cpu.numpy(), rtol=1e-4, atol=1e-6)
