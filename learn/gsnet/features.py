"""GSNet's inputs from a garment and a body motion (numpy; GSNet Sec. 3.2-3.3, 3.5).

- Template features per garment vertex (Sec. 3.2: "location in world space, material and
  relaxation schedule"): the rest position relative to the rest body's root joint [m], the rest
  vertex normal, the vertex's UV (its first UV corner; the flat pattern's place), the material as
  log10 ratios of density, tensile and bending stiffness to cotton's, and the fabric layers (hems),
  ``TEMPLATE_FEATURES`` numbers.
- The body's bone transforms per frame, relative to the root joint of that frame (SMPL's skinning
  matrices ``A`` with the root position taken out), and the root positions: the network works in
  the frame that moves with the body's root, so where the body walks to does not matter.
"""

from __future__ import annotations

import numpy as np
import torch

from learn.methods.skinned_mlp import pose_transforms
from learn.metrics.geometry import vertex_normals
from sim.garments.materials import get_material

TEMPLATE_FEATURES = 12
"""position (3), normal (3), UV (2), material (3), layers (1)."""

REFERENCE_MATERIAL = "cotton"
"""The material whose density and stiffness are the zero of the material features."""


def material_features(material) -> np.ndarray:
    """log10 of density, Young's modulus and bending stiffness over cotton's, (3,) float32, of a
    preset name or a ``Material``."""
    m, ref = get_material(material or REFERENCE_MATERIAL), get_material(REFERENCE_MATERIAL)
    return np.log10([m.density / ref.density, m.youngs_modulus / ref.youngs_modulus,
                     m.bending_stiffness / ref.bending_stiffness]).astype(np.float32)


def vertex_uvs(faces: np.ndarray, uvs: np.ndarray, uv_faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """Each vertex's UV (the UV of its first face corner in face order), (V, 2) float32."""
    out = np.zeros((num_vertices, 2), np.float32)
    f, uf = np.asarray(faces).reshape(-1), np.asarray(uv_faces).reshape(-1)
    used, first = np.unique(f, return_index=True)  # each vertex's first corner
    out[used] = np.asarray(uvs, np.float32)[uf[first]]
    return out


def vertex_layers(faces: np.ndarray, face_layers: np.ndarray | None, num_vertices: int) -> np.ndarray:
    """Mean fabric layers of the faces around each vertex (V,) float32 (1 without layers)."""
    if face_layers is None:
        return np.ones(num_vertices, np.float32)
    f = np.asarray(faces, np.int64)
    total = np.zeros(num_vertices)
    count = np.zeros(num_vertices)
    for k in range(3):
        np.add.at(total, f[:, k], np.asarray(face_layers, np.float64))
        np.add.at(count, f[:, k], 1.0)
    return np.where(count > 0, total / np.maximum(count, 1), 1.0).astype(np.float32)


def template_features(rest: np.ndarray, faces: np.ndarray, uvs: np.ndarray, uv_faces: np.ndarray,
                      material, rest_root: np.ndarray,
                      face_layers: np.ndarray | None = None) -> np.ndarray:
    """The template features of every vertex (V, ``TEMPLATE_FEATURES``) float32 (module docstring).

    Args:
        rest: rest garment on the rest body [m] (V, 3); faces (F, 3); uvs (U, 2), uv_faces (F, 3).
        material: preset name or ``Material``; rest_root: the rest body's root joint [m] (3,).
        face_layers: fabric layers per face (F,), None for one layer.
    """
    v = np.asarray(rest, np.float32)
    n = v.shape[0]
    mat = np.broadcast_to(material_features(material), (n, 3))
    normals = vertex_normals(torch.from_numpy(v), np.asarray(faces)).numpy()  # unit, area-weighted
    return np.concatenate([v - np.asarray(rest_root, np.float32), normals,
                           vertex_uvs(faces, uvs, uv_faces, n), mat,
                           vertex_layers(faces, face_layers, n)[:, None]], axis=1).astype(np.float32)


def body_motion(poses: np.ndarray, joints: np.ndarray, rest_joints: np.ndarray,
                parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Root-relative bone transforms (T, 24, 3, 4) and root positions (T, 3) [m] of a posed body.

    ``x - root_t = A'_j [x_rest; 1]`` for a point carried rigidly by joint j, with
    ``A'_j = A_j - [0 | root_t]`` and ``A`` SMPL's skinning matrices
    (``learn.methods.skinned_mlp.pose_transforms``).
    """
    joints = np.asarray(joints, np.float32)
    A, _ = pose_transforms(np.asarray(poses, np.float32), joints, rest_joints, parents)
    roots = joints[:, 0].copy()
    A[..., 3] -= roots[:, None]
    return A, roots

