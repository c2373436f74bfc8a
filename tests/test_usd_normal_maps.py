"""Garment normal maps in USD: per-frame PNGs beside the stage, a UsdUVTexture on the material's
normal input that decodes them back to the maps, atomic writes, input checks, and the UV
winding that makes our tangent frame the one renderers use."""

from __future__ import annotations

import dataclasses
import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdShade

from sim.errors import WrinklesInputError
from sim.garments.templates import TEMPLATES
from usd_io import GarmentTrack, validation_report, write_stage
from usd_io.textures import (
    decode_normal_map,
    encode_normal_map,
    fill_outside_charts,
    normal_texture_files,
    png_bytes,
    read_png,
    write_png,
)

T = 2
H, W = 12, 16
START = 5


def quad_garment(maps: np.ndarray | None) -> GarmentTrack:
    """A unit square of two triangles (UVs = x, y), T frames, with ``maps``."""
    verts = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    faces = np.int32([[0, 1, 2], [2, 1, 3]])
    return GarmentTrack("shirt", np.repeat(verts[None], len(maps) if maps is not None else T, 0), faces,
                        uvs=verts[:, :2].copy(), normal_maps=maps)


def random_maps(seed: int = 0) -> np.ndarray:
    """T unit-vector maps (H, W) with a chart in the middle and zeros around it."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(T, H, W, 3)).astype(np.float32)
    n[..., 2] = np.abs(n[..., 2]) + 0.5
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[:, :2], n[:, :, -3:] = 0.0, 0.0
    return n


def normal_texture(stage: Usd.Stage, mesh_path: str) -> UsdShade.Shader:
    """The shader feeding the normal input of the material bound to a mesh."""
    material, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(mesh_path)).ComputeBoundMaterial()
    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetShaderId() == "UsdPreviewSurface"
    normal = surface.GetInput("normal")
    assert normal.HasConnectedSource()
    source, output, _ = normal.GetConnectedSource()
    assert output == "rgb"
    return UsdShade.Shader(source.GetPrim())


@pytest.mark.parametrize("bits", [16, 8])
def test_maps_come_back_through_the_texture(tmp_path: Path, bits: int) -> None:
    maps = random_maps()
    path = write_stage(tmp_path / "maps.usda", body=None, fps=30.0, garments=[quad_garment(maps)],
                       start_time_code=START, normal_map_bits=bits)
    stage = Usd.Stage.Open(str(path))
    tex = normal_texture(stage, "/World/Garments/shirt")
    assert tex.GetShaderId() == "UsdUVTexture"
    assert tex.GetInput("sourceColorSpace").Get() == "raw"
    assert tex.GetInput("scale").GetTypeName() == tex.GetInput("bias").GetTypeName() == "float4"
    scale, bias = np.array(tex.GetInput("scale").Get()), np.array(tex.GetInput("bias").Get())
    np.testing.assert_array_equal(scale, [2, 2, 2, 1])
    np.testing.assert_array_equal(bias, [-1, -1, -1, 0])
    # the st reader reads the mesh's UV primvar
    reader, _, _ = tex.GetInput("st").GetConnectedSource()
    reader = UsdShade.Shader(reader.GetPrim())
    assert reader.GetShaderId() == "UsdPrimvarReader_float2"
    varname = reader.GetInput("varname").Get()
    assert UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Garments/shirt")).GetPrimvar(varname).HasValue()
    # one image per frame, at the frame's time code; the first also as the default
    file_attr = tex.GetInput("file").GetAttr()
    assert file_attr.GetTimeSamples() == [START, START + 1]
    assert file_attr.Get().path == file_attr.Get(START).path
    top = (1 << bits) - 1
    for k, t in enumerate(file_attr.GetTimeSamples()):
        image = Path(file_attr.Get(t).resolvedPath)
        assert image == tmp_path / "maps_normals" / f"shirt_{k:04d}.png" and image.is_file()
        pixels = read_png(image)
        assert pixels.dtype == (np.uint16 if bits == 16 else np.uint8) and pixels.shape == (H, W, 3)
        decoded = pixels / top * scale[:3] + bias[:3]  # what a renderer does with the texel
        inside = np.linalg.norm(maps[k], axis=-1) > 0
        np.testing.assert_allclose(decoded[inside], maps[k][inside], atol=1.0 / top + 1e-6)
        # outside the chart: the nearest chart texel's normal (no grey seams when filtering)
        np.testing.assert_allclose(np.linalg.norm(decoded, axis=-1), 1.0, atol=3.0 / top)
    assert validation_report(path).errors == []
    assert normal_texture_files(stage, "/World/Looks/shirtMaterial")[1][0] == START + 1


def test_a_bad_maps_shape_is_one_line_and_writes_nothing(tmp_path: Path) -> None:
    g = quad_garment(random_maps())
    shape = r"garment 'shirt' normal_maps must have shape \(2, H, W, 3\)"
    for bad in (g.normal_maps[:1], g.normal_maps[..., :2], g.normal_maps[0]):
        with pytest.raises(WrinklesInputError, match=shape) as err:
            write_stage(tmp_path / "bad.usdc", body=None, fps=30.0,
                        garments=[dataclasses.replace(g, normal_maps=bad)])
        assert "\n" not in str(err.value)
    with pytest.raises(WrinklesInputError, match="no uvs"):
        write_stage(tmp_path / "bad.usdc", body=None, fps=30.0,
                    garments=[dataclasses.replace(g, uvs=None)])
    with pytest.raises(WrinklesInputError, match="unit vectors"):
        write_stage(tmp_path / "bad.usdc", body=None, fps=30.0,
                    garments=[dataclasses.replace(g, normal_maps=g.normal_maps * 2)])
    with pytest.raises(WrinklesInputError, match="bit depth"):
        write_stage(tmp_path / "bad.usdc", body=None, fps=30.0, garments=[g], normal_map_bits=12)
    assert list(tmp_path.iterdir()) == []


def test_a_failed_write_keeps_the_old_stage_and_maps(tmp_path: Path) -> None:
    old = random_maps(1)
    path = write_stage(tmp_path / "a.usdc", body=None, fps=30.0, garments=[quad_garment(old)])
    before = {p.name: p.read_bytes() for p in (tmp_path / "a_normals").iterdir()}
    stage_bytes = path.read_bytes()

    def fail(done: int, total: int) -> None:
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_stage(path, body=None, fps=30.0, garments=[quad_garment(random_maps(2))], progress=fail)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.usdc", "a_normals"]
    assert path.read_bytes() == stage_bytes
    assert {p.name: p.read_bytes() for p in (tmp_path / "a_normals").iterdir()} == before
    new = random_maps(3)
    write_stage(path, body=None, fps=30.0, garments=[quad_garment(new)])
    got = decode_normal_map(read_png(tmp_path / "a_normals" / "shirt_0001.png"))
    inside = np.linalg.norm(new[1], axis=-1) > 0
    np.testing.assert_allclose(got[inside], new[1][inside], atol=2e-5)


def test_usdz_packages_the_maps(tmp_path: Path) -> None:
    maps = random_maps()
    path = write_stage(tmp_path / "a.usdz", body=None, fps=30.0, garments=[quad_garment(maps)])
    assert [p.name for p in tmp_path.iterdir()] == ["a.usdz"]
    with zipfile.ZipFile(path) as z:
        names = z.namelist()
        assert {"a_normals/shirt_0000.png", "a_normals/shirt_0001.png"} <= set(names)
        pixels = read_png_bytes(z.read("a_normals/shirt_0001.png"), tmp_path)
    files = normal_texture_files(Usd.Stage.Open(str(path)), "/World/Looks/shirtMaterial")
    assert [f.endswith(f"[a_normals/shirt_000{k}.png]") for k, (_, f) in enumerate(files)] == [True, True]
    np.testing.assert_array_equal(pixels, encode_normal_map(maps[1], 16))


def read_png_bytes(data: bytes, folder: Path) -> np.ndarray:
    path = folder / "read.png"
    path.write_bytes(data)
    pixels = read_png(path)
    path.unlink()
    return pixels


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_png_round_trip(tmp_path: Path, dtype, channels: int) -> None:
    rng = np.random.default_rng(channels)
    smooth = np.cumsum(rng.integers(0, 4, size=(9, 13, channels)), axis=1)  # every filter type wins somewhere
    pixels = np.where(rng.random((9, 13, channels)) < 0.3, rng.integers(0, 200, (9, 13, channels)), smooth)
    pixels = (pixels * (257 if dtype == np.uint16 else 1)).astype(dtype)
    path = write_png(tmp_path / "p.png", pixels)
    back = read_png(path)
    assert back.dtype == dtype
    np.testing.assert_array_equal(back, pixels)


def test_pngs_agree_with_pillow(tmp_path: Path) -> None:
    """Pillow reads ours (8-bit colour and 16-bit grey, which it keeps whole) and we read its
    (optimised: any filter type)."""
    image = pytest.importorskip("PIL.Image")
    rng = np.random.default_rng(4)
    rgb = np.cumsum(rng.integers(0, 3, size=(20, 30, 3)), axis=0).astype(np.uint8)
    grey = (np.arange(20 * 30).reshape(20, 30) * 97).astype(np.uint16)
    for pixels in (rgb, grey):
        buf = io.BytesIO(png_bytes(pixels))
        np.testing.assert_array_equal(np.asarray(image.open(buf)), pixels)
    image.fromarray(rgb).save(tmp_path / "pil.png", optimize=True)
    np.testing.assert_array_equal(read_png(tmp_path / "pil.png"), rgb)


def test_outside_the_charts_is_the_nearest_chart_normal() -> None:
    n = np.zeros((4, 5, 3), np.float32)
    n[1, 1] = [0.6, 0.0, 0.8]
    n[2, 4] = [0.0, 0.6, 0.8]
    out = fill_outside_charts(n)
    np.testing.assert_array_equal(out[[0, 1, 3], [0, 1, 4]], n[[1, 1, 2], [1, 1, 4]])
    up = np.tile([0.0, 0.0, 1.0], (2, 2, 1))
    np.testing.assert_array_equal(fill_outside_charts(np.zeros((2, 2, 3))), up)
    np.testing.assert_allclose(decode_normal_map(encode_normal_map(np.zeros((2, 2, 3)), 8)), up, atol=1 / 254)


@pytest.mark.slow  # sewing a template takes ~15 s on 2 cores unless the garment cache has it
@pytest.mark.parametrize("category", sorted(TEMPLATES))
def test_template_uvs_wind_like_their_faces(category: str) -> None:
    """Every face's UV triangle winds counter-clockwise, as its vertices seen from the outside:
    dP/du x dP/dv points along the normal, so MikkTSpace's bitangent sign is +1 and our
    n x t1 is its bitangent (``usd_io.textures``: no green-channel flip)."""
    from sim.bodies import load_body
    from sim.garments.templates import make_garment

    g = make_garment(category, load_body(), resolution="coarse")
    q = np.asarray(g.uvs, np.float64)[g.uv_faces]
    d1, d2 = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]
    assert (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0] > 0).all()



# ----------------------------------------------------------------- wrinkles animate --method deepwrinkles
@pytest.mark.parametrize("args, says", [
    (["--method", "deepwrinkles", "--garment", "skirt"], "no shipped DeepWrinkles model for straight_skirt"),
    (["--model", "m.pt"], "--model applies to --method deepwrinkles"),
    (["--surface", "fine"], "--surface applies to --method deepwrinkles"),
    (["--method", "deepwrinkles", "--model", "m.pt", "--data", "d", "--steps", "3"],
     "--steps applies to --method diffusion"),
    (["--method", "deepwrinkles", "--model", "missing.pt", "--data", "d"], "missing.pt: no such model file"),
])
def test_animate_deepwrinkles_refuses_bad_options(tmp_path: Path, capsys, args: list[str], says: str) -> None:
    from pipelines.cli import main

    out = tmp_path / "o" / "a.usdc"
    code = main(["animate", *args, "--motion", "walk", "--out", str(out), "-q", "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and says in err[0], err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_animate_deepwrinkles_writes_the_global_shape_with_its_maps(sample_dataset, tmp_path: Path) -> None:
    """A DeepWrinkles model trained briefly on the sample's t-shirts animates a new motion on a
    new body shape: the stage holds the body and the garment on the fine mesh, with one 16-bit
    normal map per frame on its material (``--surface global``), or the fine garment without
    maps (``--surface fine``); the preview sheet is drawn."""
    from pipelines.cli import main

    settings = ("garments=['t_shirt']", "source='simulation'", "resolution=32", "filters=4", "hidden=16",
                "layers=1", "components=16")
    train = ["train", "deepwrinkles", "--data", str(sample_dataset), "--out", str(tmp_path / "dw"),
             "--steps", "2", "--batch-size", "2", "-q", "--device", "cpu"]
    assert main([*train, *[a for kv in settings for a in ("--set", f"model.{kv}")]]) == 0
    model = tmp_path / "dw" / "checkpoints" / "last.pt"
    common = ["animate", "--method", "deepwrinkles", "--model", str(model),
              "--motion", "walk", "--duration", "0.3", "--shape", "height=0.5", "-q", "--device", "cpu"]
    out = tmp_path / "anim" / "dw.usda"
    data = ["--data", str(sample_dataset)]
    assert main([*common, *data, "--out", str(out), "--sheet", str(tmp_path / "anim" / "dw.png")]) == 0
    stage = Usd.Stage.Open(str(out))
    shirt = stage.GetPrimAtPath("/World/Garments/t_shirt")
    assert shirt and stage.GetPrimAtPath("/World/BodyRig/Body")
    T = int(stage.GetEndTimeCode() - stage.GetStartTimeCode()) + 1
    points = np.asarray(UsdGeom.Mesh(shirt).GetPointsAttr().Get(0))
    files = normal_texture_files(stage, "/World/Looks/t_shirtMaterial")
    assert len(files) == T == 9 and all(Path(f).is_file() for _, f in files)
    pixels = read_png(files[-1][1])
    assert pixels.dtype == np.uint16 and pixels.shape == (32, 32, 3)
    np.testing.assert_allclose(np.linalg.norm(decode_normal_map(pixels), axis=-1), 1.0, atol=1e-3)
    assert validation_report(out).errors == []
    meta = json.loads((tmp_path / "anim" / "dw.animate.json").read_text())
    assert meta["surface"] == "global" and meta["method"] == "deepwrinkles"
    assert (tmp_path / "anim" / "dw.png").stat().st_size > 1000
    fine = tmp_path / "anim" / "fine.usdc"  # the garment the checkpoint keeps: no --data
    assert main([*common, "--out", str(fine), "--surface", "fine"]) == 0
    stage = Usd.Stage.Open(str(fine))
    fine_shirt = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Garments/t_shirt"))
    fine_points = np.asarray(fine_shirt.GetPointsAttr().Get(0))
    assert fine_points.shape == points.shape and np.abs(fine_points - points).max() > 1e-4
    assert normal_texture_files(stage, "/World/Looks/t_shirtMaterial") is None
    assert sorted(p.name for p in (tmp_path / "anim").iterdir()) == [
        "dw.animate.json", "dw.png", "dw.usda", "dw_normals", "fine.animate.json", "fine.usdc"]
