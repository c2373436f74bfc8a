"""Off-screen previews of animated meshes: a PNG contact sheet and an MP4 (or GIF/APNG).

One VTK scene (pyvista ``Plotter``) is built per call and reused for every frame: mesh
points, normals and scalars are updated in place, actors are never rebuilt. The camera is
fitted once to the bounding box of the whole sequence, so a walking body moves through a
fixed frame; the floor sits at the lowest point of the sequence. Rendering is deterministic
(same input, same pixels on the same machine).

pyvista, imageio-ffmpeg and Pillow are optional (extra ``preview``) and imported only inside
the functions that need them (STYLE.md 7); a missing one raises ``WrinklesInputError``
naming the extra to install.

Conventions: Y up, metres, bodies face +Z (ARCHITECTURE.md).
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError
from sim.geometry.points import coordinate_bounds
from sim.types import BodyFrames

#: default body colour, a neutral clay (RGB in [0, 1]).
BODY_COLOR: tuple[float, float, float] = (0.80, 0.72, 0.64)
#: background: light grey at the bottom fading to white at the top.
BACKGROUND_BOTTOM: tuple[float, float, float] = (0.86, 0.87, 0.89)
BACKGROUND_TOP: tuple[float, float, float] = (1.0, 1.0, 1.0)
FLOOR_COLOR: tuple[float, float, float] = (0.93, 0.93, 0.94)
GRID_COLOR: tuple[float, float, float] = (0.78, 0.79, 0.81)
#: floor grid spacing [m].
GRID_SPACING = 0.25
#: the grid extends at least this far beyond the motion's footprint [m].
GRID_MARGIN = 1.0
#: floor sits this far below the lowest vertex of the sequence [m] (no z-fighting with feet).
FLOOR_GAP = 1e-3
#: contact shadow height above the floor [m]; grid lines sit at half of it.
SHADOW_LIFT = 2e-3
SHADOW_COLOR: tuple[float, float, float] = (0.80, 0.81, 0.83)
#: horizontal lean of the contact shadow away from the key light (0 = straight down).
SHADOW_LEAN = 0.35
#: lights as ((right, up, back) in camera axes, intensity): key, fill, rim, floor bounce.
LIGHT_RIG: tuple[tuple[tuple[float, float, float], float], ...] = (
    ((-0.75, 0.85, 0.9), 0.95),
    ((0.9, 0.25, 0.8), 0.45),
    ((0.3, 0.9, -1.0), 0.50),
    ((0.0, -1.0, 0.3), 0.12),
)

#: camera views: name -> (azimuth [deg] about +Y measured from +Z toward +X,
#: elevation [deg] above the horizontal). Bodies face +Z, so "front" looks at their front.
CAMERA_VIEWS: dict[str, tuple[float, float]] = {
    "front": (0.0, 10.0),
    "side": (90.0, 10.0),
    "three_quarter": (35.0, 14.0),
}
#: vertical field of view of the camera [deg] (VTK's default).
VIEW_ANGLE_DEG = 30.0
#: fraction of the image the sequence's bounding box may fill (the rest is margin).
FRAME_FILL = 0.86
#: video containers written by ``write_video``, by file extension.
VIDEO_FORMATS = (".mp4", ".gif", ".png")

_INSTALL_HINT = "install the preview extra: pip install 'wrinkles[preview]'"

ProgressCallback = Callable[[int, int], None]


# --------------------------------------------------------------------------- data


@dataclass(frozen=True)
class PreviewMesh:
    """One animated triangle mesh to draw.

    Attributes:
        name: label, used in error messages.
        vertices: positions [m], shape (T, V, 3) float32; a static mesh may pass (V, 3) or
            T = 1, which is shown unchanged in every frame.
        faces: triangle indices, shape (F, 3) int32.
        color: RGB in [0, 1], used where ``scalars`` is None.
        scalars: optional per-vertex values, shape (T, V) (or (V,)), drawn through ``cmap``
            (e.g. strain norm); the colour range is ``clim`` or the sequence's min/max.
        opacity: 0 (invisible) .. 1 (opaque).
        smooth: smooth (Gouraud, per-vertex normals) or flat shading.
        cmap: matplotlib/pyvista colour map name for ``scalars``.
        clim: (low, high) colour range for ``scalars``; None = sequence min/max.
        normals: optional shading normals, shape (T, V, 3) (or (V, 3)), e.g. decoded from a
            normal map; None = the mesh's own vertex normals.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    color: tuple[float, float, float] = BODY_COLOR
    scalars: np.ndarray | None = None
    opacity: float = 1.0
    smooth: bool = True
    cmap: str = "viridis"
    clim: tuple[float, float] | None = None
    normals: np.ndarray | None = None

    def __post_init__(self) -> None:
        where = f"mesh {self.name!r}"
        verts = np.asarray(self.vertices, dtype=np.float32)
        if verts.ndim == 2:
            verts = verts[None]
        if verts.ndim != 3 or verts.shape[2] != 3 or verts.shape[0] < 1 or verts.shape[1] < 3:
            raise WrinklesInputError(
                f"{where}: vertices must have shape (T, V, 3) with T >= 1, V >= 3, got "
                f"{np.shape(self.vertices)}")
        if not np.all(np.isfinite(verts)):
            bad = int(np.where(~np.isfinite(verts).all(axis=(1, 2)))[0][0])
            raise WrinklesInputError(f"{where}: vertices have NaN/inf values at frame {bad}")
        faces = np.asarray(self.faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] < 1:
            raise WrinklesInputError(f"{where}: faces must have shape (F, 3), got {faces.shape}")
        if not np.issubdtype(faces.dtype, np.integer):
            raise WrinklesInputError(f"{where}: faces must be integers, got {faces.dtype}")
        if faces.min() < 0 or faces.max() >= verts.shape[1]:
            raise WrinklesInputError(
                f"{where}: face indices must lie in [0, {verts.shape[1] - 1}], got "
                f"[{int(faces.min())}, {int(faces.max())}]")
        color = tuple(float(c) for c in self.color)
        if len(color) != 3 or not all(0.0 <= c <= 1.0 for c in color):
            raise WrinklesInputError(f"{where}: color must be 3 floats in [0, 1], got {self.color}")
        if not 0.0 <= float(self.opacity) <= 1.0:
            raise WrinklesInputError(f"{where}: opacity must lie in [0, 1], got {self.opacity}")
        scalars = self.scalars
        if scalars is not None:
            scalars = np.asarray(scalars, dtype=np.float32)
            if scalars.ndim == 1:
                scalars = scalars[None]
            if scalars.ndim != 2 or scalars.shape[1] != verts.shape[1] or (
                    scalars.shape[0] not in (1, verts.shape[0])):
                raise WrinklesInputError(
                    f"{where}: scalars must have shape ({verts.shape[0]}, {verts.shape[1]}), "
                    f"got {np.shape(self.scalars)}")
            if not np.all(np.isfinite(scalars)):
                raise WrinklesInputError(f"{where}: scalars have NaN/inf values")
        if self.normals is not None:
            normals = np.asarray(self.normals, dtype=np.float32)
            normals = normals[None] if normals.ndim == 2 else normals
            if normals.shape[1:] != verts.shape[1:] or normals.shape[0] not in (1, verts.shape[0]):
                raise WrinklesInputError(f"{where}: normals must have shape ({verts.shape[0]}, "
                                         f"{verts.shape[1]}, 3), got {np.shape(self.normals)}")
            if not np.all(np.isfinite(normals)):
                raise WrinklesInputError(f"{where}: normals have NaN/inf values")
            object.__setattr__(self, "normals", normals)
        object.__setattr__(self, "vertices", verts)
        object.__setattr__(self, "faces", faces.astype(np.int32, copy=False))
        object.__setattr__(self, "color", color)
        object.__setattr__(self, "scalars", scalars)

    @property
    def num_frames(self) -> int:
        return int(self.vertices.shape[0])

    def frame(self, t: int) -> np.ndarray:
        """Positions [m] of frame ``t``, shape (V, 3); a static mesh returns its only frame."""
        return self.vertices[t if self.num_frames > 1 else 0]

    def frame_normals(self, t: int) -> np.ndarray:
        """Shading normals of frame ``t`` (V, 3): the given ones, else the mesh's own."""
        if self.normals is None:
            return vertex_normals(self.frame(t), self.faces)
        return self.normals[t if self.normals.shape[0] > 1 else 0]

    def frame_scalars(self, t: int) -> np.ndarray | None:
        if self.scalars is None:
            return None
        return self.scalars[t if self.scalars.shape[0] > 1 else 0]


def frames_to_preview_meshes(body: BodyFrames, color: tuple[float, float, float] = BODY_COLOR,
                             *, name: str = "body") -> list[PreviewMesh]:
    """The meshes that show a posed body sequence (one mesh, smooth clay shading)."""
    return [PreviewMesh(name=name, vertices=body.vertices, faces=body.faces, color=color)]


# --------------------------------------------------------------------------- pure geometry


def sequence_length(meshes: Sequence[PreviewMesh]) -> int:
    """Number of frames shared by ``meshes`` (static meshes, T = 1, fit any length)."""
    if not meshes:
        raise WrinklesInputError("nothing to render: the list of preview meshes is empty")
    lengths = {m.num_frames for m in meshes if m.num_frames > 1}
    if len(lengths) > 1:
        detail = ", ".join(f"{m.name}: {m.num_frames}" for m in meshes)
        raise WrinklesInputError(f"preview meshes have different frame counts ({detail})")
    return lengths.pop() if lengths else 1


def sequence_bounds(meshes: Sequence[PreviewMesh]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box [m] over every vertex of every frame: (low (3,), high (3,))."""
    boxes = [coordinate_bounds(m.vertices) for m in meshes]
    return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals, shape (V, 3) float32 (zero-area fans give +Y)."""
    v = vertices.astype(np.float32, copy=False)
    tri = v[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # |fn| = 2 * area
    n = np.zeros_like(v)
    for k in range(3):
        for c in range(3):
            n[:, c] += np.bincount(faces[:, k], weights=fn[:, c], minlength=len(v))
    length = np.linalg.norm(n, axis=1, keepdims=True)
    out = np.where(length > 1e-20, n / np.maximum(length, 1e-20), np.float32([0.0, 1.0, 0.0]))
    return out.astype(np.float32)


@dataclass(frozen=True)
class CameraPose:
    """A fixed camera: position and focal point [m], view-up vector, vertical angle [deg]."""

    position: tuple[float, float, float]
    focal_point: tuple[float, float, float]
    view_up: tuple[float, float, float]
    view_angle: float


def view_direction(view: str) -> np.ndarray:
    """Unit vector from the target toward the camera for a named view."""
    if view not in CAMERA_VIEWS:
        raise WrinklesInputError(
            f"unknown camera view {view!r}; allowed: {', '.join(sorted(CAMERA_VIEWS))}")
    az, el = (math.radians(a) for a in CAMERA_VIEWS[view])
    return np.array([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])


def fit_camera(low: np.ndarray, high: np.ndarray, view: str, aspect: float,
               *, view_angle: float = VIEW_ANGLE_DEG, fill: float = FRAME_FILL) -> CameraPose:
    """Camera that keeps the whole box [low, high] [m] in view from the named direction.

    The distance is the smallest one at which every box corner projects inside ``fill`` of
    the image in both directions (perspective, vertical angle ``view_angle`` [deg],
    ``aspect`` = width / height).
    """
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    centre = 0.5 * (low + high)
    half = np.maximum(0.5 * (high - low), 1e-3)  # a flat or point-like box still gets a frame
    back = view_direction(view)                   # target -> camera
    right = np.cross(np.array([0.0, 1.0, 0.0]), back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    tan_v = math.tan(math.radians(view_angle) / 2.0) * fill
    tan_h = tan_v * aspect
    corners = centre + half * np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                                        for sz in (-1, 1)])
    rel = corners - centre
    x, y, z = rel @ right, rel @ up, rel @ back
    # a corner at depth z fits when |x| <= (d - z) tan_h, |y| <= (d - z) tan_v
    dist = float(np.max(np.maximum(z + np.abs(x) / tan_h, z + np.abs(y) / tan_v)))
    dist = max(dist, 1e-2)
    pos = centre + dist * back
    return CameraPose(tuple(pos.tolist()), tuple(centre.tolist()), tuple(up.tolist()),
                      float(view_angle))


def light_rig(pose: CameraPose) -> list[tuple[np.ndarray, float]]:
    """Three-point lighting for a camera: (unit direction target -> light, intensity) pairs.

    Key from camera-left above, fill from camera-right low, rim from behind above, and a
    faint bounce from below; fixed in the world once the camera is fixed.
    """
    back = np.asarray(pose.position, np.float64) - np.asarray(pose.focal_point, np.float64)
    back /= np.linalg.norm(back)
    up = np.asarray(pose.view_up, np.float64)
    right = np.cross(up, back)
    rig = []
    for (a, b, c), intensity in LIGHT_RIG:
        d = a * right + b * up + c * back
        rig.append((d / np.linalg.norm(d), intensity))
    return rig


def shadow_direction(pose: CameraPose) -> np.ndarray:
    """Direction light travels for the contact shadow: mostly down, leaning away from the key."""
    key = light_rig(pose)[0][0]
    d = -np.array([SHADOW_LEAN * key[0], 1.0, SHADOW_LEAN * key[2]])
    return d / np.linalg.norm(d)


def project_to_floor(points: np.ndarray, floor_y: float, direction: np.ndarray) -> np.ndarray:
    """Project points [m], shape (V, 3), along ``direction`` (y < 0) onto the plane y = floor_y."""
    p = points.astype(np.float32, copy=True)
    s = (p[:, 1] - floor_y) / float(direction[1])
    p -= s[:, None] * np.asarray(direction, np.float32)[None, :]
    p[:, 1] = floor_y
    return p


# --------------------------------------------------------------------------- optional deps


def _import_pyvista():
    try:
        import pyvista
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise WrinklesInputError(f"rendering previews needs pyvista ({exc}); {_INSTALL_HINT}") from None
    return pyvista


def _import_pil():
    try:
        from PIL import Image, ImageDraw, ImageFont
    except ImportError as exc:  # pragma: no cover
        raise WrinklesInputError(f"writing preview images needs Pillow ({exc}); {_INSTALL_HINT}") from None
    return Image, ImageDraw, ImageFont


def _import_imageio_ffmpeg():
    try:
        import imageio_ffmpeg
    except ImportError as exc:  # pragma: no cover
        raise WrinklesInputError(
            f"writing MP4 previews needs imageio-ffmpeg ({exc}); {_INSTALL_HINT}") from None
    return imageio_ffmpeg


# --------------------------------------------------------------------------- scene


class _Scene:
    """A pyvista plotter with the meshes, floor, lights and a fixed camera; renders frames."""

    def __init__(self, meshes: Sequence[PreviewMesh], size: tuple[int, int], camera: str,
                 *, floor: bool, shadows: bool, anti_aliasing: bool):
        pv = _import_pyvista()
        self.meshes = list(meshes)
        self.size = (int(size[0]), int(size[1]))
        low, high = sequence_bounds(self.meshes)
        pose = fit_camera(low, high, camera, self.size[0] / self.size[1])
        self.floor_y = float(low[1]) - FLOOR_GAP
        self.shadow_dir = shadow_direction(pose)
        with pv.vtk_verbosity("off"):  # silences VTK's "no X server" probe before EGL
            self.plotter = pv.Plotter(off_screen=True, window_size=list(self.size),
                                      lighting="none")
        pl = self.plotter
        try:
            pl.set_background(BACKGROUND_BOTTOM, top=BACKGROUND_TOP)
            self.polys = [self._add_mesh(pv, m) for m in self.meshes]
            # planar contact shadows of the opaque meshes (VTK's shadow-map pass fails
            # under EGL/Mesa, and a flattened silhouette is cheap and steady)
            self.shadows = [self._add_shadow(pv, m) if floor and shadows and m.opacity >= 1.0
                            else None for m in self.meshes]
            if floor:
                self._add_floor(pv, low, high, pose)
            self._add_lights(pv, pose)
            pl.camera.position = pose.position
            pl.camera.focal_point = pose.focal_point
            pl.camera.up = pose.view_up
            pl.camera.view_angle = pose.view_angle
            # near/far planes fixed once from the whole scene, so no per-frame re-fit
            pl.renderer.ResetCameraClippingRange()
            if anti_aliasing:
                pl.enable_anti_aliasing("ssaa")  # FXAA is not supported under EGL/OSMesa
        except BaseException:
            pl.close()
            raise

    @staticmethod
    def _polydata(pv, points: np.ndarray, faces: np.ndarray):
        cells = np.empty((len(faces), 4), dtype=np.int64)
        cells[:, 0] = 3
        cells[:, 1:] = faces
        return pv.PolyData(points.astype(np.float32), cells.ravel())

    def _add_mesh(self, pv, m: PreviewMesh):
        poly = self._polydata(pv, m.frame(0), m.faces)
        poly.point_data.active_normals = m.frame_normals(0)
        kw = dict(opacity=m.opacity, smooth_shading=False, ambient=0.2, diffuse=0.8,
                  specular=0.12, specular_power=25.0, show_scalar_bar=False)
        if m.scalars is not None:
            lo, hi = m.clim if m.clim is not None else (float(m.scalars.min()),
                                                         float(m.scalars.max()))
            poly.point_data["scalars"] = m.frame_scalars(0)
            kw.update(scalars="scalars", cmap=m.cmap, clim=(lo, hi if hi > lo else lo + 1e-6))
        else:
            kw.update(color=m.color)
        actor = self.plotter.add_mesh(poly, **kw)
        actor.prop.interpolation = "gouraud" if m.smooth else "flat"
        return poly

    def _add_shadow(self, pv, m: PreviewMesh):
        pts = project_to_floor(m.frame(0), self.floor_y + SHADOW_LIFT, self.shadow_dir)
        poly = self._polydata(pv, pts, m.faces)
        # unlit and opaque, so overlapping flattened triangles give one even tone
        self.plotter.add_mesh(poly, color=SHADOW_COLOR, lighting=False, show_scalar_bar=False)
        return poly

    def _add_floor(self, pv, low, high, pose: CameraPose) -> None:
        y0 = self.floor_y
        span = float(max(high[0] - low[0], high[2] - low[2], high[1] - low[1], 0.5))
        cx, cz = 0.5 * (low[0] + high[0]), 0.5 * (low[2] + high[2])
        # the floor runs far beyond the frame so its far edge melts into the background
        far = 40.0 * span
        plane = pv.Plane(center=(cx, y0, cz), direction=(0.0, 1.0, 0.0), i_size=2 * far,
                         j_size=2 * far)
        # directional lights shade a plane evenly, so the floor is drawn unlit (cheaper)
        self.plotter.add_mesh(plane, color=FLOOR_COLOR, lighting=False, show_scalar_bar=False)
        # the grid covers the motion's footprint plus a margin; farther out its lines
        # would crowd into moire near the horizon; toward the camera it runs to the
        # camera's foot, so the foreground never shows the grid's edge
        margin = max(GRID_MARGIN, 0.25 * span)
        cam_x, cam_z = pose.position[0], pose.position[2]
        x_lo, x_hi = min(float(low[0]) - margin, cam_x), max(float(high[0]) + margin, cam_x)
        z_lo, z_hi = min(float(low[2]) - margin, cam_z), max(float(high[2]) + margin, cam_z)
        ys = y0 + 0.5 * SHADOW_LIFT
        xs = np.arange(math.ceil(x_lo / GRID_SPACING), math.floor(x_hi / GRID_SPACING) + 1)
        zs = np.arange(math.ceil(z_lo / GRID_SPACING), math.floor(z_hi / GRID_SPACING) + 1)
        segs = [((x * GRID_SPACING, ys, z_lo), (x * GRID_SPACING, ys, z_hi)) for x in xs]
        segs += [((x_lo, ys, z * GRID_SPACING), (x_hi, ys, z * GRID_SPACING)) for z in zs]
        if segs:
            pts = np.asarray(segs, dtype=np.float32).reshape(-1, 3)
            lines = np.column_stack([np.full(len(segs), 2), np.arange(0, 2 * len(segs), 2),
                                     np.arange(1, 2 * len(segs), 2)]).ravel()
            grid = pv.PolyData(pts, lines=lines)
            self.plotter.add_mesh(grid, color=GRID_COLOR, line_width=1.0, lighting=False,
                                  show_scalar_bar=False)

    def _add_lights(self, pv, pose: CameraPose) -> None:
        """Soft three-point rig (plus a faint floor bounce), placed relative to the camera."""
        focal = np.asarray(pose.focal_point)
        dist = float(np.linalg.norm(np.asarray(pose.position) - focal))
        for direction, intensity in light_rig(pose):
            light = pv.Light(position=tuple((focal + 3.0 * dist * direction).tolist()),
                             focal_point=tuple(focal.tolist()), intensity=intensity,
                             light_type="scene light")
            light.positional = False
            self.plotter.add_light(light)

    def render(self, t: int) -> np.ndarray:
        """Frame ``t`` as an RGB image, shape (H, W, 3) uint8."""
        for m, poly, shadow in zip(self.meshes, self.polys, self.shadows, strict=True):
            if m.num_frames > 1:
                v = m.frame(t)
                poly.points[:] = v
                poly.GetPoints().Modified()
                poly.point_data["Normals"][:] = m.frame_normals(t)
                poly.point_data.GetNormals().Modified()
                if shadow is not None:
                    shadow.points[:] = project_to_floor(v, self.floor_y + SHADOW_LIFT,
                                                        self.shadow_dir)
                    shadow.GetPoints().Modified()
                    shadow.Modified()
            s = m.frame_scalars(t)
            if s is not None and m.scalars.shape[0] > 1:
                poly.point_data["scalars"][:] = s
                poly.point_data.GetArray("scalars").Modified()
            poly.Modified()
        self.plotter.render()
        img = self.plotter.screenshot(return_img=True)
        return np.ascontiguousarray(img[..., :3], dtype=np.uint8)

    def close(self) -> None:
        self.plotter.close()


def _check_size(size: tuple[int, int]) -> tuple[int, int]:
    try:
        w, h = (int(s) for s in size)
    except (TypeError, ValueError):
        raise WrinklesInputError(f"image size must be (width, height), got {size!r}") from None
    if not (8 <= w <= 8192 and 8 <= h <= 8192):
        raise WrinklesInputError(f"image size must lie in [8, 8192] pixels, got {w}x{h}")
    return w, h


def render_frames(meshes: Sequence[PreviewMesh], frame_indices: Iterable[int] | None = None, *,
                  size: tuple[int, int] = (640, 480), camera: str = "front", floor: bool = True,
                  shadows: bool = True, anti_aliasing: bool = True) -> Iterator[np.ndarray]:
    """Render frames of an animated scene off-screen.

    One plotter serves all frames; the camera is fitted once to the whole sequence. This is
    a generator: arguments are checked, and the scene built, when the first frame is asked
    for; closing the generator early releases the plotter.

    Args:
        meshes: what to draw (body, garments ...); all animated meshes share one frame count.
        frame_indices: frames to render, in order; None = every frame.
        size: image (width, height) [px].
        camera: a name from ``CAMERA_VIEWS`` ("front", "side", "three_quarter").
        floor: draw a floor with a 25 cm grid at the lowest point of the sequence.
        shadows: draw flat contact shadows of the opaque meshes on the floor.
        anti_aliasing: supersampled anti-aliasing (SSAA).

    Yields:
        RGB images, shape (H, W, 3) uint8.
    """
    size = _check_size(size)
    n = sequence_length(meshes)
    indices = list(range(n)) if frame_indices is None else [int(i) for i in frame_indices]
    for i in indices:
        if not 0 <= i < n:
            raise WrinklesInputError(f"frame index {i} is out of range [0, {n - 1}]")
    view_direction(camera)  # validate before building a scene
    scene = _Scene(meshes, size, camera, floor=floor, shadows=shadows,
                   anti_aliasing=anti_aliasing)
    try:
        for i in indices:
            yield scene.render(i)
    finally:
        scene.close()


def render_frame(meshes: Sequence[PreviewMesh], t: int = 0, **kwargs) -> np.ndarray:
    """Frame ``t`` of a scene as one RGB image (H, W, 3) uint8 (``render_frames``' options)."""
    frames = render_frames(meshes, [t], **kwargs)
    try:
        return next(frames)
    finally:
        frames.close()


# --------------------------------------------------------------------------- writers


def _temp_path(path: Path) -> Path:
    """A fresh temp file beside ``path`` with the same extension (for atomic rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}")
    os.close(fd)
    # mkstemp makes 0600 files; give the final file the mode a plain open() would (umask)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    return Path(tmp)


def contact_sheet_frames(num_frames: int, n: int) -> list[int]:
    """``n`` evenly spaced frame indices in [0, num_frames), first and last included."""
    if n < 1:
        raise WrinklesInputError(f"contact sheet needs n_frames >= 1, got {n}")
    if num_frames <= n:
        return list(range(num_frames))
    return sorted({int(round(x)) for x in np.linspace(0, num_frames - 1, n)})


def _label_font(ImageFont, px: int):
    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # Pillow < 10.1: bitmap font, fixed size
        return ImageFont.load_default()


def write_contact_sheet(meshes: Sequence[PreviewMesh], path_png: str | os.PathLike, *,
                        n_frames: int = 8, cols: int = 4, size: tuple[int, int] = (320, 400),
                        labels: bool = True, fps: float | None = None, camera: str = "front",
                        floor: bool = True, progress: ProgressCallback | None = None) -> Path:
    """Tile evenly spaced frames into one PNG, written atomically.

    The sheet is ``cols * W`` by ``rows * H`` pixels for tiles of ``size`` = (W, H), with
    rows = ceil(frames / cols); empty tiles at the end are background grey.

    Args:
        meshes: what to draw.
        path_png: output file (.png); parent folders are created.
        n_frames: number of frames to show (fewer if the sequence is shorter).
        cols: tiles per row.
        size: tile (width, height) [px].
        labels: write "frame i" (and the time when ``fps`` is given) on each tile.
        fps: frame rate [1/s] of the sequence, for time labels.
        camera: a name from ``CAMERA_VIEWS``.
        floor: draw the floor.
        progress: called as ``progress(tiles_done, tiles_total)`` after each tile.

    Returns:
        The written path.
    """
    Image, ImageDraw, ImageFont = _import_pil()
    path = Path(path_png)
    if path.suffix.lower() != ".png":
        raise WrinklesInputError("contact sheet must be a .png file", path=path)
    if cols < 1:
        raise WrinklesInputError(f"contact sheet needs cols >= 1, got {cols}")
    w, h = _check_size(size)
    frames = contact_sheet_frames(sequence_length(meshes), n_frames)
    cols = min(cols, len(frames))
    rows = math.ceil(len(frames) / cols)
    bg = tuple(int(round(255 * c)) for c in BACKGROUND_BOTTOM)
    sheet = Image.new("RGB", (cols * w, rows * h), bg)
    draw = ImageDraw.Draw(sheet)
    font = _label_font(ImageFont, max(10, h // 24))
    for k, img in enumerate(render_frames(meshes, frames, size=(w, h), camera=camera, floor=floor)):
        x0, y0 = (k % cols) * w, (k // cols) * h
        sheet.paste(Image.fromarray(img), (x0, y0))
        if labels:
            text = f"frame {frames[k]}"
            if fps:
                text += f"   {frames[k] / fps:.2f} s"
            draw.text((x0 + 8, y0 + 6), text, fill=(60, 62, 66), font=font)
        if progress is not None:
            progress(k + 1, len(frames))
    # thin separators between tiles
    for c in range(1, cols):
        draw.line([(c * w, 0), (c * w, rows * h)], fill=(200, 202, 206), width=1)
    for r in range(1, rows):
        draw.line([(0, r * h), (cols * w, r * h)], fill=(200, 202, 206), width=1)
    tmp = _temp_path(path)
    try:
        sheet.save(tmp, format="PNG")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_video(meshes: Sequence[PreviewMesh], path: str | os.PathLike, *, fps: float,
                size: tuple[int, int] = (640, 480), camera: str = "front", floor: bool = True,
                quality: int = 8, progress: ProgressCallback | None = None) -> Path:
    """Render every frame into a video, written atomically (temp file, rename at the end).

    ``.mp4``: H.264 (libx264), yuv420p, via imageio-ffmpeg; odd sizes are rounded up to
    even. ``.gif`` and ``.png`` (animated PNG, lossless) are written with Pillow, looping.
    On any exception (including one raised by ``progress``) no file is left at ``path``.

    Args:
        meshes: what to draw.
        path: output file; the extension picks the format (``VIDEO_FORMATS``).
        fps: frames per second [1/s].
        size: frame (width, height) [px].
        camera: a name from ``CAMERA_VIEWS``.
        floor: draw the floor.
        quality: H.264 quality 0 (worst) .. 10 (lossless-ish); 8 is crf 10.
        progress: called as ``progress(frames_done, frames_total)`` after each frame.

    Returns:
        The written path.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in VIDEO_FORMATS:
        raise WrinklesInputError(
            f"unsupported video extension {path.suffix!r}; allowed: {', '.join(VIDEO_FORMATS)}",
            path=path)
    if not (np.isfinite(fps) and fps > 0):
        raise WrinklesInputError(f"video fps must be positive, got {fps}", path=path)
    w, h = _check_size(size)
    if ext == ".mp4":
        w, h = w + w % 2, h + h % 2  # yuv420p needs even dimensions
        ffmpeg = _import_imageio_ffmpeg()
    else:
        Image = _import_pil()[0]
    total = sequence_length(meshes)
    frames = render_frames(meshes, None, size=(w, h), camera=camera, floor=floor)
    tmp = _temp_path(path)
    writer = None
    try:
        if ext == ".mp4":
            writer = ffmpeg.write_frames(
                str(tmp), (w, h), fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                quality=quality, macro_block_size=1, output_params=["-movflags", "+faststart"])
            writer.send(None)
        images = []
        for k, img in enumerate(frames):
            if writer is not None:
                writer.send(img)
            else:
                images.append(Image.fromarray(img))
            if progress is not None:
                progress(k + 1, total)
        if writer is not None:
            writer.close()  # flushes and waits for ffmpeg
            writer = None
        else:
            ms = 1000.0 / fps
            if ext == ".gif":
                images = [im.quantize(colors=255, method=Image.Quantize.MEDIANCUT) for im in images]
            images[0].save(tmp, format="GIF" if ext == ".gif" else "PNG", save_all=True,
                           append_images=images[1:], duration=ms, loop=0)
        os.replace(tmp, path)
    except BaseException:
        frames.close()
        if writer is not None:
            try:
                writer.close()
            except Exception:  # noqa: BLE001 - the original error matters more
                pass
        tmp.unlink(missing_ok=True)
        raise
    return path


# --------------------------------------------------------------------------- colour bars


COLOUR_BAR_SIZE = (96, 18)
"""Width [px] of the strip a colour bar adds to the right of an image, and of its ramp."""
COLOUR_BAR_TICKS = 5
"""Labelled values on a colour bar, its two ends included."""


@dataclass(frozen=True)
class ColourBar:
    """Where a colour bar is in an image and what it means.

    Attributes:
        box: the ramp's pixels, (left, top, right, bottom), right and bottom exclusive; the
            top row is ``high``, the bottom row ``low``.
        low, high: the values at the ends [``units``].
        units: e.g. "mm".
        cmap: the matplotlib colour map of the ramp (and of the scalars it explains).
    """

    box: tuple[int, int, int, int]
    low: float
    high: float
    units: str
    cmap: str

    def to_json(self, **more) -> dict:
        return {"box": list(self.box), "low": self.low, "high": self.high, "units": self.units,
                "cmap": self.cmap, **more}


def colour_ramp(cmap: str, n: int) -> np.ndarray:
    """``n`` colours of the matplotlib colour map ``cmap``, low end first, (n, 3) uint8 (the
    map pyvista draws ``PreviewMesh.scalars`` with)."""
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover
        raise WrinklesInputError(f"colour bars need matplotlib ({exc}); {_INSTALL_HINT}") from None
    rgba = np.asarray(matplotlib.colormaps[cmap](np.linspace(0.0, 1.0, n)))
    return np.round(255.0 * rgba[:, :3]).astype(np.uint8)


def add_colour_bar(image: np.ndarray, *, cmap: str, clim: tuple[float, float], units: str,
                   label: str = "") -> tuple[np.ndarray, ColourBar]:
    """``image`` (H, W, 3) uint8 with a vertical colour bar to its right: the ramp of ``cmap``
    from ``clim[0]`` (bottom) to ``clim[1]`` (top), ``COLOUR_BAR_TICKS`` values labelled, and
    "``label`` [``units``]" above it.

    Returns:
        The wider image, (H, W + ``COLOUR_BAR_SIZE[0]``, 3) uint8, and where the bar is.
    """
    Image, ImageDraw, ImageFont = _import_pil()
    h, w = image.shape[:2]
    strip, ramp_w = COLOUR_BAR_SIZE
    top, bottom = 28, h - 14
    out = Image.new("RGB", (w + strip, h), "white")
    out.paste(Image.fromarray(np.ascontiguousarray(image[..., :3])), (0, 0))
    x0 = w + 8
    ramp = colour_ramp(cmap, bottom - top)[::-1]  # top row = high end
    out.paste(Image.fromarray(np.repeat(ramp[:, None, :], ramp_w, axis=1)), (x0, top))
    draw = ImageDraw.Draw(out)
    font = _label_font(ImageFont, 11)
    draw.rectangle([x0 - 1, top - 1, x0 + ramp_w, bottom], outline=(60, 62, 66))
    low, high = (float(v) for v in clim)
    for k in range(COLOUR_BAR_TICKS):
        f = k / (COLOUR_BAR_TICKS - 1)
        y = round(bottom - 1 - f * (bottom - top - 1))
        draw.line([(x0 + ramp_w, y), (x0 + ramp_w + 3, y)], fill=(60, 62, 66))
        draw.text((x0 + ramp_w + 5, y), f"{low + f * (high - low):.3g}", fill=(30, 30, 30), font=font,
                  anchor="lm")
    draw.text((w + strip // 2, 4), f"{label} [{units}]".strip(), fill=(30, 30, 30), font=font, anchor="ma")
    bar = ColourBar(box=(x0, top, x0 + ramp_w, bottom), low=low, high=high, units=units, cmap=cmap)
    return np.asarray(out), bar
