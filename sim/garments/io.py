"""Import a user garment mesh (OBJ / PLY / GLB / glTF / OFF / STL via trimesh) with its UVs.

Repairs what can be repaired without changing the surface (``sim.garments.repair``: duplicate
vertices merged while UV seams are kept, needle edges collapsed, collapsed faces and faces
given twice dropped, slivers flipped or dropped, tiny disconnected pieces and unused vertices
removed) and refuses the rest with a one-line ``WrinklesInputError`` naming the file: no UVs,
non-manifold edges, slivers that only the modelling tool can fix. A file that loads has faces
a simulation can use.

USD files are read above ``sim`` (``pipelines.garment_files.load_garment_file``, through
``usd_io``), which hands its reader to ``load_garment``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.hems import HEM_LAYERS, hem_face_layers
from sim.garments.materials import Material, get_material
from sim.garments.parameters import HEM_SPECS, check_parameter
from sim.garments.repair import SHORT_EDGE, TINY_COMPONENT, repair_mesh
from sim.garments.types import Garment

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".off", ".stl")
"""Garment files ``read_mesh`` reads."""
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
"""Garment files read by ``pipelines.garment_files`` (``sim`` does not read USD)."""


class GarmentMesh(NamedTuple):
    """A garment file's first mesh as read, before repair."""

    points: np.ndarray  # (V, 3) [m], Y up
    faces: np.ndarray  # (F, 3) indices into points
    uvs: np.ndarray | None  # (U, 2), None: the file has none
    uv_faces: np.ndarray | None  # (F, 3) indices into uvs


def read_mesh(path: Path) -> GarmentMesh:
    """The first triangle mesh of a file trimesh reads (``MESH_SUFFIXES``), read as metres,
    Y up; UVs per vertex as trimesh gives them (vertices split along UV seams)."""
    suffix = path.suffix.lower()
    if suffix in USD_SUFFIXES:
        raise WrinklesInputError("USD garment files are read by pipelines.garment_files.load_garment_file "
                                 "(the simulator core does not read USD)", path=path)
    if suffix not in MESH_SUFFIXES:
        raise WrinklesInputError(f"unsupported garment format {suffix!r}; expected one of "
                                 f"{', '.join(MESH_SUFFIXES + USD_SUFFIXES)}", path=path)
    import trimesh

    try:
        # no maintain_order: with it, the OBJ reader keeps one UV per position and loses seams
        loaded = trimesh.load(path, process=False)
    except Exception as exc:  # trimesh raises many types for broken files
        raise WrinklesInputError(f"cannot read mesh: {type(exc).__name__}: {exc}", path=path) from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
        if not geoms:
            raise WrinklesInputError("no triangle mesh in the file", path=path)
        loaded = geoms[0]
    if not isinstance(loaded, trimesh.Trimesh):
        raise WrinklesInputError(f"not a triangle mesh ({type(loaded).__name__})", path=path)
    uv = getattr(loaded.visual, "uv", None)
    points = np.asarray(loaded.vertices, np.float64)
    faces = np.asarray(loaded.faces, np.int64)
    if uv is None or len(uv) != len(points):
        return GarmentMesh(points, faces, None, None)
    # trimesh splits vertices along UV seams: per-vertex UVs, uv_faces == faces before merging
    return GarmentMesh(points, faces, np.asarray(uv, np.float64), faces.copy())


def load_garment(path: str | os.PathLike, *, material: str | Material = "cotton", name: str | None = None,
                 require_uvs: bool = True, hem_width: float = 0.0, hem_layers: float = HEM_LAYERS,
                 read: Callable[[Path], GarmentMesh] = read_mesh) -> Garment:
    """Read a garment mesh, repair it, and check it is a usable cloth mesh.

    Args:
        path: .obj, .ply, .glb/.gltf, .off, .stl (read as metres, Y up); with ``read``, any
            file that reader reads.
        material: preset name or ``Material``.
        name: garment name (default: the file stem).
        require_uvs: refuse meshes without UVs.
        hem_width, hem_layers: hems along every boundary loop, as the templates have
            (``sim.garments.hems``); 0, the default: none (a file does not say how its
            openings are sewn).
        read: ``read(path) -> GarmentMesh`` (``read_mesh``; ``pipelines.garment_files`` passes
            its USD reader).

    Returns:
        Garment with category "imported", all faces in one panel (``"mesh"``; UV islands are
        not turned into panels), no attachments, and what was repaired in ``repairs``
        (``sim.garments.repair.repair_mesh``'s counts).

    Raises:
        WrinklesInputError: unreadable, empty, no UVs (when required), non-manifold edges,
            degenerate triangles that no repair fixes.
    """
    path = Path(path)
    for key, value in (("hem_width", hem_width), ("hem_layers", hem_layers)):
        check_parameter(key, value, HEM_SPECS[key], "load_garment", path=path)
    if not path.is_file():
        raise WrinklesInputError("no such file", path=path)
    mesh = repair_mesh(*_checked(read(path), require_uvs, path), path=path)
    rest, tris = mesh.points.astype(np.float32), mesh.faces.astype(np.int32)
    return Garment(rest_vertices=rest, faces=tris, uvs=mesh.uvs.astype(np.float32),
                   uv_faces=mesh.uv_faces.astype(np.int32), material=get_material(material), attachments={},
                   category="imported", name=name or path.stem, panel_ids=np.zeros(len(tris), np.int32),
                   panel_names=("mesh",), face_layers=hem_face_layers(rest, tris, hem_width, hem_layers),
                   repairs=mesh.repairs)


def _checked(mesh: GarmentMesh, require_uvs: bool, path: Path) -> GarmentMesh:
    """The mesh if it has faces, finite positions and (when required) usable UVs; a mesh
    without UVs that may go without gets one UV at the origin."""
    points, faces, uvs, uv_faces = mesh
    if len(points) == 0 or len(faces) == 0:
        raise WrinklesInputError("the mesh is empty", path=path)
    if not np.all(np.isfinite(points)):
        raise WrinklesInputError("vertex positions contain NaN/inf", path=path)
    if uvs is None and require_uvs:
        raise WrinklesInputError("the mesh has no UVs (texture coordinates); UVs are required", path=path)
    if uvs is None:
        uvs, uv_faces = np.zeros((1, 2)), np.zeros_like(faces)
    elif require_uvs:
        d1, d2 = uvs[uv_faces[:, 1]] - uvs[uv_faces[:, 0]], uvs[uv_faces[:, 2]] - uvs[uv_faces[:, 0]]
        uv_area = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).sum()
        if not np.all(np.isfinite(uvs)) or uv_area <= 1e-12:
            raise WrinklesInputError("the mesh's UVs are NaN/inf or all collapsed (zero UV area); "
                                     "UVs are required", path=path)
    return GarmentMesh(points, faces, uvs, uv_faces)


def describe_drops(repairs: dict[str, int]) -> str:
    """What a garment file's repair changed in its surface (``Garment.repairs``), in words (''
    if nothing; merged duplicate vertices, e.g. split along UV seams, and unused vertices are
    no change and not told)."""
    parts = []
    if repairs.get("short_edges_collapsed"):
        parts.append(f"collapsed {repairs['short_edges_collapsed']} needle edges (under "
                     f"{100 * SHORT_EDGE:g} % of the median edge)")
    if repairs.get("collapsed_faces_dropped"):
        parts.append(f"dropped {repairs['collapsed_faces_dropped']} collapsed (zero-area) faces")
    if repairs.get("duplicate_faces_dropped"):
        parts.append(f"dropped {repairs['duplicate_faces_dropped']} faces given twice")
    if repairs.get("tiny_pieces_dropped"):
        parts.append(f"dropped {repairs['tiny_pieces_dropped']} stray piece(s) of "
                     f"{repairs['tiny_piece_faces_dropped']} faces (each under {100 * TINY_COMPONENT:g} % "
                     "of the mesh)")
    if repairs.get("sliver_edges_flipped"):
        parts.append(f"flipped the long edge of {repairs['sliver_edges_flipped']} sliver triangles")
    if repairs.get("slivers_dropped"):
        parts.append(f"dropped {repairs['slivers_dropped']} sliver triangles that covered nothing")
    return "; ".join(parts)


FIT_MARGIN = 0.3
"""How far [m] beyond the rest body's bounding box a garment vertex may lie and still count as
around the body (``check_garment_on_body``): a flared hem, a cape or a loose sleeve reaches
this far past the body; a garment modelled elsewhere, or in other units, does not."""


def check_garment_on_body(garment: Garment, body_vertices: np.ndarray, path: str | os.PathLike) -> None:
    """Refuse a garment file that is not modelled around the body in its rest pose, with one
    line naming the file: one far larger or smaller than the body (other units: centimetres read
    as metres), one with more than a tenth of its vertices ``FIT_MARGIN`` outside the body's
    box, or one reaching above the head by more than that (another frame: e.g. modelled around a
    body standing on the floor, where the simulator's rest body has its pelvis near the origin;
    ``wrinkles garments --export NAME --body-out FILE`` writes that body: every template lifted
    into it is refused). Smaller shifts, up to ~0.6 m for a skirt, are not caught.

    Args:
        garment: the garment as loaded (``load_garment``).
        body_vertices: the body's rest-pose vertices [m] (``BodyModel.rest_mesh(betas)``).
        path: the garment file, for the message.
    """
    x = np.asarray(garment.rest_vertices, np.float64)
    b = np.asarray(body_vertices, np.float64)
    lo, hi = b.min(axis=0), b.max(axis=0)
    height = float(hi[1] - lo[1])
    size = float(np.linalg.norm(x.max(axis=0) - x.min(axis=0)))
    if size > 3.0 * height or size < 0.02 * height:
        cm = 30.0 * height < size < 300.0 * height
        units = " (in centimetres? garment files are read in metres)" if cm else ""
        raise WrinklesInputError(f"the garment is {size:.3g} m across, the body {height:.2f} m tall{units}; "
                                 "model it around the body in its rest pose, in metres", path=path)
    near = np.all((x >= lo - FIT_MARGIN) & (x <= hi + FIT_MARGIN), axis=1).mean()
    top = float(x[:, 1].max())
    # nearly all of it near the body, and nothing above the head: a long garment (a dress,
    # trousers) lifted into the floor-standing frame keeps half its vertices in the tall box
    if near < 0.9 or top > hi[1] + FIT_MARGIN:
        off = np.maximum(np.maximum(lo - x, x - hi), 0.0)
        gap = float(np.median(np.linalg.norm(off, axis=1)))
        centre = 0.5 * (x.min(axis=0) + x.max(axis=0))
        raise WrinklesInputError(
            f"the garment is not around the body: {100.0 * (1.0 - near):.0f}% of its vertices lie more than "
            f"{FIT_MARGIN:g} m outside the rest body's box (median {gap:.2f} m; garment centre "
            f"({centre[0]:.2f}, {centre[1]:.2f}, {centre[2]:.2f}), top y {top:.2f} m; body box y "
            f"{lo[1]:.2f} to {hi[1]:.2f} m); "
            "model it around the body in its rest pose, in the frame 'wrinkles garments --export NAME "
            "--body-out body.obj' writes", path=path)
