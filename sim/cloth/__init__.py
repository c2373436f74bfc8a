"""Cloth simulation: model / state / control / solver split.

``ClothModelBuilder`` -> ``ClothModel`` (static, on a device, many instances batched),
``ClothState`` (positions, velocities), ``ClothControl`` (pin targets, body meshes as
``BodyCollider``), ``SolverVBD.step(state_in, state_out, control, dt)`` with its settings
``VBDConfig`` (``job_config``: the job's).
"""

from sim.cloth.config import (
    BodyContact,
    CoarseConfig,
    KernelLayout,
    SelfContactConfig,
    Stepping,
    VBDConfig,
    apply_overrides,
    job_config,
)
from sim.cloth.model import ClothMaterialParams, ClothModel, ClothModelBuilder
from sim.cloth.solver_vbd import SolverVBD
from sim.cloth.state import BodyCollider, ClothControl, ClothState

__all__ = [
    "BodyCollider",
    "BodyContact",
    "ClothControl",
    "ClothMaterialParams",
    "ClothModel",
    "ClothModelBuilder",
    "ClothState",
    "CoarseConfig",
    "KernelLayout",
    "SelfContactConfig",
    "SolverVBD",
    "Stepping",
    "VBDConfig",
    "apply_overrides",
    "job_config",
]
