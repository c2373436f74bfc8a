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
