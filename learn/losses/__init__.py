"""Loss terms for training garment models: Warp-backed physics energies (``physics``), their
torch bridge (``warp_autograd``) and plain-torch references (``reference``).

``LOSS_TERMS`` is the registry a trainer builds its weighted sum from (STYLE.md 5): config name
-> term class; every class takes the garment topology first, then keyword-only parameters.
"""

from learn.losses.physics import (
    BendingLoss,
    BodyAnchors,
    CollisionLoss,
    GravityLoss,
    GSNetBendingLoss,
    GSNetCollisionLoss,
    GSNetEdgeLoss,
    InertiaLoss,
    MembraneLoss,
    PhysicsBatch,
    PhysicsLoss,
)

LOSS_TERMS: dict[str, type[PhysicsLoss]] = {
    "membrane": MembraneLoss,
    "bending": BendingLoss,
    "collision": CollisionLoss,
    "inertia": InertiaLoss,
    "gravity": GravityLoss,
    "gsnet_edge": GSNetEdgeLoss,
    "gsnet_bending": GSNetBendingLoss,
    "gsnet_collision": GSNetCollisionLoss,
}
"""Physics loss terms by config name."""

__all__ = [
    "LOSS_TERMS",
    "BendingLoss",
    "BodyAnchors",
    "CollisionLoss",
    "GSNetBendingLoss",
    "GSNetCollisionLoss",
    "GSNetEdgeLoss",
    "GravityLoss",
    "InertiaLoss",
    "MembraneLoss",
    "PhysicsBatch",
    "PhysicsLoss",
]
