"""Progress on stderr (pipelines/progress.py): a tqdm bar on a terminal; on a pipe or a log, a
line when a stage starts, one every PROGRESS_INTERVAL seconds with the stage, done/total, the
rate and the ETA, and one when it ends; nothing with --quiet."""

from __future__ import annotations

import io
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipelines import progress as P

ROOT = Path(__file__).resolve().parents[1]


class FakeClock:
    """Seconds that pass only when the test says so."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_lines_on_a_pipe_carry_stage_count_rate_and_eta():
    clock, out = FakeClock(), io.StringIO()
    with P.ProgressLines(10, "simulating skirt", stream=out, interval=5.0, clock=clock,
                         heartbeat=False) as progress:
        clock.now += 1.0
        progress(1, 10)  # 1 s in: no line before the interval
        clock.now += 4.0
        progress(3, 10)  # 5 s in: a line; 2 frames in the 4 s since the first callback
        clock.now += 2.0
        progress(4, 10)
        clock.now += 3.0
        progress(6, 10)  # 10 s in: 5 frames in 9 s since the first
        clock.now += 4.0
        progress(10, 10)  # 4 s after the last line: none
    lines = out.getvalue().splitlines()
    assert lines == [
        "simulating skirt: 0/10 frames (0%), started",
        "simulating skirt: 3/10 frames (30%), 2 s/frame, 0:05 elapsed, ETA 0:14",
        "simulating skirt: 6/10 frames (60%), 1.8 s/frame, 0:10 elapsed, ETA 0:07",
        "simulating skirt: 10/10 frames (100%), 1.44 s/frame, done in 0:14",
    ]


def test_rates_over_one_per_second_and_a_total_known_late():
    clock, out = FakeClock(), io.StringIO()
    with P.ProgressLines(0, "evaluate test_id", unit="sequence", stream=out, interval=0.0, clock=clock,
                         heartbeat=False) as progress:
        clock.now += 2.0
        progress(5, 40)
        clock.now += 2.0
        progress(40, note="loss 0.25")
    lines = out.getvalue().splitlines()
    assert lines[0] == "evaluate test_id: 0 sequences, started"
    assert lines[1] == "evaluate test_id: 5/40 sequences (12%), 2.5 sequences/s, 0:02 elapsed, ETA 0:14"
    assert lines[2] == ("evaluate test_id: 40/40 sequences (100%), 17.5 sequences/s, 0:04 elapsed, ETA 0:00, "
                        "loss 0.25")
    assert lines[3] == "evaluate test_id: 40/40 sequences (100%), 17.5 sequences/s, done in 0:04, loss 0.25"


def test_a_stage_that_fails_ends_without_a_done_line():
    clock, out = FakeClock(), io.StringIO()
    with pytest.raises(RuntimeError), P.ProgressLines(4, "writing USD", stream=out, clock=clock,
                                                      heartbeat=False) as progress:
        progress(1, 4)
        raise RuntimeError("disk full")
    assert out.getvalue().splitlines() == ["writing USD: 0/4 frames (0%), started"]


def test_the_heartbeat_writes_while_no_callback_comes():
    """A diffusion batch can take a minute between two callbacks: the line still comes every
    interval, with the time elapsed."""
    out = io.StringIO()
    with P.ProgressLines(60, "wrinkle sampling", stream=out, interval=0.02):
        deadline = time.monotonic() + 10.0
        while out.getvalue().count("\n") < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
    lines = out.getvalue().splitlines()
    assert len(lines) >= 4, lines
    assert lines[1].startswith("wrinkle sampling: 0/60 frames (0%), 0:00 elapsed, ETA unknown")
    assert lines[-1].startswith("wrinkle sampling: 0/60 frames (0%), done in")


def test_progress_bar_picks_tqdm_on_a_terminal_lines_elsewhere_nothing_when_quiet(monkeypatch):
    monkeypatch.setattr(P, "PROGRESS_INTERVAL", 0.0)
    term, pipe = Terminal(), io.StringIO()
    for stream in (term, pipe):
        with P.progress_bar(3, "skinning", stream=stream) as progress:
            for k in range(1, 4):
                progress(k, 3)
    assert "\r" in term.getvalue() and "skinning" in term.getvalue() and "0/3" in term.getvalue()
    assert "started" not in term.getvalue()
    lines = pipe.getvalue().splitlines()
    assert "\r" not in pipe.getvalue() and lines[0] == "skinning: 0/3 frames (0%), started"
    assert len(lines) == 5 and re.fullmatch(r"skinning: 3/3 frames \(100%\), .* done in 0:00", lines[-1])
    quiet = io.StringIO()
    with P.progress_bar(3, "skinning", quiet=True, stream=quiet) as progress:
        progress(3, 3, note="x")
    assert quiet.getvalue() == ""


def test_quiet_progress_silences_bars_opened_inside_it_and_only_there(monkeypatch):
    """A command's --quiet reaches the bars of code it calls (a method preparing its data opens
    its own): inside ``quiet_progress`` every bar is quiet, nested blocks cannot undo it, and
    after the block bars write again."""
    monkeypatch.setattr(P, "PROGRESS_INTERVAL", 0.0)
    inside, after = io.StringIO(), io.StringIO()
    with P.quiet_progress():
        with P.quiet_progress(False):  # an inner block without --quiet stays quiet
            with P.progress_bar(2, "preparing sequences", stream=inside) as progress:
                progress(2, 2)
    assert inside.getvalue() == ""
    with P.quiet_progress(False), P.progress_bar(2, "preparing sequences", stream=after) as progress:
        progress(2, 2)
    assert after.getvalue().splitlines()[0] == "preparing sequences: 0/2 frames (0%), started"


def test_lazy_bar_opens_at_the_first_callback_and_closes_with_its_block(monkeypatch):
    out = io.StringIO()
    monkeypatch.setattr(sys, "stderr", out)
    with P.LazyProgressBar("dataset report", quiet=False) as bar:
        assert out.getvalue() == ""
        bar(1, 2)
        bar(2, 2)
    lines = out.getvalue().splitlines()
    assert lines[0] == "dataset report: 0/2 steps (0%), started" and "done in" in lines[-1]


def test_a_command_on_a_pipe_prints_progress_lines(tmp_path):
    """``wrinkles body`` with stderr on a pipe: each stage says it started and when it was done,
    with its frame count; stdout keeps the summary alone."""
    out = tmp_path / "b.usdc"
    proc = subprocess.run([sys.executable, "-m", "pipelines.cli", "body", "--motion", "walk", "--duration",
                           "0.2", "--device", "cpu", "--out", str(out)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    started = [ln for ln in lines if re.fullmatch(r"[\w ]+: 0/\d+ frames \(0%\), started", ln)]
    done = [ln for ln in lines
            if re.fullmatch(r"[\w ]+: (\d+)/\1 frames \(100%\)(, .*)?, done in \d+:\d\d", ln)]
    assert len(started) >= 2 and len(done) == len(started), proc.stderr
    assert "\r" not in proc.stderr and "started" not in proc.stdout


def test_a_command_with_quiet_prints_no_progress(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "pipelines.cli", "body", "--motion", "walk", "--duration",
                           "0.2", "--device", "cpu", "--out", str(tmp_path / "b.usdc"), "--quiet"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


@pytest.mark.slow
def test_animate_on_a_pipe_reports_every_stage(tmp_path, monkeypatch, capsys):
    """The demo's command in miniature, stderr captured (not a terminal), a line at every
    callback: the wrinkle sampling says its DDIM steps, frames, rate and ETA; the USD and the
    preview stages report too."""
    from pipelines.cli import main

    monkeypatch.setattr(P, "PROGRESS_INTERVAL", 0.0)
    out = tmp_path / "a.usdc"
    assert main(["animate", "--garment", "tshirt", "--motion", "walk", "--duration", "0.2", "--steps", "2",
                 "--device", "cpu", "--out", str(out), "--preview", str(tmp_path / "a.gif")]) == 0
    err = capsys.readouterr().err.splitlines()
    for stage in ("wrinkle sampling (2 DDIM steps)", "writing USD", "preview"):
        mine = [ln for ln in err if ln.startswith(stage + ":")]
        assert mine[0] == f"{stage}: 0/6 frames (0%), started", err
        assert re.fullmatch(rf"{re.escape(stage)}: 6/6 frames \(100%\)(, .*)?, done in \d+:\d\d", mine[-1])
    # the lines once frames are done (before, the heartbeat's say "ETA unknown")
    sampling = [ln for ln in err if ln.startswith("wrinkle sampling") and "elapsed" in ln
                and " 0/6" not in ln]
    assert sampling and all(re.search(r"\d+/6 frames \(\d+%\), [\d.]+ (s/frame|frames/s), \d+:\d\d elapsed, "
                                      r"ETA \d+:\d\d", ln) for ln in sampling), sampling


def test_a_closed_stream_silences_the_lines_not_the_work():
    class Gone(io.StringIO):
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

    with P.ProgressLines(3, "preview", stream=Gone(), interval=0.0, heartbeat=False) as progress:
        for k in range(1, 4):
            progress(k, 3)
    assert progress.done == 3
