"""Where a long job's wall time goes, phase by phase (``bench_dataset`` reports it).

Code marks its phases with ``with phase("name"):``; phases nest, and a phase inside another is
recorded under the path of names (``"simulation/prelude/body separation"``). Off by default, a
mark costs one attribute test. ``PHASES.start(device)`` turns it on: a phase then waits for the
device when it begins and ends (``wp.synchronize_device``), so the GPU work launched inside it
counts there and not in whichever later phase happens to wait for it (measured this way a run
is slower by the waits it adds, which a real run overlaps). ``PHASES.report()`` gives, per
path, the wall seconds, the seconds outside its nested phases (``self_s``: these add up to the
time spent inside any phase) and how often it ran.
"""

from __future__ import annotations

import time
from contextlib import contextmanager


class Phases:
    """The phase recorder (``PHASES``); see the module docstring."""

    def __init__(self) -> None:
        self.on = False
        self.device: str | None = None
        self._stack: list[str] = []  # the names of the phases now running, outermost first
        self._child: list[float] = []  # per running phase, the seconds of the phases it ran
        self._paths: dict[str, list] = {}  # path -> [s, self_s, calls], in the order paths began

    def start(self, device: str | None = None) -> None:
        """Forget what was recorded and record from now on, waiting for ``device`` (a Warp
        device; None: no wait) at every phase's start and end."""
        self._stack, self._child, self._paths = [], [], {}
        self.on, self.device = True, device

    def stop(self) -> None:
        """Record no more (what was recorded stays for ``report``)."""
        self.on = False

    def _wait(self) -> None:
        if self.device is not None:
            from sim.device import warp

            warp().synchronize_device(self.device)

    @contextmanager
    def record(self, name: str):
        """Time the block as phase ``name`` under the phases it runs in."""
        self._wait()
        path = "/".join([*self._stack, name])
        entry = self._paths.setdefault(path, [0.0, 0.0, 0])
        self._stack.append(name)
        self._child.append(0.0)
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self._wait()
            dt = time.perf_counter() - t0
            self._stack.pop()
            inner = self._child.pop()
            if self._child:
                self._child[-1] += dt
            entry[0] += dt
            entry[1] += dt - inner
            entry[2] += 1

    def add(self, name: str, seconds: float, calls: int = 1) -> None:
        """Record ``seconds`` measured by the caller as phase ``name`` inside the phase now
        running (e.g. the device time of a loop's solver steps inside the loop's phase: the
        loop's own seconds are then the rest of it)."""
        if not self.on:
            return
        entry = self._paths.setdefault("/".join([*self._stack, name]), [0.0, 0.0, 0])
        entry[0] += seconds
        entry[1] += seconds
        entry[2] += calls
        if self._child:
            self._child[-1] += seconds

    def report(self) -> dict[str, dict]:
        """Per phase path, in the order the paths first began (a phase before those inside it):
        ``{"s", "self_s", "calls"}``."""
        return {p: {"s": s, "self_s": own, "calls": n} for p, (s, own, n) in self._paths.items()}


PHASES = Phases()


@contextmanager
def phase(name: str):
    """Mark the block as phase ``name`` (recorded only while ``PHASES`` is on)."""
    if not PHASES.on:
        yield
        return
    with PHASES.record(name):
        yield
