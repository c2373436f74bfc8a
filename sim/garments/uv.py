"""UV layout of sewing-pattern panels: packing flat panels into [0, 1]² and measuring distortion.

A sewn garment's UVs are its flat pattern (``sim.garments.pattern_mesh``): every panel is one
chart in its own plane, in metres. ``pack_uvs`` places the charts side by side in the unit square
with one common scale (one texel covers the same cloth area everywhere); ``uv_stats`` measures how
far a layout is from the 3D surface (angles, areas, flips, texel density).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UV_MARGIN = 0.02
"""Gap between charts and around the border, fraction of the unit square (5 px at 256²)."""


def _local_frames(x3: np.ndarray) -> np.ndarray:
    """Each triangle (F, 3, 3) [m] isometrically in its own plane: (F, 3, 2), corner 0 at 0."""
    e1, e2 = x3[:, 1] - x3[:, 0], x3[:, 2] - x3[:, 0]
    n = np.cross(e1, e2)
    ex = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    ey = np.cross(n / np.linalg.norm(n, axis=1, keepdims=True), ex)
    out = np.zeros(x3.shape[:2] + (2,))
    out[:, 1, 0] = np.linalg.norm(e1, axis=1)
    out[:, 2, 0] = (e2 * ex).sum(1)
    out[:, 2, 1] = (e2 * ey).sum(1)
    return out


def _shelf(size: np.ndarray, gap: float, width: float) -> tuple[np.ndarray, float]:
    """Shelf packing of boxes (K, 2), tallest first, rows no wider than ``width``.

    Returns:
        (lower-left corners (K, 2), side of the enclosing square).
    """
    order = np.argsort(-size[:, 1], kind="stable")
    place = np.zeros_like(size)
    x = y = shelf_h = 0.0
    for i in order:
        if x > 0 and x + size[i, 0] > width:
            x, y, shelf_h = 0.0, y + shelf_h + gap, 0.0
        place[i] = (x, y)
        x += size[i, 0] + gap
        shelf_h = max(shelf_h, size[i, 1])
    return place, float((place + size).max(axis=0).max())


def pack_uvs(uvs_m: np.ndarray, uv_panel: np.ndarray, *, margin: float = UV_MARGIN) -> np.ndarray:
    """Pack panel-local UVs [m] into [0, 1]² with one common scale, panels kept upright.

    Shelf packing of the panels' bounding boxes, tallest first; the shelf width is chosen
    among every width at which a new panel starts a shelf, for the smallest enclosing square
    (the highest texel density).

    Args:
        uvs_m: (U, 2) [m]; uv_panel: (U,) panel id of each UV vertex.
        margin: gap between panels' boxes and around the border, fraction of the unit square
            (0.02 = 5 px at 256²).

    Returns:
        (U, 2) float32 in [margin, 1 − margin].
    """
    ids = np.unique(uv_panel)
    lo = np.array([uvs_m[uv_panel == i].min(0) for i in ids])
    size = np.array([uvs_m[uv_panel == i].max(0) for i in ids]) - lo
    # the gap [m] scales with the result: grow the guess of the square's side from a lower
    # bound until the packing fits in it (then every gap is >= ``margin`` after scaling)
    total = float(np.sqrt(size.prod(axis=1).sum()))
    for _ in range(50):
        gap = margin / (1.0 - 2.0 * margin) * total
        # a shelf that holds exactly the (height-sorted) boxes i..k is this wide
        wg = np.r_[0.0, np.cumsum(size[np.argsort(-size[:, 1], kind="stable"), 0] + gap)]
        candidates = np.unique((wg[None, 1:] - wg[:-1, None] - gap)[np.triu_indices(len(ids))])
        candidates = candidates[candidates >= size[:, 0].max()]
        best = min((_shelf(size, gap, wd + 1e-12) for wd in candidates), key=lambda r: r[1])
        if best[1] <= total:
            break
        total = best[1] * (1.0 + 1e-6)
    place, total = best
    scale = (1.0 - 2.0 * margin) / total
    out = np.empty_like(uvs_m, dtype=np.float64)
    for k, i in enumerate(ids):
        m = uv_panel == i
        out[m] = (uvs_m[m] - lo[k] + place[k]) * scale + margin
    return np.clip(out, 0.0, 1.0).astype(np.float32)


@dataclass(frozen=True)
class UVStats:
    """Distortion of a UV layout against the 3D surface (per triangle, area-weighted by 3D area).

    Attributes:
        angle_mean, angle_p95, angle_max: conformal distortion σ1/σ2 of the 3D → UV map
            (singular values of its 2×2 Jacobian; 1 = angles kept).
        area_p5, area_p95: area ratio UV / 3D after one global scale (so the mean is 1);
            1 = areas kept.
        flipped: number of UV triangles with the opposite orientation to the rest.
        texels_per_metre_256: texels along 1 m of cloth in a 256² image (x 2 at 512²).
        mean_edge_texels_256: mean 3D edge length in texels of a 256² image.
        min_triangle_texels_512: smallest UV triangle area in texels of a 512² image.
        fill: fraction of the unit square covered by UV triangles.
    """

    angle_mean: float
    angle_p95: float
    angle_max: float
    area_p5: float
    area_p95: float
    flipped: int
    texels_per_metre_256: float
    mean_edge_texels_256: float
    min_triangle_texels_512: float
    fill: float


def _weighted_quantile(v: np.ndarray, w: np.ndarray, q: float) -> float:
    o = np.argsort(v)
    c = np.cumsum(w[o])
    return float(v[o][min(np.searchsorted(c, q * c[-1]), len(v) - 1)])


def uv_stats(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, uv_faces: np.ndarray) -> UVStats:
    """Angle and area distortion, flips and texel density of a UV layout.

    Args:
        vertices: (V, 3) [m]; faces: (F, 3); uvs: (U, 2) in [0, 1]²; uv_faces: (F, 3).
    """
    x = _local_frames(np.asarray(vertices, np.float64)[faces])
    t = np.asarray(uvs, np.float64)[uv_faces]
    p = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]], axis=2)  # columns: edges in the plane
    q = np.stack([t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]], axis=2)
    a3 = 0.5 * np.abs(p[:, 0, 0] * p[:, 1, 1] - p[:, 0, 1] * p[:, 1, 0])
    det_q = q[:, 0, 0] * q[:, 1, 1] - q[:, 0, 1] * q[:, 1, 0]
    a2 = 0.5 * np.abs(det_q)
    jac = q @ np.linalg.inv(p)
    sv = np.linalg.svd(jac, compute_uv=False)
    angle = sv[:, 0] / np.maximum(sv[:, 1], 1e-30)
    scale = a2.sum() / a3.sum()  # UV area per m²
    area = a2 / np.maximum(a3, 1e-30) / scale
    w = a3 / a3.sum()
    major = np.sign(det_q.sum())
    el = np.linalg.norm(np.asarray(vertices, np.float64)[faces[:, [1, 2, 0]]]
                        - np.asarray(vertices, np.float64)[faces], axis=2)
    tpm = float(np.sqrt(scale) * 256)
    return UVStats(angle_mean=float((w * angle).sum()), angle_p95=_weighted_quantile(angle, w, 0.95),
                   angle_max=float(angle.max()), area_p5=_weighted_quantile(area, w, 0.05),
                   area_p95=_weighted_quantile(area, w, 0.95), flipped=int((np.sign(det_q) != major).sum()),
                   texels_per_metre_256=tpm, mean_edge_texels_256=float(el.mean() * tpm),
                   min_triangle_texels_512=float(a2.min() * 512 ** 2), fill=float(a2.sum()))
