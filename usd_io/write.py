"""Write animated body and garment meshes to a USD stage.

Stage layout::

    /World                      Xform, default prim
    /World/BodyRig              the body as a UsdSkel rig (``body_as="skel"``, usd_io/skel.py):
                                SkelRoot with Skeleton, SkelAnimation and the skinned mesh
                                /World/BodyRig/Body (skin material)
    /World/Body                 or the body as a point cache (``body_as="points"``): Mesh,
                                time-sampled points + extent, skin material
    /World/BodyJoints           Points (purpose "guide"), time-sampled joint positions (point
                                cache only; the skeleton carries them in a rig)
    /World/Garments/<name>      Mesh, time-sampled points, primvars:st, cloth material,
                                primvars:fabricLayers (uniform float, per face) where it has hems
    /World/Looks/<name>Material UsdPreviewSurface materials; a garment with normal maps also
                                has NormalTexture (UsdUVTexture, one image per frame) and
                                NormalUVReader (its st) feeding the surface's normal

Joints are a sibling of ``/World/Body`` rather than a child: a gprim nested in a gprim breaks
``usdGeomValidators:EncapsulationChecker``.

Units SI, Y up: ``upAxis = Y``, ``metersPerUnit = 1``, ``timeCodesPerSecond =
framesPerSecond = fps``; frame ``k`` is time code ``start_time_code + k``. The file appears
only when complete (written in a temporary directory beside it, then renamed).

Normal maps (``GarmentTrack.normal_maps``, ``usd_io.textures``) are PNG images in the folder
``<stem>_normals`` beside the stage (``<garment>_0000.png`` ..., referred to by paths relative to
the stage; inside the package for ``.usdz``). The folder is written with the stage, in the same
temporary directory, and renamed into place just before it, replacing a folder of that name.
It is named after the file written, so write such a stage under its final name.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdShade, UsdUtils, Vt

from sim.errors import WrinklesInputError
from sim.types import BodyFrames, BodyRig, face_layers_array
from usd_io.skel import RIG_SUFFIX, check_rig, define_skel_body
from usd_io.textures import (
    NORMALS_FOLDER_SUFFIX,
    check_bits,
    check_normal_maps,
    define_normal_texture,
    encode_normal_map,
    normal_map_files,
    write_png,
)

WORLD_PATH = "/World"
BODY_PATH = "/World/Body"
#: the body mesh of a rig (``body_as="skel"``), under its SkelRoot.
SKEL_BODY_PATH = f"/World/Body{RIG_SUFFIX}/Body"
#: ways ``write_stage`` writes the body.
BODY_AS = ("skel", "points")
JOINTS_PATH = "/World/BodyJoints"
GARMENTS_PATH = "/World/Garments"
LOOKS_PATH = "/World/Looks"
#: customLayerData key holding the provenance dict as a JSON string.
METADATA_KEY = "wrinkles:metadata"
#: file suffix -> Sdf file-format argument (".usd" is written as crate, i.e. usdc).
SUFFIX_FORMATS: dict[str, str] = {".usda": "usda", ".usdc": "usdc", ".usd": "usdc",
                                  ".usdz": "usdc"}

SKIN_COLOR: tuple[float, float, float] = (0.80, 0.57, 0.47)
CLOTH_COLOR: tuple[float, float, float] = (0.20, 0.33, 0.60)
#: display radius of the joint points [m].
JOINT_WIDTH = 0.03
#: primvar of a garment's fabric layers per face (hems): uniform float.
FABRIC_LAYERS = "fabricLayers"

#: progress(frames_done, frames_total); raising from it aborts the write (nothing is left).
ProgressFn = Callable[[int, int], None]


@dataclass(frozen=True)
class GarmentTrack:
    """One garment's animation, ready to write.

    Attributes:
        name: prim name under ``/World/Garments`` (made a valid USD identifier).
        vertices: positions [m], shape (T, V, 3), float32.
        faces: triangle indices into ``vertices``, shape (F, 3), int32.
        uvs: texture coordinates, shape (U, 2), or None.
        uv_faces: per-corner indices into ``uvs``, shape (F, 3) (seams allowed), or None for
            per-vertex UVs (then U == V).
        normals: vertex normals, shape (T, V, 3) or (V, 3), or None.
        color: linear RGB diffuse colour of the cloth material, each in [0, 1].
        face_layers: fabric layers per face (hems, ``Garment.face_layers``), shape (F,), >= 1, or
            None. Written as ``primvars:fabricLayers`` (``FABRIC_LAYERS``, uniform float: one value
            per face) when any face has more than one: DCCs import it as a face attribute.
        normal_maps: tangent-space normal maps over the UV layout, one per frame, shape
            (T, H, W, 3), unit vectors, zero outside the UV charts (DeepWrinkles' maps), or None.
            Needs ``uvs``. Written as PNG images applied by the material's ``normal`` input
            (``usd_io.textures``: encoding, the tangent-frame convention).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None
    uv_faces: np.ndarray | None = None
    normals: np.ndarray | None = None
    color: tuple[float, float, float] = CLOTH_COLOR
    face_layers: np.ndarray | None = None
    normal_maps: np.ndarray | None = None


# ----------------------------------------------------------------------------- checks


def _positions(a: np.ndarray, what: str) -> np.ndarray:
    """(T, V, 3) float32, finite, or ValueError naming ``what``."""
    a = np.ascontiguousarray(a, dtype=np.float32)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{what} must have shape (T, V, 3) with T, V >= 1, got {a.shape}")
    if not np.isfinite(a).all():
        frame = int(np.where(~np.isfinite(a).all(axis=(1, 2)))[0][0])
        raise ValueError(f"{what} has NaN/inf values at frame {frame}")
    return a


def _faces(f: np.ndarray, n: int, what: str) -> np.ndarray:
    """(F, 3) int32 indices in [0, n), or ValueError naming ``what``."""
    f = np.ascontiguousarray(f)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] < 1 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"{what} must be integer with shape (F, 3), got {f.dtype} {f.shape}")
    if f.min() < 0 or f.max() >= n:
        raise ValueError(f"{what} indices must lie in [0, {n}), got [{f.min()}, {f.max()}]")
    return f.astype(np.int32)


def _check_garment(g: GarmentTrack) -> GarmentTrack:
    verts = _positions(g.vertices, f"garment {g.name!r} vertices")
    faces = _faces(g.faces, verts.shape[1], f"garment {g.name!r} faces")
    uvs, uv_faces = g.uvs, g.uv_faces
    if uvs is not None:
        uvs = np.ascontiguousarray(uvs, dtype=np.float32)
        if uvs.ndim != 2 or uvs.shape[1] != 2 or not np.isfinite(uvs).all():
            raise ValueError(f"garment {g.name!r} uvs must be finite with shape (U, 2), got "
                             f"{uvs.shape}")
        if uv_faces is not None:
            uv_faces = _faces(uv_faces, uvs.shape[0], f"garment {g.name!r} uv_faces")
            if uv_faces.shape != faces.shape:
                raise ValueError(f"garment {g.name!r} uv_faces shape {uv_faces.shape} must "
                                 f"match faces {faces.shape}")
        elif uvs.shape[0] != verts.shape[1]:
            raise ValueError(f"garment {g.name!r} has {uvs.shape[0]} uvs but "
                             f"{verts.shape[1]} vertices and no uv_faces")
    elif uv_faces is not None:
        raise ValueError(f"garment {g.name!r} has uv_faces but no uvs")
    normals = g.normals
    if normals is not None:
        normals = np.ascontiguousarray(normals, dtype=np.float32)
        if normals.shape not in (verts.shape, verts.shape[1:]):
            raise ValueError(f"garment {g.name!r} normals must have shape {verts.shape} or "
                             f"{verts.shape[1:]}, got {normals.shape}")
    color = tuple(float(c) for c in g.color)
    if len(color) != 3 or not all(0.0 <= c <= 1.0 for c in color):
        raise ValueError(f"garment {g.name!r} color must be 3 floats in [0, 1], got {g.color}")
    layers = g.face_layers
    if layers is not None:
        layers = face_layers_array(layers, faces.shape[0], f"garment {g.name!r}").astype(np.float32)
    maps = g.normal_maps
    if maps is not None:
        if uvs is None:
            raise WrinklesInputError(f"garment {g.name!r} has normal_maps but no uvs to map them with")
        maps = check_normal_maps(maps, verts.shape[0], f"garment {g.name!r}")
    return GarmentTrack(g.name, verts, faces, uvs, uv_faces, normals, color, layers, maps)


def _metadata_json(metadata: dict | None) -> str:
    try:
        return json.dumps(metadata or {}, sort_keys=True)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"write_stage metadata must be JSON-serialisable: {exc}") from exc


# ----------------------------------------------------------------------------- authoring


def _define_material(stage: Usd.Stage, name: str, color: Sequence[float],
                     roughness: float) -> UsdShade.Material:
    """A ``UsdPreviewSurface`` material at ``/World/Looks/<name>``."""
    material = UsdShade.Material.Define(stage, f"{LOOKS_PATH}/{name}")
    shader = UsdShade.Shader.Define(stage, f"{LOOKS_PATH}/{name}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(roughness))
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def _define_mesh(stage: Usd.Stage, path: str, faces: np.ndarray, color: Sequence[float],
                 material: UsdShade.Material, double_sided: bool) -> UsdGeom.Mesh:
    """A triangle mesh with static topology; points are authored per frame later."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateDoubleSidedAttr(bool(double_sided))
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*color)]))
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def _author_uvs(mesh: UsdGeom.Mesh, g: GarmentTrack) -> None:
    """``primvars:st``: faceVarying, indexed by ``uv_faces`` (seams), or per-vertex."""
    if g.uvs is None:
        return
    api = UsdGeom.PrimvarsAPI(mesh.GetPrim())
    interp = UsdGeom.Tokens.faceVarying if g.uv_faces is not None else UsdGeom.Tokens.vertex
    st = api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, interp)
    st.Set(Vt.Vec2fArray.FromNumpy(g.uvs))
    if g.uv_faces is not None:
        st.SetIndices(Vt.IntArray.FromNumpy(g.uv_faces.reshape(-1)))


def _extents(vertices: np.ndarray) -> np.ndarray:
    """Per-frame bounding boxes [m], shape (T, 2, 3), float32."""
    return np.stack([vertices.min(axis=1), vertices.max(axis=1)], axis=1)


def _stage_path(final: Path) -> tuple[Path, str]:
    """Validate the output suffix; return (path, Sdf format)."""
    suffix = final.suffix.lower()
    if suffix not in SUFFIX_FORMATS:
        raise WrinklesInputError(
            f"unknown USD suffix {final.suffix!r}; use one of {sorted(SUFFIX_FORMATS)}",
            path=final)
    return final, SUFFIX_FORMATS[suffix]


def write_stage(
    path: str | os.PathLike,
    *,
    body: BodyFrames | None,
    fps: float,
    garments: Sequence[GarmentTrack] = (),
    body_name: str = "Body",
    metadata: dict | None = None,
    start_time_code: int = 0,
    write_joints: bool = True,
    progress: ProgressFn | None = None,
    rig: BodyRig | None = None,
    body_as: str | None = None,
    normal_map_bits: int = 16,
) -> Path:
    """Write an animated body and garments to a USD file, atomically.

    Args:
        path: output file; ``.usda`` (text), ``.usdc`` / ``.usd`` (binary crate) or ``.usdz``
            (package). Parent directories are created.
        body: the body over time (vertices [m] (T, V, 3), joints [m] (T, J, 3), world joint
            transforms (T, J, 4, 4), faces (F, 3)), or None for garments only.
        fps: frames per second [1/s]; becomes ``timeCodesPerSecond`` and ``framesPerSecond``.
        garments: garment tracks; each must have the same T as the body (and each other).
        body_name: prim name of the body under ``/World`` (default ``Body``; readers look
            for ``/World/Body`` and ``/World/BodyRig/Body``).
        metadata: provenance (command, config, versions ...), JSON-serialisable; stored as a
            JSON string in the root layer's ``customLayerData["wrinkles:metadata"]``.
        start_time_code: time code of frame 0.
        write_joints: with the point cache, also write the body joints as a guide
            ``UsdGeom.Points`` (a rig's skeleton holds them).
        progress: called as ``progress(frames_done, frames_total)`` after each frame; an
            exception raised from it aborts the write and leaves no file behind.
        rig: the body's skeleton and skin (``BodyModel.rig(betas)`` with the betas ``body``
            was posed with); it must reproduce ``body.vertices`` (``usd_io.skel.check_rig``).
        body_as: ``"skel"``: the body as a UsdSkel rig (needs ``rig``), a few hundred bytes of
            joint animation per frame; ``"points"``: a point cache, every vertex every frame.
            None: ``"skel"`` when a rig is given, else ``"points"``.
        normal_map_bits: bit depth of the garments' normal-map PNGs, 16 or 8 (files several
            times smaller; the normal's components within 1/255, ~0.2 degrees).

    Returns:
        The path written.

    Raises:
        WrinklesInputError: unknown suffix; bad normal maps or bit depth.
        ValueError: bad shapes, NaN/inf, mismatched frame counts, duplicate garment names,
            non-JSON metadata, non-positive fps, an unknown ``body_as``, ``"skel"`` without a
            rig, or a rig that does not reproduce the body.
    """
    final, fmt = _stage_path(Path(path))
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"write_stage fps must be positive, got {fps}")
    as_skel = _body_as_skel(body_as, rig)
    c = _content(body, garments, body_name, write_joints and not as_skel)
    if as_skel and body is not None:
        c = dataclasses.replace(c, rig=check_rig(rig, dataclasses.replace(
            body, vertices=c.body_verts, faces=c.body_faces)))
    meta_json = _metadata_json(metadata)
    maps = _MapsOut(final.stem + NORMALS_FOLDER_SUFFIX, check_bits(normal_map_bits))

    def author(stage: Usd.Stage, tmp_dir: Path) -> None:
        _author(stage, c, body=body, body_name=body_name, fps=float(fps),
                start=int(start_time_code), meta_json=meta_json, progress=progress,
                maps=dataclasses.replace(maps, where=tmp_dir / maps.folder))

    has_maps = any(g.normal_maps is not None for g in c.tracks)
    _write_layer(final, fmt, author, folder=maps.folder if has_maps else None)
    return final


def _body_as_skel(body_as: str | None, rig: BodyRig | None) -> bool:
    """Whether the body is written as a rig (``write_stage``'s ``body_as``)."""
    if body_as is None:
        return rig is not None
    if body_as not in BODY_AS:
        raise ValueError(f"body_as must be one of {BODY_AS}, got {body_as!r}")
    if body_as == "skel" and rig is None:
        raise ValueError("body_as='skel' needs the body's rig (BodyModel.rig(betas))")
    return body_as == "skel"


@dataclass(frozen=True)
class _MapsOut:
    """Where a stage's normal maps go: ``folder`` beside the stage (its name in the asset
    paths), written at ``where`` (inside the temporary directory), at ``bits`` per channel."""

    folder: str
    bits: int
    where: Path | None = None


@dataclass(frozen=True)
class _Content:
    """The checked arrays of a stage (see ``write_stage``); ``rig`` set for a rigged body."""

    body_verts: np.ndarray | None
    body_faces: np.ndarray | None
    joints: np.ndarray | None
    tracks: list[GarmentTrack]
    names: list[str]
    n_frames: int
    rig: BodyRig | None = None


def _content(body: BodyFrames | None, garments: Sequence[GarmentTrack], body_name: str,
             write_joints: bool) -> _Content:
    """Shapes, finiteness, frame counts and names checked (``ValueError`` naming what is wrong)."""
    tracks = [_check_garment(g) for g in garments]
    body_verts = None if body is None else _positions(body.vertices, "body vertices")
    body_faces = None
    if body is not None:
        body_faces = _faces(body.faces, body_verts.shape[1], "body faces")
    counts = ([] if body_verts is None else [body_verts.shape[0]]) + [
        g.vertices.shape[0] for g in tracks]
    if not counts:
        raise ValueError("write_stage needs a body or at least one garment")
    if len(set(counts)) != 1:
        raise ValueError(f"body and garments must have the same number of frames, got {counts}")
    n_frames = counts[0]
    names = [Tf.MakeValidIdentifier(g.name) for g in tracks]
    if len(set(names)) != len(names):
        raise ValueError(f"garment names must be unique as USD identifiers, got {names}")
    if not Tf.IsValidIdentifier(body_name):
        raise ValueError(f"body_name must be a valid USD identifier, got {body_name!r}")
    joints = None
    if body is not None and write_joints and body.joints is not None:
        joints = _positions(body.joints, "body joints")
        if joints.shape[0] != n_frames:
            raise ValueError(f"body joints have {joints.shape[0]} frames, vertices {n_frames}")
    return _Content(body_verts, body_faces, joints, tracks, names, n_frames)


def _write_layer(final: Path, fmt: str, author: Callable[[Usd.Stage, Path], None], *,
                 folder: str | None = None) -> None:
    """A new layer of format ``fmt`` authored by ``author(stage, tmp_dir)`` in a temporary
    directory beside ``final`` (packaged for ``.usdz``), then renamed to ``final``; nothing is
    left on error. ``folder``: a folder the author wrote in ``tmp_dir`` (files the layer refers
    to by relative paths), packaged for ``.usdz``, else renamed beside ``final`` just before it."""
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".partial",
                                    dir=final.parent))
    try:
        layer_path = tmp_dir / (final.stem + (".usdc" if final.suffix.lower() == ".usdz"
                                              else final.suffix))
        layer = Sdf.Layer.CreateNew(str(layer_path), args={"format": fmt})
        if layer is None:
            raise OSError(f"{final}: cannot create a USD layer at {layer_path}")
        stage = Usd.Stage.Open(layer)
        author(stage, tmp_dir)
        layer.Save()
        del stage, layer
        if final.suffix.lower() == ".usdz":
            packaged = tmp_dir / (final.stem + ".usdz")
            if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(layer_path)), str(packaged)):
                raise OSError(f"{final}: could not create the usdz package")
            layer_path, folder = packaged, None
        _replace_with_folder(layer_path, final, tmp_dir, folder)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


def _replace_with_folder(layer_path: Path, final: Path, tmp_dir: Path, folder: str | None) -> None:
    """Rename ``layer_path`` to ``final``, and first ``tmp_dir / folder`` beside it (whatever had
    its name is moved into ``tmp_dir``, to be deleted with it, or put back if the stage's rename
    fails)."""
    if folder is None:
        os.replace(layer_path, final)
        return
    dest, old = final.parent / folder, tmp_dir / ".previous"
    had_old = os.path.lexists(dest)
    if had_old:
        os.replace(dest, old)
    try:
        os.replace(tmp_dir / folder, dest)
        os.replace(layer_path, final)
    except BaseException:
        if os.path.lexists(dest) and not os.path.lexists(tmp_dir / folder):
            os.replace(dest, tmp_dir / folder)
        if had_old:
            os.replace(old, dest)
        raise


#: per-frame values to author: (attribute, values (T, ...), Vt array constructor).
_Samples = list[tuple[Usd.Attribute, np.ndarray, Callable]]


def _author(stage: Usd.Stage, c: _Content, *, body: BodyFrames | None, body_name: str, fps: float,
            start: int, meta_json: str, progress: ProgressFn | None, maps: _MapsOut) -> None:
    """Author everything into ``stage`` (see ``write_stage``)."""
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(start)
    stage.SetEndTimeCode(start + c.n_frames - 1)
    layer_data = {METADATA_KEY: meta_json, "wrinkles:usdVersion": ".".join(
        str(v) for v in Usd.GetVersion())}
    stage.GetRootLayer().customLayerData = layer_data

    world = UsdGeom.Xform.Define(stage, WORLD_PATH)
    stage.SetDefaultPrim(world.GetPrim())
    UsdGeom.Scope.Define(stage, LOOKS_PATH)

    samples: _Samples = []
    images: list[Callable[[int], None]] = []  # each writes frame k's image of one garment
    if c.body_verts is not None:
        samples += _author_body(stage, c, body, body_name)
    if c.tracks:
        UsdGeom.Scope.Define(stage, GARMENTS_PATH)
    for g, name in zip(c.tracks, c.names, strict=True):
        samples += _author_garment(stage, g, name)
        if g.normal_maps is not None:
            samples.append(_author_normal_maps(stage, g, name, maps))
            images.append(_image_writer(g.normal_maps, name, maps))

    for k in range(c.n_frames):
        t = Usd.TimeCode(start + k)
        with Sdf.ChangeBlock():
            for attr, values, make in samples:
                attr.Set(make(values[k]), t)
        for write_image in images:
            write_image(k)
        if progress is not None:
            progress(k + 1, c.n_frames)


def _author_body(stage: Usd.Stage, c: _Content, body: BodyFrames, body_name: str) -> _Samples:
    """The body as a rig (``c.rig``) or a point cache, and its joints; returns the samples."""
    mat = _define_material(stage, f"{body_name}Material", SKIN_COLOR, roughness=0.6)

    def define(path: str) -> UsdGeom.Mesh:
        return _define_mesh(stage, path, c.body_faces, SKIN_COLOR, mat, double_sided=False)

    if c.rig is not None:
        rigged = dataclasses.replace(body, vertices=c.body_verts)
        return define_skel_body(stage, f"{WORLD_PATH}/{body_name}{RIG_SUFFIX}", body_name, c.rig,
                                rigged, define).samples
    mesh = define(f"{WORLD_PATH}/{body_name}")
    samples: _Samples = [(mesh.CreatePointsAttr(), c.body_verts, Vt.Vec3fArray.FromNumpy),
                         (mesh.CreateExtentAttr(), _extents(c.body_verts), Vt.Vec3fArray.FromNumpy)]
    if c.joints is not None:
        pts = UsdGeom.Points.Define(stage, f"{WORLD_PATH}/{body_name}Joints")
        pts.CreatePurposeAttr(UsdGeom.Tokens.guide)
        pts.CreateWidthsAttr(Vt.FloatArray([JOINT_WIDTH]))
        pts.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        half = np.float32(JOINT_WIDTH / 2)
        ext = _extents(c.joints) + np.array([-half, half], np.float32)[None, :, None]
        samples += [(pts.CreatePointsAttr(), c.joints, Vt.Vec3fArray.FromNumpy),
                    (pts.CreateExtentAttr(), ext, Vt.Vec3fArray.FromNumpy)]
    return samples


def _author_garment(stage: Usd.Stage, g: GarmentTrack, name: str) -> _Samples:
    """A garment mesh (material, UVs, fabric layers, normals); returns its samples."""
    mat = _define_material(stage, f"{name}Material", g.color, roughness=0.9)
    mesh = _define_mesh(stage, f"{GARMENTS_PATH}/{name}", g.faces, g.color, mat,
                        double_sided=True)
    if name != g.name:
        mesh.GetPrim().SetCustomDataByKey("wrinkles:name", g.name)
    _author_uvs(mesh, g)
    if g.face_layers is not None and (g.face_layers > 1.0).any():
        layers = UsdGeom.PrimvarsAPI(mesh.GetPrim()).CreatePrimvar(
            FABRIC_LAYERS, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.uniform)
        layers.Set(Vt.FloatArray.FromNumpy(g.face_layers))
    samples: _Samples = [
        (mesh.CreatePointsAttr(), g.vertices, Vt.Vec3fArray.FromNumpy),
        (mesh.CreateExtentAttr(), _extents(g.vertices), Vt.Vec3fArray.FromNumpy)]
    if g.normals is not None:
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        normals = mesh.CreateNormalsAttr()
        if g.normals.ndim == 2:
            normals.Set(Vt.Vec3fArray.FromNumpy(g.normals))
        else:
            samples.append((normals, g.normals, Vt.Vec3fArray.FromNumpy))
    return samples


def _author_normal_maps(stage: Usd.Stage, g: GarmentTrack, name: str, maps: _MapsOut) -> tuple:
    """The garment material's normal texture (``usd_io.textures.define_normal_texture``); returns
    the sample of its per-frame image paths."""
    files = normal_map_files(maps.folder, name, len(g.normal_maps))
    material = UsdShade.Material.Get(stage, f"{LOOKS_PATH}/{name}Material")
    surface = UsdShade.Shader.Get(stage, f"{LOOKS_PATH}/{name}Material/PreviewSurface")
    attr = define_normal_texture(stage, material, surface, files[0])
    return attr, np.asarray(files), lambda f: Sdf.AssetPath(str(f))


def _image_writer(normal_maps: np.ndarray, name: str, maps: _MapsOut) -> Callable[[int], None]:
    """``write(k)``: frame k's normal map as a PNG in ``maps.where`` (made on first use)."""
    files = normal_map_files(maps.folder, name, len(normal_maps))

    def write(k: int) -> None:
        maps.where.mkdir(exist_ok=True)
        write_png(maps.where / Path(files[k]).name, encode_normal_map(normal_maps[k], maps.bits))

    return write
