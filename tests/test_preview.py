"""Off-screen previews: contact sheet, video, fixed camera, atomic writes (pipelines/preview.py)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from pipelines import preview
from pipelines.preview import PreviewMesh
from sim.errors import WrinklesInputError
from sim.types import BodyFrames

pytest.importorskip("pyvista")
imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
Image = pytest.importorskip("PIL.Image")

RED = (1.0, 0.0, 0.0)
TILE = (96, 80)
FPS = 12.0


def _icosphere(radius: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """A small closed triangle mesh (once-subdivided icosahedron), centred at the origin."""
    t = (1.0 + 5 ** 0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
                 dtype=np.float64)
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    verts, faces, mid = list(v), [], {}

    def midpoint(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in mid:
            mid[key] = len(verts)
            verts.append(0.5 * (verts[a] + verts[b]))
        return mid[key]

    for a, b, c in f:
        ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
        faces += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
    verts = np.asarray(verts)
    verts = radius * verts / np.linalg.norm(verts, axis=1, keepdims=True)
    return verts.astype(np.float32), np.asarray(faces, dtype=np.int32)


def _moving_sphere(frames: int = 6) -> PreviewMesh:
    """A red sphere resting on y = 0, moving 1 m along +X over the sequence."""
    v, f = _icosphere()
    v = v + np.float32([0.0, 0.25, 0.0])
    xs = np.linspace(-0.5, 0.5, frames, dtype=np.float32)
    seq = np.stack([v + np.float32([x, 0.0, 0.0]) for x in xs])
    return PreviewMesh(name="ball", vertices=seq, faces=f, color=RED)


def _red_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the red mesh (shading keeps red well above green and blue)."""
    rgb = img.astype(np.int32)
    return (rgb[..., 0] - rgb[..., 1] > 60) & (rgb[..., 0] - rgb[..., 2] > 60)


def test_contact_sheet_size_content_and_motion(tmp_path):
    out = tmp_path / "sheet.png"
    calls = []
    written = preview.write_contact_sheet([_moving_sphere()], out, n_frames=6, cols=3,
                                          size=TILE, fps=FPS, progress=lambda d, t: calls.append((d, t)))
    assert written == out and out.is_file()
    assert calls == [(k, 6) for k in range(1, 7)]
    img = np.asarray(Image.open(out).convert("RGB"))
    w, h = TILE
    assert img.shape == (2 * h, 3 * w, 3)
    centroids = []
    for k in range(6):
        tile = img[(k // 3) * h:(k // 3 + 1) * h, (k % 3) * w:(k % 3 + 1) * w]
        mask = _red_mask(tile)
        assert mask.sum() > 30, f"tile {k} shows no mesh"
        centroids.append(np.nonzero(mask)[1].mean())
    # the sphere moves along +X, which is image-right from the front camera
    assert np.all(np.diff(centroids) > 1.0), centroids
    assert not list(tmp_path.glob(".*tmp*")), "temp file left behind"


def test_mp4_frame_count_fps_and_motion(tmp_path):
    out = tmp_path / "clip.mp4"
    calls = []
    preview.write_video([_moving_sphere()], out, fps=FPS, size=(97, 81),  # odd: rounded up
                        progress=lambda done, total: calls.append((done, total)))
    assert calls == [(i, 6) for i in range(1, 7)]
    n_frames, secs = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert n_frames == 6
    np.testing.assert_allclose(secs, 6 / FPS, atol=1.0 / FPS)
    reader = imageio_ffmpeg.read_frames(str(out))
    meta = reader.__next__()
    np.testing.assert_allclose(meta["fps"], FPS, rtol=1e-3)
    assert tuple(meta["size"]) == (98, 82)
    w, h = meta["size"]
    frames = [np.frombuffer(b, dtype=np.uint8).reshape(h, w, 3) for b in reader]
    assert len(frames) == 6
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1.0
    assert not list(tmp_path.glob(".*tmp*"))


def test_failure_mid_write_leaves_no_file(tmp_path):
    out = tmp_path / "clip.mp4"

    def boom(done: int, total: int) -> None:
        if done == 3:
            raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError, match="interrupted"):
        preview.write_video([_moving_sphere()], out, fps=FPS, size=(64, 48), progress=boom)
    assert list(tmp_path.iterdir()) == []


def test_existing_target_kept_on_failure(tmp_path):
    out = tmp_path / "clip.gif"
    out.write_bytes(b"old")

    def boom(done: int, total: int) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        preview.write_video([_moving_sphere()], out, fps=FPS, size=(64, 48), progress=boom)
    assert out.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["clip.gif"]


def test_gif_fallback(tmp_path):
    out = preview.write_video([_moving_sphere(4)], tmp_path / "clip.gif", fps=FPS, size=(64, 48))
    with Image.open(out) as im:
        assert im.n_frames == 4 and im.size == (64, 48)


def test_camera_fixed_static_mesh_renders_identically():
    v, f = _icosphere()
    still = PreviewMesh("still", np.stack([v, v, v]) + np.float32([0, 0.25, 0]), f)
    a, b, c = preview.render_frames([still], [0, 1, 2], size=(80, 64))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)


def test_static_mesh_beside_animated_one():
    v, f = _icosphere()
    moving = _moving_sphere(3)
    mixed = [PreviewMesh("still", v + np.float32([0, 0.25, -1.5]), f), moving]  # (V, 3)
    imgs = list(preview.render_frames(mixed, [0, 2], size=(80, 64)))
    assert imgs[0].shape == (64, 80, 3) and imgs[0].dtype == np.uint8
    assert (imgs[0] != imgs[1]).any()  # the frames differ


def test_given_normals_shade_the_mesh_instead_of_its_own():
    """Shading normals (a normal map's): the sphere's own normals reproduce the default render,
    normals that all face the camera's side light it flat, unlike its own."""
    v, f = _icosphere()
    v = v + np.float32([0.0, 0.25, 0.0])
    own = PreviewMesh("ball", v, f, color=RED)
    radial = (v - np.float32([0.0, 0.25, 0.0])) / 0.25
    same = PreviewMesh("ball", v, f, color=RED, normals=radial)
    np.testing.assert_allclose(own.frame_normals(0), preview.vertex_normals(v, f))
    np.testing.assert_array_equal(same.frame_normals(0), radial.astype(np.float32))
    flat = PreviewMesh("ball", v, f, color=RED, normals=np.tile(np.float32([0, 0, 1]), (len(v), 1)))
    a, b, c = (next(preview.render_frames([m], [0], size=(96, 96), floor=False, shadows=False))
               for m in (own, same, flat))
    inside = _red_mask(a)
    assert inside.sum() > 500
    assert np.abs(a.astype(int) - b.astype(int))[inside].mean() < 8  # own ~ radial normals
    red_a, red_c = a[..., 0][inside].astype(float), c[..., 0][inside].astype(float)
    assert red_c.std() < 0.5 * red_a.std()  # one normal everywhere: nearly one shade


def test_rendering_is_deterministic():
    m = [_moving_sphere(3)]
    first = list(preview.render_frames(m, [1], size=(80, 64)))[0]
    second = list(preview.render_frames(m, [1], size=(80, 64)))[0]
    np.testing.assert_array_equal(first, second)


def test_fit_camera_keeps_box_in_view():
    low, high = np.array([-0.3, 0.0, -1.0]), np.array([0.4, 1.8, 2.0])
    for view in preview.CAMERA_VIEWS:
        pose = preview.fit_camera(low, high, view, aspect=4 / 3)
        pos, focal, up = (np.asarray(x) for x in (pose.position, pose.focal_point, pose.view_up))
        back = (pos - focal) / np.linalg.norm(pos - focal)
        right = np.cross(up, back)
        tan_v = np.tan(np.radians(pose.view_angle) / 2)
        corners = np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1])
                            for z in (low[2], high[2])])
        rel = corners - pos
        depth = -(rel @ back)
        assert np.all(depth > 0)
        assert np.all(np.abs(rel @ up) / depth <= tan_v * (1 + 1e-9))
        assert np.all(np.abs(rel @ right) / depth <= tan_v * 4 / 3 * (1 + 1e-9))
        # tight: some corner touches the FRAME_FILL border
        fill = max(np.max(np.abs(rel @ up) / depth / tan_v),
                   np.max(np.abs(rel @ right) / depth / (tan_v * 4 / 3)))
        np.testing.assert_allclose(fill, preview.FRAME_FILL, rtol=1e-6)


def test_vertex_normals_and_floor_projection_exact():
    # a unit square in the XZ plane, wound so its normal is +Y
    v = np.float32([[0, 0, 0], [0, 0, 1], [1, 0, 1], [1, 0, 0]])
    f = np.int32([[0, 1, 2], [0, 2, 3]])
    np.testing.assert_allclose(preview.vertex_normals(v, f), np.tile([0, 1, 0], (4, 1)), atol=1e-7)
    d = np.array([0.6, -0.8, 0.0])
    p = preview.project_to_floor(np.float32([[0, 2, 0], [1, 0.5, 3]]), 0.5, d)
    np.testing.assert_allclose(p, [[1.125, 0.5, 0.0], [1.0, 0.5, 3.0]], atol=1e-6)


def test_contact_sheet_frames_are_even_and_inclusive():
    assert preview.contact_sheet_frames(100, 5) == [0, 25, 50, 74, 99]  # round(74.25) == 74
    assert preview.contact_sheet_frames(3, 8) == [0, 1, 2]


def test_frames_to_preview_meshes():
    v, f = _icosphere()
    body = BodyFrames(vertices=np.stack([v, v]), joints=np.zeros((2, 24, 3), np.float32),
                      transforms=np.tile(np.eye(4, dtype=np.float32), (2, 24, 1, 1)), faces=f)
    (m,) = preview.frames_to_preview_meshes(body)
    assert m.num_frames == 2 and m.faces.dtype == np.int32 and m.color == preview.BODY_COLOR


@pytest.mark.parametrize("bad", [
    lambda: PreviewMesh("m", np.zeros((2, 3)), np.int32([[0, 1, 2]])),                  # V=2
    lambda: PreviewMesh("m", np.full((3, 3), np.nan), np.int32([[0, 1, 2]])),
    lambda: PreviewMesh("m", np.zeros((3, 3)), np.int32([[0, 1, 3]])),
    lambda: PreviewMesh("m", np.zeros((3, 3)), np.int32([[0, 1, 2]]), color=(255, 0, 0)),
    lambda: PreviewMesh("m", np.zeros((2, 3, 3)), np.int32([[0, 1, 2]]), scalars=np.zeros((3, 3))),
    lambda: PreviewMesh("m", np.zeros((2, 3, 3)), np.int32([[0, 1, 2]]), normals=np.zeros((3, 4, 3))),
    lambda: preview.sequence_length([]),
    lambda: preview.sequence_length([_moving_sphere(3), _moving_sphere(4)]),
    lambda: preview.view_direction("top"),
    lambda: preview.write_video([_moving_sphere(2)], "x.avi", fps=10),
    lambda: preview.write_video([_moving_sphere(2)], "x.mp4", fps=0),
    lambda: next(preview.render_frames([_moving_sphere(2)], [5])),
])
def test_bad_input_is_a_user_error(bad):
    with pytest.raises(WrinklesInputError):
        bad()


def test_missing_dependency_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyvista", None)  # makes `import pyvista` fail
    with pytest.raises(WrinklesInputError, match=r"wrinkles\[preview\]"):
        next(preview.render_frames([_moving_sphere(2)]))


def test_module_import_is_lazy():
    code = ("import sys, pipelines.preview; "
            "bad = [m for m in ('pyvista', 'vtk', 'imageio', 'imageio_ffmpeg') if m in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_colour_bar_is_the_ramp_of_the_map_with_its_range():
    """The bar added right of an image holds the colour map's ramp, low end at the bottom,
    and says its range and units; the image itself is untouched."""
    img = np.full((200, 120, 3), 77, np.uint8)
    out, bar = preview.add_colour_bar(img, cmap="magma", clim=(0.0, 12.5), units="mm", label="error")
    assert out.shape == (200, 120 + preview.COLOUR_BAR_SIZE[0], 3)
    np.testing.assert_array_equal(out[:, :120], img)
    x0, y0, x1, y1 = bar.box
    assert 120 <= x0 < x1 <= out.shape[1] and 0 <= y0 < y1 <= 200
    assert (bar.low, bar.high, bar.units, bar.cmap) == (0.0, 12.5, "mm", "magma")
    ramp = preview.colour_ramp("magma", y1 - y0)
    column = out[y0:y1, (x0 + x1) // 2].astype(int)
    np.testing.assert_allclose(column[::-1], ramp, atol=1)  # bottom row = low end
    assert column[-1].sum() < 60 and column[0].sum() > 500  # magma: black at 0, pale at the top


def test_error_renders_carry_a_colour_bar_in_mm(tmp_path):
    """``wrinkles evaluate``'s renders.png: each tile's colour bar shows the error map's ramp
    from 0 to the frame's 99th-percentile error, in mm, recorded in the PNG's metadata; the
    predicted garment is drawn in the bar's colours."""
    import json

    from pipelines.evaluate_cmd import ERROR_CMAP, _renders

    v, f = _icosphere()
    examples = []
    for k, scale in enumerate((0.004, 0.02)):
        error = scale * (v[:, 1] - v[:, 1].min()) / np.ptp(v[:, 1])  # 0 at the bottom .. scale [m]
        examples.append({"sequence": f"seq{k}", "frame": 3 * k, "pred": v, "gt": v, "faces": f,
                         "error": error})
    path = _renders(examples, tmp_path / "renders.png")
    with Image.open(path) as im:
        bars = json.loads(im.text["colour_bars"])
        pixels = np.asarray(im.convert("RGB"))
    assert [(b["sequence"], b["frame"], b["units"], b["cmap"]) for b in bars] == [
        ("seq0", 0, "mm", ERROR_CMAP), ("seq1", 3, "mm", ERROR_CMAP)]
    for b, e in zip(bars, examples, strict=True):
        assert b["low"] == 0.0
        np.testing.assert_allclose(b["high"], 1000.0 * np.percentile(e["error"], 99), rtol=1e-6)
        x0, y0, x1, y1 = b["box"]
        column = pixels[y0:y1, (x0 + x1) // 2].astype(int)
        np.testing.assert_allclose(column[::-1], preview.colour_ramp(ERROR_CMAP, y1 - y0), atol=1)
    # the two tiles' bars are stacked, each inside its own tile
    assert bars[0]["box"][3] <= bars[1]["box"][1] and pixels.shape[0] == 2 * 400


def test_closeups_show_the_surface_under_each_shading_beside_the_maps(tmp_path):
    """``wrinkles evaluate``'s closeups.png: per example, the simulated garment, the base surface
    under its first shading, the LR and HR maps, then the surface under each further shading; a
    shading whose normals all face one way draws that tile nearly flat."""
    from pipelines.evaluate_cmd import _closeups

    v, f = _icosphere()
    v = v + np.float32([0.0, 0.25, 0.0])
    own = preview.vertex_normals(v, f)
    flat = np.tile(np.float32([0.0, 0.0, 1.0]), (len(v), 1))
    rng = np.random.default_rng(0)
    maps = {key: rng.normal(size=(16, 16, 3)).astype(np.float32) for key in ("lr_maps", "normal_maps")}
    ex = {"sequence": "seq-00000", "frame": 3, "gt": v, "faces": f, "surface": 0.98 * v,
          "surface_normals": {"global shape": own, "flat": flat}, "method_maps": maps}
    path = _closeups([ex, ex], tmp_path / "closeups.png")
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape[1] > 3 * img.shape[0] / 2  # 5 tiles wide, 2 rows
    tiles = np.array_split(img[: img.shape[0] // 2], 5, axis=1)
    grey = [t.astype(float).std(axis=(0, 1)).mean() for t in tiles]
    assert grey[4] < grey[1]  # the flat shading: less contrast than the surface's own normals
