"""The ``wrinkles`` CLI end to end on tiny CPU configurations, and its handling of bad input:
one line naming the file and the problem, exit status 2, no traceback, no partial output."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipelines.cli import main


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run the CLI in a fresh interpreter, as a user would."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.run([sys.executable, "-m", "pipelines.cli", *args], capture_output=True,
                          text=True, cwd=cwd, env=env, timeout=300)


def assert_user_error(proc: subprocess.CompletedProcess, *needles: str) -> None:
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert "Traceback" not in err, err
    assert len(err.splitlines()) == 1, err
    for n in needles:
        assert n in err, err


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "body" in out and "motions" in out


def test_body_help_explains_itself(capsys):
    with pytest.raises(SystemExit):
        main(["body", "--help"])
    out = capsys.readouterr().out
    for flag in ("--motion", "--shape", "--out", "--preview", "--device", "--seed", "examples:"):
        assert flag in out


def test_motions_lists_library(capsys):
    assert main(["motions", "--params"]) == 0
    out = capsys.readouterr().out
    for name in ("walk", "run", "jump", "squat", "arm_raise", "torso_twist", "random", "rest_to_apose"):
        assert name in out
    assert "--motion-param" in out


@pytest.mark.slow
def test_body_writes_usd_and_preview(tmp_path):
    from usd_io import read_stage, validate_stage

    usd = tmp_path / "walk.usda"
    mp4 = tmp_path / "walk.mp4"
    rc = main(["body", "--motion", "walk", "--param", "ramp=0.1", "--duration", "0.5", "--fps", "10",
               "--out", str(usd),
               "--preview", str(mp4), "--device", "cpu", "--quiet"])
    assert rc == 0
    st = read_stage(usd)
    assert st.fps == 10
    pts = st.body.points
    assert pts.shape[0] == 5
    # grounded: the lowest vertex of frame 0 is on the floor
    assert abs(float(pts[0, :, 1].min())) < 1e-5
    # the walker moves forward (+Z), at about the default 1.3 m/s once past the 0.1 s ramp
    assert pts[-1, :, 2].mean() > pts[0, :, 2].mean() + 0.3
    assert validate_stage(usd) == []
    assert mp4.stat().st_size > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.mp4", "walk.usda"]


@pytest.mark.slow
def test_body_self_crossings_are_counted_by_joint(tmp_path, capsys):
    """``wrinkles body --self-crossings``: the default body never passes through itself in the walk;
    in the run its knee pits fold through themselves (the calf into the thigh, skinned by the knee
    and hip joints), counted by frame and joint, printed and kept in the stage's metadata."""
    from usd_io import read_stage

    found = {}
    for motion, seconds in (("walk", 1.0), ("run", 1.5)):
        usd = tmp_path / f"{motion}.usda"
        assert main(["body", "--motion", motion, "--duration", str(seconds), "--out", str(usd),
                     "--device", "cpu", "--self-crossings"]) == 0
        out = capsys.readouterr().out
        c = read_stage(usd).metadata["self_crossings"]
        assert len(c["per_frame"]) == int(round(seconds * 30))
        assert c["rest_pose_crossing_edges"] > 0  # the default mesh's toes, not counted per frame
        found[motion] = c
        assert ("self-crossings: the body does not pass through itself in its" in out) == (motion == "walk")
        assert ("self-crossings: the body passes through itself in" in out) == (motion == "run")
    assert found["walk"]["frames_with_crossings"] == 0 and found["walk"]["by_joint"] == {}
    run = found["run"]
    assert run["frames_with_crossings"] > 0 and run["max_edges"] > 0
    assert {"left_knee", "right_knee"} & set(run["by_joint"])
    for v in run["by_joint"].values():
        assert all(run["per_frame"][t] > 0 for t in v["frames"])


def test_same_seed_same_output(tmp_path):
    outs = []
    for k in range(2):
        p = tmp_path / f"r{k}.usda"
        assert main(["body", "--motion", "random", "--duration", "0.3", "--fps", "10", "--seed", "3",
                     "--out", str(p), "--device", "cpu", "--quiet"]) == 0
        from usd_io import read_stage

        outs.append(read_stage(p).body.points)
    np.testing.assert_array_equal(outs[0], outs[1])


def write(path: Path, data: bytes | str) -> Path:
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


@pytest.mark.parametrize("case", ["unknown_motion", "bad_bvh", "corrupt_model", "missing_model",
                                  "nan_amass", "bad_suffix", "bad_shape", "negative_shape", "bad_param"])
def test_bad_input_is_one_line_exit_2_no_output(tmp_path, case):
    out = tmp_path / "o.usda"
    args = ["body", "--out", str(out), "--device", "cpu", "--quiet", "--duration", "0.2"]
    needles: tuple[str, ...]
    if case == "unknown_motion":
        args += ["--motion", "moonwalk"]
        needles = ("moonwalk", "walk")
    elif case == "bad_bvh":
        f = write(tmp_path / "broken.bvh", "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
        args += ["--motion", str(f)]
        needles = ("broken.bvh",)
    elif case == "corrupt_model":
        f = write(tmp_path / "SMPL_BROKEN.npz", b"PK\x03\x04 this is not a zip")
        args += ["--body", str(f)]
        needles = ("SMPL_BROKEN.npz",)
    elif case == "missing_model":
        args += ["--body", str(tmp_path / "nope.pkl")]
        needles = ("nope.pkl",)
    elif case == "nan_amass":
        f = tmp_path / "clip.npz"
        poses = np.zeros((10, 156), np.float32)
        poses[4, 7] = np.nan
        np.savez(f, poses=poses, trans=np.zeros((10, 3)), mocap_framerate=30.0, betas=np.zeros(16))
        args += ["--motion", str(f)]
        needles = ("clip.npz", "NaN")
    elif case == "bad_suffix":
        args[args.index("--out") + 1] = str(tmp_path / "o.obj")
        needles = ("o.obj", "--out")
    elif case == "bad_shape":
        args += ["--shape", "height=abc"]
        needles = ("height",)
    elif case == "negative_shape":
        # betas starting with a minus sign reach the shape parser (argparse alone stops at "--shape
        # expected one argument"), which names the count
        args += ["--shape", ",".join(["-0.5"] * 21)]
        needles = ("--shape", "21 betas", "16")
    else:
        args += ["--param", "wings=2"]
        needles = ("wings",)
    proc = run_cli(*args)
    assert_user_error(proc, *needles)
    assert list(tmp_path.glob("o.*")) == []
    assert not any(p.name.startswith(".o.") for p in tmp_path.iterdir())


def test_negative_betas_are_joined_to_their_option():
    from pipelines.cli import build_parser
    from pipelines.options import join_negative_values

    argv = ["body", "--shape", "-1.2,0.5", "--out", "a.usda", "--seed", "-1"]
    joined = join_negative_values(argv)
    assert joined == ["body", "--shape=-1.2,0.5", "--out", "a.usda", "--seed", "-1"]
    assert build_parser().parse_args(joined).shape == "-1.2,0.5"
    assert join_negative_values(["--shape", "-2"]) == ["--shape=-2"]
    # not number lists, other options, a missing value and everything after "--" stay as they are
    for same in (["--shape", "height=0.5"], ["--shape", "-h"], ["--shape", "-1,,2"], ["--shape"],
                 ["--shape=-1,2"], ["--body", "-1,2"], ["--", "--shape", "-1,2"]):
        assert join_negative_values(same) == same


def test_interrupted_preview_leaves_nothing(tmp_path, monkeypatch):
    """An error in the last writer removes the files the earlier writers produced."""
    import pipelines.preview as preview

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(preview, "write_video", boom)
    with pytest.raises(RuntimeError):
        main(["body", "--motion", "squat", "--duration", "0.2", "--fps", "10", "--device", "cpu",
              "--out", str(tmp_path / "a.usda"), "--preview", str(tmp_path / "a.mp4"), "--quiet"])
    assert list(tmp_path.iterdir()) == []


def test_every_documented_shape_parses_and_the_help_states_the_ranges():
    """Every ``--shape`` example in the README and the commands' help is a shape the default
    body takes (a value out of its range, such as height=0.9, is refused), and ``--help``'s
    phenotype ranges and means are the body's own."""
    import re
    from pathlib import Path

    from pipelines.cli import COMMANDS
    from pipelines.options import SHAPE_RANGES_HELP
    from sim.bodies.default import parse_shape, phenotype_mean, phenotype_ranges

    texts = [Path(__file__).resolve().parents[1].joinpath("README.md").read_text()]
    texts += [mod.DESCRIPTION for mod in COMMANDS.values()]
    item = r"(?:[a-z]+=)?-?[\d.]+"
    examples = {m for t in texts for m in re.findall(rf"--shape[ =]'?({item}(?:,{item})*)", t)}
    assert len(examples) >= 3
    for spec in examples:
        parse_shape(spec)  # raises on a value out of range
    for name, (lo, hi) in phenotype_ranges().items():
        assert re.search(rf"{name} {lo:.2g}-{hi:.2g}", SHAPE_RANGES_HELP), name
    for name in ("height", "weight", "muscle"):
        assert f"{phenotype_mean()[name]:.2f}" in SHAPE_RANGES_HELP, name


@pytest.mark.parametrize("command, want", [
    (["simulate", "--garment", "skirt", "--motion", "squat"], "out/skirt_squat.usdc"),
    (["animate", "--garment", "tshirt", "--motion", "walk"], "out/tshirt_walk.usdc"),
])
def test_stages_are_binary_usd_unless_asked(monkeypatch, capsys, command, want):
    """Without --out, simulate and animate write a binary .usdc stage; the help says so, and
    names the motion's parameters --motion-param."""
    from pipelines import animate_cmd, simulate_cmd
    from sim.errors import WrinklesInputError

    asked = []

    def stop(out, *args, **kwargs):
        asked.append(out)
        raise WrinklesInputError("stopped by the test")

    for mod in (animate_cmd, simulate_cmd):
        monkeypatch.setattr(mod, "check_stage_outputs", stop)
    assert main([*command, "--device", "cpu", "--quiet"]) == 2
    assert asked == [want]
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main([command[0], "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: out/" in text and ".usdc)" in text and "--motion-param" in text
    described = (simulate_cmd if command[0] == "simulate" else animate_cmd).DESCRIPTION
    assert "--motion-param" in described and "/--param/" not in described and ".usda \\" not in described
