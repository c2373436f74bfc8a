"""Posture of imported motions on the default body.

A CMU-style and a Mixamo-style (A-pose) BVH skeleton, written here with zero spine, neck, head
and hand rotations, must pose the body with its head as at rest on its torso and its wrists
straight, while the limbs point where the file's limbs point; AMASS poses are SMPL's own. The
``--rest`` and ``--motion-param`` / ``--param`` options are checked through the CLI. CPU only.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pipelines.cli import build_parser, main
from sim.bodies.default import load_default_body
from sim.motions import MotionSkeleton, load_amass, load_bvh, load_motion
from sim.motions.bvh import parse_bvh, resolve_joint_map
from sim.rotations import matrix_to_axis_angle
from sim.types import SMPL_JOINT_NAMES

# Tolerances (one place, STYLE.md 11).
TOL_DEG = 0.5    # [deg] angles through float32 poses and float32 skinning of the joints
TOL_DIR = 2e-3   # unit bone directions, body joints (float32) against the file's (float64)

J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
UP = np.array([0.0, 1.0, 0.0])

# A skeleton node: (name, offset, children) or, for a leaf, (name, offset, end-site offset).
def cmu_skeleton(finger_base: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple:
    """The hierarchy and joint names of the BVH release of the CMU Graphics Lab Motion Capture
    Database with one subject's rest offsets (rounded): legs spread 20 degrees, the neck and
    head bones leaning back, the finger base at the wrist joint (or at ``finger_base``)."""
    def arm(side: str, x: float, arm_offset: tuple, lengths: tuple) -> tuple:
        fore, hand, index, tip = lengths
        thumb = "LThumb" if side == "Left" else "RThumb"
        fb = (finger_base[0] * x, finger_base[1], finger_base[2])
        return (f"{side}Shoulder", (0, 0, 0), [(f"{side}Arm", arm_offset, [
            (f"{side}ForeArm", (fore * x, 0, 0), [(f"{side}Hand", (hand * x, 0, 0), [
                (f"{side}FingerBase", fb, [(f"{side}HandIndex1", (index * x, 0, 0), (tip * x, 0, 0))]),
                (thumb, (0, 0, 0), (0.6 * x, 0, 0.6))])])])])

    def leg(side: str, up: tuple, knee: tuple, ankle: tuple, toe: tuple, tip: float) -> tuple:
        return (f"{side[0]}HipJoint", (0, 0, 0), [(f"{side}UpLeg", up, [(f"{side}Leg", knee, [
            (f"{side}Foot", ankle, [(f"{side}ToeBase", toe, (0, 0, tip))])])])])

    return ("Hips", (0, 0, 0), [
        leg("Left", (1.65, -1.71, 0.85), (2.25, -6.18, 0), (2.72, -7.47, 0), (0.19, -0.52, 2.25),
            1.16),
        leg("Right", (-1.59, -1.71, 0.85), (-2.25, -6.18, 0), (-2.73, -7.50, 0), (-0.22, -0.59, 2.11),
            1.10),
        ("LowerBack", (0, 0, 0), [("Spine", (0.03, 2.10, -0.11), [("Spine1", (-0.02, 2.11, -0.07), [
            ("Neck", (0, 0, 0), [("Neck1", (-0.02, 1.73, 0.0), [
                ("Head", (-0.06, 1.55, -0.62), (-0.01, 1.71, -0.21))])]),
            arm("Left", 1, (3.45, 0.50, 0.22), (5.42, 2.44, 0.73, 0.59)),
            arm("Right", -1, (-3.23, 0.56, 0.31), (5.59, 2.48, 0.82, 0.66)),
        ])])]),
    ])


def mixamo_a_pose(angle_deg: float = 45.0) -> tuple:
    """A Mixamo-style skeleton (centimetres, ``mixamorig:`` names) whose rest has the arms
    ``angle_deg`` below horizontal, the hands continuing the forearms."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))

    def arm(side: str, x: float) -> tuple:
        down = lambda n: (n * c * x, -n * s, 0)  # noqa: E731 - along the lowered arm
        return (f"mixamorig:{side}Shoulder", (6 * x, 10, 0), [(f"mixamorig:{side}Arm", (12 * x, 0, 0), [
            (f"mixamorig:{side}ForeArm", down(27), [(f"mixamorig:{side}Hand", down(25), [
                (f"mixamorig:{side}HandMiddle1", down(9), down(4))])])])])

    def leg(side: str, x: float) -> tuple:
        return (f"mixamorig:{side}UpLeg", (9 * x, -6, 0), [(f"mixamorig:{side}Leg", (0, -44, 0), [
            (f"mixamorig:{side}Foot", (0, -42, 0), [(f"mixamorig:{side}ToeBase", (0, -7, 12), (0, 0, 8))])])])

    return ("mixamorig:Hips", (0, 0, 0), [
        ("mixamorig:Spine", (0, 9, -1), [("mixamorig:Spine1", (0, 11, 0), [("mixamorig:Spine2", (0, 12, 0), [
            ("mixamorig:Neck", (0, 15, 1.5), [("mixamorig:Head", (0, 10, 2), (0, 18, 0))]),
            arm("Left", 1.0), arm("Right", -1.0)])])]),
        leg("Left", 1.0), leg("Right", -1.0)])


def joint_names(node: tuple) -> list[str]:
    kids = node[2]
    return [node[0]] + ([n for k in kids for n in joint_names(k)] if isinstance(kids, list) else [])


def write_bvh(path: Path, skeleton: tuple, rotations: list[dict[str, tuple[float, float, float]]],
              root_height: float, order: str = "ZYX", fps: float = 120.0) -> Path:
    """A BVH file: one frame per dict of joint name -> rotation angles [deg] in ``order``
    (root position channels, then three rotation channels per joint; unlisted joints zero)."""
    chans = " ".join(f"{a}rotation" for a in order)
    lines = ["HIERARCHY"]

    def emit(node: tuple, depth: int) -> None:
        name, off, kids = node
        pad = "  " * depth
        lines.extend([f"{pad}{'JOINT' if depth else 'ROOT'} {name}", pad + "{",
                      f"{pad}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}",
                      f"{pad}  CHANNELS {6 if depth == 0 else 3} "
                      f"{'Xposition Yposition Zposition ' if depth == 0 else ''}{chans}"])
        if isinstance(kids, list):
            for k in kids:
                emit(k, depth + 1)
        else:
            lines.extend([f"{pad}  End Site", pad + "  {",
                          f"{pad}    OFFSET {kids[0]:.6f} {kids[1]:.6f} {kids[2]:.6f}", pad + "  }"])
        lines.append(pad + "}")

    emit(skeleton, 0)
    lines += ["MOTION", f"Frames: {len(rotations)}", f"Frame Time: {1.0 / fps:.6f}"]
    for frame in rotations:
        row = [0.0, root_height, 0.0]
        for n in joint_names(skeleton):
            row += list(frame.get(n, (0.0, 0.0, 0.0)))
        lines.append(" ".join(f"{v:.4f}" for v in row))
    path.write_text("\n".join(lines) + "\n")
    return path


#: CMU frames (Z, Y, X angles [deg]): rest; legs together, arms lowered 60 degrees, elbows bent;
#: turned 30 degrees with a hip and a knee flexed. Spine, neck, head and hands stay at zero.
CMU_FRAMES = [
    {},
    {"LeftUpLeg": (-20, 0, 0), "RightUpLeg": (20, 0, 0), "LeftArm": (-60, 0, 0), "RightArm": (60, 0, 0),
     "LeftForeArm": (0, -40, 0), "RightForeArm": (0, 40, 0)},
    {"Hips": (0, 30, 0), "LeftUpLeg": (-20, 0, -30), "LeftLeg": (0, 0, 40), "RightUpLeg": (20, 0, 10),
     "LeftArm": (-70, 0, 0), "RightArm": (70, 20, 0)},
]


@pytest.fixture(scope="module")
def body():
    return load_default_body()


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(unit(a) * unit(b), axis=-1), -1.0, 1.0)))


def posture(body, motion) -> dict[str, np.ndarray]:
    """Per frame [deg]: the head's rotation relative to the pelvis, the neck-to-head direction's
    angle from the pelvis's up axis, the chest's (spine3) rotation relative to the pelvis, and
    the bend of each wrist (forearm direction to hand direction); plus joints and rotations."""
    frames = body.pose(None, motion.poses, motion.trans, device="cpu")
    m = body.body_joint_map
    P = frames.joints[:, m].astype(np.float64)
    R = frames.transforms[:, m, :3, :3].astype(np.float64)
    pelvis_t = np.swapaxes(R[:, J["pelvis"]], -1, -2)
    rel = lambda j: np.degrees(np.linalg.norm(matrix_to_axis_angle(pelvis_t @ R[:, j]), axis=-1))  # noqa: E731
    neck_head = np.einsum("tab,tb->ta", pelvis_t, P[:, J["head"]] - P[:, J["neck"]])
    wrist = {side: angle_deg(P[:, J[f"{side}_wrist"]] - P[:, J[f"{side}_elbow"]],
                             P[:, J[f"{side}_hand"]] - P[:, J[f"{side}_wrist"]])
             for side in ("left", "right")}
    return {"head": rel(J["head"]), "chest": rel(J["spine3"]), "neck_head": angle_deg(neck_head, UP),
            "wrist_left": wrist["left"], "wrist_right": wrist["right"], "P": P}


def rest_posture(body) -> dict[str, float]:
    Jr = body.rest_joints()[body.body_joint_map].astype(np.float64)
    return {"neck_head": float(angle_deg(Jr[J["head"]] - Jr[J["neck"]], UP)),
            "wrist": float(angle_deg(Jr[J["left_wrist"]] - Jr[J["left_elbow"]],
                                     Jr[J["left_hand"]] - Jr[J["left_wrist"]]))}


def assert_natural(body, motion) -> dict[str, np.ndarray]:
    """Head and chest as at rest on the pelvis, wrists as straight as the body's at rest."""
    got, rest = posture(body, motion), rest_posture(body)
    np.testing.assert_allclose(got["head"], 0.0, atol=TOL_DEG)
    np.testing.assert_allclose(got["chest"], 0.0, atol=TOL_DEG)
    np.testing.assert_allclose(got["neck_head"], rest["neck_head"], atol=TOL_DEG)
    np.testing.assert_allclose(got["wrist_left"], rest["wrist"], atol=TOL_DEG)
    np.testing.assert_allclose(got["wrist_right"], rest["wrist"], atol=TOL_DEG)
    return got


def assert_limbs_follow_file(path: Path, P_body: np.ndarray) -> None:
    """The body's upper arms, forearms, thighs and shins point where the file's do."""
    bvh = parse_bvh(path)
    mapping, _ = resolve_joint_map(bvh)
    _, P = bvh.global_transforms()
    for a, b in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle")):
        for side in ("left", "right"):
            s, e = J[f"{side}_{a}"], J[f"{side}_{b}"]
            np.testing.assert_allclose(unit(P_body[:, e] - P_body[:, s]),
                                       unit(P[:, mapping[e]] - P[:, mapping[s]]),
                                       atol=TOL_DIR, err_msg=f"{side}_{a}")


def body_rest_joints(body) -> np.ndarray:
    return MotionSkeleton.from_body(body).rest_joints


@pytest.mark.parametrize("finger_base", [(0.0, 0.0, 0.0), (0.1, -0.7, 0.0)], ids=["at_wrist", "below_wrist"])
def test_cmu_head_level_wrists_straight(tmp_path, body, finger_base):
    """Zero neck, head and hand rotations: the head sits on the torso as at rest and the wrists
    are straight, whether or not the file's hand bone continues its forearm."""
    path = write_bvh(tmp_path / "cmu.bvh", cmu_skeleton(finger_base), CMU_FRAMES, root_height=16.0)
    motion = load_bvh(path, rest_joints=body_rest_joints(body))
    assert motion.extra["rest"] == "auto" and motion.extra["joint_map"] == "cmu"
    got = assert_natural(body, motion)
    assert_limbs_follow_file(path, got["P"])
    # "file" aligns every bone: the neck-to-head bone then takes the file's direction, 10.6
    # degrees back from vertical, and the head tilts with it
    every = posture(body, load_bvh(path, rest="file", rest_joints=body_rest_joints(body)))
    file_neck_head = np.array([-0.02 - 0.06, 1.73 + 1.55, -0.62])
    np.testing.assert_allclose(every["neck_head"][0], angle_deg(file_neck_head, UP), atol=TOL_DEG)
    assert every["head"][0] > 10.0
    if finger_base != (0.0, 0.0, 0.0):  # and the hands take the file's hand direction
        np.testing.assert_allclose(every["wrist_left"][0],
                                   angle_deg(np.array([2.44, 0, 0]), np.array(finger_base)), atol=TOL_DEG)
    # "tpose": the file's rest is the body's T-pose, limbs included (legs straight down)
    tpose = posture(body, load_bvh(path, rest="tpose"))
    np.testing.assert_allclose(tpose["head"], 0.0, atol=TOL_DEG)
    legs = body.rest_joints()[body.body_joint_map]
    np.testing.assert_allclose(angle_deg(tpose["P"][0, J["left_knee"]] - tpose["P"][0, J["left_hip"]], -UP),
                               angle_deg(legs[J["left_knee"]] - legs[J["left_hip"]], -UP), atol=TOL_DEG)


def test_mixamo_a_pose_arms_and_wrists(tmp_path, body):
    """An A-pose rest (arms 45 degrees down): at rest the arms are lowered 45 degrees like the
    file's, raised 45 degrees they are horizontal, and the wrists are straight throughout."""
    frames = [{}, {"mixamorig:LeftArm": (45, 0, 0), "mixamorig:RightArm": (-45, 0, 0)}]
    path = write_bvh(tmp_path / "apose.bvh", mixamo_a_pose(45.0), frames, root_height=100.0, order="ZXY",
                     fps=30)
    motion = load_bvh(path, rest_joints=body_rest_joints(body))
    assert motion.extra["joint_map"] == "mixamo" and motion.extra["scale"] == 0.01
    got = assert_natural(body, motion)
    assert_limbs_follow_file(path, got["P"])
    P = got["P"]
    for side, x in (("left", 1.0), ("right", -1.0)):
        for a, b in (("shoulder", "elbow"), ("elbow", "wrist")):
            bone = P[:, J[f"{side}_{b}"]] - P[:, J[f"{side}_{a}"]]
            np.testing.assert_allclose(angle_deg(bone, np.array([x, 0.0, 0.0])), [45.0, 0.0], atol=TOL_DEG)


def test_amass_poses_are_smpl_rotations(tmp_path, body):
    """AMASS has no rest alignment: zero body pose with an upright Z-up root is the body's
    rest posture, head level and wrists straight; through the CLI options a subject standing on
    AMASS's floor (z = 0) stands on ours (y = 0) with the body's own pelvis."""
    from pipelines.options import load_body_and_motion

    Jb = body.rest_joints()[body.body_joint_map].astype(np.float64)
    lowest = float(body.rest_mesh()[:, 1].min())
    T = 3
    poses = np.zeros((T, 156))
    poses[:, 0] = np.pi / 2  # Rx(90 deg): upright in AMASS's Z-up world, model +Y -> world +Z
    trans = np.zeros((T, 3))
    trans[:, 2] = Jb[0, 1] - Jb[0, 2] - lowest  # the lowest vertex at z = 0
    np.savez(tmp_path / "a.npz", poses=poses, trans=trans, mocap_framerate=30.0)
    motion = load_amass(tmp_path / "a.npz")
    assert motion.extra["pelvis_exact"] is False
    got = assert_natural(body, motion)
    np.testing.assert_allclose(unit(got["P"][:, J["neck"]] - got["P"][:, J["pelvis"]]),
                               np.broadcast_to(unit(Jb[J["neck"]] - Jb[J["pelvis"]]), (T, 3)), atol=1e-5)
    bm = load_body_and_motion(build_parser().parse_args(["body", "--motion", str(tmp_path / "a.npz")]))
    assert bm.params == {} and bm.motion.extra["pelvis_exact"] is True
    frames = body.pose(bm.betas, bm.motion.poses, bm.motion.trans, device="cpu")
    np.testing.assert_allclose(frames.vertices[:, :, 1].min(axis=1), 0.0, atol=1e-4)
    # the pelvis where the file has it: (J0x, J0y, J0z + trans_z) in Z-up
    np.testing.assert_allclose(frames.joints[:, body.body_joint_map[0]], np.broadcast_to(
        [Jb[0, 0], Jb[0, 1] - lowest, -Jb[0, 1]], (T, 3)), atol=1e-4)


# --- the CLI ----------------------------------------------------------------------------------

def _cmu_file(tmp_path: Path) -> Path:
    return write_bvh(tmp_path / "cmu.bvh", cmu_skeleton(), CMU_FRAMES * 4, root_height=16.0)


def test_rest_flag_reaches_the_loader(tmp_path, body):
    from pipelines.options import load_body_and_motion

    path = _cmu_file(tmp_path)
    base = ["body", "--motion", str(path), "--fps", "120", "--device", "cpu"]
    for rest in ("auto", "tpose", "file"):
        bm = load_body_and_motion(build_parser().parse_args(base + ["--rest", rest]))
        want = load_bvh(path, rest=rest, rest_joints=body_rest_joints(body))
        np.testing.assert_array_equal(bm.motion.poses, want.poses)
        assert bm.params == {"rest": rest}
    bm = load_body_and_motion(build_parser().parse_args(base))  # default: auto, recorded
    assert bm.params == {"rest": "auto"}
    np.testing.assert_array_equal(bm.motion.poses, load_bvh(path, rest_joints=body_rest_joints(body)).poses)
    assert np.abs(bm.motion.poses - load_bvh(path, rest="file").poses).max() > 0.1


def test_body_command_with_rest_writes_the_stage(tmp_path, capsys):
    out = tmp_path / "cmu.usda"
    code = main(["body", "--motion", str(_cmu_file(tmp_path)), "--rest", "tpose", "--fps", "30",
                 "--out", str(out), "--device", "cpu", "--quiet"])
    assert code == 0
    from usd_io import read_stage

    stage = read_stage(out)
    assert stage.metadata["config"]["params"] == {"rest": "tpose"}
    assert stage.metadata["config"]["frames"] == 3  # 12 frames at 120 fps read at 30


@pytest.mark.parametrize("extra,needles", [
    (["--rest", "sideways"], ("--rest 'sideways'", "auto, tpose, file")),
    (["--rest", "tpose", "--motion", "walk"], ("--rest applies to BVH files", "'walk'")),
    (["--rest", "tpose", "--motion-param", "rest=file"], ("given twice",)),
    (["--param", "wings"], ("--motion-param 'wings'", "KEY=VALUE")),
])
def test_bad_rest_and_params_are_one_line_exit_2(tmp_path, capsys, extra, needles):
    out = tmp_path / "o.usdc"
    args = ["body", "--motion", str(_cmu_file(tmp_path)), "--out", str(out), "--device", "cpu", "--quiet"]
    assert main(args + extra) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for n in needles:
        assert n in err, err
    assert not out.exists()


def test_motion_param_and_its_param_alias(body):
    from pipelines.options import load_body_and_motion

    for flags in (["--motion-param", "depth_deg=60", "--motion-param", "period=1.5"],
                  ["--param", "depth_deg=60", "--param", "period=1.5"],
                  ["--motion-param", "depth_deg=60", "--param", "period=1.5"]):
        args = build_parser().parse_args(["body", "--motion", "squat", "--duration", "1", "--fps", "10",
                                          *flags])
        assert args.motion_param == [flags[1], flags[3]]
        bm = load_body_and_motion(args)
        assert bm.params == {"depth_deg": 60.0, "period": 1.5}
        want = load_motion("squat", fps=10, duration=1, skeleton=MotionSkeleton.from_body(body),
                           depth_deg=60.0, period=1.5)
        np.testing.assert_array_equal(bm.motion.poses, want.poses)
    default = load_motion("squat", fps=10, duration=1, skeleton=MotionSkeleton.from_body(body))
    assert np.abs(bm.motion.poses - default.poses).max() > 0.1


def test_help_documents_rest_and_motion_param(capsys):
    with pytest.raises(SystemExit):
        main(["body", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    for words in ("--motion-param KEY=VALUE, --param KEY=VALUE", "--rest {auto,tpose,file}",
                  "tpose: SMPL's T-pose as it is", "file: every bone", "BVH files only",
                  "default: out/body.usdc"):
        assert words in out, words


def test_dataset_sequences_pose_files_on_their_body(tmp_path, body):
    """The dataset generator builds a BVH sequence's rest alignment on the sequence's own body
    shape, and an AMASS sequence's Z-up translation exact for that body's pelvis."""
    from sim.datasets.config import load_config
    from sim.datasets.generate import sequence_inputs
    from sim.datasets.sampling import SequenceSpec
    from sim.motions.amass import place_pelvis

    cfg = load_config("sample")
    betas = (1.0, -0.5)
    full = body.full_betas(np.array(betas))
    joints = MotionSkeleton.from_body(body, full).rest_joints
    bvh = write_bvh(tmp_path / "cmu.bvh", cmu_skeleton(), CMU_FRAMES * 30, root_height=16.0)
    sp = SequenceSpec(index=0, id="seq-00000", seed=1, category="t_shirt", betas=betas, motion=str(bvh))
    _, m = sequence_inputs(cfg, sp, body)
    want = load_motion(bvh, fps=cfg.fps, duration=cfg.seconds, rest_joints=joints)
    np.testing.assert_array_equal(m.poses, want.poses)
    assert np.abs(m.poses - load_motion(bvh, fps=cfg.fps, duration=cfg.seconds).poses).max() > 1e-4
    T = round(cfg.seconds * 120) + 2
    np.savez(tmp_path / "a.npz", poses=np.zeros((T, 156)), trans=np.zeros((T, 3)), mocap_framerate=120.0)
    sp = SequenceSpec(index=1, id="seq-00001", seed=2, category="t_shirt", betas=betas,
                      motion=str(tmp_path / "a.npz"))
    _, m = sequence_inputs(cfg, sp, body)
    raw = load_motion(tmp_path / "a.npz", fps=cfg.fps, duration=cfg.seconds)
    assert raw.extra["pelvis_exact"] is False and m.extra["pelvis_exact"] is True
    placed = place_pelvis(raw, body.rest_joints(full)[body.body_joint_map[0]])
    np.testing.assert_allclose(m.trans, placed.trans, atol=1e-6)
    assert np.abs(m.trans - raw.trans).max() > 0.01
