"""Per-garment static data of the physics losses (numpy, built once per garment topology).

Everything a loss term needs besides the current positions: unique edges with rest lengths,
the rest-shape ``Dm^-1`` and area of every triangle, the bending hinges with rest angle and
stiffness factor, lumped vertex areas (masses per unit density) and the inverse vertex degrees
of the uniform graph Laplacian. The rest-shape helpers are the
simulator's (``sim.cloth.model``), so a loss and the solver see the same discretisation, and so
are the fabric layers of a garment's hems (``Garment.face_layers``): a face of n layers has n
times the membrane energy, mass and bending of one (a hinge the mean of its two faces), as
``ClothModelBuilder.add_cloth`` builds it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.cloth.model import (
    dihedral_angles,
    hinge_factors,
    lumped_areas,
    mesh_edges,
    triangle_rest_data,
)
from sim.cloth.topology import build_hinges
from sim.types import face_layers_array


@dataclass(frozen=True)
class GarmentTopology:
    """Static data of one garment mesh (rest shape), shared by every sample of a batch.

    Attributes:
        rest_vertices: rest positions [m], (V, 3) float32.
        faces: triangles, (F, 3) int32, consistently oriented.
        edges: unique undirected edges ``(a, b)``, ``a < b``, (E, 2) int32.
        rest_edge_lengths: rest length of each edge [m], (E,) float32.
        dm_inv: rest ``Dm^-1`` of each triangle in its own 2D frame [1/m], (F, 2, 2) float32.
        areas: rest area of each triangle [m^2], (F,) float32.
        hinges: interior edges ``(o0, o1, a, b)`` (layout of ``sim.cloth.energies``), (H, 4) int32.
        hinge_rest_angles: rest dihedral angle of each hinge [rad], (H,) float32.
        hinge_factors: ``3 |e|^2 / (A_1 + A_2)`` of each hinge (rest shape) times the mean
            layers of its two faces [-], (H,) float32; the hinge stiffness is ``k_e = k_b *
            factor`` (Grinspun et al. 2003), as in ``sim.cloth.model.ClothModelBuilder``.
        vertex_areas: lumped area of each vertex, one third of its triangles' rest areas times
            their layers [m^2], (V,) float32; the vertex mass is ``density * vertex_areas``.
        inv_degree: ``1 / (number of edge neighbours)`` of each vertex (0 for isolated vertices),
            (V,) float32: weights of the uniform graph Laplacian.
        face_layers: fabric layers of each triangle (>= 1; hems), (F,) float32: the weight of its
            membrane energy (``areas * face_layers``).
    """

    rest_vertices: np.ndarray
    faces: np.ndarray
    edges: np.ndarray
    rest_edge_lengths: np.ndarray
    dm_inv: np.ndarray
    areas: np.ndarray
    hinges: np.ndarray
    hinge_rest_angles: np.ndarray
    hinge_factors: np.ndarray
    vertex_areas: np.ndarray
    inv_degree: np.ndarray
    face_layers: np.ndarray

    @property
    def num_vertices(self) -> int:
        return int(self.rest_vertices.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])

    def vertex_masses(self, density: float) -> np.ndarray:
        """Lumped vertex masses [kg], (V,) float32, for an area density [kg/m^2]."""
        return (float(density) * self.vertex_areas.astype(np.float64)).astype(np.float32)


def garment_topology(rest_vertices: np.ndarray, faces: np.ndarray,
                     face_layers: np.ndarray | None = None) -> GarmentTopology:
    """Build the static loss data of a garment from its rest mesh.

    Args:
        rest_vertices: rest positions [m], shape (V, 3).
        faces: triangle vertex indices, shape (F, 3), consistently oriented.
        face_layers: fabric layers per face, shape (F,), >= 1 (None: one everywhere), e.g. a
            garment's hems (``Garment.face_layers``).

    Returns:
        The topology (float32 / int32 arrays).

    Raises:
        ValueError: faces index outside the vertices, a triangle of zero rest area, or layers
            of the wrong shape or under 1.
    """
    rest = np.ascontiguousarray(rest_vertices, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
    nv = len(rest)
    if len(f) == 0 or f.min() < 0 or f.max() >= nv:
        raise ValueError(f"garment_topology: faces must index 0..{nv - 1} (got {len(f)} faces)")
    layers = face_layers_array(face_layers, len(f), "garment_topology")
    dm_inv, areas = triangle_rest_data(rest, f)
    edges = mesh_edges(f)
    lengths = np.linalg.norm(rest[edges[:, 1]] - rest[edges[:, 0]], axis=1)
    hinges = build_hinges(f)
    if len(hinges):
        factors = hinge_factors(rest, f, hinges, areas, layers)
        rest_angles = dihedral_angles(rest, hinges)
    else:
        factors = np.zeros(0)
        rest_angles = np.zeros(0)
    vertex_areas = lumped_areas(nv, f, areas, layers)
    degree = np.bincount(edges.reshape(-1), minlength=nv).astype(np.float64)
    inv_degree = np.divide(1.0, degree, out=np.zeros(nv), where=degree > 0)
    return GarmentTopology(
        rest_vertices=rest.astype(np.float32),
        faces=f,
        edges=edges.astype(np.int32),
        rest_edge_lengths=lengths.astype(np.float32),
        dm_inv=dm_inv.astype(np.float32),
        areas=areas.astype(np.float32),
        hinges=hinges.astype(np.int32).reshape(-1, 4),
        hinge_rest_angles=rest_angles.astype(np.float32),
        hinge_factors=factors.astype(np.float32),
        vertex_areas=vertex_areas.astype(np.float32),
        inv_degree=inv_degree.astype(np.float32),
        face_layers=layers.astype(np.float32),
    )


def topology_of(garment) -> GarmentTopology:
    """``garment_topology`` of a ``sim.garments.Garment`` (its rest vertices, faces and hems'
    layers)."""
    return garment_topology(garment.rest_vertices, garment.faces, garment.face_layers)
