"""Exponential moving average of model weights (Polyak averaging).

``shadow <- d * shadow + (1 - d) * param`` after every optimizer step, with the warm-up
``d_k = min(decay, (1 + k) / (10 + k))`` (as in TensorFlow's ``ExponentialMovingAverage`` with
``num_updates``) so early averages are not dominated by the random initialisation. Buffers
(batch-norm statistics, ...) are copied, not averaged. Shadows are float32 whatever the
parameters' precision.
"""

from __future__ import annotations

import torch


class ExponentialMovingAverage:
    """EMA shadows of a module's parameters.

    Args:
        model: the module whose parameters are averaged (its ``state_dict`` keys are kept).
        decay: the asymptotic decay ``d`` in [0, 1).
    """

    def __init__(self, model: torch.nn.Module, decay: float):
        if not 0.0 <= decay < 1.0:
            raise ValueError(f"EMA decay must be in [0, 1), got {decay}")
        self.decay = float(decay)
        self.updates = 0
        self.shadow = {k: v.detach().clone().float() if v.is_floating_point() else v.detach().clone()
                       for k, v in model.state_dict().items()}
        self._params = {k for k, _ in model.named_parameters()}

    def current_decay(self) -> float:
        """The decay the next update uses (with warm-up)."""
        return min(self.decay, (1.0 + self.updates) / (10.0 + self.updates))

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        """Blend the model's current weights into the shadows."""
        d = self.current_decay()
        for k, v in model.state_dict().items():
            s = self.shadow[k]
            if k in self._params and v.is_floating_point():
                s.mul_(d).add_(v.detach().float(), alpha=1.0 - d)
            else:
                s.copy_(v.detach())
        self.updates += 1

    def copy_to(self, model: torch.nn.Module) -> None:
        """Load the shadows into ``model`` (cast to its dtypes)."""
        model.load_state_dict({k: v.to(model.state_dict()[k].dtype) for k, v in self.shadow.items()})

    def state_dict(self) -> dict:
        return {"decay": self.decay, "updates": self.updates, "shadow": self.shadow}

    def load_state_dict(self, state: dict) -> None:
        self.decay = float(state["decay"])
        self.updates = int(state["updates"])
        for k, v in state["shadow"].items():
            self.shadow[k].copy_(v)
