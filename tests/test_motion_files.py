"""Motion files: AMASS ``.npz`` (SMPL, SMPL-H, SMPL-X layouts, Z up) and BVH retargeted to SMPL.

Everything runs on CPU; bone directions are checked by forward kinematics on SMPL's approximate
skeleton (``sim.motions.retarget.SMPL_REST_JOINTS``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.motions import load_amass, load_bvh, load_motion
from sim.motions.bvh import parse_bvh, resolve_joint_map
from sim.motions.procedural import JOINT
from sim.motions.retarget import BONE_CHILD, LIMB_JOINTS, forward_kinematics
from sim.rotations import axis_angle_to_matrix
from sim.types import Motion

DATA = Path(__file__).parent / "data"
CMU = DATA / "cmu_style.bvh"
MIXAMO = DATA / "mixamo_style.bvh"

# Tolerances (one place, STYLE.md 11).
TOL_ROT = 1e-5      # float32 storage of axis-angle [rad]
TOL_DIR = 1e-4      # unit bone directions after float32 poses
TOL_POS = 1e-5      # positions [m] after float32 trans


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


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

def _bone_check(path: Path, frames: slice, skip: tuple[str, ...] = (), rest: str = "file") -> Motion:
    """Retargeted SMPL bones point exactly where the BVH bones point: every mapped bone under
    ``rest="file"``, the limbs under ``rest="auto"`` (whose torso, head, hands and feet turn
    with the file's joints from SMPL's rest instead, checked in tests/test_motion_posture.py)."""
    bvh = parse_bvh(path)
    m = load_bvh(path, rest=rest)
    mapping, _ = resolve_joint_map(bvh)
    _, P = bvh.global_transforms()
    _, Ps = forward_kinematics(m.poses)
    checked = 0
    for s, b in mapping.items():
        c = BONE_CHILD[s]
        if s == 0 or c < 0 or c not in mapping or SMPL_NAME[s] in skip:
            continue
        if rest == "auto" and s not in LIMB_JOINTS:
            continue
        want = _unit(P[frames, mapping[c]] - P[frames, b])
        got = _unit(Ps[frames, c] - Ps[frames, s])
        np.testing.assert_allclose(got, want, atol=TOL_DIR, err_msg=SMPL_NAME[s])
        checked += 1
    assert checked >= (14 if rest == "file" else len(LIMB_JOINTS))
    return m


SMPL_NAME = {v: k for k, v in JOINT.items()}


def test_bvh_cmu_style_retarget():
    m = _bone_check(CMU, slice(0, 3))
    _bone_check(CMU, slice(3, 4), skip=("neck",))  # CMU's Neck1 has no SMPL joint
    m = _bone_check(CMU, slice(None), rest="auto")
    assert m.extra["joint_map"] == "cmu" and m.fps == 120.0 and m.num_frames == 4
    assert m.extra["rest"] == "auto"
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
    _bone_check(MIXAMO, slice(None))
    m = _bone_check(MIXAMO, slice(None), rest="auto")
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


@pytest.mark.parametrize("case", ["pickle", "object_array"])
def test_pickled_motion_files_are_refused_without_unsafe_advice(tmp_path, capsys, case):
    """A motion file that is a pickle, or a single object array saved as .npz: one line, exit 2,
    saying what the file is and that wrinkles never unpickles objects; numpy's advice to load it
    with allow_pickle is not passed on."""
    import pickle

    from pipelines.cli import main

    path = tmp_path / "motion.npz"
    if case == "pickle":
        path.write_bytes(pickle.dumps({"poses": np.zeros((3, 72))}))
    else:
        with open(path, "wb") as fh:
            np.save(fh, np.array([{"poses": 1}], dtype=object))
    out = tmp_path / "o.usdc"
    assert main(["body", "--motion", str(path), "--out", str(out), "--device", "cpu", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"wrinkles body: error: {path}: "), err
    assert "wrinkles never loads pickled Python objects" in err, err
    for advice in ("allow_pickle", "unsafe", "pickle.load", "trust"):
        assert advice not in err.lower(), (advice, err)
    assert not out.exists()
