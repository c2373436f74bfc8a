"""Strain-conditioned wrinkle diffusion (Guo et al. 2024, Sec. 3.2, 4.1, 4.3, 4.4) as a method.

Data: one item is one frame of a sequence with UV images (``sim.datasets.schema``): the wrinkle
field ``images/wrinkle`` (``x_0``, the fine surface over its base in the base's local frame,
metres, divided by a per-channel scale fitted on the training split) and conditioning maps of
the *base* surface — the strain norm (``images/strain_norm``, the paper's choice), the strain
tensor (E11, E22, E12 in UV-aligned frames) or the base normals (the ablation variants; both
made from ``fine/base`` by :class:`sim.geometry.wrinkle_maps.WrinkleMaps` when the dataset is
opened) — each standardised with training statistics, plus the UV mask as one more channel.
The material is a class label for classifier-free guidance (Sec. 4.4), dropped to the null label
with probability ``label_dropout`` in training.

Loss: Eq. 7, ``|eps - eps_theta(sqrt(a_t) x_0 + sqrt(1 - a_t) eps, t, c)|^2`` averaged over the
pixels inside the UV charts (outside, ``x_0 = 0`` and the map is never read).

Inference (``predict_sequence``, ``sample_wrinkles``): DDIM (S steps, eta) from the base surface
of every frame; the generated map is decoded onto the base (``WrinkleMaps.decode``). Temporal
coherence (the paper is per frame): every frame of a sequence starts from the same ``x_T``
(``shared_noise``) and, while the sample is still coarse, each frame's estimate of ``x_0`` is
pulled toward its neighbours' (and, for a chunk's first frame, toward the previous chunk's last
result) with weight ``temporal_weight * t / T`` (``learn.diffusion.sampling.ddim_sample``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch

from learn.methods.base import LossOutput, Method, Prediction
from sim.errors import WrinklesInputError
from sim.geometry.wrinkle_maps import CONDITIONINGS


@dataclass(frozen=True)
class WrinkleDiffusionConfig:
    """Data, network and sampling settings of the wrinkle diffusion model."""

    conditioning: str = "strain_norm"
    """Conditioning maps: "strain_norm" (Guo et al.), "strain_tensor" or "normal" (ablation)."""
    garments: tuple[str, ...] = ()
    """Garment categories to train on (empty: all in the dataset)."""
    materials: tuple[str, ...] = ()
    """Material labels for guidance, in label order (empty: the training split's, sorted)."""
    label_dropout: float = 0.1
    """Probability of training with the null label (classifier-free guidance)."""
    guidance_scale: float = 1.0
    """Classifier-free guidance scale at sampling (1: the conditional model alone)."""
    sample_steps: int = 50
    """DDIM steps S at sampling (Guo et al.: 50)."""
    eta: float = 0.0
    """DDIM eta at sampling (0: deterministic)."""
    shared_noise: bool = True
    """All frames of a sequence start from one x_T (temporal coherence)."""
    temporal_weight: float = 0.5
    """Pull of each frame's x_0 estimate toward its neighbours', scaled by t / T (0: off)."""
    clip_x0: float = 1.0
    """Clamp the x_0 estimate at every DDIM step to this times the training split's largest
    |wrinkle| per channel (0: off)."""
    infer_batch: int = 8
    """Frames sampled together at inference."""
    base_channels: int = 64
    """U-Net width of the first level."""
    channel_mult: tuple[int, ...] = (1, 1, 2, 2, 2, 2)
    """U-Net width multipliers per level (the image side must be divisible by 2^(levels - 1))."""
    num_res_blocks: int = 2
    """Residual blocks per U-Net level."""
    attention_levels: tuple[int, ...] = (4, 5)
    """U-Net levels with self-attention (0 = full resolution)."""
    dropout: float = 0.0
    """Dropout in the residual blocks."""
    stats_frames: int = 512
    """Training frames (evenly spread) that the normalisation statistics are fitted on."""


def _unet_config(cfg: WrinkleDiffusionConfig, num_labels: int):
    from learn.diffusion.unet import UNetConfig

    return UNetConfig(
        in_channels=3,
        cond_channels=CONDITIONINGS[cfg.conditioning] + 1,
        out_channels=3,
        base_channels=cfg.base_channels,
        channel_mult=tuple(cfg.channel_mult),
        num_res_blocks=cfg.num_res_blocks,
        attention_levels=tuple(cfg.attention_levels),
        dropout=cfg.dropout,
        num_labels=num_labels,
    )


class _Frames(torch.utils.data.Dataset):
    """Frames of the training split with their conditioning maps (see the module docstring)."""

    def __init__(self, method: WrinkleDiffusionMethod, root):
        from learn.data import GarmentSequenceDataset

        cfg = method.config
        keys = ["images/wrinkle", "images/mask"]
        if cfg.conditioning == "strain_norm":
            keys.append("images/strain_norm")
        self.ds = GarmentSequenceDataset(root, "train", keys=keys, garments=cfg.garments or None)
        self.method = method
        self.label = {
            sid: method.label_of(self.ds.entries[sid].get("material")) for sid in self.ds.sequence_ids
        }
        self.cond: dict[str, np.ndarray] = {}
        if cfg.conditioning != "strain_norm":  # made once, up front (before workers fork)
            for sid in self.ds.sequence_ids:
                self.cond[sid] = method.sequence_conditioning(self.ds.open_sequence(sid))

    def __len__(self) -> int:
        return len(self.ds)

    def __getitem__(self, key) -> dict:
        index, _seed = key
        sid, t = self.ds.locate(index)
        f = self.ds.open_sequence(sid)
        cond = self.cond[sid][t] if sid in self.cond else np.asarray(f["images/strain_norm"][t], np.float32)
        x0, c = self.method.normalise(
            np.asarray(f["images/wrinkle"][t], np.float32), cond, np.asarray(f["images/mask"])
        )
        return {
            "x0": torch.from_numpy(x0),
            "cond": torch.from_numpy(c),
            "label": torch.tensor(self.label[sid], dtype=torch.long),
        }


class WrinkleDiffusionMethod(Method):
    """Guo et al. 2024's wrinkle generator (see the module docstring)."""

    name = "wrinkle_diffusion"
    Config = WrinkleDiffusionConfig

    @classmethod
    def validate_config(cls, config: WrinkleDiffusionConfig, err) -> None:
        if config.conditioning not in CONDITIONINGS:
            raise err(f"conditioning must be one of {', '.join(CONDITIONINGS)}, got {config.conditioning!r}")
        if not 0.0 <= config.label_dropout < 1.0:
            raise err(f"label_dropout must be in [0, 1), got {config.label_dropout}")
        if config.sample_steps < 1 or config.infer_batch < 1 or config.stats_frames < 1:
            raise err("sample_steps, infer_batch and stats_frames must be >= 1")
        if min(config.eta, config.temporal_weight, config.guidance_scale, config.clip_x0) < 0:
            raise err("eta, temporal_weight, guidance_scale and clip_x0 must be >= 0")

    # ------------------------------------------------------------------ fitted state
    def prepare(self, root) -> dict:
        """Label vocabulary, image size and normalisation statistics of the training split."""
        from learn.data import GarmentSequenceDataset

        cfg = self.config
        ds = GarmentSequenceDataset(
            root, "train", keys=["images/wrinkle", "images/mask"], garments=cfg.garments or None
        )
        if len(ds) == 0:
            raise WrinklesInputError("no training frames with UV images", path=ds.root)
        materials = list(cfg.materials) or sorted(
            {str(ds.entries[s].get("material")) for s in ds.sequence_ids}
        )
        pick = np.unique(np.linspace(0, len(ds) - 1, min(cfg.stats_frames, len(ds))).round().astype(int))
        by_seq: dict[str, list[int]] = {}
        for i in pick:
            sid, t = ds.locate(int(i))
            by_seq.setdefault(sid, []).append(t)
        w_sum, w_sq, c_sum, c_sq, n = 0.0, 0.0, 0.0, 0.0, 0
        w_max = np.zeros(3)
        for sid, ts in by_seq.items():
            f = ds.open_sequence(sid)
            m = np.asarray(f["images/mask"]).astype(bool)
            w = np.asarray(f["images/wrinkle"][ts], np.float64)[:, m]  # (k, P, 3)
            c = self._conditioning_frames(f, ts)[:, m].astype(np.float64)
            w_sum, w_sq = w_sum + w.sum((0, 1)), w_sq + (w * w).sum((0, 1))
            w_max = np.maximum(w_max, np.abs(w).max((0, 1)) if w.size else 0.0)
            c_sum, c_sq = c_sum + c.sum((0, 1)), c_sq + (c * c).sum((0, 1))
            n += w.shape[0] * w.shape[1]
        w_std = np.sqrt(np.maximum(w_sq / n - (w_sum / n) ** 2, 1e-14))
        c_mean = c_sum / n
        c_std = np.sqrt(np.maximum(c_sq / n - c_mean**2, 1e-12))
        H, W = np.asarray(ds.open_sequence(ds.sequence_ids[0])["images/mask"]).shape
        fac = _unet_config(cfg, 0).downsample_factor
        if H % fac or W % fac:
            raise WrinklesInputError(
                f"UV images of {H}x{W} px: the U-Net needs sides divisible by {fac} "
                "(generate the dataset with another derive.image_resolution or use "
                "fewer channel_mult levels)",
                path=ds.root,
            )
        return {
            "materials": materials,
            "resolution": int(H),
            "wrinkle_std": torch.tensor(w_std, dtype=torch.float32),
            # per-channel bound of the sampled x0 (in std units): the largest |wrinkle| seen
            "wrinkle_clip": torch.tensor(w_max / w_std, dtype=torch.float32),
            "cond_mean": torch.tensor(c_mean, dtype=torch.float32),
            "cond_std": torch.tensor(c_std, dtype=torch.float32),
        }

    def _conditioning_frames(self, f, ts, maps=None) -> np.ndarray:
        """Conditioning maps of frames ``ts`` of a sequence file, (len(ts), H, W, C); ``maps``: the
        sequence's ``WrinkleMaps`` when the caller already has them."""
        if self.config.conditioning == "strain_norm":
            return np.asarray(f["images/strain_norm"][ts], np.float32)
        if maps is None:
            from sim.geometry.wrinkle_maps import WrinkleMaps

            maps = WrinkleMaps.from_sequence(f, np.asarray(f["images/mask"]).shape[0])
        return maps.conditioning(np.asarray(f["fine/base"][ts], np.float32), self.config.conditioning)

    def sequence_conditioning(self, f) -> np.ndarray:
        """Conditioning maps of every frame of a sequence file, (T, H, W, C) float16 (operators
        built once, frames in chunks of 64)."""
        from sim.geometry.wrinkle_maps import WrinkleMaps

        maps = WrinkleMaps.from_sequence(f, np.asarray(f["images/mask"]).shape[0])
        T = f.shape("fine/base")[0]
        chunks = [range(s, min(s + 64, T)) for s in range(0, T, 64)]
        parts = [self._conditioning_frames(f, list(c), maps).astype(np.float16) for c in chunks]
        return np.concatenate(parts)

    @property
    def materials(self) -> list[str]:
        return list(self.state["materials"])

    def label_of(self, material: str | None) -> int:
        """Label index of a material name; the null label for an unknown one."""
        m = self.materials
        return m.index(material) if material in m else len(m)

    def normalise(self, wrinkle: np.ndarray | None, cond: np.ndarray, mask: np.ndarray):
        """Network inputs: ``x0`` (3, H, W) (None without ``wrinkle``) and conditioning
        (C + 1, H, W) from maps (H, W, 3), (H, W, C) and the mask (H, W)."""
        m = np.asarray(mask, np.float32)[..., None]
        c = (np.asarray(cond, np.float32) - self.state["cond_mean"].numpy()) / self.state["cond_std"].numpy()
        c = np.concatenate([c * m, m], axis=-1).transpose(2, 0, 1)
        x0 = None
        if wrinkle is not None:
            x0 = (np.asarray(wrinkle, np.float32) / self.state["wrinkle_std"].numpy() * m).transpose(2, 0, 1)
            x0 = np.ascontiguousarray(x0)
        return x0, np.ascontiguousarray(c, dtype=np.float32)

    # ------------------------------------------------------------------ model, data, loss
    def build_model(self) -> torch.nn.Module:
        from learn.diffusion.unet import WrinkleUNet

        if not self.state:
            raise ValueError("wrinkle_diffusion: prepare() or load_state() before build_model()")
        return WrinkleUNet(_unet_config(self.config, len(self.materials)))

    def train_dataset(self, root) -> torch.utils.data.Dataset:
        return _Frames(self, root)

    def training_loss(self, model, batch, generator: torch.Generator) -> LossOutput:
        from learn.diffusion.scheduler import DDPMScheduler

        x0, cond, label = batch["x0"], batch["cond"], batch["label"]
        B = x0.shape[0]
        sched = DDPMScheduler()
        t = sched.sample_timesteps(B, generator=generator, device=x0.device)
        noise = torch.randn(x0.shape, generator=generator, device=generator.device).to(x0.device)
        drop = (
            torch.rand(B, generator=generator, device=generator.device).to(x0.device)
            < self.config.label_dropout
        )
        null = len(self.materials)
        label = torch.where(drop, torch.full_like(label, null), label)
        eps = model(sched.add_noise(x0, noise, t), t, cond, label)
        mask = cond[:, -1:]
        err = ((eps.float() - noise) ** 2 * mask).sum() / (3.0 * mask.sum()).clamp_min(1.0)
        return LossOutput(err, {"eps_mse": err.detach()})

    # ------------------------------------------------------------------ inference
    def sample_wrinkles(
        self,
        model,
        cond_maps: np.ndarray,
        mask: np.ndarray,
        *,
        material: str | None = None,
        device: torch.device | str = "cpu",
        steps: int | None = None,
        guidance_scale: float | None = None,
        seed: int = 0,
        progress=None,
    ) -> np.ndarray:
        """Wrinkle maps [m] (T, H, W, 3) for conditioning maps (T, H, W, C) of a sequence's base.

        Args:
            model: the trained U-Net (eval mode).
            cond_maps: conditioning maps of this method's kind, unnormalised.
            mask: UV mask (H, W).
            material: material label (None or unknown: the null label).
            device: where to run.
            steps: DDIM steps (default ``config.sample_steps``).
            guidance_scale: default ``config.guidance_scale``.
            seed: seed of the initial noise.
            progress: called as ``progress(frames_done, frames_total)``.
        """
        from learn.diffusion.sampling import ddim_sample
        from learn.diffusion.scheduler import DDIMScheduler, DDPMScheduler

        cfg = self.config
        device = torch.device(device)
        if device.type == "cpu":
            # channels-last convolutions: 111 against 144 ms per 128² frame and step on a 2-core
            # EPYC (torch 2.13, docs/DECISIONS.md)
            model = model.to(memory_format=torch.channels_last)
        steps = steps or cfg.sample_steps
        scale = cfg.guidance_scale if guidance_scale is None else guidance_scale
        T = len(cond_maps)
        H, W = np.asarray(mask).shape
        sched = DDIMScheduler.from_ddpm(DDPMScheduler())
        gen = torch.Generator(device=device).manual_seed(int(seed))
        shared = torch.randn((3, H, W), generator=gen, device=device) if cfg.shared_noise else None
        label = self.label_of(material)
        std = self.state["wrinkle_std"].to(device)
        clip = None  # a checkpoint without a fitted bound samples unclamped
        if cfg.clip_x0 > 0 and "wrinkle_clip" in self.state:
            clip = (self.state["wrinkle_clip"] * cfg.clip_x0).to(device)
        mask_t = torch.from_numpy(np.asarray(mask, np.float32)).to(device)
        out = np.empty((T, H, W, 3), np.float32)
        anchor = None
        dtype = next(model.parameters()).dtype
        for s in range(0, T, cfg.infer_batch):
            chunk = [self.normalise(None, c, mask)[1] for c in cond_maps[s : s + cfg.infer_batch]]
            cond = torch.from_numpy(np.stack(chunk)).to(device, dtype)
            B = cond.shape[0]
            x0 = ddim_sample(
                model,
                sched,
                cond,
                label=torch.full((B,), label, dtype=torch.long, device=device),
                guidance_scale=scale if label < len(self.materials) else 1.0,
                num_steps=steps,
                eta=cfg.eta,
                generator=gen,
                initial_noise=None if shared is None else shared.to(dtype),
                mask=mask_t.expand(B, H, W),
                temporal_weight=cfg.temporal_weight,
                anchor=anchor,
                clip_x0=clip,
            )
            anchor = x0[-1]
            out[s : s + B] = (x0.float() * std[:, None, None]).permute(0, 2, 3, 1).cpu().numpy()
            if progress is not None:
                progress(s + B, T)
        return out

    def predict_sequence(
        self,
        model,
        sequence: Mapping[str, np.ndarray],
        *,
        device: torch.device,
        steps: int | None = None,
        seed: int = 0,
        base: np.ndarray | None = None,
    ) -> Prediction:
        """Wrinkles generated on the sequence's ground-truth base surface (``fine/base``), or on
        ``base`` (T, V, 3) [m] when given (e.g. a coarse model's); decoded onto it."""
        from sim.geometry.wrinkle_maps import WrinkleMaps

        res = int(self.state["resolution"])
        maps = WrinkleMaps.from_sequence(sequence, res)
        b = np.asarray(sequence["fine/base"] if base is None else base, np.float32)
        cond = maps.conditioning(b, self.config.conditioning)
        meta = sequence.get("material")
        material = None if meta is None else str(np.asarray(meta))
        w = self.sample_wrinkles(
            model, cond, maps.mask, material=material, device=device, steps=steps, seed=seed
        )
        return Prediction(maps.decode(w, b), {"wrinkle_maps": w})
