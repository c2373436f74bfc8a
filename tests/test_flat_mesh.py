"""The flat panel mesher: boundary kept, conforming manifold disk, near-equilateral triangles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from sim.garments.flat_mesh import (
    FlatMesh,
    lattice_points,
    mesh_polygon,
    missing_segments,
    polygon_area,
)

H = 0.01  # target edge length of the shape tests [m]


def _sampled(a, b, step: float) -> np.ndarray:
    """Points from ``a`` towards ``b`` (``b`` excluded) at about ``step`` [m] apart."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(1, int(round(np.hypot(*(b - a)) / step)))
    return a + np.linspace(0.0, 1.0, n + 1)[:-1, None] * (b - a)


def _polyline(corners, steps=None) -> np.ndarray:
    """Closed outline through ``corners`` with segment ``i`` sampled at ``steps[i]`` [m]."""
    steps = steps or [H] * len(corners)
    return np.concatenate([_sampled(corners[i], corners[(i + 1) % len(corners)], steps[i])
                           for i in range(len(corners))])


def _curve(dense: np.ndarray, step: float) -> np.ndarray:
    """The polyline ``dense`` resampled at equal arc length about ``step`` apart, end excluded."""
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(dense, axis=0).T))]
    t = np.linspace(0.0, s[-1], max(1, int(round(s[-1] / step))) + 1)[:-1]
    return np.stack([np.interp(t, s, dense[:, 0]), np.interp(t, s, dense[:, 1])], axis=1)


def _bezier(a, c, b) -> np.ndarray:
    t = np.linspace(0.0, 1.0, 400)[:, None]
    return (1 - t) ** 2 * np.asarray(a) + 2 * t * (1 - t) * np.asarray(c) + t ** 2 * np.asarray(b)


def rectangle() -> np.ndarray:
    return _polyline([(0, 0), (0.4, 0), (0.4, 0.3), (0, 0.3)])


def tshirt_body() -> np.ndarray:
    """Front body panel: hem, side seams, concave armhole curves, shoulders and a neck scoop."""
    pieces = [_sampled((0, 0), (0.5, 0), H), _sampled((0.5, 0), (0.5, 0.45), H),
              _curve(_bezier((0.5, 0.45), (0.42, 0.48), (0.42, 0.62)), H),
              _sampled((0.42, 0.62), (0.33, 0.66), H),
              _curve(_bezier((0.33, 0.66), (0.25, 0.52), (0.17, 0.66)), H),
              _sampled((0.17, 0.66), (0.08, 0.62), H),
              _curve(_bezier((0.08, 0.62), (0.08, 0.48), (0, 0.45)), H),
              _sampled((0, 0.45), (0, 0), H)]
    return np.concatenate(pieces)


def l_shape() -> np.ndarray:
    return _polyline([(0, 0), (0.4, 0), (0.4, 0.15), (0.15, 0.15), (0.15, 0.5), (0, 0.5)])


def v_notch(degrees: float = 30.0, steps=(1.0, 1.0)) -> np.ndarray:
    """Square with a dart's V notch of ``degrees`` cut 0.2 m deep from the top; the notch's
    sides sampled at ``steps`` times ``H``."""
    half = np.tan(np.radians(degrees / 2)) * 0.2
    corners = [(0, 0), (0.4, 0), (0.4, 0.4), (0.2 + half, 0.4), (0.2, 0.2), (0.2 - half, 0.4), (0, 0.4)]
    return _polyline(corners, [H, H, H, steps[0] * H, steps[1] * H, H, H])


def gore(degrees: float = 30.0) -> np.ndarray:
    """Skirt gore: 0.3 m wide at the hem, sides meeting at a convex point of ``degrees``."""
    top = 0.15 / np.tan(np.radians(degrees / 2))
    return _polyline([(-0.15, 0), (0.15, 0), (0, top)])


def uneven_rectangle() -> np.ndarray:
    """0.3 m x 0.25 m: bottom at 0.5 h, right side at 1.5 h, top alternating 0.5 h / 1.5 h."""
    bottom = _sampled((0, 0), (0.3, 0), 0.5 * H)
    right = _sampled((0.3, 0), (0.3, 0.25), 1.5 * H)
    x = 0.3 - np.cumsum(np.r_[0.0, np.tile([0.5 * H, 1.5 * H], 14), H])  # ends 0.01 m from x = 0
    top = np.stack([x, np.full(len(x), 0.25)], axis=1)
    left = _sampled((0, 0.25), (0, 0), H)
    return np.concatenate([bottom, right, top, left])


SHAPES = {"rectangle": rectangle, "tshirt_body": tshirt_body, "l_shape": l_shape,
          "v_notch_30": v_notch, "gore_30": gore, "v_notch_20_uneven": lambda: v_notch(20.0, (0.5, 1.5)),
          "uneven_rectangle": uneven_rectangle}


@pytest.fixture(scope="module")
def meshes() -> dict[str, tuple[np.ndarray, FlatMesh]]:
    return {name: (make(), mesh_polygon(make(), H)) for name, make in SHAPES.items()}


def _angles(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Inner angles [deg] of each triangle, (T, 3)."""
    out = []
    for k in range(3):
        p, q, r = (points[tris[:, (k + i) % 3]] for i in range(3))
        u, v = q - p, r - p
        out.append(np.degrees(np.arctan2(np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]),
                                         np.sum(u * v, axis=1))))
    return np.stack(out, axis=1)


def _inside(points: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test of ``points`` (K, 2) against the closed ``loop`` (N, 2)."""
    a, b = loop, np.roll(loop, -1, axis=0)
    y = points[:, 1:2]
    crosses = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        x = a[None, :, 0] + (y - a[None, :, 1]) * slope[None]
    return np.sum(crosses & (points[:, 0:1] < x), axis=1) % 2 == 1


def _edges(tris: np.ndarray) -> np.ndarray:
    """Directed edges (3T, 2) of counter-clockwise triangles."""
    return np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])


@pytest.mark.parametrize("name", SHAPES)
def test_boundary_points_kept_bit_for_bit_and_in_order(meshes, name):
    boundary, mesh = meshes[name]
    assert mesh.points.dtype == np.float64 and mesh.triangles.dtype == np.int32
    np.testing.assert_array_equal(mesh.points[:len(boundary)], boundary)
    assert len(mesh.points) > len(boundary)


@pytest.mark.parametrize("name", SHAPES)
def test_every_boundary_segment_is_one_triangles_edge(meshes, name):
    boundary, mesh = meshes[name]
    n, m = len(boundary), len(mesh.points)
    directed = _edges(mesh.triangles.astype(np.int64))
    key = np.minimum(directed[:, 0], directed[:, 1]) * m + np.maximum(directed[:, 0], directed[:, 1])
    keys, count = np.unique(key, return_counts=True)
    a = np.arange(n)
    segment_keys = np.minimum(a, (a + 1) % n) * m + np.maximum(a, (a + 1) % n)
    # each segment once, counter-clockwise (the inside on its left); every other edge twice
    np.testing.assert_array_equal(count[np.searchsorted(keys, segment_keys)], np.ones(n))
    np.testing.assert_array_equal(np.isin(a * m + (a + 1) % n, directed[:, 0] * m + directed[:, 1]),
                                  np.ones(n, bool))
    assert np.all(count[~np.isin(keys, segment_keys)] == 2)


@pytest.mark.parametrize("name", SHAPES)
def test_manifold_disk(meshes, name):
    _, mesh = meshes[name]
    tris = mesh.triangles.astype(np.int64)
    directed = _edges(tris)
    m = len(mesh.points)
    # no directed edge twice: neighbouring triangles agree in orientation
    assert len(np.unique(directed[:, 0] * m + directed[:, 1])) == len(directed)
    undirected = np.unique(np.sort(directed, axis=1), axis=0)
    assert m - len(undirected) + len(tris) == 1  # Euler characteristic of a disk
    np.testing.assert_array_equal(np.unique(tris), np.arange(m))  # every point used


@pytest.mark.parametrize("name", SHAPES)
def test_triangles_counter_clockwise_inside_and_covering(meshes, name):
    boundary, mesh = meshes[name]
    p, t = mesh.points, mesh.triangles
    u, v = p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]]
    area = 0.5 * (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    assert area.min() > 0
    assert np.all(_inside(p[t].mean(axis=1), boundary))
    np.testing.assert_allclose(area.sum(), polygon_area(boundary), rtol=1e-9)


@pytest.mark.parametrize("name", SHAPES)
def test_near_equilateral_triangles_of_edge_h(meshes, name):
    boundary, mesh = meshes[name]
    angles = _angles(mesh.points, mesh.triangles)
    interior = np.all(mesh.triangles >= len(boundary), axis=1)
    assert interior.sum() > 0.5 * len(mesh.triangles)
    assert angles[interior].min() >= 25.0
    # all angles of these outlines (corners >= 20 degrees, segments 0.5 h to 1.5 h): measured
    # minimum 18.8 degrees, at a right-angle corner joining a 0.5 h and a 1.5 h segment
    assert angles.min() >= 15.0
    edges = np.unique(np.sort(_edges(mesh.triangles), axis=1), axis=0)
    length = np.hypot(*(mesh.points[edges[:, 0]] - mesh.points[edges[:, 1]]).T)
    np.testing.assert_allclose(length.mean(), H, rtol=0.10)
    hexagonal = polygon_area(boundary) / (np.sqrt(3.0) / 2.0 * H * H)
    np.testing.assert_allclose(len(mesh.points), hexagonal, rtol=0.15)


def test_large_panel_is_uniform():
    """A 0.6 m x 0.8 m panel at h = 2 cm: the bulk is a hexagonal lattice of edge h."""
    h = 0.02
    boundary = _polyline([(0, 0), (0.6, 0), (0.6, 0.8), (0, 0.8)], [h] * 4)
    mesh = mesh_polygon(boundary, h)
    angles = _angles(mesh.points, mesh.triangles)
    interior = np.all(mesh.triangles >= len(boundary), axis=1)
    np.testing.assert_allclose(np.median(angles[interior].min(axis=1)), 60.0, atol=1.0)
    assert np.percentile(angles.min(axis=1), 1) > 35.0
    np.testing.assert_allclose(len(mesh.points), 0.48 / (np.sqrt(3.0) / 2.0 * h * h), rtol=0.05)


def test_segments_missing_from_delaunay_are_recovered():
    """A 20-degree dart notch whose sides are sampled at 0.5 h and 1.5 h: Delaunay of the
    boundary and lattice points lacks boundary segments, the mesh has every one of them."""
    boundary = v_notch(20.0, (0.5, 1.5))
    n = len(boundary)
    seeds = np.concatenate([boundary, lattice_points(boundary, H)])
    assert len(missing_segments(Delaunay(seeds).simplices, n)) > 0
    mesh = mesh_polygon(boundary, H)
    assert len(missing_segments(mesh.triangles, n)) == 0


def test_deterministic():
    a, b = mesh_polygon(tshirt_body(), H), mesh_polygon(tshirt_body(), H)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.triangles, b.triangles)


def test_outlines_without_interior_points():
    """A strip narrower than h and a single triangle mesh with their boundary points only."""
    strip = _polyline([(0, 0), (0.3, 0), (0.3, 0.008), (0, 0.008)])
    mesh = mesh_polygon(strip, H)
    assert len(mesh.points) == len(strip) and len(mesh.triangles) == len(strip) - 2
    tri = np.array([[0.0, 0.0], [0.01, 0.0], [0.0, 0.01]])
    (t,) = mesh_polygon(tri, H).triangles
    np.testing.assert_array_equal(np.roll(t, -int(np.argmin(t))), [0, 1, 2])  # counter-clockwise


def test_long_boundary_segments_still_conform():
    """Four corners only, h far below the side lengths: triangles stretch along the sides."""
    boundary = np.array([[0.0, 0.0], [0.2, 0.0], [0.2, 0.1], [0.0, 0.1]])
    mesh = mesh_polygon(boundary, H)
    assert len(missing_segments(mesh.triangles, 4)) == 0
    u = mesh.points[mesh.triangles[:, 1]] - mesh.points[mesh.triangles[:, 0]]
    v = mesh.points[mesh.triangles[:, 2]] - mesh.points[mesh.triangles[:, 0]]
    np.testing.assert_allclose(0.5 * np.sum(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]), 0.02, rtol=1e-9)


def test_polygon_area():
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 3.0], [0.0, 3.0]])
    np.testing.assert_allclose(polygon_area(square), 6.0)
    np.testing.assert_allclose(polygon_area(square[::-1]), -6.0)
    np.testing.assert_allclose(polygon_area(l_shape()), 0.4 * 0.15 + 0.15 * 0.35, rtol=1e-12)


@pytest.mark.parametrize("boundary, h, message", [
    (rectangle()[::-1], H, "clockwise"),
    (np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]), H, "crosses or touches itself"),
    (np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [1.0, 0.0], [0.0, 2.0]]), H, "crosses or touches"),
    (np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), H, "repeats point"),
    (np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]), H, "crosses or touches"),
    (np.array([[0.0, 0.0], [1.0, 0.0]]), H, "N >= 3"),
    (rectangle(), 0.0, "positive"),
])
def test_bad_outlines_raise(boundary, h, message):
    with pytest.raises(ValueError, match=message):
        mesh_polygon(boundary, h)
