"""Warp skinning kernels against the numpy reference and against exact rigid-body answers."""

from __future__ import annotations

import numpy as np
import pytest

from sim.rotations import axis_angle_to_matrix
from sim.skinning.lbs import csr, lbs_reference, sparse_weights
from tests.conftest import random_body

# float32 kernels vs float64 reference on O(1 m) coordinates: a few ulps of 1 m each step.
ATOL = 2e-5


@pytest.mark.parametrize("posedirs", [True, False])
def test_lbs_matches_numpy_reference(device, posedirs):
    body = random_body(posedirs=posedirs, seed=1)
    rng = np.random.default_rng(2)
    T = 9
    poses = (rng.normal(size=(T, 24, 3)) * 0.6).astype(np.float32)
    trans = rng.normal(size=(T, 3)).astype(np.float32)
    betas = rng.normal(size=8).astype(np.float32)
    frames = body.pose(betas, poses, trans, device=device)
    ref_v, ref_j = lbs_reference(body, betas, poses, trans)
    assert frames.vertices.shape == (T, body.num_vertices, 3)
    assert frames.vertices.dtype == np.float32
    np.testing.assert_allclose(frames.vertices, ref_v, atol=ATOL)
    np.testing.assert_allclose(frames.joints, ref_j, atol=ATOL)
    # world frames: rotation part is the accumulated chain rotation
    R = axis_angle_to_matrix(poses)
    np.testing.assert_allclose(frames.transforms[:, 0, :3, :3], R[:, 0], atol=1e-5)
    np.testing.assert_allclose(frames.transforms[:, 4, :3, :3], R[:, 0] @ R[:, 1] @ R[:, 4], atol=1e-5)


def test_zero_pose_is_rest_shape(device):
    body = random_body(seed=3)
    betas = np.linspace(-1, 1, 8).astype(np.float32)
    frames = body.pose(betas, np.zeros((2, 24, 3)), np.zeros((2, 3)), device=device)
    np.testing.assert_allclose(frames.vertices[0], body.rest_mesh(betas), atol=1e-6)
    np.testing.assert_allclose(frames.joints[1], body.rest_joints(betas), atol=1e-6)


def test_global_rotation_is_rigid(device):
    """Rotating only the root by 90 deg about Y rotates every vertex about the root joint."""
    body = random_body(seed=4, posedirs=True)  # pose blend shapes ignore the root (SMPL Eq. 9)
    poses = np.zeros((1, 24, 3), np.float32)
    poses[0, 0] = [0.0, np.pi / 2, 0.0]
    trans = np.array([[0.5, -0.25, 2.0]], np.float32)
    frames = body.pose(None, poses, trans, device=device)
    j0 = body.rest_joints()[0]
    Ry = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], np.float64)
    expect = (body.rest_mesh() - j0) @ Ry.T + j0 + trans[0]
    np.testing.assert_allclose(frames.vertices[0], expect, atol=ATOL)


def test_child_rotation_leaves_unweighted_vertices(device):
    """Bending joint 18 (left elbow) moves only vertices that joints 18/20/22 influence."""
    body = random_body(seed=5, posedirs=False)
    poses = np.zeros((1, 24, 3), np.float32)
    poses[0, 18] = [0.0, 0.0, 1.2]
    frames = body.pose(None, poses, None, device=device)
    moved = np.linalg.norm(frames.vertices[0] - body.rest_mesh(), axis=1) > 1e-6
    influenced = body.weights[:, [18, 20, 22]].sum(axis=1) > 0
    assert moved.any()
    assert not np.any(moved & ~influenced)


def test_chunking_does_not_change_result():
    body = random_body(seed=6)
    rng = np.random.default_rng(7)
    poses = (rng.normal(size=(11, 24, 3)) * 0.4).astype(np.float32)
    trans = rng.normal(size=(11, 3)).astype(np.float32)
    sk = body.skinner("cpu")
    full = sk.pose(None, poses, trans, chunk=64)
    parts = sk.pose(None, poses, trans, chunk=3)
    np.testing.assert_array_equal(full.vertices, parts.vertices)


def test_sparse_weights_is_exact():
    rng = np.random.default_rng(8)
    w = rng.random((50, 24))
    w[w < 0.7] = 0
    w[:, 3] += 0.01
    idx, val = sparse_weights(w)
    dense = np.zeros_like(w)
    np.add.at(dense, (np.repeat(np.arange(50), idx.shape[1]), idx.ravel()), val.ravel())
    np.testing.assert_allclose(dense, w, rtol=1e-6)
    assert idx.shape[1] == int((w != 0).sum(axis=1).max())


def test_csr_roundtrip():
    rng = np.random.default_rng(9)
    m = rng.random((24, 100))
    m[m < 0.9] = 0
    off, cols, vals = csr(m)
    back = np.zeros_like(m)
    for r in range(24):
        back[r, cols[off[r]:off[r + 1]]] = vals[off[r]:off[r + 1]]
    np.testing.assert_allclose(back, m, rtol=1e-6)


def test_bad_pose_input_is_user_error():
    from sim.errors import WrinklesInputError

    body = random_body(seed=10)
    with pytest.raises(WrinklesInputError, match="shape"):
        body.pose(None, np.zeros((3, 23, 3)), None, device="cpu")
    bad = np.zeros((3, 24, 3), np.float32)
    bad[1, 5, 0] = np.nan
    with pytest.raises(WrinklesInputError, match="NaN"):
        body.pose(None, bad, None, device="cpu")
    with pytest.raises(WrinklesInputError, match="shape coefficients"):
        body.pose(np.zeros(99), np.zeros((1, 24, 3)), None, device="cpu")
