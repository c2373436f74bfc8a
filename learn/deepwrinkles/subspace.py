"""DeepWrinkles' statistical garment model (Lähner et al. 2018, Sec. 3.2, Eq. 3).

Registered garment frames ``R_i`` are pose-normalised by inverse skinning, ``R̄_i = S^-1(R_i,
θ_i)`` (``unpose``), and the normalised frames are modelled as a mean shape plus a linear
subspace: ``R̄_i = M̄ + o_i``, the principal directions ``V_l`` of the offsets ``O = [o_1 ... o_n]``
from its singular value decomposition, so that ``B(λ, θ) = S(M̄ + Σ_l λ_l V_l, θ)`` (``repose`` of
``GarmentSubspace.decode``) with ``λ_l = V_lᵀ (R̄ - M̄)`` (``encode``). The paper keeps k = 500
components (under 5 mm error on its registrations); ``variance_kept`` reports the share of the
offsets' variance a smaller k keeps.

Skinning is the body's linear blend skinning with per-vertex weights (V, J) and bone transforms
(T, J, 3, 4) that take a rest-pose point to the posed world (``x = Σ_j w_j A_j [x̄; 1]``). Its
inverse at a vertex is that of the blended affine map, exact wherever the blend is invertible.

The principal directions come from the smaller of the two Gram matrices of the offsets, the
frames' (n x n) or the coordinates' (3V x 3V, accumulated over blocks of frames, so memory does
not grow with the frame count), in float64 with torch's symmetric eigensolver on ``device``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from sim.errors import WrinklesInputError

FRAME_BLOCK = 256
"""Frames skinned, unposed or accumulated at once (bounds the (block, V, 3, 4) blends in memory)."""
MAX_GRAM = 20_000
"""Largest side of the Gram matrix the fit forms (20k x 20k float64 is 3.2 GB)."""
RANK_TOLERANCE = 1e-12
"""Eigenvalues of the Gram matrix below this share of the largest (or of the frames' summed
squares) are round-off, not directions."""


def _blends(weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Per frame and vertex, the blended affine map Σ_j w_vj A_tj, float64 (T, V, 3, 4)."""
    return np.einsum("vj,tjab->tvab", weights.astype(np.float64), transforms.astype(np.float64),
                     optimize=True)


def _check_skinning(points: np.ndarray, weights: np.ndarray, transforms: np.ndarray, what: str) -> None:
    if points.ndim != 3 or points.shape[-1] != 3:
        raise WrinklesInputError(f"{what}: expected (T, V, 3) points, got shape {points.shape}")
    if weights.ndim != 2 or weights.shape[0] != points.shape[1]:
        raise WrinklesInputError(f"{what}: weights {weights.shape} do not match {points.shape[1]} vertices")
    if transforms.shape[1:] != (weights.shape[1], 3, 4) or transforms.shape[0] != points.shape[0]:
        raise WrinklesInputError(f"{what}: transforms {transforms.shape}, expected "
                                 f"({points.shape[0]}, {weights.shape[1]}, 3, 4)")


def repose(rest: np.ndarray, weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Linear blend skinning ``S`` (``learn.skinning.linear_blend_skinning``): pose-normalised
    points ``rest`` [m] (T, V, 3) (or (V, 3) for every frame) with weights (V, J) and bone
    transforms (T, J, 3, 4); float32 (T, V, 3)."""
    from learn.skinning import linear_blend_skinning

    x = np.asarray(rest, np.float32)
    t = np.asarray(transforms, np.float32)
    w = np.asarray(weights, np.float32)
    _check_skinning(np.broadcast_to(x, (t.shape[0], *x.shape)) if x.ndim == 2 else x, w, t, "repose")
    x, t, w = (torch.from_numpy(np.ascontiguousarray(a)) for a in (x, t, w))
    return linear_blend_skinning(x, t, w).numpy()


def unpose(posed: np.ndarray, weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Inverse skinning ``S^-1``: posed points [m] (T, V, 3) back to the pose-normalised space of
    the weights (V, J) and transforms (T, J, 3, 4), float32 (T, V, 3).

    Raises:
        WrinklesInputError: a vertex's blended map is singular (opposed bones cancel out).
    """
    x = np.asarray(posed, np.float64)
    w = np.asarray(weights)
    t = np.asarray(transforms)
    _check_skinning(x, w, t, "unpose")
    out = np.empty(x.shape, np.float32)
    for s in range(0, x.shape[0], FRAME_BLOCK):
        m = _blends(w, t[s:s + FRAME_BLOCK])
        rot = m[..., :3]
        det = np.linalg.det(rot)
        if np.any(np.abs(det) < 1e-8):
            f, v = np.argwhere(np.abs(det) < 1e-8)[0]
            raise WrinklesInputError(f"unpose: the blended skinning map of vertex {v} at frame {s + f} "
                                     "is singular")
        rhs = (x[s:s + FRAME_BLOCK] - m[..., 3])[..., None]
        out[s:s + FRAME_BLOCK] = np.linalg.solve(rot, rhs)[..., 0]
    return out


@dataclass(frozen=True)
class GarmentSubspace:
    """Mean shape and principal directions of pose-normalised garment frames (Eq. 3).

    Attributes:
        mean: M̄ [m], float32 (V, 3).
        components: V_l as rows, orthonormal, float32 (k, 3V), largest singular value first.
        singular_values: σ_l of the offsets [m], float64 (k,).
        total_variance: Σ σ² over every direction of the offsets [m²] (the kept ones and the rest).
        frames: n, the frames it was fitted on.
    """

    mean: np.ndarray
    components: np.ndarray
    singular_values: np.ndarray
    total_variance: float
    frames: int

    @property
    def size(self) -> int:
        """k, the number of components."""
        return int(self.components.shape[0])

    def variance_kept(self, k: int | None = None) -> float:
        """Share of the offsets' variance in the first ``k`` components (None: all kept)."""
        k = self.size if k is None else int(k)
        if not 0 <= k <= self.size:
            raise WrinklesInputError(f"variance_kept: k must be in 0..{self.size}, got {k}")
        if self.total_variance <= 0.0:
            return 1.0
        return float(np.sum(self.singular_values[:k] ** 2) / self.total_variance)

    def encode(self, rest: np.ndarray, k: int | None = None) -> np.ndarray:
        """λ = V_lᵀ (R̄ - M̄) of pose-normalised frames ``rest`` [m] (T, V, 3): float32 (T, k)."""
        x = np.asarray(rest, np.float64)
        if x.ndim != 3 or x.shape[1:] != self.mean.shape:
            raise WrinklesInputError(f"encode: expected (T, {self.mean.shape[0]}, 3), got {x.shape}")
        k = self.size if k is None else int(k)
        if not 1 <= k <= self.size:
            raise WrinklesInputError(f"encode: k must be in 1..{self.size}, got {k}")
        c = self.components[:k].astype(np.float64)
        return ((x - self.mean).reshape(len(x), -1) @ c.T).astype(np.float32)

    def decode(self, coefficients: np.ndarray) -> np.ndarray:
        """M̄ + Σ_l λ_l V_l of coefficients (T, k') (the first k' components), float32 (T, V, 3)."""
        lam = np.asarray(coefficients, np.float64)
        if lam.ndim != 2 or lam.shape[1] > self.size:
            raise WrinklesInputError(f"decode: expected (T, k <= {self.size}) coefficients, got {lam.shape}")
        off = lam @ self.components[: lam.shape[1]].astype(np.float64)
        return (self.mean + off.reshape(len(lam), *self.mean.shape)).astype(np.float32)

    def save(self, path: str | Path) -> None:
        """Write the subspace to ``path`` (.npz, no pickles)."""
        np.savez(path, mean=self.mean, components=self.components, singular_values=self.singular_values,
                 total_variance=np.float64(self.total_variance), frames=np.int64(self.frames))

    @classmethod
    def load(cls, path: str | Path) -> GarmentSubspace:
        """Read a subspace written by ``save``."""
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(z["mean"], z["components"], z["singular_values"], float(z["total_variance"]),
                           int(z["frames"]))
        except (OSError, KeyError, ValueError) as e:
            raise WrinklesInputError(f"not a garment subspace file: {e}", path=path) from None


def fit_subspace(rest: np.ndarray, k: int = 500, *, device: str = "cpu") -> GarmentSubspace:
    """The mean and the first ``k`` principal directions of pose-normalised frames ``rest`` [m]
    (n, V, 3) (``unpose`` of registered frames); k is clipped to the offsets' rank bound
    min(n - 1, 3V) (n frames less their mean span at most n - 1 directions) and to the directions
    the offsets really span. Each component is signed so that its largest entry is positive.

    Raises:
        WrinklesInputError: fewer than 2 frames, k < 1, both Gram sides over ``MAX_GRAM``, or
            frames all of one shape.
    """
    x = np.asarray(rest)
    if x.ndim != 3 or x.shape[-1] != 3 or len(x) < 2:
        raise WrinklesInputError(f"fit_subspace: expected (n >= 2, V, 3) frames, got shape {x.shape}")
    if k < 1:
        raise WrinklesInputError(f"fit_subspace: k must be >= 1, got {k}")
    n, dim = len(x), 3 * x.shape[1]
    if min(n, dim) > MAX_GRAM:
        raise WrinklesInputError(f"fit_subspace: {n} frames of {dim} coordinates; one of them must be "
                                 f"<= {MAX_GRAM} (fewer frames, or a coarser template)")
    dev = torch.device(device)
    mean = x.mean(axis=0, dtype=np.float64)
    k = min(int(k), n - 1, dim)
    o = None
    if n <= dim:
        o = torch.as_tensor((x.reshape(n, dim) - mean.reshape(1, dim)), dtype=torch.float64, device=dev)
        gram = o @ o.T
    else:
        gram = torch.zeros(dim, dim, dtype=torch.float64, device=dev)
        for s in range(0, n, FRAME_BLOCK):
            block = torch.as_tensor(x[s:s + FRAME_BLOCK].reshape(-1, dim) - mean.reshape(1, dim),
                                    dtype=torch.float64, device=dev)
            gram += block.T @ block
    evals, evecs = torch.linalg.eigh(gram)  # ascending
    evals, evecs = evals.flip(0).clamp_min(0), evecs.flip(1)
    total = float(evals.sum())
    # directions the offsets really span: repeated or static frames span fewer than n - 1
    scale = float(np.sum(np.square(x, dtype=np.float64)))  # the frames' own size: round-off is relative
    k = min(k, int((evals > RANK_TOLERANCE * max(float(evals[0]), scale, 1e-300)).sum()))
    if k == 0:
        raise WrinklesInputError("fit_subspace: the frames are all the same shape (no offsets to model)")
    sigma = evals[:k].sqrt()
    # the frames' side: right singular vectors from the left ones; the coordinates' side: direct
    comps = ((o.T @ evecs[:, :k]) / sigma).T if o is not None else evecs[:, :k].T
    comps = comps.cpu().numpy()
    sign = np.sign(comps[np.arange(k), np.argmax(np.abs(comps), axis=1)])
    comps *= np.where(sign == 0, 1.0, sign)[:, None]
    return GarmentSubspace(mean=mean.astype(np.float32), components=comps.astype(np.float32),
                           singular_values=sigma.cpu().numpy(), total_variance=total, frames=n)
