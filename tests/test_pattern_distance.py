"""Particles' places in their sewing pattern (sim.cloth.pattern_distance): panels, seam
vertices and the flat distance to the nearest seam."""

from __future__ import annotations

import numpy as np

from sim.cloth.pattern_distance import pattern_positions
from tests.test_cloth_solver import grid


def _two_panels(n: int = 6, e: float = 0.01):
    """Two n x n grids of spacing ``e`` sewn along one side: panel A's column n-1 is panel B's
    column 0 (shared vertices). Returns faces, flat corners (each panel in its own frame,
    B's x starting at 0), the sewn vertex count and each vertex's (panel, column)."""
    v, f = grid(n, n, (n - 1) * e, (n - 1) * e, plane="xz")
    col = np.arange(len(v)) % n
    row = np.arange(len(v)) // n
    # B's vertices: new ids for its columns 1.., its column 0 is A's column n-1
    b_id = np.where(col == 0, row * n + (n - 1), len(v) + row * (n - 1) + (col - 1))
    faces = np.concatenate([f, b_id[f]])
    flat_a = v[f][:, :, [0, 2]]
    corners = np.concatenate([flat_a, flat_a])  # B in its own frame: the same grid
    count = len(v) + n * (n - 1)
    return faces, corners, count, n, e


def test_seam_vertices_have_no_panel_and_the_others_their_flat_distance_to_the_seam():
    faces, corners, count, n, e = _two_panels()
    panel, flat = pattern_positions(count, faces, corners)
    seam = np.arange(n) * n + (n - 1)
    assert (panel[seam] == -1).all() and (panel >= 0).sum() == count - n
    a = np.setdiff1d(np.arange(n * n), seam)
    b = np.arange(n * n, count)
    assert len(set(panel[a])) == 1 and len(set(panel[b])) == 1 and panel[a][0] != panel[b][0]
    # A's column c is (n-1-c) columns from the seam, B's column c is c columns from it
    np.testing.assert_allclose(flat[a, 2], (n - 1 - a % n) * e, atol=1e-6)
    np.testing.assert_allclose(flat[b, 2], ((b - n * n) % (n - 1) + 1) * e, atol=1e-6)
    np.testing.assert_allclose(flat[seam, 2], 0.0)


def test_without_a_pattern_every_particle_keeps_the_rest_shapes_distance():
    faces, _, count, _, _ = _two_panels()
    panel, flat = pattern_positions(count, faces, None)
    assert (panel == -1).all() and (flat == 0).all()
