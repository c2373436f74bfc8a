"""DeepWrinkles' pose-to-shape maps (``learn.deepwrinkles.regression``, Lähner et al. Sec. 3.3):
the control vector's physics (root velocity and acceleration, heading invariance), the linear
map's least-squares solution, and the LSTM encoder-decoder learning a motion-dependent map the
linear one cannot."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learn.deepwrinkles.regression import (
    ROOT_MOTION,
    LinearPoseToShape,
    PoseToShapeLSTM,
    control_columns,
    control_vectors,
    windows,
)
from sim.errors import WrinklesInputError
from sim.rotations import axis_angle_to_matrix, matrix_to_axis_angle


def motion(frames: int = 40, seed: int = 0):
    rng = np.random.default_rng(seed)
    poses = rng.normal(scale=0.3, size=(frames, 24, 3))
    t = np.arange(frames) / 30.0
    trans = np.stack([0.5 * t ** 2, 0.9 + 0.0 * t, 1.2 * t], axis=1)  # accelerating along x, walking along z
    return poses, trans


def test_root_velocity_and_acceleration_are_the_translations_derivatives_in_the_heading_frame():
    poses, trans = motion()
    poses[:, 0] = 0.0  # root facing +Z: the heading frame is the world's
    th = control_vectors(poses, trans, 30.0)
    assert th.shape == (40, 6 * 24 + ROOT_MOTION)
    vel, acc = th[:, -6:-3], th[:, -3:]
    inner = slice(2, -2)  # central differences are exact for a quadratic away from the ends
    np.testing.assert_allclose(vel[inner, 0], (np.arange(40) / 30.0)[inner], atol=1e-5)
    np.testing.assert_allclose(vel[inner, 2], 1.2, atol=1e-5)
    np.testing.assert_allclose(acc[inner], np.broadcast_to([1.0, 0.0, 0.0], acc[inner].shape), atol=1e-3)


def test_turning_the_whole_motion_about_the_vertical_leaves_the_control_vectors():
    poses, trans = motion(seed=1)
    turn = axis_angle_to_matrix(np.array([[0.0, 1.1, 0.0]]))[0]
    root = axis_angle_to_matrix(poses[:, 0])
    turned = poses.copy()
    turned[:, 0] = matrix_to_axis_angle(turn @ root)
    a = control_vectors(poses, trans, 30.0)
    b = control_vectors(turned, trans @ turn.T, 30.0)
    np.testing.assert_allclose(a, b, atol=2e-5)
    tilted = poses.copy()  # a tilt against gravity is not a heading: it changes Θ
    tilted[:, 0] = matrix_to_axis_angle(axis_angle_to_matrix(np.array([[0.4, 0.0, 0.0]]))[0] @ root)
    assert np.abs(control_vectors(tilted, trans, 30.0)[:, :6] - a[:, :6]).max() > 0.1


def test_the_linear_map_is_the_least_squares_solution():
    rng = np.random.default_rng(2)
    th = rng.normal(size=(200, 12))
    f = rng.normal(size=(5, 12))
    lam = th @ f.T + [1.0, -2.0, 0.5, 0.0, 3.0]
    lin = LinearPoseToShape.fit(th, lam)
    np.testing.assert_allclose(lin(th), lam, atol=1e-4)  # exactly linear data: recovered
    noisy = lam + rng.normal(scale=0.1, size=lam.shape)
    fit = LinearPoseToShape.fit(th, noisy)
    a = np.concatenate([th, np.ones((200, 1))], axis=1)
    np.testing.assert_allclose(fit.matrix.T, np.linalg.pinv(a) @ noisy, atol=1e-8)  # F = Λ Θ†
    shrunk = LinearPoseToShape.fit(th, noisy, ridge=1e3)
    assert np.abs(shrunk.matrix[:, :-1]).sum() < np.abs(fit.matrix[:, :-1]).sum()


def test_the_lstm_learns_what_depends_on_the_motion_before_a_frame():
    """Coefficients that follow the change of the control signal over the window (the
    direction of a movement), which a per-frame linear map cannot see: the LSTM's error falls
    well below the linear map's on the same frames."""
    torch.manual_seed(0)
    rng = np.random.default_rng(3)
    th = np.cumsum(rng.normal(scale=0.3, size=(400, 4)), axis=0).astype(np.float32)
    th -= th.mean(axis=0)
    target = np.concatenate([th[:1], np.diff(th, axis=0)])[:, :2] * 3.0  # the last step's change
    lin_err = float(np.mean((LinearPoseToShape.fit(th, target)(th) - target) ** 2))
    x = torch.from_numpy(windows(th, 3))
    y = torch.from_numpy(target.astype(np.float32))
    model = PoseToShapeLSTM(4, 2, hidden=32, layers=2)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    for _ in range(200):
        opt.zero_grad()
        loss = torch.mean((model(x)[:, -1] - y) ** 2)
        loss.backward()
        opt.step()
    assert loss.item() < 0.1 * lin_err


def test_windows_end_at_each_frame_and_bad_input_is_refused():
    th = np.arange(10, dtype=np.float32).reshape(5, 2)
    w = windows(th, 3)
    assert w.shape == (5, 3, 2)
    np.testing.assert_array_equal(w[0], th[[0, 0, 0]])
    np.testing.assert_array_equal(w[4], th[[2, 3, 4]])
    with pytest.raises(WrinklesInputError, match="expected"):
        control_vectors(np.zeros((4, 24, 3)), np.zeros((3, 3)), 30.0)
    with pytest.raises(WrinklesInputError, match="same number of frames"):
        LinearPoseToShape.fit(np.zeros((4, 2)), np.zeros((3, 1)))
    with pytest.raises(WrinklesInputError, match=r"\(B, W, 4\)"):
        PoseToShapeLSTM(4, 2, hidden=8, layers=1)(torch.zeros(2, 3, 5))


def test_upper_body_controls_follow_the_arms_and_ignore_the_legs():
    """Sec. 5.3's restriction for shirts: Θ keeps the upper body's joints and the root motion, so
    bending a knee leaves it and bending an elbow or walking faster changes it."""
    poses, trans = motion()
    cols = control_columns("upper", 24)
    assert len(cols) == 6 * 11 + ROOT_MOTION and len(control_columns("all", 24)) == 6 * 24 + ROOT_MOTION
    base = control_vectors(poses, trans, 30.0)[:, cols]
    knee, elbow = poses.copy(), poses.copy()
    knee[:, 4] += [0.8, 0.0, 0.0]  # left knee
    elbow[:, 18] += [0.0, 0.0, 0.8]  # left elbow
    np.testing.assert_array_equal(control_vectors(knee, trans, 30.0)[:, cols], base)
    assert np.abs(control_vectors(elbow, trans, 30.0)[:, cols] - base).max() > 0.1
    faster = control_vectors(poses, 2 * trans, 30.0)[:, cols]  # twice the root velocity and acceleration
    np.testing.assert_allclose(faster[:, -ROOT_MOTION:], 2 * base[:, -ROOT_MOTION:], rtol=1e-5, atol=1e-6)
    lower = control_columns("lower", 24)
    np.testing.assert_array_equal(control_vectors(elbow, trans, 30.0)[:, lower],
                                  control_vectors(poses, trans, 30.0)[:, lower])
    with pytest.raises(WrinklesInputError, match="need 20 joints, the motion has 10"):
        control_columns("upper", 10)
