"""Skin through cloth: how much of the body under a garment ends outside it.

A body vertex is *under the garment* (``covered_vertices``) when, with both at rest,

1. its closest garment point is within ``reach`` (5 cm) and not on the garment's open border
   (a hem, cuff, neckline or armhole edge): a body vertex beyond an opening is not under it;
2. it lies on the inner side of the garment there (the angle-weighted pseudo-normal of the
   closest point, faces wound outward, points away from it);
3. the ray from it along the body's outward vertex normal meets the garment within ``reach``:
   a vertex the cloth is beside but not over (a chin above a neckline) is not under it.

In a frame each covered vertex is, against its closest garment point in that frame
(``skin_sides``): *inside* (inner side), *through* (outer side: the skin came out through the
cloth) or *exposed* (the closest point is on the open border, or no garment is within
``max_dist``: the cloth slid off it, as a hem rides up over the belly when the arms go up, which
is uncovered skin but no skin through cloth). ``skin_through_fraction`` is the share of the
covered vertices that are *through*, per frame.

The garment surface is its mid-surface (no thickness): a body vertex resting against the cloth
is inside by the cloth's contact distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.device import resolve_device, warp

COVER_REACH = 0.05
"""Largest distance [m] from a body vertex to the garment, at rest, for it to count as under
the garment (closest point and along its normal): ease and drape keep regular-fit cloth within a
few cm of the skin, and at 5 cm a vertex beside an opening is not counted."""
BORDER_EPS = 1e-4
"""Barycentric coordinate below which a closest point lies on a face's edge (above 1 minus it:
at a corner), for the open-border test."""
INSIDE, THROUGH, EXPOSED = 0, 1, 2
"""``skin_sides`` codes (``sim.coverage_kernels``)."""


def border_flags(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """Per face, int32 bits: bit k set where the edge opposite corner k is on the open border
    (one face uses it), bit 3 + k where corner k is a border vertex."""
    f = np.asarray(faces, np.int64)
    opposite = np.stack([f[:, [1, 2]], f[:, [2, 0]], f[:, [0, 1]]], axis=1)  # (F, 3, 2)
    keys = np.sort(opposite, axis=2).reshape(-1, 2)
    _, inverse, uses = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    edge_border = (uses[inverse.ravel()] == 1).reshape(-1, 3)
    vertex_border = np.zeros(num_vertices, bool)
    vertex_border[keys[edge_border.ravel()].ravel()] = True
    bits = (edge_border * (1 << np.arange(3))).sum(axis=1)
    bits += (vertex_border[f] * (8 << np.arange(3))).sum(axis=1)
    return bits.astype(np.int32)


def _frames(x: np.ndarray, T: int, what: str) -> np.ndarray:
    a = np.asarray(x, np.float32)
    if a.ndim == 2:
        a = np.broadcast_to(a, (T, *a.shape))
    if a.ndim != 3 or a.shape[0] != T or a.shape[2] != 3:
        raise ValueError(f"{what}: expected (V, 3) or ({T}, V, 3) positions, got shape {np.shape(x)}")
    return a


def _garment_mesh(points: np.ndarray, faces: np.ndarray, device: str):
    wp = warp()
    pts = wp.array(np.ascontiguousarray(points, np.float32), dtype=wp.vec3, device=device)
    idx = wp.array(np.ascontiguousarray(faces, np.int32).ravel(), dtype=wp.int32, device=device)
    return pts, wp.Mesh(points=pts, indices=idx)


def covered_vertices(body_rest: np.ndarray, body_faces: np.ndarray, garment_rest: np.ndarray,
                     garment_faces: np.ndarray, *, reach: float = COVER_REACH,
                     device: str | None = None) -> np.ndarray:
    """The body vertices under the garment at rest (module docstring).

    Args:
        body_rest: the body at rest [m], (Vb, 3); body_faces: (Fb, 3), wound outward.
        garment_rest: the garment at rest on that body [m], (G, 3); garment_faces: (Fg, 3),
            wound outward (away from the body).
        reach: largest distance [m] to the garment (closest point and along the normal).
        device: Warp device.

    Returns:
        bool (Vb,).
    """
    wp = warp()
    from sim import coverage_kernels as K
    from sim.geometry.frames import vertex_normals

    d = resolve_device(device)
    body = np.ascontiguousarray(body_rest, np.float32)
    normals = vertex_normals(body, body_faces, device=d)
    _, mesh = _garment_mesh(garment_rest, garment_faces, d)
    border = border_flags(garment_faces, len(garment_rest))
    out = wp.empty(len(body), dtype=int, device=d)
    wp.launch(K.covered_kernel, dim=len(body),
              inputs=[mesh.id, wp.array(body, dtype=wp.vec3, device=d),
                      wp.array(np.ascontiguousarray(normals, np.float32), dtype=wp.vec3, device=d),
                      wp.array(border, dtype=int, device=d), float(reach), BORDER_EPS],
              outputs=[out], device=d)
    return out.numpy().astype(bool)


@dataclass(frozen=True)
class SkinSides:
    """Where the covered body vertices are against the garment, frame by frame.

    Attributes:
        side: int8 (T, C), C the covered vertices in index order: ``INSIDE``, ``THROUGH`` or
            ``EXPOSED``.
        distance: float32 (T, C), signed distance [m] to the closest garment point (positive:
            outside the cloth); NaN where exposed.
    """

    side: np.ndarray
    distance: np.ndarray

    def fraction(self, side: int) -> np.ndarray:
        """Per frame, the share of the covered vertices on ``side`` (0 where none is covered), (T,)."""
        if self.side.shape[1] == 0:
            return np.zeros(self.side.shape[0])
        return (self.side == side).mean(axis=1)

    def deeper_than(self, depth: float) -> np.ndarray:
        """Per frame, the share of the covered vertices more than ``depth`` [m] outside the cloth, (T,)."""
        if self.side.shape[1] == 0:
            return np.zeros(self.side.shape[0])
        return ((self.side == THROUGH) & (self.distance > depth)).mean(axis=1)


def skin_sides(body_vertices: np.ndarray, garment_vertices: np.ndarray, garment_faces: np.ndarray,
               covered: np.ndarray, *, max_dist: float = 1.0, device: str | None = None) -> SkinSides:
    """Where each covered body vertex is against the garment in each frame.

    Args:
        body_vertices: the body [m], (T, Vb, 3) or (Vb, 3) (static).
        garment_vertices: the garment [m], (T, G, 3) or (G, 3) (static); at least one of the
            two has T frames.
        garment_faces: (F, 3), wound outward.
        covered: bool (Vb,), the vertices to test (``covered_vertices``).
        max_dist: a covered vertex with no garment within this distance [m] is exposed.
        device: Warp device.
    """
    wp = warp()
    from sim import coverage_kernels as K

    d = resolve_device(device)
    T = max(np.shape(x)[0] if np.ndim(x) == 3 else 1 for x in (body_vertices, garment_vertices))
    body = _frames(body_vertices, T, "body_vertices")
    cloth = _frames(garment_vertices, T, "garment_vertices")
    covered = np.asarray(covered, bool)
    if covered.shape != (body.shape[1],):
        raise ValueError(f"covered: expected bool ({body.shape[1]},), got shape {covered.shape}")
    ids = np.nonzero(covered)[0].astype(np.int32)
    out = SkinSides(np.zeros((T, ids.size), np.int8), np.zeros((T, ids.size), np.float32))
    if ids.size == 0:
        return out
    pts, mesh = _garment_mesh(cloth[0], garment_faces, d)
    border = wp.array(border_flags(garment_faces, cloth.shape[1]), dtype=int, device=d)
    ids_d = wp.array(ids, dtype=int, device=d)
    body_d = wp.empty(body.shape[1], dtype=wp.vec3, device=d)
    side = wp.empty(ids.size, dtype=int, device=d)
    distance = wp.empty(ids.size, dtype=float, device=d)
    for t in range(T):
        if t > 0:
            pts.assign(np.ascontiguousarray(cloth[t]))
            mesh.refit()
        body_d.assign(np.ascontiguousarray(body[t]))
        wp.launch(K.side_kernel, dim=ids.size,
                  inputs=[mesh.id, body_d, ids_d, border, float(max_dist), BORDER_EPS],
                  outputs=[side, distance], device=d)
        out.side[t] = side.numpy()
        out.distance[t] = distance.numpy()
    return out


def skin_through_fraction(body_vertices: np.ndarray, garment_vertices: np.ndarray, garment_faces: np.ndarray,
                          covered: np.ndarray, *, device: str | None = None) -> np.ndarray:
    """Per frame, the share of the covered body vertices that end outside the cloth (``THROUGH``
    of ``skin_sides``; the arguments are its), float (T,); 0 where no vertex is covered."""
    sides = skin_sides(body_vertices, garment_vertices, garment_faces, covered, device=device)
    return sides.fraction(THROUGH)
