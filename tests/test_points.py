"""Per-coordinate reductions (``sim.geometry.points``): the same numbers as numpy's multi-axis
reductions: bounds bit for bit, centroids bit for bit on float32 frames (the bodies') and to
round-off on float64 ones (the summation order differs)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.geometry.points import coordinate_bounds, frame_centroids


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_bounds_and_centroids_equal_numpys_reductions(dtype):
    rng = np.random.default_rng(3)
    frames = (rng.normal(size=(7, 501, 3)) * [1.0, 20.0, 0.01] + [5.0, -2.0, 0.3]).astype(dtype)
    lo, hi = coordinate_bounds(frames)
    np.testing.assert_array_equal(lo, frames.min(axis=(0, 1)).astype(np.float64))
    np.testing.assert_array_equal(hi, frames.max(axis=(0, 1)).astype(np.float64))
    assert lo.dtype == hi.dtype == np.float64
    c = frame_centroids(frames)
    if dtype == np.float32:
        np.testing.assert_array_equal(c, frames.mean(axis=1, dtype=np.float64))
    else:
        np.testing.assert_allclose(c, frames.mean(axis=1), rtol=1e-14, atol=1e-14)
    assert c.shape == (7, 3)


def test_bounds_of_a_single_point_set_and_bad_shapes():
    lo, hi = coordinate_bounds(np.array([[0.0, 1.0], [2.0, -1.0]]))
    np.testing.assert_array_equal(lo, [0.0, -1.0])
    np.testing.assert_array_equal(hi, [2.0, 1.0])
    with pytest.raises(ValueError, match="empty"):
        coordinate_bounds(np.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"\(T, V, D\)"):
        frame_centroids(np.zeros((4, 3)))
