"""pipelines/outputs.py and the CLI's interrupt handling: a failed or killed job leaves nothing
behind, not even the folders it would have written into."""

from __future__ import annotations

import os
import signal

import pytest

from pipelines.outputs import OutputSet, check_output_path
from sim.errors import WrinklesInputError


def test_checking_an_output_path_makes_nothing(tmp_path):
    out = check_output_path(tmp_path / "a" / "b" / "x.usda", (".usda",), "--out")
    assert out == tmp_path / "a" / "b" / "x.usda"
    assert list(tmp_path.iterdir()) == []  # the folders come when the job writes
    (tmp_path / "afile").write_text("")
    with pytest.raises(WrinklesInputError, match="afile is not a directory"):
        check_output_path(tmp_path / "afile" / "x.usda", (".usda",), "--out")
    with pytest.raises(WrinklesInputError, match="must end in one of"):
        check_output_path(tmp_path / "x.abc", (".usda",), "--out")


def test_an_unusable_output_place_is_refused_up_front(tmp_path, monkeypatch):
    """A link to nowhere on the way, and a folder that refuses files (the suite runs as root,
    so the refusal is simulated), are one-line errors before the job, not tracebacks after it."""
    import tempfile

    (tmp_path / "dangling").symlink_to(tmp_path / "missing")
    with pytest.raises(WrinklesInputError, match="dangling is not a directory"):
        check_output_path(tmp_path / "dangling" / "x.usda", (".usda",), "--out")

    def refused(*a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "TemporaryFile", refused)
    with pytest.raises(WrinklesInputError, match=r"x.usda: cannot write there: Permission denied"):
        check_output_path(tmp_path / "sub" / "x.usda", (".usda",), "--out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dangling"]


def test_a_failed_job_removes_its_temporaries_and_the_folders_it_made(tmp_path):
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "other.txt").write_text("someone else's")
    with pytest.raises(RuntimeError), OutputSet() as out:
        out.temp(tmp_path / "new" / "x.usda").write_text("partial")  # a shallow folder first,
        out.temp(tmp_path / "new" / "deeper" / "still" / "x.png").write_text("partial")  # then deeper
        out.temp(tmp_path / "kept" / "y.json").write_text("partial")
        raise RuntimeError("the job failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"]
    assert [p.name for p in (tmp_path / "kept").iterdir()] == ["other.txt"]
    # a job that succeeds keeps its folders and files
    with OutputSet() as out:
        out.temp(tmp_path / "new" / "x.usda").write_text("done")
    assert (tmp_path / "new" / "x.usda").read_text() == "done"
    assert [p.name for p in (tmp_path / "new").iterdir()] == ["x.usda"]


def test_sigterm_unwinds_a_command_as_an_interrupt(tmp_path, monkeypatch, capsys):
    """A scheduler's SIGTERM during the write: exit 143, one line, no temporaries left, and the
    process's own SIGTERM handler back in place afterwards."""
    from pipelines import cli, garments_cmd

    def killed_while_writing(args):
        with OutputSet() as out:
            out.temp(tmp_path / "sub" / "tee.obj").write_text("half a mesh")
            os.kill(os.getpid(), signal.SIGTERM)
        return 0

    monkeypatch.setattr(garments_cmd, "run", killed_while_writing)
    before = signal.getsignal(signal.SIGTERM)
    assert cli.main(["garments"]) == 143
    assert capsys.readouterr().err.strip() == "wrinkles garments: terminated; no output was written"
    assert list(tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGTERM) == before


def test_a_closed_pipe_ends_the_listing_quietly(monkeypatch, capsys):
    """``wrinkles garments | head``: the reader leaves, the command stops without a traceback."""
    from pipelines import cli, garments_cmd

    def reader_gone(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(garments_cmd, "run", reader_gone)
    saved = os.dup(1)
    try:
        assert cli.main(["garments"]) == 141
    finally:
        os.dup2(saved, 1)
        os.close(saved)
    assert "Traceback" not in capsys.readouterr().err


def test_a_reader_that_left_ends_the_command_quietly_with_buffered_output():
    """With ordinary buffering (no PYTHONUNBUFFERED), stdout is flushed inside the command, where
    the closed pipe is caught: exit 141 and nothing on stderr, not "Exception ignored ... Broken
    pipe" at the interpreter's exit."""
    import subprocess
    import sys
    from pathlib import Path

    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    r, w = os.pipe()
    os.close(r)  # the reader is gone before the command writes
    try:
        proc = subprocess.run([sys.executable, "-m", "pipelines.cli", "motions"], stdout=w,
                              stderr=subprocess.PIPE, env=env, cwd=Path(__file__).resolve().parents[1],
                              timeout=120)
    finally:
        os.close(w)
    assert proc.returncode == 141 and proc.stderr == b"", proc.stderr.decode()


def test_stage_rig_is_the_shaped_body_unless_points_are_asked_or_the_shape_changes():
    """``stage_rig``: the body model's rig for the frames' betas; None (a point cache) with
    ``--body-points`` or for frames whose body changes shape (no one rig poses them)."""
    import argparse
    import dataclasses

    import numpy as np

    from pipelines.outputs import add_body_points_option, stage_rig
    from tests.conftest import random_body

    body = random_body(120, seed=1, posedirs=False)
    betas = np.linspace(-1.0, 1.0, body.num_betas).astype(np.float32)
    poses = np.random.default_rng(0).normal(scale=0.3, size=(4, 24, 3)).astype(np.float32)
    frames = body.pose(betas, poses, device="cpu")
    rig = stage_rig(body, betas, frames, points=False)
    np.testing.assert_array_equal(rig.rest_vertices, body.rest_mesh(betas))
    assert stage_rig(body, betas, frames, points=True) is None
    morphed = body.pose(None, poses, device="cpu")  # frame 1 posed on the mean shape
    mixed = dataclasses.replace(frames, vertices=frames.vertices.copy(),
                                transforms=frames.transforms.copy())
    mixed.vertices[1], mixed.transforms[1] = morphed.vertices[1], morphed.transforms[1]
    assert stage_rig(body, betas, mixed, points=False) is None
    parser = argparse.ArgumentParser()
    add_body_points_option(parser)
    assert parser.parse_args(["--body-points"]).body_points
    assert not parser.parse_args([]).body_points
