"""Tailor's measurements of a body (sim.garments.body_measurements) and ``wrinkles body
--measurements``: plane sections against analytic perimeters, the default body's measurements
within adult ranges, symmetric, ordered, and growing with the shape."""

from __future__ import annotations

import json
from dataclasses import fields

import numpy as np
import pytest

from sim.garments.body_measurements import (
    BodyMeasurements,
    cross_section_perimeter,
    measure_body,
    measurement_notes,
    taut_length,
)


def tube(outline: np.ndarray, ys) -> tuple[np.ndarray, np.ndarray]:
    """A prism's side wall: the closed (x, z) outline (n, 2) repeated at heights ``ys``, two
    triangles per quad."""
    n = len(outline)
    v = np.concatenate([np.column_stack([outline[:, 0], np.full(n, y), outline[:, 1]]) for y in ys])
    faces = []
    for r in range(len(ys) - 1):
        for k in range(n):
            a, b, c, d = r * n + k, r * n + (k + 1) % n, (r + 1) * n + k, (r + 1) * n + (k + 1) % n
            faces += [(a, b, d), (a, d, c)]
    return v, np.asarray(faces)


def circle(n: int, r: float, center=(0.0, 0.0)) -> np.ndarray:
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([center[0] + r * np.cos(t), center[1] + r * np.sin(t)])


def ramanujan(a: float, b: float) -> float:
    """Ellipse perimeter, Ramanujan's first approximation (relative error < 1e-9 at a = 2b)."""
    return np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))


def uv_sphere(radius: float, rings: int, segments: int) -> tuple[np.ndarray, np.ndarray]:
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    body = np.column_stack([np.sin(th).ravel() * np.cos(ph).ravel(), np.cos(th).ravel(),
                            np.sin(th).ravel() * np.sin(ph).ravel()]) * radius
    v = np.vstack([[0.0, radius, 0.0], body, [0.0, -radius, 0.0]])
    faces = []
    s, last = segments, len(v) - 1
    for k in range(s):
        faces.append((0, 1 + (k + 1) % s, 1 + k))
        faces.append((last, 1 + (rings - 2) * s + k, 1 + (rings - 2) * s + (k + 1) % s))
    for r in range(rings - 2):
        for k in range(s):
            a, b = 1 + r * s + k, 1 + r * s + (k + 1) % s
            faces += [(a, b, b + s), (a, b + s, a + s)]
    return v, np.asarray(faces)


# ----------------------------------------------------------------------------- sections


def test_cylinder_section_is_its_polygon_and_tends_to_two_pi_r():
    n, r = 96, 0.3
    v, f = tube(circle(n, r), [-1.0, -0.2, 0.5, 1.0])
    exact = 2 * n * r * np.sin(np.pi / n)  # the inscribed n-gon, what the mesh is
    for y in (-0.7, 0.1, 0.9):
        np.testing.assert_allclose(cross_section_perimeter(v, f, (0.0, y, 0.0), (0.0, 1.0, 0.0)),
                                   exact, rtol=1e-12)
    # a plane through a ring of vertices cuts exactly there
    np.testing.assert_allclose(cross_section_perimeter(v, f, (0.0, -0.2, 0.0), (0.0, 1.0, 0.0)),
                               exact, rtol=1e-12)
    np.testing.assert_allclose(exact, 2 * np.pi * r, rtol=(np.pi / n) ** 2 / 6 * 1.01)


def test_tilted_cylinder_section_is_ramanujans_ellipse():
    n, r, tilt = 512, 0.2, np.radians(35.0)
    v, f = tube(circle(n, r), [-1.0, 1.0])
    normal = (np.sin(tilt), np.cos(tilt), 0.0)
    p = cross_section_perimeter(v, f, (0.0, 0.05, 0.0), normal)
    np.testing.assert_allclose(p, ramanujan(r / np.cos(tilt), r), rtol=1e-4)


def test_elliptic_prism_section_is_ramanujans_ellipse():
    n, a, b = 720, 0.4, 0.2
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    v, f = tube(np.column_stack([a * np.cos(t), b * np.sin(t)]), [0.0, 1.0])
    np.testing.assert_allclose(cross_section_perimeter(v, f, (0.0, 0.4, 0.0), (0.0, 1.0, 0.0)),
                               ramanujan(a, b), rtol=1e-4)


@pytest.mark.parametrize("h", [0.0, 0.37, -0.8])
def test_sphere_section_is_its_small_circle(h):
    R = 1.0
    v, f = uv_sphere(R, rings=96, segments=192)
    p = cross_section_perimeter(v, f, (0.0, h, 0.0), (0.0, 1.0, 0.0))
    # chords between rings and between meridians sit inside the sphere: second order in the step
    np.testing.assert_allclose(p, 2 * np.pi * np.sqrt(R * R - h * h), rtol=2e-3)
    assert p < 2 * np.pi * np.sqrt(R * R - h * h)


def test_mask_picks_the_faces_that_count_and_the_hull_bridges_the_rest():
    n, r, d = 64, 0.1, 0.5
    va, fa = tube(circle(n, r, (-d / 2, 0.0)), [0.0, 1.0])
    vb, fb = tube(circle(n, r, (d / 2, 0.0)), [0.0, 1.0])
    v, f = np.vstack([va, vb]), np.vstack([fa, fb + len(va)])
    left = np.arange(len(f)) < len(fa)
    ngon = 2 * n * r * np.sin(np.pi / n)
    at = (0.0, 0.5, 0.0)
    np.testing.assert_allclose(cross_section_perimeter(v, f, at, (0.0, 1.0, 0.0), left), ngon, rtol=1e-12)
    # the hull of a convex section and its translate by d: its perimeter plus 2 d
    np.testing.assert_allclose(cross_section_perimeter(v, f, at, (0.0, 1.0, 0.0)), ngon + 2 * d, rtol=1e-12)
    assert cross_section_perimeter(v, f, (0.0, 2.0, 0.0), (0.0, 1.0, 0.0)) == 0.0


def test_taut_tape_bridges_hollows_and_follows_bumps():
    np.testing.assert_allclose(taut_length(np.array([0.0, 1.0, 2.0]), np.array([1.0, 0.0, 1.0])), 2.0)
    np.testing.assert_allclose(taut_length(np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0, 0.0])),
                               2 * np.sqrt(2.0))
    t = np.linspace(0.0, np.pi, 2001)  # a half circle of radius 1, bulging outward
    np.testing.assert_allclose(taut_length(-np.cos(t), np.sin(t)), np.pi, rtol=1e-6)


# ----------------------------------------------------------------------------- bodies


@pytest.fixture(scope="module")
def body():
    from sim.bodies import load_body

    return load_body()


@pytest.fixture(scope="module")
def shaped(body):
    from sim.bodies.default import parse_shape

    specs = ("", "weight=0.1", "weight=0.9", "height=0.2", "height=0.6")
    return {s: measure_body(body, parse_shape(s) if s else None) for s in specs}


ADULT_RANGES = {  # [m], a 1.7 m adult (ISO 8559-2 size tables span these)
    "neck_base": (0.36, 0.48), "chest": (0.85, 1.15), "waist": (0.65, 1.00), "hip": (0.85, 1.15),
    "bicep": (0.25, 0.40), "elbow": (0.20, 0.32), "wrist": (0.13, 0.20), "thigh": (0.45, 0.65),
    "knee": (0.32, 0.45), "calf": (0.30, 0.45), "ankle": (0.19, 0.30),
    "shoulder_width": (0.35, 0.50), "arm_length": (0.45, 0.65), "back_length": (0.35, 0.50),
    "front_length": (0.30, 0.45), "inseam": (0.70, 0.90), "rise": (0.20, 0.32),
    "neck_to_shoulder": (0.10, 0.17),
}


def test_default_body_measures_within_adult_ranges(shaped):
    m = shaped[""]
    for name, (lo, hi) in ADULT_RANGES.items():
        assert lo <= getattr(m, name) <= hi, (name, getattr(m, name))
    assert m.waist < m.hip and m.waist < m.chest
    assert m.wrist < m.elbow < m.bicep < m.thigh
    assert m.ankle < m.calf < m.thigh
    np.testing.assert_allclose(m.outseam, m.rise + m.inseam, rtol=1e-12)
    np.testing.assert_allclose(m.shoulder_width, np.linalg.norm(m.shoulder_points[0] - m.shoulder_points[1]))


def test_default_body_is_measured_symmetrically(shaped):
    m = shaped[""]
    for name, (left, right) in m.sides.items():
        assert abs(left - right) < 0.005, name
    mirror = np.array([-1.0, 1.0, 1.0])
    for pts in (m.shoulder_points, m.side_neck_points, m.armpit_points):
        np.testing.assert_allclose(pts[1], pts[0] * mirror, atol=0.005)
    np.testing.assert_allclose(m.leg_axis_x[1], -m.leg_axis_x[0], atol=0.005)
    for ext in (m.chest_extent, m.waist_extent, m.hip_extent):
        assert abs(ext.center[0]) < 0.005


def test_landmarks_are_ordered_from_the_floor_up(shaped, body):
    for m in shaped.values():
        heights = [m.floor_height, m.ankle_height, m.knee_height, m.crotch_height, m.hip_height,
                   m.waist_height, m.chest_height, m.armpit_height, m.shoulder_height,
                   m.neck_base_height]
        assert np.all(np.diff(heights) > 0), heights
        assert m.armpit_height < m.front_neck_point[1] < m.neck_base_height
        assert np.all(np.abs(m.side_neck_points[:, 0]) < np.abs(m.shoulder_points[:, 0]))
        assert np.all(np.abs(m.armpit_points[:, 0]) < m.wrist_x)
        # the back starts behind the front, the waist section lies between them
        assert m.nape_point[2] < m.waist_extent.center[1] < m.front_neck_point[2] + 0.1
    j = body.rest_joints(None)
    m = shaped[""]
    np.testing.assert_allclose(m.shoulder_points[:, 0], j[[16, 17], 0], atol=1e-9)
    assert np.all(m.shoulder_points[:, 1] > j[[16, 17], 1])  # on the surface above the joint


def test_measurements_grow_with_the_shape(shaped):
    thin, heavy = shaped["weight=0.1"], shaped["weight=0.9"]
    for name in ("chest", "waist", "hip", "thigh", "bicep", "neck_base"):
        assert getattr(heavy, name) > getattr(thin, name) + 0.02, name
    short, tall = shaped["height=0.2"], shaped["height=0.6"]
    for name in ("inseam", "arm_length", "outseam", "back_length", "shoulder_width"):
        assert getattr(tall, name) > getattr(short, name) + 0.01, name


def test_every_field_says_how_it_is_taken_and_round_trips_through_json(shaped):
    notes = measurement_notes()
    assert set(notes) == {f.name for f in fields(BodyMeasurements)}
    assert all(len(v) > 20 for v in notes.values())
    d = json.loads(json.dumps(shaped[""].to_dict()))
    np.testing.assert_allclose(d["chest"], shaped[""].chest)
    np.testing.assert_allclose(d["shoulder_points"], shaped[""].shoulder_points)
    np.testing.assert_allclose(d["hip_extent"]["center"], shaped[""].hip_extent.center)


# ----------------------------------------------------------------------------- CLI


def test_cli_prints_the_table_and_writes_json_without_posing(body, tmp_path, monkeypatch, capsys):
    from pipelines.cli import main
    from sim.bodies.default import parse_shape

    monkeypatch.chdir(tmp_path)
    shape = "height=0.6,weight=0.8"
    m = measure_body(body, parse_shape(shape))
    assert main(["body", "--measurements", "--shape", shape]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split()[1] for line in out.splitlines()[1:] if line[:1].strip()}
    assert float(rows["chest"]) == pytest.approx(100 * m.chest, abs=0.051)
    assert float(rows["inseam"]) == pytest.approx(100 * m.inseam, abs=0.051)
    assert "Natural waist girth" in out
    path = tmp_path / "sub" / "m.json"
    assert main(["body", "--measurements-json", str(path), "--shape", shape, "--quiet"]) == 0
    assert capsys.readouterr().out == ""
    rec = json.loads(path.read_text())
    assert rec["units"] == "m" and rec["shape"] == shape
    for name in ("chest", "waist", "hip", "inseam", "neck_base_height"):
        np.testing.assert_allclose(rec["measurements"][name], getattr(m, name), rtol=1e-12)
    assert set(rec["how"]) == set(rec["measurements"])
    assert not (tmp_path / "out").exists()  # no stage written


def test_cli_refuses_a_json_path_of_another_kind(tmp_path, capsys):
    from pipelines.cli import main

    bad = tmp_path / "m.txt"
    assert main(["body", "--measurements-json", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "m.txt" in err and ".json" in err
    assert not bad.exists()
