"""Progress bars for long work (tqdm on stderr; silent with --quiet or when not a TTY in CI)."""

from __future__ import annotations

import contextlib


@contextlib.contextmanager
def progress_bar(total: int, desc: str, *, quiet: bool = False, unit: str = "frame"):
    """Yield a callable ``advance(n)`` that moves a tqdm bar by ``n``."""
    if quiet:
        yield lambda n=1: None
        return
    from tqdm import tqdm

    with tqdm(total=total, desc=desc, unit=unit, dynamic_ncols=True, leave=False) as bar:
        yield lambda n=1: bar.update(n)
