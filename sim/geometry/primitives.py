"""Closed meshes of simple solids, for colliders in scenes and tests."""

from __future__ import annotations

import numpy as np


def uv_sphere(radius: float, n_lat: int = 16, n_lon: int = 24,
              center=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A closed sphere of ``n_lat`` latitude bands and ``n_lon`` meridians around ``center``, its
    faces counter-clockwise seen from outside (positive signed volume): (V, 3) float32 vertices
    (the poles first and last), (F, 3) int32 faces."""
    v = [(0.0, radius, 0.0)]
    for i in range(1, n_lat):
        th = np.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * np.pi * j / n_lon
            s = radius * np.sin(th)
            v.append((s * np.cos(ph), radius * np.cos(th), s * np.sin(ph)))
    v.append((0.0, -radius, 0.0))
    bottom = len(v) - 1
    f = [(0, 1 + (j + 1) % n_lon, 1 + j) for j in range(n_lon)]
    for i in range(n_lat - 2):
        r0, r1 = 1 + i * n_lon, 1 + (i + 1) * n_lon
        for j in range(n_lon):
            j1 = (j + 1) % n_lon
            f += [(r0 + j, r0 + j1, r1 + j), (r0 + j1, r1 + j1, r1 + j)]
    r = 1 + (n_lat - 2) * n_lon
    f += [(bottom, r + j, r + (j + 1) % n_lon) for j in range(n_lon)]
    return (np.asarray(v, np.float32) + np.asarray(center, np.float32)), np.asarray(f, np.int32)
