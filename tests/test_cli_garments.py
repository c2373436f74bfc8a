"""``wrinkles garments``: the listing, the JSON catalogue, exports that load back, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipelines.cli import main
from pipelines.garment_files import load_garment_file
from sim.garments import MATERIALS, TEMPLATES
from tests.test_cli import assert_user_error, run_cli


def test_lists_every_template_with_counts_and_attachments(capsys):
    assert main(["garments"]) == 0
    out = capsys.readouterr().out
    for name, t in TEMPLATES.items():
        line = next(ln for ln in out.splitlines() if ln.startswith(name + " "))
        assert f"{t.vertices[0]:,} v" in line and f"{t.vertices[1]:,} v" in line
        assert ", ".join(t.attachments) in line
    for m in MATERIALS:
        assert m in out


def test_params_and_json(capsys):
    assert main(["garments", "--params"]) == 0
    out = capsys.readouterr().out
    assert "--garment-param sleeve_length=0.2 [m]" in out and "--garment-param waist_drop=0.02 [m]" in out
    assert "--garment-param hood=no  a two-piece hood sewn into the neckline (no | yes)" in out
    assert main(["garments", "--json"]) == 0
    cat = json.loads(capsys.readouterr().out)
    assert [t["name"] for t in cat["templates"]] == list(TEMPLATES)
    for t in cat["templates"]:
        assert t["resolutions"]["fine"]["edge_m"] < t["resolutions"]["coarse"]["edge_m"]
        for p in t["parameters"]:  # every parameter documented: a unit (or its choices) and a meaning
            assert p["unit"] in ("m", "-", "choice") and len(p["meaning"]) > 10, p
            if p["unit"] == "choice":  # the meaning ends with the choices, the default among them
                assert p["default"] in p["meaning"].rsplit("(", 1)[1].rstrip(")").split(" | "), p
    assert {m["name"] for m in cat["materials"]} == set(MATERIALS)
    # every numeric material field has its unit, in the JSON and in the table --params prints
    numeric = {k for k, v in cat["materials"][0].items() if isinstance(v, float)}
    assert set(cat["material_units"]) == numeric
    main(["garments", "--params"])
    table = capsys.readouterr().out
    for field, unit in cat["material_units"].items():
        assert f"{field} [{unit}]" in table
    # each parameter's line is its description as written, without markup or code names
    from sim.garments.drafting.tops import TopDesign
    from sim.garments.parameters import parameter_specs

    for word in ("``", "armhole_inset", "sim.garments"):
        assert word not in table
    assert parameter_specs(TopDesign)["neck_depth"].description in table


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".glb", ".usda"])
def test_export_loads_back_with_the_same_mesh_and_uvs(tmp_path, capsys, suffix):
    from sim.bodies import load_body
    from sim.bodies.default import parse_shape
    from sim.garments import make_garment

    out, png = tmp_path / f"skirt{suffix}", tmp_path / "skirt_uv.png"
    args = ["garments", "--export", "flared-skirt", "--out", str(out), "--resolution", "0.04",
            "--shape", "weight=0.7", "--garment-param", "length=0.5"]
    assert main(args + (["--uv-image", str(png), "--uv-image-size", "256"] if suffix == ".obj" else [])) == 0
    assert "flared_skirt:" in capsys.readouterr().out
    want = make_garment("flared_skirt", load_body(), parse_shape("weight=0.7"), resolution=0.04, length=0.5)
    g = load_garment_file(out)
    assert g.num_vertices == want.num_vertices and g.num_faces == want.num_faces
    assert len(g.uvs) == len(want.uvs)  # seams kept
    np.testing.assert_allclose(g.rest_vertices[g.faces], want.rest_vertices[want.faces], atol=1e-6)
    np.testing.assert_allclose(g.uvs[g.uv_faces], want.uvs[want.uv_faces], atol=1e-6)
    if suffix == ".usda":
        from usd_io import validate_stage

        assert validate_stage(out) == []
    if suffix == ".obj":
        from PIL import Image

        with Image.open(png) as im:
            assert im.size == (256, 256)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [out.name] + ([png.name] if suffix == ".obj" else []))  # no temporaries left


@pytest.mark.parametrize("args, needles", [
    (["--export", "cape", "--out", "x.obj"], ["unknown template", "t_shirt"]),
    (["--export", "t_shirt"], ["--export needs --out"]),
    (["--export", "t_shirt", "--out", "x.stl"], ["x.stl", "--out must end in"]),
    (["--out", "x.obj"], ["need --export"]),
    (["--body-out", "b.obj"], ["need --export"]),
    (["--export", "t_shirt", "--out", "x.obj", "--body-out", "b.usda"], ["b.usda", "--body-out must end in"]),
    (["--export", "t_shirt", "--out", "x.obj", "--garment-param", "lenght=0.4"],
     ["unknown parameter", "length"]),
    (["--export", "t_shirt", "--out", "x.obj", "--param", "lenght=0.4"], ["unknown parameter", "length"]),
    (["--export", "t_shirt", "--out", "x.obj", "--resolution", "ultra"], ["--resolution 'ultra'"]),
    (["--export", "t_shirt", "--out", "x.obj", "--material", "tweed"], ["unknown material", "denim"]),
])
def test_bad_input_is_one_line_exit_2_no_output(tmp_path, capsys, monkeypatch, args, needles):
    monkeypatch.chdir(tmp_path)
    code = main(["garments", *args])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and err.startswith("wrinkles garments: error:"), err
    for n in needles:
        assert n in err, err
    assert not list(tmp_path.iterdir())


class _Boom(RuntimeError):
    pass


def test_failure_midway_leaves_nothing(tmp_path, monkeypatch):
    from pipelines import garments_cmd

    def boom(*a, **k):
        raise _Boom("drawing failed")

    monkeypatch.setattr(garments_cmd, "draw_uv_layout", boom)
    with pytest.raises(_Boom):
        main(["garments", "--export", "shorts", "--resolution", "0.05", "--out", str(tmp_path / "s.obj"),
              "--uv-image", str(tmp_path / "s.png")])
    assert not list(tmp_path.iterdir())  # the OBJ written before the failure is gone too


def test_cli_process_user_error(tmp_path):
    proc = run_cli("garments", "--export", "dress", "--out", "x.fbx", cwd=tmp_path)
    assert_user_error(proc, "x.fbx", "--out")
    assert not list(tmp_path.iterdir())


@pytest.mark.slow
def test_a_garment_file_must_be_around_the_rest_body_in_metres(tmp_path, capsys):
    """``--body-out`` writes the rest body in the garment's frame; a garment exported there is
    simulated as it is, the same file moved 1.2 m up (modelled around a body standing on the
    floor, as the output stages show it) or in centimetres is refused in one line, exit 2,
    before any simulation (``check_garment_on_body``)."""
    import trimesh

    from sim.bodies import load_body
    from sim.bodies.default import parse_shape
    from sim.errors import WrinklesInputError
    from sim.garments.io import check_garment_on_body

    tee, body_file = tmp_path / "tee.obj", tmp_path / "body.obj"
    assert main(["garments", "--export", "t_shirt", "--out", str(tee), "--resolution", "0.05",
                 "--shape", "height=0.6", "--body-out", str(body_file)]) == 0
    body = load_body()
    rest = body.rest_mesh(parse_shape("height=0.6"))
    written = trimesh.load(body_file, process=False)
    np.testing.assert_allclose(written.vertices, rest, atol=1e-5)
    assert len(written.faces) == len(body.faces)
    g = load_garment_file(tee)
    check_garment_on_body(g, rest, tee)  # the export itself fits
    from dataclasses import replace

    up = replace(g, rest_vertices=g.rest_vertices + np.float32([0.0, 1.2, 0.0]))
    with pytest.raises(WrinklesInputError, match=r"up.obj: the garment is not around the body: 100% of its"):
        check_garment_on_body(up, rest, "up.obj")
    # every template lifted into the floor-standing frame, long ones too (a dress kept half its
    # vertices in the body's tall box when lifted)
    from sim.garments import make_garment

    lift = np.float32([0.0, -rest[:, 1].min(), 0.0])
    for name in TEMPLATES:
        fitted = make_garment(name, body, parse_shape("height=0.6"), resolution=0.05)
        check_garment_on_body(fitted, rest, name)
        with pytest.raises(WrinklesInputError, match="not around the body"):
            check_garment_on_body(replace(fitted, rest_vertices=fitted.rest_vertices + lift), rest, name)
    cm = replace(g, rest_vertices=g.rest_vertices * np.float32(100.0))
    with pytest.raises(WrinklesInputError, match=r"cm.obj: the garment is \S+ m across.*in centimetres"):
        check_garment_on_body(cm, rest, "cm.obj")
    # through the command: one line, exit 2, nothing written
    lines = tee.read_text().splitlines()
    moved = [f"v {float(a):.6f} {float(b) + 1.2:.6f} {float(c):.6f}" if ln.startswith("v ") else ln
             for ln in lines for a, b, c in [ln.split()[1:4] if ln.startswith("v ") else (0, 0, 0)]]
    (tmp_path / "up.obj").write_text("\n".join(moved) + "\n")
    capsys.readouterr()
    out = tmp_path / "sim" / "up.usda"
    assert main(["simulate", "--garment", str(tmp_path / "up.obj"), "--out", str(out), "--device", "cpu",
                 "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not around the body" in err, err
    assert not (tmp_path / "sim").exists()


def test_a_garment_file_keeps_its_own_mesh(tmp_path, capsys):
    """--resolution is a template's: with a garment file it is an error, not ignored."""
    tee = tmp_path / "tee.obj"
    assert main(["garments", "--export", "t_shirt", "--out", str(tee), "--resolution", "0.05"]) == 0
    capsys.readouterr()
    out = tmp_path / "sim" / "tee.usda"
    assert main(["simulate", "--garment", str(tee), "--resolution", "fine", "--out", str(out),
                 "--device", "cpu", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--resolution applies to templates" in err and str(tee) in err and len(err.splitlines()) == 1
    assert not (tmp_path / "sim").exists()
