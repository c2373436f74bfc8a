"""Trainable garment methods, by name (STYLE.md 5: an explicit registry, never import-by-string).

Each entry is a ``learn.methods.base.Method`` subclass; ``wrinkles train METHOD`` and the
evaluation harness look methods up here.
"""

from __future__ import annotations

from learn.methods.base import LossOutput, Method, Prediction
from learn.methods.skinned_mlp import SkinnedMLPMethod

METHODS: dict[str, type[Method]] = {
    SkinnedMLPMethod.name: SkinnedMLPMethod,
}

__all__ = ["METHODS", "LossOutput", "Method", "Prediction"]
