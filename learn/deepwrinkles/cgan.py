"""DeepWrinkles' conditional GAN (Lähner et al. 2018, Sec. 4.2, Fig. 8, Eq. 4): a pix2pix network
(Isola et al. 2017) that turns a low-resolution (LR) UV normal map of the regressed garment into a
high-resolution (HR) one carrying the fine wrinkles of the scans.

- ``UNetGenerator``: the pix2pix U-Net, ``log2(resolution)`` levels down to a 1x1 bottleneck (8 at
  256², the paper's "2x 8 layers, 64 filters in the first"), skip connections across every level.
- ``PatchDiscriminator``: the 70x70 PatchGAN, conditioned on the LR map by channel concatenation; it
  scores overlapping patches, so it acts as a texture loss on the wrinkle pattern.
- Losses masked by the UV coverage mask: pixels outside every UV chart carry no loss and do not
  count in means. ``data_term`` (Eq. 4's L_data), ``temporal_term`` (Eq. 4's L_temp and the L1 / L2
  alternatives of the paper's Table 1), ``adversarial_term`` (pix2pix's BCE or least squares).
- ``cgan_loss``: generator and discriminator objectives summed so that one optimizer over both
  networks trains the GAN: each term's gradient reaches only the network it is meant to train.

Normal maps are in [-1, 1] per channel; the generator's tanh output is not unit length, and callers
renormalise it. Weights follow the paper's Sec. 5 (``CGANWeights``: data 100, temporal 50, GAN 1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import chain

import torch
import torch.nn.functional as F
from torch import nn
from torch.func import functional_call

from sim.errors import WrinklesInputError

MIN_RESOLUTION = 16
"""Smallest generator resolution [px]: four levels, enough for the three dropout blocks above the
tanh output level."""
INIT_STD = 0.02
"""Standard deviation of the pix2pix weight initialisation (convolutions N(0, 0.02), norm scales
N(1, 0.02))."""
DENOMINATOR_FLOOR = 1e-12
"""Floor of a masked mean's denominator: an empty mask gives a zero loss, not NaN."""

NORMS: dict[str, Callable[[int], nn.Module]] = {
    "batch": lambda c: nn.BatchNorm2d(c),
    # pix2pix's instance norm: no affine scale, no running statistics
    "instance": lambda c: nn.InstanceNorm2d(c, affine=False, track_running_stats=False),
}
"""Normalisation layers by name, built for a channel count."""

GAN_LOSSES: dict[str, Callable[[torch.Tensor, torch.Tensor], torch.Tensor]] = {
    "vanilla": lambda x, t: F.binary_cross_entropy_with_logits(x, t, reduction="none"),
    "lsgan": lambda x, t: F.mse_loss(x, t, reduction="none"),
}
"""Per-patch adversarial losses by ``gan_mode``, (discriminator output, 0/1 target) -> loss map:
"vanilla" is binary cross-entropy on logits (pix2pix's default), "lsgan" least squares (Mao et al.
2017)."""


def _norm(name: str, what: str) -> Callable[[int], nn.Module]:
    if name not in NORMS:
        raise WrinklesInputError(f"{what}: norm {name!r} is not one of {sorted(NORMS)}")
    return NORMS[name]


def _check_gan_mode(gan_mode: str) -> None:
    if gan_mode not in GAN_LOSSES:
        raise WrinklesInputError(f"gan_mode {gan_mode!r} is not one of {sorted(GAN_LOSSES)}")


def _init_pix2pix(module: nn.Module) -> None:
    """pix2pix's "normal" initialisation, applied module by module (``nn.Module.apply``)."""
    if isinstance(module, (nn.Conv2d, nn.ConvTranspose2d)):
        nn.init.normal_(module.weight, 0.0, INIT_STD)
        if module.bias is not None:
            nn.init.zeros_(module.bias)
    elif isinstance(module, nn.BatchNorm2d):
        nn.init.normal_(module.weight, 1.0, INIT_STD)
        nn.init.zeros_(module.bias)


def unet_depth(resolution: int) -> int:
    """Number of stride-2 levels of the U-Net at ``resolution`` [px]: log2 of it, so the innermost
    level is 1x1 (8 at 256², 9 at 512²)."""
    if not isinstance(resolution, int) or resolution < MIN_RESOLUTION or resolution & (resolution - 1):
        raise WrinklesInputError(f"UNetGenerator: resolution must be a power of two >= {MIN_RESOLUTION}, "
                                 f"got {resolution!r}")
    return resolution.bit_length() - 1


class UNetGenerator(nn.Module):
    """pix2pix U-Net generator (Isola et al. 2017, Sec. 3.2.1 and Appendix 6.1.1; Lähner et al. Fig. 8).

    Encoder level i (i = 0 .. depth-1) halves the size with a 4x4 stride-2 convolution to
    ``filters * min(2^i, 8)`` channels (64, 128, 256, 512, 512, ... at 64 filters); decoder level i
    doubles it with a 4x4 stride-2 transposed convolution back to level i-1's channels (the output
    channels at level 0) and reads the concatenation of its encoder level's features and the level
    below's output (the skip connections that keep the image's structure). Encoder levels apply
    LeakyReLU(0.2) to their input, then convolution and norm; decoder levels ReLU, transposed
    convolution, norm, and dropout in the three innermost levels (pix2pix's noise source). This
    pre-activation order computes pix2pix's Conv-Norm-(Leaky)ReLU layers. As in pix2pix the first
    encoder level and the innermost (1x1) one carry no norm, and the output is tanh, in [-1, 1].

    Args:
        in_channels: channels of the LR condition (3 for a normal map).
        out_channels: channels of the generated map (3).
        filters: channels of the first encoder level (64 in the paper).
        resolution: side of the square input and output [px], a power of two >= 16 (256 in the paper).
        norm: "batch" or "instance" (``NORMS``).
        dropout: drop probability in the three innermost decoder levels; 0 builds none.
    """

    def __init__(self, in_channels: int = 3, out_channels: int = 3, filters: int = 64, resolution: int = 256,
                 *, norm: str = "batch", dropout: float = 0.5):
        super().__init__()
        make_norm = _norm(norm, "UNetGenerator")
        if not 0.0 <= dropout < 1.0:
            raise WrinklesInputError(f"UNetGenerator: dropout must be in [0, 1), got {dropout}")
        self.in_channels, self.out_channels, self.resolution = in_channels, out_channels, resolution
        depth = unet_depth(resolution)
        ch = [filters * min(2**i, 8) for i in range(depth)]
        self.down = nn.ModuleList()
        self.up = nn.ModuleList()
        for i in range(depth):
            normed = 0 < i < depth - 1
            down: list[nn.Module] = [] if i == 0 else [nn.LeakyReLU(0.2)]
            down.append(nn.Conv2d(in_channels if i == 0 else ch[i - 1], ch[i], 4, 2, 1, bias=not normed))
            self.down.append(nn.Sequential(*down, *([make_norm(ch[i])] if normed else [])))
            up_in = ch[i] if i == depth - 1 else 2 * ch[i]
            up_out = out_channels if i == 0 else ch[i - 1]
            up: list[nn.Module] = [nn.ReLU(), nn.ConvTranspose2d(up_in, up_out, 4, 2, 1, bias=i == 0)]
            if i == 0:
                up.append(nn.Tanh())
            else:
                up.append(make_norm(up_out))
                if dropout > 0 and i >= depth - 3:
                    up.append(nn.Dropout(dropout))
            self.up.append(nn.Sequential(*up))
        self.apply(_init_pix2pix)

    def forward(self, lr: torch.Tensor) -> torch.Tensor:
        """HR map (B, out_channels, R, R) in [-1, 1] from the LR map (B, in_channels, R, R)."""
        r = self.resolution
        if lr.ndim != 4 or lr.shape[1] != self.in_channels or tuple(lr.shape[2:]) != (r, r):
            raise WrinklesInputError(f"UNetGenerator: input {tuple(lr.shape)}, expected "
                                     f"(B, {self.in_channels}, {r}, {r})")
        skips = []
        h = lr
        for level in self.down:
            h = level(h)
            skips.append(h)
        h = self.up[-1](skips[-1])
        for i in range(len(self.up) - 2, -1, -1):
            h = self.up[i](torch.cat([skips[i], h], dim=1))
        return h


def patchgan_receptive_field(layers: int) -> int:
    """Side [px] of the input patch one output of ``PatchDiscriminator(layers=layers)`` sees: two
    4x4 stride-1 convolutions, then ``layers`` 4x4 stride-2 ones walked back to the input
    (r <- 2 r + 2), which gives 16, 34, 70 px for 1, 2, 3 layers (70 is the paper's patch size)."""
    r = 1 + 3 + 3
    for _ in range(layers):
        r = 2 * r + 2
    return r


class PatchDiscriminator(nn.Module):
    """Conditional PatchGAN discriminator (Isola et al. 2017, Sec. 3.2.2; Lähner et al. Sec. 5: 70x70).

    ``layers`` 4x4 stride-2 convolutions (``filters * min(2^i, 8)`` channels), one 4x4 stride-1
    convolution, and a 4x4 stride-1 convolution to one channel: a map of logits, one per
    overlapping patch of ``patchgan_receptive_field(layers)`` px. LeakyReLU(0.2) after every
    convolution but the last, norm after every one but the first and the last.

    Args:
        in_channels: channels of the input, the LR condition and the HR map concatenated (3 + 3).
        filters: channels of the first convolution (64).
        layers: stride-2 convolutions (3 gives 70x70 patches).
        norm: "batch" or "instance" (``NORMS``).
    """

    def __init__(self, in_channels: int = 6, filters: int = 64, layers: int = 3, *, norm: str = "batch"):
        super().__init__()
        make_norm = _norm(norm, "PatchDiscriminator")
        if layers < 1:
            raise WrinklesInputError(f"PatchDiscriminator: layers must be >= 1, got {layers}")
        self.in_channels, self.layers = in_channels, layers
        net: list[nn.Module] = [nn.Conv2d(in_channels, filters, 4, 2, 1), nn.LeakyReLU(0.2)]
        c = filters
        for i in range(1, layers + 1):
            c_next = filters * min(2**i, 8)
            stride = 2 if i < layers else 1
            net += [nn.Conv2d(c, c_next, 4, stride, 1, bias=False), make_norm(c_next), nn.LeakyReLU(0.2)]
            c = c_next
        net.append(nn.Conv2d(c, 1, 4, 1, 1))
        self.net = nn.Sequential(*net)
        self.apply(_init_pix2pix)

    def forward(self, pair: torch.Tensor) -> torch.Tensor:
        """Logits (B, 1, h, w), one per patch, of the concatenated (LR, HR) maps (B, in_channels, H, W)."""
        if pair.ndim != 4 or pair.shape[1] != self.in_channels:
            raise WrinklesInputError(f"PatchDiscriminator: input {tuple(pair.shape)}, expected "
                                     f"(B, {self.in_channels}, H, W)")
        return self.net(pair)

    def patch_weights(self, mask: torch.Tensor) -> torch.Tensor:
        """Weight of each output patch (B, 1, h, w) from a coverage mask (B, 1, H, W): the largest mask
        value inside the patch's receptive field, by max-pooling with the convolutions' kernels,
        strides and paddings, so patches that see no UV chart carry no adversarial loss."""
        w = mask
        for _ in range(self.layers):
            w = F.max_pool2d(w, 4, 2, 1)
        for _ in range(2):
            w = F.max_pool2d(w, 4, 1, 1)
        return w


# --- losses ------------------------------------------------------------------------------------


def coverage_mask(mask: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """The UV coverage mask as a float tensor (B or 1, 1, H, W) in ``like``'s dtype and device.

    Args:
        mask: (H, W) or (B or 1, 1, H, W), bool or float; 1 inside a UV chart, 0 outside (fractional
            values weight pixels).
        like: a map (B, C, H, W) the mask applies to.
    """
    m = torch.as_tensor(mask, device=like.device)
    if m.ndim == 2:
        m = m[None, None]
    b, _, h, w = like.shape
    if m.ndim != 4 or m.shape[1] != 1 or m.shape[0] not in (1, b) or tuple(m.shape[2:]) != (h, w):
        raise WrinklesInputError(f"coverage mask {tuple(m.shape)} does not fit maps {tuple(like.shape)}: "
                                 f"expected ({h}, {w}) or ({b} or 1, 1, {h}, {w})")
    return m.to(like.dtype)


def _masked_mean(values: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Mean of ``values`` (B, C, H, W) over its weighted pixels and all channels, ``weights`` (B or 1,
    1, H, W): pixels of weight 0 neither add to the sum nor count in the mean."""
    b, c = values.shape[:2]
    count = weights.expand(b, 1, *values.shape[2:]).sum() * c
    return (values * weights).sum() / count.clamp_min(DENOMINATOR_FLOOR)


def data_term(gen: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Eq. 4's L_data = ||I_gen^t - I_gt^t||_1, as the mean absolute difference over the masked
    pixels and all channels (pix2pix's L1 term, which blurs less than L2).

    Args:
        gen: generated maps (B, C, H, W).
        target: ground-truth maps (B, C, H, W).
        mask: UV coverage (H, W) or (B or 1, 1, H, W) (``coverage_mask``).
    """
    return _masked_mean((gen - target).abs(), coverage_mask(mask, gen))


def _temporal_eq4(diff: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    b = diff.shape[0]
    summed = (diff * m).sum(dim=(2, 3)).abs().sum(dim=1)
    pixels = m.expand(b, 1, *diff.shape[2:]).sum(dim=(1, 2, 3))
    return (summed / pixels.clamp_min(DENOMINATOR_FLOOR)).mean()


TEMPORAL_TERMS: dict[str, Callable[[torch.Tensor, torch.Tensor], torch.Tensor]] = {
    "eq4": _temporal_eq4,
    "l1": lambda diff, m: _masked_mean(diff.abs(), m),
    "l2": lambda diff, m: _masked_mean(diff.square(), m),
}
"""Temporal consistency terms by name, (I_gen^t - I_gt^{t-1}, coverage mask) -> loss
(``temporal_term``)."""


def temporal_term(gen_t: torch.Tensor, gt_prev: torch.Tensor, mask: torch.Tensor,
                  *, kind: str = "eq4") -> torch.Tensor:
    """Temporal consistency between the generated map at t and the ground truth at t-1 (Eq. 4).

    "eq4" is Eq. 4's L_temp = |Σ_ij (I_gen^t - I_gt^{t-1})_ij|: per image and channel, the absolute
    value of the difference summed over the masked pixels, so folds that appear in one place and
    vanish close by cancel and only global fold movement is penalised (the paper's intent; it
    ignores where on the surface the changes are). The per-channel values are summed over channels
    and divided by the image's number of masked pixels, which puts the term on the scale of a per-
    pixel mean like the L1 data term (the paper leaves the normalisation unstated; an unnormalised
    sum would grow with the resolution and dwarf the other terms at the paper's weights), then
    averaged over the batch. "l1" and "l2" are the alternatives of the paper's Table 1: the mean
    absolute and mean squared difference over the masked pixels and all channels.

    Args:
        gen_t: generated maps at frame t (B, C, H, W).
        gt_prev: ground-truth maps at frame t-1 (B, C, H, W).
        mask: UV coverage (H, W) or (B or 1, 1, H, W) (``coverage_mask``).
        kind: "eq4", "l1" or "l2" (``TEMPORAL_TERMS``).
    """
    if kind not in TEMPORAL_TERMS:
        raise WrinklesInputError(f"temporal_term: kind {kind!r} is not one of {sorted(TEMPORAL_TERMS)}")
    if gen_t.shape != gt_prev.shape:
        raise WrinklesInputError(f"temporal_term: maps {tuple(gen_t.shape)} and {tuple(gt_prev.shape)} "
                                 "differ")
    return TEMPORAL_TERMS[kind](gen_t - gt_prev, coverage_mask(mask, gen_t))


def adversarial_term(scores: torch.Tensor, real: bool, patch_weights: torch.Tensor,
                     *, gan_mode: str = "vanilla") -> torch.Tensor:
    """GAN loss of discriminator outputs (B, 1, h, w) against the label ``real`` (1) or fake (0),
    averaged over the patches weighted by ``patch_weights`` (B or 1, 1, h, w)
    (``PatchDiscriminator.patch_weights``).

    Args:
        scores: discriminator outputs, logits for "vanilla".
        real: the target label.
        patch_weights: weight of each patch; 0 leaves a patch out.
        gan_mode: "vanilla" or "lsgan" (``GAN_LOSSES``).
    """
    _check_gan_mode(gan_mode)
    target = torch.full_like(scores, 1.0 if real else 0.0)
    return _masked_mean(GAN_LOSSES[gan_mode](scores, target), patch_weights)


@dataclass(frozen=True)
class CGANWeights:
    """Weights of the terms of the generator's objective (Lähner et al. Sec. 5).

    Attributes:
        data: weight of the L1 data term (100).
        temporal: weight of the temporal consistency term (50); ignored without a previous frame.
        gan: weight of the generator's adversarial term (1).
        temporal_kind: "eq4", "l1" or "l2" (``temporal_term``).
    """

    data: float = 100.0
    temporal: float = 50.0
    gan: float = 1.0
    temporal_kind: str = "eq4"

    def __post_init__(self):
        if self.temporal_kind not in TEMPORAL_TERMS:
            raise WrinklesInputError(f"CGANWeights: temporal_kind {self.temporal_kind!r} is not one of "
                                     f"{sorted(TEMPORAL_TERMS)}")
        for name in ("data", "temporal", "gan"):
            if not getattr(self, name) >= 0:
                raise WrinklesInputError(f"CGANWeights: {name} must be >= 0, got {getattr(self, name)}")


def _frozen_call(module: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """``module(x)`` with its parameters and buffers detached: gradients reach ``x`` only. Buffers
    share storage with the module's, so a batch norm's running statistics update as in a plain call."""
    state = {name: t.detach() for name, t in chain(module.named_parameters(), module.named_buffers())}
    return functional_call(module, state, (x,))


@torch.no_grad()
def _mean_score(scores: torch.Tensor, patch_weights: torch.Tensor, gan_mode: str) -> torch.Tensor:
    """Weighted mean over patches of the probability "real" (sigmoid of the logits) for "vanilla", of
    the raw score (regressed to 1 for real, 0 for fake) for "lsgan"."""
    return _masked_mean(torch.sigmoid(scores) if gan_mode == "vanilla" else scores, patch_weights)


def _check_maps(lr: torch.Tensor, hr: torch.Tensor, hr_prev: torch.Tensor | None) -> None:
    if lr.ndim != 4 or hr.ndim != 4 or lr.shape[0] != hr.shape[0] or lr.shape[2:] != hr.shape[2:]:
        raise WrinklesInputError(f"cgan_loss: LR maps {tuple(lr.shape)} and HR maps {tuple(hr.shape)} "
                                 "must be (B, C, H, W) of one batch and size")
    if hr_prev is not None and hr_prev.shape != hr.shape:
        raise WrinklesInputError(f"cgan_loss: previous HR maps {tuple(hr_prev.shape)} differ from "
                                 f"HR maps {tuple(hr.shape)}")


def cgan_loss(generator: nn.Module, discriminator: PatchDiscriminator, lr: torch.Tensor, hr: torch.Tensor,
              hr_prev: torch.Tensor | None, mask: torch.Tensor, weights: CGANWeights,
              *, gan_mode: str = "vanilla") -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """DeepWrinkles' training objective for one batch, for one optimizer over both networks.

    total = w_data L_data + w_temp L_temp + w_gan L_GAN(G) + L_GAN(D), where
    L_GAN(G) = GAN(D(LR, G(LR)), real) reaches the discriminator with its parameters and buffers
    detached, so it gives the discriminator no gradient, and L_GAN(D) = 0.5 (GAN(D(LR, HR), real) +
    GAN(D(LR, G(LR) detached), fake)) (pix2pix halves it to slow the discriminator) sees the
    generated map detached, so it gives the generator no gradient. Each network's gradient of the
    total is therefore its own objective's, and one backward pass and optimizer step update both
    (simultaneously, where pix2pix alternates).

    The discriminator sees both maps multiplied by the coverage mask and its patches are weighted by
    ``PatchDiscriminator.patch_weights``: outside the UV charts real and generated maps are equal,
    so no term depends on what the generator puts there.

    Args:
        generator: maps LR (B, 3, H, W) to HR (B, 3, H, W) (``UNetGenerator``).
        discriminator: a ``PatchDiscriminator`` over (LR, HR) concatenated.
        lr: LR normal maps at frame t (B, 3, H, W) in [-1, 1].
        hr: ground-truth HR normal maps at frame t (B, 3, H, W).
        hr_prev: ground-truth HR maps at frame t-1 (B, 3, H, W), or None (no temporal term).
        mask: UV coverage (H, W) or (B or 1, 1, H, W) (``coverage_mask``).
        weights: term weights (``CGANWeights``).
        gan_mode: "vanilla" or "lsgan" (``GAN_LOSSES``).

    Returns:
        The total (0-d, differentiable) and detached 0-d scalars: "data", "temporal", "gan_g",
        "gan_d", and "d_real" / "d_fake", the discriminator's mean probability of "real" on the
        ground-truth and generated maps (mean raw score for "lsgan").
    """
    _check_gan_mode(gan_mode)
    _check_maps(lr, hr, hr_prev)
    fake = generator(lr)
    if fake.shape != hr.shape:
        raise WrinklesInputError(f"cgan_loss: generated maps {tuple(fake.shape)} differ from HR maps "
                                 f"{tuple(hr.shape)}")
    m = coverage_mask(mask, hr)
    data = data_term(fake, hr, m)
    temporal = (fake.new_zeros(()) if hr_prev is None
                else temporal_term(fake, hr_prev, m, kind=weights.temporal_kind))
    patches = discriminator.patch_weights(m)
    real_pair = torch.cat([lr, hr], dim=1) * m
    fake_pair = torch.cat([lr, fake], dim=1) * m
    gan_g = adversarial_term(_frozen_call(discriminator, fake_pair), True, patches, gan_mode=gan_mode)
    real_scores = discriminator(real_pair)
    fake_scores = discriminator(fake_pair.detach())
    gan_d = 0.5 * (adversarial_term(real_scores, True, patches, gan_mode=gan_mode)
                   + adversarial_term(fake_scores, False, patches, gan_mode=gan_mode))
    total = weights.data * data + weights.gan * gan_g + gan_d
    if hr_prev is not None:
        total = total + weights.temporal * temporal
    scalars = {"data": data.detach(), "temporal": temporal.detach(), "gan_g": gan_g.detach(),
               "gan_d": gan_d.detach(), "d_real": _mean_score(real_scores, patches, gan_mode),
               "d_fake": _mean_score(fake_scores, patches, gan_mode)}
    return total, scalars
