"""The way into a motion from the rest pose (dressing starts at rest): a blend, or a procedural
motion's lead-in."""

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


# --- the way in: a procedural motion's lead-in -------------------------------------------------

def test_enter_from_rest_plays_a_procedural_lead_in():
    from sim.motions import procedural_motion
    from sim.motions.blend import enter_from_rest

    m = procedural_motion("walk", duration=0.5, fps=30.0, ramp=0.4)
    lead = m.extra["lead_in"]
    assert m.num_frames == 15 and lead.num_frames == 12
    b, n = enter_from_rest(m, 1.0, hold=0.2)  # the 1 s blend is not used: the lead-in is the way in
    assert n == 6 + 12 and b.num_frames == n + 15 and b.extra["prefix_frames"] == n
    assert "lead_in" not in b.extra
    np.testing.assert_array_equal(b.poses[:6], 0.0)  # the hold at rest ...
    np.testing.assert_array_equal(b.trans[:6], np.repeat(lead.trans[:1], 6, axis=0))  # ... where it starts
    np.testing.assert_array_equal(b.poses[6:n], lead.poses)
    np.testing.assert_array_equal(b.poses[n:], m.poses)
    np.testing.assert_array_equal(b.trans[n:], m.trans)
    # the walk reaches z = 0 at full speed at t = 0, from rest 0.4 s behind
    z = b.trans[:, 2].astype(np.float64)
    assert b.trans[n, 2] == 0.0 and z[6] < -0.2
    assert abs(z[7] - z[6]) < 1e-4  # leaves rest at ~zero speed
    np.testing.assert_allclose((z[n + 1] - z[n]) * 30.0, 1.3, rtol=1e-5)
    assert abs((z[n] - z[n - 1]) * 30.0 - 1.3) < 0.01  # no speed jump into the clip
    # a motion without a lead-in is blended (the same frames as blend_from_rest)
    f = motion_starting_bent()
    a, k = enter_from_rest(f, 1.0, hold=0.2)
    c, kc = blend_from_rest(f, 1.0, hold=0.2)
    assert k == kc == 36
    np.testing.assert_array_equal(a.poses, c.poses)
    with pytest.raises(WrinklesInputError, match="walk"):
        enter_from_rest(m, -1.0)


def test_resampling_keeps_the_lead_in_in_step():
    from sim.motions import procedural_motion, resample_motion
    from sim.motions.blend import enter_from_rest
    from sim.simulate import SimulationConfig

    m = procedural_motion("walk", duration=1.0, fps=30.0, ramp=0.8)
    lead = m.extra["lead_in"]
    r = resample_motion(m, 60.0)
    rl = r.extra["lead_in"]
    assert r.num_frames == 60 and rl.num_frames == 48 and rl.fps == 60.0
    np.testing.assert_array_equal(rl.poses[0], 0.0)
    np.testing.assert_array_equal(rl.trans[::2], lead.trans)  # shared times: t = -k / 30
    np.testing.assert_allclose(rl.trans[-1], 0.5 * (lead.trans[-1] + m.trans[0]), atol=1e-6)  # t = -1/60
    # 24 frames of 0.6 s at 40 fps -> 24 fps: ceil(14.4) = 15 frames, the first still at rest
    j = procedural_motion("jump", duration=0.5, fps=40.0)
    rj = resample_motion(j, 24.0).extra["lead_in"]
    assert j.extra["lead_in"].num_frames == 24 and rj.num_frames == 15
    np.testing.assert_array_equal(rj.poses[0], 0.0)
    # the simulation's solver steps count the lead-in at the run's fps
    cfg = SimulationConfig(fps=60.0, settle_seconds=0.5, blend_seconds=1.0)
    timeline, _ = enter_from_rest(r, cfg.blend_seconds, hold=cfg.settle_seconds)
    assert cfg.solver_steps(m) == timeline.num_frames - 1 == 30 + 48 + 60 - 1
    assert cfg.solver_steps(motion_starting_bent()) == 30 + 60 + 20 - 1
    assert cfg.solver_steps(10) == 30 + 60 + 10 - 1
