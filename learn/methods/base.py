"""What every trainable garment method provides to the shared trainer and evaluation harness.

A method (DeepWrinkles, GSNet, the strain diffusion, a baseline...) is a class with a frozen
``Config`` dataclass and these operations, kept apart as STYLE.md 4 asks (network, data, loss,
inference loop):

- ``prepare(root)`` -> the method's *fitted state*: constants derived from the training data
  before training (normalisation statistics, a fitted virtual skeleton...), a flat dict of
  tensors. The trainer calls it once per run (not on resume), stores it in every checkpoint
  (``"method_state"``) and hands it back through ``load_state`` when a run resumes or a
  checkpoint is loaded, so ``build_model`` can size and fill buffers from it. Default: none;
- ``build_model()`` -> the ``torch.nn.Module`` (built deterministically from the config and the
  fitted state; the trainer seeds torch first);
- ``train_dataset(root)`` -> a map-style dataset whose ``__getitem__`` takes ``(index, seed)``:
  every random draw of an item (vertex subsets, augmentation) comes from ``seed``, which the
  trainer derives from the run seed, the epoch and the index; this is what makes a resumed run
  bit-identical to an uninterrupted one;
- ``collate(items)`` -> a batch (nested dicts of tensors);
- ``training_loss(model, batch, generator)`` -> :class:`LossOutput`; random draws of the loss
  (noise, timesteps) use ``generator``, a ``torch.Generator`` seeded per step and process;
- ``predict_sequence(model, sequence, device)`` -> :class:`Prediction` for one whole sequence
  of a dataset (its arrays as numpy, ``sim.datasets.schema`` names, plus ``"body/model"``: the
  body model's name or file as a 0-d string array, ``"fps"``, ``"sequence/path"``: its file,
  where a method caches per-sequence work, ``"garment/material"``: the material's preset
  name, empty when unknown, and ``"garment/betas"`` where the garment was made on another shape
  than the body's, a reference fit); the evaluation harness
  turns predictions into metrics, so every method is measured by the same code.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import torch


@dataclass
class LossOutput:
    """A training loss and the scalars to log with it.

    Attributes:
        loss: the scalar to minimise (a 0-d tensor with grad).
        scalars: named floats or 0-d tensors to log (detached by the trainer).
    """

    loss: torch.Tensor
    scalars: dict[str, Any] = field(default_factory=dict)


@dataclass
class Prediction:
    """A method's output for one sequence.

    Attributes:
        vertices: garment positions [m], shape (T, V, 3), float32, on the sequence's fine garment
            topology (``fine/faces``).
        extras: optional method-specific arrays (e.g. ``"normal_maps"`` (T, H, W, 3)).
        metrics: optional method-specific per-sequence metrics (keys of
            ``learn.evaluate.METRIC_UNITS``), reported beside the harness's own.
    """

    vertices: np.ndarray
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)


class Method:
    """Base class of trainable methods (see the module docstring)."""

    name: ClassVar[str] = ""
    Config: ClassVar[type]
    half_state: ClassVar[tuple[str, ...]] = ()
    """Fitted-state entries a release file (``learn.train.export``) may keep in float16; loading
    brings them back to float32."""

    def __init__(self, config: Any):
        self.config = config
        self.state: dict[str, torch.Tensor] = {}

    def prepare(self, root) -> dict[str, torch.Tensor]:
        """Fit data-derived constants on the training split of the dataset at ``root`` (see the
        module docstring); the result becomes ``self.state``. Default: none."""
        return {}

    def load_state(self, state: Mapping[str, torch.Tensor]) -> None:
        """Adopt a fitted state (from ``prepare`` or a checkpoint); float16 entries (``half_state``
        of a release file) come back as float32. The state lives on the CPU whatever device the
        checkpoint was read to, as ``prepare`` leaves it: data loaders read it with numpy."""
        def host(k, v):
            if not torch.is_tensor(v):
                return v
            return (v.float() if k in self.half_state and v.dtype == torch.float16 else v).cpu()

        self.state = {k: host(k, v) for k, v in state.items()}

    @classmethod
    def validate_config(cls, config: Any, err) -> None:
        """Range checks of ``config``; raise ``err(message)``. Default: none."""

    def build_model(self) -> torch.nn.Module:
        raise NotImplementedError

    def train_dataset(self, root) -> torch.utils.data.Dataset:
        raise NotImplementedError

    def collate(self, items: list) -> Any:
        from torch.utils.data import default_collate

        return default_collate(items)

    def training_loss(self, model: torch.nn.Module, batch: Any, generator: torch.Generator) -> LossOutput:
        raise NotImplementedError

    def predict_sequence(self, model: torch.nn.Module, sequence: Mapping[str, np.ndarray], *,
                         device: torch.device) -> Prediction:
        raise NotImplementedError


def batch_to(batch: Any, device: torch.device) -> Any:
    """Move every tensor of a nested batch to ``device``."""
    if isinstance(batch, torch.Tensor):
        return batch.to(device, non_blocking=True)
    if isinstance(batch, dict):
        return {k: batch_to(v, device) for k, v in batch.items()}
    if isinstance(batch, (list, tuple)):
        return type(batch)(batch_to(v, device) for v in batch)
    return batch
