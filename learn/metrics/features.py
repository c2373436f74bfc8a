"""A fixed feature extractor for UV normal maps, the project's stand-in for Inception in FID.

Guo et al. 2024 (Sec 4.1, Table 2) score wrinkle realism with FID on UV-space normal maps: the
Fréchet distance between Gaussians fitted to Inception-v3 features of two image sets. Inception
weights cannot be downloaded here, and a network trained on photographs is an odd judge of
normal maps anyway, so the project ships its own extractor:
deterministic, no training, no downloaded weights. **Its Fréchet distances are NOT comparable
with Inception FID numbers in papers**; every table must say "FD on NormalMapFeatures
``VERSION``", and numbers are comparable only at equal ``VERSION`` and equal set sizes.

What it measures. Wrinkles are oriented, band-limited ripples; in a normal map they show as
oriented oscillations of the normal's components. The extractor is a bank of complex Gabor
(analytic, quadrature-pair) filters, the classical model of V1 simple/complex cells and the
texture descriptor of Manjunath & Ma 1996, at

- 4 scales, wavelengths ``λ = 3, 6, 12, 24`` px at 128 px per UV unit (i.e. 1/43 .. 1/5.3 of
  the UV square: from the finest wrinkles a 128² map holds to folds a fifth of a panel wide),
  one octave apart, each one octave wide (radial σ_f = 0.283 f0 in frequency);
- 6 orientations, 0°, 30°, .., 150° (a complex filter's magnitude is the same for θ and θ + 180°),

applied to each of the 3 normal-map channels. The magnitude of each complex response is the
local *oriented energy* of the wrinkles at that scale and orientation, insensitive to phase
(where exactly a crest lies), as Inception's pooled activations are insensitive to position.
Each of the 3 x 4 x 6 = 72 energy maps is pooled inside the mask (mean and standard deviation,
pixels whose filter support leaves the mask weigh less, see :data:`COVERAGE_FULL`), and the
per-channel mean and standard deviation of the normals themselves (the "colour moments": mean
orientation and overall roughness) are appended: ``D = 72 x 2 + 3 x 2 = 150`` features.

Why it is a reasonable FID substitute: like Inception's pool features it summarises an image
by statistics of nonlinear (rectified) responses of localised oriented filters at several
scales, pooled over space; the Fréchet distance between Gaussians fitted to such features then
compares the *distributions* of wrinkle amplitude, size and direction between two sets of
maps, not pixel-wise agreement. Blurring (missing fine wrinkles) lowers the small-scale
energies and noise raises them, so both increase the distance (tests/test_metrics.py). It does
not see semantics (seams, where on the garment a fold sits) beyond the colour moments.

Resolution independence: maps are first resampled (mask-aware, antialiased bilinear) to
``size x size`` (128 by default) and the filters are defined in cycles per UV unit, so the same
pattern at 64² or 256² gives nearly the same features (as far as the 64² map holds its fine
scales: its Nyquist wavelength, 2 px at 64² = 4 px at 128², lies below only the finest band).

Input convention: normal maps ``(N, H, W, 3)`` with unit-normal components in [-1, 1] (the
dataset's ``images/normal_tangent`` or ``images/normal_world``), plus an optional coverage mask
``(H, W)`` or ``(N, H, W)`` (``images/mask``). Features are float64 on the cpu.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from learn.metrics.geometry import as_tensor
from sim.errors import WrinklesInputError

VERSION = "nmf-gabor-1"
"""Identifies the extractor; bump it whenever a change alters any feature value."""

WAVELENGTHS_AT_128 = (3.0, 6.0, 12.0, 24.0)
"""Filter wavelengths [px] at 128 px per UV unit (the image side spans one UV unit)."""
ORIENTATIONS = 6
"""Filter orientations, evenly spaced over [0°, 180°)."""
BANDWIDTH = 0.283
"""Gaussian radial std of each filter's passband over its centre frequency: 1 octave full width
at half amplitude (f0 ± 1.177 σ_f spans a factor 2)."""
COVERAGE_FULL = 0.95
"""A pixel weighs fully in the pooling of a scale when this share of its filter's Gaussian
envelope lies inside the mask; the weight falls linearly to 0 at half coverage (a straight
chart edge), so chart boundaries add little spurious energy."""
BATCH = 8
"""Images filtered at once (bounds memory: BATCH x 3 complex (1.5 size)² maps per filter)."""
FEATURE_DIM = 3 * len(WAVELENGTHS_AT_128) * ORIENTATIONS * 2 + 3 * 2
"""Length of a feature vector (150)."""


def _default_device(device) -> torch.device:
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


class NormalMapFeatures:
    """Fixed multi-scale oriented-energy features of UV normal maps (module docstring).

    Args:
        size: side [px] maps are resampled to before filtering (>= 128; filters are defined in
            UV units, so a larger size only samples them more finely).
        device: torch device for the filtering (None: cuda when present, else cpu).
    """

    VERSION = VERSION

    def __init__(self, *, size: int = 128, device: torch.device | str | None = None):
        if size < 128:
            raise ValueError(f"size must be >= 128 px (finest filter wavelength 3 px at 128), got {size}")
        self.size = int(size)
        self.device = _default_device(device)
        self.dim = FEATURE_DIM
        S = self.size
        self._pad = int(math.ceil(1.5 * S / 16) * 16)  # >= S + 3 spatial sigmas of the coarsest filter
        P = self._pad
        f = torch.fft.fftfreq(P, dtype=torch.float64)
        fy, fx = f[:, None], f[None, :]
        filters, envelopes = [], []
        for lam in WAVELENGTHS_AT_128:
            f0 = 128.0 / (lam * S)  # cycles / px at this size
            sf = BANDWIDTH * f0
            env = torch.exp(-(fx ** 2 + fy ** 2) / (2 * sf ** 2))  # spatial Gaussian envelope, DC gain 1
            envelopes.append(env)
            for k in range(ORIENTATIONS):
                th = math.pi * k / ORIENTATIONS
                ux, uy = f0 * math.cos(th), f0 * math.sin(th)
                g = torch.exp(-((fx - ux) ** 2 + (fy - uy) ** 2) / (2 * sf ** 2))
                g = g - math.exp(-f0 ** 2 / (2 * sf ** 2)) * env  # zero DC gain (Morlet correction)
                filters.append(g)
        self._filters = torch.stack(filters).to(self.device, torch.complex64)  # (S*O, P, P)
        self._envelopes = torch.stack(envelopes).to(self.device, torch.complex64)  # (S, P, P)

    def _resample(self, x: torch.Tensor, m: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Mask-aware resampling to size² : x (n, 3, H, W), m (n, 1, H, W) -> same at S x S."""
        S = self.size
        if x.shape[-2:] == (S, S):
            return x, (m > 0.5).to(x.dtype)
        kw = dict(size=(S, S), mode="bilinear", align_corners=False, antialias=True)
        xm = F.interpolate(x * m, **kw)
        ms = F.interpolate(m, **kw)
        return xm / ms.clamp(min=1e-6), (ms > 0.5).to(x.dtype)

    def _batch(self, x: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
        """Features of x (n, 3, S, S) float32 with masks m (n, 1, S, S) -> (n, D) float64."""
        n, S, P = x.shape[0], self.size, self._pad
        cnt = m.sum(dim=(-2, -1), keepdim=True).double()  # (n, 1, 1, 1)
        mean = (x.double() * m).sum(dim=(-2, -1), keepdim=True) / cnt
        var = ((x.double() - mean) ** 2 * m).sum(dim=(-2, -1), keepdim=True) / cnt
        y = ((x - mean.float()) * m)
        Y = torch.fft.fft2(F.pad(y, (0, P - S, 0, P - S)))  # (n, 3, P, P)
        M = torch.fft.fft2(F.pad(m, (0, P - S, 0, P - S)))  # (n, 1, P, P)
        means, stds = [], []
        for s in range(len(WAVELENGTHS_AT_128)):
            cov = torch.fft.ifft2(M * self._envelopes[s]).real[..., :S, :S]
            w = (m * ((cov - 0.5) / (COVERAGE_FULL - 0.5)).clamp(0.0, 1.0)).double()  # (n, 1, S, S)
            sw = w.sum(dim=(-2, -1), keepdim=True)
            w = torch.where(sw > 1.0, w, m.double())  # a chart thinner than the filter: plain mask
            sw = w.sum(dim=(-2, -1), keepdim=True)
            for o in range(ORIENTATIONS):
                g = self._filters[s * ORIENTATIONS + o]
                e = torch.fft.ifft2(Y * g)[..., :S, :S].abs().double()  # (n, 3, S, S) oriented energy
                mu = (e * w).sum(dim=(-2, -1), keepdim=True) / sw
                sd = (((e - mu) ** 2 * w).sum(dim=(-2, -1), keepdim=True) / sw).sqrt()
                means.append(mu.reshape(n, 3))
                stds.append(sd.reshape(n, 3))
        # order: [energy means (scale, orientation, channel)], [energy stds], [colour means], [colour stds]
        return torch.cat([torch.stack(means, 1).reshape(n, -1), torch.stack(stds, 1).reshape(n, -1),
                          mean.reshape(n, 3), var.sqrt().reshape(n, 3)], dim=1)

    def __call__(self, maps, mask=None) -> torch.Tensor:
        """Features of each normal map.

        Args:
            maps: normal maps, shape (N, H, W, 3), components in [-1, 1].
            mask: coverage, bool, shape (H, W) or (N, H, W); None: every pixel.

        Returns:
            Features, float64 on the cpu, shape (N, :data:`FEATURE_DIM`).
        """
        x = as_tensor(maps, device=self.device, dtype=torch.float32)
        if x.ndim != 4 or x.shape[-1] != 3:
            raise WrinklesInputError(f"normal maps must have shape (N, H, W, 3), got {tuple(x.shape)}")
        N, H, W, _ = x.shape
        if H < 8 or W < 8:
            raise WrinklesInputError(f"normal maps of {H}x{W} px are too small")
        if mask is None:
            m = torch.ones(1, H, W, dtype=torch.float32, device=self.device)
        else:
            m = (as_tensor(mask, device=self.device, dtype=torch.float32) > 0).float()
            if m.shape[-2:] != (H, W) or m.ndim not in (2, 3) or (m.ndim == 3 and m.shape[0] != N):
                raise WrinklesInputError(f"mask must have shape ({H}, {W}) or ({N}, {H}, {W}), "
                                         f"got {tuple(m.shape)}")
            if m.ndim == 2:
                m = m[None]
        m = m.expand(N, H, W)
        x = x.permute(0, 3, 1, 2)
        out = []
        for i in range(0, N, BATCH):
            xi, mi = self._resample(x[i:i + BATCH], m[i:i + BATCH, None])
            if bool((mi.sum(dim=(-2, -1)) == 0).any()):
                raise WrinklesInputError("a mask covers no pixel at the extractor's resolution")
            out.append(self._batch(xi, mi).cpu())
        return torch.cat(out) if out else torch.empty(0, FEATURE_DIM, dtype=torch.float64)
