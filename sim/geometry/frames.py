"""Normals, local frames and the wrinkle field in them (Guo et al. 2024, Eqs. 1-2).

The garment f = f_b + f_w is a smooth base surface plus wrinkles (Eq. 1). At each UV vertex the
local frame is {∂f_b/∂u1, ∂f_b/∂u2, n̂_b} (Eq. 2), and the wrinkle displacement f − f_b of its
3D vertex is stored as the components w̃ in that frame, f_w = w̃1 t1 + w̃2 t2 + w̃3 n̂_b.

Discretisation:

- tangents: the gradient of the base positions with respect to UV on each face,
  Ds Q⁻¹ (Ds, Q the 3D and UV edge matrices), averaged with UV-area weights over the faces of
  the UV vertex. UV vertices are split along seams, so each side of a seam averages over its own
  chart only: the two copies of a seam vertex have their own tangents and their own w̃.
- scale: ∂f_b/∂u is in metres per UV unit; it is divided by the garment's metres-per-UV-unit,
  ``uv_scale`` = sqrt(Σ rest 3D area / Σ UV area) (the packing uses one scale for every panel),
  so t1, t2 are about unit length at rest and w̃ is in metres.
- normal: the unit area-weighted normal over the same faces (the UV vertex's chart). Away from
  seams that is the 3D vertex normal. On a seam each copy takes its own side's normal: the 3D
  vertex normal averages both sides, and where panels meet at a crease it lies almost in one
  side's tangent plane (on the t-shirt template |det[t1 t2 n̂]| / (|t1| |t2|) drops to 0.03 at
  side seams, and a 3 mm offset encodes as w̃ of 17 cm), while the chart's own normal keeps
  the frame well conditioned (t1 × t2 and n̂ come from the same faces).
- decode: every UV copy gives a displacement; a 3D vertex takes the mean over its copies
  (identical for an encoded field, since every copy solves for the same displacement).

Degenerate frames: where a tangent is shorter than ``FRAME_MIN_TANGENT`` or the frame is nearly
flat (|det[t1 t2 n̂]| < ``FRAME_MIN_VOLUME`` |t1| |t2|: tangents within ~0.6° of parallel or
tilted out of the tangent plane), the 3×3 system is ill-conditioned; the frame is replaced by an
orthonormal one {e1, e2, n̂}: e1 the part of t1 orthogonal to n̂ (else of t2, else any direction),
e2 = ±n̂ × e1 on the side of t2. Encode and decode use the same rule, so the round trip stays
exact; w̃ there is in metres along unit axes.
"""

from __future__ import annotations

import numpy as np

from sim.device import resolve_device, warp
from sim.errors import WrinklesInputError
from sim.geometry.strain import as_frames, check_faces, incidence_csr

FRAME_MIN_TANGENT = 1e-3
"""Shortest accepted (scaled, ~1 at rest) tangent: a panel compressed 1000-fold along u is a
degenerate base surface, not cloth."""
FRAME_MIN_VOLUME = 1e-2
"""Smallest accepted |det[t1 t2 n̂]| / (|t1| |t2|): keeps the frame's condition number below
~100 × |t|max / |t|min, so float32 solves lose at most two digits."""


def uv_scale(rest_vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, uv_faces: np.ndarray) -> float:
    """The garment's metres per UV unit, sqrt(Σ rest 3D area / Σ UV area).

    Args:
        rest_vertices: (V, 3) [m]; faces: (F, 3); uvs: (U, 2) in [0, 1]²; uv_faces: (F, 3).
    """
    x = np.asarray(rest_vertices, np.float64)
    f = check_faces(faces, len(x))
    q = np.asarray(uvs, np.float64)
    uf = check_faces(uv_faces, len(q), "uv_faces")
    p = x[f]
    a3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    t = q[uf]
    d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    a2 = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).sum()
    if a2 <= 0.0 or a3 <= 0.0:
        raise WrinklesInputError("uv_scale: the UV layout or the rest mesh has zero total area")
    return float(np.sqrt(a3 / a2))


def uv_vertex_map(faces: np.ndarray, uv_faces: np.ndarray, num_uvs: int) -> np.ndarray:
    """The 3D vertex of every UV vertex, shape (U,) int32; -1 for a UV vertex no face uses.

    Raises:
        WrinklesInputError: a UV vertex is a corner of two different 3D vertices.
    """
    f = np.asarray(faces, np.int64).ravel()
    uf = np.asarray(uv_faces, np.int64).ravel()
    if uf.size != f.size or uf.min() < 0 or uf.max() >= num_uvs:
        raise WrinklesInputError(f"uv_faces must be (F, 3) like faces, indices into {num_uvs} UV vertices")
    out = np.full(num_uvs, -1, np.int64)
    out[uf] = f
    bad = np.flatnonzero(out[uf] != f)
    if bad.size:
        raise WrinklesInputError(f"UV vertex {uf[bad[0]]} is a corner of 3D vertices {out[uf[bad[0]]]} "
                                 f"and {f[bad[0]]}: a UV vertex must map to one 3D vertex")
    return out.astype(np.int32)


class SurfaceFrames:
    """Local frames of one garment's UV layout: incidence lists and UV gradients built once, then
    any number of base/fine frames.

    Args:
        num_vertices: V, the number of 3D vertices.
        faces: (F, 3) int into the 3D vertices.
        uvs: (U, 2) texture coordinates (U >= V, split along seams).
        uv_faces: (F, 3) int into ``uvs``, corner for corner with ``faces``.
        scale: metres per UV unit (:func:`uv_scale` of the rest mesh).
        device: Warp device (None: cuda when present, else cpu).
    """

    def __init__(self, num_vertices: int, faces: np.ndarray, uvs: np.ndarray, uv_faces: np.ndarray,
                 scale: float, *, device: str | None = None):
        wp = warp()
        self.device = d = resolve_device(device)
        self.num_vertices = V = int(num_vertices)
        self.faces = check_faces(faces, V)
        q = np.asarray(uvs, np.float64)
        if q.ndim != 2 or q.shape[1] != 2:
            raise WrinklesInputError(f"uvs must have shape (U, 2), got {q.shape}")
        uf = check_faces(uv_faces, len(q), "uv_faces")
        if uf.shape != self.faces.shape:
            raise WrinklesInputError(f"uv_faces has shape {uf.shape}, faces {self.faces.shape}: "
                                     "they must match")
        if not np.isfinite(scale) or scale <= 0:
            raise WrinklesInputError(f"scale must be a positive number of metres per UV unit, got {scale}")
        self.num_uvs = U = len(q)
        self.scale = float(scale)
        self.uv_vertex = uv_vertex_map(self.faces, uf, U)
        F = len(uf)
        t = q[uf]
        Q = np.stack([t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]], axis=2)  # columns: UV edges
        det = Q[:, 0, 0] * Q[:, 1, 1] - Q[:, 0, 1] * Q[:, 1, 0]
        ok = np.abs(det) > 1e-14  # UV-degenerate faces carry no gradient (weight 0)
        grad_inv = np.zeros((F, 2, 2))
        grad_inv[ok] = np.linalg.inv(Q[ok]) / self.scale
        face_ids = np.repeat(np.arange(F), 3)
        uv_csr = incidence_csr(uf.ravel(), face_ids, U, np.repeat(np.where(ok, 0.5 * np.abs(det), 0.0), 3))
        v_off, v_faces, _ = incidence_csr(self.faces.ravel(), face_ids, V)  # for vertex normals
        used = np.flatnonzero(self.uv_vertex >= 0)
        self._copies = incidence_csr(self.uv_vertex[used], used, V)  # 3D vertex -> its UV copies, 1/n
        arr = [wp.array(self.faces, dtype=int, device=d),
               wp.array(self.uv_vertex, dtype=int, device=d),
               *(wp.array(a, dtype=dt, device=d) for a, dt in zip(uv_csr, (int, int, float), strict=True)),
               wp.array(grad_inv.astype(np.float32), dtype=wp.mat22, device=d),
               float(FRAME_MIN_TANGENT), float(FRAME_MIN_VOLUME)]
        self._frame_args = arr
        self._normal_args = [arr[0], wp.array(v_off, dtype=int, device=d),
                             wp.array(v_faces, dtype=int, device=d)]
        self._copies_d = [wp.array(a, dtype=dt, device=d) for a, dt in zip(self._copies, (int, int, float),
                                                                               strict=True)]

    @classmethod
    def from_garment(cls, garment, *, device: str | None = None) -> SurfaceFrames:
        """Frames of a ``Garment`` (its UV layout, scale from its rest mesh)."""
        s = uv_scale(garment.rest_vertices, garment.faces, garment.uvs, garment.uv_faces)
        return cls(garment.num_vertices, garment.faces, garment.uvs, garment.uv_faces, s, device=device)

    def _x(self, x: np.ndarray, what: str):
        a, single = as_frames(x, self.num_vertices, what)
        return warp().array(a, dtype=warp().vec3, device=self.device), single

    def normals(self, base: np.ndarray) -> np.ndarray:
        """Unit area-weighted 3D vertex normals of positions [m] (T, V, 3) or (V, 3); same shape
        (the frames' n̂ is this away from seams, see the module docstring)."""
        wp = warp()
        from sim.geometry import geometry_kernels as K

        x, single = self._x(base, "base")
        out = wp.empty(x.shape, dtype=wp.vec3, device=self.device)
        wp.launch(K.vertex_normals_kernel, dim=out.shape, inputs=[x, *self._normal_args], outputs=[out],
                  device=self.device)
        a = out.numpy()
        return a[0] if single else a

    def frames(self, base: np.ndarray) -> np.ndarray:
        """Local frame of every UV vertex: (T, U, 3, 3) (or (U, 3, 3)), columns t1, t2, n̂.

        Args:
            base: base-surface positions [m], shape (T, V, 3) or (V, 3).
        """
        wp = warp()
        from sim.geometry import geometry_kernels as K

        x, single = self._x(base, "base")
        out = wp.empty((x.shape[0], self.num_uvs), dtype=wp.mat33, device=self.device)
        wp.launch(K.uv_frames_kernel, dim=out.shape, inputs=[x, *self._frame_args], outputs=[out],
                  device=self.device)
        a = out.numpy()
        return a[0] if single else a

    def encode(self, fine: np.ndarray, base: np.ndarray) -> np.ndarray:
        """Wrinkle field w̃ [m] of ``fine`` over ``base``: (T, U, 3) (or (U, 3)).

        Args:
            fine: wrinkled positions [m], shape (T, V, 3) or (V, 3).
            base: base-surface positions [m], same shape.
        """
        wp = warp()
        from sim.geometry import geometry_kernels as K

        xf, single = self._x(fine, "fine")
        xb, single_b = self._x(base, "base")
        if xf.shape != xb.shape or single != single_b:
            raise WrinklesInputError(f"fine and base must have the same shape, got {np.shape(fine)} "
                                     f"and {np.shape(base)}")
        out = wp.empty((xf.shape[0], self.num_uvs), dtype=wp.vec3, device=self.device)
        wp.launch(K.encode_wrinkles_kernel, dim=out.shape, inputs=[xf, xb, *self._frame_args], outputs=[out],
                  device=self.device)
        a = out.numpy()
        return a[0] if single else a

    def decode(self, w: np.ndarray, base: np.ndarray) -> np.ndarray:
        """Positions base + Σ w̃_i t_i [m], (T, V, 3) (or (V, 3)); a 3D vertex takes the mean
        displacement of its UV copies (vertices without a UV copy stay at ``base``).

        Args:
            w: wrinkle field [m], shape (T, U, 3) or (U, 3).
            base: base-surface positions [m], shape (T, V, 3) or (V, 3).
        """
        wp = warp()
        from sim.geometry import geometry_kernels as K

        xb, single = self._x(base, "base")
        wa, single_w = as_frames(w, self.num_uvs, "w")
        T = xb.shape[0]
        if wa.shape[0] != T or single != single_w:
            raise WrinklesInputError(f"w {np.shape(w)} and base {np.shape(base)} must have the same frames")
        d = self.device
        wd = wp.array(wa, dtype=wp.vec3, device=d)
        disp = wp.empty((T, self.num_uvs), dtype=wp.vec3, device=d)
        wp.launch(K.decode_wrinkles_kernel, dim=disp.shape, inputs=[wd, xb, *self._frame_args],
                  outputs=[disp], device=d)
        out = wp.empty((T, self.num_vertices), dtype=wp.vec3, device=d)
        wp.launch(K.csr_mean_vec3_kernel, dim=out.shape, inputs=[disp, *self._copies_d], outputs=[out],
                  device=d)
        a = xb.numpy() + out.numpy()
        return a[0] if single else a


def unit_vectors(a: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) scaled to unit length (zero vectors stay zero)."""
    return a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)


def tangent_basis(frames: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """Orthonormal tangent bases, columns (t1', n x t1', n): n the unit normal (the frames' own n̂,
    or ``normals``), t1' the unit part of the frames' t1 orthogonal to it. The basis of
    tangent-space normal maps (the dataset's ``images/normal_tangent``).

    Args:
        frames: (..., U, 3, 3) from :meth:`SurfaceFrames.frames`, columns t1, t2, n̂.
        normals: optional (..., U, 3) normals to use instead of n̂ (a smoother surface's).

    Returns:
        (..., U, 3, 3) float32.
    """
    f = np.asarray(frames, np.float32)
    n = unit_vectors(f[..., 2] if normals is None else np.asarray(normals, np.float32))
    t1 = unit_vectors(f[..., 0] - np.sum(f[..., 0] * n, axis=-1, keepdims=True) * n)
    return np.stack([t1, np.cross(n, t1), n], axis=-1).astype(np.float32)


def to_tangent(basis: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """World vectors (..., 3) as components in ``basis`` (..., 3, 3) (orthonormal columns)."""
    return np.einsum("...ki,...k->...i", basis, vectors).astype(np.float32)


def from_tangent(basis: np.ndarray, components: np.ndarray) -> np.ndarray:
    """Components (..., 3) in ``basis`` (..., 3, 3) back to world vectors."""
    return np.einsum("...ik,...k->...i", basis, components).astype(np.float32)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, *, device: str | None = None) -> np.ndarray:
    """Unit area-weighted vertex normals (zero where the incident faces cancel out).

    Args:
        vertices: positions [m], shape (T, V, 3) or (V, 3).
        faces: (F, 3) int, counter-clockwise seen from the side the normals point to.
        device: Warp device.

    Returns:
        float32, the shape of ``vertices``.
    """
    wp = warp()
    from sim.geometry import geometry_kernels as K

    d = resolve_device(device)
    x, single = as_frames(vertices, None, "vertices")
    V = x.shape[1]
    f = check_faces(faces, V)
    off, vf, _ = incidence_csr(f.ravel(), np.repeat(np.arange(len(f)), 3), V)
    xd = wp.array(x, dtype=wp.vec3, device=d)
    out = wp.empty((x.shape[0], V), dtype=wp.vec3, device=d)
    wp.launch(K.vertex_normals_kernel, dim=out.shape,
              inputs=[xd, wp.array(f, dtype=int, device=d), wp.array(off, dtype=int, device=d),
                      wp.array(vf, dtype=int, device=d)], outputs=[out], device=d)
    a = out.numpy()
    return a[0] if single else a


def local_frames(base: np.ndarray, faces: np.ndarray, uvs: np.ndarray, uv_faces: np.ndarray, scale: float, *,
                 device: str | None = None) -> np.ndarray:
    """Local frames {t1, t2, n̂} of every UV vertex (module docstring), columns of (T, U, 3, 3).

    Args:
        base: base-surface positions [m], shape (T, V, 3) or (V, 3).
        faces: (F, 3); uvs: (U, 2); uv_faces: (F, 3); scale: metres per UV unit (:func:`uv_scale`).
        device: Warp device.
    """
    V = as_frames(base, None, "base")[0].shape[1]
    return SurfaceFrames(V, faces, uvs, uv_faces, scale, device=device).frames(base)


def encode_wrinkles(fine: np.ndarray, base: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
                    uv_faces: np.ndarray, scale: float, *, device: str | None = None) -> np.ndarray:
    """Wrinkle field w̃ [m] at every UV vertex, (T, U, 3) or (U, 3): fine − base in the local frame.

    Args:
        fine, base: positions [m], shape (T, V, 3) or (V, 3).
        faces: (F, 3); uvs: (U, 2); uv_faces: (F, 3); scale: metres per UV unit (:func:`uv_scale`).
        device: Warp device.
    """
    V = as_frames(base, None, "base")[0].shape[1]
    return SurfaceFrames(V, faces, uvs, uv_faces, scale, device=device).encode(fine, base)


def decode_wrinkles(w: np.ndarray, base: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
                    uv_faces: np.ndarray, scale: float, *, device: str | None = None) -> np.ndarray:
    """Wrinkled positions [m], (T, V, 3) or (V, 3), from a wrinkle field w̃ (T, U, 3) on ``base``.

    Args:
        w: wrinkle field [m], shape (T, U, 3) or (U, 3).
        base: base-surface positions [m], shape (T, V, 3) or (V, 3).
        faces: (F, 3); uvs: (U, 2); uv_faces: (F, 3); scale: metres per UV unit (:func:`uv_scale`).
        device: Warp device.
    """
    V = as_frames(base, None, "base")[0].shape[1]
    return SurfaceFrames(V, faces, uvs, uv_faces, scale, device=device).decode(w, base)
