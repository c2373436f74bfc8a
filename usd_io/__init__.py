"""USD out and back in; the only package that imports ``pxr`` (ARCHITECTURE.md).

- ``write_stage(path, body=..., fps=..., garments=[GarmentTrack(...)])`` writes
  ``/World/Body`` and ``/World/Garments/<name>`` as time-sampled ``UsdGeom.Mesh`` prims
  (``.usda``, ``.usdc``/``.usd``, ``.usdz``), atomically.
- ``read_stage(path) -> StageData`` reads timing, units and every mesh's points per frame.
- ``validate_stage(path) -> list[str]`` runs OpenUSD's ``UsdValidation`` validators plus
  mesh-topology checks and returns the error-level issues.
"""

from usd_io.read import MeshData, StageData, open_stage, read_stage
from usd_io.validate import ValidationReport, validate_stage, validation_report
from usd_io.write import (
    BODY_PATH,
    GARMENTS_PATH,
    JOINTS_PATH,
    WORLD_PATH,
    GarmentTrack,
    write_stage,
)

__all__ = [
    "BODY_PATH",
    "GARMENTS_PATH",
    "JOINTS_PATH",
    "WORLD_PATH",
    "GarmentTrack",
    "MeshData",
    "StageData",
    "ValidationReport",
    "open_stage",
    "read_stage",
    "validate_stage",
    "validation_report",
    "write_stage",
]
