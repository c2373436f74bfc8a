"""In-process caches of what is made from a mesh's arrays: ``content_key`` names the content,
``LRU`` keeps the values made last (a batch of sequences of one garment asks for the same
mesh's data again and again)."""

from __future__ import annotations

import collections
import hashlib
from collections.abc import Callable
from typing import Any

import numpy as np


def content_key(*parts: Any) -> str:
    """A digest of ``parts``: arrays by dtype, shape and bytes, None as itself, anything else
    by its ``repr``."""
    h = hashlib.sha1()
    for p in parts:
        if p is None:
            h.update(b"-")
        elif isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"{a.dtype.str}{a.shape}".encode() + a.tobytes())
        else:
            h.update(repr(p).encode())
    return h.hexdigest()


def read_only(a: np.ndarray) -> np.ndarray:
    """``a``, marked read-only (a cached array that every caller shares)."""
    a.setflags(write=False)
    return a


class LRU(collections.OrderedDict):
    """A dict that keeps its ``size`` entries used last (the oldest first in iteration order)."""

    def __init__(self, size: int):
        super().__init__()
        self.size = int(size)

    def get_or_make(self, key: Any, make: Callable[[], Any]) -> Any:
        """The value of ``key``, made by ``make()`` and kept when missing; marked used last."""
        if key in self:
            self.move_to_end(key)
        else:
            self.put(key, make())
        return self[key]

    def put(self, key: Any, value: Any) -> None:
        """Keep ``value`` under ``key`` as the entry used last, dropping the oldest beyond ``size``."""
        self[key] = value
        self.move_to_end(key)
        while len(self) > self.size:
            self.popitem(last=False)
