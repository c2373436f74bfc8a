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


def _locate(point: np.ndarray, group: np.ndarray, target: np.ndarray,
            target_group: np.ndarray) -> SurfaceLocations:
    """Each point (N, 2) in the target triangle (corners ``target`` (F, 3, 2)) of its own group
    that holds it; a point a hair outside its group's outline goes to the candidate triangle it
    lies least outside."""
    n = len(point)
    face = np.zeros(n, np.int32)
    bary = np.zeros((n, 3))
    inside = np.zeros(n, bool)
    for g in np.unique(group):
        mine = np.flatnonzero(group == g)
        theirs = np.flatnonzero(target_group == g)
        k = min(CANDIDATES, len(theirs))
        _, cand = cKDTree(target[theirs].mean(axis=1)).query(point[mine], k=k)
        cand = theirs[cand.reshape(len(mine), k)]
        w = _barycentric(point[mine][:, None], target[cand])  # (m, k, 3)
        best = np.argmax(w.min(axis=2), axis=1)
        pick = w[np.arange(len(mine)), best]
        inside[mine] = pick.min(axis=1) >= -INSIDE_TOLERANCE
        pick = np.clip(pick, 0.0, None)
        bary[mine] = pick / pick.sum(axis=1, keepdims=True)
        face[mine] = cand[np.arange(len(mine)), best]
    return SurfaceLocations(face=face, barycentric=bary, inside=inside)


def _first_corners(faces: np.ndarray, n: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex's first face and its corner there."""
    nf = len(faces)
    if n == 0 or nf == 0:
        raise WrinklesInputError(f"{what} has no faces to locate")
    first = np.full(n, nf, np.int64)
    np.minimum.at(first, faces.ravel(), np.arange(3 * nf) // 3)
    if np.any(first == nf):
        lone = int(np.argmax(first == nf))
        raise WrinklesInputError(f"{what}: vertex {lone} is in no face")
    return first, np.argmax(faces[first] == np.arange(n)[:, None], axis=1)


def pattern_locations(source: Garment, target: Garment) -> SurfaceLocations:
    """Each source vertex's place on the target: the target triangle of the same panel that holds
    the vertex's flat pattern position (a seam vertex: its first face's panel), with weights;
    a position a hair outside the target's outline goes to the candidate triangle it lies least
    outside (``SurfaceLocations.inside``)."""
    offsets = panel_offsets(source, target)
    src_flat, tgt_flat = source.flat_corners(), target.flat_corners()
    first, corner = _first_corners(np.asarray(source.faces), source.num_vertices, f"garment {source.name!r}")
    names = np.array(source.panel_names)[source.panel_ids[first]]
    point = src_flat[first, corner] + np.stack([offsets[s] for s in names])
    tgt_names = np.array(target.panel_names)[target.panel_ids]
    return _locate(point, names, tgt_flat, tgt_names)


def _chart_centroids(corners: np.ndarray, face_chart: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Area centroid (C, 2) and area (C,) of each UV chart."""
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    nc = int(face_chart.max()) + 1
    total = np.bincount(face_chart, area, nc)
    mid = np.stack([np.bincount(face_chart, corners.mean(axis=1)[:, i] * area, nc) for i in range(2)], axis=1)
    return mid / np.maximum(total, 1e-30)[:, None], total


def layout_locations(source_faces: np.ndarray, source_uvs: np.ndarray, source_uv_faces: np.ndarray,
                     target_uvs: np.ndarray, target_uv_faces: np.ndarray) -> SurfaceLocations:
    """``pattern_locations`` from two UV layouts alone (a dataset's ``coarse/*`` and ``fine/*``
    arrays, which keep no panel names): each UV chart is a panel; a source chart goes to the
    target chart whose area centroid is nearest, both layouts are brought to one scale by their
    total UV areas (two meshings tile the same panels) and each chart pair is aligned by its
    centroids. Locations are of the source's 3D vertices (their first face's UV corner), on the
    target's faces.

    Raises:
        WrinklesInputError: the layouts have different numbers of charts, or two source charts
            claim one target chart (not the same pattern).
    """
    from sim.geometry.uv_raster import uv_charts

    sf, suf, tuf = (np.asarray(a, np.int64) for a in (source_faces, source_uv_faces, target_uv_faces))
    suv, tuv = np.asarray(source_uvs, np.float64), np.asarray(target_uvs, np.float64)
    s_chart, _ = uv_charts(suf, len(suv))
    t_chart, _ = uv_charts(tuf, len(tuv))
    s_mid, s_area = _chart_centroids(suv[suf], s_chart)
    t_mid, t_area = _chart_centroids(tuv[tuf], t_chart)
    match = cKDTree(t_mid).query(s_mid)[1]
    if len(s_mid) != len(t_mid) or len(np.unique(match)) != len(match):
        raise WrinklesInputError(f"UV layouts of {len(s_mid)} and {len(t_mid)} charts do not match chart for "
                                 "chart: not the same pattern")
    scale = np.sqrt(t_area.sum() / s_area.sum())
    first, corner = _first_corners(sf, int(sf.max()) + 1, "source mesh")
    group = match[s_chart[first]]
    point = (suv[suf[first, corner]] - s_mid[s_chart[first]]) * scale + t_mid[group]
    return _locate(point, group, tuv[tuf], t_chart)
