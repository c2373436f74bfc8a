"""Cloth simulation: model / state / control / solver split (DESIGN.md, Core types).

``ClothModelBuilder`` -> ``ClothModel`` (static, on a device, many instances batched),
``ClothState`` (positions, velocities), ``ClothControl`` (pin targets, body meshes as
``BodyCollider``), ``SolverVBD.step(state_in, state_out, control, dt)``.
"""

from sim.cloth.model import ClothMaterialParams, ClothModel, ClothModelBuilder
from sim.cloth.solver_vbd import SolverVBD, VBDConfig
from sim.cloth.state import BodyCollider, ClothControl, ClothState

__all__ = [
    "BodyCollider",
    "ClothControl",
    "ClothMaterialParams",
    "ClothModel",
    "ClothModelBuilder",
    "ClothState",
    "SolverVBD",
    "VBDConfig",
]
