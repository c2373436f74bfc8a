"""Sewing-pattern types: curve geometry, placements, validation (sim.garments.pattern)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.garments.pattern import Edge, Panel, Pattern, Placement, Seam, arc_geometry

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def square(name: str = "p", edges=None, placement=None) -> Panel:
    edges = edges or (Edge(label="bottom"), Edge(label="right"), Edge(label="top"), Edge(label="left"))
    return Panel(name, SQUARE * 0.5, edges, placement or Placement((0.0, 0.0, 0.0)))


@pytest.mark.parametrize("right", [0, 1])
@pytest.mark.parametrize("large", [0, 1])
def test_arc_passes_through_both_ends_at_its_radius_on_the_side_it_bulges(right, large):
    p0, p1 = np.array([0.2, 0.1]), np.array([0.5, 0.5])
    e = Edge("arc", ((0.4, large, right),))
    pts = e.points(p0, p1, np.linspace(0.0, 1.0, 101))
    centre, _, sweep, r = arc_geometry(p0, p1, 0.4, large, right)
    np.testing.assert_allclose(pts[[0, -1]], [p0, p1], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(pts - centre, axis=1), 0.4, atol=1e-12)
    assert (abs(sweep) > np.pi) == bool(large)
    d = p1 - p0
    mid = pts[50] - p0
    side = d[0] * mid[1] - d[1] * mid[0]  # > 0: left of p0 -> p1
    assert (side < 0) == bool(right)


def test_half_circle_arc_length_and_quadratic_bezier_midpoint():
    p = square(edges=(Edge("arc", ((0.25, 0, 1),)), Edge(), Edge("quadratic", ((0.25, 0.9),)), Edge()))
    assert p.edge_length(0) == pytest.approx(np.pi * 0.25, rel=1e-4)
    # a quadratic Bezier's point at t = 1/2 is (p0 + 2c + p1) / 4
    top = Edge("quadratic", ((0.25, 0.9),))
    mid = top.points(np.array([0.5, 0.5]), np.array([0.0, 0.5]), np.array([0.5]))
    np.testing.assert_allclose(mid[0], [0.25, 0.7], atol=1e-12)
    # the arc bulges out below the square, the parabola (height 0.2) above it
    assert p.area() == pytest.approx(0.25 + 0.5 * np.pi * 0.25 ** 2 + (2 / 3) * 0.5 * 0.2, rel=2e-3)


def test_edge_curve_samples_equal_arc_lengths_with_exact_ends():
    p = square(edges=(Edge("cubic", ((0.1, -0.2), (0.4, 0.3))), Edge(), Edge(), Edge()))
    pts = p.edge_curve(0, 12)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    # equal arcs; their chords differ by the curvature under them (~1 % at this bend)
    np.testing.assert_allclose(seg, seg.mean(), rtol=2e-2)
    assert seg.sum() == pytest.approx(p.edge_length(0), rel=1e-2)
    np.testing.assert_array_equal(pts[[0, -1]], p.corners[[0, 1]])


def test_cylinder_placement_is_an_isometry_and_faces_outward():
    r = 0.2
    pl = Placement(anchor=(0.0, 1.0, r), curvature=1.0 / r, origin=(0.0, 0.0))
    xy = np.stack([np.linspace(-0.3, 0.3, 61), np.zeros(61)], axis=1)
    x = pl.place(xy)
    # every point on the cylinder of radius r around the y axis, arc length = panel distance
    np.testing.assert_allclose(np.hypot(x[:, 0], x[:, 2]), r, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.diff(x, axis=0), axis=1).sum(),
                               0.6 * np.sinc(0.005 / r / np.pi) * 1.0, rtol=1e-4)
    np.testing.assert_allclose(pl.place(np.array([[0.0, 0.3]])), [[0.0, 1.3, r]], atol=1e-12)
    flat = Placement(anchor=(1.0, 2.0, 3.0), u_dir=(-1.0, 0.0, 0.0), origin=(0.1, 0.0))
    np.testing.assert_allclose(flat.place(np.array([[0.3, 0.5]])), [[0.8, 2.5, 3.0]], atol=1e-12)


def test_pattern_validates_seams_and_winding():
    a, b = square("a"), square("b")
    Pattern("ok", (a, b), (Seam(("a", 1), ("b", 3)),))
    with pytest.raises(ValueError, match="missing edge"):
        Pattern("bad", (a, b), (Seam(("a", 1), ("c", 3)),))
    with pytest.raises(ValueError, match="two seams"):
        Pattern("bad", (a, b), (Seam(("a", 1), ("b", 3)), Seam(("a", 1), ("b", 2))))
    with pytest.raises(ValueError, match="dart"):
        Pattern("bad", (a, b), (Seam(("a", 1), ("b", 3), dart=True),))
    cw = Panel("cw", SQUARE[::-1] * 0.5, (Edge(),) * 4)
    with pytest.raises(ValueError, match="counter-clockwise"):
        Pattern("bad", (cw,), ())
    with pytest.raises(ValueError, match="repeat"):
        Pattern("bad", (a, square("a")), ())
    p = Pattern("ok", (a, b), (Seam(("a", 1), ("b", 3)),))
    assert p.free_edges() == [("a", 0), ("a", 2), ("a", 3), ("b", 0), ("b", 1), ("b", 2)]
    assert p.labelled("top") == [("a", 2), ("b", 2)]


def test_hood_halves_meet_at_the_centre_back_without_wrapping_past_it():
    """The back seam of each hood half is placed on the head's mid-plane at every height, and
    neither half reaches past that plane below its crown (where the halves would cross when
    sewn)."""
    from sim.garments.drafting.hood import hood_panels
    from sim.garments.pattern_mesh import mesh_pattern

    cx = 0.01
    panels, seams = hood_panels(0.11, 0.09, 0.045, np.array([cx, 0.0]), 1.5, 1.75, 0.1)
    mesh = mesh_pattern(Pattern("hood", tuple(panels), tuple(seams)), 0.01)
    for ref in (("hood_l", 2), ("hood_r", 2)):
        pts = mesh.placed[mesh.edge_vertices[ref]]
        np.testing.assert_allclose(pts[:, 0], cx, atol=2e-3)
    crown_start = panels[0].corners[3][1] + 1.5
    for k, sign in ((0, 1.0), (1, -1.0)):  # hood_l on +x, hood_r on -x
        x = mesh.placed[(mesh.vertex_panel == k) & (mesh.placed[:, 1] < crown_start - 0.01), 0]
        assert np.all(sign * (x - cx) > -2e-3)
