"""Read animated meshes back from a USD stage (the inverse of ``usd_io.write``)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Tf, Usd, UsdGeom

from sim.errors import WrinklesInputError
from usd_io.skel import is_skinned, skinned_points
from usd_io.write import BODY_PATH, FABRIC_LAYERS, JOINTS_PATH, METADATA_KEY, SKEL_BODY_PATH

#: where a body mesh is looked for: the point cache, then the rig's skinned mesh.
BODY_PATHS = (BODY_PATH, SKEL_BODY_PATH)


@dataclass(frozen=True)
class MeshData:
    """One ``UsdGeom.Mesh`` of a stage.

    Attributes:
        name: prim name (``Body``, a garment name ...).
        path: prim path, e.g. ``/World/Garments/shirt``.
        faces: triangle indices, shape (F, 3), int32 (polygons fan-triangulated).
        points: positions [stage units; m for our stages] at each of the stage's time codes,
            shape (T, V, 3), float32 (static points are repeated; a mesh bound to a UsdSkel
            skeleton is posed by UsdSkel: blend shapes, then skinning).
        uvs: ``primvars:st`` values, shape (U, 2), float32, or None.
        uv_faces: per-corner indices into ``uvs``, shape (F, 3), int32, or None (None with
            ``uvs`` means per-vertex UVs).
        normals: authored normals, shape (T, V, 3) float32, or None.
        face_layers: ``primvars:fabricLayers`` (a garment's hems), one per triangle, shape (F,),
            float32, or None where the mesh has none (or not one per face).
    """

    name: str
    path: str
    faces: np.ndarray
    points: np.ndarray
    uvs: np.ndarray | None = None
    uv_faces: np.ndarray | None = None
    normals: np.ndarray | None = None
    face_layers: np.ndarray | None = None


@dataclass(frozen=True)
class StageData:
    """What ``read_stage`` found.

    Attributes:
        path: the file read.
        fps: ``timeCodesPerSecond`` [time codes per second]; one frame per time code.
        frames_per_second: ``framesPerSecond`` (playback rate hint).
        up_axis: ``"Y"`` or ``"Z"``.
        meters_per_unit: metres per stage unit (1 for our stages).
        start_time_code: first time code.
        end_time_code: last time code.
        time_codes: the time codes sampled, shape (T,), float64.
        meshes: every mesh prim by path, in stage traversal order.
        joints: body joint positions [m], shape (T, J, 3), float32 (the guide points of a
            point cache, the skeleton's joints of a rig), or None.
        metadata: the provenance dict stored by ``write_stage`` ({} when absent).
    """

    path: str
    fps: float
    frames_per_second: float
    up_axis: str
    meters_per_unit: float
    start_time_code: float
    end_time_code: float
    time_codes: np.ndarray
    meshes: dict[str, MeshData]
    joints: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)

    @property
    def body(self) -> MeshData | None:
        """The body mesh (``/World/Body``, or ``/World/BodyRig/Body`` of a rig), or None."""
        return next((self.meshes[p] for p in BODY_PATHS if p in self.meshes), None)

    @property
    def garments(self) -> dict[str, MeshData]:
        """Garment meshes by name (those under ``/World/Garments``)."""
        return {m.name: m for m in self.meshes.values() if m.path.startswith("/World/Garments/")}


def open_stage(path: str | os.PathLike) -> Usd.Stage:
    """Open a USD file, or raise ``WrinklesInputError`` naming it."""
    path = Path(path)
    if not path.is_file():
        raise WrinklesInputError("USD file not found", path=path)
    try:
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    except Tf.ErrorException:
        raise WrinklesInputError("not a readable USD file (the USD parser rejected it)",
                                 path=path) from None
    if stage is None:
        raise WrinklesInputError("not a readable USD file", path=path)
    return stage


def _fan(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons; returns corner positions into ``indices``, shape (F', 3)."""
    if counts.size and np.all(counts == 3):
        return np.arange(indices.size, dtype=np.int64).reshape(-1, 3)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tris = [(s, s + i, s + i + 1) for s, c in zip(starts, counts, strict=True)
            for i in range(1, c - 1)]
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def _samples(attr: Usd.Attribute, times: list[Usd.TimeCode], n: int) -> np.ndarray | None:
    """Vec3f attribute at each time -> (T, n, 3) float32, or None when unauthored."""
    if not attr or not attr.HasAuthoredValue():
        return None
    if attr.GetNumTimeSamples() == 0:
        value = attr.Get()
        if value is None:
            return None
        one = np.asarray(value, dtype=np.float32).reshape(-1, 3)
        return np.repeat(one[None], len(times), axis=0) if one.shape[0] == n else None
    out = np.empty((len(times), n, 3), np.float32)
    for k, t in enumerate(times):
        value = np.asarray(attr.Get(t), dtype=np.float32).reshape(-1, 3)
        if value.shape[0] != n:
            return None
        out[k] = value
    return out


def _read_mesh(mesh: UsdGeom.Mesh, times: list[Usd.TimeCode], file: Path,
               posed: np.ndarray | None = None) -> MeshData:
    """One mesh; ``posed`` (T, V, 3) replaces its authored points (a skinned mesh)."""
    prim = mesh.GetPrim()
    where = f"mesh {prim.GetPath()}"
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int64)
    if counts.sum() != indices.size or np.any(counts < 3):
        raise WrinklesInputError(f"{where} has inconsistent faceVertexCounts / "
                                 "faceVertexIndices", path=file)
    corners = _fan(counts, indices)
    n = len(mesh.GetPointsAttr().Get(times[0]) or [])
    points = _samples(mesh.GetPointsAttr(), times, n) if posed is None else posed
    if points is None:
        raise WrinklesInputError(f"{where} has no points or a changing point count", path=file)
    if indices.size and (indices.min() < 0 or indices.max() >= n):
        raise WrinklesInputError(f"{where} faceVertexIndices out of range for {n} points",
                                 path=file)
    uvs = uv_faces = None
    st = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
    if st and st.HasAuthoredValue():
        uvs = np.asarray(st.Get(), dtype=np.float32).reshape(-1, 2)
        interp = st.GetInterpolation()
        if interp == UsdGeom.Tokens.faceVarying:
            corner_uv = (np.asarray(st.GetIndices(), dtype=np.int64) if st.IsIndexed()
                         else np.arange(uvs.shape[0], dtype=np.int64))
            uv_faces = corner_uv[corners].astype(np.int32)
        elif interp not in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
            uvs = None  # constant/uniform UVs carry no per-corner information
        elif st.IsIndexed():
            uvs = uvs[np.asarray(st.GetIndices(), dtype=np.int64)]
    normals = _samples(mesh.GetNormalsAttr(), times, n)
    face_layers = None
    layers = UsdGeom.PrimvarsAPI(prim).GetPrimvar(FABRIC_LAYERS)
    if layers and layers.HasAuthoredValue() and layers.GetInterpolation() == UsdGeom.Tokens.uniform:
        per_face = np.asarray(layers.ComputeFlattened(), dtype=np.float32).reshape(-1)
        if per_face.size == counts.size:  # one per polygon: one per fan triangle
            face_layers = np.repeat(per_face, counts - 2)
    return MeshData(name=prim.GetName(), path=str(prim.GetPath()),
                    faces=indices[corners].astype(np.int32), points=points, uvs=uvs,
                    uv_faces=uv_faces, normals=normals, face_layers=face_layers)


def read_stage(path: str | os.PathLike, *, require_body: bool = True) -> StageData:
    """Read every mesh of a stage, with points at each time code.

    Args:
        path: a ``.usda`` / ``.usdc`` / ``.usd`` / ``.usdz`` file.
        require_body: raise when there is no body mesh (``BODY_PATHS``).

    Returns:
        The stage's timing, units and meshes. Frames are the integer time codes from
        ``startTimeCode`` to ``endTimeCode`` (one sample at the default time when the stage
        has no time range). A skinned mesh's points are UsdSkel's posed points.

    Raises:
        WrinklesInputError: missing file, not USD, no body mesh (when required), or
            malformed mesh topology; the message names the file.
    """
    file = Path(path)
    stage = open_stage(file)
    if require_body and not any((prim := stage.GetPrimAtPath(p)) and prim.IsA(UsdGeom.Mesh)
                                for p in BODY_PATHS):
        raise WrinklesInputError(f"no {' or '.join(BODY_PATHS)} mesh in the stage", path=file)
    if stage.HasAuthoredTimeCodeRange():
        start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
        codes = np.arange(start, end + 0.5, 1.0, dtype=np.float64)
        times = [Usd.TimeCode(float(c)) for c in codes]
    else:
        start = end = 0.0
        codes = np.zeros(1)
        times = [Usd.TimeCode.Default()]
    meshes: dict[str, MeshData] = {}
    joints = None
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            skinned = skinned_points(stage, prim, times) if is_skinned(prim) else None
            path = str(prim.GetPath())
            meshes[path] = _read_mesh(UsdGeom.Mesh(prim), times, file,
                                      None if skinned is None else skinned[0])
            if skinned is not None and path == SKEL_BODY_PATH:
                joints = skinned[1]
    joint_prim = stage.GetPrimAtPath(JOINTS_PATH)
    if joint_prim and joint_prim.IsA(UsdGeom.Points):
        attr = UsdGeom.Points(joint_prim).GetPointsAttr()
        joints = _samples(attr, times, len(attr.Get(times[0]) or []))
    raw = stage.GetRootLayer().customLayerData.get(METADATA_KEY)
    try:
        metadata = json.loads(raw) if isinstance(raw, str) else {}
    except json.JSONDecodeError:
        raise WrinklesInputError(f"customLayerData {METADATA_KEY!r} is not JSON",
                                 path=file) from None
    return StageData(
        path=str(file),
        fps=float(stage.GetTimeCodesPerSecond()),
        frames_per_second=float(stage.GetFramesPerSecond()),
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)),
        start_time_code=float(start),
        end_time_code=float(end),
        time_codes=codes,
        meshes=meshes,
        joints=joints,
        metadata=metadata,
    )


__all__ = ["BODY_PATHS", "MeshData", "StageData", "open_stage", "read_stage"]
