"""The pants crotch diagnostic (benchmarks/crotch_gap.py): which point it follows and how it measures."""

import numpy as np
import pytest

from benchmarks.crotch_gap import crotch_gap, crotch_point, main
from sim.garments.templates import midplane_crossings


def _plate(y: float, z0: float, z1: float):
    """A horizontal quad at height y across the mid-plane (x in [-0.1, 0.1], z in [z0, z1])."""
    v = np.array([[-0.1, y, z0], [0.1, y, z0], [0.1, y, z1], [-0.1, y, z1]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def _garment():
    """Rest vertices: two in the mid-plane (the lower is C), one lower but off the plane."""
    return np.array([[0.0, -0.10, 0.0], [0.0, -0.40, 0.03], [0.05, -0.60, 0.0], [0.0, -0.20, 0.1]])


def test_the_crotch_point_is_the_lowest_mid_plane_vertex():
    assert crotch_point(_garment()) == 1
    with pytest.raises(ValueError, match="mid-plane"):
        crotch_point(_garment()[[2]])


def test_mid_plane_crossings_lie_on_the_plane_at_the_edge_heights():
    v, f = _plate(0.3, -0.05, 0.05)
    p = midplane_crossings(v, f)
    assert len(p) > 0
    np.testing.assert_allclose(p[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(p[:, 1], 0.3)


def test_drop_is_measured_to_the_body_above_c_near_its_z():
    """The body's crotch plate sits at y = -0.37 over C's z; a second plate far behind in z and
    lower (y = -0.39) must be ignored. C falls from -0.40 (30 mm below) to -0.45 (80 mm below)."""
    a, fa = _plate(-0.37, 0.0, 0.06)
    b, fb = _plate(-0.39, 0.3, 0.4)
    body = np.concatenate([a, b])
    faces = np.concatenate([fa, fb + 4])
    rest = _garment()
    x = np.stack([rest, rest + [0.0, -0.05, 0.0]])
    r = crotch_gap(x, rest, np.stack([body, body]), faces)
    np.testing.assert_allclose(r["drop_mm"], [30.0, 80.0], atol=1e-6)
    assert r["crotch_vertex"] == 1 and r["first_frame_drop_mm"] == pytest.approx(30.0)
    assert r["max_drop_mm"] == pytest.approx(80.0)
    # nearest body vertex of frame 0: the plate's corner (+-0.1, -0.37, 0.0 or 0.06)
    assert r["nearest_body_mm"][0] == pytest.approx(1000 * np.sqrt(0.1**2 + 0.03**2 + 0.03**2), abs=0.1)


def test_bad_file_exits_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "run.npz"
    np.savez(bad, x=np.zeros((1, 3, 3)))
    assert main([str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(bad) in err


def _wall(x: float, y0: float, y1: float, z0: float, z1: float):
    """A vertical quad in the plane x = const (a thigh's inner face), y in [y0, y1], z in [z0, z1]."""
    v = np.array([[x, y0, z0], [x, y1, z0], [x, y1, z1], [x, y0, z1]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_thigh_gap_is_the_distance_between_the_nearest_faces_either_side():
    """Walls at x = -0.012 and x = +0.009, with farther ones (x = -0.05, +0.07) behind them on the
    same line: 21 mm. Off the walls' extent in y a side is missed: inf."""
    from benchmarks.crotch_gap import thigh_gap

    parts = [_wall(-0.012, -0.5, -0.3, -0.1, 0.1), _wall(0.009, -0.5, -0.3, -0.1, 0.1),
             _wall(-0.05, -0.5, -0.3, -0.1, 0.1), _wall(0.07, -0.6, -0.3, -0.1, 0.1)]
    v = np.concatenate([p[0] for p in parts])
    f = np.concatenate([p[1] + 4 * k for k, p in enumerate(parts)])
    assert thigh_gap(v, f, -0.4, 0.02) == pytest.approx(0.021, abs=1e-12)
    assert thigh_gap(v, f, -0.55, 0.0) == float("inf")  # only the x = +0.07 wall reaches y = -0.55


def test_room_between_the_thighs_is_reported_per_frame_below_the_crotch():
    """The crotch plate at y = -0.37 over walls 20 mm apart that move to 12 mm in frame 1 from 3 cm
    below it (y < -0.40): the gaps 1 / 3 / 5 / 8 cm below the crotch follow, and the least per depth."""
    plate, fp = _plate(-0.37, 0.0, 0.06)
    rest = _garment()
    frames = []
    for near in (0.010, 0.006):
        parts = [(plate, fp), _wall(-0.010, -0.395, -0.36, -0.1, 0.1), _wall(0.010, -0.395, -0.36, -0.1, 0.1),
                 _wall(-near, -0.6, -0.395, -0.1, 0.1), _wall(near, -0.6, -0.395, -0.1, 0.1)]
        frames.append(np.concatenate([p[0] for p in parts]))
    faces = np.concatenate([p[1] + 4 * k for k, p in enumerate(parts)])
    r = crotch_gap(np.stack([rest, rest]), rest, np.stack(frames), faces)
    np.testing.assert_allclose(r["thigh_gap_mm"], [[20, 20, 20, 20], [20, 12, 12, 12]], atol=1e-6)
    np.testing.assert_allclose(r["least_thigh_gap_mm"], [20, 12, 12, 12], atol=1e-6)
