"""Our USD stages import into Blender 4.5 with the right frames, positions and UVs; a body
written as a UsdSkel rig comes in as an armature with a skinned mesh posed as our LBS; a
garment's normal maps come in as an image texture through a tangent-space Normal Map node, in
the tangent frame we encode them in.

Runs tests/blender_import_check.py in Blender's Python (PyPI ``bpy``), found at
``$WRINKLES_BLENDER_PYTHON`` or ``.venv-blender/bin/python`` (make it with
scripts/setup-blender-venv.sh); skipped when neither exists.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sim.bodies import load_body
from sim.motions import procedural_motion
from sim.types import BodyFrames
from tests import smpl_synth
from usd_io import GarmentTrack, write_stage

ROOT = Path(__file__).resolve().parents[1]
CHECK_SCRIPT = ROOT / "tests" / "blender_import_check.py"
FPS = 30.0  # not Blender's default 24, so a silently ignored fps would show
START = 1
T = 4
SEED = 3
#: one Blender run takes ~1-2 s; the limit only guards against a hung interpreter.
TIMEOUT_S = 60


def blender_python() -> Path | None:
    """Blender's Python interpreter, or None when it is not installed."""
    env = os.environ.get("WRINKLES_BLENDER_PYTHON")
    path = Path(env) if env else ROOT / ".venv-blender" / "bin" / "python"
    return path if path.is_file() else None


def make_scene() -> tuple[BodyFrames, GarmentTrack]:
    """A deforming icosphere body and a waving sheet whose UVs are split at every corner."""
    rng = np.random.default_rng(SEED)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    rest = np.asarray(sphere.vertices, np.float32) + np.float32([0.0, 1.0, 0.0])
    t = np.arange(T, dtype=np.float32)[:, None, None]
    verts = (rest[None] * (1.0 + 0.1 * t) + np.float32([0.0, 0.0, 0.05]) * t
             + rng.normal(scale=0.01, size=(T, *rest.shape))).astype(np.float32)
    body = BodyFrames(vertices=verts, joints=verts[:, :3].copy(),
                      transforms=np.tile(np.eye(4, dtype=np.float32), (T, 3, 1, 1)),
                      faces=np.asarray(sphere.faces, np.int32))
    n = 6
    xs, zs = np.meshgrid(np.linspace(-0.3, 0.3, n), np.linspace(-0.3, 0.3, n))
    sheet = np.stack([xs, np.full_like(xs, 1.4), zs], -1).reshape(-1, 3).astype(np.float32)
    quads = [(r * n + c, (r + 1) * n + c, r * n + c + 1, (r + 1) * n + c + 1)
             for r in range(n - 1) for c in range(n - 1)]
    faces = np.asarray([f for a, b, c, d in quads for f in ((a, b, c), (c, b, d))], np.int32)
    wave = 0.05 * np.sin(3.0 * sheet[None, :, 0] + t[:, :, 0])
    g_verts = np.repeat(sheet[None], T, 0)
    g_verts[..., 1] += wave.astype(np.float32)
    uv_faces = np.arange(faces.size, dtype=np.int32).reshape(-1, 3)  # every corner its own UV
    uvs = (sheet[faces.reshape(-1)][:, [0, 2]] + 0.5
           + 0.01 * np.repeat(np.arange(len(faces)), 3)[:, None] / len(faces)).astype(np.float32)
    return body, GarmentTrack("sheet", g_verts, faces, uvs=uvs, uv_faces=uv_faces)


def run_check(tmp_path: Path, stage: Path, expected: dict) -> dict:
    """Run the check script on ``stage`` in Blender; its result (asserted free of problems)."""
    python = blender_python()
    if python is None:
        pytest.skip("Blender's Python not found: run scripts/setup-blender-venv.sh or set "
                    "WRINKLES_BLENDER_PYTHON")
    path = tmp_path / "expected.npz"
    np.savez(path, **expected)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    proc = subprocess.run([str(python), str(CHECK_SCRIPT), str(stage), str(path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("WRINKLES_CHECK_RESULT ")]
    assert lines, f"check script printed no result (rc {proc.returncode}):\n{proc.stderr[-3000:]}"
    res = json.loads(lines[-1].split(" ", 1)[1])
    assert res["problems"] == [], json.dumps(res, indent=1)
    assert proc.returncode == 0
    return res


@pytest.mark.parametrize("suffix", [".usdc", ".usda"])
def test_blender_imports_our_stage(tmp_path: Path, suffix: str) -> None:
    if blender_python() is None:
        pytest.skip("Blender's Python not found: run scripts/setup-blender-venv.sh or set "
                    "WRINKLES_BLENDER_PYTHON")
    body, garment = make_scene()
    stage = write_stage(tmp_path / f"anim{suffix}", body=body, fps=FPS, garments=[garment],
                        start_time_code=START)
    res = run_check(tmp_path, stage, {
        "fps": FPS, "start": START, "end": START + T - 1, "names": np.array(["Body", "sheet"]),
        "points__Body": body.vertices, "faces__Body": body.faces,
        "points__sheet": garment.vertices, "faces__sheet": garment.faces,
        "corner_uvs__sheet": garment.uvs[garment.uv_faces]})
    assert res["frame_range"] == [START, START + T - 1]
    assert res["fps_after_setting"] == pytest.approx(FPS)
    for name in ("Body", "sheet"):
        info = res["meshes"][name]
        assert "MESH_SEQUENCE_CACHE" in info["modifiers"]
        assert len(info["max_err_per_frame"]) == T
        assert max(info["max_err_per_frame"]) <= 1e-4
        assert info["first_last_max_diff"] > 1e-2
        assert info["topology_ok"]
    assert res["meshes"]["sheet"]["uv_max_err"] <= 1e-6


def posed_body(which: str, tmp_path: Path):
    """(model, betas, frames): the default body walking T frames, or a synthetic SMPL model
    (tests/smpl_synth.py, pose correctives) in random poses (rotations past 90 degrees)."""
    rng = np.random.default_rng(SEED)
    if which == "default":
        model = load_body()
        betas = np.zeros(model.num_betas, np.float32)
        betas[:2] = [0.6, -0.4]
        motion = procedural_motion("walk", duration=T / FPS, fps=FPS)
        return model, betas, model.pose_motion(motion, betas, device="cpu")
    model = load_body(smpl_synth.write_model(tmp_path, "smpl", "npz", seed=SEED))
    betas = rng.normal(size=4).astype(np.float32)
    poses = rng.normal(scale=1.0, size=(T, 24, 3)).astype(np.float32)
    trans = rng.normal(scale=0.3, size=(T, 3)).astype(np.float32)
    return model, betas, model.pose(betas, poses, trans, device="cpu")


@pytest.mark.parametrize("which", ["default", "correctives"])
def test_blender_imports_the_rig_as_an_armature(tmp_path: Path, which: str) -> None:
    """The body as a UsdSkel rig: an Armature object with a bone per joint, the body mesh with
    an Armature modifier, a vertex group per joint and a shape key per pose blend shape, posed
    by Blender at each frame as our LBS; the garment stays a time-sampled mesh."""
    if blender_python() is None:
        pytest.skip("Blender's Python not found: run scripts/setup-blender-venv.sh or set "
                    "WRINKLES_BLENDER_PYTHON")
    model, betas, frames = posed_body(which, tmp_path)
    _, garment = make_scene()
    stage = write_stage(tmp_path / "rig.usdc", body=frames, fps=FPS, garments=[garment],
                        start_time_code=START, rig=model.rig(betas))
    n_shapes = 0 if model.posedirs is None else 15 * (model.num_joints - 1)
    res = run_check(tmp_path, stage, {
        "fps": FPS, "start": START, "end": START + T - 1, "names": np.array(["Body", "sheet"]),
        "points__Body": frames.vertices, "faces__Body": frames.faces,
        "points__sheet": garment.vertices, "faces__sheet": garment.faces,
        "corner_uvs__sheet": garment.uvs[garment.uv_faces],
        "skinned": "Body", "joints": np.array(model.joint_names), "shape_keys": n_shapes})
    assert "Skeleton:ARMATURE" in res["objects"]
    skin = res["meshes"]["Body"]["skin"]
    assert skin["armature"] == "Skeleton:ARMATURE" and len(skin["bones"]) == 24
    assert skin["shape_keys"] == n_shapes
    assert "ARMATURE" in res["meshes"]["Body"]["modifiers"]
    assert "MESH_SEQUENCE_CACHE" not in res["meshes"]["Body"]["modifiers"]
    assert max(res["meshes"]["Body"]["max_err_per_frame"]) <= 1e-4
    assert res["meshes"]["Body"]["first_last_max_diff"] > 1e-2
    assert "MESH_SEQUENCE_CACHE" in res["meshes"]["sheet"]["modifiers"]


def normal_mapped_sheet() -> tuple[GarmentTrack, dict]:
    """A waving sheet whose UVs wind counter-clockwise seen from its normal (as every garment
    template's do), with T normal maps (32 x 24, a chart with zeros around it), and what Blender
    should see: the first map's pixels and our tangent frame at every face corner."""
    from sim.geometry.frames import SurfaceFrames, tangent_basis
    from usd_io.textures import encode_normal_map

    _, sheet = make_scene()
    verts, faces = sheet.vertices, sheet.faces
    x, z = verts[0, :, 0], verts[0, :, 2]
    uvs = np.stack([x + 0.5, 0.5 - z], axis=-1).astype(np.float32)  # dP/du x dP/dv along +y
    h, w = 32, 24
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    maps = np.zeros((T, h, w, 3), np.float32)
    for k in range(T):
        n = np.stack([0.4 * np.sin(cols / 3 + k), 0.3 * (rows / h - 0.5), np.ones_like(rows)], -1)
        maps[k] = n / np.linalg.norm(n, axis=-1, keepdims=True)
    maps[:, :3], maps[:, :, -2:] = 0.0, 0.0  # outside the chart
    track = dataclasses.replace(sheet, uvs=uvs, uv_faces=None, normal_maps=maps)
    basis = tangent_basis(SurfaceFrames(len(uvs), faces, uvs, faces, 1.0, device="cpu").frames(verts[0]))
    corner = basis[faces]  # (F, 3, 3 xyz, 3 columns)
    return track, {"normal_map__sheet": encode_normal_map(maps[0], 16) / 65535.0,
                   "tangents__sheet": corner[..., 0], "bitangents__sheet": corner[..., 1]}


def test_blender_imports_the_normal_map(tmp_path: Path) -> None:
    """Blender turns the garment's UsdUVTexture into an Image Texture (our first frame's PNG,
    non-colour) -> Normal Map (tangent space) -> Principled BSDF Normal, and its MikkTSpace
    tangent frame on our UVs is ours (green = +v, no channel flip)."""
    if blender_python() is None:
        pytest.skip("Blender's Python not found: run scripts/setup-blender-venv.sh or set "
                    "WRINKLES_BLENDER_PYTHON")
    body, _ = make_scene()
    sheet, expected = normal_mapped_sheet()
    stage = write_stage(tmp_path / "maps.usdc", body=body, fps=FPS, garments=[sheet],
                        start_time_code=START)
    res = run_check(tmp_path, stage, {
        "fps": FPS, "start": START, "end": START + T - 1, "names": np.array(["sheet"]),
        "points__sheet": sheet.vertices, "faces__sheet": sheet.faces, **expected})
    info = res["meshes"]["sheet"]["normal_map"]
    assert info["chain"] == ["TEX_IMAGE", "NORMAL_MAP", "BSDF_PRINCIPLED"] and info["space"] == "TANGENT"
    assert Path(info["image"]) == tmp_path / "maps_normals" / "sheet_0000.png"
    assert info["pixel_max_err"] <= 1e-4 and info["bitangent_signs"] == [1.0]
    assert min(info["tangent_cos_min"], info["bitangent_cos_min"]) >= 0.95
