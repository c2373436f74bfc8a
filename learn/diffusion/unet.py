"""The noise-prediction U-Net ``eps_theta(x_t, t; c)`` of the wrinkle diffusion model.

Guo et al. 2024 Sec. 3.2 and 4.1: a U-Net (Ronneberger et al. 2015) over a 256 x 256 UV image that
holds the noisy wrinkle field (3 channels: displacement in the base surface's local frame) and
the conditioning maps (strain norm and the UV chart mask by default; the ablation variants
"surface normal" (3), "strain tensor" (3), "strain norm" (1) change ``cond_channels``).
Sec. 4.4: classifier-free guidance (Ho & Salimans 2022) on a fabric-material label.

Architecture (ADM-like, Dhariwal & Nichol 2021, simplified): sinusoidal timestep embedding +
MLP; per resolution level ``num_res_blocks`` residual blocks with GroupNorm + SiLU and a
timestep FiLM (scale/shift after the second GroupNorm); optional self-attention on chosen levels
and in the middle; one skip connection per level; nearest upsampling + conv; zero-initialised
output convolution so the untrained network predicts ``eps = 0``.

The network never owns its noise schedule (ARCHITECTURE.md); see ``scheduler.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn


@dataclass(frozen=True)
class UNetConfig:
    """Shape and width of :class:`WrinkleUNet`. Defaults: 9,978,883 parameters (~20 MB in fp16).

    At 256 x 256 the default levels run at 256, 128, 64, 32, 16, 8 pixels with widths 64, 64, 128,
    128, 128, 128 and attention at 16 x 16 and 8 x 8.
    """

    in_channels: int = 3
    """Channels of the noisy sample ``x_t`` (wrinkle displacement, local frame)."""
    cond_channels: int = 2
    """Channels of the conditioning maps (default: strain norm 1 + mask 1)."""
    out_channels: int = 3
    """Channels of the prediction ``eps``."""
    base_channels: int = 64
    """Width of the first level; level ``i`` has ``base_channels * channel_mult[i]``."""
    channel_mult: tuple[int, ...] = (1, 1, 2, 2, 2, 2)
    """One multiplier per resolution level; the image is halved between levels, so H and W must be
    divisible by ``2 ** (len(channel_mult) - 1)`` (32 for the default: 256 -> 8 at the bottom)."""
    num_res_blocks: int = 2
    """Residual blocks per level on the way down (and on the way up)."""
    attention_levels: tuple[int, ...] = (4, 5)
    """Level indices (0 = full resolution) with self-attention after each residual block."""
    mid_attention: bool = True
    """Self-attention in the middle block (lowest resolution)."""
    num_heads: int = 4
    """Attention heads (channels per head = level width / num_heads)."""
    norm_groups: int = 32
    """GroupNorm groups; every level width must be divisible by it."""
    dropout: float = 0.0
    """Dropout inside residual blocks."""
    num_labels: int = 0
    """Material labels for classifier-free guidance (Guo et al. Sec. 4.4); 0 disables labels. The
    embedding has ``num_labels + 1`` rows, the last being the "no label" (null) token."""

    def __post_init__(self) -> None:
        if min(self.in_channels, self.out_channels, self.base_channels) < 1 or self.cond_channels < 0:
            raise ValueError(f"UNetConfig: channel counts must be positive, got {self}")
        if not self.channel_mult or min(self.channel_mult) < 1:
            raise ValueError(f"UNetConfig.channel_mult must be non-empty, positive: {self.channel_mult}")
        for w in (self.base_channels * m for m in self.channel_mult):
            if w % self.norm_groups or w % self.num_heads:
                raise ValueError(
                    f"UNetConfig: level width {w} must be divisible by norm_groups={self.norm_groups} "
                    f"and num_heads={self.num_heads}"
                )
        bad = [i for i in self.attention_levels if not 0 <= i < len(self.channel_mult)]
        if bad:
            raise ValueError(f"UNetConfig.attention_levels {bad} outside [0, {len(self.channel_mult)})")
        if self.num_labels < 0 or self.num_res_blocks < 1:
            raise ValueError("UNetConfig: num_labels must be >= 0 and num_res_blocks >= 1")

    @property
    def downsample_factor(self) -> int:
        return 2 ** (len(self.channel_mult) - 1)


def timestep_embedding(t: torch.Tensor, dim: int, *, max_period: float = 10000.0) -> torch.Tensor:
    """Sinusoidal embedding of (possibly fractional) timesteps (Vaswani et al. 2017; Ho et al. 2020).

    Args:
        t: timesteps, shape (B,).
        dim: embedding width (even).

    Returns:
        ``[cos(t w_k), sin(t w_k)]`` with ``w_k = max_period^(-k / (dim/2))``, float32, shape (B, dim).
    """
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, dtype=torch.float32, device=t.device) / half)
    args = t.float()[:, None] * freqs[None]
    emb = torch.cat([torch.cos(args), torch.sin(args)], dim=-1)
    if dim % 2:
        emb = F.pad(emb, (0, 1))
    return emb


class ResBlock(nn.Module):
    """GroupNorm-SiLU-Conv, timestep FiLM ``h = GN(h) (1 + scale) + shift``, SiLU-Dropout-Conv, + skip."""

    def __init__(self, c_in: int, c_out: int, emb_dim: int, *, groups: int, dropout: float):
        super().__init__()
        self.norm1 = nn.GroupNorm(_groups(c_in, groups), c_in)
        self.conv1 = nn.Conv2d(c_in, c_out, 3, padding=1)
        self.film = nn.Linear(emb_dim, 2 * c_out)
        self.norm2 = nn.GroupNorm(groups, c_out)
        self.dropout = nn.Dropout(dropout)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1)
        self.skip = nn.Conv2d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, emb: torch.Tensor) -> torch.Tensor:
        h = self.conv1(F.silu(self.norm1(x)))
        scale, shift = self.film(F.silu(emb))[:, :, None, None].chunk(2, dim=1)
        h = self.norm2(h) * (1.0 + scale) + shift
        h = self.conv2(self.dropout(F.silu(h)))
        return self.skip(x) + h


class AttentionBlock(nn.Module):
    """Multi-head self-attention over the pixels of a feature map, with a residual connection."""

    def __init__(self, channels: int, *, num_heads: int, groups: int):
        super().__init__()
        self.num_heads = num_heads
        self.norm = nn.GroupNorm(groups, channels)
        self.qkv = nn.Conv2d(channels, 3 * channels, 1)
        self.proj = nn.Conv2d(channels, channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, C, H, W = x.shape
        q, k, v = self.qkv(self.norm(x)).reshape(B, 3, self.num_heads, C // self.num_heads, H * W).unbind(1)
        h = F.scaled_dot_product_attention(q.transpose(-1, -2), k.transpose(-1, -2), v.transpose(-1, -2))
        return x + self.proj(h.transpose(-1, -2).reshape(B, C, H, W))


def _groups(channels: int, groups: int) -> int:
    """``groups`` when it divides ``channels`` (the concatenated up-path inputs), else their gcd."""
    return groups if channels % groups == 0 else math.gcd(channels, groups)


def _attention(channels: int, cfg: UNetConfig) -> AttentionBlock:
    return AttentionBlock(channels, num_heads=cfg.num_heads, groups=cfg.norm_groups)


class _Level(nn.Module):
    """Residual blocks (each optionally followed by attention) at one resolution."""

    def __init__(self, c_in: int, c_out: int, n: int, emb_dim: int, cfg: UNetConfig, attention: bool):
        super().__init__()
        self.blocks = nn.ModuleList(
            ResBlock(c_in if i == 0 else c_out, c_out, emb_dim, groups=cfg.norm_groups, dropout=cfg.dropout)
            for i in range(n)
        )
        self.attn = nn.ModuleList(_attention(c_out, cfg) if attention else nn.Identity() for _ in range(n))

    def forward(self, x: torch.Tensor, emb: torch.Tensor) -> torch.Tensor:
        for block, attn in zip(self.blocks, self.attn, strict=True):
            x = attn(block(x, emb))
        return x


class WrinkleUNet(nn.Module):
    """``eps_theta(x_t, t; c, label)``: predicts the noise of a UV wrinkle image (Guo et al. Eq. 7).

    Args:
        config: a :class:`UNetConfig`.
    """

    def __init__(self, config: UNetConfig | None = None):
        super().__init__()
        cfg = self.config = config or UNetConfig()
        ch = cfg.base_channels
        emb_dim = 4 * ch
        self.time_mlp = nn.Sequential(nn.Linear(ch, emb_dim), nn.SiLU(), nn.Linear(emb_dim, emb_dim))
        self.label_embedding = nn.Embedding(cfg.num_labels + 1, emb_dim) if cfg.num_labels > 0 else None
        self.conv_in = nn.Conv2d(cfg.in_channels + cfg.cond_channels, ch, 3, padding=1)

        widths = [ch * m for m in cfg.channel_mult]
        self.down = nn.ModuleList()
        self.downsample = nn.ModuleList()
        c = ch
        for i, w in enumerate(widths):
            self.down.append(_Level(c, w, cfg.num_res_blocks, emb_dim, cfg, i in cfg.attention_levels))
            last = i == len(widths) - 1
            self.downsample.append(nn.Identity() if last else nn.Conv2d(w, w, 3, stride=2, padding=1))
            c = w
        self.mid1 = ResBlock(c, c, emb_dim, groups=cfg.norm_groups, dropout=cfg.dropout)
        self.mid2 = ResBlock(c, c, emb_dim, groups=cfg.norm_groups, dropout=cfg.dropout)
        self.mid_attn = _attention(c, cfg) if cfg.mid_attention else nn.Identity()
        self.up = nn.ModuleList()
        self.upsample = nn.ModuleList()
        for i in reversed(range(len(widths))):
            w = widths[i]
            self.up.append(_Level(c + w, w, cfg.num_res_blocks, emb_dim, cfg, i in cfg.attention_levels))
            self.upsample.append(nn.Conv2d(w, w, 3, padding=1) if i > 0 else nn.Identity())
            c = w
        self.norm_out = nn.GroupNorm(cfg.norm_groups, c)
        self.conv_out = nn.Conv2d(c, cfg.out_channels, 3, padding=1)
        nn.init.zeros_(self.conv_out.weight)  # untrained net predicts eps = 0
        nn.init.zeros_(self.conv_out.bias)

    @property
    def out_channels(self) -> int:
        return self.config.out_channels

    @property
    def null_label(self) -> int:
        """Index of the "no label" row used for the unconditional pass of classifier-free guidance."""
        return self.config.num_labels

    def forward(
        self,
        x_t: torch.Tensor,
        t: torch.Tensor,
        cond: torch.Tensor | None,
        label: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Predict the noise.

        Args:
            x_t: noisy wrinkle field, shape (B, in_channels, H, W); H, W divisible by
                ``config.downsample_factor``.
            t: timesteps in ``[0, T)``, shape (B,) (int or float).
            cond: conditioning maps (strain norm, mask, ...), shape (B, cond_channels, H, W); None
                only when ``cond_channels == 0``.
            label: material labels in ``[0, num_labels]`` (``num_labels`` = no label), int64,
                shape (B,); None means "no label" for every sample. Must be None when
                ``num_labels == 0``.

        Returns:
            eps, shape (B, out_channels, H, W), dtype of ``x_t``.
        """
        cfg = self.config
        B, C, H, W = x_t.shape
        if C != cfg.in_channels:
            raise ValueError(f"x_t has {C} channels, the model expects in_channels={cfg.in_channels}")
        f = cfg.downsample_factor
        if H % f or W % f:
            raise ValueError(f"image size {H}x{W} must be divisible by {f} (2 ** (len(channel_mult) - 1))")
        if cfg.cond_channels:
            if cond is None or cond.shape != (B, cfg.cond_channels, H, W):
                got = None if cond is None else tuple(cond.shape)
                raise ValueError(f"cond must have shape {(B, cfg.cond_channels, H, W)}, got {got}")
            x = torch.cat([x_t, cond.to(x_t.dtype)], dim=1)
        else:
            x = x_t
        t = torch.as_tensor(t, device=x_t.device)
        if t.ndim == 0:
            t = t.expand(B)
        emb = self.time_mlp(timestep_embedding(t, cfg.base_channels).to(x_t.dtype))
        if self.label_embedding is not None:
            if label is None:
                label = torch.full((B,), self.null_label, dtype=torch.long, device=x_t.device)
            emb = emb + self.label_embedding(label.to(x_t.device).long())
        elif label is not None:
            raise ValueError("label given but the model was built with num_labels=0")

        h = self.conv_in(x)
        skips = []
        for level, down in zip(self.down, self.downsample, strict=True):
            h = level(h, emb)
            skips.append(h)
            h = down(h)
        h = self.mid2(self.mid_attn(self.mid1(h, emb)), emb)
        for level, up in zip(self.up, self.upsample, strict=True):
            h = level(torch.cat([h, skips.pop()], dim=1), emb)
            if not isinstance(up, nn.Identity):
                h = up(F.interpolate(h, scale_factor=2.0, mode="nearest"))
        return self.conv_out(F.silu(self.norm_out(h)))


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
