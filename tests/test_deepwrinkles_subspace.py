"""DeepWrinkles' statistical model (``learn.deepwrinkles.subspace``, Lähner et al. Sec. 3.2):
skinning and its inverse against a numpy loop, the subspace against numpy's SVD, Eq. 3's
encode / decode, both Gram sides agreeing, and the error messages."""

from __future__ import annotations

import numpy as np
import pytest

from learn.deepwrinkles.subspace import GarmentSubspace, fit_subspace, repose, unpose
from sim.errors import WrinklesInputError
from sim.rotations import axis_angle_to_matrix


def rig(frames: int = 5, vertices: int = 40, joints: int = 3, seed: int = 0):
    """Random skinning weights (V, J) (rows summing to 1) and bone transforms (T, J, 3, 4) of
    rotations up to ~0.6 rad with translations, and rest points (V, 3)."""
    rng = np.random.default_rng(seed)
    w = rng.random((vertices, joints)) ** 3
    w /= w.sum(axis=1, keepdims=True)
    rot = axis_angle_to_matrix(rng.normal(scale=0.35, size=(frames * joints, 3)))
    rot = rot.reshape(frames, joints, 3, 3)
    a = np.concatenate([rot, rng.normal(scale=0.3, size=(frames, joints, 3, 1))], axis=3)
    return w.astype(np.float32), a.astype(np.float32), rng.normal(size=(vertices, 3)).astype(np.float32)


def test_repose_is_linear_blend_skinning_and_unpose_inverts_it():
    w, a, rest = rig()
    posed = repose(rest, w, a)
    ref = np.zeros_like(posed, dtype=np.float64)
    for t in range(a.shape[0]):
        for v in range(len(rest)):
            m = sum(w[v, j] * a[t, j].astype(np.float64) for j in range(w.shape[1]))
            ref[t, v] = m[:, :3] @ rest[v] + m[:, 3]
    np.testing.assert_allclose(posed, ref, atol=1e-5)
    back = unpose(posed, w, a)
    np.testing.assert_allclose(back, np.broadcast_to(rest, back.shape), atol=1e-4)


def test_subspace_matches_numpys_svd_and_reconstructs_its_frames():
    rng = np.random.default_rng(1)
    n, v = 30, 50
    basis = rng.normal(size=(6, v * 3))
    scales = np.array([3, 2, 1, .5, .2, .1])
    frames = rng.normal(size=(v, 3)).reshape(1, -1) + (rng.normal(size=(n, 6)) * scales) @ basis
    frames = frames.reshape(n, v, 3).astype(np.float32)
    sub = fit_subspace(frames, k=10)
    o = frames.reshape(n, -1).astype(np.float64) - frames.reshape(n, -1).astype(np.float64).mean(axis=0)
    _, s, vt = np.linalg.svd(o, full_matrices=False)
    assert sub.size == 6  # k = 10 asked, the frames span 6 directions
    np.testing.assert_allclose(sub.singular_values[:6], s[:6], rtol=1e-6)
    for l in range(6):  # the same directions up to sign (fit_subspace fixes the sign)
        assert abs(float(sub.components[l] @ vt[l])) == pytest.approx(1.0, abs=1e-5)
    np.testing.assert_allclose(sub.components[:6] @ sub.components[:6].T, np.eye(6), atol=1e-5)
    assert sub.variance_kept(6) == pytest.approx(1.0, abs=1e-9)
    assert sub.variance_kept(1) == pytest.approx(s[0] ** 2 / np.sum(s ** 2), rel=1e-6)
    assert 0.0 < sub.variance_kept(1) < sub.variance_kept(2) < sub.variance_kept(3) < 1.0
    lam = sub.encode(frames, k=6)
    np.testing.assert_allclose(sub.decode(lam), frames, atol=2e-4)
    # fewer components: the error is what the dropped directions held, no more
    err2 = float(np.sum((sub.decode(sub.encode(frames, k=2)) - frames) ** 2))
    assert err2 == pytest.approx(float(np.sum(s[2:] ** 2)), rel=1e-3)


def test_both_gram_sides_give_one_subspace():
    rng = np.random.default_rng(2)
    for n, v in ((12, 3), (5, 6)):  # more frames than coordinates (covariance), fewer (frames' Gram)
        frames = rng.normal(size=(n, v, 3)).astype(np.float32)
        sub = fit_subspace(frames, k=20)
        o = frames.reshape(n, -1).astype(np.float64) - frames.reshape(n, -1).astype(np.float64).mean(axis=0)
        _, s, vt = np.linalg.svd(o, full_matrices=False)
        rank = min(n - 1, 3 * v)
        assert sub.size == rank
        np.testing.assert_allclose(sub.singular_values, s[:rank], rtol=1e-6)
        np.testing.assert_allclose(np.abs(np.sum(sub.components * vt[:rank], axis=1)), 1.0, atol=1e-5)
        assert sub.total_variance == pytest.approx(float(np.sum(o ** 2)), rel=1e-6)


def test_frames_spanning_fewer_directions_give_only_those():
    rng = np.random.default_rng(5)
    base, dirs = rng.normal(size=(1, 30)), rng.normal(size=(2, 30))
    frames = (base + rng.normal(size=(5, 2)) @ dirs).reshape(5, 10, 3)
    sub = fit_subspace(frames, k=4)
    assert sub.size == 2
    np.testing.assert_allclose(sub.components @ sub.components.T, np.eye(2), atol=1e-6)
    with pytest.raises(WrinklesInputError, match="all the same shape"):
        fit_subspace(np.repeat(frames[:1], 3, axis=0))


def test_k_is_clipped_to_the_rank_bound_and_a_round_trip_through_a_file(tmp_path):
    rng = np.random.default_rng(3)
    frames = rng.normal(size=(4, 20, 3)).astype(np.float32)
    sub = fit_subspace(frames, k=500)
    assert sub.size == 3  # 4 frames less their mean span 3 directions
    sub.save(tmp_path / "s.npz")
    again = GarmentSubspace.load(tmp_path / "s.npz")
    np.testing.assert_array_equal(again.components, sub.components)
    assert again.frames == 4 and again.total_variance == sub.total_variance


def test_bad_input_is_refused_in_one_line(tmp_path):
    w, a, rest = rig()
    with pytest.raises(WrinklesInputError, match="weights"):
        unpose(np.zeros((5, 7, 3)), w, a)
    with pytest.raises(WrinklesInputError, match="transforms"):
        repose(rest, w, a[:, :2])
    singular = a.copy()
    singular[:, :, :3, :3] = 0.0
    with pytest.raises(WrinklesInputError, match="singular"):
        unpose(np.zeros((5, len(rest), 3)), w, singular)
    with pytest.raises(WrinklesInputError, match="n >= 2"):
        fit_subspace(np.zeros((1, 4, 3)))
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(WrinklesInputError, match="bad.npz"):
        GarmentSubspace.load(tmp_path / "bad.npz")
