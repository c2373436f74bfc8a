"""Import a user garment mesh (OBJ / PLY / GLB / glTF / OFF / STL via trimesh) with its UVs.

Repairs what is safe to repair (duplicate vertices merged while UV seams are kept, faces that
collapse to an edge or a point once duplicates are merged dropped, faces given twice dropped,
tiny disconnected pieces dropped) and refuses the rest with a one-line ``WrinklesInputError``
naming the file: no UVs, non-manifold edges, degenerate triangles (three distinct vertices, no
area: removing one leaves a crack, so the mesh needs fixing in the modelling tool).

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
from sim.garments.types import Garment

MERGE_TOL = 1e-6
"""Vertices closer than 1 µm are one vertex (exporters split them along UV seams) [m]."""
TINY_COMPONENT = 0.05
"""Components with fewer than 5 % of the faces are stray pieces and are dropped."""
DEGENERATE_AREA = 1e-12
"""Faces below 1e-12 m² (1 µm × 1 µm) have no usable normal [m²]."""
DEGENERATE_ASPECT = 1e-6
"""A face whose height is below 2e-6 × its longest edge (area / longest² < 1e-6) is a
needle with a vertex on the opposite edge (a T-junction) [-]."""
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


def _edge_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0, return_counts=True)


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
        (duplicate positions merged, collapsed faces, faces given twice and stray pieces
        dropped).

    Raises:
        WrinklesInputError: unreadable, empty, no UVs (when required), non-manifold edges,
            degenerate triangles.
    """
    path = Path(path)
    for key, value in (("hem_width", hem_width), ("hem_layers", hem_layers)):
        check_parameter(key, value, HEM_SPECS[key], "load_garment", path=path)
    if not path.is_file():
        raise WrinklesInputError("no such file", path=path)
    points, faces, uvs, uv_faces = _checked(read(path), require_uvs, path)
    n_read = len(points)
    points, faces = _merge_duplicates(points, faces)
    faces, uv_faces, n_degenerate = _drop_collapsed(points, faces, uv_faces, path)
    # faces given twice (the same three vertices, either winding: an exporter's double) would
    # otherwise read as non-manifold edges
    _, first_face = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    unique = np.zeros(len(faces), bool)
    unique[first_face] = True
    n_duplicate = int((~unique).sum())
    faces, uv_faces = faces[unique], uv_faces[unique]
    edges = _manifold_edges(points, faces, n_degenerate, path)
    faces, uv_faces, tiny = _drop_tiny_pieces(len(points), faces, uv_faces, edges)
    repairs = {"merged_vertices": int(n_read - len(points)), "collapsed_faces_dropped": n_degenerate,
               "duplicate_faces_dropped": n_duplicate, **tiny}
    # compact vertices and UVs
    used = np.unique(faces)
    remap = np.full(len(points), -1, np.int64)
    remap[used] = np.arange(len(used))
    used_uv = np.unique(uv_faces)
    remap_uv = np.full(len(uvs), -1, np.int64)
    remap_uv[used_uv] = np.arange(len(used_uv))
    rest, tris = points[used].astype(np.float32), remap[faces].astype(np.int32)
    return Garment(rest_vertices=rest, faces=tris,
                   uvs=uvs[used_uv].astype(np.float32), uv_faces=remap_uv[uv_faces].astype(np.int32),
                   material=get_material(material), attachments={}, category="imported",
                   name=name or path.stem, panel_ids=np.zeros(len(faces), np.int32), panel_names=("mesh",),
                   face_layers=hem_face_layers(rest, tris, hem_width, hem_layers),
                   repairs={k: v for k, v in repairs.items() if v})


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


def _merge_duplicates(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions within ``MERGE_TOL`` merged into their first occurrence, in reading order (UV
    seams stay: uv_faces keep their own indices)."""
    key = np.round(points / MERGE_TOL).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return points[first[order]], rank[inv.reshape(-1)][faces]


def _drop_collapsed(points: np.ndarray, faces: np.ndarray, uv_faces: np.ndarray, path: Path):
    """Faces that collapsed to an edge or a point dropped (a repair); flat ones with three
    distinct vertices refused (removing them would open a crack along their longest edge).

    Returns:
        (faces, uv_faces, number dropped).
    """
    same = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    tri = points[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    longest = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2).max(axis=1)
    flat = ~same & ((area <= DEGENERATE_AREA) | (area <= DEGENERATE_ASPECT * longest ** 2))
    if flat.any():
        k = int(np.flatnonzero(flat)[0])
        x, y, z = tri[k].mean(axis=0)
        raise WrinklesInputError(
            f"{int(flat.sum())} degenerate triangle(s) with three distinct vertices and no area, e.g. "
            f"face {k} at ({x:.4g}, {y:.4g}, {z:.4g}); fix the mesh (merge the vertex that lies on "
            "the opposite edge, or flip that edge)", path=path)
    faces, uv_faces = faces[~same], uv_faces[~same]
    if len(faces) == 0:
        raise WrinklesInputError("every face is degenerate (zero area)", path=path)
    return faces, uv_faces, int(same.sum())


def _manifold_edges(points: np.ndarray, faces: np.ndarray, n_degenerate: int, path: Path) -> np.ndarray:
    """The mesh's unique edges (E, 2); refused when one is in more than two faces."""
    edges, counts = _edge_counts(faces)
    bad = counts > 2
    if bad.any():
        a, b = edges[bad][0]
        x, y, z = 0.5 * (points[a] + points[b])
        extra = f" (after removing {n_degenerate} collapsed faces)" if n_degenerate else ""
        raise WrinklesInputError(f"{int(bad.sum())} non-manifold edges (in more than 2 faces){extra}, "
                                 f"e.g. the edge at ({x:.4g}, {y:.4g}, {z:.4g})", path=path)
    return edges


def _drop_tiny_pieces(n: int, faces: np.ndarray, uv_faces: np.ndarray, edges: np.ndarray):
    """Connected pieces with fewer than ``TINY_COMPONENT`` of the faces dropped.

    Returns:
        (faces, uv_faces, repair counts ``tiny_piece_faces_dropped``, ``tiny_pieces_dropped``).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    adj = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    face_label = label[faces[:, 0]]
    sizes = np.bincount(face_label)
    keep = sizes[face_label] >= TINY_COMPONENT * len(faces)
    counts = {"tiny_piece_faces_dropped": int((~keep).sum()),
              "tiny_pieces_dropped": int(len(np.unique(face_label[~keep])))}
    return faces[keep], uv_faces[keep], counts


def describe_drops(repairs: dict[str, int]) -> str:
    """The faces a garment file lost in its repair (``Garment.repairs``), in words ('' if none;
    merged duplicate vertices, e.g. split along UV seams, are no loss and not told)."""
    parts = []
    if repairs.get("collapsed_faces_dropped"):
        parts.append(f"dropped {repairs['collapsed_faces_dropped']} collapsed (zero-area) faces")
    if repairs.get("duplicate_faces_dropped"):
        parts.append(f"dropped {repairs['duplicate_faces_dropped']} faces given twice")
    if repairs.get("tiny_pieces_dropped"):
        parts.append(f"dropped {repairs['tiny_pieces_dropped']} stray piece(s) of "
                     f"{repairs['tiny_piece_faces_dropped']} faces (each under {100 * TINY_COMPONENT:g} % "
                     "of the mesh)")
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
