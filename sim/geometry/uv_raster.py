"""UV-image rasterisation and sample-back (the dataset generator's UV images).

A garment's per-vertex fields (strain, wrinkle displacement, normals) become images over its UV
layout for convolutional networks, and images become per-vertex fields again.

Image convention (that of a texture on a USD ``primvars:st`` or Blender UV map, whose origin is
the bottom-left corner): an image has shape (…, H, W, C); row 0 is the *top* (v = 1), so pixel
(row, col) has its centre at

    u = (col + 0.5) / W,    v = 1 − (row + 0.5) / H,

and ``PIL.Image.fromarray(image)`` shows the texture as a DCC tool's UV editor shows it.

A pixel is *covered* (``mask``) when its centre lies in a UV triangle; it takes the lowest
such triangle index and its barycentrics there. Pixels within ``dilate`` px of a chart but not
covered take the nearest triangle's values, continued linearly outward (or, with
``extrapolate=False`` and for slivers, those of their closest point on it), so bilinear
sampling and convolutions near a seam see the panel's own field, not zeros; the rest of the
image is 0. Every result is independent of thread scheduling (no atomics; ties go to the lowest
triangle index): two runs on the same device give byte-identical images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.device import resolve_device, warp
from sim.errors import WrinklesInputError

DILATE_PX = 2.0
"""Default dilation [px] around the charts: a point inside a triangle has its four bilinear
taps within √2 px, so 2 px makes every tap of every in-chart sample a panel pixel. The packed
layout keeps 0.02 of the square between panels (``sim.garments.uv.UV_MARGIN``, 5 px at 256²),
so dilated rims of neighbouring panels do not meet at 256² and above."""
INSIDE_EPS = 1e-6
"""Barycentric tolerance of the inside test: a pixel centre on an edge shared by two
triangles (or a hair outside both through float32 rounding) is covered by one of them (the
lower index), never by neither."""
EXTRAPOLATE_MIN_WEIGHT = -1.5
"""Rim pixels extrapolate the nearest triangle's linear function only while every barycentric
weight stays >= -1.5, i.e. where the pixel is at most 1.5 triangle heights from it; slivers
would amplify their corner values, and fall back to the closest point's (clamped)
barycentrics. The bound covers the 2 px rim of the triangles along the panels' outlines (the
coarse t-shirt's flat pattern mesh: 1.7 px tall at the least at 256², 3.0 px the median). Linear
extension makes a linear field exact in the rim, so sampling back at chart boundary vertices is
as accurate as inside. Measured (coarse t-shirt, 256², sin(3u)cos(2v) + u/2 − v sampled back at
the 402 boundary UV vertices): max error 3.4e-3 clamped, 1.3e-4 extrapolated (1.4e-4 at
interior vertices)."""
TILE_PX = 8
"""Side [px] of the square tiles that bin triangles for the per-pixel coverage kernel."""
MAX_RESOLUTION = 16384
"""Largest image side accepted [px]."""


@dataclass(frozen=True)
class UVCoverage:
    """Which triangle each pixel of a UV image samples, and where.

    Attributes:
        face: triangle index per pixel, shape (H, W), int32; -1 where the pixel is neither
            covered nor in the dilated rim.
        barycentrics: weights of the triangle's three UV corners at the pixel (the pixel centre
            inside a triangle, its closest point on the nearest triangle in the rim), shape
            (H, W, 3), float32; 0 where ``face`` is -1.
        mask: pixel centre inside a UV triangle (true coverage), shape (H, W), bool.
        valid: ``face >= 0`` (coverage plus the dilated rim), shape (H, W), bool.
        chart: connected UV chart (panel) of each pixel's triangle, shape (H, W), int32; -1
            where ``face`` is -1.
    """

    face: np.ndarray
    barycentrics: np.ndarray
    mask: np.ndarray
    valid: np.ndarray
    chart: np.ndarray

    @property
    def resolution(self) -> tuple[int, int]:
        """(H, W) [px]."""
        return int(self.face.shape[0]), int(self.face.shape[1])


def _resolution(resolution: int | tuple[int, int]) -> tuple[int, int]:
    if isinstance(resolution, (int, np.integer)):
        hw = (int(resolution), int(resolution))
    else:
        try:
            hw = tuple(int(r) for r in resolution)
        except (TypeError, ValueError):
            hw = ()
        if len(hw) != 2 or any(r != s for r, s in zip(hw, resolution, strict=True)):
            raise WrinklesInputError(f"UV image resolution must be an int or (H, W), got {resolution!r}")
    if not all(1 <= r <= MAX_RESOLUTION for r in hw):
        raise WrinklesInputError(f"UV image resolution {hw} must be within 1..{MAX_RESOLUTION} px")
    return hw


def _check_layout(uvs: np.ndarray, uv_faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uv = np.asarray(uvs, dtype=np.float32)
    if uv.ndim != 2 or uv.shape[1] != 2 or len(uv) < 3:
        raise WrinklesInputError(f"uvs must have shape (U, 2) with U >= 3, got {uv.shape}")
    if not np.all(np.isfinite(uv)):
        raise WrinklesInputError("uvs contain NaN or inf")
    f = np.asarray(uv_faces)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1 or not np.issubdtype(f.dtype, np.integer):
        raise WrinklesInputError(f"uv_faces must be integer (F, 3) with F >= 1, got {f.dtype} {f.shape}")
    if f.min() < 0 or f.max() >= len(uv):
        raise WrinklesInputError(f"uv_faces index outside [0, {len(uv) - 1}] (the uvs)")
    return uv, f.astype(np.int32)


def uv_charts(uv_faces: np.ndarray, num_uvs: int) -> tuple[np.ndarray, np.ndarray]:
    """Connected charts of a UV layout (faces sharing a UV vertex).

    Args:
        uv_faces: (F, 3) int into the UV vertices.
        num_uvs: U.

    Returns:
        ``(face_chart (F,), uv_chart (U,))``, int32, charts numbered 0.. in order of their lowest
        UV vertex; -1 for a UV vertex no face uses.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(uv_faces, np.int64)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    g = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(num_uvs, num_uvs))
    _, labels = connected_components(g, directed=False)  # numbered by lowest vertex: deterministic
    used = np.zeros(num_uvs, bool)
    used[f.ravel()] = True
    uv_chart = np.where(used, labels, -1)
    _, uv_chart[used] = np.unique(labels[used], return_inverse=True)
    return uv_chart[f[:, 0]].astype(np.int32), uv_chart.astype(np.int32)


def uv_to_vertex(faces: np.ndarray, uv_faces: np.ndarray, num_uvs: int) -> np.ndarray:
    """The 3D vertex of each UV vertex, by the corner correspondence of ``faces`` and ``uv_faces``.

    Args:
        faces: (F, 3) int into the 3D vertices.
        uv_faces: (F, 3) int into the UV vertices, same triangles and corner order.
        num_uvs: U.

    Returns:
        (U,) int32; -1 for a UV vertex no face uses.

    Raises:
        WrinklesInputError: shapes differ, or a UV vertex is a corner of two different 3D vertices.
    """
    f = np.asarray(faces)
    uf = np.asarray(uv_faces)
    if f.shape != uf.shape or f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise WrinklesInputError(f"faces must be integer (F, 3) like uv_faces {uf.shape}, "
                                 f"got {f.dtype} {f.shape}")
    if uf.size and (uf.min() < 0 or uf.max() >= num_uvs):
        raise WrinklesInputError(f"uv_faces index outside [0, {num_uvs - 1}] (the uvs)")
    if f.size and f.min() < 0:
        raise WrinklesInputError("faces hold a negative vertex index")
    out = np.full(num_uvs, -1, np.int64)
    out[uf.ravel()] = f.ravel()
    bad = out[uf] != f
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise WrinklesInputError(f"UV vertex {int(uf[i, j])} is a corner of 3D vertices {int(out[uf[i, j]])} "
                                 f"and {int(f[i, j])}: faces and uv_faces disagree")
    return out.astype(np.int32)


def lift_to_uvs(values: np.ndarray, faces: np.ndarray, uv_faces: np.ndarray, num_uvs: int) -> np.ndarray:
    """Per-3D-vertex values to per-UV-vertex values: each UV copy takes its vertex's value.

    Args:
        values: (…, V, C) per 3D vertex.
        faces: (F, 3) int into the V vertices.
        uv_faces: (F, 3) int into the U UV vertices, corners matching ``faces``.
        num_uvs: U.

    Returns:
        (…, U, C) float32; 0 for a UV vertex no face uses.
    """
    x = np.asarray(values, dtype=np.float32)
    m = uv_to_vertex(faces, uv_faces, num_uvs)
    if x.ndim < 2 or (m.size and m.max() >= x.shape[-2]):
        raise WrinklesInputError(f"values must have shape (..., V, C) with V > {int(m.max())} "
                                 f"(the largest vertex index in faces), got {x.shape}")
    out = x[..., np.maximum(m, 0), :]
    out[..., m < 0, :] = 0.0
    return np.ascontiguousarray(out)


def _pixel_space(uvs: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """UVs (N, 2) to pixel space (N, 2) float32: x = u·W (columns), y = (1 − v)·H (rows from the top)."""
    uv = np.asarray(uvs, np.float64)
    return np.stack([uv[:, 0] * hw[1], (1.0 - uv[:, 1]) * hw[0]], axis=1).astype(np.float32)


def _tile_bins(tri: np.ndarray, hw: tuple[int, int], radius: float) -> tuple[np.ndarray, np.ndarray, int]:
    """CSR lists, per tile of TILE_PX² pixels, of the triangles (ascending) whose bounding box
    grown by ``radius`` px reaches a pixel centre of the tile. tri: (F, 3, 2) in pixel space."""
    H, W = hw
    tx, ty = -(-W // TILE_PX), -(-H // TILE_PX)
    slop = radius + 1e-3  # pixel centres on an edge count as inside (INSIDE_EPS)
    lo = tri.min(axis=1) - slop
    hi = tri.max(axis=1) + slop
    # pixel centres c + 0.5 within [lo, hi]: columns ceil(lo - 0.5) .. floor(hi - 0.5)
    c0 = np.clip(np.ceil(lo[:, 0] - 0.5), 0, W - 1).astype(np.int64) // TILE_PX
    c1 = np.clip(np.floor(hi[:, 0] - 0.5), 0, W - 1).astype(np.int64) // TILE_PX
    r0 = np.clip(np.ceil(lo[:, 1] - 0.5), 0, H - 1).astype(np.int64) // TILE_PX
    r1 = np.clip(np.floor(hi[:, 1] - 0.5), 0, H - 1).astype(np.int64) // TILE_PX
    empty = (hi[:, 0] - 0.5 < 0) | (lo[:, 0] - 0.5 > W - 1) | (hi[:, 1] - 0.5 < 0) | (lo[:, 1] - 0.5 > H - 1)
    nx = np.where(empty, 0, c1 - c0 + 1)
    ny = np.where(empty, 0, r1 - r0 + 1)
    n = nx * ny
    face = np.repeat(np.arange(len(tri), dtype=np.int64), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)  # index within each triangle's block
    nxr = np.repeat(nx, n)
    tile = (np.repeat(r0, n) + k // np.maximum(nxr, 1)) * tx + np.repeat(c0, n) + k % np.maximum(nxr, 1)
    order = np.argsort(tile, kind="stable")  # stable: ascending face index within each tile
    start = np.zeros(tx * ty + 1, np.int64)
    np.cumsum(np.bincount(tile, minlength=tx * ty), out=start[1:])
    return start.astype(np.int32), face[order].astype(np.int32), tx


def uv_coverage(uvs: np.ndarray, uv_faces: np.ndarray, resolution: int | tuple[int, int] = 256, *,
                dilate: float = DILATE_PX, extrapolate: bool = True, device: str | None = None) -> UVCoverage:
    """Rasterise a UV layout: covering triangle and barycentrics of every pixel (Warp kernel).

    Args:
        uvs: texture coordinates, shape (U, 2), normally in [0, 1]² (outside parts are cut off).
        uv_faces: (F, 3) int into ``uvs``.
        resolution: image side [px], or (H, W).
        dilate: width [px] of the rim outside the charts that takes the nearest triangle's
            values (0: none).
        extrapolate: rim pixels continue the nearest triangle's linear function (True) or take
            the value of their closest point on it (False).
        device: Warp device (None: cuda when present, else cpu).

    Returns:
        The coverage (see ``UVCoverage`` and the module docstring for the pixel convention).
    """
    wp = warp()
    from sim.geometry import uv_raster_kernels as K

    uv, f = _check_layout(uvs, uv_faces)
    H, W = _resolution(resolution)
    dilate = float(dilate)
    if not 0.0 <= dilate <= 64.0:
        raise WrinklesInputError(f"dilate must be within 0..64 px, got {dilate}")
    d = resolve_device(device)
    tri = _pixel_space(uv, (H, W))[f]  # (F, 3, 2)
    start, tile_faces, tiles_x = _tile_bins(tri, (H, W), dilate)
    face = wp.empty((H, W), dtype=int, device=d)
    bary = wp.empty((H, W), dtype=wp.vec3, device=d)
    covered = wp.empty((H, W), dtype=int, device=d)
    wp.launch(K.coverage_kernel, dim=(H, W),
              inputs=[wp.array(tri.astype(np.float32), dtype=wp.vec2, device=d),
                      wp.array(start, dtype=int, device=d),
                      wp.array(np.maximum(tile_faces, 0) if tile_faces.size else np.zeros(1, np.int32),
                               dtype=int, device=d),
                      int(tiles_x), TILE_PX, dilate, INSIDE_EPS,
                      EXTRAPOLATE_MIN_WEIGHT if extrapolate else 2.0],  # no weight is >= 2: clamp
              outputs=[face, bary, covered], device=d)
    face_np = face.numpy().astype(np.int32)
    valid = face_np >= 0
    face_chart, _ = uv_charts(f, len(uv))
    chart = np.where(valid, face_chart[np.maximum(face_np, 0)], -1).astype(np.int32)
    b = bary.numpy().astype(np.float32)
    b[~valid] = 0.0
    return UVCoverage(face=face_np, barycentrics=b, mask=covered.numpy().astype(bool), valid=valid,
                      chart=chart)


class UVRasterizer:
    """Maps per-vertex fields of one UV layout to images and back, on one device.

    The coverage is computed once (``uv_coverage``); the lists of valid pixels, UV positions and
    charts stay on the device for every later call. Images follow the module's convention: row
    0 is v = 1, pixel (row, col) centred at u = (col + 0.5) / W, v = 1 − (row + 0.5) / H.

    Args:
        uvs: (U, 2) texture coordinates in [0, 1]² (``Garment.uvs``).
        uv_faces: (F, 3) int (``Garment.uv_faces``).
        resolution: image side [px], or (H, W).
        dilate: rim [px] around the charts filled from the nearest triangle.
        extrapolate: rim values continue the nearest triangle's linear function (else clamped).
        device: Warp device (None: cuda when present, else cpu).

    Attributes:
        coverage: the ``UVCoverage``; ``mask`` (H, W) bool is its true coverage.
        num_uvs, num_faces: U and F.
    """

    def __init__(self, uvs: np.ndarray, uv_faces: np.ndarray, resolution: int | tuple[int, int] = 256, *,
                 dilate: float = DILATE_PX, extrapolate: bool = True, device: str | None = None):
        wp = warp()
        self.device = resolve_device(device)
        self._uvs, self._uv_faces = _check_layout(uvs, uv_faces)
        self.coverage = uv_coverage(self._uvs, self._uv_faces, resolution, dilate=dilate,
                                    extrapolate=extrapolate, device=self.device)
        H, W = self.coverage.resolution
        d = self.device
        flat = np.flatnonzero(self.coverage.valid).astype(np.int32)  # row-major: ascending
        self._pixel = wp.array(flat, dtype=int, device=d)
        self._face = wp.array(self.coverage.face.ravel()[flat], dtype=int, device=d)
        self._bary = wp.array(self.coverage.barycentrics.reshape(-1, 3)[flat], dtype=wp.vec3, device=d)
        self._corners = wp.array(self._uv_faces, dtype=int, device=d)
        self._uv_px = wp.array(_pixel_space(self._uvs, (H, W)), dtype=wp.vec2, device=d)
        _, uv_chart = uv_charts(self._uv_faces, len(self._uvs))
        self._uv_chart = wp.array(uv_chart, dtype=int, device=d)
        self._pixel_chart = wp.array(self.coverage.chart.ravel(), dtype=int, device=d)
        self._copies: dict[bytes, tuple] = {}

    @classmethod
    def from_garment(cls, garment, resolution: int | tuple[int, int] = 256, *, dilate: float = DILATE_PX,
                     extrapolate: bool = True, device: str | None = None) -> UVRasterizer:
        """The rasterizer of a ``Garment``'s UV layout."""
        return cls(garment.uvs, garment.uv_faces, resolution, dilate=dilate, extrapolate=extrapolate,
                   device=device)

    @property
    def resolution(self) -> tuple[int, int]:
        """(H, W) [px]."""
        return self.coverage.resolution

    @property
    def mask(self) -> np.ndarray:
        """True coverage, shape (H, W), bool."""
        return self.coverage.mask

    @property
    def num_uvs(self) -> int:
        return int(len(self._uvs))

    @property
    def num_faces(self) -> int:
        return int(len(self._uv_faces))

    def rasterize(self, values: np.ndarray, *, per: str | None = None) -> np.ndarray:
        """Per-UV-vertex or per-face values to images (one kernel launch for all frames).

        Args:
            values: (…, U, C) per UV vertex (interpolated with the pixel's barycentrics), or
                (…, F, C) per face (constant over each triangle); any leading axes (e.g. T).
            per: "uv" or "face"; None infers it from the size of axis −2 (required when U == F).

        Returns:
            Images, shape (…, H, W, C), float32; 0 outside ``coverage.valid``.
        """
        wp = warp()
        from sim.geometry import uv_raster_kernels as K

        x = np.asarray(values, dtype=np.float32)
        U, F = self.num_uvs, self.num_faces
        if x.ndim < 2 or x.shape[-1] < 1 or x.shape[-2] not in (U, F):
            raise WrinklesInputError(f"values must have shape (..., U={U}, C) or (..., F={F}, C), "
                                     f"got {x.shape}")
        if per is None:
            if U == F:
                raise WrinklesInputError(f"values (..., {U}, C) could be per UV vertex or per face (U == F): "
                                         "pass per='uv' or per='face'")
            per = "uv" if x.shape[-2] == U else "face"
        if per not in ("uv", "face") or x.shape[-2] != (U if per == "uv" else F):
            raise WrinklesInputError(f"per={per!r} with values {x.shape}: expected per='uv' with "
                                     f"(..., {U}, C) or per='face' with (..., {F}, C)")
        lead, (N, C) = x.shape[:-2], x.shape[-2:]
        T = int(np.prod(lead, dtype=np.int64))
        H, W = self.resolution
        d = self.device
        out = wp.zeros((T, H * W, C), dtype=float, device=d)
        if T and self._pixel.shape[0]:
            vals = wp.array(np.ascontiguousarray(x.reshape(T, N, C)), dtype=float, device=d)
            if per == "uv":
                wp.launch(K.interpolate_kernel, dim=(T, self._pixel.shape[0]),
                          inputs=[vals, self._corners, self._pixel, self._face, self._bary],
                          outputs=[out], device=d)
            else:
                wp.launch(K.face_constant_kernel, dim=(T, self._pixel.shape[0]),
                          inputs=[vals, self._pixel, self._face], outputs=[out], device=d)
        return out.numpy().reshape(*lead, H, W, C)

    def rasterize_vertices(self, values: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Per-3D-vertex values (…, V, C) to images (…, H, W, C), via ``lift_to_uvs``.

        Args:
            values: (…, V, C) per 3D vertex.
            faces: (F, 3) int into the V vertices, corners matching ``uv_faces``.
        """
        return self.rasterize(lift_to_uvs(values, faces, self._uv_faces, self.num_uvs), per="uv")

    def _check_images(self, images: np.ndarray) -> np.ndarray:
        x = np.asarray(images, dtype=np.float32)
        H, W = self.resolution
        if x.ndim < 3 or x.shape[-3:-1] != (H, W) or x.shape[-1] < 1:
            raise WrinklesInputError(f"images must have shape (..., H={H}, W={W}, C), got {x.shape}")
        return x

    def sample(self, images: np.ndarray) -> np.ndarray:
        """Bilinear sample of images at every UV vertex (one kernel launch for all frames).

        Only the taps in the vertex's own chart count (weights renormalised), so empty pixels
        and other panels never bleed in. Taps beyond the image border repeat the border pixel,
        so a UV within half a pixel of the border reads that pixel's value (``pack_uvs``
        leaves a 0.02 margin, 5 px at 256²).

        Args:
            images: (…, H, W, C).

        Returns:
            (…, U, C) float32 per UV vertex.
        """
        wp = warp()
        from sim.geometry import uv_raster_kernels as K

        x = self._check_images(images)
        lead, C = x.shape[:-3], x.shape[-1]
        T = int(np.prod(lead, dtype=np.int64))
        H, W = self.resolution
        U = self.num_uvs
        d = self.device
        out = wp.empty((T, U, C), dtype=float, device=d)
        if T:
            img = wp.array(np.ascontiguousarray(x.reshape(T, H * W, C)), dtype=float, device=d)
            wp.launch(K.bilinear_sample_kernel, dim=(T, U),
                      inputs=[img, H, W, self._uv_px, self._uv_chart, self._pixel_chart],
                      outputs=[out], device=d)
        return out.numpy().reshape(*lead, U, C)

    def _copy_lists(self, faces: np.ndarray):
        f = np.ascontiguousarray(faces)
        key = f.tobytes() + str(f.shape).encode()
        if key not in self._copies:
            wp = warp()
            m = uv_to_vertex(f, self._uv_faces, self.num_uvs)
            V = int(f.max()) + 1
            used = np.flatnonzero(m >= 0)
            order = used[np.argsort(m[used], kind="stable")]  # each vertex's copies, ascending
            start = np.zeros(V + 1, np.int32)
            np.cumsum(np.bincount(m[used], minlength=V), out=start[1:])
            self._copies = {key: (V, wp.array(start, dtype=int, device=self.device),
                                  wp.array(order.astype(np.int32), dtype=int, device=self.device))}
        return self._copies[key]

    def sample_vertices(self, images: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Per-3D-vertex values: the mean of ``sample`` over each vertex's UV copies.

        A vertex on a seam has one UV copy per panel; averaging them makes the field
        single-valued on the 3D mesh.

        Args:
            images: (…, H, W, C).
            faces: (F, 3) int into the 3D vertices, corners matching ``uv_faces``
                (``Garment.faces``); V = max index + 1.

        Returns:
            (…, V, C) float32; 0 for a vertex no face uses.
        """
        wp = warp()
        from sim.geometry import uv_raster_kernels as K

        per_uv = self.sample(images)
        V, start, copies = self._copy_lists(faces)
        lead, C = per_uv.shape[:-2], per_uv.shape[-1]
        T = int(np.prod(lead, dtype=np.int64))
        d = self.device
        out = wp.empty((T, V, C), dtype=float, device=d)
        if T:
            vals = wp.array(np.ascontiguousarray(per_uv.reshape(T, self.num_uvs, C)), dtype=float, device=d)
            wp.launch(K.average_copies_kernel, dim=(T, V), inputs=[vals, start, copies], outputs=[out],
                      device=d)
        return out.numpy().reshape(*lead, V, C)
