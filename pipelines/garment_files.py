"""Garment files for the commands: the trimesh formats through ``sim.garments.load_garment``,
USD through ``usd_io`` (``pxr`` stays out of ``sim``)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.hems import HEM_LAYERS
from sim.garments.io import MESH_SUFFIXES, USD_SUFFIXES, GarmentMesh, load_garment, read_mesh
from sim.garments.materials import Material
from sim.garments.types import Garment

GARMENT_SUFFIXES = MESH_SUFFIXES + USD_SUFFIXES
"""Every garment file suffix ``load_garment_file`` reads."""


def read_usd_mesh(path: Path) -> GarmentMesh:
    """The first garment mesh of a USD stage at frame 0: under /World/Garments, else any mesh
    but the body; the stage's metersPerUnit and upAxis applied (metres, Y up)."""
    from usd_io import BODY_PATHS, read_stage

    stage = read_stage(path, require_body=False)  # a garment file has no body
    meshes = list(stage.garments.values()) or [m for m in stage.meshes.values() if m.path not in BODY_PATHS]
    if not meshes:
        raise WrinklesInputError("no garment mesh in the stage", path=path)
    m = meshes[0]
    uv_faces = m.uv_faces
    if m.uvs is not None and uv_faces is None:
        uv_faces = m.faces
    points = np.asarray(m.points[0], np.float64) * stage.meters_per_unit  # to metres
    if stage.up_axis.upper() == "Z":  # to Y up: (x, y, z) -> (x, z, -y)
        points = np.stack([points[:, 0], points[:, 2], -points[:, 1]], axis=1)
    return GarmentMesh(points, m.faces, m.uvs, uv_faces)


def load_garment_file(path: str | os.PathLike, *, material: str | Material = "cotton",
                      name: str | None = None, require_uvs: bool = True, hem_width: float = 0.0,
                      hem_layers: float = HEM_LAYERS) -> Garment:
    """Read, repair and check a garment file (``sim.garments.load_garment``): .obj, .ply,
    .glb/.gltf, .off, .stl (metres, Y up) or .usd/.usda/.usdc/.usdz (frame 0, the stage's
    units and up axis applied); the options are ``load_garment``'s."""
    read = read_usd_mesh if Path(path).suffix.lower() in USD_SUFFIXES else read_mesh
    return load_garment(path, material=material, name=name, require_uvs=require_uvs,
                        hem_width=hem_width, hem_layers=hem_layers, read=read)
