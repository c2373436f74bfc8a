"""Where a point of one sewn garment lies on another garment sewn from the same pattern.

Two meshings of one design (a coarse template and the fine simulated garment, say) share their
flat sewing pattern: a vertex of one has a position in its panel's plane, and the other's
triangle of that panel containing that position is the same piece of cloth. That gives
DeepWrinkles' registration its ground truth (the template vertex's true place on a simulated
frame, Lähner et al. Sec. 3.1) and moves a fine frame's surface into the template's UV layout.

The flat coordinates come from each garment's packed UVs in metres (``Garment.flat_corners``):
packing places every panel at one common scale but its own offset, and that offset differs
between meshings (each packs its own outline samples). Panels are matched by name and aligned
by their area centroids in the plane (``panel_offsets``): both meshings tile the same polygon,
so the centroids agree up to how finely the curved edges are sampled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sim.errors import WrinklesInputError
from sim.garments.types import Garment

CANDIDATES = 12
"""Target triangles (nearest centroids) tried for each point."""
INSIDE_TOLERANCE = 1e-5
"""Smallest barycentric weight of a point still in its triangle: float32 UVs put a point of the
panel outline ~1e-8 m to either side of it."""


@dataclass(frozen=True)
class SurfaceLocations:
    """Points on a target mesh: a face and barycentric weights of its corners per point.

    Attributes:
        face: int32 (N,), into the target's faces.
        barycentric: float64 (N, 3), non-negative, rows summing to 1.
        inside: bool (N,): the point lay in its triangle (else, a hair outside the target's
            panel outline, it went to the candidate triangle it lies least outside, its
            negative weights clipped to 0).
    """

    face: np.ndarray
    barycentric: np.ndarray
    inside: np.ndarray

    def evaluate(self, faces: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """The points on a target configuration: ``positions`` (..., V, 3) of the target's
        vertices (one frame or many), ``faces`` its faces (F, 3); float32 (..., N, 3)."""
        x = np.asarray(positions, np.float64)
        corners = x[..., np.asarray(faces)[self.face], :]  # (..., N, 3, 3)
        return np.einsum("...nkc,nk->...nc", corners, self.barycentric).astype(np.float32)


def _panel_centroids(g: Garment) -> dict[str, np.ndarray]:
    """Area centroid of each panel in the garment's flat coordinates [m]."""
    flat = g.flat_corners()
    if flat is None:
        raise WrinklesInputError(f"garment {g.name!r} has no flat sewing pattern (uv_scale)")
    e1, e2 = flat[:, 1] - flat[:, 0], flat[:, 2] - flat[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    mid = flat.mean(axis=1)
    out = {}
    for pid, name in enumerate(g.panel_names):
        m = g.panel_ids == pid
        if m.any():
            out[name] = (mid[m] * area[m, None]).sum(axis=0) / max(area[m].sum(), 1e-30)
    return out


def panel_offsets(source: Garment, target: Garment) -> dict[str, np.ndarray]:
    """Per panel name, the translation [m] from the source's flat coordinates to the target's.

    Raises:
        WrinklesInputError: a source panel the target does not have.
    """
    a, b = _panel_centroids(source), _panel_centroids(target)
    missing = sorted(set(a) - set(b))
    if missing:
        raise WrinklesInputError(f"garment {target.name!r} has no panel {missing[0]!r} of {source.name!r}: "
                                 "not the same pattern")
    return {name: b[name] - a[name] for name in a}


def _barycentric(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric weights of points p (..., 2) in triangles tri (..., 3, 2)."""
    e1, e2, d = tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :], p - tri[..., 0, :]
    det = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]
    flat = np.abs(det) < 1e-30
    det = np.where(flat, 1.0, det)
    v = (d[..., 0] * e2[..., 1] - d[..., 1] * e2[..., 0]) / det
    w = (e1[..., 0] * d[..., 1] - e1[..., 1] * d[..., 0]) / det
    out = np.stack([1.0 - v - w, v, w], axis=-1)
    out[flat] = -np.inf  # a triangle without area holds no point
    return out


def pattern_locations(source: Garment, target: Garment) -> SurfaceLocations:
    """Each source vertex's place on the target: the target triangle of the same panel that holds
    the vertex's flat pattern position (a seam vertex: its first face's panel), with weights;
    a position a hair outside the target's outline goes to the candidate triangle it lies least
    outside (``SurfaceLocations.inside``)."""
    offsets = panel_offsets(source, target)
    src_flat, tgt_flat = source.flat_corners(), target.flat_corners()
    n = source.num_vertices
    nf = len(source.faces)
    if n == 0 or nf == 0:
        raise WrinklesInputError(f"garment {source.name!r} has no faces to locate")
    first = np.full(n, nf, np.int64)  # each vertex's first face
    np.minimum.at(first, source.faces.ravel(), np.arange(3 * nf) // 3)
    if np.any(first == nf):
        lone = int(np.argmax(first == nf))
        raise WrinklesInputError(f"garment {source.name!r}: vertex {lone} is in no face")
    corner = np.argmax(source.faces[first] == np.arange(n)[:, None], axis=1)
    names = np.array(source.panel_names)[source.panel_ids[first]]
    point = src_flat[first, corner] + np.stack([offsets[s] for s in names])
    face = np.zeros(n, np.int32)
    bary = np.zeros((n, 3))
    inside = np.zeros(n, bool)
    tgt_names = np.array(target.panel_names)[target.panel_ids]
    for name in np.unique(names):
        mine = np.flatnonzero(names == name)
        theirs = np.flatnonzero(tgt_names == name)
        k = min(CANDIDATES, len(theirs))
        _, cand = cKDTree(tgt_flat[theirs].mean(axis=1)).query(point[mine], k=k)
        cand = theirs[cand.reshape(len(mine), k)]
        w = _barycentric(point[mine][:, None], tgt_flat[cand])  # (m, k, 3)
        best = np.argmax(w.min(axis=2), axis=1)
        pick = w[np.arange(len(mine)), best]
        inside[mine] = pick.min(axis=1) >= -INSIDE_TOLERANCE
        pick = np.clip(pick, 0.0, None)
        bary[mine] = pick / pick.sum(axis=1, keepdims=True)
        face[mine] = cand[np.arange(len(mine)), best]
    return SurfaceLocations(face=face, barycentric=bary, inside=inside)
