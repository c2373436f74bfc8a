"""Device selection for Warp kernels.

Every kernel runs on ``cpu`` and ``cuda`` (ARCHITECTURE.md). ``None`` or ``"auto"``
picks ``cuda`` when a CUDA device is present, else ``cpu``.
"""

from __future__ import annotations

import functools

from sim.errors import WrinklesInputError


@functools.cache
def _warp():
    import logging
    import os
    import sys

    import warp as wp

    wp.config.log_level = logging.ERROR
    # Warp's native code prints a driver warning on CPU-only machines straight to fd 2;
    # silence that one call at the file-descriptor level to keep CLI output clean.
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            wp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    return wp


def warp():
    """The initialised ``warp`` module (imported lazily, quiet)."""
    return _warp()


def resolve_device(device: str | None = None) -> str:
    """Resolve a device name to a Warp device string.

    Args:
        device: ``None``/``"auto"`` (cuda when present, else cpu), ``"cpu"``, ``"cuda"`` or
            ``"cuda:N"``.

    Returns:
        The Warp device alias.
    """
    wp = warp()
    if device in (None, "", "auto"):
        return "cuda" if wp.get_cuda_device_count() > 0 else "cpu"
    if device == "cpu":
        return "cpu"
    if device.startswith("cuda"):
        if wp.get_cuda_device_count() == 0:
            raise WrinklesInputError(f"--device {device}: no CUDA device is available here (use cpu)")
        return device
    raise WrinklesInputError(f"--device {device}: unknown device (use auto, cpu, cuda or cuda:N)")


def device_name(device: str | None = None) -> str:
    """The full name of the Warp device ``device`` resolves to ("cuda:N" for "cuda" or "auto" on a
    GPU machine, "cpu"), as torch names it too."""
    return str(warp().get_device(resolve_device(device)))


class SideStreams:
    """CUDA streams that fork from the device's current stream and join back into it, so
    independent latency-bound kernels of a step run side by side (in a CUDA graph captured on
    the current stream too: the forks and joins are its edges). On the CPU everything runs in
    order on the one stream.

    ``with side.on(k):`` runs the block's launches on side stream ``k``, after everything issued
    so far on the current stream; ``side.join()`` makes the current stream wait for those used
    since the last join (waiting on an unused one would, in a graph capture, depend on work
    outside the capture: CUDA error 905).

    Args:
        device: Warp device.
        count: side streams.
    """

    def __init__(self, device: str, count: int):
        wp = warp()
        self.device = device
        self.cuda = wp.get_device(device).is_cuda
        self.streams = [wp.Stream(device) for _ in range(count)] if self.cuda else []
        self._used: set[int] = set()

    def on(self, k: int):
        import contextlib

        if not self.cuda:
            return contextlib.nullcontext()
        self._used.add(k)
        return warp().ScopedStream(self.streams[k], sync_enter=True)

    def wait_here(self) -> None:
        """The current stream waits for the side streams used since the last join, which stay
        to be joined (another side stream's block that reads what they write)."""
        if self.cuda:
            current = warp().get_stream(self.device)
            for k in sorted(self._used):
                current.wait_stream(self.streams[k])

    def join(self) -> None:
        if self.cuda:
            main = warp().get_stream(self.device)
            for k in sorted(self._used):
                main.wait_stream(self.streams[k])
        self._used.clear()
