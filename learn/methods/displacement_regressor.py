"""LFGD-style baseline: wrinkles as world-frame displacements regressed from the base surface.

Guo et al. 2024 compare against LFGD, whose high-frequency component "represents the wrinkle
details as vertex displacement in the global coordinate frame, making it difficult to generalize
to unseen coarse deformation" (Sec. 4.3). This baseline keeps exactly that representation and
changes nothing else: the same U-Net (``learn.diffusion.unet.WrinkleUNet`` at a fixed timestep 0,
no noise, one forward pass) maps UV images of the base — its positions in the body's root frame
and its unit normals, both world-oriented, plus the mask — to the displacement ``fine - base`` in
world coordinates (``WrinkleMaps.displacement``), trained with the masked mean squared error and
decoded by adding the sampled displacement to the base (``WrinkleMaps.decode_global``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch

from learn.methods.base import LossOutput, Method, Prediction
from sim.errors import WrinklesInputError


@dataclass(frozen=True)
class DisplacementRegressorConfig:
    """Data and network settings of the world-frame displacement regressor."""

    garments: tuple[str, ...] = ()
    """Garment categories to train on (empty: all in the dataset)."""
    base_channels: int = 64
    """U-Net width of the first level."""
    channel_mult: tuple[int, ...] = (1, 1, 2, 2, 2, 2)
    """U-Net width multipliers per level."""
    num_res_blocks: int = 2
    """Residual blocks per U-Net level."""
    attention_levels: tuple[int, ...] = (4, 5)
    """U-Net levels with self-attention."""
    infer_batch: int = 8
    """Frames per forward pass at inference."""


def _maps(f, ts, res: int):
    from sim.geometry.wrinkle_maps import WrinkleMaps

    wm = WrinkleMaps.from_sequence(f, res)
    base = np.asarray(f["fine/base"][ts], np.float32)
    inputs = np.concatenate(
        [wm.positions(base, np.asarray(f["body/trans"][ts], np.float32)), wm.conditioning(base, "normal")],
        axis=-1,
    )
    return wm, inputs


class _Frames(torch.utils.data.Dataset):
    def __init__(self, method: DisplacementRegressorMethod, root):
        from learn.data import GarmentSequenceDataset

        self.method = method
        self.ds = GarmentSequenceDataset(
            root, "train", keys=["images/mask"], garments=method.config.garments or None
        )
        res = int(method.state["resolution"])
        self.data = {}
        for sid in self.ds.sequence_ids:  # made once, up front (before workers fork)
            f = self.ds.open_sequence(sid)
            ts = np.arange(f.shape("fine/base")[0])
            wm, inputs = _maps(f, ts, res)
            disp = wm.displacement(
                np.asarray(f["fine/vertices"], np.float32), np.asarray(f["fine/base"], np.float32)
            )
            self.data[sid] = (inputs.astype(np.float16), disp.astype(np.float16), wm.mask)

    def __len__(self) -> int:
        return len(self.ds)

    def __getitem__(self, key) -> dict:
        index, _seed = key
        sid, t = self.ds.locate(index)
        inputs, disp, mask = self.data[sid]
        x, c = self.method.normalise(inputs[t], mask)
        y = disp[t].astype(np.float32) / self.method.state["disp_std"].numpy() * mask[..., None]
        return {
            "cond": torch.from_numpy(c),
            "target": torch.from_numpy(np.ascontiguousarray(y.transpose(2, 0, 1))),
        }


class DisplacementRegressorMethod(Method):
    """The LFGD-style global displacement baseline (see the module docstring)."""

    name = "displacement_regressor"
    Config = DisplacementRegressorConfig

    def prepare(self, root) -> dict:
        from learn.data import GarmentSequenceDataset

        ds = GarmentSequenceDataset(
            root, "train", keys=["images/mask"], garments=self.config.garments or None
        )
        if len(ds) == 0:
            raise WrinklesInputError("no training frames with UV images", path=ds.root)
        res = int(np.asarray(ds.open_sequence(ds.sequence_ids[0])["images/mask"]).shape[0])
        i_sum = i_sq = d_sq = 0.0
        n = 0
        for sid in ds.sequence_ids[:: max(1, len(ds.sequence_ids) // 16)]:
            f = ds.open_sequence(sid)
            T = f.shape("fine/base")[0]
            ts = np.unique(np.linspace(0, T - 1, min(T, 16)).round().astype(int))
            wm, inputs = _maps(f, ts, res)
            d = wm.displacement(
                np.asarray(f["fine/vertices"][ts], np.float32), np.asarray(f["fine/base"][ts], np.float32)
            )
            m = wm.mask
            x = inputs[:, m].astype(np.float64)
            i_sum, i_sq = i_sum + x.sum((0, 1)), i_sq + (x * x).sum((0, 1))
            d_sq = d_sq + (d[:, m].astype(np.float64) ** 2).sum((0, 1))
            n += x.shape[0] * x.shape[1]
        mean = i_sum / n
        return {
            "resolution": res,
            "in_mean": torch.tensor(mean, dtype=torch.float32),
            "in_std": torch.tensor(np.sqrt(np.maximum(i_sq / n - mean**2, 1e-12)), dtype=torch.float32),
            "disp_std": torch.tensor(np.sqrt(np.maximum(d_sq / n, 1e-14)), dtype=torch.float32),
        }

    def normalise(self, inputs: np.ndarray, mask: np.ndarray):
        m = np.asarray(mask, np.float32)[..., None]
        x = (np.asarray(inputs, np.float32) - self.state["in_mean"].numpy()) / self.state["in_std"].numpy()
        c = np.concatenate([x * m, m], axis=-1).transpose(2, 0, 1)
        return None, np.ascontiguousarray(c, dtype=np.float32)

    def build_model(self) -> torch.nn.Module:
        from learn.diffusion.unet import UNetConfig, WrinkleUNet

        c = self.config
        return WrinkleUNet(
            UNetConfig(
                in_channels=1,
                cond_channels=7,
                out_channels=3,
                base_channels=c.base_channels,
                channel_mult=tuple(c.channel_mult),
                num_res_blocks=c.num_res_blocks,
                attention_levels=tuple(c.attention_levels),
            )
        )

    def train_dataset(self, root) -> torch.utils.data.Dataset:
        return _Frames(self, root)

    @staticmethod
    def _forward(model, cond: torch.Tensor) -> torch.Tensor:
        B, _, H, W = cond.shape
        zeros = torch.zeros((B, 1, H, W), device=cond.device, dtype=cond.dtype)
        return model(zeros, torch.zeros(B, dtype=torch.long, device=cond.device), cond)

    def training_loss(self, model, batch, generator: torch.Generator) -> LossOutput:
        cond, target = batch["cond"], batch["target"]
        mask = cond[:, -1:]
        err = ((self._forward(model, cond).float() - target) ** 2 * mask).sum() / (
            3.0 * mask.sum()
        ).clamp_min(1.0)
        return LossOutput(err, {"mse": err.detach()})

    def predict_sequence(
        self,
        model,
        sequence: Mapping[str, np.ndarray],
        *,
        device: torch.device,
        base: np.ndarray | None = None,
    ) -> Prediction:
        seq = dict(sequence)
        if base is not None:
            seq["fine/base"] = base
        ts = np.arange(len(seq["fine/base"]))
        wm, inputs = _maps(seq, ts, int(self.state["resolution"]))
        std = self.state["disp_std"].numpy()
        out = []
        dtype = next(model.parameters()).dtype
        with torch.no_grad():
            for s in range(0, len(ts), self.config.infer_batch):
                c = np.stack([self.normalise(x, wm.mask)[1] for x in inputs[s : s + self.config.infer_batch]])
                y = self._forward(model, torch.from_numpy(c).to(device, dtype)).float().cpu().numpy()
                out.append(y.transpose(0, 2, 3, 1) * std * wm.mask[..., None])
        maps = np.concatenate(out)
        return Prediction(
            wm.decode_global(maps, np.asarray(seq["fine/base"], np.float32)), {"displacement_maps": maps}
        )
