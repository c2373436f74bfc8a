"""Noise schedules for the wrinkle diffusion model (Guo et al. 2024, Sec. 3.2 and 4.1).

The scheduler owns the betas, the forward process ``add_noise`` and the reverse ``step``; it
never owns a network (STYLE.md 4, diffusers' ``scheduling_ddpm.py`` / ``scheduling_ddim.py``).

* :class:`DDPMScheduler` — the linear variance schedule of Ho et al. 2020 used for training:
  ``beta_t`` from ``1e-4`` to ``0.02`` over ``T = 1000`` steps (Guo et al. Sec. 4.1),
  ``q(x_t | x_0)`` (Ho et al. Eq. 4) and the epsilon target of the loss (Guo et al. Eq. 7).
* :class:`DDIMScheduler` — the same betas, sampled with DDIM (Song et al. 2021, Eq. 12) on a
  sub-sequence of ``S`` timesteps (the paper uses ``S = 50``, ``eta = 0``).

Indexing: timesteps are 0-based, ``t in [0, T)``; ``alphas_cumprod[t]`` is
``prod_{i<=t} (1 - beta_i)`` (the paper's ``alpha_bar_{t+1}`` in 1-based notation), as in
diffusers. The schedule is held in float64 on the CPU; coefficients are computed in float64
and applied to float32 (or any floating) samples on their own device.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

TIMESTEP_SPACINGS = ("leading", "trailing")


@dataclass(frozen=True)
class ScheduleConfig:
    """The variance schedule shared by training (DDPM) and sampling (DDIM)."""

    num_train_timesteps: int = 1000
    """``T``, the number of forward diffusion steps (Guo et al. Sec. 4.1: 1000)."""
    beta_start: float = 1.0e-4
    """``beta_1``, variance of the first step (dimensionless)."""
    beta_end: float = 0.02
    """``beta_T``, variance of the last step; betas are linear in between."""

    def __post_init__(self) -> None:
        if self.num_train_timesteps < 2:
            raise ValueError(f"ScheduleConfig.num_train_timesteps must be >= 2, got "
                             f"{self.num_train_timesteps}")
        if not (0.0 < self.beta_start <= self.beta_end < 1.0):
            raise ValueError(
                f"ScheduleConfig needs 0 < beta_start <= beta_end < 1, got {self.beta_start}, {self.beta_end}"
            )


@dataclass(frozen=True)
class DDIMConfig:
    """How DDIM picks its inference timesteps and ends the chain."""

    timestep_spacing: str = "leading"
    """``leading`` (diffusers' DDIM default): ``t_i = i * (T // S)``, so the first step is at
    ``(S - 1) * (T // S)`` (980 for T=1000, S=50) and the last at 0. ``trailing``:
    ``t_i = round(T - i * T / S) - 1``, starting at ``T - 1`` (999) and ending at ``T / S - 1``."""
    set_alpha_to_one: bool = True
    """The step after the last timestep uses ``alpha_bar_prev = 1`` (returns the predicted
    ``x_0``), as diffusers' default; False uses ``alphas_cumprod[0]``."""

    def __post_init__(self) -> None:
        if self.timestep_spacing not in TIMESTEP_SPACINGS:
            raise ValueError(
                f"DDIMConfig.timestep_spacing must be one of {TIMESTEP_SPACINGS}, "
                f"got {self.timestep_spacing!r}"
            )


@dataclass(frozen=True)
class DDIMStepOutput:
    """Result of one reverse DDIM step."""

    prev_sample: torch.Tensor
    """``x_{t_prev}``, same shape, dtype and device as ``x_t``."""
    pred_original_sample: torch.Tensor
    """The model's estimate of ``x_0`` at this step (Song et al. Eq. 12, first bracket)."""


def linear_betas(config: ScheduleConfig) -> torch.Tensor:
    """Linear variance schedule (Ho et al. 2020 Sec. 4; Guo et al. Sec. 4.1).

    Returns:
        betas, float64, shape (T,).
    """
    return torch.linspace(config.beta_start, config.beta_end, config.num_train_timesteps, dtype=torch.float64)


def _gather(values: torch.Tensor, t: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """``values[t]`` broadcast to ``like``'s rank, on its device (float64)."""
    t = torch.as_tensor(t, dtype=torch.long).to("cpu")
    if t.ndim == 0:
        t = t.expand(like.shape[0])
    if t.shape != (like.shape[0],):
        raise ValueError(f"timesteps must have shape () or ({like.shape[0]},), got {tuple(t.shape)}")
    out = values[t].to(like.device)
    return out.reshape(-1, *([1] * (like.ndim - 1)))


class DDPMScheduler:
    """Linear-beta DDPM schedule: the forward process and the training target.

    Args:
        num_train_timesteps: ``T``.
        beta_start: ``beta_1``.
        beta_end: ``beta_T``.

    Attributes:
        config: the resolved :class:`ScheduleConfig`.
        betas, alphas, alphas_cumprod: float64 CPU tensors, shape (T,);
            ``alphas = 1 - betas``, ``alphas_cumprod[t] = prod_{i<=t} alphas[i]``.
    """

    def __init__(self, num_train_timesteps: int = 1000, beta_start: float = 1.0e-4, beta_end: float = 0.02):
        self.config = ScheduleConfig(num_train_timesteps, beta_start, beta_end)
        self.betas = linear_betas(self.config)
        self.alphas = 1.0 - self.betas
        self.alphas_cumprod = torch.cumprod(self.alphas, dim=0)

    @classmethod
    def from_config(cls, config: ScheduleConfig) -> DDPMScheduler:
        return cls(config.num_train_timesteps, config.beta_start, config.beta_end)

    @property
    def num_train_timesteps(self) -> int:
        return self.config.num_train_timesteps

    def sample_timesteps(
        self, batch_size: int, *, generator: torch.Generator | None = None, device: torch.device | str = "cpu"
    ) -> torch.Tensor:
        """Uniform training timesteps ``t ~ U{0, ..., T-1}`` (Guo et al. Eq. 7), int64, shape (B,).

        Drawn on the generator's device (CPU by default), then moved to ``device``.
        """
        gen_device = generator.device if generator is not None else "cpu"
        t = torch.randint(0, self.num_train_timesteps, (batch_size,), generator=generator, device=gen_device)
        return t.to(device)

    def add_noise(self, x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor | int) -> torch.Tensor:
        """Sample ``q(x_t | x_0)`` (Ho et al. 2020 Eq. 4; Guo et al. Eq. 7 argument).

        ``x_t = sqrt(alpha_bar_t) x_0 + sqrt(1 - alpha_bar_t) eps``, coefficients computed in float64
        and cast to ``x0.dtype``.

        Args:
            x0: clean samples, shape (B, ...).
            noise: ``eps ~ N(0, I)``, same shape as ``x0``.
            t: timesteps in ``[0, T)``, int, shape (B,) or scalar.

        Returns:
            x_t, shape and dtype of ``x0``.
        """
        if noise.shape != x0.shape:
            raise ValueError(f"noise shape {tuple(noise.shape)} != x0 shape {tuple(x0.shape)}")
        a_bar = _gather(self.alphas_cumprod, t, x0)
        return a_bar.sqrt().to(x0.dtype) * x0 + (1.0 - a_bar).sqrt().to(x0.dtype) * noise

    def training_target(self, x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor | int) -> torch.Tensor:
        """The regression target of the network: the noise itself (epsilon prediction, Guo et al. Eq. 7)."""
        del x0, t  # epsilon parameterisation: the target does not depend on them
        return noise


class DDIMScheduler(DDPMScheduler):
    """DDIM sampling (Song et al. 2021, Eq. 12) on the DDPM betas.

    Call :meth:`set_timesteps` once, then :meth:`step` for each ``t`` in :attr:`timesteps`
    (descending).

    Args:
        num_train_timesteps, beta_start, beta_end: the shared schedule (see :class:`DDPMScheduler`).
        timestep_spacing: ``"leading"`` (default, as diffusers' DDIM) or ``"trailing"``.
        set_alpha_to_one: see :class:`DDIMConfig`.
    """

    def __init__(
        self,
        num_train_timesteps: int = 1000,
        beta_start: float = 1.0e-4,
        beta_end: float = 0.02,
        *,
        timestep_spacing: str = "leading",
        set_alpha_to_one: bool = True,
    ):
        super().__init__(num_train_timesteps, beta_start, beta_end)
        self.ddim_config = DDIMConfig(timestep_spacing, set_alpha_to_one)
        self.final_alpha_cumprod = 1.0 if set_alpha_to_one else float(self.alphas_cumprod[0])
        self.timesteps: torch.Tensor | None = None
        self._prev: dict[int, int] = {}

    @classmethod
    def from_ddpm(cls, ddpm: DDPMScheduler, ddim_config: DDIMConfig | None = None) -> DDIMScheduler:
        """A DDIM sampler sharing ``ddpm``'s betas (same config)."""
        d = ddim_config or DDIMConfig()
        c = ddpm.config
        return cls(
            c.num_train_timesteps,
            c.beta_start,
            c.beta_end,
            timestep_spacing=d.timestep_spacing,
            set_alpha_to_one=d.set_alpha_to_one,
        )

    def set_timesteps(self, num_inference_steps: int) -> torch.Tensor:
        """Choose ``S`` evenly spaced timesteps, descending (int64, shape (S,)), and store them."""
        T = self.num_train_timesteps
        if not 1 <= num_inference_steps <= T:
            raise ValueError(f"num_inference_steps must be in [1, {T}], got {num_inference_steps}")
        S = num_inference_steps
        if self.ddim_config.timestep_spacing == "leading":
            steps = [i * (T // S) for i in range(S)][::-1]
        else:  # trailing
            steps = [round(T - i * T / S) - 1 for i in range(S)]
        self.timesteps = torch.tensor(steps, dtype=torch.long)
        self._prev = {steps[i]: (steps[i + 1] if i + 1 < S else -1) for i in range(S)}
        return self.timesteps

    def _alpha_bar(self, t: int) -> float:
        return float(self.alphas_cumprod[t]) if t >= 0 else self.final_alpha_cumprod

    def step(
        self,
        eps: torch.Tensor,
        t: int | torch.Tensor,
        x_t: torch.Tensor,
        *,
        eta: float = 0.0,
        generator: torch.Generator | None = None,
        prev_t: int | None = None,
        variance_noise: torch.Tensor | None = None,
    ) -> DDIMStepOutput:
        """One reverse step ``x_t -> x_{prev_t}`` (Song et al. 2021, Eq. 12 with Eq. 16's sigma).

        ``x0_hat = (x_t - sqrt(1 - a_t) eps) / sqrt(a_t)``;
        ``x_prev = sqrt(a_prev) x0_hat + sqrt(1 - a_prev - sigma^2) eps + sigma z``;
        ``sigma = eta sqrt((1 - a_prev) / (1 - a_t)) sqrt(1 - a_t / a_prev)``, where ``a`` is
        ``alphas_cumprod`` and ``a_prev = 1`` (or ``alphas_cumprod[0]``) past the last step.
        ``eta = 0`` is deterministic DDIM, ``eta = 1`` the DDPM posterior variance.

        Args:
            eps: predicted noise, shape of ``x_t``.
            t: current timestep (one for the whole batch), int in ``[0, T)``.
            x_t: current sample, shape (B, ...).
            eta: stochasticity, >= 0.
            generator: draws ``z`` when ``eta > 0`` (must live on ``x_t``'s device).
            prev_t: the timestep to step to; default: the next one of :meth:`set_timesteps`
                (-1 after the last one).
            variance_noise: ``z`` itself, shape of ``x_t`` (overrides ``generator``).

        Returns:
            :class:`DDIMStepOutput` with ``prev_sample`` and ``pred_original_sample``.
        """
        t = int(t)
        if not 0 <= t < self.num_train_timesteps:
            raise ValueError(f"timestep {t} outside [0, {self.num_train_timesteps})")
        if prev_t is None:
            if t not in self._prev:
                raise ValueError(f"timestep {t} is not one of set_timesteps(); call it first or pass prev_t")
            prev_t = self._prev[t]
        if not -1 <= prev_t < t:
            raise ValueError(f"prev_t must be in [-1, {t}), got {prev_t}")
        if eta < 0.0:
            raise ValueError(f"eta must be >= 0, got {eta}")
        a_t = self._alpha_bar(t)
        a_prev = self._alpha_bar(prev_t)
        sigma = eta * math.sqrt((1.0 - a_prev) / (1.0 - a_t)) * math.sqrt(1.0 - a_t / a_prev)
        pred_x0 = (x_t - math.sqrt(1.0 - a_t) * eps) / math.sqrt(a_t)
        dir_xt = math.sqrt(max(1.0 - a_prev - sigma * sigma, 0.0)) * eps
        prev = math.sqrt(a_prev) * pred_x0 + dir_xt
        if sigma > 0.0:
            if variance_noise is None:
                variance_noise = torch.randn(
                    x_t.shape, generator=generator, device=x_t.device, dtype=x_t.dtype
                )
            elif variance_noise.shape != x_t.shape:
                raise ValueError(f"variance_noise shape {tuple(variance_noise.shape)} != {tuple(x_t.shape)}")
            prev = prev + sigma * variance_noise
        return DDIMStepOutput(prev_sample=prev, pred_original_sample=pred_x0)
