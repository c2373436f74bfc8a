"""USD out and back in: exact round trip, stage metadata, atomic writes, validation."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from pxr import Sdf, Usd, UsdGeom, UsdShade

from sim.errors import WrinklesInputError
from sim.types import BodyFrames
from usd_io import (
    BODY_PATH,
    GarmentTrack,
    read_stage,
    validate_stage,
    validation_report,
    write_stage,
)

FPS = 30.0
T = 5
SEED = 7


def tube(n_around: int, n_rings: int, radius: float, height: float) -> tuple:
    """An open cylinder with a UV seam along x = radius.

    Returns:
        vertices (n_rings * n_around, 3) [m], faces (F, 3), uvs ((n_around + 1) * n_rings, 2),
        uv_faces (F, 3): the seam column is duplicated in UV space, so uv_faces != faces.
    """
    ang = np.arange(n_around) * (2 * np.pi / n_around)
    ys = np.linspace(0.0, height, n_rings)
    verts = np.stack([np.repeat(np.cos(ang)[None], n_rings, 0) * radius,
                      np.repeat(ys[:, None], n_around, 1),
                      np.repeat(np.sin(ang)[None], n_rings, 0) * radius], axis=-1)
    uvs = np.stack(np.meshgrid(np.arange(n_around + 1) / n_around, ys / height), -1)
    faces, uv_faces = [], []
    for r in range(n_rings - 1):
        for j in range(n_around):
            a, b = r * n_around + j, r * n_around + (j + 1) % n_around
            c, d = a + n_around, b + n_around
            ua, ub = r * (n_around + 1) + j, r * (n_around + 1) + j + 1
            uc, ud = ua + n_around + 1, ub + n_around + 1
            faces += [(a, c, b), (b, c, d)]
            uv_faces += [(ua, uc, ub), (ub, uc, ud)]
    return (verts.reshape(-1, 3).astype(np.float32), np.asarray(faces, np.int32),
            uvs.reshape(-1, 2).astype(np.float32), np.asarray(uv_faces, np.int32))


@pytest.fixture(scope="module")
def scene() -> tuple[BodyFrames, GarmentTrack]:
    """A deforming icosphere "body" (642 vertices) and a seamed tube "garment", T frames."""
    rng = np.random.default_rng(SEED)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    rest = np.asarray(sphere.vertices, np.float32) + np.float32([0.0, 1.0, 0.0])
    wobble = rng.normal(scale=0.01, size=(T, *rest.shape)).astype(np.float32)
    t = np.arange(T, dtype=np.float32)[:, None, None]
    verts = rest[None] * (1.0 + 0.05 * t) + wobble
    joints = np.stack([np.tile([0.0, 1.0, 0.0], (T, 1)),
                       np.stack([0.1 * t[:, 0, 0], np.full(T, 1.3), np.zeros(T)], 1)],
                      axis=1).astype(np.float32)
    body = BodyFrames(vertices=verts, joints=joints,
                      transforms=np.tile(np.eye(4, dtype=np.float32), (T, 2, 1, 1)),
                      faces=np.asarray(sphere.faces, np.int32))
    gv, gf, uvs, uv_faces = tube(24, 6, 0.35, 0.5)
    g_verts = (gv[None] + np.float32([0.0, 0.8, 0.0])
               + rng.normal(scale=0.005, size=(T, *gv.shape))).astype(np.float32)
    normals = np.zeros_like(g_verts)
    normals[..., 0], normals[..., 2] = gv[:, 0] / 0.35, gv[:, 2] / 0.35
    layers = np.ones(len(gf), np.float32)
    layers[: len(gf) // 5] = 3.0  # a hem band
    garment = GarmentTrack("t-shirt", g_verts, gf, uvs=uvs, uv_faces=uv_faces, normals=normals,
                           color=(0.1, 0.4, 0.2), face_layers=layers)
    return body, garment


def _write(path: Path, scene, **kw) -> Path:
    body, garment = scene
    return write_stage(path, body=body, fps=FPS, garments=[garment],
                       metadata={"command": "wrinkles animate", "config": {"seed": SEED},
                                 "versions": {"wrinkles": "0.1.0"}}, **kw)


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usd", ".usdz"])
def test_round_trip_is_exact(tmp_path: Path, scene, suffix: str) -> None:
    body, garment = scene
    path = _write(tmp_path / f"anim{suffix}", scene)
    assert path.is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temp leftovers
    data = read_stage(path)
    assert data.fps == FPS and data.frames_per_second == FPS
    assert data.up_axis == "Y" and data.meters_per_unit == 1.0
    assert (data.start_time_code, data.end_time_code) == (0.0, T - 1.0)
    np.testing.assert_array_equal(data.time_codes, np.arange(T))
    assert list(data.meshes) == [BODY_PATH, "/World/Garments/t_shirt"]
    assert data.body.points.dtype == np.float32
    np.testing.assert_array_equal(data.body.points, body.vertices)
    np.testing.assert_array_equal(data.body.faces, body.faces)
    assert data.body.uvs is None
    np.testing.assert_array_equal(data.joints, body.joints)
    g = data.garments["t_shirt"]
    np.testing.assert_array_equal(g.points, garment.vertices)
    np.testing.assert_array_equal(g.faces, garment.faces)
    np.testing.assert_array_equal(g.uvs, garment.uvs)
    np.testing.assert_array_equal(g.uv_faces, garment.uv_faces)
    assert (g.uv_faces != g.faces).any()  # the seam survived
    np.testing.assert_array_equal(g.normals, garment.normals)
    np.testing.assert_array_equal(g.face_layers, garment.face_layers)
    assert data.body.face_layers is None
    assert data.metadata == {"command": "wrinkles animate", "config": {"seed": SEED},
                             "versions": {"wrinkles": "0.1.0"}}


def test_stage_layout(tmp_path: Path, scene) -> None:
    """What other tools rely on: metadata, static topology, time-sampled points and extent."""
    body, _ = scene
    stage = Usd.Stage.Open(str(_write(tmp_path / "anim.usda", scene)))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == FPS and stage.GetFramesPerSecond() == FPS
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/World")
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(BODY_PATH))
    assert mesh.GetPointsAttr().GetNumTimeSamples() == T
    assert mesh.GetExtentAttr().GetNumTimeSamples() == T
    assert mesh.GetFaceVertexIndicesAttr().GetNumTimeSamples() == 0
    assert mesh.GetFaceVertexCountsAttr().GetNumTimeSamples() == 0
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    assert mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.rightHanded
    ext = np.asarray(mesh.GetExtentAttr().Get(Usd.TimeCode(2)))
    np.testing.assert_array_equal(ext, [body.vertices[2].min(0), body.vertices[2].max(0)])
    mat, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
    assert mat.GetPath() == Sdf.Path("/World/Looks/BodyMaterial")
    shader = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/BodyMaterial/PreviewSurface"))
    assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
    garment = stage.GetPrimAtPath("/World/Garments/t_shirt")
    st = UsdGeom.PrimvarsAPI(garment).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying and st.IsIndexed()
    assert garment.GetCustomDataByKey("wrinkles:name") == "t-shirt"
    layers = UsdGeom.PrimvarsAPI(garment).GetPrimvar("fabricLayers")
    assert layers.GetInterpolation() == UsdGeom.Tokens.uniform  # one value per face
    assert layers.GetTypeName() == Sdf.ValueTypeNames.FloatArray
    joints = UsdGeom.Points(stage.GetPrimAtPath("/World/BodyJoints"))
    assert joints.GetPurposeAttr().Get() == UsdGeom.Tokens.guide
    meta = json.loads(stage.GetRootLayer().customLayerData["wrinkles:metadata"])
    assert meta["command"] == "wrinkles animate"


def test_progress_reports_each_frame(tmp_path: Path, scene) -> None:
    calls: list[tuple[int, int]] = []
    _write(tmp_path / "anim.usdc", scene, progress=lambda k, n: calls.append((k, n)))
    assert calls == [(k, T) for k in range(1, T + 1)]


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usdz"])
def test_failed_write_leaves_nothing(tmp_path: Path, scene, suffix: str) -> None:
    def fail(k: int, n: int) -> None:
        if k == 3:
            raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError, match="disk on fire"):
        _write(tmp_path / f"anim{suffix}", scene, progress=fail)
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_previous_file(tmp_path: Path, scene) -> None:
    path = _write(tmp_path / "anim.usdc", scene)
    before = path.read_bytes()

    def fail(k: int, n: int) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _write(path, scene, progress=fail)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["anim.usdc"]


def test_garments_only_and_start_time(tmp_path: Path, scene) -> None:
    _, garment = scene
    path = write_stage(tmp_path / "g.usdc", body=None, fps=24.0, garments=[garment],
                       start_time_code=1)
    with pytest.raises(WrinklesInputError, match="no /World/Body"):
        read_stage(path)
    data = read_stage(path, require_body=False)
    np.testing.assert_array_equal(data.time_codes, np.arange(1, T + 1))
    np.testing.assert_array_equal(data.garments["t_shirt"].points, garment.vertices)
    assert validate_stage(path) == []


def test_bad_inputs_are_rejected(tmp_path: Path, scene) -> None:
    body, garment = scene
    with pytest.raises(WrinklesInputError, match=r"anim\.obj.*unknown USD suffix"):
        write_stage(tmp_path / "anim.obj", body=body, fps=FPS)
    short = GarmentTrack("short", garment.vertices[:2], garment.faces)
    with pytest.raises(ValueError, match="same number of frames"):
        write_stage(tmp_path / "a.usdc", body=body, fps=FPS, garments=[short])
    nan = body.vertices.copy()
    nan[3, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN/inf values at frame 3"):
        write_stage(tmp_path / "a.usdc", body=BodyFrames(nan, body.joints, body.transforms,
                                                        body.faces), fps=FPS)
    with pytest.raises(ValueError, match="JSON"):
        write_stage(tmp_path / "a.usdc", body=body, fps=FPS, metadata={"x": object()})
    with pytest.raises(ValueError, match="unique"):
        write_stage(tmp_path / "a.usdc", body=body, fps=FPS, garments=[garment, garment])
    thin = dataclasses.replace(garment, face_layers=np.full(len(garment.faces), 0.5, np.float32))
    with pytest.raises(ValueError, match="face_layers must be"):
        write_stage(tmp_path / "a.usdc", body=body, fps=FPS, garments=[thin])
    assert list(tmp_path.iterdir()) == []


def test_fabric_layers_only_where_there_are_hems(tmp_path: Path, scene) -> None:
    """A garment without hems (all faces one layer, or none given) gets no ``fabricLayers``
    primvar; a quad mesh's per-polygon layers come back one per fan triangle."""
    body, garment = scene
    plain = dataclasses.replace(garment, face_layers=np.ones(len(garment.faces), np.float32))
    path = write_stage(tmp_path / "plain.usda", body=None, fps=FPS, garments=[plain])
    written = Usd.Stage.Open(str(path))  # held: a prim of a released stage is invalid
    prim = written.GetPrimAtPath("/World/Garments/t_shirt")
    assert not UsdGeom.PrimvarsAPI(prim).HasPrimvar("fabricLayers")
    assert read_stage(path, require_body=False).garments["t_shirt"].face_layers is None
    stage = Usd.Stage.CreateNew(str(tmp_path / "quads.usda"))
    mesh = UsdGeom.Mesh.Define(stage, "/World/Garments/quads")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([4, 4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3, 1, 4, 5, 2])
    pv = UsdGeom.PrimvarsAPI(mesh.GetPrim()).CreatePrimvar("fabricLayers", Sdf.ValueTypeNames.FloatArray,
                                                            UsdGeom.Tokens.uniform)
    pv.Set([1.0, 3.0])
    stage.GetRootLayer().Save()
    quads = read_stage(tmp_path / "quads.usda", require_body=False).garments["quads"]
    np.testing.assert_array_equal(quads.face_layers, [1.0, 1.0, 3.0, 3.0])


def test_read_errors_name_the_file(tmp_path: Path) -> None:
    missing = tmp_path / "missing.usdc"
    with pytest.raises(WrinklesInputError, match=r"missing\.usdc: USD file not found"):
        read_stage(missing)
    junk = tmp_path / "junk.usda"
    junk.write_text("this is not USD\n")
    with pytest.raises(WrinklesInputError, match=r"junk\.usda: not a readable USD file"):
        read_stage(junk)
    junk_c = tmp_path / "junk.usdc"
    junk_c.write_bytes(b"\x00\x01garbage" * 10)
    with pytest.raises(WrinklesInputError, match=r"junk\.usdc: not a readable USD file"):
        read_stage(junk_c)
    empty = tmp_path / "empty.usda"
    Usd.Stage.CreateNew(str(empty)).Save()
    with pytest.raises(WrinklesInputError, match=r"empty\.usda: no /World/Body or /World/BodyRig/Body mesh"):
        read_stage(empty)


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usdz"])
def test_our_stages_validate_clean(tmp_path: Path, scene, suffix: str) -> None:
    report = validation_report(_write(tmp_path / f"anim{suffix}", scene))
    assert report.errors == []
    assert report.warnings == []


def test_validation_catches_missing_stage_metadata(tmp_path: Path) -> None:
    path = tmp_path / "bare.usda"
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/World/Body")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    stage.Save()
    errors = "\n".join(validate_stage(path))
    assert "MissingUpAxisMetadata" in errors
    assert "MissingMetersPerUnitMetadata" in errors
    assert "MissingDefaultPrim" in errors


def test_validation_catches_bad_topology(tmp_path: Path, scene) -> None:
    path = _write(tmp_path / "anim.usda", scene)
    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(BODY_PATH))
    idx = np.array(mesh.GetFaceVertexIndicesAttr().Get())
    idx[5] = 10_000
    mesh.GetFaceVertexIndicesAttr().Set(idx.tolist())
    st = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Garments/t_shirt")).GetPrimvar("st")
    st.SetIndices(np.asarray(st.GetIndices())[:-3].tolist())
    stage.Save()
    errors = validate_stage(path)
    assert len(errors) == 2, errors
    assert "/World/Body" in errors[0] and "Out of range face vertex index 10000" in errors[0]
    assert "/World/Garments/t_shirt" in errors[1] and "face-varying indices" in errors[1]
    with pytest.raises(WrinklesInputError, match="out of range"):
        read_stage(path)
