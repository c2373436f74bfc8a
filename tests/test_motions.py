"""Motions: loaders (AMASS, BVH), resampling, retargeting and the procedural library.

Everything runs on CPU. Kinematics are checked by forward kinematics on SMPL's approximate
skeleton (``sim.motions.retarget.SMPL_REST_JOINTS``); the body-aware tests at the end skin the
embedded default body (numpy/Warp on cpu) and measure the lowest vertex against the floor.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.motions import (
    PROCEDURAL_MOTIONS,
    list_motions,
    load_amass,
    load_bvh,
    load_motion,
    procedural_motion,
    resample_motion,
)
from sim.motions.bvh import parse_bvh, resolve_joint_map
from sim.motions.limits import JOINT_LIMITS, limit_violation, within_limits
from sim.motions.procedural import (
    GRAVITY,
    JOINT,
    center_of_mass,
    contact_heights,
)
from sim.motions.resample import resample_times, slerp_axis_angle
from sim.motions.retarget import BONE_CHILD, SMPL_REST_JOINTS, forward_kinematics
from sim.motions.skeleton import MotionSkeleton
from sim.rotations import axis_angle_to_matrix
from sim.types import Motion

DATA = Path(__file__).parent / "data"
CMU = DATA / "cmu_style.bvh"
MIXAMO = DATA / "mixamo_style.bvh"

# Tolerances (one place, STYLE.md 11).
TOL_ROT = 1e-5      # float32 storage of axis-angle [rad]
TOL_DIR = 1e-4      # unit bone directions after float32 poses
TOL_POS = 1e-5      # positions [m] after float32 trans
TOL_FLOOR = 0.01    # [m] lowest skinned vertex from the floor, body-aware motions

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


# --- AMASS ------------------------------------------------------------------------------------

def _amass(tmp_path: Path, width: int, T: int = 12, fps_key: str = "mocap_framerate",
           name: str = "seq.npz", **over) -> tuple[Path, dict]:
    rng = np.random.default_rng(width)
    d = {"poses": rng.normal(0, 0.3, (T, width)), "trans": rng.normal(0, 0.5, (T, 3)),
         "betas": rng.normal(size=16), fps_key: np.array(120.0), "gender": np.array("female")}
    d.update(over)
    d = {k: v for k, v in d.items() if v is not None}
    path = tmp_path / name
    np.savez(path, **d)
    return path, d


@pytest.mark.parametrize("width,layout", [(156, "smplh"), (165, "smplx"), (72, "smpl")])
def test_amass_layouts_round_trip(tmp_path, width, layout):
    key = "mocap_frame_rate" if layout == "smplx" else "mocap_framerate"
    path, d = _amass(tmp_path, width, fps_key=key)
    m = load_amass(path, up_axis="y")
    T = d["poses"].shape[0]
    assert m.poses.shape == (T, 24, 3) and m.trans.shape == (T, 3) and m.fps == 120.0
    assert m.poses.dtype == np.float32 and m.extra["layout"] == layout
    joints = d["poses"].reshape(T, -1, 3)
    np.testing.assert_allclose(m.poses[:, :22], joints[:, :22], atol=TOL_ROT)
    np.testing.assert_allclose(m.trans, d["trans"], atol=TOL_POS)
    np.testing.assert_allclose(m.betas, d["betas"], atol=1e-6)
    assert m.extra["gender"] == "female"
    if layout == "smpl":
        np.testing.assert_allclose(m.poses[:, 22:], joints[:, 22:], atol=TOL_ROT)
    else:
        np.testing.assert_array_equal(m.poses[:, 22:], 0.0)  # SMPL hand joints zeroed
        hands = joints[:, 22:52] if layout == "smplh" else joints[:, 25:55]
        np.testing.assert_allclose(m.extra["hand_pose"], hands, atol=TOL_ROT)
    if layout == "smplx":
        np.testing.assert_allclose(m.extra["jaw_pose"][:, 0], joints[:, 22], atol=TOL_ROT)
        np.testing.assert_allclose(m.extra["eye_pose"], joints[:, 23:25], atol=TOL_ROT)
    # resampled through load_motion: 12 frames at 120 -> 3 at 30, hands resampled too
    r = load_motion(str(path), fps=30, up_axis="y")
    assert r.num_frames == 3 and r.fps == 30
    np.testing.assert_array_equal(r.poses[1], m.poses[4])
    if layout != "smpl":
        assert r.extra["hand_pose"].shape == (3, 30, 3)


def test_amass_split_keys(tmp_path):
    rng = np.random.default_rng(0)
    T = 5
    d = {"root_orient": rng.normal(size=(T, 3)), "pose_body": rng.normal(size=(T, 63)),
         "pose_hand": rng.normal(size=(T, 90)), "trans": rng.normal(size=(T, 3)),
         "mocap_frame_rate": 60.0}
    np.savez(tmp_path / "split.npz", **d)
    m = load_amass(tmp_path / "split.npz", up_axis="y")
    np.testing.assert_allclose(m.poses[:, 0], d["root_orient"], atol=TOL_ROT)
    np.testing.assert_allclose(m.poses[:, 1:22].reshape(T, 63), d["pose_body"], atol=TOL_ROT)
    np.testing.assert_allclose(m.extra["hand_pose"].reshape(T, 90), d["pose_hand"], atol=TOL_ROT)


def test_amass_z_up_to_y_up(tmp_path):
    """An upright AMASS subject (root Rx(+90) in Z-up) stands with identity root in Y-up."""
    T = 3
    poses = np.zeros((T, 156))
    poses[:, 0] = np.pi / 2
    trans = np.array([[1.0, 2.0, 3.0]] * T)
    path, _ = _amass(tmp_path, 156, T=T, poses=poses, trans=trans)
    m = load_amass(path)
    np.testing.assert_allclose(m.poses[:, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(m.trans[0], [1.0, 3.0, -2.0], atol=1e-6)  # Z up -> Y up

    # with the pelvis offset the whole body maps exactly: A (R (v - J0) + J0 + t)
    rng = np.random.default_rng(2)
    poses = rng.normal(0, 0.5, (T, 156))
    path, d = _amass(tmp_path, 156, T=T, poses=poses, trans=trans, name="b.npz")
    j0 = np.array([0.0, -0.2, 0.03])
    m = load_amass(path, pelvis_offset=j0)
    A = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], dtype=float)
    v = np.array([0.3, 0.5, -0.2])
    R = axis_angle_to_matrix(poses[:, :3])
    want = (R @ (v - j0) + j0 + trans) @ A.T
    got = axis_angle_to_matrix(m.poses[:, 0]) @ (v - j0) + j0 + m.trans
    np.testing.assert_allclose(got, want, atol=1e-5)


@pytest.mark.parametrize("case,words", [
    ("no_poses", "poses"), ("no_trans", "trans"), ("short_trans", "trans"), ("nan", "frame 3"),
    ("zero", "zero frames"), ("width", "numbers per frame"), ("no_fps", "frame rate"),
    ("corrupt", "npz"), ("missing_file", "not found"),
])
def test_amass_errors_name_the_file(tmp_path, case, words):
    T = 6
    over: dict = {}
    if case == "no_poses":
        over["poses"] = None
    elif case == "no_trans":
        over["trans"] = None
    elif case == "short_trans":
        over["trans"] = np.zeros((T - 1, 3))
    elif case == "nan":
        p = np.zeros((T, 156))
        p[3, 7] = np.nan
        over["poses"] = p
    elif case == "zero":
        over.update(poses=np.zeros((0, 156)), trans=np.zeros((0, 3)))
    elif case == "width":
        over["poses"] = np.zeros((T, 100))
    elif case == "no_fps":
        over["mocap_framerate"] = None
    path, _ = _amass(tmp_path, 156, T=T, name=f"{case}.npz", **over)
    if case == "corrupt":
        path.write_bytes(b"PK\x03\x04 this is not a zip archive")
    elif case == "missing_file":
        path = tmp_path / "nothere.npz"
    with pytest.raises(WrinklesInputError) as e:
        load_motion(str(path))
    assert path.name in str(e.value) and words in str(e.value)
    assert "\n" not in str(e.value)


# --- BVH --------------------------------------------------------------------------------------

def _bone_check(path: Path, frames: slice, skip: tuple[str, ...] = ()) -> Motion:
    """Retargeted SMPL bones point exactly where the BVH bones point."""
    bvh = parse_bvh(path)
    m = load_bvh(path)
    mapping, _ = resolve_joint_map(bvh)
    _, P = bvh.global_transforms()
    _, Ps = forward_kinematics(m.poses)
    checked = 0
    for s, b in mapping.items():
        c = BONE_CHILD[s]
        if s == 0 or c < 0 or c not in mapping or SMPL_NAME[s] in skip:
            continue
        want = _unit(P[frames, mapping[c]] - P[frames, b])
        got = _unit(Ps[frames, c] - Ps[frames, s])
        np.testing.assert_allclose(got, want, atol=TOL_DIR, err_msg=SMPL_NAME[s])
        checked += 1
    assert checked >= 14
    return m


SMPL_NAME = {v: k for k, v in JOINT.items()}


def test_bvh_cmu_style_retarget():
    m = _bone_check(CMU, slice(0, 3))
    _bone_check(CMU, slice(3, 4), skip=("neck",))  # CMU's Neck1 has no SMPL joint
    assert m.extra["joint_map"] == "cmu" and m.fps == 120.0 and m.num_frames == 4
    assert m.extra["mapped"]["spine1"] == "LowerBack" and m.extra["mapped"]["spine3"] == "Spine1"
    assert "left_hand" not in m.extra["mapped"]  # unmapped: identity local rotation
    np.testing.assert_array_equal(m.poses[:, JOINT["left_hand"]], 0.0)
    # auto scale: 26.7 units tall -> 1.7 m
    assert m.extra["scale"] == pytest.approx(1.7 / 26.7)
    np.testing.assert_allclose(m.trans[0], 0.0, atol=TOL_POS)  # stands on the floor at rest
    np.testing.assert_allclose(m.trans[2], [0, 0, 10 * 1.7 / 26.7], atol=TOL_POS)
    # frame 1: left elbow bent 90 deg, forearm forward
    _, P = forward_kinematics(m.poses)
    upper = _unit(P[1, JOINT["left_elbow"]] - P[1, JOINT["left_shoulder"]])
    fore = _unit(P[1, JOINT["left_wrist"]] - P[1, JOINT["left_elbow"]])
    assert np.degrees(np.arccos(upper @ fore)) == pytest.approx(90.0, abs=0.5)
    assert fore[2] > 0.99


def test_bvh_mixamo_style_retarget():
    m = _bone_check(MIXAMO, slice(None))
    assert m.extra["joint_map"] == "mixamo" and m.extra["scale"] == 0.01 and m.fps == 30.0
    assert m.extra["mapped"]["spine3"] == "mixamorig:Spine2"
    np.testing.assert_allclose(m.trans[2] - m.trans[0], [0.05, -0.05, 0.30], atol=TOL_POS)
    _, P = forward_kinematics(m.poses)
    fore = _unit(P[1, JOINT["left_wrist"]] - P[1, JOINT["left_elbow"]])
    assert fore[2] > 0.99  # elbow bent 90 deg: forearm points forward (+Z)
    # a mapped leaf (hand) at rest keeps identity local rotation
    np.testing.assert_allclose(m.poses[0, JOINT["left_hand"]], 0.0, atol=1e-6)
    # explicit options through load_motion: scale, rest, resampling
    r = load_motion(str(MIXAMO), fps=60, scale=0.01, rest="tpose")
    assert r.num_frames == 6 and r.fps == 60


def _corrupt(tmp_path: Path, name: str, edit) -> Path:
    lines = CMU.read_text().splitlines()
    lines = edit(lines)
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def _motion_line(lines: list[str]) -> int:
    return lines.index("MOTION")


@pytest.mark.parametrize("case,words", [
    ("no_motion", "MOTION"),
    ("short_frame", "values"),
    ("non_numeric", "not a number"),
    ("frame_count", "Frames: 4"),
    ("bad_hierarchy", "line"),
    ("bad_channels", "CHANNELS"),
    ("unknown_channel", "unknown channel"),
])
def test_bvh_malformed(tmp_path, case, words):
    def edit(lines):
        m = _motion_line(lines)
        if case == "no_motion":
            return lines[:m]
        if case == "short_frame":
            lines[m + 4] = " ".join(lines[m + 4].split()[:-1])
        elif case == "non_numeric":
            vals = lines[m + 3].split()
            vals[5] = "abc"
            lines[m + 3] = " ".join(vals)
        elif case == "frame_count":
            lines = lines[:-1]
        elif case == "bad_hierarchy":
            lines = [ln for i, ln in enumerate(lines) if not (i == 3 and ln.strip() == "{")]
            lines.insert(3, "  JUNK")
        elif case == "bad_channels":
            i = next(i for i, ln in enumerate(lines) if "CHANNELS 3" in ln)
            lines[i] = lines[i].replace("CHANNELS 3", "CHANNELS 4")
        elif case == "unknown_channel":
            i = next(i for i, ln in enumerate(lines) if "CHANNELS 3" in ln)
            lines[i] = lines[i].replace("Xrotation", "Wrotation")
        return lines

    path = _corrupt(tmp_path, f"{case}.bvh", edit)
    with pytest.raises(WrinklesInputError) as e:
        load_motion(str(path))
    msg = str(e.value)
    assert path.name in msg and words in msg and "\n" not in msg
    if case != "no_motion":
        assert "line " in msg


def test_bvh_frame_line_number_is_reported(tmp_path):
    lines = CMU.read_text().splitlines()
    m = _motion_line(lines)
    lines[m + 5] += " 1.0"  # last frame line gets an extra value
    p = tmp_path / "extra.bvh"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(WrinklesInputError, match=f"line {m + 6}:"):
        load_bvh(p)


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
    # starts at rest, smoothly (zero velocity at t = 0: tiny first step)
    np.testing.assert_allclose(m.poses[0], 0.0, atol=1e-7)
    np.testing.assert_allclose(m.trans[0], 0.0, atol=1e-7)
    assert np.abs(m.poses[1] - m.poses[0]).max() < 0.03
    assert np.abs(m.trans[1] - m.trans[0]).max() < 0.01


# --- procedural kinematics -------------------------------------------------------------------------

def test_walk_gait_kinematics():
    fps, speed = 30.0, 1.2
    m = procedural_motion("walk", duration=6.0, fps=fps, speed=speed, stride=1.2)  # 1 stride/s
    steady = slice(60, None)  # after the 1 s ramp plus a margin
    rk, lk = (np.degrees(m.poses[:, JOINT[f"{s}_knee"], 0]) for s in ("right", "left"))
    # knee flexion peaks in swing at ~60 deg (Perry; Winter)
    cyc = slice(90, 120)
    k = int(np.argmax(rk[cyc])) + 90
    assert 55.0 < rk[k] < 65.0
    assert 0.62 < np.mod(m.extra["phase"][k], 1.0) < 0.85
    # the legs are half a stride (15 frames) apart
    np.testing.assert_allclose(lk[75:150], rk[90:165], atol=1e-3)
    # forward speed along +Z, nothing sideways
    z = m.trans[:, 2]
    assert (z[-1] - z[90]) / ((m.num_frames - 1 - 90) / fps) == pytest.approx(speed, rel=1e-4)
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
    mid = (np.arange(m.num_frames) > 60) & (ph > 0.1) & (ph < 0.45)
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
    top = 30 + 30  # ramp 1 s + half a period
    for style in ("front", "side"):
        r = procedural_motion("arm_raise", duration=3.0, fps=30.0, style=style, period=2.0,
                              elevation_deg=160.0)
        _, P = forward_kinematics(r.poses)
        for side in ("left", "right"):
            arm = _unit(P[top, JOINT[f"{side}_elbow"]] - P[top, JOINT[f"{side}_shoulder"]])
            # SMPL's rest arm droops ~3 deg below the horizontal
            assert np.degrees(np.arccos(-arm[1])) == pytest.approx(160.0, abs=4.0)
            if style == "front":
                assert arm[2] > 0.2  # went up in front, not to the side


# --- body-aware procedural motions (skinned on the default body, cpu) -------------------------

@pytest.fixture(scope="module")
def default_body():
    from sim.bodies import load_body

    return load_body()


def _floor_heights(body, motion: Motion, betas=None) -> np.ndarray:
    """Lowest skinned vertex per frame [m] after grounding frame 0 (the rest pose)."""
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
    steady = np.arange(m.num_frames) > 1.2 * m.fps
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
    """The right ankle's mean forward speed [m/s] over each whole mid-stance of run ``m`` after
    its ramp (15-75 % of the stance): zero where the stance foot does not slide."""
    _, P = sk.forward_kinematics(m.poses, m.trans)
    ph = np.mod(m.extra["phase"], 1.0)
    duty = m.extra["duty"]
    mid = np.nonzero((np.arange(m.num_frames) > 1.2 * fps) & (ph > 0.15 * duty) & (ph < 0.75 * duty))[0]
    z = P[:, JOINT["right_ankle"], 2]
    windows = [w for w in np.split(mid, np.nonzero(np.diff(mid) > 1)[0] + 1) if np.ptp(ph[w]) > 0.55 * duty]
    assert windows
    return np.array([(z[w[-1]] - z[w[0]]) / ((w[-1] - w[0]) / fps) for w in windows])


def test_gaits_keep_the_hips_inside_their_limits_by_quicker_steps(default_body):
    """Session 52: at the automatic cadence the run at 3.5 m/s needed 35 deg of hip extension on
    the default body and 49 on a short one (the table allows 30). Where the calibrated hip swing
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
    swing's clip at 2, past which it slid before session 52 too)."""
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
    and its hips swing less than the curves' half: until session 53 the calibration stopped at
    half and the stance foot slid forward (~0.5 m/s at a 0.5 m/s jog). Now it moves with the
    floor down to the slowest run ``RunParams`` allows, and the swing shrinks with the speed."""
    from sim.motions.gait import HIP_SCALE_RANGE, gait_record

    sk = MotionSkeleton.from_body(default_body, np.zeros(default_body.num_betas, np.float32))
    fps = 240.0
    scales = []
    for speed in (0.5, 0.8):
        m = procedural_motion("run", duration=2.5, fps=fps, skeleton=sk, speed=speed)
        assert np.abs(stance_ankle_speeds(sk, m, fps)).max() < 0.05, speed
        assert within_limits(m.poses, tol=1e-6)
        scales.append(m.extra["hip_scale"])
    assert HIP_SCALE_RANGE[0] < scales[0] < scales[1] < 0.5  # below the old floor, which slid
    assert gait_record()["hip_scale_range"] == list(HIP_SCALE_RANGE)  # datasets see the change
