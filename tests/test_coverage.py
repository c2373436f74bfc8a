"""Skin through cloth on a hand-built case: a closed cylinder body in an open cylinder garment,
with known rings of body vertices under the garment, pushed through it, and uncovered."""

from __future__ import annotations

import numpy as np
import pytest

from sim.coverage import (
    EXPOSED,
    INSIDE,
    THROUGH,
    border_flags,
    covered_vertices,
    skin_sides,
    skin_through_fraction,
)
from sim.geometry.frames import vertex_normals

AROUND_BODY, AROUND_CLOTH = 16, 24
BODY_RINGS = np.round(np.arange(-0.45, 0.46, 0.1), 6)  # ten rings, none at a garment border
CLOTH_RINGS = np.round(np.arange(-0.3, 0.31, 0.05), 6)  # the garment spans y in [-0.3, 0.3]


def rings(radius: float, heights: np.ndarray, around: int) -> tuple[np.ndarray, np.ndarray]:
    """Rings of ``around`` vertices about the y axis, and the quads between them as triangles
    wound outward (away from the axis)."""
    a = 2 * np.pi * np.arange(around) / around
    v = np.array([[radius * np.cos(t), y, radius * np.sin(t)] for y in heights for t in a], np.float32)
    f = []
    for j in range(len(heights) - 1):
        for i in range(around):
            p, q = j * around + i, j * around + (i + 1) % around
            f += [[p, q + around, q], [p, p + around, q + around]]
    return v, np.array(f, np.int32)


def body_cylinder(radius: float = 0.10) -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder: ``BODY_RINGS`` and a fan cap at each end (y = -0.5 and 0.5)."""
    v, f = rings(radius, BODY_RINGS, AROUND_BODY)
    n = len(v)
    v = np.vstack([v, [[0, -0.5, 0], [0, 0.5, 0]]]).astype(np.float32)
    top = n - AROUND_BODY
    caps = [[n, i, (i + 1) % AROUND_BODY] for i in range(AROUND_BODY)]
    caps += [[n + 1, top + (i + 1) % AROUND_BODY, top + i] for i in range(AROUND_BODY)]
    return v, np.vstack([f, caps]).astype(np.int32)


def test_rings_are_wound_outward():
    v, f = body_cylinder()
    n = vertex_normals(v, f, device="cpu")
    side = np.abs(v[:, 1]) < 0.4
    radial = v[side] * np.array([1, 0, 1], np.float32)
    np.testing.assert_allclose(n[side], radial / np.linalg.norm(radial, axis=1, keepdims=True), atol=1e-5)
    np.testing.assert_allclose(n[-2:], [[0, -1, 0], [0, 1, 0]], atol=1e-5)


def test_border_flags_mark_open_edges_and_their_corners():
    np.testing.assert_array_equal(border_flags(np.array([[0, 1, 2]]), 3), [63])
    # a quad: the diagonal (0, 2) is inside, opposite corner 1 of the first face and corner 2 of the
    # second; every vertex is on the border
    np.testing.assert_array_equal(border_flags(np.array([[0, 1, 2], [0, 2, 3]]), 4), [61, 59])
    _, f = rings(0.12, CLOTH_RINGS, AROUND_CLOTH)
    flags = border_flags(f, len(CLOTH_RINGS) * AROUND_CLOTH)
    last = len(f) - 2 * AROUND_CLOTH  # faces of the top band
    assert np.all(flags[2 * AROUND_CLOTH:last] == 0)  # no border away from the two end bands
    assert np.all(flags[:2 * AROUND_CLOTH] != 0) and np.all(flags[last:] != 0)


def test_covered_vertices_are_the_rings_inside_the_tube(device):
    body, bf = body_cylinder()
    cloth, cf = rings(0.12, CLOTH_RINGS, AROUND_CLOTH)
    covered = covered_vertices(body, bf, cloth, cf, device=device)
    expected = np.abs(body[:, 1]) < 0.3
    expected[-2:] = False  # the caps' centres
    np.testing.assert_array_equal(covered, expected)
    assert covered.sum() == 6 * AROUND_BODY
    # a longer reach: the rings at |y| = 0.35, 5.4 cm from the border, stay out (their closest garment
    # point is on the border, their rays pass the tube's end)
    np.testing.assert_array_equal(covered_vertices(body, bf, cloth, cf, reach=0.1, device=device), expected)
    # normals turned inward: the rays cross 22 cm of air to the far side of the tube, beyond reach
    assert not covered_vertices(body, bf[:, ::-1], cloth, cf, device=device).any()


def test_skin_through_counts_the_pushed_ring_and_not_the_uncovered_ones(device):
    body, bf = body_cylinder()
    cloth, cf = rings(0.12, CLOTH_RINGS, AROUND_CLOTH)
    covered = covered_vertices(body, bf, cloth, cf, device=device)
    ring = np.abs(body[:, 1] - 0.05) < 1e-6
    bodies = np.stack([body] * 4)
    bodies[1, ring] *= np.array([1.4, 1.0, 1.4], np.float32)  # radius 0.14: out through the cloth
    cloths = np.stack([cloth] * 4)
    cloths[2, :, 1] += 0.2  # the tube rides up to y in [-0.1, 0.5]: the rings below are uncovered
    cloths[3, :, 0] += 5.0  # the garment is gone
    sides = skin_sides(bodies, cloths, cf, covered, device=device)
    side = sides.side
    assert side.shape == (4, 96)
    low = body[covered, 1] < -0.1
    assert np.all(side[0] == INSIDE)
    np.testing.assert_array_equal(side[1] == THROUGH, ring[covered])
    np.testing.assert_array_equal(side[2], np.where(low, EXPOSED, INSIDE))
    assert np.all(side[3] == EXPOSED)
    # radius 10 cm in a tube of 24 chords of radius 12 cm: 2 cm from a tube vertex, 12 cos(7.5 deg) - 10
    # cm from a chord's middle; the pushed ring at radius 14 cm is outside by as much
    gap = 0.12 * np.cos(np.pi / 24) - 0.10
    np.testing.assert_array_less(sides.distance[0], -gap + 1e-6)
    np.testing.assert_array_less(-0.02 - 1e-6, sides.distance[0])
    pushed = sides.distance[1][ring[covered]]
    np.testing.assert_array_less(0.14 - 0.12 - 1e-6, pushed)
    np.testing.assert_array_less(pushed, 0.14 - 0.12 * np.cos(np.pi / 24) + 1e-6)
    assert np.all(np.isnan(sides.distance[3]))
    np.testing.assert_allclose(sides.fraction(EXPOSED), [0, 0, 32 / 96, 1])
    np.testing.assert_allclose(sides.deeper_than(0.0215), [0, 0, 0, 0])
    np.testing.assert_allclose(sides.deeper_than(0.0199), [0, 16 / 96, 0, 0])
    np.testing.assert_allclose(skin_through_fraction(bodies, cloths, cf, covered, device=device),
                               [0.0, 16 / 96, 0.0, 0.0])
    # a static garment and moving body, and the other way round
    moving_body = skin_through_fraction(bodies[:2], cloth, cf, covered, device=device)
    np.testing.assert_allclose(moving_body, [0, 1 / 6])
    np.testing.assert_allclose(skin_through_fraction(body, cloths[:2], cf, covered, device=device), [0, 0])


def test_skin_through_refuses_mismatched_shapes():
    body, bf = body_cylinder()
    cloth, cf = rings(0.12, CLOTH_RINGS, AROUND_CLOTH)
    with pytest.raises(ValueError, match="covered"):
        skin_sides(body, cloth, cf, np.ones(5, bool), device="cpu")
    with pytest.raises(ValueError, match="garment_vertices"):
        skin_sides(np.stack([body] * 3), np.stack([cloth] * 2), cf, np.ones(len(body), bool), device="cpu")
    assert skin_through_fraction(np.stack([body] * 2), cloth, cf, np.zeros(len(body), bool),
                                 device="cpu").tolist() == [0.0, 0.0]
