"""Progress of long work on stderr: a tqdm bar on a terminal; on a pipe or a log file, lines.

Every long function in wrinkles takes a callback ``progress(done, total)``; ``progress_bar``
makes one. On a terminal it drives a tqdm bar. Anywhere else (a pipe, a log file, a CI job) a
bar's carriage returns are noise or nothing at all, so it writes a line when the stage starts,
one every ``PROGRESS_INTERVAL`` seconds (also while the work is between two callbacks: a
diffusion batch can take a minute) and one when it ends, each with the stage, done/total, the
rate, the time spent and the time left::

    wrinkle sampling: 16/60 frames (27%), 3.25 s/frame, 0:52 elapsed, ETA 2:22

``--quiet`` gives a callback that does nothing, also to library code that draws its own bars
(a method's data preparation inside ``wrinkles train``): the CLI runs a quiet command inside
``quiet_progress``.
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
import threading
import time
from collections.abc import Callable
from typing import TextIO

PROGRESS_INTERVAL = 5.0
"""Seconds between two progress lines on a pipe or a log [s]: often enough to see a run move,
rarely enough to keep a 20-minute log short (~240 lines)."""


def _clock_text(seconds: float) -> str:
    """``m:ss`` or ``h:mm:ss``."""
    s = int(round(max(seconds, 0.0)))
    h, m = divmod(s // 60, 60)
    return f"{h}:{m:02d}:{s % 60:02d}" if h else f"{m}:{s % 60:02d}"


def _plural(unit: str) -> str:
    return unit if unit.endswith("s") else unit + "s"


class ProgressLines:
    """A ``progress(done, total=None, *, note=None)`` callback that writes progress lines (see
    the module doc); ``note`` (e.g. "loss 0.012") ends the line.

    The rate is measured from the first callback on, once there are two (so a resumed run's
    earlier work and the time before the first unit, kernel compilation included, do not skew
    it), and from the start before that. The ETA is the work left at that rate.

    Args:
        total: units of work (0 or None: not known yet; a later callback may give it).
        desc: the stage, e.g. "simulating t_shirt".
        unit: what is counted, singular ("frame", "step", "sequence").
        stream: where the lines go (default: ``sys.stderr`` at the time of each line).
        interval: seconds between lines [s] (default ``PROGRESS_INTERVAL``).
        clock: monotonic time in seconds (a fake one in tests).
        heartbeat: a background thread writes the line that is due when no callback comes.
    """

    def __init__(self, total: int | None, desc: str, *, unit: str = "frame", stream: TextIO | None = None,
                 interval: float | None = None, clock: Callable[[], float] = time.monotonic,
                 heartbeat: bool = True):
        self.total = int(total or 0)
        self.desc, self.unit, self.stream = desc, unit, stream
        self.interval = PROGRESS_INTERVAL if interval is None else float(interval)
        self.clock, self.heartbeat = clock, heartbeat
        self.done, self.note = 0, ""
        self._start = self._last_line = 0.0
        self._first: tuple[int, float] | None = None  # (done, time) of the first callback
        self._latest: tuple[int, float] | None = None  # and of the latest
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed_stream = False

    def __enter__(self) -> ProgressLines:
        self._start = self._last_line = self.clock()
        self._write(f"{self.desc}: {self._count()}, started")
        if self.heartbeat:
            self._thread = threading.Thread(target=self._beat, name=f"progress: {self.desc}", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if exc_type is None:  # a stage that stopped says so in its own error, not here
            with self._lock:
                rate = self.rate()
                text = f"{self.desc}: {self._count()}"
                text += f", {self._rate_text(rate)}" if rate else ""
                self._write(f"{text}, done in {_clock_text(self.clock() - self._start)}{self._note()}")

    def __call__(self, done: int, total: int | None = None, *, note: str | None = None) -> None:
        with self._lock:
            now = self.clock()
            self.done = int(done)
            if total:
                self.total = int(total)
            if note is not None:
                self.note = note
            self._latest = (self.done, now)
            if self._first is None:
                self._first = self._latest
            if now - self._last_line >= self.interval:
                self._line()

    def rate(self) -> float | None:
        """Units per second (None before any progress)."""
        if self._latest is None:
            return None
        (d0, t0), (d1, t1) = self._first, self._latest
        if d1 > d0 and t1 > t0:
            return (d1 - d0) / (t1 - t0)
        if d1 > 0 and t1 > self._start:
            return d1 / (t1 - self._start)
        return None

    def line(self) -> str:
        """The progress line as it stands now."""
        now = self.clock()
        rate = self.rate()
        text = f"{self.desc}: {self._count()}"
        if rate:
            text += f", {self._rate_text(rate)}"
        text += f", {_clock_text(now - self._start)} elapsed"
        if self.total and rate:
            left = (self.total - self.done) / rate - (now - self._latest[1])
            text += f", ETA {_clock_text(left)}"
        elif self.total:
            text += ", ETA unknown"
        return text + self._note()

    def _count(self) -> str:
        units = _plural(self.unit)
        if not self.total:
            return f"{self.done} {units}"
        return f"{self.done}/{self.total} {units} ({100.0 * self.done / self.total:.0f}%)"

    def _rate_text(self, rate: float) -> str:
        if rate >= 1.0:
            number = f"{rate:.0f}" if rate >= 100 else f"{rate:.3g}"
            return f"{number} {_plural(self.unit)}/s"
        return f"{1.0 / rate:.3g} s/{self.unit}"

    def _note(self) -> str:
        return f", {self.note}" if self.note else ""

    def _line(self) -> None:
        self._last_line = self.clock()
        self._write(self.line())

    def _write(self, text: str) -> None:
        if self._closed_stream:
            return
        try:
            print(text, file=self.stream or sys.stderr, flush=True)
        except (OSError, ValueError):  # the reader of the pipe left, or the log was closed: go quiet
            self._closed_stream = True

    def _beat(self) -> None:
        while True:
            with self._lock:
                wait = self._last_line + self.interval - self.clock()
            if self._stop.wait(max(wait, 0.05)):
                return
            with self._lock:
                if self.clock() - self._last_line >= self.interval:
                    self._line()


def is_terminal(stream: TextIO) -> bool:
    """Whether ``stream`` is an interactive terminal (where a bar can redraw itself)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed file
        return False


_QUIET = contextvars.ContextVar("wrinkles_quiet_progress", default=False)


@contextlib.contextmanager
def quiet_progress(quiet: bool = True):
    """Every ``progress_bar`` opened inside the block is quiet when ``quiet`` (a command's
    ``--quiet`` reaching bars it does not open itself)."""
    token = _QUIET.set(bool(quiet) or _QUIET.get())
    try:
        yield
    finally:
        _QUIET.reset(token)


@contextlib.contextmanager
def progress_bar(total: int, desc: str, *, quiet: bool = False, unit: str = "frame",
                 stream: TextIO | None = None):
    """Yield a callback ``progress(done, total=None, *, note=None)`` that shows the progress of
    one stage: a tqdm bar on a terminal, progress lines elsewhere (``ProgressLines``), nothing
    when ``quiet``. ``total`` may be 0 when it is known only once the work starts; ``note`` is
    a short status shown after the count (e.g. "loss 0.012")."""
    if quiet or _QUIET.get():
        yield lambda done, total=None, *, note=None: None
        return
    stream = sys.stderr if stream is None else stream
    if not is_terminal(stream):
        with ProgressLines(total, desc, unit=unit, stream=stream) as lines:
            yield lines
        return
    from tqdm import tqdm

    with tqdm(total=total, desc=desc, unit=unit, dynamic_ncols=True, leave=False, file=stream,
              disable=False) as bar:

        def progress(done: int, total: int | None = None, *, note: str | None = None) -> None:
            if total and bar.total != total:  # callers that learn the total late (evaluate)
                bar.total = total
            if note is not None:
                bar.set_postfix_str(note, refresh=False)
            bar.update(done - bar.n)

        yield progress


class LazyProgressBar:
    """A ``progress(done, total)`` callback that opens a ``progress_bar`` on its first call (for
    work whose total is known only once it starts); the ``with`` block it is used in ends it."""

    def __init__(self, desc: str, quiet: bool, *, unit: str = "step"):
        self.desc, self.quiet, self.unit = desc, quiet, unit
        self._cm = None
        self._cb = None

    def __enter__(self) -> LazyProgressBar:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._cm is not None:
            cm, self._cm, self._cb = self._cm, None, None
            if exc_type is None:
                cm.__exit__(None, None, None)
            else:  # let the bar see the error (no "done" line), then let it propagate
                with contextlib.suppress(BaseException):
                    cm.__exit__(exc_type, exc, tb)

    def __call__(self, done: int, total: int, *, note: str | None = None) -> None:
        if self._cb is None:
            self._cm = progress_bar(total, self.desc, quiet=self.quiet, unit=self.unit)
            self._cb = self._cm.__enter__()
        self._cb(done, total, note=note)
