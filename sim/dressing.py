"""Dressing: placing a garment on the body in rest pose and binding its attachments to the skin.

A template garment is sewn on the body's rest (T-pose) mesh and settles there, clear of the
skin (``sim.garments.sewing``), so placing it is a rigid translation: the body's root
translation at the first frame of the run plus the grounding offset (``place_garment``).

Attachments ("waistband", "shoulders", ...) are pinned to the body: each pinned vertex is
bound to its closest point on the rest body surface (a triangle, barycentric weights) with its
offset expressed in that triangle's orthonormal frame (``bind_to_surface``). On every step the
pin target is the same barycentric point of the *posed* triangle plus the same offset in the
posed triangle's frame (``SurfaceBinding.targets``, on the device ``AttachmentPins``), so a
pinned vertex keeps its clearance to the skin and follows the skinned surface exactly, pose
blend shapes included, with no skinning weights of its own.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.device import resolve_device, warp

BIND_MAX_DIST = 0.5
"""An attachment vertex farther than this from the rest body is not on the body [m]."""


def triangle_frames(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Orthonormal frames of triangles (a, b, c): rows t0 (along ab), t1 = n x t0, n (unit
    normal, right-handed winding), shape (..., 3, 3) float64."""
    a, b, c = (np.asarray(p, np.float64) for p in (a, b, c))
    e1 = b - a
    t0 = e1 / np.linalg.norm(e1, axis=-1, keepdims=True)
    n = np.cross(e1, c - a)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return np.stack([t0, np.cross(n, t0), n], axis=-2)


@dataclass(frozen=True)
class SurfaceBinding:
    """Garment vertices bound to a body surface.

    Attributes:
        vertices: the bound garment vertex indices, shape (P,), int32.
        corners: body vertex indices of each vertex's triangle, shape (P, 3), int32.
        bary: barycentric weights of the closest point in that triangle, shape (P, 3), float32.
        offset: vertex minus closest point, in the triangle's frame (t0, t1, n) [m], shape
            (P, 3), float32.
    """

    vertices: np.ndarray
    corners: np.ndarray
    bary: np.ndarray
    offset: np.ndarray

    @property
    def count(self) -> int:
        return int(self.vertices.shape[0])

    def targets(self, body_vertices: np.ndarray) -> np.ndarray:
        """Positions [m] of the bound vertices on a posed body (V_body, 3) -> (P, 3) float32
        (numpy reference of ``sim.dressing_kernels.attachment_targets_kernel``)."""
        bv = np.asarray(body_vertices, np.float64)
        a, b, c = (bv[self.corners[:, k]] for k in range(3))
        frames = triangle_frames(a, b, c)
        p = self.bary[:, :1] * a + self.bary[:, 1:2] * b + self.bary[:, 2:] * c
        return (p + np.einsum("pk,pkj->pj", self.offset.astype(np.float64), frames)).astype(np.float32)


def bind_to_surface(points: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray, *,
                    vertices: np.ndarray | None = None, device: str | None = None,
                    max_dist: float = BIND_MAX_DIST) -> SurfaceBinding:
    """Bind points to their closest points on a body surface.

    Args:
        points: garment positions [m], shape (V, 3), placed on the body.
        body_vertices: body positions [m] in the same pose, shape (V_body, 3).
        body_faces: body triangles, shape (F_body, 3).
        vertices: which garment vertices to bind (indices into ``points``); None: all.
        device: Warp device for the closest-point query.
        max_dist: search radius [m].

    Raises:
        ValueError: a point has no body surface within ``max_dist`` (the garment is not on
            this body).
    """
    wp = warp()
    from sim import dressing_kernels as K

    d = resolve_device(device)
    idx = np.arange(len(points)) if vertices is None else np.asarray(vertices, np.int64).reshape(-1)
    idx = idx.astype(np.int32)
    faces = np.asarray(body_faces, np.int32)
    if idx.size == 0:
        z = np.zeros((0, 3), np.float32)
        return SurfaceBinding(idx, np.zeros((0, 3), np.int32), z, z.copy())
    q = np.ascontiguousarray(np.asarray(points, np.float32)[idx])
    bv = np.ascontiguousarray(body_vertices, np.float32)
    mesh = wp.Mesh(points=wp.array(bv, dtype=wp.vec3, device=d),
                   indices=wp.array(faces.ravel(), dtype=wp.int32, device=d))
    face = wp.empty(len(idx), dtype=wp.int32, device=d)
    bary = wp.empty(len(idx), dtype=wp.vec3, device=d)
    wp.launch(K.closest_point_kernel, dim=len(idx), inputs=[mesh.id, wp.array(q, dtype=wp.vec3, device=d),
                                                             float(max_dist)],
              outputs=[face, bary], device=d)
    face_np, bary_np = face.numpy(), bary.numpy().astype(np.float64)
    if (face_np < 0).any():
        k = int(np.argmax(face_np < 0))
        raise ValueError(f"garment vertex {int(idx[k])} is more than {max_dist} m from the body surface; "
                         "the garment is not placed on this body")
    corners = faces[face_np]
    a, b, c = (bv[corners[:, k]].astype(np.float64) for k in range(3))
    p = bary_np[:, :1] * a + bary_np[:, 1:2] * b + bary_np[:, 2:] * c
    frames = triangle_frames(a, b, c)
    offset = np.einsum("pj,pkj->pk", q.astype(np.float64) - p, frames)
    return SurfaceBinding(idx, corners.astype(np.int32), bary_np.astype(np.float32),
                          offset.astype(np.float32))


def attachment_vertices(attachments: dict[str, np.ndarray], names: Iterable[str]) -> np.ndarray:
    """Union (sorted, int32) of the attachment sets in ``names`` that the garment has; names the
    garment does not define are skipped (a t-shirt has no waistband)."""
    sets = [np.asarray(attachments[n], np.int32).reshape(-1) for n in names if n in attachments]
    if not sets:
        return np.zeros(0, np.int32)
    return np.unique(np.concatenate(sets)).astype(np.int32)


def place_garment(rest_vertices: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """A garment built around the rest body moved with it by ``offset`` [m] (3,): (V, 3) float32."""
    return (np.asarray(rest_vertices, np.float32) + np.asarray(offset, np.float32).reshape(1, 3)).astype(
        np.float32)


class AttachmentPins:
    """Pin targets of bound particles computed on the device from a body's end-of-step points.

    Args:
        binding: the binding; its ``vertices`` are garment-local.
        particle_offset: first particle of the garment's instance in the cloth model.
        body_points: the Warp array of body positions at the end of the step
            (``BodyCollider.points_end``); read at launch time, so the launch can be captured
            in a CUDA graph and replayed after new frames are copied into it.
        device: Warp device.
    """

    def __init__(self, binding: SurfaceBinding, particle_offset: int, body_points: Any, *, device: str):
        wp = warp()
        self.count = binding.count
        self.device = device
        self.body_points = body_points
        self.corners = wp.array(binding.corners, dtype=wp.vec3i, device=device)
        self.bary = wp.array(binding.bary, dtype=wp.vec3, device=device)
        self.offset = wp.array(binding.offset, dtype=wp.vec3, device=device)
        self.particle = wp.array((binding.vertices + particle_offset).astype(np.int32), dtype=wp.int32,
                                 device=device)

    def launch(self, pin_targets: Any) -> None:
        """Write the targets of the bound particles into ``pin_targets`` (vec3 per particle)."""
        if self.count == 0:
            return
        wp = warp()
        from sim import dressing_kernels as K

        wp.launch(K.attachment_targets_kernel, dim=self.count,
                  inputs=[self.body_points, self.corners, self.bary, self.offset, self.particle],
                  outputs=[pin_targets], device=self.device)
