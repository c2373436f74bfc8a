"""Clips are what they say: a procedural motion of ``duration`` seconds is that many seconds of
the motion, in full motion from its first frame; the way in from the rest pose is its lead-in,
played in a simulation's prelude and in no output."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from sim.motions import PROCEDURAL_MOTIONS, load_motion
from sim.motions.procedural import JOINT

needs_usd = pytest.mark.skipif(importlib.util.find_spec("pxr") is None, reason="usd-core (pxr) not installed")


def joint_rotation_deg(poses: np.ndarray) -> np.ndarray:
    """Largest joint rotation from the rest pose per frame [deg], the root's excluded, (T,)."""
    return np.degrees(np.linalg.norm(np.asarray(poses, np.float64)[:, 1:], axis=-1)).max(axis=1)


@pytest.fixture(scope="module")
def body():
    from sim.bodies import load_body

    return load_body()


def test_a_one_second_squat_squats(body):
    """``--duration 1``: 30 frames at 30 fps, the knees flexing from standing at t = 0 along the
    squat's cosine (period 2.5 s: 88 of 100 deg by the last frame), the pelvis going down with them."""
    m = load_motion("squat", fps=30.0, duration=1.0)
    assert m.num_frames == 30 and m.duration == pytest.approx(1.0)
    t = np.arange(30) / 30.0
    knee = 100.0 * 0.5 * (1.0 - np.cos(2.0 * np.pi * t / 2.5))
    np.testing.assert_allclose(np.degrees(m.poses[:, JOINT["left_knee"], 0]), knee, atol=0.01)
    assert knee[-1] > 87.0
    # the posed body (what ``wrinkles body`` writes): its pelvis sinks by 3/4 of the full squat's drop
    frames = body.pose_motion(m, None, device="cpu")
    assert frames.num_frames == 30
    full = body.pose_motion(load_motion("squat", fps=30.0, duration=2.5), None, device="cpu")
    y, y_full = frames.joints[:, 0, 1], full.joints[:, 0, 1]
    assert y[0] == pytest.approx(y_full[0], abs=1e-6)  # the same standing start
    assert y[0] - y.min() > 0.75 * (y_full[0] - y_full.min()) > 0.2  # 25 of 32 cm


@pytest.mark.parametrize("name, speed", [("walk", 1.3), ("run", 3.5)])
def test_a_gait_moves_at_its_speed_from_the_first_frame(name, speed):
    m = load_motion(name, fps=30.0, duration=2.0)
    z = m.trans[:, 2].astype(np.float64)
    assert m.num_frames == 60 and z[0] == 0.0
    np.testing.assert_allclose(np.diff(z) * 30.0, speed, rtol=1e-4)  # frame 0 onwards at speed
    assert joint_rotation_deg(m.poses).min() > 50.0  # never the T-pose: the arms hang, swinging
    # the lead-in before t = 0 starts standing still in the T-pose and reaches the speed there
    lead = m.extra["lead_in"]
    assert lead.num_frames == 30
    np.testing.assert_array_equal(lead.poses[0], 0.0)
    lz = lead.trans[:, 2].astype(np.float64)
    assert abs(lz[1] - lz[0]) * 30.0 < 0.01 * speed
    assert (z[0] - lz[-1]) * 30.0 == pytest.approx(speed, rel=0.01)


@pytest.mark.parametrize("name", [n for n in PROCEDURAL_MOTIONS if n != "rest_to_apose"])
def test_short_clips_are_the_motion_not_the_ramp(name):
    """0.6 s clips (the sample dataset's): every motion is away from the rest pose over the whole
    clip (the ramp from it, 1 s by default, is the lead-in); ``rest_to_apose`` is the ramp itself."""
    m = load_motion(name, fps=30.0, duration=0.6)
    assert m.num_frames == 18 and m.extra["lead_in"].num_frames > 0
    rot = joint_rotation_deg(m.poses)
    assert np.median(rot) > 30.0, (name, np.median(rot))


def test_the_sample_dataset_clips_contain_their_motion(body):
    """The shipped sample config's sequences, as the generator builds them (no simulation): every
    stored clip is in full motion, the walks walking at their sampled speed from frame 0."""
    from sim.datasets.config import load_config
    from sim.datasets.generate import sequence_inputs
    from sim.datasets.sampling import sample_sequences

    cfg = load_config("sample")
    specs = sample_sequences(cfg)
    assert {sp.motion_label for sp in specs} >= {"walk", "arm_raise"}
    for sp in specs:
        _, m = sequence_inputs(cfg, sp, body)
        assert m.num_frames == round(cfg.seconds * cfg.fps)
        rot = joint_rotation_deg(m.poses)
        assert np.median(rot) > 30.0, (sp.id, sp.motion_label)
        moved = np.degrees(np.ptp(m.poses[:, 1:], axis=0)).max()  # some joint moves in the clip
        assert moved > 10.0, (sp.id, sp.motion_label, moved)
        if sp.motion_label == "walk":
            speed = m.extra["params"]["speed"]
            assert 1.0 <= speed <= 1.5
            np.testing.assert_allclose(np.diff(m.trans[:, 2].astype(np.float64)) * cfg.fps, speed, rtol=1e-4)


@pytest.mark.slow
@needs_usd
def test_a_simulated_one_second_squat_is_one_second_of_squatting(tmp_path):
    """``wrinkles simulate --motion squat --duration 1``: 30 output frames, none of the prelude
    (settle, lead-in) among them, and the skirt's waistband, pinned to the waist, sinks with the
    pelvis over them."""
    from pipelines.cli import main
    from usd_io import read_stage

    out = tmp_path / "squat.usda"
    rc = main(["simulate", "--garment", "straight_skirt", "--motion", "squat", "--duration", "1",
               "--param", "ramp=0.3", "--resolution", "0.06", "--settle", "0.2", "--substeps", "3",
               "--iterations", "3", "--allow-failed-gates", "--no-retry", "--device", "cpu", "--quiet",
               "--out", str(out)])
    assert rc == 0
    st = read_stage(out)
    g = st.garments["straight_skirt"]
    assert g.points.shape[0] == 30
    frames = st.metadata["provenance"]["frames"]
    assert frames["output"] == 30 and frames["settle"] == 6 and frames["blend"] == 9
    assert frames["entry"] == "lead_in" and frames["first_output_timeline_frame"] == 15
    top = g.points[:, :, 1].max(axis=1)  # the waistband: the skirt's highest points
    assert top[0] - top[-1] > 0.2
    assert np.all(np.diff(top) < 2e-3)  # going down all along (the first squat's descent)
