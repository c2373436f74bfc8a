"""Fréchet distance between feature distributions (the "F" of FID; Guo et al. 2024, Sec 4.1).

Two sets of feature vectors are summarised by Gaussians ``N(μ_a, Σ_a)`` and ``N(μ_b, Σ_b)``
(sample mean, unbiased sample covariance), whose squared 2-Wasserstein (Fréchet) distance is

    FD = |μ_a − μ_b|² + tr(Σ_a + Σ_b − 2 (Σ_a Σ_b)^{1/2})          (Dowson & Landau 1982)

computed here in float64 with the symmetric form ``tr (Σ_a Σ_b)^{1/2} = tr (Σ_a^{1/2} Σ_b
Σ_a^{1/2})^{1/2}`` (both matrices positive semi-definite, so every square root is of a symmetric
PSD matrix, taken by ``eigh`` with negative round-off eigenvalues clipped to 0): no complex parts
and no failure on singular covariances (fewer samples than dimensions), unlike ``sqrtm`` of the
non-symmetric product.

:func:`normal_map_fd` is the project's wrinkle-realism score: FD of
:class:`learn.metrics.features.NormalMapFeatures` of UV normal maps. It is NOT Inception FID
(numbers are not comparable with papers'); tables must say "FD (NormalMapFeatures
``VERSION``)". Like FID it is biased upward at small set sizes: compare values computed from
sets of equal size.
"""

from __future__ import annotations

import numpy as np
import torch

from learn.metrics.features import NormalMapFeatures
from sim.errors import WrinklesInputError


def _np64(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu()
    return np.asarray(x, dtype=np.float64)


def feature_statistics(feats) -> tuple[np.ndarray, np.ndarray]:
    """Mean and unbiased covariance of feature vectors.

    Args:
        feats: features, shape (N, D), N >= 2.

    Returns:
        (mean (D,), covariance (D, D)), float64 numpy.
    """
    f = _np64(feats)
    if f.ndim != 2 or f.shape[0] < 2:
        raise WrinklesInputError(f"features must have shape (N >= 2, D), got {f.shape}")
    return f.mean(axis=0), np.atleast_2d(np.cov(f, rowvar=False))


def _sym_sqrt(s: np.ndarray) -> np.ndarray:
    lam, v = np.linalg.eigh(0.5 * (s + s.T))
    return (v * np.sqrt(np.clip(lam, 0.0, None))) @ v.T


def frechet_distance_from_stats(mu_a, cov_a, mu_b, cov_b) -> float:
    """Fréchet distance between ``N(mu_a, cov_a)`` and ``N(mu_b, cov_b)`` (module docstring).

    Args:
        mu_a, mu_b: means, shape (D,).
        cov_a, cov_b: covariances (symmetric positive semi-definite), shape (D, D).

    Returns:
        The distance (squared units of the features), >= 0.
    """
    mu_a, mu_b, cov_a, cov_b = map(_np64, (mu_a, mu_b, cov_a, cov_b))
    D = mu_a.shape[0]
    if mu_b.shape != (D,) or cov_a.shape != (D, D) or cov_b.shape != (D, D):
        raise WrinklesInputError(f"Gaussian statistics do not match: means {mu_a.shape}, {mu_b.shape}, "
                                 f"covariances {cov_a.shape}, {cov_b.shape}")
    ra = _sym_sqrt(cov_a)
    m = ra @ cov_b @ ra
    tr_sqrt = np.sqrt(np.clip(np.linalg.eigvalsh(0.5 * (m + m.T)), 0.0, None)).sum()
    d = float(((mu_a - mu_b) ** 2).sum() + np.trace(cov_a) + np.trace(cov_b) - 2.0 * tr_sqrt)
    return max(d, 0.0)


def frechet_distance(feats_a, feats_b) -> float:
    """Fréchet distance between Gaussians fitted to two feature sets.

    Args:
        feats_a: features, shape (N, D), N >= 2.
        feats_b: features, shape (M, D), M >= 2.

    Returns:
        The distance (squared feature units), >= 0.
    """
    mu_a, cov_a = feature_statistics(feats_a)
    mu_b, cov_b = feature_statistics(feats_b)
    if mu_a.shape != mu_b.shape:
        raise WrinklesInputError(f"feature sets have dimensions {mu_a.shape[0]} and {mu_b.shape[0]}")
    return frechet_distance_from_stats(mu_a, cov_a, mu_b, cov_b)


def normal_map_fd(pred_maps, target_maps, mask=None, *, extractor: NormalMapFeatures | None = None) -> float:
    """Fréchet distance of :class:`NormalMapFeatures` between two sets of UV normal maps.

    Args:
        pred_maps: predicted normal maps, shape (N, H, W, 3), components in [-1, 1].
        target_maps: ground-truth normal maps, shape (M, H', W', 3).
        mask: coverage (H, W) shared by both sets (or (N, H, W) when N = M and the sizes
            agree); None: every pixel.
        extractor: the feature extractor (None: ``NormalMapFeatures()``).

    Returns:
        The distance (not comparable with Inception FID; see the module docstring).
    """
    ext = NormalMapFeatures() if extractor is None else extractor
    return frechet_distance(ext(pred_maps, mask), ext(target_maps, mask))
