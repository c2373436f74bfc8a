"""Motions: conventions, joint limits, resampling, the registry and the procedural library.

Everything runs on CPU. Kinematics are checked by forward kinematics on SMPL's approximate
skeleton (``sim.motions.retarget.SMPL_REST_JOINTS``). The file loaders are tested in
test_motion_files.py, the gaits on a skinned body in test_gaits.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.motions import (
    PROCEDURAL_MOTIONS,
    list_motions,
    load_motion,
    procedural_motion,
    resample_motion,
)
from sim.motions.limits import JOINT_LIMITS, limit_violation, within_limits
from sim.motions.procedural import GRAVITY, JOINT, center_of_mass, contact_heights
from sim.motions.resample import resample_times, slerp_axis_angle
from sim.motions.retarget import forward_kinematics
from sim.motions.skeleton import MotionSkeleton
from sim.rotations import axis_angle_to_matrix
from sim.types import Motion

CMU = Path(__file__).parent / "data" / "cmu_style.bvh"

_REST_FLOOR = MotionSkeleton.default().rest_floor  # the approximate skeleton's floor


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _aa(axis: str, deg: float) -> np.ndarray:
    v = np.zeros(3)
    v["xyz".index(axis)] = np.deg2rad(deg)
    return v


# --- conventions ------------------------------------------------------------------------------

def test_smpl_axis_signs_by_forward_kinematics():
    """The signs documented in sim.motions.limits, checked on SMPL's skeleton."""
    def fk(joint: str, axis: str, deg: float) -> np.ndarray:
        p = np.zeros((24, 3))
        p[JOINT[joint]] = _aa(axis, deg)
        return forward_kinematics(p)[1]

    _, rest = forward_kinematics(np.zeros((24, 3)))
    d = fk("left_knee", "x", 60) - rest
    assert d[JOINT["left_ankle"], 2] < -0.1                     # knee flexion +X: foot back
    assert fk("right_knee", "x", 60)[JOINT["right_ankle"], 2] < rest[JOINT["right_ankle"], 2] - 0.1
    assert fk("left_hip", "x", -45)[JOINT["left_knee"], 2] > rest[JOINT["left_knee"], 2] + 0.1
    assert fk("left_ankle", "x", -20)[JOINT["left_foot"], 1] > rest[JOINT["left_foot"], 1]
    assert fk("spine1", "x", 30)[JOINT["head"], 2] > rest[JOINT["head"], 2] + 0.1
    assert fk("left_shoulder", "z", -70)[JOINT["left_elbow"], 1] < rest[JOINT["left_elbow"], 1] - 0.1
    assert fk("right_shoulder", "z", 70)[JOINT["right_elbow"], 1] < rest[JOINT["right_elbow"], 1] - 0.1
    assert fk("left_shoulder", "y", -45)[JOINT["left_elbow"], 2] > rest[JOINT["left_elbow"], 2] + 0.1
    assert fk("left_elbow", "y", -90)[JOINT["left_wrist"], 2] > rest[JOINT["left_wrist"], 2] + 0.1
    assert fk("right_elbow", "y", 90)[JOINT["right_wrist"], 2] > rest[JOINT["right_wrist"], 2] + 0.1
    assert fk("left_hip", "z", 30)[JOINT["left_ankle"], 0] > rest[JOINT["left_ankle"], 0] + 0.1


def test_joint_limit_table():
    assert JOINT_LIMITS.shape == (24, 3, 2)
    assert np.all(JOINT_LIMITS[..., 0] <= 0) and np.all(JOINT_LIMITS[..., 1] >= 0)
    left, right = JOINT["left_shoulder"], JOINT["right_shoulder"]
    np.testing.assert_allclose(JOINT_LIMITS[right, 0], JOINT_LIMITS[left, 0])
    np.testing.assert_allclose(JOINT_LIMITS[right, 1:], -JOINT_LIMITS[left, 1:, ::-1])
    assert within_limits(np.zeros((3, 24, 3)))
    bad = np.zeros((24, 3))
    bad[JOINT["left_knee"], 0] = -0.5  # hyperextended knee
    assert not within_limits(bad)
    assert limit_violation(bad)[JOINT["left_knee"], 0] == pytest.approx(0.5)


# --- resampling -------------------------------------------------------------------------------

def _random_motion(T: int, fps: float, seed: int = 0) -> Motion:
    rng = np.random.default_rng(seed)
    poses = np.cumsum(rng.normal(0, 0.05, (T, 24, 3)), axis=0)
    trans = np.cumsum(rng.normal(0, 0.01, (T, 3)), axis=0)
    return Motion(poses=poses, trans=trans, fps=fps, name="r")


@pytest.mark.parametrize("fps_in,fps_out", [(30, 24), (120, 30), (30, 60), (24, 30), (60, 50)])
def test_resample_keeps_duration_and_shared_frames(fps_in, fps_out):
    m = _random_motion(48, fps_in)
    r = resample_motion(m, fps_out)
    assert r.fps == fps_out
    assert abs(r.duration - m.duration) <= 0.5 / fps_out
    assert r.poses.dtype == np.float32 and r.poses.shape == (r.num_frames, 24, 3)
    # frames at shared timestamps are copied exactly
    for k in range(r.num_frames):
        src = k * fps_in / fps_out
        if abs(src - round(src)) < 1e-9 and round(src) < m.num_frames:
            np.testing.assert_array_equal(r.poses[k], m.poses[round(src)])
            np.testing.assert_array_equal(r.trans[k], m.trans[round(src)])


def test_resample_times_and_linear_translation():
    idx, frac = resample_times(4, 30, 60)
    np.testing.assert_array_equal(idx, [0, 0, 1, 1, 2, 2, 3, 3])
    np.testing.assert_allclose(frac, [0, 0.5, 0, 0.5, 0, 0.5, 0, 0])  # past the end: hold
    m = Motion(poses=np.zeros((3, 24, 3)), trans=[[0, 0, 0], [1, 2, 3], [2, 4, 6]], fps=10)
    r = resample_motion(m, 20)
    np.testing.assert_allclose(r.trans[1], [0.5, 1.0, 1.5], atol=1e-7)


def test_slerp_axis_angle():
    a, b = _aa("z", 0), _aa("z", 90)
    np.testing.assert_allclose(slerp_axis_angle(a, b, 0.5), _aa("z", 45), atol=1e-12)
    np.testing.assert_allclose(slerp_axis_angle(a, b, 0.25), _aa("z", 22.5), atol=1e-12)
    # shortest arc across +-180: 170 deg and -170 deg about X meet at 180 deg
    mid = slerp_axis_angle(_aa("x", 170), _aa("x", -170), 0.5)
    np.testing.assert_allclose(np.abs(mid), [np.pi, 0, 0], atol=1e-9)
    # geodesic: equal angles to both ends, on a general pair
    rng = np.random.default_rng(1)
    r0, r1 = rng.normal(size=3), rng.normal(size=3)
    m = axis_angle_to_matrix(slerp_axis_angle(r0, r1, 0.5))
    R0, R1 = axis_angle_to_matrix(r0), axis_angle_to_matrix(r1)

    def angle(A, B):
        return np.arccos(np.clip((np.trace(A.T @ B) - 1) / 2, -1, 1))

    assert angle(R0, m) == pytest.approx(angle(m, R1), abs=1e-9)
    assert angle(R0, m) == pytest.approx(0.5 * angle(R0, R1), abs=1e-9)


# --- registry, load_motion ----------------------------------------------------------------------

def test_registry_and_errors(tmp_path):
    names = [n for n, _ in list_motions()]
    for required in ("walk", "run", "jump", "squat", "arm_raise", "torso_twist", "random",
                     "rest_to_apose"):
        assert required in names
    assert all(isinstance(d, str) and d for _, d in list_motions())
    with pytest.raises(WrinklesInputError, match="available: walk"):
        load_motion("moonwalk")
    with pytest.raises(WrinklesInputError, match="allowed: duration, fps, speed"):
        procedural_motion("walk", sped=1.0)
    with pytest.raises(WrinklesInputError, match="speed"):
        procedural_motion("walk", speed=-1.0)
    with pytest.raises(WrinklesInputError, match="style"):
        procedural_motion("arm_raise", style="up")
    with pytest.raises(WrinklesInputError, match=r"\.fbx"):
        load_motion(str(tmp_path / "a.fbx"))
    with pytest.raises(WrinklesInputError, match="allowed: joint_map"):
        load_motion(str(CMU), speed=2.0)
    with pytest.raises(WrinklesInputError, match="lasts only"):
        load_motion(str(CMU), duration=10.0)
    assert load_motion(str(CMU), duration=2 / 120).num_frames == 2


@pytest.mark.parametrize("name", list(PROCEDURAL_MOTIONS))
def test_every_motion_finite_with_requested_duration(name):
    m = load_motion(name, fps=24.0, duration=1.7)
    T = round(1.7 * 24)
    assert m.poses.shape == (T, 24, 3) and m.trans.shape == (T, 3)
    assert m.poses.dtype == np.float32 and m.trans.dtype == np.float32
    assert np.all(np.isfinite(m.poses)) and np.all(np.isfinite(m.trans))
    assert m.fps == 24.0 and m.source == f"procedural:{name}"
    lead = m.extra.get("lead_in")
    if name == "rest_to_apose":  # the transition from rest is the motion itself
        assert lead is None
        np.testing.assert_allclose(m.poses[0], 0.0, atol=1e-7)
        return
    # the lead-in before t = 0: its ramp (1 s, or the jump's 0.6 s) from rest, zero velocity there
    assert lead.num_frames == round(PROCEDURAL_MOTIONS[name].params().ramp * 24) and lead.fps == 24.0
    np.testing.assert_allclose(lead.poses[0], 0.0, atol=1e-7)
    np.testing.assert_allclose(lead.trans[0, :2], 0.0, atol=1e-7)
    assert np.abs(lead.poses[1] - lead.poses[0]).max() < 0.03
    assert np.abs(lead.trans[1] - lead.trans[0]).max() < 0.01
    # it joins the clip without a velocity jump: the second difference across t = 0 is no larger
    # than the clip's own (a jump to full speed would be speed / fps: 5 cm for the walk)
    for a, b in ((lead.poses, m.poses), (lead.trans, m.trans)):
        x = np.concatenate([a, b]).astype(np.float64)
        k = a.shape[0]
        across = np.abs(x[k + 1] - 2 * x[k] + x[k - 1]).max()
        assert across <= 1.25 * np.abs(np.diff(x[k:], 2, axis=0)).max() + 1e-3, (name, across)


# --- procedural kinematics -------------------------------------------------------------------------

def test_walk_gait_kinematics():
    fps, speed = 30.0, 1.2
    m = procedural_motion("walk", duration=6.0, fps=fps, speed=speed, stride=1.2)  # 1 stride/s
    steady = slice(None)  # the 1 s ramp is the lead-in, before t = 0
    rk, lk = (np.degrees(m.poses[:, JOINT[f"{s}_knee"], 0]) for s in ("right", "left"))
    # knee flexion peaks in swing at ~60 deg (Perry; Winter)
    cyc = slice(90, 120)
    k = int(np.argmax(rk[cyc])) + 90
    assert 55.0 < rk[k] < 65.0
    assert 0.62 < np.mod(m.extra["phase"][k], 1.0) < 0.85
    # the legs are half a stride (15 frames) apart
    np.testing.assert_allclose(lk[75:150], rk[90:165], atol=1e-3)
    # forward speed along +Z from the first frame, which is at z = 0; nothing sideways
    z = m.trans[:, 2].astype(np.float64)
    np.testing.assert_allclose(np.diff(z) * fps, speed, rtol=1e-4)
    assert z[0] == 0.0 and m.extra["phase"][0] == 0.0  # the right heel strikes at t = 0
    np.testing.assert_allclose(m.trans[:, 0], 0.0)
    # a foot is always on the floor, and the pelvis bobs a few centimetres
    G, P = forward_kinematics(m.poses, m.trans)
    np.testing.assert_allclose(contact_heights(G, P).min(axis=1), _REST_FLOOR, atol=1e-5)
    bob = np.ptp(m.trans[steady, 1])
    assert 0.01 < bob < 0.06
    # the arms swing against the legs: left arm forward while the right hip flexes
    lw = P[steady, JOINT["left_wrist"], 2] - P[steady, JOINT["pelvis"], 2]
    rhip = -m.poses[steady, JOINT["right_hip"], 0]
    assert np.corrcoef(lw, rhip)[0, 1] > 0.8
    # the stance foot does not slide (stride calibration), mid single support
    ph = np.mod(m.extra["phase"], 1.0)
    mid = (ph > 0.1) & (ph < 0.45)
    vz = np.gradient(P[:, JOINT["right_ankle"], 2]) * fps
    assert abs(vz[mid].mean()) < 0.05
    # resampling carries the per-frame gait phase along
    r = resample_motion(m, 60.0)
    assert r.extra["phase"].shape == (r.num_frames,)
    # default stride relation: ~110 steps/min at 1.3 m/s
    d = procedural_motion("walk", duration=1.0)
    assert 2 * 60 * d.extra["stride_frequency"] == pytest.approx(110, abs=5)


def test_run_has_ballistic_flight():
    fps = 240.0
    m = procedural_motion("run", duration=3.0, fps=fps, speed=3.5)
    G, P = forward_kinematics(m.poses, m.trans)
    low = contact_heights(G, P).min(axis=1)
    steady = np.arange(m.num_frames) > 1.2 * fps
    airborne = steady & (low > _REST_FLOOR + 0.005)
    assert airborne.sum() > 10  # both feet off the ground
    phase = np.mod(m.extra["phase"], 0.5)
    fly = steady & (phase > m.extra["duty"] + 0.01) & (phase < 0.49)
    y = m.trans[:, 1].astype(np.float64)
    idx = np.nonzero(fly[1:-1] & fly[:-2] & fly[2:])[0] + 1
    acc = (y[idx + 1] - 2 * y[idx] + y[idx - 1]) * fps**2
    np.testing.assert_allclose(acc, -GRAVITY, atol=0.05 * GRAVITY)
    knee = np.degrees(m.poses[steady, JOINT["right_knee"], 0])
    assert knee.max() > 85.0  # deeper swing knee flexion than walking
    assert np.mean(np.diff(m.trans[steady, 2])) * fps == pytest.approx(3.5, rel=1e-4)


def test_jump_flight_follows_gravity():
    fps, h = 100.0, 0.3
    m = procedural_motion("jump", duration=3.0, fps=fps, height=h)
    t = np.arange(m.num_frames) / fps
    t0, tf = m.extra["takeoff_time"], m.extra["flight_time"]
    fly = (t >= t0) & (t < t0 + tf)
    assert fly.sum() > 30
    y = m.trans[fly, 1].astype(np.float64)
    tau = t[fly] - t0
    a, b, c = np.polyfit(tau, y, 2)
    assert a == pytest.approx(-GRAVITY / 2, rel=1e-4)  # y = y0 + v0 tau - g tau^2 / 2
    assert b == pytest.approx(np.sqrt(2 * GRAVITY * h), rel=1e-4)
    assert y.max() - c == pytest.approx(h, abs=0.005)  # apex [sampled at 100 fps]
    # countermovement: the root goes down before it goes up; lands and recovers to standing
    assert m.trans[t < t0, 1].min() < -0.1
    np.testing.assert_allclose(m.trans[-1], 0.0, atol=0.01)
    assert np.degrees(m.poses[t < t0, JOINT["left_knee"], 0]).max() == pytest.approx(80, abs=1)


def test_squat_keeps_feet_and_balance():
    m = procedural_motion("squat", duration=4.0, fps=30.0, depth_deg=100.0, period=2.5)
    G, P = forward_kinematics(m.poses, m.trans)
    _, P0 = forward_kinematics(np.zeros((24, 3)))
    ankles = [JOINT["left_ankle"], JOINT["right_ankle"]]
    np.testing.assert_allclose(P[:, ankles].mean(axis=1)[:, [0, 2]], np.broadcast_to(
        P0[ankles].mean(axis=0)[[0, 2]], (m.num_frames, 2)), atol=1e-5)  # feet stay put...
    # ...each within a centimetre (SMPL's legs are not mirror images, the angles are)
    for j in ("left_ankle", "right_ankle", "left_foot", "right_foot"):
        np.testing.assert_allclose(P[:, JOINT[j]], np.broadcast_to(P0[JOINT[j]], P[:, 0].shape),
                                   atol=0.015)
    # feet flat: the lowest contact on the floor, heels and toes within 2 cm of it
    heights = contact_heights(G, P)
    np.testing.assert_allclose(heights.min(axis=1), _REST_FLOOR, atol=1e-5)
    np.testing.assert_allclose(heights, _REST_FLOOR, atol=0.02)
    knee = np.degrees(m.poses[:, JOINT["left_knee"], 0])
    assert knee.max() == pytest.approx(100.0, abs=1.0)
    bottom = int(np.argmax(knee))
    assert m.trans[bottom, 1] < -0.25  # the pelvis goes down...
    assert m.trans[bottom, 2] < -0.05  # ...and back
    com = center_of_mass(P)[:, 2] - P0[JOINT["left_ankle"], 2]
    com0 = center_of_mass(P0)[2] - P0[JOINT["left_ankle"], 2]
    np.testing.assert_allclose(com, com0, atol=0.015)  # centre of mass stays over the feet


def test_random_motion_limits_and_seed():
    a = procedural_motion("random", duration=4.0, fps=30.0, seed=7, amplitude=1.0)
    b = procedural_motion("random", duration=4.0, fps=30.0, seed=7, amplitude=1.0)
    c = procedural_motion("random", duration=4.0, fps=30.0, seed=8, amplitude=1.0)
    assert within_limits(a.poses, tol=1e-6)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.trans, b.trans)
    assert np.abs(a.poses - c.poses).max() > 0.1
    assert np.abs(np.diff(a.poses, axis=0)).max() < 0.25  # smooth at 30 fps, full amplitude
    # uses a good part of the ranges
    assert np.abs(a.poses[60:]).max() > 0.5


def test_rest_to_apose_and_arm_raise_end_poses():
    m = procedural_motion("rest_to_apose", duration=2.0, fps=30.0, angle_deg=45.0)
    _, P = forward_kinematics(m.poses[-1])
    arm = _unit(P[JOINT["left_wrist"]] - P[JOINT["left_shoulder"]])
    assert np.degrees(np.arcsin(-arm[1])) == pytest.approx(45.0, abs=1.0)
    top = 30  # half a period after t = 0, where the arms hang at the sides
    for style in ("front", "side"):
        r = procedural_motion("arm_raise", duration=3.0, fps=30.0, style=style, period=2.0,
                              elevation_deg=160.0)
        _, P = forward_kinematics(r.poses)
        hang = _unit(P[0, JOINT["left_elbow"]] - P[0, JOINT["left_shoulder"]])
        assert np.degrees(np.arccos(-hang[1])) == pytest.approx(15.0, abs=4.0)  # at the side at t = 0
        for side in ("left", "right"):
            arm = _unit(P[top, JOINT[f"{side}_elbow"]] - P[top, JOINT[f"{side}_shoulder"]])
            # SMPL's rest arm droops ~3 deg below the horizontal
            assert np.degrees(np.arccos(-arm[1])) == pytest.approx(160.0, abs=4.0)
            if style == "front":
                assert arm[2] > 0.2  # went up in front, not to the side
