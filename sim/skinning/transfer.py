"""Skinning-weight transfer from a body to a garment (numpy; no torch).

A garment vertex takes the inverse-distance blend of the skinning weights of its k nearest
body vertices in the rest pose (Shepard interpolation), renormalised to sum to one. This is the
usual initialisation for skinning a garment with the body's bones (e.g. the skinned base of
DeepWrinkles Sec 3.1 and GSNet's garment-to-joint weights before learning).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from sim.errors import WrinklesInputError

_EXACT = 1e-9
"""Distance [m] under which a garment vertex counts as lying on a body vertex (copies its weights)."""


def transfer_skinning_weights(garment_rest: np.ndarray, body_rest: np.ndarray, body_weights: np.ndarray, *,
                              k: int = 4, power: float = 2.0) -> np.ndarray:
    """Skinning weights for garment vertices from the k nearest body vertices.

    ``w_g = sum_i d_i^-power w_i / sum_i d_i^-power`` over the k nearest body vertices ``i``
    (distance ``d_i`` in the rest pose), then each row is renormalised to sum to one. A garment
    vertex closer than 1e-9 m to body vertices copies (the mean of) their weights exactly.

    Args:
        garment_rest: garment rest vertices [m], shape (Vg, 3).
        body_rest: body rest vertices [m], shape (Vb, 3).
        body_weights: body skinning weights, shape (Vb, J), non-negative, rows not all zero.
        k: body neighbours per garment vertex (clipped to Vb).
        power: inverse-distance exponent (2: Shepard's usual choice; larger is closer to
            nearest-neighbour copying).

    Returns:
        Garment skinning weights, float32 (Vg, J), non-negative, rows summing to 1.

    Raises:
        WrinklesInputError: bad shapes, non-finite values, negative or all-zero weight rows.
    """
    g = np.asarray(garment_rest, dtype=np.float64)
    b = np.asarray(body_rest, dtype=np.float64)
    w = np.asarray(body_weights, dtype=np.float64)
    if g.ndim != 2 or g.shape[1] != 3 or b.ndim != 2 or b.shape[1] != 3 or b.shape[0] == 0:
        raise WrinklesInputError(f"garment_rest {g.shape} and body_rest {b.shape}: "
                                 "expected (Vg, 3) and (Vb, 3)")
    if w.ndim != 2 or w.shape[0] != b.shape[0] or w.shape[1] == 0:
        raise WrinklesInputError(f"body_weights: shape {w.shape}, expected ({b.shape[0]}, J)")
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(b)) and np.all(np.isfinite(w))):
        raise WrinklesInputError("transfer_skinning_weights: inputs hold NaN or inf")
    if np.any(w < 0.0) or np.any(w.sum(axis=1) <= 0.0):
        raise WrinklesInputError("body_weights: negative entries or a row that sums to zero")
    if k < 1 or power <= 0.0:
        raise WrinklesInputError(f"k={k}, power={power}: expected k >= 1 and power > 0")
    kk = min(int(k), b.shape[0])
    dist, nbr = cKDTree(b).query(g, k=kk)
    dist, nbr = dist.reshape(len(g), kk), nbr.reshape(len(g), kk)
    exact = dist < _EXACT
    on_body = exact.any(axis=1)
    inv = np.where(on_body[:, None], exact.astype(np.float64), 1.0 / np.maximum(dist, _EXACT) ** power)
    blend = np.einsum("gk,gkj->gj", inv / inv.sum(axis=1, keepdims=True), w[nbr])
    blend /= blend.sum(axis=1, keepdims=True)
    return blend.astype(np.float32)
