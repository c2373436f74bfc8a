"""Blending a motion in from the rest pose (dressing starts at rest)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.motions.blend import blend_from_rest
from sim.rotations import axis_angle_to_matrix
from sim.types import Motion


def motion_starting_bent(T: int = 10) -> Motion:
    poses = np.zeros((T, 24, 3), np.float32)
    poses[:, 0] = [0.0, 1.0, 0.0]  # root turned 1 rad about Y
    poses[:, 18] = [0.0, 0.0, -1.2]  # left elbow bent
    trans = np.tile([[0.3, 0.9, -0.2]], (T, 1)).astype(np.float32)
    return Motion(poses=poses, trans=trans, fps=30.0, name="bent")


def test_blend_starts_at_rest_and_reaches_first_frame():
    m = motion_starting_bent()
    b, n = blend_from_rest(m, 1.0, hold=0.2)
    assert n == 36 and b.num_frames == m.num_frames + 36
    assert b.extra["prefix_frames"] == 36
    np.testing.assert_array_equal(b.poses[:6], 0.0)  # the 0.2 s hold at rest
    np.testing.assert_array_equal(b.poses[n:], m.poses)
    np.testing.assert_array_equal(b.trans[:n], np.repeat(m.trans[:1], n, axis=0))
    # elbow angle rises monotonically from 0 to 1.2 rad, with small steps at both ends (eased)
    ang = np.linalg.norm(b.poses[: n + 1, 18], axis=1)
    assert np.all(np.diff(ang) >= -1e-6)
    steps = np.diff(ang[6:])
    assert steps[0] < 0.25 * steps.max() and steps[-1] < 0.25 * steps.max()
    # rotations interpolate on the sphere: halfway is half the angle about the same axis
    half = 6 + 15
    R = axis_angle_to_matrix(b.poses[half, 18])
    np.testing.assert_allclose(np.linalg.norm(b.poses[half, 18]), 0.6, atol=1e-5)
    np.testing.assert_allclose(R[2, 2], 1.0, atol=1e-6)  # rotation about Z only


def test_zero_blend_is_identity():
    m = motion_starting_bent()
    b, n = blend_from_rest(m, 0.0)
    assert n == 0 and b is m


def test_negative_blend_is_user_error():
    with pytest.raises(WrinklesInputError, match="bent"):
        blend_from_rest(motion_starting_bent(), -1.0)
