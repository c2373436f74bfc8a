"""In-process caches (``sim.memo``): keys by content, dtype and shape; the entries used last kept."""

from __future__ import annotations

import numpy as np

from sim.memo import LRU, content_key, read_only


def test_content_keys_tell_dtype_shape_and_none_apart():
    a = np.arange(6, dtype=np.int32)
    assert content_key(a) == content_key(a.copy())
    assert len({content_key(a), content_key(a.astype(np.int64)), content_key(a.reshape(2, 3)),
                content_key(a, None), content_key(a, 1.0)}) == 5


def test_lru_keeps_the_entries_used_last():
    cache, made = LRU(2), []

    def make(k):
        made.append(k)
        return k * 10

    assert [cache.get_or_make(k, lambda k=k: make(k)) for k in (1, 2, 1, 3, 1, 2)] == [10, 20, 10, 30, 10, 20]
    assert made == [1, 2, 3, 2]  # 1 was used again before 3 came, so 2 went
    assert list(cache) == [1, 2]
    assert not read_only(np.zeros(3)).flags.writeable
