"""Strain-conditioned wrinkle diffusion (Guo et al. 2024, Sec. 3.2, 4.1, 4.4).

Schedule, network and loop apart (STYLE.md 4, diffusers' layout):

* :mod:`learn.diffusion.scheduler` — betas, ``add_noise``, the epsilon target (DDPM) and the DDIM
  ``step``;
* :mod:`learn.diffusion.unet` — ``WrinkleUNet``, ``eps_theta(x_t, t; strain, mask, label)``;
* :mod:`learn.diffusion.sampling` — ``ddim_sample`` with classifier-free guidance.
"""

from learn.diffusion.sampling import ddim_sample, guided_epsilon
from learn.diffusion.scheduler import DDIMConfig, DDIMScheduler, DDIMStepOutput, DDPMScheduler, ScheduleConfig
from learn.diffusion.unet import UNetConfig, WrinkleUNet, count_parameters

__all__ = [
    "DDIMConfig",
    "DDIMScheduler",
    "DDIMStepOutput",
    "DDPMScheduler",
    "ScheduleConfig",
    "UNetConfig",
    "WrinkleUNet",
    "count_parameters",
    "ddim_sample",
    "guided_epsilon",
]
