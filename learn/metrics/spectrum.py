"""Wrinkle spectrum: radially averaged power spectrum of UV maps.

Wrinkles are a band of spatial frequencies in the garment's UV displacement (or normal) maps
(``images/wrinkle`` of the dataset, ``sim.datasets.schema``). Comparing the radially averaged
power spectra of predicted and ground-truth maps tells whether a model makes wrinkles of the
right size and strength, independently of where they are (the per-pixel errors ``Ev``/``Ecd``
penalise a wrinkle shifted by half its wavelength as much as a missing one).

Recipe (:func:`radial_power_spectrum`), per image and channel:

1. weight ``w = hann(H) ⊗ hann(W) · mask`` (a separable Hann window limits the leakage of the
   image border; the mask zeroes pixels outside the UV charts);
2. remove the weighted mean, ``y = w · (x − Σ w x / Σ w)``;
3. ``P(f) = |FFT2(y)(f)|² / Σ w²`` — normalised so that white noise of variance σ² has
   ``E[P(f)] = σ²`` at every frequency, whatever the window, mask or resolution;
4. average ``P`` over the FFT cells in each radial frequency bin, then over channels.

Units: ``frequency`` is in **cycles per pixel** (radial ``|f|``, 0 .. 0.5 at Nyquist along an
axis); a UV image of width W px spans one UV unit, so cycles per UV unit = frequency x W, and
wavelengths are in px (UV units = px / W). ``power`` is in the map's unit squared (m² for
displacement maps). Default bins are one FFT frequency step wide, ``1 / min(H, W)``, centred on
``k / min(H, W)``, k = 1 .. min(H, W) // 2 (the DC bin is left out: it is zero after step 2).

Caveat: the mask's edges are not tapered, so a chart boundary leaks some power across
frequencies; predicted and ground-truth maps share the mask, so comparisons stay fair.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from learn.metrics.geometry import as_tensor
from sim.errors import WrinklesInputError

POWER_FLOOR = 1e-30
"""Power below this is raised to it before a log10 (a bin of a constant map has power 0)."""


@dataclass(frozen=True)
class Spectrum:
    """Radially averaged power spectra of N images.

    Attributes:
        frequency: bin centres [cycles / px], float64, shape (nbins,).
        power: mean power per bin [map unit²], float64, shape (N, nbins); nan in empty bins.
        count: FFT cells per bin, int64, shape (nbins,).
        edges: bin edges [cycles / px], float64, shape (nbins + 1,).
        resolution: (H, W) of the images [px].
    """

    frequency: torch.Tensor
    power: torch.Tensor
    count: torch.Tensor
    edges: torch.Tensor
    resolution: tuple[int, int]

    @property
    def wavelength(self) -> torch.Tensor:
        """Bin-centre wavelengths [px], shape (nbins,)."""
        return 1.0 / self.frequency

    def mean_power(self) -> torch.Tensor:
        """Power averaged over the N images, shape (nbins,)."""
        return self.power.mean(dim=0)


def _bin_edges(H: int, W: int, bins, device) -> torch.Tensor:
    n0 = min(H, W)
    if bins is None:
        k = torch.arange(1, n0 // 2 + 2, dtype=torch.float64, device=device)
        return (k - 0.5) / n0
    if isinstance(bins, int):
        if bins < 1:
            raise ValueError(f"bins must be >= 1, got {bins}")
        return torch.linspace(0.5 / n0, 0.5, bins + 1, dtype=torch.float64, device=device)
    e = as_tensor(bins, device=device).reshape(-1)
    if e.numel() < 2 or bool((e[1:] <= e[:-1]).any()) or float(e[0]) <= 0.0:
        raise ValueError("bins must be increasing positive edges [cycles/px], at least two")
    return e


def radial_power_spectrum(images, *, mask=None, bins=None) -> Spectrum:
    """Radially averaged power spectrum of each image (recipe in the module docstring).

    Args:
        images: maps, shape (N, H, W, C) (any unit; displacement [m], normals [-]).
        mask: pixels that belong to the garment, bool, shape (H, W) or (N, H, W); None: all.
        bins: None (one FFT step wide bins, see module docstring), a number of uniform bins
            over [0.5 / min(H, W), 0.5] cycles/px, or increasing edges [cycles/px].

    Returns:
        :class:`Spectrum` (tensors on the images' device).
    """
    x = as_tensor(images)
    if x.ndim != 4:
        raise WrinklesInputError(f"images must have shape (N, H, W, C), got {tuple(x.shape)}")
    N, H, W, C = x.shape
    if H < 4 or W < 4:
        raise WrinklesInputError(f"images of {H}x{W} px are too small for a spectrum")
    dev = x.device
    win = (torch.hann_window(H, periodic=False, dtype=torch.float64, device=dev)[:, None]
           * torch.hann_window(W, periodic=False, dtype=torch.float64, device=dev)[None, :])
    w = win.expand(N, H, W)
    if mask is not None:
        m = as_tensor(mask, device=dev)
        if m.shape[-2:] != (H, W) or m.ndim not in (2, 3):
            raise WrinklesInputError(f"mask must have shape ({H}, {W}) or (N, {H}, {W}), "
                                     f"got {tuple(m.shape)}")
        w = w * (m > 0).to(torch.float64)
    sw = w.sum(dim=(-2, -1))  # (N,)
    if bool((sw <= 0).any()):
        raise WrinklesInputError("mask selects no pixel inside the window")
    w = w[..., None]  # (N, H, W, 1)
    mean = (w * x).sum(dim=(1, 2), keepdim=True) / sw[:, None, None, None]
    y = (w * (x - mean)).permute(0, 3, 1, 2)  # (N, C, H, W)
    P = torch.fft.fft2(y).abs().square().mean(dim=1) / (w.square().sum(dim=(1, 2, 3)))[:, None, None]

    edges = _bin_edges(H, W, bins, dev)
    fy = torch.fft.fftfreq(H, dtype=torch.float64, device=dev)
    fx = torch.fft.fftfreq(W, dtype=torch.float64, device=dev)
    f = torch.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2).reshape(-1)
    idx = torch.bucketize(f, edges, right=True) - 1  # edges[k] <= f < edges[k + 1]
    nb = edges.numel() - 1
    keep = (idx >= 0) & (idx < nb)
    idx = idx[keep]
    count = torch.zeros(nb, dtype=torch.int64, device=dev).index_add_(0, idx, torch.ones_like(idx))
    total = torch.zeros(N, nb, dtype=torch.float64, device=dev).index_add_(1, idx, P.reshape(N, -1)[:, keep])
    power = total / count.to(torch.float64)  # 0/0 = nan in empty bins
    return Spectrum(frequency=0.5 * (edges[1:] + edges[:-1]), power=power, count=count, edges=edges,
                    resolution=(H, W))


def _profile(p) -> torch.Tensor:
    return p.mean_power() if isinstance(p, Spectrum) else as_tensor(p)


def spectrum_profile_distance(p, q) -> torch.Tensor:
    """Mean absolute difference of log10 power over bins.

    ``d = mean_b |log10 P_b − log10 Q_b|`` over bins where both are defined (nan bins are
    skipped; power is floored at :data:`POWER_FLOOR`). 0 for equal spectra; scaling a map by s
    adds ``2 |log10 s|``; 0.3 is a factor 2 in power (√2 in amplitude) on average.

    Args:
        p: a :class:`Spectrum` (its images' mean power is used) or powers (..., nbins).
        q: same kind as ``p``, same bins.

    Returns:
        Distance [decades of power], float64, shape (...) (0-d for two spectra).
    """
    if isinstance(p, Spectrum) and isinstance(q, Spectrum):
        if p.edges.shape != q.edges.shape or not torch.allclose(p.edges, q.edges.to(p.edges.device)):
            raise WrinklesInputError("the two spectra have different frequency bins")
    a = _profile(p)
    b = _profile(q).to(a.device)
    if a.shape[-1] != b.shape[-1]:
        raise WrinklesInputError(f"spectra have {a.shape[-1]} and {b.shape[-1]} bins")
    d = (torch.log10(a.clamp(min=POWER_FLOOR)) - torch.log10(b.clamp(min=POWER_FLOOR))).abs()
    d = torch.where(torch.isnan(a) | torch.isnan(b), torch.nan, d)
    return torch.nanmean(d, dim=-1)


def dominant_wavelength(spectrum: Spectrum) -> torch.Tensor:
    """Power-weighted mean wavelength of each image.

    Each bin weighs by its *total* power (mean power x number of FFT cells, the energy of the
    annulus), ``λ̄ = Σ_b E_b / f_b / Σ_b E_b``.

    Args:
        spectrum: from :func:`radial_power_spectrum`.

    Returns:
        Wavelength [px] (UV units: divide by the image width), float64, shape (N,).
    """
    e = torch.nan_to_num(spectrum.power, nan=0.0) * spectrum.count.to(torch.float64)
    tot = e.sum(dim=-1)
    return (e / spectrum.frequency).sum(dim=-1) / tot


__all__ = ["POWER_FLOOR", "Spectrum", "dominant_wavelength", "radial_power_spectrum",
           "spectrum_profile_distance"]
