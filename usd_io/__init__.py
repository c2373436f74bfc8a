"""USD out and back in; the only package that imports ``pxr`` (ARCHITECTURE.md).

- ``write_stage(path, body=..., fps=..., garments=[GarmentTrack(...)], rig=...)`` writes the
  body as a ``UsdSkel`` rig (``/World/BodyRig``: skeleton, joint animation, skinned mesh
  ``/World/BodyRig/Body``, pose blend shapes; ``usd_io.skel``) when given its ``BodyRig``, or
  as a time-sampled point cache ``/World/Body`` (``body_as="points"``), and each garment as a
  time-sampled ``UsdGeom.Mesh`` under ``/World/Garments`` (``.usda``, ``.usdc``/``.usd``,
  ``.usdz``), atomically.
- ``read_stage(path) -> StageData`` reads timing, units and every mesh's points per frame (a
  rig's body posed by UsdSkel).
- ``validate_stage(path) -> list[str]`` runs OpenUSD's ``UsdValidation`` validators plus
  mesh-topology and skin checks and returns the error-level issues.
"""

from usd_io.read import BODY_PATHS, MeshData, StageData, open_stage, read_stage
from usd_io.validate import ValidationReport, validate_stage, validation_report
from usd_io.write import (
    BODY_AS,
    BODY_PATH,
    GARMENTS_PATH,
    JOINTS_PATH,
    SKEL_BODY_PATH,
    WORLD_PATH,
    GarmentTrack,
    write_stage,
)

__all__ = [
    "BODY_AS",
    "BODY_PATH",
    "BODY_PATHS",
    "GARMENTS_PATH",
    "JOINTS_PATH",
    "SKEL_BODY_PATH",
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
