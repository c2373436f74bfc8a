"""Progress bars for long work (tqdm on stderr; silent with --quiet or when not a TTY in CI)."""

from __future__ import annotations

import contextlib


@contextlib.contextmanager
def progress_bar(total: int, desc: str, *, quiet: bool = False, unit: str = "frame"):
    """Yield a callback ``progress(done, total)`` (the convention of every long function in
    wrinkles) that drives a tqdm bar."""
    if quiet:
        yield lambda done, total=None: None
        return
    from tqdm import tqdm

    # disable=None: no bar when stderr is not a terminal (CI logs, pipes)
    with tqdm(total=total, desc=desc, unit=unit, dynamic_ncols=True, leave=False, disable=None) as bar:

        def progress(done: int, total: int | None = None) -> None:
            if total and bar.total != total:  # callers that learn the total late (evaluate)
                bar.total = total
            bar.update(done - bar.n)

        yield progress


class LazyProgressBar:
    """A ``progress(done, total)`` callback that opens a ``progress_bar`` on its first call (for
    work whose total is known only once it starts); ``close()`` ends it."""

    def __init__(self, desc: str, quiet: bool):
        self.desc, self.quiet = desc, quiet
        self._cm = None
        self._cb = None

    def __call__(self, done: int, total: int) -> None:
        if self._cb is None:
            self._cm = progress_bar(total, self.desc, quiet=self.quiet, unit="step")
            self._cb = self._cm.__enter__()
        self._cb(done, total)

    def close(self) -> None:
        if self._cm is not None:
            self._cm.__exit__(None, None, None)
            self._cm = self._cb = None
