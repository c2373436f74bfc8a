"""The neckline diagnostic (benchmarks/neckline_stretch.py): which loop it takes and how it measures."""

import numpy as np

from benchmarks.neckline_stretch import neckline_loop, polyline_strain, stretch_report


def _tube(n_around: int, rows: int, radius: float, height: float):
    """An open cylinder around the y axis from y = 0 to ``height``: two boundary loops."""
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    ys = np.linspace(0.0, height, rows)
    v = np.array([[radius * np.sin(t), y, radius * np.cos(t)] for y in ys for t in a])
    f = []
    for r in range(rows - 1):
        for k in range(n_around):
            i, j = r * n_around + k, r * n_around + (k + 1) % n_around
            f += [[i, j, i + n_around], [j, j + n_around, i + n_around]]
    return v, np.array(f)


def test_the_neckline_is_the_top_boundary_loop_in_order():
    v, f = _tube(24, 5, 0.1, 0.2)
    loop = neckline_loop(v, f)
    assert sorted(loop.tolist()) == list(range(4 * 24, 5 * 24))  # the top row, each vertex once
    # in order around it: each step joins two vertices of one triangle
    edges = {tuple(sorted(e)) for t in f for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    assert all(tuple(sorted((a, b))) in edges for a, b in zip(loop, np.roll(loop, -1), strict=True))


def test_polyline_strain_of_a_stretched_segment_matches_its_length():
    p0 = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 1, 0], [0.0, 1, 0]])  # unit square, closed
    p = p0[None] * [[[1.5, 1.0, 1.0]]]  # x stretched 50 %: the x segments 0 and 2 grow, 1 and 3 keep
    np.testing.assert_allclose(polyline_strain(p, p0, np.array([True, False, False, False])), [0.5])
    np.testing.assert_allclose(polyline_strain(p, p0, np.array([False, True, False, False])), [0.0])
    np.testing.assert_allclose(polyline_strain(p, p0, np.ones(4, bool)), [1.0 / 4.0])


def test_report_separates_cloth_stretch_from_the_skin_under_it():
    """A tube garment around a tube body: frame 1 widens the garment 20 % and the body 10 % about the
    axis, so the neckline's strain is 0.2 (whole and front), the skin's 0.1, and the chords follow."""
    v, f = _tube(36, 4, 0.1, 0.2)
    body, _ = _tube(72, 4, 0.09, 0.2)
    x = np.stack([v, v * [1.2, 1.0, 1.2]])
    frames = np.stack([body, body * [1.1, 1.0, 1.1]])
    r = stretch_report(x, v, f, body, frames, front_z=0.05)
    assert r["worst_frame"] == 1 and 0 < r["front_vertices"] < r["loop_vertices"] == 36
    np.testing.assert_allclose([r["front_strain"], r["loop_strain"]], 0.2, atol=1e-9)
    np.testing.assert_allclose([r["front_skin_strain"], r["loop_skin_strain"]], 0.1, atol=1e-9)
    np.testing.assert_allclose([r["front_chord_ratio"], r["front_chord_skin_ratio"]], [1.2, 1.1], atol=1e-9)
    assert abs(r["skin_distance_at_rest_mm"] - 10.0) < 0.5  # 1 cm between the tubes at rest
    assert r["per_frame"]["front"][0] == 0.0


def test_the_command_reads_the_body_the_file_holds(tmp_path, monkeypatch, capsys):
    """A worst_edges --save file carries the body as simulated: the skin is read from it (no motion
    to rebuild, so no skeleton to get wrong); a file without it and without --motion is refused."""
    import json
    import sys

    import pytest

    from benchmarks import neckline_stretch
    from sim.bodies.default import load_default_body

    body = load_default_body().rest_mesh()
    v, f = _tube(36, 4, 0.08, 0.06)
    v = v + [0.0, 0.2, 0.03]  # a collar around the default body's neck (its front: rest z above 0.1)
    x = np.stack([v, v + (v - [0.0, 0.0, 0.03]) * [0.2, 0.0, 0.2]])  # 20 % wider about its axis
    skin = np.stack([body, body + (body - [0.0, 0.0, 0.03]) * [0.1, 0.0, 0.1]])  # the skin 10 % wider
    path = tmp_path / "t_walk.npz"
    np.savez(path, x=x, rest=v, faces=f, body=skin)
    monkeypatch.setattr(sys, "argv", ["neckline_stretch", str(path)])
    neckline_stretch.main()
    r = json.loads(capsys.readouterr().out)
    assert r["worst_frame"] == 1 and abs(r["loop_strain"] - 0.2) < 1e-6
    # the body the file holds (its horizontal spans 10 % wider), not one posed again (unstretched)
    assert 0.05 < r["loop_skin_strain"] <= 0.1 + 1e-6
    bare = tmp_path / "bare.npz"
    np.savez(bare, x=x, rest=v, faces=f)
    monkeypatch.setattr(sys, "argv", ["neckline_stretch", str(bare)])
    with pytest.raises(SystemExit) as e:
        neckline_stretch.main()
    assert e.value.code == 2 and "give --motion" in capsys.readouterr().err
