"""Linear blend skinning with shape and pose blend shapes, as Warp kernels."""

from sim.skinning.lbs import Skinner, lbs_reference

__all__ = ["Skinner", "lbs_reference"]
