"""GarmentCode pattern files through the commands: ``wrinkles garments --pattern-out`` writes a
design's pattern (JSON, SVG, PNG) without sewing, ``--pattern FILE.json`` sews a file on the
body, ``wrinkles simulate --garment FILE.json`` takes one; bad files are one line, exit 2.

The sewn file is written here in GarmentCodeData's documented format (``pygarment``'s pattern
specification): a two-panel skirt in centimetres around a body standing on the floor (y = 0 at
the soles), its back panel clockwise as GarmentCode writes back panels.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from pipelines.cli import main
from sim.garments.drafting.hood import HOOD_HOLD
from sim.garments.garmentcode import place_on_body, read_garmentcode
from tests.test_garmentcode import assert_same_pattern

H = 0.04
"""Edge length [m] the sewing tests use: coarse, to stay fast on a CPU."""


def default_body():
    from sim.bodies import load_body

    return load_body()


def floor_skirt_spec() -> dict:
    """A skirt from 60 to 108 cm above the floor (the default body's hips and waist), the front
    panel 20 cm in front of the floor's origin, the back 14 cm behind it; 104 cm round the hem,
    88 cm round the waist."""
    front = {
        "vertices": [[0, 0], [52, 0], [48, 48], [4, 48]],
        "edges": [
            {"endpoints": [0, 1], "curvature": {"type": "quadratic", "params": [[0.5, -0.03]]},
             "label": "hem"},
            {"endpoints": [1, 2], "label": "side"},
            {"endpoints": [2, 3], "curvature": {"type": "circle", "params": [100, 0, 0]},
             "label": "waistband"},
            {"endpoints": [3, 0], "label": "side"},
        ],
        "translation": [-26, 60, 20], "rotation": [0, 0, 0], "label": "body",
    }
    back = {  # clockwise in its plane: its outside faces -z
        "vertices": [[0, 0], [4, 48], [48, 48], [52, 0]],
        "edges": [
            {"endpoints": [0, 1], "label": "side"},
            {"endpoints": [1, 2], "curvature": {"type": "circle", "params": [100, 0, 1]},
             "label": "waistband"},
            {"endpoints": [2, 3], "label": "side"},
            {"endpoints": [3, 0], "curvature": {"type": "quadratic", "params": [[0.5, 0.03]]},
             "label": "hem"},
        ],
        "translation": [-26, 60, -14], "rotation": [0, 0, 0], "label": "body",
    }
    return {
        "pattern": {"panels": {"skirt_front": front, "skirt_back": back},
                    "stitches": [[{"panel": "skirt_front", "edge": 1}, {"panel": "skirt_back", "edge": 2}],
                                 [{"panel": "skirt_front", "edge": 3}, {"panel": "skirt_back", "edge": 0}]],
                    "panel_order": ["skirt_front", "skirt_back"]},
        "parameters": {}, "parameter_order": [],
        "properties": {"curvature_coords": "relative", "normalize_panel_translation": False,
                       "normalized_edge_loops": True, "units_in_meter": 100},
    }


def write_json(path, spec) -> str:
    path.write_text(json.dumps(spec))
    return str(path)


def assert_one_line_error(capsys, code: int, *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


# ----------------------------------------------------------------------------- --pattern-out


def test_pattern_out_writes_the_design_without_sewing(tmp_path, capsys, monkeypatch):
    """--pattern-out alone drafts the design for the body and writes it; nothing is sewn. The
    JSON reads back as the drafted pattern (1e-6 m), and so does the file written from it by
    --pattern FILE.json --pattern-out (our file is in the body's frame: auto keeps it there)."""
    from sim.bodies.default import parse_shape
    from sim.garments import designs

    def no_sewing(*a, **k):
        raise AssertionError("--pattern-out alone must not sew")

    monkeypatch.setattr(designs, "sew_pattern", no_sewing)
    monkeypatch.setattr(designs, "sew_patterns", no_sewing)
    tee = tmp_path / "tee.json"
    args = ["--shape", "weight=0.6", "--garment-param", "sleeve_length=0.5",
            "--garment-param", "hem_width=0.03"]
    assert main(["garments", "--garment", "tee", "--pattern-out", str(tee), *args]) == 0
    out = capsys.readouterr().out
    assert "t_shirt: pattern of 4 panels (front, back, sleeve_l, sleeve_r), 12 seams, 0 darts" in out
    want = designs.make_pattern("t_shirt", default_body(), parse_shape("weight=0.6"), sleeve_length=0.5)
    assert_same_pattern(read_garmentcode(tee), want, tol=1e-6)
    default = designs.make_pattern("t_shirt", default_body(), parse_shape("weight=0.6"))
    assert default.panel("sleeve_l").edge_length(0) != pytest.approx(want.panel("sleeve_l").edge_length(0))
    again = tmp_path / "again.json"
    assert main(["garments", "--pattern", str(tee), "--pattern-out", str(again),
                 "--shape", "weight=0.6"]) == 0
    assert_same_pattern(read_garmentcode(again), want, tol=1e-6)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.json", "tee.json"]


def test_hoodie_json_keeps_how_its_hood_is_sewn(tmp_path, capsys):
    """The hood's neck seam meets near the hood's own neck edge (``Placement.hold`` of the hood
    ``HOOD_HOLD``, the body panels' 1): our JSON keeps that, so the file sews as the design does."""
    from sim.garments.designs import make_pattern

    path = tmp_path / "hoodie.json"
    assert main(["garments", "--garment", "hoodie", "--pattern-out", str(path)]) == 0
    want = make_pattern("hoodie", default_body())
    got = read_garmentcode(path)
    assert_same_pattern(got, want, tol=1e-6)
    holds = {p.name: p.placement.hold for p in want.panels}
    assert {p.name: p.placement.hold for p in got.panels} == holds
    assert holds["hood_l"] == holds["hood_r"] == HOOD_HOLD != 1.0 and holds["front"] == 1.0


def test_pattern_out_svg_and_png(tmp_path, capsys):
    svg, png = tmp_path / "skirt.svg", tmp_path / "skirt.png"
    assert main(["garments", "--export", "straight_skirt", "--pattern-out", str(svg),
                 "--seam-allowance", "0.01"]) == 0
    root = ET.parse(svg).getroot()
    assert root.get("width").endswith("mm")
    ns = "{http://www.w3.org/2000/svg}"
    panels = [g.get("id") for g in root.iter(f"{ns}g") if (g.get("id") or "").startswith("panel-")]
    from sim.garments.designs import make_pattern

    drafted = make_pattern("straight_skirt", default_body())
    assert panels == [f"panel-{p.name}" for p in drafted.panels]
    assert len([p for p in root.iter(f"{ns}polygon") if p.get("class") == "cut"]) == len(drafted.panels)
    pytest.importorskip("matplotlib")
    from PIL import Image

    assert main(["garments", "--pattern", str(tmp_path / "x.json"), "--pattern-out", str(png)]) == 2
    capsys.readouterr()
    write_json(tmp_path / "floor.json", floor_skirt_spec())
    assert main(["garments", "--pattern", str(tmp_path / "floor.json"), "--pattern-out", str(png)]) == 0
    with Image.open(png) as im:
        assert im.size[0] == 1600 and im.size[1] > 100


# ----------------------------------------------------------------------------- --pattern FILE.json


def test_floor_standing_file_is_placed_around_the_body():
    """GarmentCodeData's frame (the soles at y = 0) is told apart from the body's own by where
    the panels are: this skirt lands 1.2 m lower, around the default body's hips."""
    from sim.garments.garmentcode import pattern_frame, pattern_from_spec

    rest = default_body().rest_mesh(None)
    floor = float(rest[:, 1].min())
    p = pattern_from_spec(floor_skirt_spec())
    assert pattern_frame(p, rest) == "floor"
    placed = place_on_body(p, rest)
    for a, b in zip(p.panels, placed.panels, strict=True):
        np.testing.assert_allclose(b.placement.place(b.corners), a.placement.place(a.corners) + [0, floor, 0],
                                   atol=1e-12)
    assert pattern_frame(placed, rest) == "body"
    assert place_on_body(placed, rest) is placed
    assert place_on_body(p, rest, "body") is p


@pytest.mark.slow
def test_pattern_file_sews_into_a_manifold_garment(tmp_path, capsys):
    """The skirt file sews on the body: its seams close within 1 mm, the garment is one tube
    (manifold, outward, two openings: waist and hem, Euler characteristic 0) around the hips,
    and the command writes that very garment."""
    from pipelines.garment_files import load_garment_file
    from sim.garments.materials import get_material
    from sim.garments.sewing import sew_pattern

    src = write_json(tmp_path / "skirt_specification.json", floor_skirt_spec())
    obj = tmp_path / "skirt.obj"
    assert main(["garments", "--pattern", src, "--out", str(obj), "--resolution", str(H)]) == 0
    out = capsys.readouterr().out
    assert "skirt (garmentcode):" in out and "panels skirt_front, skirt_back" in out
    assert "attachments hem (" in out and "waistband (" in out
    body = default_body()
    rest = body.rest_mesh(None)
    pattern = place_on_body(read_garmentcode(src), rest)
    sewn = sew_pattern(pattern, rest, body.faces, H, get_material("cotton"))
    assert sewn.seam_gap <= 1e-3
    g = load_garment_file(obj)
    np.testing.assert_allclose(g.rest_vertices, sewn.vertices, atol=1e-5)
    f = g.faces
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed)  # oriented: no edge twice one way
    edges, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    assert counts.max() == 2
    assert g.num_vertices - len(edges) + g.num_faces == 0  # a tube
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    border = edges[counts == 1]
    graph = coo_matrix((np.ones(len(border)), (border[:, 0], border[:, 1])), shape=(g.num_vertices,) * 2)
    _, label = connected_components(graph, directed=False)
    loops = [np.unique(border[label[border[:, 0]] == k]) for k in np.unique(label[border[:, 0]])]
    assert len(loops) == 2  # the waist and the hem
    heights = sorted(float(g.rest_vertices[v, 1].mean()) for v in loops)
    np.testing.assert_allclose(heights, [-0.6, -0.12], atol=0.05)  # as placed: 60 and 108 cm up
    y = g.rest_vertices[:, 1]
    assert -0.75 < y.min() < -0.55 and -0.2 < y.max() < -0.05  # hips to waist, not the floor frame


def test_a_pattern_that_does_not_sew_is_one_line(tmp_path, capsys, monkeypatch):
    """Sewing that ends in non-finite positions is refused naming the file; nothing is written."""
    from sim.garments import designs

    def blown_up(pattern, *a, **k):
        sewn = real(pattern, *a, **k)
        return type(sewn)(sewn.vertices * np.nan, sewn.faces, sewn.mesh, sewn.seam_gap)

    real = designs.sew_pattern
    monkeypatch.setattr(designs, "sew_pattern", blown_up)
    monkeypatch.setenv("WRINKLES_CACHE", "off")
    src = write_json(tmp_path / "skirt.json", floor_skirt_spec())
    code = main(["garments", "--pattern", src, "--out", str(tmp_path / "s.obj"), "--resolution", "0.1"])
    assert_one_line_error(capsys, code, f"{src}: pattern 'skirt' did not sew", "not finite")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["skirt.json"]


# ----------------------------------------------------------------------------- bad input


def _bad_stitch() -> dict:
    spec = floor_skirt_spec()
    spec["pattern"]["stitches"].append([{"panel": "sleeve", "edge": 0}, {"panel": "skirt_back", "edge": 1}])
    return spec


@pytest.mark.parametrize(("content", "args", "needles"), [
    ("{'pattern': }", ["--out", "g.obj"], ["p.json: is not a GarmentCode pattern: not JSON"]),
    (_bad_stitch, ["--out", "g.obj"], ["p.json: GarmentCode pattern: stitch 2 refers to panel 'sleeve'"]),
    (None, ["--pattern-out", "g.svg"], ["p.json: cannot read the pattern file"]),
    (floor_skirt_spec, ["--export", "t_shirt", "--out", "g.obj"], ["give one"]),
    (floor_skirt_spec, [], ["--pattern needs --out", "--pattern-out"]),
    (floor_skirt_spec, ["--pattern-out", "g.pdf"], ["g.pdf", "--pattern-out must end in"]),
    (floor_skirt_spec, ["--pattern-out", "g.svg", "--uv-image", "u.png"], ["--uv-image", "needs --out"]),
    (floor_skirt_spec, ["--out", "g.obj", "--garment-param", "length=0.5"],
     ["--garment-param length applies to templates", "p.json"]),
    (floor_skirt_spec, ["--out", "g.obj", "--garment-param", "hem_width=9"],
     ["hem_width", "outside its range"]),
    (floor_skirt_spec, ["--out", "g.obj", "--resolution", "0.5"], ["resolution 0.5 m is outside"]),
    (floor_skirt_spec, ["--pattern-out", "g.svg", "--seam-allowance", "-1"], ["--seam-allowance"]),
    (floor_skirt_spec, ["--pattern-out", "g.json", "--seam-allowance", "0.01"], ["--seam-allowance", ".svg"]),
])
def test_bad_pattern_input_is_one_line_exit_2_no_output(tmp_path, capsys, monkeypatch, content, args,
                                                         needles):
    monkeypatch.chdir(tmp_path)
    if content is not None:  # text, or a function giving the specification
        (tmp_path / "p.json").write_text(content if isinstance(content, str) else json.dumps(content()))
    before = sorted(p.name for p in tmp_path.iterdir())
    assert_one_line_error(capsys, main(["garments", "--pattern", "p.json", *args]), *needles)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_garments_pattern_outputs_need_a_garment(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert_one_line_error(capsys, main(["garments", "--pattern-out", "p.svg"]),
                          "need --export NAME (or --pattern FILE.json)")
    code = main(["garments", "--garment", "t_shirt", "--pattern-out", "p.svg", "--pattern-frame", "floor"])
    assert_one_line_error(capsys, code, "--pattern-frame", "--pattern FILE.json")
    assert not list(tmp_path.iterdir())


def test_simulate_sews_a_pattern_file(tmp_path, monkeypatch):
    """simulate's --garment FILE.json is the garment 'garments --pattern' sews: at --resolution,
    hems from --garment-param (extra layers along the waist and hem by default, none
    with hem_width=0), template parameters refused."""
    import argparse

    from pipelines.simulate_cmd import check_garment_spec, load_garment_arg
    from sim.errors import WrinklesInputError

    monkeypatch.chdir(tmp_path)
    write_json(tmp_path / "skirt.json", floor_skirt_spec())

    def args(*params):
        return argparse.Namespace(garment="skirt.json", material="cotton", material_param=[],
                                  garment_param=list(params), resolution="0.1", quiet=True)

    check_garment_spec(args())  # --resolution applies to a pattern file
    body = default_body()
    g = load_garment_arg(args(), body, None)
    assert g.category == "garmentcode" and g.name == "skirt"
    assert g.panel_names == ("skirt_front", "skirt_back") and set(g.attachments) == {"hem", "waistband"}
    assert 1.0 < g.face_layers.max() <= 3.0  # faces along the openings: part of each in the hem
    assert (load_garment_arg(args("hem_width=0"), body, None).face_layers == 1.0).all()
    with pytest.raises(WrinklesInputError, match="--garment-param length.*hem_width and hem_layers only"):
        load_garment_arg(args("length=0.5"), body, None)


def test_simulate_refuses_a_bad_pattern_file_before_loading_anything(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p.json").write_text("[1, 2]")
    code = main(["simulate", "--garment", "p.json", "--out", "sim/p.usda", "--device", "cpu", "--quiet"])
    assert_one_line_error(capsys, code, "p.json: GarmentCode pattern: no 'pattern' object")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.json"]


# ----------------------------------------------------------------------------- help


def test_help_explains_the_pattern_options(capsys):
    with pytest.raises(SystemExit) as e:
        main(["garments", "--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for words in ("--pattern-out FILE", "--pattern FILE.json", "--pattern-frame {auto,floor,body}",
                  "--seam-allowance M", "--export NAME, --garment NAME", "GarmentCode pattern specification",
                  "full size in millimetres", "Without --out nothing is sewn",
                  "wrinkles garments --garment t_shirt --pattern-out tee.svg"):
        assert words in text, words
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "GarmentCode pattern file (.json) to sew" in text
    assert "pattern file (.json) is sewn on the body at --resolution" in text
