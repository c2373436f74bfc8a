"""wrinkles.sim — the physical world in Warp kernels and numpy.

Bodies (model loading, LBS skinning), motions, garments, the cloth solver, collisions, strain
and geometry. Nothing here imports ``torch`` at module level (ARCHITECTURE.md).
"""

__version__ = "0.1.0"
