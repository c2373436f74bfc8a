"""Evaluation metrics: one implementation, used by training, evaluation and benchmarks.

- Accuracy (Guo et al. 2024, Sec 4.1): :func:`vertex_error` ``Ev`` [m],
  :func:`chamfer_distance` ``Ecd`` [m²].
- Physics (GSNet Sec 4.3): :func:`edge_elongation` (:class:`EdgeStats`), :func:`bending_angles`,
  :func:`bending_error`, :func:`vertex_normal_angles`, :func:`collision_rate`.
- Temporal: :func:`flicker`, :func:`flicker_ratio`, :func:`image_flicker`.
- Wrinkle spectrum of UV maps: :func:`radial_power_spectrum` (:class:`Spectrum`),
  :func:`spectrum_profile_distance`, :func:`dominant_wavelength`.
- Perceptual: :class:`NormalMapFeatures` (fixed, shipped extractor, NOT Inception),
  :func:`frechet_distance`, :func:`normal_map_fd`.
"""

from learn.metrics.features import FEATURE_DIM, VERSION, NormalMapFeatures
from learn.metrics.frechet import (
    feature_statistics,
    frechet_distance,
    frechet_distance_from_stats,
    normal_map_fd,
)
from learn.metrics.geometry import (
    EdgeStats,
    as_tensor,
    bending_angles,
    bending_error,
    chamfer_distance,
    collision_rate,
    edge_elongation,
    edge_lengths,
    face_normals,
    interior_edges,
    mesh_edges,
    vertex_error,
    vertex_normal_angles,
    vertex_normals,
)
from learn.metrics.spectrum import (
    Spectrum,
    dominant_wavelength,
    radial_power_spectrum,
    spectrum_profile_distance,
)
from learn.metrics.temporal import flicker, flicker_ratio, image_flicker

__all__ = [
    "FEATURE_DIM",
    "VERSION",
    "EdgeStats",
    "NormalMapFeatures",
    "Spectrum",
    "as_tensor",
    "bending_angles",
    "bending_error",
    "chamfer_distance",
    "collision_rate",
    "dominant_wavelength",
    "edge_elongation",
    "edge_lengths",
    "face_normals",
    "feature_statistics",
    "flicker",
    "flicker_ratio",
    "frechet_distance",
    "frechet_distance_from_stats",
    "image_flicker",
    "interior_edges",
    "mesh_edges",
    "normal_map_fd",
    "radial_power_spectrum",
    "spectrum_profile_distance",
    "vertex_error",
    "vertex_normal_angles",
    "vertex_normals",
]
