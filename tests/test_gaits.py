"""Gaits and other procedural motions on a skinned body: the body's own skeleton and soles
(``MotionSkeleton.from_body``), feet on the floor, no sliding stance foot, hips inside the joint
limits, arms clear of the torso. The embedded default body is skinned on cpu.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim.motions import load_motion, procedural_motion
from sim.motions.limits import JOINT_LIMITS, within_limits
from sim.motions.procedural import JOINT
from sim.motions.retarget import SMPL_REST_JOINTS
from sim.motions.skeleton import MotionSkeleton
from sim.types import Motion

CMU = Path(__file__).parent / "data" / "cmu_style.bvh"
TOL_FLOOR = 0.01    # [m] lowest skinned vertex from the floor, body-aware motions


@pytest.fixture(scope="module")
def default_body():
    from sim.bodies import load_body

    return load_body()


def _floor_heights(body, motion: Motion, betas=None) -> np.ndarray:
    """Lowest skinned vertex per frame [m] after grounding frame 0 (a foot on the floor there)."""
    from sim.bodies.placement import ground

    frames, _ = ground(body.pose_motion(motion, betas, device="cpu"))
    return frames.vertices[:, :, 1].min(axis=1)


def test_skeleton_default_and_from_body(default_body):
    d = MotionSkeleton.default()
    assert d is MotionSkeleton.default()
    np.testing.assert_array_equal(d.rest_joints, SMPL_REST_JOINTS)
    assert d.num_contacts == 4
    assert d.rest_floor == pytest.approx(min(SMPL_REST_JOINTS[7, 1] - 0.075,
                                             SMPL_REST_JOINTS[10, 1] - 0.02))
    b = default_body
    s = MotionSkeleton.from_body(b)
    np.testing.assert_allclose(s.rest_joints, b.rest_joints()[b.body_joint_map], atol=1e-6)
    # the contact points are sole vertices: the lowest is the rest mesh's lowest vertex
    assert s.rest_floor == pytest.approx(float(b.rest_mesh()[:, 1].min()), abs=1e-6)
    assert set(s.contact_foot.tolist()) == {0, 1}
    np.testing.assert_allclose(s.contact_weights.sum(axis=1), 1.0)
    left = s.contact_points[s.contact_foot == 0]
    assert np.all(left[:, 0] > 0.03)  # the left foot is on +X
    # the contacts are posed like the skinned mesh: the lowest equals the lowest vertex
    m = procedural_motion("walk", duration=1.5, fps=10.0, skeleton=s)
    G, P = s.forward_kinematics(m.poses, m.trans)
    frames = b.pose_motion(m, device="cpu")
    np.testing.assert_allclose(s.contact_heights(G, P).min(axis=1),
                               frames.vertices[:, :, 1].min(axis=1), atol=1e-3)
    # a body without some SMPL joints: they keep the default offsets from their parents
    class NoHands:
        def __init__(self, body):
            self._b, self.weights, self.parents = body, body.weights, body.parents
            self.body_joint_map = body.body_joint_map.copy()
            self.body_joint_map[22:] = -1

        def rest_joints(self, betas=None):
            return self._b.rest_joints(betas)

        def rest_mesh(self, betas=None):
            return self._b.rest_mesh(betas)

    h = MotionSkeleton.from_body(NoHands(b))
    for j, w in ((22, 20), (23, 21)):
        np.testing.assert_allclose(h.rest_joints[j] - h.rest_joints[w],
                                   SMPL_REST_JOINTS[j] - SMPL_REST_JOINTS[w], atol=1e-9)
    assert h.rest_floor == pytest.approx(s.rest_floor)


@pytest.mark.parametrize("name", ["walk", "idle", "squat"])
def test_body_aware_feet_stay_on_floor(default_body, name):
    sk = MotionSkeleton.from_body(default_body)
    m = load_motion(name, fps=30.0, duration=2.0, skeleton=sk)
    low = _floor_heights(default_body, m)
    np.testing.assert_allclose(low, 0.0, atol=TOL_FLOOR)


def test_body_aware_walk_stance_foot_does_not_slide(default_body):
    fps = 30.0
    sk = MotionSkeleton.from_body(default_body)
    m = procedural_motion("walk", duration=3.0, fps=fps, speed=1.2, stride=1.2, skeleton=sk)
    _, P = sk.forward_kinematics(m.poses, m.trans)
    ph = np.mod(m.extra["phase"], 1.0)
    mid = (np.arange(m.num_frames) > 40) & (ph > 0.1) & (ph < 0.45)
    assert mid.sum() >= 5
    vz = np.gradient(P[:, JOINT["right_ankle"], 2]) * fps
    assert abs(vz[mid].mean()) < 0.05


def test_body_aware_run_never_sinks_and_flies(default_body):
    sk = MotionSkeleton.from_body(default_body)
    m = procedural_motion("run", duration=2.0, fps=60.0, skeleton=sk)
    low = _floor_heights(default_body, m)
    assert low.min() > -TOL_FLOOR
    phase = np.mod(m.extra["phase"], 0.5)
    steady = np.ones(m.num_frames, bool)  # the ramp is the lead-in, before t = 0
    fly = steady & (phase > m.extra["duty"] + 0.02) & (phase < 0.48)
    assert fly.sum() >= 3 and np.all(low[fly] > 0.002)
    stance = steady & (phase > 0.05) & (phase < m.extra["duty"] - 0.05)
    np.testing.assert_allclose(low[stance], 0.0, atol=TOL_FLOOR)  # stance foot on the floor


def test_body_aware_jump_lands_on_floor(default_body):
    sk = MotionSkeleton.from_body(default_body)
    m = procedural_motion("jump", duration=3.0, fps=30.0, height=0.3, skeleton=sk)
    low = _floor_heights(default_body, m)
    t = np.arange(m.num_frames) / m.fps
    t0, tf = m.extra["takeoff_time"], m.extra["flight_time"]
    assert np.all(low[t < t0] > -TOL_FLOOR) and np.all(low[t < t0] < TOL_FLOOR)
    assert low[(t > t0 + 0.3 * tf) & (t < t0 + 0.7 * tf)].min() > 0.2  # in the air
    np.testing.assert_allclose(low[t >= t0 + tf], 0.0, atol=TOL_FLOOR)  # landed


def test_body_aware_taller_shape(default_body):
    betas = np.zeros(default_body.num_betas)
    betas[0] = 2.0
    s0 = MotionSkeleton.from_body(default_body)
    s2 = MotionSkeleton.from_body(default_body, betas)

    def leg(s):
        J = s.rest_joints
        return sum(np.linalg.norm(J[JOINT[b]] - J[JOINT[a]]) for a, b in
                   (("left_hip", "left_knee"), ("left_knee", "left_ankle")))

    assert leg(s2) > leg(s0) + 0.05
    m = load_motion("walk", fps=30.0, duration=2.0, skeleton=s2)
    low = _floor_heights(default_body, m, betas)
    np.testing.assert_allclose(low, 0.0, atol=TOL_FLOOR)
    # longer legs: the calibrated hip swing is smaller for the same speed and stride
    d = load_motion("walk", fps=30.0, duration=2.0, skeleton=s0)
    assert m.extra["hip_scale"] < d.extra["hip_scale"]
    # files ignore the skeleton
    assert load_motion(str(CMU), skeleton=s2).num_frames == load_motion(str(CMU)).num_frames


def stance_ankle_speeds(sk, m, fps: float) -> np.ndarray:
    """The right ankle's mean forward speed [m/s] over each whole mid-stance of run ``m`` (15-75 %
    of the stance): zero where the stance foot does not slide."""
    _, P = sk.forward_kinematics(m.poses, m.trans)
    ph = np.mod(m.extra["phase"], 1.0)
    duty = m.extra["duty"]
    mid = np.nonzero((ph > 0.15 * duty) & (ph < 0.75 * duty))[0]
    z = P[:, JOINT["right_ankle"], 2]
    windows = [w for w in np.split(mid, np.nonzero(np.diff(mid) > 1)[0] + 1) if np.ptp(ph[w]) > 0.55 * duty]
    assert windows
    return np.array([(z[w[-1]] - z[w[0]]) / ((w[-1] - w[0]) / fps) for w in windows])


def test_gaits_keep_the_hips_inside_their_limits_by_quicker_steps(default_body):
    """At the normative cadence the run at 3.5 m/s would need 35 deg of hip extension on the
    default body and 49 on a short one (the table allows 30). Where the calibrated hip swing
    would pass the limit, the cadence rises instead: every gait of every shape stays inside the
    table, the stance foot still does not slide, and a body that needs no more keeps its
    cadence."""
    from sim.motions.gait import (
        _RUN,
        hip_scale_cap,
        peak_hip_extension,
        run_stride_frequency,
        stride_calibration,
    )

    limit = JOINT_LIMITS[JOINT["left_hip"], 0, 1]
    fps = 240.0
    for b0, b1 in ((0.0, 0.0), (-2.0, 0.0), (-1.0, 0.5), (2.0, 0.0)):
        betas = np.zeros(default_body.num_betas, np.float32)
        betas[:2] = b0, b1
        sk = MotionSkeleton.from_body(default_body, betas)
        for name in ("walk", "run"):
            m = procedural_motion(name, duration=2.5, fps=fps, skeleton=sk)
            assert within_limits(m.poses, tol=1e-6), (b0, b1, name)
        # the run: the stance foot moves with the floor (the root moves at 3.5 m/s)
        assert np.abs(stance_ankle_speeds(sk, m, fps)).max() < 0.05, (b0, b1)
        duty = m.extra["duty"]
        cap = hip_scale_cap(_RUN, duty)
        free = stride_calibration(_RUN, duty, run_stride_frequency(3.5), 3.5, sk)
        if b0 == 2.0:  # long legs reach the stride inside the limits: cadence and swing unchanged
            assert free < cap and m.extra["cadence_raised"] == 1.0 and m.extra["hip_scale"] == free
        else:  # the swing held at the cap, more strides per second
            assert free > cap and m.extra["hip_scale"] == cap and m.extra["cadence_raised"] > 1.1
            assert np.degrees(peak_hip_extension(_RUN, duty, free)) > 30.0
    assert np.degrees(peak_hip_extension(_RUN, 0.35, cap)) == pytest.approx(np.degrees(limit) - 1.0, abs=0.01)
    # a stride asked for is kept, at whatever swing it takes
    m = procedural_motion("run", duration=1.0, fps=30.0, stride=2.5)
    assert m.extra["cadence_raised"] == 1.0 and m.extra["stride_frequency"] == pytest.approx(3.5 / 2.5)


def test_the_raised_cadence_stops_at_a_human_step_rate(default_body):
    """A short body running fast would need an absurd step rate to keep its hips inside the
    limits (3 strides/s at 5 m/s, 6 at 10): the cadence stops at ``MAX_STRIDE_FREQUENCY`` and the
    hip swing grows past the cap instead, the stance foot still moving with the floor (up to the
    swing's clip at 2, past which it slides at any cadence)."""
    from sim.motions.gait import _RUN, MAX_STRIDE_FREQUENCY, hip_scale_cap

    betas = np.zeros(default_body.num_betas, np.float32)
    betas[0] = -2.0
    sk = MotionSkeleton.from_body(default_body, betas)
    fps = 240.0
    walk = procedural_motion("walk", duration=2.5, fps=fps, skeleton=sk, speed=3.0)
    assert walk.extra["stride_frequency"] == pytest.approx(MAX_STRIDE_FREQUENCY["walk"])
    for speed in (5.0, 10.0):
        m = procedural_motion("run", duration=2.5, fps=fps, skeleton=sk, speed=speed)
        cap = hip_scale_cap(_RUN, m.extra["duty"])
        assert m.extra["stride_frequency"] == pytest.approx(MAX_STRIDE_FREQUENCY["run"])
        assert m.extra["hip_scale"] > 1.1 * cap and not within_limits(m.poses, tol=1e-6)  # the ceiling wins
    # at 5 m/s the swing the ceiling needs (~1.5) is inside the calibration's range: no sliding
    m = procedural_motion("run", duration=2.5, fps=fps, skeleton=sk, speed=5.0)
    assert np.abs(stance_ankle_speeds(sk, m, fps)).max() < 0.1


@pytest.mark.parametrize("name", ["walk", "run"])
def test_gait_arms_do_not_cut_into_the_body(default_body, name):
    """The default body is skinned without pose correctives: an arm lowered past ~25 degrees
    from the torso, or an elbow bent past ~60 degrees, pushes its skin through the torso or the
    forearm, and a sleeve caught there has no room (a trapped sleeve tore on the t-shirt run).
    The gaits keep the arm skin clear (the toes' crossings are the template's own, at rest)."""
    from sim.quality import self_intersections, unique_edges

    m = load_motion(name, fps=30.0, duration=2.0)
    frames = default_body.pose(np.zeros(default_body.num_betas, np.float32), m.poses, m.trans, device="cpu")
    edges = unique_edges(frames.faces)
    arm_joints = [default_body.joint_names.index(n)
                  for n in ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow")]
    arm_vertex = np.isin(np.argmax(default_body.weights, axis=1), arm_joints)
    arms = self_intersections(frames.vertices[20::4], frames.faces, device="cpu",
                              edge_mask=arm_vertex[edges[:, 0]] & arm_vertex[edges[:, 1]])
    assert arms.max() == 0, f"{name}: arm skin crosses the body in {np.count_nonzero(arms)} frames"


def test_a_slow_run_keeps_its_stance_foot_on_the_floor(default_body):
    """A run slower than ~1 m/s keeps its cadence above 1.25 strides/s, so its strides are short
    and its hips swing less than the curves' half (a calibration stopped at half lets the stance
    foot slide forward, ~0.5 m/s at a 0.5 m/s jog): the stance foot moves with the floor down to
    the slowest run ``RunParams`` allows, and the swing shrinks with the speed."""
    from sim.motions.gait import HIP_SCALE_RANGE, gait_record

    sk = MotionSkeleton.from_body(default_body, np.zeros(default_body.num_betas, np.float32))
    fps = 240.0
    scales = []
    for speed in (0.5, 0.8):
        m = procedural_motion("run", duration=2.5, fps=fps, skeleton=sk, speed=speed)
        assert np.abs(stance_ankle_speeds(sk, m, fps)).max() < 0.05, speed
        assert within_limits(m.poses, tol=1e-6)
        scales.append(m.extra["hip_scale"])
    assert HIP_SCALE_RANGE[0] < scales[0] < scales[1] < 0.5  # below half the curves' swing
    assert gait_record()["hip_scale_range"] == list(HIP_SCALE_RANGE)  # datasets record the range
