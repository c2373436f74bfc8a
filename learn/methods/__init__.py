"""Trainable garment methods, by name (STYLE.md 5: an explicit registry, never import-by-string).

Each entry is a ``learn.methods.base.Method`` subclass; ``wrinkles train METHOD`` and the
evaluation harness look methods up here.
"""

from __future__ import annotations

from learn.methods.base import LossOutput, Method, Prediction
from learn.methods.deepwrinkles import DeepWrinklesMethod
from learn.methods.displacement_regressor import DisplacementRegressorMethod
from learn.methods.gsnet import GSNetMethod
from learn.methods.skeleton_cvae import SkeletonCVAEMethod
from learn.methods.skinned_mlp import SkinnedMLPMethod
from learn.methods.wrinkle_diffusion import WrinkleDiffusionMethod

METHODS: dict[str, type[Method]] = {
    SkinnedMLPMethod.name: SkinnedMLPMethod,
    SkeletonCVAEMethod.name: SkeletonCVAEMethod,
    WrinkleDiffusionMethod.name: WrinkleDiffusionMethod,
    DisplacementRegressorMethod.name: DisplacementRegressorMethod,
    DeepWrinklesMethod.name: DeepWrinklesMethod,
    GSNetMethod.name: GSNetMethod,
}

METHOD_ALIASES: dict[str, str] = {"coarse": SkeletonCVAEMethod.name, "wrinkles": WrinkleDiffusionMethod.name}
"""Short names of ``wrinkles train`` (Guo et al.'s two stages)."""

__all__ = ["METHODS", "METHOD_ALIASES", "LossOutput", "Method", "Prediction"]
