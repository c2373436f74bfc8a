"""Base surface by smoothing out the wrinkles (Guo et al. 2024, Sec. 3.1 and 4: "curved Hessian
smoothing", Stein et al. 2020).

The base surface of a frame minimises, per coordinate,

    ‖M^{1/2} (x − x_fine)‖² + t · xᵀ B x,    i.e.  (M + t B) x = M x_fine,

with M the lumped (barycentric) mass matrix and B a Hessian energy, both built ONCE on the rest
mesh: one sparse LU factorisation serves every frame of a garment, and T frames are solved as
3T right-hand sides.

The energy (a documented equivalent of libigl's ``curved_hessian_energy``, which is not
available here): the Hessian energy ∫ ‖∇∇u‖² dA of Stein, Grinspun, Wardetzky, Jacobson 2018
("Natural Boundary Conditions for Smoothing in Geometry Processing", Sec. 4), in its mixed
finite-element form with lumped mass, evaluated with the surface gradient in ambient 3D
coordinates: per face, g = ∇_S u (piecewise constant, ``G``), then every component pair
(i, j) ∈ {x, y, z}² of the weak Hessian, M h_ij = ∮ φ ν_i g_j ds − ∫ ∂_i φ g_j dA, *keeping the
boundary integral* (ν the outward conormal of each boundary edge). Then B = Σ_ij h_ijᵀ M h_ij.

Why this energy and not the cotangent bi-Laplacian K M⁻¹ K:

- Boundaries. Garments are open (hems, necklines, cuffs). With the boundary term, the weak
  Hessian of an affine function vanishes exactly (discrete divergence theorem), so on a flat
  sheet affine fields, and so rigid and affine motions, are reproduced to round-off, boundary
  vertices included: this is the "natural boundary condition" of Stein et al. K M⁻¹ K
  (implicit zero-Neumann) penalises affine functions at boundary vertices and pulls hems
  inward: on the coarse t-shirt at length 0.05 m its hem moves 2.7 mm on average, this
  energy's 0.09 mm. Dropping the boundary rows of K instead leaves every harmonic function in
  the kernel, wrinkles decaying from a hem included.
- Curved surfaces. On a flat region this is Stein et al. 2018 exactly. On a curved one the
  ambient-coordinate Hessian ∇_S(∇_S u) is the covariant (curved) Hessian of Stein et al. 2020
  plus the normal part −II ∇_S u (II the second fundamental form), a curvature-weighted
  gradient penalty. Neither energy vanishes on the coordinate functions of a curved surface, so
  either one moves a curved rest shape slightly; by (length / 2π)⁴ κ⁴ that is tiny for cloth:
  the coarse t-shirt at rest moves 0.2 mm on average (at most 2.9 mm, at the armhole seam crease)
  at length 0.05 m.
- Near a boundary the Hessian energy does not penalise a linear ramp, so a wrinkle running into
  a hem head-on keeps up to ~40 % of its amplitude in its last half wavelength (measured on a
  sheet); a K M⁻¹ K smoother distorts the boundary more than that.

The length. On a flat sheet the energy's Euler-Lagrange operator is Δ², so a sinusoid of
wavelength λ is scaled by 1 / (1 + t (2π/λ)⁴). With t = (length / 2π)⁴ the filter is
1 / (1 + (length/λ)⁴): half amplitude at λ = length, 94 % removed at λ = length / 2, 99.6 % kept
at λ = 4 length.

Smoothing is linear, per coordinate, and reproduces constants, so it commutes with rigid
motions: smooth(R x + b) = R smooth(x) + b.
"""

from __future__ import annotations

import numpy as np

from sim.errors import WrinklesInputError
from sim.geometry.strain import MIN_REST_AREA, as_frames, check_faces

SMOOTHING_LENGTH = 0.05
"""Default smoothing length [m]: folds and wrinkles well below 5 cm are removed (Guo et al.'s
T-shirt wrinkles are 1-5 cm apart), body-scale shape (arm, torso radius 5-15 cm) stays."""
SOLVE_BLOCK = 32
"""Frames per block of right-hand sides (3 per frame): bounds the float64 work arrays to
~1 MB per 1000 vertices."""


def smoothing_stiffness(length: float) -> float:
    """The weight t [m⁴] of the Hessian energy for a smoothing length [m]: (length / 2π)⁴."""
    length = float(length)
    if not np.isfinite(length) or length <= 0.0:
        raise WrinklesInputError(f"smoothing length must be a positive number of metres, got {length}")
    return (length / (2.0 * np.pi)) ** 4


def hessian_energy(rest_vertices: np.ndarray, faces: np.ndarray):
    """Lumped mass and the Hessian energy matrix of a triangle mesh (module docstring).

    Args:
        rest_vertices: (V, 3) [m]; faces: (F, 3) int.

    Returns:
        mass: (V,) float64 [m²], a third of the area of every incident face (0 for a vertex no
        face uses); B: scipy CSR (V, V) float64 [1/m²], symmetric positive semi-definite, with
        B 1 = 0 and, on a flat mesh, B a = 0 for every affine function a of the positions.

    Raises:
        WrinklesInputError: a triangle with area below ``MIN_REST_AREA``.
    """
    import scipy.sparse as sp

    x = np.asarray(rest_vertices, np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise WrinklesInputError(f"rest_vertices must have shape (V, 3), got {x.shape}")
    f = check_faces(faces, len(x)).astype(np.int64)
    V, F = len(x), len(f)
    p = x[f]
    cr = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    dbl = np.linalg.norm(cr, axis=1)
    bad = np.flatnonzero(dbl < 2.0 * MIN_REST_AREA)
    if bad.size:
        raise WrinklesInputError(f"{bad.size} rest triangle(s) have (near-)zero area (first: face {bad[0]})")
    n = cr / dbl[:, None]
    area = 0.5 * dbl
    # ∇φ_k = n × (x_{k+2} − x_{k+1}) / (2A): gradient of corner k's hat function, (F, 3 corners, 3)
    grad = np.stack([np.cross(n, p[:, (k + 2) % 3] - p[:, (k + 1) % 3]) / dbl[:, None] for k in range(3)], 1)
    rows = np.repeat(np.arange(F), 3)
    G = [sp.csr_matrix((grad[:, :, c].ravel(), (rows, f.ravel())), shape=(F, V)) for c in range(3)]
    # boundary edges: half-edges whose undirected edge appears once
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    he_face = np.tile(np.arange(F), 3)
    opposite = np.concatenate([f[:, 2], f[:, 0], f[:, 1]])
    key = np.sort(he, axis=1)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    bd = count[inv.ravel()] == 1
    a, b, fb, o = he[bd, 0], he[bd, 1], he_face[bd], opposite[bd]
    nu = np.cross(x[b] - x[a], n[fb])  # |ν| = edge length, in the face plane, ⟂ edge
    nu *= np.where(((x[a] - x[o]) * nu).sum(1) < 0, -1.0, 1.0)[:, None]  # outward
    mass = np.bincount(f.ravel(), np.repeat(area / 3.0, 3), V)
    inv_mass = np.divide(1.0, mass, out=np.zeros(V), where=mass > 0)
    Af = sp.diags(area)
    H = []
    for i in range(3):
        # ∮ φ_v ν_i g ds over each boundary edge: ℓ ν_i / 2 to each end (φ linear on the edge)
        N = sp.csr_matrix((np.concatenate([nu[:, i], nu[:, i]]) / 2.0,
                           (np.concatenate([a, b]), np.concatenate([fb, fb]))), shape=(V, F))
        W = (N - G[i].T @ Af).tocsr()  # (V, F): weak ∂_i of a piecewise-constant field, times M
        H += [W @ G[j] for j in range(3)]
    H = sp.vstack(H).tocsr()  # (9V, V): M h_ij for the 9 pairs
    B = (H.T @ sp.diags(np.tile(inv_mass, 9)) @ H).tocsr()
    return mass, B


DENSE_MEMORY_SHARE = 0.25
"""A CUDA device factorises the system densely (``BaseSmoother``) when twice its float64 matrix
fits in this share of the device's total memory (17.8k vertices: 2 x 2.5 GB). The total, not
what is free now: the choice, and so the last bits of a base surface, depend on the device kind
only, as a dataset's bytes must."""


class BaseSmoother:
    """Smooth wrinkled frames of one garment into its base surface (module docstring).

    The system (M + t B) is built and factorised once from the rest mesh: on the host by scipy's
    SuperLU (minimum-degree ordering of AᵀA + A, which suits a symmetric matrix), or on a CUDA
    device as a dense float64 Cholesky factor (torch), solving a whole block of frames in two
    dense triangular solves there: the sparse solves on the host took ~2.4 s for 120 frames of
    a 17.8k-vertex garment (H200 host, ``bench_dataset``), longer than simulating them in a
    batch. Both are direct float64 solves (equal to round-off: ``tests/test_smoothing.py``).

    Args:
        rest_vertices: rest positions [m], shape (V, 3).
        faces: (F, 3) int.
        length: smoothing length [m]: wavelengths well below it are removed, well above it kept
            (filter 1 / (1 + (length / λ)⁴) on a flat sheet).
        device: where to solve: a CUDA device with its ordinal ("cuda:0", as Warp and torch both
            name it) factorises densely there when it fits (``DENSE_MEMORY_SHARE``), anything
            else on the host.
        dense: True: the dense factor on ``device`` (a torch device, "cpu" included); False: the
            sparse one on the host; None: as ``device`` says.
    """

    def __init__(self, rest_vertices: np.ndarray, faces: np.ndarray, *, length: float = SMOOTHING_LENGTH,
                 device: str | None = None, dense: bool | None = None):
        import scipy.sparse as sp

        self.length = float(length)
        self.stiffness = smoothing_stiffness(length)
        mass, B = hessian_energy(rest_vertices, faces)
        self.num_vertices = len(mass)
        # a vertex no face uses has no mass and no energy: give it its own position back
        self.mass = np.where(mass > 0, mass, max(float(mass.mean()), 1e-12))
        A = (sp.diags(self.mass) + self.stiffness * B).tocsc()
        self._lu = self._factor = None
        if dense is None:
            dense = _dense_fits(self.num_vertices, device)
        if dense:
            import torch

            self._torch_device = torch.device(str(device or "cpu"))
            coo = A.tocoo()  # made dense on the device: no V x V array on the host
            dev = self._torch_device
            full = torch.zeros(A.shape, dtype=torch.float64, device=dev)
            full.index_put_((torch.as_tensor(coo.row.astype(np.int64), device=dev),
                             torch.as_tensor(coo.col.astype(np.int64), device=dev)),
                            torch.as_tensor(coo.data, dtype=torch.float64, device=dev), accumulate=True)
            self._factor = torch.linalg.cholesky(full)
            del full
            if self._torch_device.type == "cuda":  # the matrix's block back to the device, not torch's cache
                torch.cuda.empty_cache()
        else:
            from scipy.sparse.linalg import splu

            self._lu = splu(A, permc_spec="MMD_AT_PLUS_A")

    @property
    def dense(self) -> bool:
        """Whether the system is solved with the dense factor (``device``)."""
        return self._factor is not None

    @property
    def device_bytes(self) -> int:
        """Device memory the dense factor holds (0 on the host)."""
        return 0 if self._factor is None else int(self._factor.numel() * self._factor.element_size())

    def _solve(self, rhs: np.ndarray) -> np.ndarray:
        """A⁻¹ rhs for float64 (V, k) right-hand sides."""
        if self._factor is None:
            return self._lu.solve(np.asfortranarray(rhs))
        import torch

        b = torch.as_tensor(rhs, device=self._torch_device)
        return torch.cholesky_solve(b, self._factor).cpu().numpy()

    def smooth(self, vertices: np.ndarray) -> np.ndarray:
        """Base surface of every frame.

        Args:
            vertices: wrinkled positions [m], shape (T, V, 3) or (V, 3).

        Returns:
            float32, the shape of ``vertices``.
        """
        x, single = as_frames(vertices, self.num_vertices, "vertices")
        T, V = x.shape[:2]
        out = np.empty_like(x)
        m = self.mass[:, None]
        block = SOLVE_BLOCK if self._factor is None else DENSE_SOLVE_BLOCK
        for s in range(0, T, block):
            blk = x[s:s + block].astype(np.float64)  # (k, V, 3)
            # remove each frame's centre first (reproduced exactly): round-off relative to the shape
            c = np.einsum("v,kvc->kc", self.mass, blk) / self.mass.sum()
            rhs = (blk - c[:, None]).transpose(1, 0, 2).reshape(V, -1) * m
            sol = self._solve(rhs)
            out[s:s + block] = sol.reshape(V, -1, 3).transpose(1, 0, 2) + c[:, None]
        return out[0] if single else out


DENSE_SOLVE_BLOCK = 256
"""Frames per block of right-hand sides with the dense factor (~37 MB of float64 per 1000
vertices on the device)."""


def _dense_fits(vertices: int, device: str | None) -> bool:
    """Whether ``BaseSmoother`` factorises densely on ``device``: a CUDA device with torch and
    twice the float64 matrix within its ``dense_budget``."""
    return 2 * 8 * vertices**2 <= dense_budget(device)


def dense_budget(device: str | None) -> int:
    """Bytes of ``device``'s memory dense factors may take: ``DENSE_MEMORY_SHARE`` of a CUDA
    device's total (0 elsewhere, or without a torch that reaches it). A holder of several
    smoothers (``sim.datasets.generate``) keeps their ``device_bytes`` within it."""
    if device is None or not str(device).startswith("cuda"):
        return 0
    try:
        import torch

        if not torch.cuda.is_available():
            return 0
        total = torch.cuda.get_device_properties(torch.device(str(device))).total_memory
        return int(DENSE_MEMORY_SHARE * total)
    except Exception:  # no torch, or one that cannot reach the device: the host solves
        return 0


def smooth_base(vertices: np.ndarray, rest_vertices: np.ndarray, faces: np.ndarray, *,
                length: float = SMOOTHING_LENGTH, device: str | None = None) -> np.ndarray:
    """Base surface of wrinkled frames: :class:`BaseSmoother` built and applied once.

    Args:
        vertices: wrinkled positions [m], shape (T, V, 3) or (V, 3).
        rest_vertices: rest positions [m], shape (V, 3).
        faces: (F, 3) int.
        length: smoothing length [m].
        device: a CUDA device solves there when the dense factor fits (``BaseSmoother``), else
            the host (scipy).

    Returns:
        float32, the shape of ``vertices``.
    """
    return BaseSmoother(rest_vertices, faces, length=length, device=device).smooth(vertices)
