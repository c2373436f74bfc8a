"""DeepWrinkles (Lähner, Cremers, Tung, ECCV 2018) on simulated data, as one trainable method.

- ``prepare``: every training sequence's fine frames are scanned and the template (the coarse
  garment) is registered to them (Sec. 3.1; ``learn.deepwrinkles.registrations``, cached), the
  registrations are pose- and shape-normalised and their subspace fitted (Sec. 3.2, k <= 500
  components), control vectors are normalised and the linear pose-to-shape map fitted in closed
  form (Sec. 3.3). The fitted state (subspace, statistics, linear map) goes in every checkpoint.
- the model: the LSTM encoder-decoder from a window of control vectors to subspace coefficients
  (Sec. 3.3, 4 x 256, windows of 3) and the cGAN (Sec. 4): a pix2pix U-Net from the LR normal
  map to the HR one and a 70 x 70 PatchGAN, trained together with one optimizer
  (``learn.deepwrinkles.cgan.cgan_loss``).
- an item: one frame t of a training sequence: the control window and normalised
  coefficients of frames t-2..t with ``regression_windows - 1`` more windows of random training
  frames (the LSTM's share of the batch), the LR map of the global shape at t (the registration
  projected on the subspace's ``lr_components``, the paper's "BS k" input, or the
  registration itself), and the HR maps at t and t-1 (Eq. 4's temporal term).
- the loss: coefficient MSE (in units of each component's standard deviation) times
  ``coefficient_weight``, plus Eq. 4 with the GAN terms.
- ``predict_sequence``: controls -> coefficients (LSTM or the linear map) -> global shape
  (reposed by skinning) -> LR maps -> generated HR maps -> the fine garment moved to match
  them (Guo et al. Eq. 10, ``sim.geometry.normal_geometry``), so DeepWrinkles gets the same
  vertex metrics as the other methods; the maps go in ``extras``.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from learn.methods.base import LossOutput, Method, Prediction
from sim.errors import WrinklesInputError

REGRESSORS = ("lstm", "linear")
SOURCES = ("registration", "simulation")
LR_SOURCES = ("subspace", "registration")


@dataclass(frozen=True)
class DeepWrinklesConfig:
    """Settings of DeepWrinkles (paper values where it gives them)."""

    components: int = 500
    """Subspace size k (Sec. 3.2: 500); capped by the registrations' rank."""
    regressor: str = "lstm"
    """Pose-to-shape map at prediction: "lstm" (trained) or "linear" (closed form)."""
    hidden: int = 256
    """LSTM units per layer (Sec. 5.3: 256)."""
    layers: int = 4
    """LSTM layers of the encoder and the decoder (Sec. 5.3: 4)."""
    window: int = 3
    """Frames per LSTM window (Sec. 5.3: 3)."""
    control_joints: str = "all"
    """Joints of Θ (``regression.CONTROL_JOINTS``): "all", "upper" (Sec. 5.3's choice for shirts)
    or "lower"."""
    ridge: float = 1e-3
    """Ridge of the linear map (on normalised controls)."""
    resolution: int = 256
    """Normal-map side [px] (Sec. 4: 256; 512 also works)."""
    filters: int = 64
    """Filters of the first U-Net and PatchGAN layers (Sec. 5: 64)."""
    norm: str = "batch"
    """Normalisation layers of the cGAN: "batch" (pix2pix) or "instance"."""
    data_weight: float = 100.0
    """Eq. 4's L_data weight (Sec. 5: 100)."""
    temporal_weight: float = 50.0
    """Eq. 4's L_temp weight (Sec. 5: 50; 0: no temporal term)."""
    gan_weight: float = 1.0
    """The generator's adversarial weight (Sec. 5: 1)."""
    temporal_kind: str = "eq4"
    """"eq4", or the Table 1 alternatives "l1" / "l2"."""
    coefficient_weight: float = 1.0
    """Weight of the LSTM's coefficient loss in the total."""
    regression_windows: int = 16
    """Control windows the LSTM trains on per item: the item's own and more of random frames of
    the prepared training sequences (all of them up to 128), so the regression sees
    ``batch_size`` x this windows a step while the cGAN sees ``batch_size`` images (windows are
    cheap; with one window per item, 663 steps left the LSTM behind the closed-form map: 29.2 /
    22.1 against 26.3 / 20.0 mm on two test sequences)."""
    lr_source: str = "subspace"
    """Training LR maps from the registration projected on ``lr_components`` ("subspace") or
    from the registration itself ("registration")."""
    lr_components: int = 0
    """Components of the training LR maps' projection (0: ``components``)."""
    source: str = "registration"
    """Global-shape data: "registration" (scan + Eq. 1) or "simulation" (perfect registration)."""
    register_every: int = 1
    """Register every k-th frame, interpolate the normalised shapes between."""
    workers: int = 1
    """Processes that register the training sequences (each scans on the default Warp device)."""
    garments: tuple[str, ...] = ()
    """Garment categories to train on (empty: all; one template topology is required)."""
    infer_batch: int = 8
    """Frames per generator batch at prediction."""


class DeepWrinklesModel(nn.Module):
    """The LSTM pose-to-shape regressor and the cGAN's two networks."""

    def __init__(self, cfg: DeepWrinklesConfig, controls: int, coefficients: int):
        super().__init__()
        from learn.deepwrinkles.cgan import PatchDiscriminator, UNetGenerator
        from learn.deepwrinkles.regression import PoseToShapeLSTM

        self.regressor = PoseToShapeLSTM(controls, coefficients, hidden=cfg.hidden, layers=cfg.layers)
        self.generator = UNetGenerator(3, 3, cfg.filters, cfg.resolution, norm=cfg.norm)
        self.discriminator = PatchDiscriminator(6, cfg.filters, 3, norm=cfg.norm)


class DeepWrinklesMethod(Method):
    """DeepWrinkles (module docstring)."""

    name = "deepwrinkles"
    Config = DeepWrinklesConfig
    half_state = ("components",)  # the subspace's basis: 3.4 MB of a release file at k = 200 in float16

    @classmethod
    def validate_config(cls, config: DeepWrinklesConfig, err) -> None:
        from learn.deepwrinkles.regression import CONTROL_JOINTS

        positive = ("components", "hidden", "layers", "window", "filters", "register_every", "infer_batch",
                    "workers", "regression_windows")
        for f in positive:
            if getattr(config, f) < 1:
                raise err(f"model.{f} must be >= 1, got {getattr(config, f)}")
        if config.resolution < 16 or config.resolution & (config.resolution - 1):
            raise err(f"model.resolution must be a power of two >= 16, got {config.resolution}")
        choices = {
            "regressor": REGRESSORS,
            "lr_source": LR_SOURCES,
            "source": SOURCES,
            "norm": ("batch", "instance"),
            "temporal_kind": ("eq4", "l1", "l2"),
            "control_joints": tuple(CONTROL_JOINTS),
        }
        for f, allowed in choices.items():
            if getattr(config, f) not in allowed:
                raise err(f"model.{f} must be one of {', '.join(allowed)}, got {getattr(config, f)!r}")
        for f in (
            "data_weight",
            "temporal_weight",
            "gan_weight",
            "coefficient_weight",
            "ridge",
            "lr_components",
        ):
            if getattr(config, f) < 0:
                raise err(f"model.{f} must be >= 0, got {getattr(config, f)}")

    @functools.cache  # noqa: B019 - one body model per method object is the point
    def body(self, name: str = "default"):
        from sim.bodies import load_body

        return load_body(name)

    def settings(self):
        from learn.deepwrinkles.global_shape import RegistrationSettings

        return RegistrationSettings(source=self.config.source, register_every=self.config.register_every)

    def prepare(self, root) -> dict[str, torch.Tensor]:
        from learn.deepwrinkles.training import fit_state

        return fit_state(self, root)

    def subspace(self):
        from learn.deepwrinkles.subspace import GarmentSubspace

        s = self.state
        return GarmentSubspace(
            mean=s["mean"].numpy(),
            components=s["components"].numpy(),
            singular_values=s["singular_values"].numpy(),
            total_variance=float(s["total_variance"]),
            frames=int(s["frames"]),
        )

    def select_controls(self, controls: np.ndarray) -> np.ndarray:
        """The columns of control vectors (..., 6 J + 6) of ``config.control_joints``."""
        from learn.deepwrinkles.regression import ROOT_MOTION, control_columns

        num_joints = (controls.shape[-1] - ROOT_MOTION) // 6
        return controls[..., control_columns(self.config.control_joints, num_joints)]

    def normalise_controls(self, controls: np.ndarray) -> np.ndarray:
        """Control vectors (T, 6 J + 6), their ``control_joints`` columns in units of the training
        frames' mean and standard deviation: what both pose-to-shape maps read."""
        s = self.state
        return (self.select_controls(controls) - s["control_mean"].numpy()) / s["control_std"].numpy()

    def build_model(self) -> nn.Module:
        if not self.state:
            raise WrinklesInputError("DeepWrinkles needs its fitted state (prepare or a checkpoint) to build")
        return DeepWrinklesModel(
            self.config, int(self.state["control_mean"].numel()), int(self.state["components"].shape[0])
        )

    def train_dataset(self, root) -> torch.utils.data.Dataset:
        from learn.deepwrinkles.training import TrainFrames

        frames = TrainFrames(self, root)
        frames.warm()
        return frames

    def training_loss(self, model: nn.Module, batch: dict, generator: torch.Generator) -> LossOutput:
        from learn.deepwrinkles.cgan import CGANWeights, cgan_loss

        cfg = self.config
        controls, target = batch["controls"], batch["coefficients"]
        if controls.ndim == 4:  # (B, regression_windows, W, C): every item's windows in one batch
            controls, target = controls.flatten(0, 1), target.flatten(0, 1)
        coeff = model.regressor(controls)
        coeff_loss = (coeff.float() - target).square().mean()
        w = CGANWeights(
            data=cfg.data_weight,
            temporal=cfg.temporal_weight,
            gan=cfg.gan_weight,
            temporal_kind=cfg.temporal_kind,
        )
        hr_prev = batch["hr_prev"] if cfg.temporal_weight > 0 else None
        total, scalars = cgan_loss(
            model.generator, model.discriminator, batch["lr"], batch["hr"], hr_prev, batch["mask"], w
        )
        return LossOutput(
            total + cfg.coefficient_weight * coeff_loss, {**scalars, "coefficients": coeff_loss.detach()}
        )

    @torch.no_grad()
    def predict_sequence(
        self,
        model: nn.Module,
        sequence: Mapping[str, np.ndarray],
        *,
        device: torch.device,
        lr_input: str = "regression",
        components: int = 0,
        regressor: str = "",
        source: str = "",
    ) -> Prediction:
        """``learn.deepwrinkles.prediction.predict``: ``lr_input`` "regression" (from the body
        motion, by ``regressor``: "lstm" or "linear"), "registration" or "subspace" (``components``
        of it; from scans or the true places: ``source``): the paper's Table 1 inputs."""
        from learn.deepwrinkles.prediction import predict

        return predict(self, model, sequence, device=device, lr_input=lr_input, components=components,
                       regressor=regressor, source=source)
