"""GarmentCode pattern files: reading against hand-computed geometry, writing, round trips and
refusals of bad files (sim.garments.garmentcode).

Every file is written here from the documented format (GarmentCode's ``pygarment`` and the
Garment-Pattern-Generator's ``template_spec_with_comments.json``): a two-panel skirt in
centimetres whose back panel is clockwise, as GarmentCode writes back panels.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.garments.garmentcode import (
    euler_angles,
    pattern_from_spec,
    pattern_to_spec,
    read_garmentcode,
    rotation_matrix,
    write_garmentcode,
)
from sim.garments.pattern import Edge, Panel, Pattern, Placement, Seam

# the hem: a quadratic from (0, 0) to (50, 0) cm with its control 5 cm below the middle, a
# parabola 2.5 cm deep; its length is 125 cm * (0.2 sqrt(1.04) + asinh 0.2) (y' runs -0.2..0.2)
HEM_LENGTH = 1.25 * (0.2 * np.sqrt(1.04) + np.arcsinh(0.2))
# the waist: a circle of radius 25 cm through two points 40 cm apart: 10 cm deep, 2 asin(0.8) rad
WAIST_LENGTH = 0.25 * 2.0 * np.arcsin(0.8)


def skirt_spec() -> dict:
    """A two-panel skirt in cm: the front counter-clockwise, the back clockwise."""
    front = {
        "vertices": [[0, 0], [50, 0], [45, 60], [5, 60]],
        "edges": [
            {"endpoints": [0, 1], "curvature": {"type": "quadratic", "params": [[0.5, -0.1]]},
             "label": "hem"},
            {"endpoints": [1, 2]},
            {"endpoints": [2, 3], "curvature": {"type": "circle", "params": [25, 0, 0]},
             "label": "waistband"},
            {"endpoints": [3, 0], "label": "side"},
        ],
        "translation": [-25, 40, 15], "rotation": [0, 0, 0], "label": "leg",
    }
    back = {  # clockwise in its plane: its outside faces -z
        "vertices": [[0, 0], [5, 60], [45, 60], [50, 0]],
        "edges": [
            {"endpoints": [0, 1]},
            {"endpoints": [1, 2], "curvature": {"type": "circle", "params": [25, 0, 1]},
             "label": "waistband"},
            {"endpoints": [2, 3]},
            {"endpoints": [3, 0], "curvature": {"type": "quadratic", "params": [[0.5, 0.1]]},
             "label": "hem"},
        ],
        "translation": [-25, 40, -15], "rotation": [0, 0, 0],
    }
    return {
        "pattern": {"panels": {"front": front, "back": back},
                    "stitches": [[{"panel": "front", "edge": 1}, {"panel": "back", "edge": 2}],
                                 [{"panel": "front", "edge": 3}, {"panel": "back", "edge": 0}]],
                    "panel_order": ["front", "back"]},
        "parameters": {}, "parameter_order": [],
        "properties": {"curvature_coords": "relative", "normalize_panel_translation": False,
                       "normalized_edge_loops": True, "units_in_meter": 100},
    }


def write_spec(tmp_path, spec, name="skirt_specification.json"):
    path = tmp_path / name
    path.write_text(json.dumps(spec))
    return path


def placed_outline(p: Panel) -> np.ndarray:
    return p.placement.place(p.outline(16))


def assert_same_pattern(a: Pattern, b: Pattern, tol: float = 1e-9) -> None:
    """Same panels (corners, edges, labels, placements), seams and parameters."""
    assert a.name == b.name
    assert [p.name for p in a.panels] == [p.name for p in b.panels]
    for pa, pb in zip(a.panels, b.panels, strict=True):
        np.testing.assert_allclose(pa.corners, pb.corners, atol=tol)
        assert [(e.kind, e.label) for e in pa.edges] == [(e.kind, e.label) for e in pb.edges]
        for ea, eb in zip(pa.edges, pb.edges, strict=True):
            np.testing.assert_allclose(np.reshape(ea.controls, -1), np.reshape(eb.controls, -1), atol=tol)
        la, lb = pa.placement, pb.placement
        for f in ("anchor", "origin"):
            np.testing.assert_allclose(getattr(la, f), getattr(lb, f), atol=tol)
        for f in ("u_dir", "v_dir"):
            np.testing.assert_allclose(np.asarray(getattr(la, f)) / np.linalg.norm(getattr(la, f)),
                                       np.asarray(getattr(lb, f)) / np.linalg.norm(getattr(lb, f)), atol=tol)
        np.testing.assert_allclose([la.curvature, la.radius_slope], [lb.curvature, lb.radius_slope], atol=tol)
    assert a.seams == b.seams
    assert json.loads(json.dumps(a.parameters)) == json.loads(json.dumps(b.parameters))


# ----------------------------------------------------------------------------- reading


def test_skirt_geometry_in_metres(tmp_path):
    p = read_garmentcode(write_spec(tmp_path, skirt_spec()))
    assert p.name == "skirt"
    front, back = p.panels
    assert (front.name, back.name) == ("front", "back")
    np.testing.assert_allclose(front.corners, [[0, 0], [0.5, 0], [0.45, 0.6], [0.05, 0.6]], atol=1e-12)
    assert [e.kind for e in front.edges] == ["quadratic", "line", "arc", "line"]
    assert [e.label for e in front.edges] == ["hem", "", "waistband", "side"]
    # relative (0.5, -0.1): half way along, a tenth of the edge to its right (below it)
    np.testing.assert_allclose(front.edges[0].controls, [[0.25, -0.05]], atol=1e-12)
    np.testing.assert_allclose(front.edges[2].controls, [[0.25, 0.0, 0.0]], atol=1e-12)  # radius in m
    for panel, hem, waist in ((front, 0, 2), (back, 3, 1)):
        np.testing.assert_allclose(panel.edge_length(hem), HEM_LENGTH, rtol=1e-5)
        np.testing.assert_allclose(panel.edge_length(waist), WAIST_LENGTH, rtol=1e-5)
    # arc-length midpoints of the symmetric curves: the hem 2.5 cm below, the waist 10 cm below
    np.testing.assert_allclose(front.edge_curve(0, 2)[1], [0.25, -0.025], atol=1e-6)
    np.testing.assert_allclose(front.edge_curve(2, 2)[1], [0.25, 0.50], atol=1e-6)
    assert p.parameters == {"panel_labels": {"front": "leg"}}


def test_clockwise_panel_is_mirrored_and_keeps_its_3d_outline(tmp_path):
    spec = skirt_spec()
    p = read_garmentcode(write_spec(tmp_path, spec))
    front, back = p.panels
    assert front.area() > 0 and back.area() > 0
    # mirrored x -> -x: same edge order and directions, so indices and stitches hold
    file_xy = np.asarray(spec["pattern"]["panels"]["back"]["vertices"], float) / 100
    np.testing.assert_allclose(back.corners, file_xy * [-1, 1], atol=1e-12)
    # 3D corners: translation + file vertex (rotation 0), in metres
    np.testing.assert_allclose(back.placement.place(back.corners),
                               np.c_[file_xy, np.zeros(4)] + [-0.25, 0.40, -0.15], atol=1e-12)
    np.testing.assert_allclose(front.placement.place(front.corners[2:3]), [[0.20, 1.00, 0.15]], atol=1e-12)
    # outsides: the front faces +z, the back -z
    for panel, out in ((front, [0, 0, 1]), (back, [0, 0, -1])):
        n = np.cross(panel.placement.u_dir, panel.placement.v_dir)
        np.testing.assert_allclose(n, out, atol=1e-12)
    # the hems' midpoints meet under the body's axis, 2.5 cm below the corners, front and back
    def mid3d(panel, edge):
        return panel.placement.place(panel.edge_curve(edge, 2)[1])[0]

    np.testing.assert_allclose(mid3d(front, 0), [0, 0.375, 0.15], atol=1e-6)
    np.testing.assert_allclose(mid3d(back, 3), [0, 0.375, -0.15], atol=1e-6)
    # the back waist bulges down in 3D as the front does
    np.testing.assert_allclose(mid3d(back, 1), [0, 0.90, -0.15], atol=1e-6)


def test_stitches_become_seams(tmp_path):
    spec = skirt_spec()
    spec["pattern"]["stitches"][1].append("right_wrong")
    p = read_garmentcode(write_spec(tmp_path, spec))
    assert p.seams == (Seam(("front", 1), ("back", 2), reverse=True),
                       Seam(("front", 3), ("back", 0), reverse=False))
    # the default stitch joins the end of its first edge to the start of its second, in 3D
    front, back = p.panels
    a = front.placement.place(np.array(front.edge_ends(1)))
    b = back.placement.place(np.array(back.edge_ends(2)))
    np.testing.assert_allclose(a[1, :2], b[0, :2], atol=1e-12)
    np.testing.assert_allclose(a[0, :2], b[1, :2], atol=1e-12)


def test_darts_are_consecutive_edges_of_one_panel(tmp_path):
    spec = skirt_spec()
    spec["pattern"]["panels"]["front"] = {  # a waist dart: a 4 cm notch 12 cm deep
        "vertices": [[0, 0], [50, 0], [45, 60], [27, 60], [25, 48], [23, 60], [5, 60]],
        "edges": [{"endpoints": [i, (i + 1) % 7]} for i in range(7)],
        "translation": [-25, 40, 15], "rotation": [0, 0, 0]}
    spec["pattern"]["stitches"] = [[{"panel": "front", "edge": 3}, {"panel": "front", "edge": 4}],
                                   [{"panel": "front", "edge": 1}, {"panel": "back", "edge": 2}],
                                   [{"panel": "front", "edge": 6}, {"panel": "back", "edge": 0}]]
    p = read_garmentcode(write_spec(tmp_path, spec))
    assert [s.dart for s in p.seams] == [True, False, False]
    assert p.darts == (Seam(("front", 3), ("front", 4), reverse=True, dart=True),)


def test_rotations_place_corners(tmp_path):
    spec = skirt_spec()
    front = spec["pattern"]["panels"]["front"]
    # XYZ Euler angles applied x first (Maya's order): (10, 20, 0) -> x 90° -> (10, 0, 20) -> z 90°
    # -> (0, 10, 20); the other order would give (-20, 0, 10)
    cases = [([0, 90, 0], [5, 100, 0], [5, 120, -10]), ([90, 0, 90], [1, 2, 3], [1, 12, 23]),
             ([0, 0, -90], [0, 0, 0], [20, -10, 0])]
    for angles, t, want in cases:
        front["vertices"][0] = [10, 20]
        front["rotation"], front["translation"] = angles, t
        p = pattern_from_spec(copy.deepcopy(spec))
        got = p.panel("front").placement.place(p.panel("front").corners[:1])[0]
        np.testing.assert_allclose(got, np.asarray(want) / 100, atol=1e-12)
    front["rotation"] = rotation_matrix([90, 0, 90]).tolist()  # a 3x3 matrix means the same
    front["translation"] = [1, 2, 3]
    p = pattern_from_spec(spec)
    np.testing.assert_allclose(p.panel("front").placement.place(p.panel("front").corners[:1])[0],
                               [0.01, 0.12, 0.23], atol=1e-12)


def test_euler_angles_invert_rotation_matrix():
    rng = np.random.default_rng(7)
    for angles in [*rng.uniform(-179, 179, (20, 3)) * [1, 0.49, 1], [30, 90, 0], [10, -90, 0], [0, 0, 0]]:
        r = rotation_matrix(angles)
        np.testing.assert_allclose(rotation_matrix(euler_angles(r)), r, atol=1e-12)


def test_units_absolute_coords_and_bare_curvature_read_the_same(tmp_path):
    ref = pattern_from_spec(skirt_spec(), name="skirt")
    mm = skirt_spec()  # millimetres, absolute control points, a bare [x, y] quadratic
    mm["properties"].update(units_in_meter=1000, curvature_coords="absolute")
    for panel in mm["pattern"]["panels"].values():
        panel["vertices"] = (np.asarray(panel["vertices"], float) * 10).tolist()
        panel["translation"] = [10 * x for x in panel["translation"]]
    mm["pattern"]["panels"]["front"]["edges"][0]["curvature"] = [250, -50]
    mm["pattern"]["panels"]["front"]["edges"][2]["curvature"]["params"] = [250, 0, 0]
    mm["pattern"]["panels"]["back"]["edges"][1]["curvature"]["params"] = [250, 0, 1]
    mm["pattern"]["panels"]["back"]["edges"][3]["curvature"] = {"type": "quadratic", "params": [[250, -50]]}
    assert_same_pattern(pattern_from_spec(mm, name="skirt"), ref, tol=1e-12)


def test_cubic_and_normalized_translation(tmp_path):
    spec = skirt_spec()
    front = spec["pattern"]["panels"]["front"]
    front["edges"][1]["curvature"] = {"type": "cubic", "params": [[0.25, 0.1], [0.75, -0.1]]}
    front["rotation"] = [0, 90, 0]
    p = pattern_from_spec(spec)
    c = p.panel("front").edges[1].controls  # edge (50, 0) -> (45, 60) cm; left of it is (-60, -5)
    np.testing.assert_allclose(c, [[0.4875 - 0.06, 0.15 - 0.005], [0.4625 + 0.06, 0.45 + 0.005]], atol=1e-12)
    # GarmentCode's normalize_panel_translation centres the vertices and moves the translation
    # by their mean, unrotated
    spec["properties"]["normalize_panel_translation"] = True
    q = pattern_from_spec(spec)
    mean = np.append(np.mean(front["vertices"], axis=0), 0.0) / 100
    local = np.c_[np.asarray(front["vertices"]) / 100, np.zeros(4)] - mean
    want = np.asarray(front["translation"]) / 100 + mean + local @ rotation_matrix([0, 90, 0]).T
    np.testing.assert_allclose(q.panel("front").placement.place(q.panel("front").corners), want, atol=1e-12)


# ----------------------------------------------------------------------------- writing


def test_read_write_read_keeps_geometry(tmp_path):
    src = write_spec(tmp_path, skirt_spec())
    first = read_garmentcode(src)
    out = tmp_path / "again.json"
    write_garmentcode(first, out)
    spec = json.loads(out.read_text())
    assert spec["properties"]["units_in_meter"] == 100
    assert spec["properties"]["curvature_coords"] == "relative"
    assert spec["pattern"]["panel_order"] == ["front", "back"]
    front = spec["pattern"]["panels"]["front"]
    np.testing.assert_allclose(front["vertices"], skirt_spec()["pattern"]["panels"]["front"]["vertices"],
                               atol=1e-9)
    assert front["edges"][0]["curvature"]["type"] == "quadratic"
    np.testing.assert_allclose(front["edges"][0]["curvature"]["params"], [[0.5, -0.1]], atol=1e-12)
    assert front["edges"][2]["curvature"] == {"type": "circle", "params": [25.0, 0, 0]}
    assert front["label"] == "leg" and front["edges"][2]["label"] == "waistband"
    again = read_garmentcode(out)
    assert_same_pattern(again, first)
    for a, b in zip(first.panels, again.panels, strict=True):
        np.testing.assert_allclose(placed_outline(b), placed_outline(a), atol=1e-9)


def curved_pattern() -> Pattern:
    """Our own pattern: cubic and arc edges, cylinder placements, a dart, a right-to-wrong seam."""
    tube = Panel("sleeve", np.array([[0, 0], [0.3, 0], [0.3, 0.5], [0.15, 0.58], [0, 0.5]]),
                 (Edge(label="cuff"), Edge(label="underarm"),
                  Edge("cubic", ((0.27, 0.55), (0.2, 0.6))), Edge("arc", ((0.2, 0.0, 0.0),)),
                  Edge(label="underarm")),
                 Placement((0.5, 1.2, 0.05), (0, 0, -1), (1, 0.2, 0), curvature=12.0, origin=(0.15, 0.25),
                           radius_slope=-0.05))
    body = Panel("body", np.array([[0, 0], [0.4, 0], [0.4, 0.6], [0.22, 0.6], [0.2, 0.45], [0.18, 0.6],
                                   [0, 0.6]]),
                 tuple(Edge() for _ in range(7)), Placement((0.0, 1.0, 0.1), curvature=4.0))
    return Pattern("mine", (tube, body), (Seam(("sleeve", 1), ("sleeve", 4)),
                                          Seam(("body", 3), ("body", 4), dart=True),
                                          Seam(("body", 1), ("body", 6), reverse=False)),
                   {"fit": "regular", "ease": {"chest": 0.08}})


def test_write_read_round_trip_of_our_pattern(tmp_path):
    p = curved_pattern()
    path = tmp_path / "mine.json"
    write_garmentcode(p, path)
    assert_same_pattern(read_garmentcode(path), p)
    spec = json.loads(path.read_text())
    assert spec["pattern"]["stitches"][2] == [{"panel": "body", "edge": 1}, {"panel": "body", "edge": 6},
                                              "right_wrong"]
    # GarmentCode places the panel flat on the plane tangent to its cylinder at the anchor
    sleeve = spec["pattern"]["panels"]["sleeve"]
    r = rotation_matrix(sleeve["rotation"])
    flat = np.asarray(sleeve["translation"]) / 100 + r @ np.array([15.0, 25.0, 0.0]) / 100
    np.testing.assert_allclose(flat, [0.5, 1.2, 0.05], atol=1e-9)
    np.testing.assert_allclose(r[:, 0], [0, 0, -1], atol=1e-12)


def test_spec_round_trip_in_memory():
    p = curved_pattern()
    assert_same_pattern(pattern_from_spec(json.loads(json.dumps(pattern_to_spec(p)))), p)


# ----------------------------------------------------------------------------- bad files


def bad(spec_edit):
    spec = skirt_spec()
    spec_edit(spec)
    return spec


def stitch(a, i, b, j):
    return [{"panel": a, "edge": i}, {"panel": b, "edge": j}]


@pytest.mark.parametrize(("edit", "words"), [
    (lambda s: s["pattern"]["stitches"].append(stitch("sleeve", 0, "back", 1)), "panel 'sleeve'"),
    (lambda s: s["pattern"]["stitches"].append(stitch("front", 9, "back", 1)), "edge 9 of panel 'front'"),
    (lambda s: s["pattern"]["panels"]["front"]["edges"][0].update(curvature={"type": "spline", "params": []}),
     "unknown curvature type 'spline'"),
    (lambda s: s["pattern"]["panels"]["front"]["edges"][1].update(endpoints=[1, 3]), "closed loop"),
    (lambda s: s["pattern"]["stitches"][0].append("left"), "unknown third entry 'left'"),
    (lambda s: s["properties"].update(units_in_meter=0), "units_in_meter"),
    (lambda s: s["properties"].update(curvature_coords="polar"), "curvature_coords"),
    (lambda s: s["pattern"]["stitches"].append(stitch("front", 1, "back", 1)), "two seams"),
    (lambda s: s.pop("pattern"), "no 'pattern'"),
])
def test_bad_files_name_the_file_and_the_problem(tmp_path, edit, words):
    path = write_spec(tmp_path, bad(edit), "broken.json")
    with pytest.raises(WrinklesInputError) as err:
        read_garmentcode(path)
    msg = str(err.value)
    assert msg.startswith(str(path)) and words in msg and "\n" not in msg


def test_not_json_and_missing_file(tmp_path):
    path = tmp_path / "pattern.json"
    path.write_text("{'pattern': }")
    with pytest.raises(WrinklesInputError, match=r"pattern\.json: .*not JSON"):
        read_garmentcode(path)
    with pytest.raises(WrinklesInputError, match=r"nowhere\.json: cannot read"):
        read_garmentcode(tmp_path / "nowhere.json")
