"""SSDR (Le & Deng 2012) on a synthetic rig with known bones and weights."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from sim.errors import WrinklesInputError
from sim.skinning.ssdr import SSDRResult, _convex_lsq, fit_bone_transforms, fit_ssdr, ssdr_reconstruct

NUM_BONES = 6
FRAMES = 30


def _cylinder(rings: int = 25, around: int = 24, radius: float = 0.2, height: float = 1.2) -> np.ndarray:
    """Open cylinder along y, (rings * around, 3) [m]."""
    phi = np.linspace(0, 2 * np.pi, around, endpoint=False)
    y = np.linspace(0, height, rings)
    yy, pp = np.meshgrid(y, phi, indexing="ij")
    return np.stack([radius * np.cos(pp), yy, radius * np.sin(pp)], -1).reshape(-1, 3)


def _synthetic_rig(seed: int = 3, sigma: float = 0.1, angle: float = 0.5):
    """Articulated chain of 6 bones along a cylinder: rest (V, 3), true weights (V, 6), frames (T, V, 3).

    Weights: Gaussian fall-off in height around each bone centre (``sigma`` [m]), truncated to
    the 3 largest and normalised (smooth, sparse, K <= 3). Motion: forward kinematics with
    random joint rotations (std ``angle`` [rad] per axis) and a random root translation.
    """
    rng = np.random.default_rng(seed)
    rest = _cylinder()
    centers = np.linspace(0.1, 1.1, NUM_BONES)
    w = np.exp(-0.5 * ((rest[:, 1:2] - centers[None]) / sigma) ** 2)
    drop = np.argsort(-w, axis=1)[:, 3:]
    np.put_along_axis(w, drop, 0.0, axis=1)
    w /= w.sum(axis=1, keepdims=True)
    joints = np.stack([np.zeros(NUM_BONES), centers - 0.1, np.zeros(NUM_BONES)], axis=1)
    local = Rotation.from_rotvec(rng.normal(scale=angle, size=(FRAMES * NUM_BONES, 3))).as_matrix()
    local = local.reshape(FRAMES, NUM_BONES, 3, 3)
    rot = np.zeros((FRAMES, NUM_BONES, 3, 3))
    tr = np.zeros((FRAMES, NUM_BONES, 3))
    rot[:, 0] = local[:, 0]
    tr[:, 0] = rng.normal(scale=0.3, size=(FRAMES, 3)) + joints[0] - local[:, 0] @ joints[0]
    for j in range(1, NUM_BONES):
        rot[:, j] = rot[:, j - 1] @ local[:, j]
        joint_pos = rot[:, j - 1] @ joints[j] + tr[:, j - 1]  # joint j carried by its parent
        tr[:, j] = joint_pos - rot[:, j] @ joints[j]
    per_bone = np.einsum("tjab,vb->tjva", rot, rest) + tr[:, :, None]
    frames = np.einsum("vj,tjva->tva", w, per_bone)
    return rest.astype(np.float32), w, frames.astype(np.float32)


@pytest.fixture(scope="module")
def rig():
    return _synthetic_rig()


@pytest.fixture(scope="module")
def fitted(rig) -> SSDRResult:
    rest, _, frames = rig
    return fit_ssdr(rest, frames, num_bones=NUM_BONES, max_influences=3, iterations=30, seed=0)


@pytest.mark.slow
def test_reconstruction_error_small(rig, fitted):
    rest, _, frames = rig
    size = float(np.linalg.norm(rest.max(0) - rest.min(0)))
    recon = ssdr_reconstruct(fitted)
    assert recon.shape == frames.shape and recon.dtype == np.float32
    rmse = np.sqrt(np.mean(np.sum((recon - frames) ** 2, axis=2)))
    np.testing.assert_allclose(rmse, fitted.rmse, rtol=1e-3, atol=1e-6)
    assert rmse < 1e-3 * size, (rmse, fitted.rmse_per_iteration)


@pytest.mark.slow
def test_weights_match_truth_up_to_permutation(rig, fitted):
    _, w_true, _ = rig
    w_fit = fitted.dense_weights()
    cost = -(w_true.T @ w_fit)  # (true bone, fitted bone) overlap
    row, col = linear_sum_assignment(cost)
    np.testing.assert_array_equal(row, np.arange(NUM_BONES))
    np.testing.assert_allclose(w_fit[:, col], w_true, atol=2e-2)


@pytest.mark.slow
def test_weight_constraints(fitted):
    v = fitted.rest.shape[0]
    assert fitted.weight_idx.shape == (v, 3) and fitted.weight_idx.dtype == np.int32
    assert fitted.weight_val.shape == (v, 3) and fitted.weight_val.dtype == np.float32
    assert np.all(fitted.weight_val >= 0)
    np.testing.assert_allclose(fitted.weight_val.sum(axis=1), 1.0, atol=1e-5)
    assert np.all((fitted.weight_idx >= 0) & (fitted.weight_idx < NUM_BONES))
    # the (at most K) non-zero influences name distinct bones
    for row_idx, row_val in zip(fitted.weight_idx, fitted.weight_val, strict=True):
        nz = row_idx[row_val > 0]
        assert len(set(nz.tolist())) == len(nz)


@pytest.mark.slow
def test_rotations_proper(fitted):
    r = fitted.rotations.astype(np.float64)
    assert r.shape == (FRAMES, NUM_BONES, 3, 3) and fitted.translations.shape == (FRAMES, NUM_BONES, 3)
    eye = np.broadcast_to(np.eye(3), r.shape)
    np.testing.assert_allclose(np.swapaxes(r, -1, -2) @ r, eye, atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-5)


@pytest.mark.slow
def test_rmse_history_non_increasing(fitted):
    h = np.asarray(fitted.rmse_per_iteration)
    assert len(h) == 31
    # only bone re-seeding (first half) may raise the error; none happens on this rig
    assert np.all(np.diff(h) <= 1e-7 + 1e-6 * h[:-1]), h
    assert fitted.rmse == h[-1]


def test_deterministic_same_seed(rig):
    rest, _, frames = rig
    a = fit_ssdr(rest, frames, num_bones=4, max_influences=2, iterations=3, seed=7)
    b = fit_ssdr(rest, frames, num_bones=4, max_influences=2, iterations=3, seed=7)
    np.testing.assert_array_equal(a.weight_idx, b.weight_idx)
    np.testing.assert_array_equal(a.weight_val, b.weight_val)
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.translations, b.translations)
    assert a.rmse_per_iteration == b.rmse_per_iteration


@pytest.mark.slow
def test_reconstruct_with_given_transforms(fitted):
    """Identity bones give back the rest mesh (convex weights)."""
    rot = np.tile(np.eye(3, dtype=np.float32), (2, NUM_BONES, 1, 1))
    tr = np.zeros((2, NUM_BONES, 3), np.float32)
    out = ssdr_reconstruct(fitted, rotations=rot, translations=tr)
    np.testing.assert_allclose(out, np.broadcast_to(fitted.rest, out.shape), atol=1e-6)
    with pytest.raises(WrinklesInputError):
        ssdr_reconstruct(fitted, rotations=rot[:, :2], translations=tr)


def test_convex_lsq_matches_reference():
    """Exact support enumeration vs scipy NNLS with a heavily weighted sum-to-one row."""
    from scipy.optimize import nnls

    rng = np.random.default_rng(0)
    a = rng.normal(size=(50, 12, 4))
    b = rng.normal(size=(50, 12))
    g = np.einsum("vik,vil->vkl", a, a)
    c = np.einsum("vik,vi->vk", a, b)
    w, f = _convex_lsq(g, c, np.einsum("vi,vi->v", b, b))
    big = 1e4
    for i in range(50):
        ref, _ = nnls(np.vstack([a[i], big * np.ones((1, 4))]), np.concatenate([b[i], [big]]))
        np.testing.assert_allclose(w[i], ref, atol=1e-5)
        np.testing.assert_allclose(f[i], np.sum((a[i] @ w[i] - b[i]) ** 2), rtol=1e-9, atol=1e-12)


def test_bad_input():
    rest = np.zeros((10, 3), np.float32)
    with pytest.raises(WrinklesInputError):
        fit_ssdr(rest, np.zeros((2, 9, 3), np.float32), num_bones=2)
    with pytest.raises(WrinklesInputError):
        fit_ssdr(rest, np.zeros((2, 10, 3), np.float32), num_bones=2, max_influences=3)
    with pytest.raises(WrinklesInputError):
        fit_ssdr(rest, np.zeros((2, 10, 3), np.float32), num_bones=11)


def test_single_bone_recovers_rigid_motion():
    """A rigidly moving mesh with one bone: exact rotations and translations, zero error."""
    rest = _cylinder(rings=6, around=8)
    rot = Rotation.from_rotvec(np.random.default_rng(1).normal(size=(5, 3))).as_matrix()
    tr = np.random.default_rng(2).normal(size=(5, 3))
    frames = (np.einsum("tab,vb->tva", rot, rest) + tr[:, None]).astype(np.float32)
    res = fit_ssdr(rest.astype(np.float32), frames, num_bones=1, max_influences=1, iterations=2)
    np.testing.assert_allclose(res.rotations[:, 0], rot, atol=1e-5)
    np.testing.assert_allclose(res.translations[:, 0], tr, atol=1e-5)
    np.testing.assert_allclose(res.weight_val, 1.0)
    assert res.rmse < 1e-6


@pytest.mark.slow
def test_fit_bone_transforms_labels_new_frames(rig, fitted):
    """With the fitted weights fixed, new frames of the same rig get transforms that reconstruct
    them as well as the joint fit did (the CVAE's per-frame targets)."""
    rest, _, _ = rig
    _, _, new = _synthetic_rig(seed=11)  # same weights and rest, other motion
    rot, tr = fit_bone_transforms(rest, fitted.weight_idx, fitted.weight_val, new, iterations=4, chunk=7)
    assert rot.shape == (FRAMES, NUM_BONES, 3, 3) and tr.shape == (FRAMES, NUM_BONES, 3)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-4)
    rec = ssdr_reconstruct(fitted, rotations=rot, translations=tr)
    rmse = float(np.sqrt(np.mean(np.sum((rec - new) ** 2, axis=-1))))
    assert rmse < 3 * max(fitted.rmse, 1e-4), (rmse, fitted.rmse)
    # the fitted frames themselves: close to the joint fit (block descent converges slowly)
    _, _, frames = rig
    rot0, tr0 = fit_bone_transforms(rest, fitted.weight_idx, fitted.weight_val, frames, iterations=4)
    rec0 = ssdr_reconstruct(fitted, rotations=rot0, translations=tr0)
    assert np.sqrt(np.mean(np.sum((rec0 - frames) ** 2, axis=-1))) < 3 * fitted.rmse + 1e-4  # 0.1 mm
