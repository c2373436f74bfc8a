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
