"""Temporal smoothness metrics: how much a sequence flickers from frame to frame.

- :func:`flicker`: mean over interior frames and vertices of the norm of the second difference
  ``|x_{t+1} - 2 x_t + x_{t-1}|`` [m], i.e. acceleration x dt². Zero for motion at constant
  velocity; ``|a| dt²`` for constant acceleration ``a``. Learned models that predict each frame
  on its own jitter, which raises it (the temporal consistency DeepWrinkles Sec 4 trains for
  with its temporal loss, and GSNet Sec 4.2 discusses qualitatively).
- :func:`flicker_ratio`: ``flicker(pred) / flicker(target)``; 1 means as smooth as the ground
  truth, > 1 jittery, < 1 over-smoothed.
- :func:`image_flicker`: for UV maps, mean over frame pairs and (masked) pixels of the L2 norm
  over channels of ``m_{t+1} - m_t`` (in the map's unit).

Inputs are torch tensors (cpu or cuda) or numpy arrays; results are float64 tensors.
"""

from __future__ import annotations

import torch

from learn.metrics.geometry import as_tensor
from sim.errors import WrinklesInputError


def flicker(vertices) -> torch.Tensor:
    """Mean norm of the second time difference of positions.

    Args:
        vertices: positions [m], shape (..., T, V, 3), T >= 3.

    Returns:
        Mean ``|x_{t+1} - 2 x_t + x_{t-1}|`` over t = 1..T-2 and vertices [m], float64, shape (...).
    """
    x = as_tensor(vertices)
    if x.ndim < 3 or x.shape[-1] != 3:
        raise WrinklesInputError(f"vertices must have shape (..., T, V, 3), got {tuple(x.shape)}")
    if x.shape[-3] < 3:
        raise WrinklesInputError(f"flicker needs at least 3 frames, got {x.shape[-3]}")
    d2 = x[..., 2:, :, :] - 2.0 * x[..., 1:-1, :, :] + x[..., :-2, :, :]
    return torch.linalg.vector_norm(d2, dim=-1).mean(dim=(-2, -1))


def flicker_ratio(pred, target) -> torch.Tensor:
    """``flicker(pred) / flicker(target)`` (1: as smooth as the ground truth).

    Args:
        pred: predicted positions [m], shape (..., T, V, 3).
        target: ground-truth positions [m], shape (..., T, V, 3).

    Returns:
        Ratio [-], float64, shape (...); inf where the target does not move (flicker 0) and
        the prediction does, nan where neither does.
    """
    a = flicker(pred)
    return a / flicker(target).to(a.device)


def image_flicker(maps, mask=None) -> torch.Tensor:
    """Mean frame-to-frame change of UV maps.

    Args:
        maps: images, shape (..., T, H, W, C), T >= 2 (any unit; normals [-], displacement [m]).
        mask: pixels to average over, bool, shape (H, W) or per frame (..., T, H, W) (a pixel
            pair counts where both frames have it); None: every pixel.

    Returns:
        Mean over t = 0..T-2 and pixels of ``|m_{t+1} - m_t|`` (L2 over channels), float64,
        shape (...).
    """
    m = as_tensor(maps)
    if m.ndim < 4:
        raise WrinklesInputError(f"maps must have shape (..., T, H, W, C), got {tuple(m.shape)}")
    if m.shape[-4] < 2:
        raise WrinklesInputError(f"image_flicker needs at least 2 frames, got {m.shape[-4]}")
    d = torch.linalg.vector_norm(m[..., 1:, :, :, :] - m[..., :-1, :, :, :], dim=-1)  # (..., T-1, H, W)
    if mask is None:
        return d.mean(dim=(-3, -2, -1))
    w = as_tensor(mask, device=d.device)
    if w.shape[-2:] != d.shape[-2:]:
        raise WrinklesInputError(f"mask shape {tuple(w.shape)} does not match maps {tuple(m.shape)}")
    w = (w > 0).to(d.dtype)
    if w.ndim >= 3:
        if w.shape[-3] != m.shape[-4]:
            raise WrinklesInputError(f"mask has {w.shape[-3]} frames, maps {m.shape[-4]}")
        w = w[..., 1:, :, :] * w[..., :-1, :, :]
    w = w.expand_as(d)
    n = w.sum(dim=(-3, -2, -1))
    if (n == 0).any():
        raise WrinklesInputError("mask selects no pixel")
    return (d * w).sum(dim=(-3, -2, -1)) / n
