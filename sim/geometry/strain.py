"""Green-Lagrange strain of a deformed garment against its rest shape (Guo et al. 2024, Eq. 3).

Per face, F = ∂x/∂X is the 3×2 deformation gradient of the deformed triangle with respect to
the rest triangle written in a 2D orthonormal frame of its own plane, and
E = ½ (FᵀF − I) the symmetric 2×2 Green-Lagrange tensor, returned as (E11, E22, E12). Its
Frobenius norm ‖E‖_F = sqrt(E11² + E22² + 2 E12²) is the paper's rotation-invariant
conditioning signal. ``Dm⁻¹`` (rest edges in the face frame, inverted) is computed once per
garment; the per-frame work is one Warp launch over (T, F).

Which orthonormal frame: by default axis 1 runs along the rest edge x0 → x1 (any choice gives
the same norm, trace and determinant). Given the garment's UV layout, axis 1 runs along the rest
direction of increasing u1 and axis 2 toward increasing u2 (panels are packed upright, so E11
is the horizontal/weft strain and E22 the vertical/grain-line strain), and the components mean
the same thing on every face: only then is the per-vertex average of the tensor meaningful.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.device import resolve_device, warp
from sim.errors import WrinklesInputError

MIN_REST_AREA = 1e-12
"""Smallest rest triangle area [m²] accepted (a 1.4 µm right triangle): below it Dm is singular
in float32 and the strain of the face is meaningless."""


def as_frames(x: np.ndarray, num: int | None, what: str) -> tuple[np.ndarray, bool]:
    """``x`` as float32 (T, N, 3), and whether it was a single (N, 3) frame.

    Raises:
        WrinklesInputError: wrong shape, or N != ``num`` (when given).
    """
    a = np.asarray(x, dtype=np.float32)
    single = a.ndim == 2
    if single:
        a = a[None]
    if a.ndim != 3 or a.shape[2] != 3 or (num is not None and a.shape[1] != num):
        want = "(T, V, 3) or (V, 3)" if num is None else f"(T, {num}, 3) or ({num}, 3)"
        raise WrinklesInputError(f"{what} must have shape {want}, got {np.shape(x)}")
    return np.ascontiguousarray(a), single


def check_faces(faces: np.ndarray, num_vertices: int, what: str = "faces") -> np.ndarray:
    """``faces`` as int32 (F, 3) indices into ``num_vertices`` vertices (else WrinklesInputError)."""
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or not np.issubdtype(f.dtype, np.integer):
        raise WrinklesInputError(f"{what} must be a non-empty integer array of shape (F, 3), got {f.shape}")
    if f.min() < 0 or f.max() >= num_vertices:
        raise WrinklesInputError(f"{what} index {int(f.max()) if f.max() >= num_vertices else int(f.min())} "
                                 f"is outside [0, {num_vertices - 1}]")
    return np.ascontiguousarray(f, dtype=np.int32)


def incidence_csr(rows: np.ndarray, cols: np.ndarray, num_rows: int,
                  weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR lists ``row -> cols`` with weights normalised to sum 1 per row.

    Args:
        rows, cols: (K,) int pairs; weights: (K,) >= 0, None = equal.

    Returns:
        offsets (num_rows + 1,) int32, cols (K,) int32 sorted by row (stable), weights (K,)
        float32 (rows whose weights sum to 0 get equal weights).
    """
    rows = np.asarray(rows, np.int64)
    order = np.argsort(rows, kind="stable")
    counts = np.bincount(rows, minlength=num_rows)
    offsets = np.zeros(num_rows + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    w = np.ones(len(rows)) if weights is None else np.asarray(weights, np.float64)
    w = w[order]
    r = rows[order]
    total = np.bincount(r, w, minlength=num_rows)
    zero = total[r] <= 0.0
    w = np.where(zero, 1.0 / np.maximum(counts[r], 1), w / np.where(zero, 1.0, total[r]))
    return offsets.astype(np.int32), np.asarray(cols, np.int64)[order].astype(np.int32), w.astype(np.float32)


def rest_strain_frames(rest_vertices: np.ndarray, faces: np.ndarray, *, uvs: np.ndarray | None = None,
                       uv_faces: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Inverse rest edge matrices Dm⁻¹ of every face in its 2D orthonormal frame, and rest areas.

    Args:
        rest_vertices: rest positions [m], shape (V, 3).
        faces: (F, 3) int.
        uvs: texture coordinates, shape (U, 2); with ``uv_faces`` (F, 3), axis 1 of each face's
            frame follows increasing u1 and axis 2 increasing u2 (module docstring); None: axis 1
            along the edge x0 → x1, axis 2 completing a right-handed frame about the face normal.

    Returns:
        dm_inv: (F, 2, 2) float32 [1/m]; rest_area: (F,) float64 [m²].

    Raises:
        WrinklesInputError: a rest triangle with area below ``MIN_REST_AREA``.
    """
    x = np.asarray(rest_vertices, np.float64)
    f = check_faces(faces, len(x))
    p = x[f]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    n = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(n, axis=1)
    bad = np.flatnonzero(area < MIN_REST_AREA)
    if bad.size:
        raise WrinklesInputError(f"{bad.size} rest triangle(s) have (near-)zero area (first: face {bad[0]})")
    n /= (2.0 * area)[:, None]
    ax = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    if uvs is not None and uv_faces is not None:
        uf = check_faces(uv_faces, len(uvs), "uv_faces")
        if uf.shape != f.shape:
            raise WrinklesInputError(f"uv_faces has shape {uf.shape}, faces {f.shape}: they must match")
        q = np.asarray(uvs, np.float64)[uf]
        Q = np.stack([q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]], axis=2)  # (F, 2, 2), columns = UV edges
        det = Q[:, 0, 0] * Q[:, 1, 1] - Q[:, 0, 1] * Q[:, 1, 0]
        ok = np.abs(det) > 1e-14
        Qi = np.zeros_like(Q)
        Qi[ok] = np.linalg.inv(Q[ok])
        D = np.stack([e1, e2], axis=2)  # (F, 3, 2)
        g = D @ Qi  # ∂X/∂u, columns along u1 and u2
        g1 = np.linalg.norm(g[:, :, 0], axis=1)
        ok &= g1 > 1e-12
        ax[ok] = g[ok, :, 0] / g1[ok, None]
        ay = np.cross(n, ax)
        flip = ok & ((ay * g[:, :, 1]).sum(1) < 0)  # a mirrored chart: axis 2 toward +u2
        ay[flip] *= -1
    else:
        ay = np.cross(n, ax)
    Dm = np.empty((len(f), 2, 2))
    Dm[:, 0, 0], Dm[:, 0, 1] = (e1 * ax).sum(1), (e2 * ax).sum(1)
    Dm[:, 1, 0], Dm[:, 1, 1] = (e1 * ay).sum(1), (e2 * ay).sum(1)
    return np.linalg.inv(Dm).astype(np.float32), area


def strain_norm(strain: np.ndarray) -> np.ndarray:
    """Frobenius norm sqrt(E11² + E22² + 2 E12²) of symmetric tensors stored as (..., 3)."""
    e = np.asarray(strain)
    return np.sqrt(e[..., 0] ** 2 + e[..., 1] ** 2 + 2.0 * e[..., 2] ** 2)


@dataclass(frozen=True)
class StrainField:
    """Green-Lagrange strain of a sequence (T frames; the T axis is absent for one frame).

    Attributes:
        face: (E11, E22, E12) per face [-], shape (T, F, 3).
        face_norm: ‖E‖_F per face [-], shape (T, F).
        vertex: rest-area-weighted average of ``face`` over the faces of each vertex, (T, V, 3)
            (meaningful when the frames follow the UV layout, see the module docstring).
        vertex_norm: rest-area-weighted average of ``face_norm`` over the faces of each vertex,
            (T, V): the scalar field E(u) of Guo et al. sampled at vertices, for UV images
            (index it with ``sim.geometry.frames.uv_vertex_map`` for UV vertices).
    """

    face: np.ndarray
    face_norm: np.ndarray
    vertex: np.ndarray
    vertex_norm: np.ndarray


class GreenStrain:
    """Strain of one garment: Dm⁻¹ and the vertex-face incidence built once, then any number of
    frames.

    Args:
        rest_vertices: rest positions [m], shape (V, 3).
        faces: (F, 3) int.
        uvs, uv_faces: optional UV layout, (U, 2) and (F, 3): UV-aligned face frames
            (:func:`rest_strain_frames`).
        device: Warp device (None: cuda when present, else cpu).
    """

    def __init__(self, rest_vertices: np.ndarray, faces: np.ndarray, *, uvs: np.ndarray | None = None,
                 uv_faces: np.ndarray | None = None, device: str | None = None):
        wp = warp()
        self.device = resolve_device(device)
        rest, _ = as_frames(rest_vertices, None, "rest_vertices")
        if rest.shape[0] != 1:
            raise WrinklesInputError(f"rest_vertices must have shape (V, 3), got {np.shape(rest_vertices)}")
        self.num_vertices = rest.shape[1]
        self.faces = check_faces(faces, self.num_vertices)
        dm_inv, area = rest_strain_frames(rest[0], self.faces, uvs=uvs, uv_faces=uv_faces)
        self.rest_area = area
        offsets, index, weight = incidence_csr(self.faces.ravel(), np.repeat(np.arange(len(self.faces)), 3),
                                               self.num_vertices, np.repeat(area, 3))
        d = self.device
        self._faces = wp.array(self.faces, dtype=int, device=d)
        self._dm_inv = wp.array(dm_inv, dtype=wp.mat22, device=d)
        self._csr = [wp.array(offsets, dtype=int, device=d), wp.array(index, dtype=int, device=d),
                     wp.array(weight, dtype=float, device=d)]

    def _launch(self, vertices: np.ndarray, per_vertex: bool):
        wp = warp()
        from sim.geometry import geometry_kernels as K

        x, single = as_frames(vertices, self.num_vertices, "vertices")
        d = self.device
        T, F = x.shape[0], len(self.faces)
        xd = wp.array(x, dtype=wp.vec3, device=d)
        e = wp.empty((T, F), dtype=wp.vec3, device=d)
        en = wp.empty((T, F), dtype=float, device=d)
        wp.launch(K.green_lagrange_kernel, dim=(T, F), inputs=[xd, self._faces, self._dm_inv],
                  outputs=[e, en], device=d)
        out = [e, en]
        if per_vertex:
            ev = wp.empty((T, self.num_vertices), dtype=wp.vec3, device=d)
            evn = wp.empty((T, self.num_vertices), dtype=float, device=d)
            wp.launch(K.csr_mean_vec3_kernel, dim=ev.shape, inputs=[e, *self._csr], outputs=[ev], device=d)
            wp.launch(K.csr_mean_float_kernel, dim=evn.shape, inputs=[en, *self._csr], outputs=[evn],
                      device=d)
            out += [ev, evn]
        out = [a.numpy() for a in out]
        return [a[0] for a in out] if single else out

    def face_strain(self, vertices: np.ndarray) -> np.ndarray:
        """(E11, E22, E12) per face [-]: (T, F, 3) for positions (T, V, 3) [m], (F, 3) for (V, 3)."""
        return self._launch(vertices, per_vertex=False)[0]

    def compute(self, vertices: np.ndarray) -> StrainField:
        """Per-face and per-vertex strain and norm of positions [m], (T, V, 3) or (V, 3)."""
        return StrainField(*self._launch(vertices, per_vertex=True))


def green_lagrange(vertices: np.ndarray, rest_vertices: np.ndarray, faces: np.ndarray, *,
                   uvs: np.ndarray | None = None, uv_faces: np.ndarray | None = None,
                   device: str | None = None) -> np.ndarray:
    """Green-Lagrange strain (E11, E22, E12) of every face (Guo et al. 2024, Eq. 3).

    Args:
        vertices: deformed positions [m], shape (T, V, 3) or (V, 3).
        rest_vertices: rest positions [m], shape (V, 3).
        faces: (F, 3) int.
        uvs, uv_faces: optional UV layout for UV-aligned face frames (module docstring).
        device: Warp device.

    Returns:
        float32 (T, F, 3) or (F, 3).
    """
    return GreenStrain(rest_vertices, faces, uvs=uvs, uv_faces=uv_faces, device=device).face_strain(vertices)


def strain_field(vertices: np.ndarray, rest_vertices: np.ndarray, faces: np.ndarray, *,
                 uvs: np.ndarray | None = None, uv_faces: np.ndarray | None = None,
                 device: str | None = None) -> StrainField:
    """Per-face and per-vertex strain tensor and norm; arguments as :func:`green_lagrange`."""
    return GreenStrain(rest_vertices, faces, uvs=uvs, uv_faces=uv_faces, device=device).compute(vertices)
