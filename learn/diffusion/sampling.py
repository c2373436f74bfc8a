"""DDIM sampling loop for the wrinkle diffusion model (Guo et al. 2024 Sec. 4.1: S = 50, eta = 0).

A few lines that call the network and the scheduler (STYLE.md 4, diffusers'
``pipeline_ddim.py``), with classifier-free guidance on a material label (Guo et al. Sec. 4.4;
Ho & Salimans 2022): ``eps = eps_uncond + s (eps_cond - eps_uncond)``.
"""

from __future__ import annotations

from functools import partial
from typing import Protocol

import torch

from learn.diffusion.scheduler import DDIMScheduler


class EpsilonModel(Protocol):
    """What the loop needs from a network (``WrinkleUNet`` satisfies it)."""

    out_channels: int
    null_label: int

    def __call__(
        self, x_t: torch.Tensor, t: torch.Tensor, cond: torch.Tensor | None, label: torch.Tensor | None = None
    ) -> torch.Tensor: ...


def guided_epsilon(
    model: EpsilonModel,
    x_t: torch.Tensor,
    t: torch.Tensor,
    cond: torch.Tensor | None,
    *,
    label: torch.Tensor | None = None,
    guidance_scale: float = 1.0,
) -> torch.Tensor:
    """Noise prediction with classifier-free guidance (Ho & Salimans 2022, Eq. 6).

    With a label and ``guidance_scale != 1`` the conditional and unconditional passes run as one
    forward of batch 2B (label, then the null label ``model.null_label``); otherwise one plain
    forward of batch B (``s = 1`` is exactly the conditional prediction).

    Args:
        model: an :class:`EpsilonModel`.
        x_t: noisy samples, shape (B, C, H, W).
        t: timesteps, int64, shape (B,).
        cond: conditioning maps, shape (B, C_cond, H, W), or None.
        label: labels, int64, shape (B,), or None (no guidance).
        guidance_scale: ``s``; 1 = conditional only, 0 = unconditional only.

    Returns:
        eps, shape (B, out_channels, H, W).
    """
    if label is None or guidance_scale == 1.0:
        return model(x_t, t, cond, label)
    B = x_t.shape[0]
    null = torch.full_like(label, model.null_label)
    eps = model(
        torch.cat([x_t, x_t]),
        torch.cat([t, t]),
        None if cond is None else torch.cat([cond, cond]),
        torch.cat([label, null]),
    )
    eps_cond, eps_uncond = eps[:B], eps[B:]
    return eps_uncond + guidance_scale * (eps_cond - eps_uncond)


@torch.no_grad()
def ddim_sample(
    model: EpsilonModel,
    scheduler: DDIMScheduler,
    cond: torch.Tensor,
    *,
    label: torch.Tensor | None = None,
    guidance_scale: float = 1.0,
    num_steps: int = 50,
    eta: float = 0.0,
    generator: torch.Generator | None = None,
    initial_noise: torch.Tensor | None = None,
    mask: torch.Tensor | None = None,
    temporal_weight: float = 0.0,
    anchor: torch.Tensor | None = None,
    clip_x0: torch.Tensor | float | None = None,
) -> torch.Tensor:
    """Generate wrinkle UV images by DDIM (Song et al. 2021, Eq. 12) from ``x_T ~ N(0, I)``.

    Runs under ``torch.no_grad``; put the model in ``eval()`` mode first. Calls
    ``scheduler.set_timesteps(num_steps)``.

    Args:
        model: the noise predictor (e.g. :class:`learn.diffusion.unet.WrinkleUNet`).
        scheduler: a :class:`DDIMScheduler` with the training betas.
        cond: conditioning maps, shape (B, C_cond, H, W); its batch, size, device and dtype set the
            output's.
        label: material labels, int64, shape (B,), or None.
        guidance_scale: classifier-free guidance scale ``s`` (needs ``label``).
        num_steps: ``S``, DDIM steps.
        eta: 0 = deterministic DDIM; 1 = DDPM-like variance.
        generator: draws ``x_T`` (when ``initial_noise`` is None) and, for ``eta > 0``, the step
            noise; must live on ``cond``'s device.
        initial_noise: ``x_T``, shape (B, C_out, H, W), or (C_out, H, W) / (1, C_out, H, W) shared by
            the whole batch (e.g. the frames of one sequence, for temporal coherence).
        mask: UV chart mask (1 inside, 0 outside), shape (B, 1, H, W) or (B, H, W). The training loss
            never sees pixels outside, so the network's noise there is untrained: at every step
            their ``x0`` estimate is set to 0 (the data's value) and the noise re-derived, which
            keeps ``x_t`` outside the pure scaled noise of training; without this the outside
            drifts and, through the convolutions at the chart borders, spoils the inside (without
            it samples have 5-8x the data's wrinkle std, 20x without ``clip_x0``:
            docs/WRINKLES.md). 0 outside in the output.
        temporal_weight: ``w`` of the temporal guidance for a batch of consecutive frames: at each
            step the estimate ``x0_hat_k`` is replaced by
            ``x0_hat_k + w (t / T) (mean(x0_hat_{k-1}, x0_hat_{k+1}) - x0_hat_k)`` (the ends use
            their one neighbour, frame 0's previous being ``anchor`` when given) and the noise
            is re-derived from it, so frames agree while the sample is coarse and keep their
            own detail at the end (0: off; not in Guo et al., who sample frames independently).
        anchor: the previous batch's last result ``x_0``, shape (C_out, H, W) (a sequence sampled
            in chunks).
        clip_x0: bound of the ``x0`` estimate at every step, a number or per channel (C_out,):
            ``x0_hat`` is clamped to ``[-clip, clip]`` and the noise re-derived from it (the
            ``clip_sample`` of DDPM/DDIM implementations, here with the training data's range),
            so a sample cannot leave the range the data spans; None: no clamp.

    Returns:
        x_0, the generated wrinkle field, shape (B, C_out, H, W), dtype of ``cond``.
    """
    B, _, H, W = cond.shape
    shape = (B, model.out_channels, H, W)
    if label is None and guidance_scale != 1.0:
        raise ValueError("guidance_scale != 1 needs a label (classifier-free guidance)")
    x = _initial_noise(shape, cond, initial_noise, generator)
    if label is not None:
        label = label.to(cond.device).long()
    m = None
    if mask is not None:
        m = mask.to(device=x.device, dtype=x.dtype)
        m = m[:, None] if m.ndim == 3 else m
    for t in scheduler.set_timesteps(num_steps).tolist():
        t_batch = torch.full((B,), t, dtype=torch.long, device=cond.device)
        eps = guided_epsilon(model, x, t_batch, cond, label=label, guidance_scale=guidance_scale)
        if temporal_weight > 0.0 and (B > 1 or anchor is not None):
            eps = _temporal_guidance(scheduler, x, eps, t, temporal_weight, anchor)
        if clip_x0 is not None or m is not None:
            eps = _edit_x0(scheduler, x, eps, t, partial(_clamp, clip=clip_x0, mask=m))
        x = scheduler.step(eps, t, x, eta=eta, generator=generator).prev_sample
    if m is not None:
        x = x * m
    return x


def _initial_noise(shape: tuple[int, ...], cond: torch.Tensor, initial_noise: torch.Tensor | None,
                   generator: torch.Generator | None) -> torch.Tensor:
    """``x_T`` of shape ``shape``: drawn from ``generator``, or ``initial_noise`` broadcast over the
    batch, on ``cond``'s device and dtype."""
    if initial_noise is None:
        return torch.randn(shape, generator=generator, device=cond.device, dtype=cond.dtype)
    x = initial_noise.to(device=cond.device, dtype=cond.dtype)
    if x.ndim == 3:
        x = x[None]
    if x.shape[1:] != shape[1:] or x.shape[0] not in (1, shape[0]):
        raise ValueError(f"initial_noise shape {tuple(initial_noise.shape)} does not fit {shape}")
    return x.expand(shape).clone()


def _edit_x0(scheduler: DDIMScheduler, x: torch.Tensor, eps: torch.Tensor, t: int, edit) -> torch.Tensor:
    """``eps`` re-derived after ``edit`` changes the estimate
    ``x0_hat = (x_t - sqrt(1 - a_t) eps) / sqrt(a_t)`` (the guidance and the clamp of ``ddim_sample``)."""
    a = float(scheduler.alphas_cumprod[t])
    sa, sb = a ** 0.5, (1.0 - a) ** 0.5
    return (x - sa * edit((x - sb * eps) / sa)) / sb


def _clamp(x0: torch.Tensor, clip: torch.Tensor | float | None,
           mask: torch.Tensor | None = None) -> torch.Tensor:
    """``x0`` clamped to ``[-clip, clip]`` (a number or per channel (C,); None: no clamp) and
    set to 0 where ``mask`` (broadcastable to ``x0``) is 0."""
    if clip is not None:
        c = torch.as_tensor(clip, device=x0.device, dtype=x0.dtype)
        if c.ndim == 1:
            c = c[None, :, None, None]
        x0 = torch.clamp(x0, -c, c)
    return x0 if mask is None else x0 * mask


def _temporal_guidance(scheduler: DDIMScheduler, x: torch.Tensor, eps: torch.Tensor, t: int, weight: float,
                       anchor: torch.Tensor | None) -> torch.Tensor:
    """``eps`` re-derived from the neighbour-pulled ``x0_hat`` (by ``weight t / T``, see ``ddim_sample``)."""
    pull = weight * t / scheduler.num_train_timesteps
    return _edit_x0(scheduler, x, eps, t, partial(_neighbour_pull, weight=pull, anchor=anchor))


def _neighbour_pull(x0: torch.Tensor, weight: float, anchor: torch.Tensor | None) -> torch.Tensor:
    """Each frame's ``x0`` moved by ``weight`` toward the mean of its neighbours' (frame 0's previous
    is ``anchor`` when given)."""
    prev = torch.cat([x0[:1] if anchor is None else anchor[None].to(x0), x0[:-1]])
    nxt = torch.cat([x0[1:], x0[-1:]])
    has_prev = torch.ones(x0.shape[0], device=x0.device, dtype=x0.dtype)
    has_next = torch.ones_like(has_prev)
    if anchor is None:
        has_prev[0] = 0
    has_next[-1] = 0
    n = (has_prev + has_next).clamp_min(1.0)[:, None, None, None]
    target = (prev * has_prev[:, None, None, None] + nxt * has_next[:, None, None, None]) / n
    return x0 + weight * (target - x0)
