"""Body models: the embedded default body and user SMPL-family files."""

from sim.bodies.model import BodyModel

__all__ = ["BodyModel", "load_body"]


def load_body(spec: str | None = None) -> BodyModel:
    """Load a body model.

    Args:
        spec: ``None`` or ``"default"`` for the embedded default body, else a path to an SMPL,
            SMPL-H or SMPL-X model file (``.npz`` or ``.pkl``).
    """
    if spec in (None, "", "default"):
        from sim.bodies.default import load_default_body

        return load_default_body()
    from sim.bodies.smpl_io import load_smpl_model

    return load_smpl_model(spec)
