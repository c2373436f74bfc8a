"""Base-surface smoothing (Hessian energy): its spectrum on a sheet (long waves kept, wrinkles
removed, half amplitude at the smoothing length), affine fields and rigid motions reproduced,
garment boundaries kept in place, and 100 frames of a 15k-vertex mesh smoothed."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.geometry.smoothing import BaseSmoother, hessian_energy, smooth_base, smoothing_stiffness
from tests.test_geometry import rotation, sheet


@pytest.fixture(scope="module")
def tshirt():
    from sim.bodies import load_body
    from sim.garments import make_garment

    return make_garment("t_shirt", load_body(), resolution="coarse")


def test_spectrum_keeps_long_waves_and_removes_wrinkles():
    """A 1 m sheet (1 cm edges, jittered) bent by a long wave (λ = 0.5 m = 5 × length) with
    wrinkles on it (λ = 4 cm = length / 2.5, along a diagonal): the long wave keeps ≥ 90 % of its
    amplitude (1 / (1 + (1/5)⁴) = 99.8 % in theory) and the wrinkles lose ≥ 90 % (theory 97.5 %;
    4 vertices per wavelength damp a little less). A wave at λ = length keeps about half."""
    length = 0.1
    v, f, _ = sheet(101, 1.0, jitter=0.25)
    m = hessian_energy(v, f)[0]
    X, Y = v[:, 0], v[:, 1]
    low = 0.02 * np.sin(2 * np.pi * X / 0.5 + 0.3)
    high = 0.003 * np.sin(2 * np.pi * (X + Y) / np.sqrt(2) / 0.04)
    mid = 0.003 * np.sin(2 * np.pi * Y / length)
    frames = np.stack([v, v, v])
    frames[0, :, 2] = low + high
    frames[1, :, 2] = mid
    frames[2, :, 2] = high
    out = BaseSmoother(v, f, length=length).smooth(frames)

    def kept(z, wave):  # amplitude of ``wave`` left in z (mass-weighted projection)
        return float((m * z * wave).sum() / (m * wave * wave).sum())

    k_low, k_high = kept(out[0, :, 2], low), kept(out[0, :, 2], high)
    print(f"\nlow wave kept {k_low:.4f}, wrinkles kept {k_high:.4f}, wave at the length kept "
          f"{kept(out[1, :, 2], mid):.3f}")
    assert k_low >= 0.9
    assert abs(k_high) <= 0.1
    assert abs(kept(out[2, :, 2], high)) <= 0.1
    assert 0.4 <= kept(out[1, :, 2], mid) <= 0.6
    # in-plane coordinates are affine: untouched
    np.testing.assert_allclose(out[:, :, :2], frames[:, :, :2], atol=1e-6)


def test_affine_fields_are_reproduced():
    """On a flat sheet (jittered, open boundary, anywhere in 3D) every affine map of the rest
    positions, rigid or not, comes back unchanged, boundary vertices included."""
    rng = np.random.default_rng(1)
    v, f, _ = sheet(30, 0.6, jitter=0.3)
    rest = v @ rotation(rng).T + [0.1, 1.0, -0.3]
    maps = [(rotation(rng), rng.normal(size=3)),
            (np.eye(3) + 0.4 * rng.normal(size=(3, 3)), rng.normal(size=3))]
    seq = np.stack([rest @ A.T + b for A, b in maps]).astype(np.float32)
    out = smooth_base(seq, rest, f, length=0.1)
    np.testing.assert_allclose(out, seq, atol=2e-6)
    mass, B = hessian_energy(rest, f)
    np.testing.assert_allclose(B @ rest, 0.0, atol=1e-9 * abs(B).max())
    np.testing.assert_allclose(B @ np.ones(len(rest)), 0.0, atol=1e-9 * abs(B).max())
    np.testing.assert_allclose(mass.sum(), 0.36, rtol=1e-12)
    assert abs(B - B.T).max() <= 1e-9 * abs(B).max()


def test_smoothing_commutes_with_rigid_motions(tshirt):
    """A curved, open garment with wrinkles: smooth(R x + b) = R smooth(x) + b."""
    rng = np.random.default_rng(2)
    x = tshirt.rest_vertices.astype(np.float64)
    fine = x + 0.004 * np.sin(60 * x[:, [1]]) * rng.normal(size=(1, 3)) + 0.001 * rng.normal(size=x.shape)
    R, b = rotation(rng), np.array([0.5, -0.2, 2.0])
    smoother = BaseSmoother(x, tshirt.faces, length=0.05)
    out = smoother.smooth(np.stack([fine, fine @ R.T + b]).astype(np.float32))
    np.testing.assert_allclose(out[1], out[0] @ R.T + b, atol=5e-6)


def test_garment_boundaries_stay_in_place(tshirt):
    """The rest t-shirt (curved, open at hem, cuffs, neck) barely moves at length 5 cm: its
    boundaries by less than 2 mm on average (a cotangent bi-Laplacian moves the hem 2.7 mm), the
    whole garment by less than 1 mm on average and 7 mm at the worst crease. What moves are the
    small folds sewing leaves at the cuffs and shoulder seams (measured: hem 0.45, cuffs 1.48,
    shoulders 1.74 mm on average; all 0.73 mm, at most 6.1 mm)."""
    x = tshirt.rest_vertices
    d = np.linalg.norm(smooth_base(x, x, tshirt.faces, length=0.05) - x, axis=1)
    for name in ("hem", "cuffs", "shoulders"):
        assert d[tshirt.attachments[name]].mean() < 2e-3, name
    assert d.mean() < 1e-3 and d.max() < 7e-3


@pytest.mark.slow
def test_smoothing_a_15k_vertex_sheet_over_100_frames():
    """The dataset's size of work: a float32 result of the input's shape, finite, and smoother
    than the noisy input (its per-frame noise is filtered out)."""
    rng = np.random.default_rng(3)
    v, f, _ = sheet(122, 1.2, jitter=0.3)
    v[:, 2] = 0.2 * np.sin(2 * v[:, 0]) * np.cos(3 * v[:, 1])
    seq = (v + 0.002 * rng.normal(size=(100,) + v.shape)).astype(np.float32)
    out = BaseSmoother(v, f, length=0.05).smooth(seq)
    assert out.shape == seq.shape and out.dtype == np.float32 and np.isfinite(out).all()
    assert np.abs(out - v).mean() < np.abs(seq - v).mean()


def test_the_dense_factor_solves_as_the_sparse_one():
    """The device path (a dense float64 Cholesky factor, here torch on the CPU) gives the sparse
    LU's base surface to round-off, over more frames than one block."""
    from sim.geometry import smoothing

    rng = np.random.default_rng(5)
    v, f, _ = sheet(14, 0.5, jitter=0.3)
    v[:, 2] = 0.05 * np.sin(6 * v[:, 0])
    seq = (v + 0.003 * rng.normal(size=(smoothing.SOLVE_BLOCK + 5,) + v.shape)).astype(np.float32)
    sparse = BaseSmoother(v, f, length=0.05)
    dense = BaseSmoother(v, f, length=0.05, device="cpu", dense=True)
    assert dense.dense and not sparse.dense
    np.testing.assert_allclose(dense.smooth(seq), sparse.smooth(seq), atol=1e-6)
    np.testing.assert_allclose(dense.smooth(seq[0]), sparse.smooth(seq[0]), atol=1e-6)
    # automatic: only a CUDA device factorises densely
    assert not BaseSmoother(v, f, device="cpu").dense and not smoothing._dense_fits(len(v), None)


def test_smoothing_input_errors():
    v, f, _ = sheet(5, 1.0)
    with pytest.raises(WrinklesInputError, match="positive"):
        BaseSmoother(v, f, length=0.0)
    with pytest.raises(WrinklesInputError, match="shape"):
        BaseSmoother(v, f).smooth(v[:10])
    with pytest.raises(WrinklesInputError, match="zero area"):
        BaseSmoother(np.where(np.arange(len(v))[:, None] == 0, v[1], v), f)
    assert smoothing_stiffness(2 * np.pi) == pytest.approx(1.0)
