"""UV maps of the wrinkle models (sim.geometry.wrinkle_maps): conditioning maps agree with the
dataset's derivation and with analytic strain, and a wrinkle map decodes back to the mesh."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import WrinklesInputError


@pytest.fixture(scope="module")
def tshirt():
    from sim.bodies import load_body
    from sim.garments import make_garment

    return make_garment("t_shirt", load_body(), resolution=0.03)


def _smooth_field(x: np.ndarray, amplitude: float, wavelength: float, phase: float = 0.0) -> np.ndarray:
    k = 2 * np.pi / wavelength
    return amplitude * np.sin(k * x[..., 1] + phase) * np.cos(k * x[..., 0])


def _frames(g, T: int = 3):
    """Base: the rest garment moved rigidly and bent gently; fine: base + a smooth normal field."""
    from sim.geometry.frames import vertex_normals

    rest = g.rest_vertices.astype(np.float64)
    base, fine = [], []
    for t in range(T):
        a = 0.2 * t
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        b = rest @ R.T + np.array([0.1 * t, 0.0, 0.0])
        b[:, 2] += 0.02 * np.sin(3.0 * b[:, 1])  # low-frequency bend
        n = vertex_normals(b.astype(np.float32), g.faces, device="cpu")
        f = b + _smooth_field(rest, 0.004, 0.25, phase=t)[:, None] * n
        base.append(b)
        fine.append(f)
    return np.asarray(base, np.float32), np.asarray(fine, np.float32)


def test_maps_match_the_dataset_derivation(tshirt):
    from sim.datasets.config import DeriveConfig
    from sim.datasets.derive import Deriver
    from sim.geometry.wrinkle_maps import WrinkleMaps

    base, fine = _frames(tshirt)
    d = Deriver(tshirt, DeriveConfig(smoothing_length=0.08, image_resolution=64, coarse=False), device="cpu")
    out = d(fine)
    maps = WrinkleMaps.from_garment(tshirt, 64, device="cpu")
    np.testing.assert_array_equal(maps.mask, out["images/mask"].astype(bool))
    # the dataset's base is its own smoothing of fine: compare on that base
    b = out["fine/base"]
    np.testing.assert_allclose(
        maps.conditioning(b, "strain_norm"),
        out["images/strain_norm"].astype(np.float32),
        atol=2e-3,
        rtol=2e-3,
    )  # f16 storage
    np.testing.assert_allclose(
        maps.wrinkle(fine, b), out["images/wrinkle"].astype(np.float32), atol=1e-5, rtol=2e-3
    )


def test_uniform_stretch_gives_the_analytic_strain_tensor(tshirt):
    from sim.geometry.wrinkle_maps import WrinkleMaps

    maps = WrinkleMaps.from_garment(tshirt, 64, device="cpu")
    s = 1.1
    x = (tshirt.rest_vertices * s)[None]
    e = 0.5 * (s * s - 1.0)
    m = maps.mask
    tensor = maps.conditioning(x, "strain_tensor")[0][m]
    np.testing.assert_allclose(tensor[:, 0], e, atol=1e-4)
    np.testing.assert_allclose(tensor[:, 1], e, atol=1e-4)
    np.testing.assert_allclose(tensor[:, 2], 0.0, atol=1e-4)
    norm = maps.conditioning(x, "strain_norm")[0][m, 0]
    np.testing.assert_allclose(norm, np.sqrt(2) * e, atol=1e-4)
    # a stretch along the garment's height only: E22 (along v, up the panels) carries it
    y = tshirt.rest_vertices.copy()
    y[:, 1] *= s
    t2 = maps.conditioning(y[None], "strain_tensor")[0][m]
    assert np.median(np.abs(t2[:, 1])) > 5 * np.median(np.abs(t2[:, 0]))
    normals = maps.conditioning(x, "normal")[0][m]
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=0.05)


def test_decode_round_trip_restores_the_wrinkles(tshirt):
    from sim.geometry.wrinkle_maps import WrinkleMaps

    base, fine = _frames(tshirt)
    maps = WrinkleMaps.from_garment(tshirt, 128, device="cpu")
    w = maps.wrinkle(fine, base)
    back = maps.decode(w, base)
    err = np.linalg.norm(back - fine, axis=-1)
    amp = np.linalg.norm(fine - base, axis=-1)
    assert amp.max() > 3e-3
    # bilinear resampling of a smooth 4 mm field at 128 px: sub-millimetre everywhere
    assert err.mean() < 0.05 * amp.mean(), (err.mean(), amp.mean())
    assert err.max() < 0.25 * amp.max(), (err.max(), amp.max())
    # no wrinkles in, no displacement out; base is returned exactly
    np.testing.assert_allclose(maps.decode(np.zeros_like(w), base), base, atol=1e-6)
    # world-frame route
    g = maps.displacement(fine, base)
    back_g = maps.decode_global(g, base)
    assert np.linalg.norm(back_g - fine, axis=-1).mean() < 0.1 * amp.mean()


def test_seam_vertices_decode_once(tshirt):
    """A vertex on a seam has several UV copies; decoding moves it by their mean (one value)."""
    from sim.geometry.wrinkle_maps import WrinkleMaps

    maps = WrinkleMaps.from_garment(tshirt, 128, device="cpu")
    counts = np.bincount(maps.uv_vertex, minlength=tshirt.num_vertices)
    seam = np.flatnonzero(counts > 1)
    assert seam.size > 10
    base, fine = _frames(tshirt, T=1)
    back = maps.decode(maps.wrinkle(fine, base), base)
    err = np.linalg.norm(back - fine, axis=-1)[0]
    amp = np.linalg.norm(fine - base, axis=-1).mean()
    assert err[seam].mean() < 0.1 * amp


def test_bad_inputs(tshirt):
    from sim.geometry.wrinkle_maps import WrinkleMaps

    maps = WrinkleMaps.from_garment(tshirt, 32, device="cpu")
    with pytest.raises(WrinklesInputError, match="conditioning"):
        maps.conditioning(tshirt.rest_vertices[None], "curvature")
    with pytest.raises(WrinklesInputError, match="base must have shape"):
        maps.conditioning(tshirt.rest_vertices[None, :10], "strain_norm")
