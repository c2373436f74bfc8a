"""Training configuration: frozen dataclasses, read from TOML with unknown keys refused.

STYLE.md 5: configs are frozen dataclasses with units in the field docs; the resolved config is
saved beside outputs and inside checkpoints; a test round-trips it. ``config_from_dict`` builds
any (nested) config dataclass from a plain dict and names the file and the key of the first
problem; ``config_to_dict`` is its inverse.

A run's whole configuration is a :class:`RunConfig`::

    method = "skinned_mlp"          # a key of learn.methods.METHODS

    [train]                          # TrainConfig
    steps = 2000
    batch_size = 16

    [optim]                          # OptimConfig
    lr = 1e-3

    [model]                          # the method's own config dataclass
    hidden = 256
"""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from dataclasses import dataclass, field
from typing import Any

from sim.errors import WrinklesInputError

AMP_MODES = ("auto", "off", "bf16", "fp16")
LR_SCHEDULES = ("constant", "cosine")


@dataclass(frozen=True)
class OptimConfig:
    """AdamW with warm-up and an optional cosine decay."""

    lr: float = 1.0e-3
    """Peak learning rate."""
    weight_decay: float = 0.0
    betas: tuple[float, float] = (0.9, 0.999)
    grad_clip: float = 1.0
    """Clip the global gradient norm to this value (0: no clipping)."""
    warmup_steps: int = 0
    """Linear warm-up from 0 to ``lr`` over this many steps."""
    schedule: str = "constant"
    """``constant`` or ``cosine`` (decays to ``min_lr_ratio * lr`` at the last step)."""
    min_lr_ratio: float = 0.05


@dataclass(frozen=True)
class TrainConfig:
    """The training loop: steps, batches, seeds, checkpoints, EMA, mixed precision."""

    steps: int = 1000
    """Optimizer steps in total (a resumed run continues up to this count)."""
    batch_size: int = 8
    """Global batch size (split evenly over DDP processes)."""
    seed: int = 0
    """Seeds model initialisation, the data order and every random draw of the loss."""
    num_workers: int = 0
    """DataLoader worker processes."""
    log_every: int = 10
    """Steps between logged scalars (TensorBoard, metrics.jsonl)."""
    checkpoint_every: int = 500
    """Steps between checkpoints (the last step always writes one)."""
    keep_checkpoints: int = 2
    """Older numbered checkpoints beyond this count are deleted (``last.pt`` always stays)."""
    ema_decay: float = 0.999
    """Decay of the exponential moving average of the weights (0: no EMA)."""
    amp: str = "auto"
    """Mixed precision: ``auto`` (bf16 on CUDA when supported, else off), ``off``, ``bf16``,
    ``fp16`` (CUDA only, with a gradient scaler)."""
    device: str = "auto"
    """``auto`` (cuda when present), ``cpu``, ``cuda``, ``cuda:N``; under torchrun each process
    takes ``cuda:LOCAL_RANK``."""


@dataclass(frozen=True)
class RunConfig:
    """Everything that defines a training run (saved as ``config.json`` and in checkpoints)."""

    method: str
    """Key of ``learn.methods.METHODS``."""
    model: Any
    """The method's config dataclass (``METHODS[method].Config``)."""
    train: TrainConfig = field(default_factory=TrainConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)


RESUMABLE_CHANGES = frozenset({"train.steps", "train.log_every", "train.checkpoint_every",
                               "train.keep_checkpoints", "train.num_workers"})
"""Fields a resumed run may change without breaking bit-exact continuation."""


def _check_value(tp: Any, value: Any, where: str, err) -> Any:
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        return config_from_dict(tp, value, where=where, err=err)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _check_value(a, value, where, err)
            except WrinklesInputError as e:
                errors.append(str(e))
        raise errors[0] if len(errors) == 1 else err(f"{where}: {value!r} has the wrong type")
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise err(f"{where}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_check_value(args[0], v, f"{where}[{i}]", err) for i, v in enumerate(value))
        if len(value) != len(args):
            raise err(f"{where}: expected {len(args)} values, got {len(value)}")
        pairs = enumerate(zip(args, value, strict=True))
        return tuple(_check_value(a, v, f"{where}[{i}]", err) for i, (a, v) in pairs)
    if tp is bool:
        if not isinstance(value, bool):
            raise err(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise err(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise err(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise err(f"{where}: expected a string, got {value!r}")
        return value
    return value


def config_from_dict(cls, data: Any, *, where: str = "", err=None, source: str | os.PathLike = ""):
    """Build the frozen dataclass ``cls`` (nested dataclasses too) from a plain dict.

    Args:
        cls: a dataclass type.
        data: its fields as a dict; missing fields take their defaults.
        where: dotted path of ``data`` in the whole config (for messages).
        err: ``err(message) -> Exception`` factory; default ``WrinklesInputError`` naming ``source``.
        source: the file the dict came from (for messages).

    Raises:
        WrinklesInputError: unknown keys, wrong types, missing required fields.
    """
    if err is None:
        src = os.fspath(source) or "config"

        def err(msg: str) -> WrinklesInputError:
            return WrinklesInputError(msg, path=src)

    if isinstance(data, cls):
        return data
    label = f"[{where}]" if where else "the config"
    if not isinstance(data, dict):
        raise err(f"{label} must be a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    bad = sorted(set(data) - set(fields))
    if bad:
        raise err(f"unknown key(s) {', '.join(bad)} in {label}; allowed: {', '.join(sorted(fields))}")
    kw = {}
    for name, f in fields.items():
        key = f"{where}.{name}" if where else name
        if name in data:
            kw[name] = _check_value(hints[name], data[name], key, err)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise err(f"missing required key {key}")
    return cls(**kw)


def config_to_dict(cfg: Any) -> dict:
    """JSON-ready dict of a config dataclass (tuples become lists)."""

    def conv(x):
        if dataclasses.is_dataclass(x):
            return {f.name: conv(getattr(x, f.name)) for f in dataclasses.fields(x)}
        if isinstance(x, (list, tuple)):
            return [conv(v) for v in x]
        if isinstance(x, dict):
            return {str(k): conv(v) for k, v in x.items()}
        return x

    return conv(cfg)


def validate_train(cfg: TrainConfig, err) -> None:
    """Range checks of a ``TrainConfig`` (raise ``err(message)``)."""
    if cfg.steps < 1:
        raise err(f"train.steps must be >= 1, got {cfg.steps}")
    if cfg.batch_size < 1:
        raise err(f"train.batch_size must be >= 1, got {cfg.batch_size}")
    if cfg.num_workers < 0:
        raise err(f"train.num_workers must be >= 0, got {cfg.num_workers}")
    for name in ("log_every", "checkpoint_every", "keep_checkpoints"):
        if getattr(cfg, name) < 1:
            raise err(f"train.{name} must be >= 1, got {getattr(cfg, name)}")
    if not 0.0 <= cfg.ema_decay < 1.0:
        raise err(f"train.ema_decay must be in [0, 1), got {cfg.ema_decay}")
    if cfg.amp not in AMP_MODES:
        raise err(f"train.amp {cfg.amp!r}: choose one of {', '.join(AMP_MODES)}")


def validate_optim(cfg: OptimConfig, err) -> None:
    """Range checks of an ``OptimConfig``."""
    if not cfg.lr > 0:
        raise err(f"optim.lr must be > 0, got {cfg.lr}")
    if cfg.weight_decay < 0 or cfg.grad_clip < 0 or cfg.warmup_steps < 0:
        raise err("optim.weight_decay, grad_clip and warmup_steps must be >= 0")
    if cfg.schedule not in LR_SCHEDULES:
        raise err(f"optim.schedule {cfg.schedule!r}: choose one of {', '.join(LR_SCHEDULES)}")
    if not 0.0 <= cfg.min_lr_ratio <= 1.0:
        raise err(f"optim.min_lr_ratio must be in [0, 1], got {cfg.min_lr_ratio}")


def run_config_from_dict(data: dict, *, source: str | os.PathLike = "",
                         methods: dict | None = None) -> RunConfig:
    """Build and validate a ``RunConfig``; ``data["model"]`` is parsed with the method's Config."""
    if methods is None:
        from learn.methods import METHODS as methods
    src = os.fspath(source) or "config"

    def err(msg: str) -> WrinklesInputError:
        return WrinklesInputError(msg, path=src)

    if not isinstance(data, dict):
        raise err("the config must be a table")
    allowed = {"method", "model", "train", "optim"}
    bad = sorted(set(data) - allowed)
    if bad:
        raise err(f"unknown key(s) {', '.join(bad)}; allowed: {', '.join(sorted(allowed))}")
    name = data.get("method")
    if name not in methods:
        raise err(f"method {name!r}: choose one of {', '.join(sorted(methods))}")
    method = methods[name]
    model = config_from_dict(method.Config, data.get("model", {}), where="model", err=err)
    train = config_from_dict(TrainConfig, data.get("train", {}), where="train", err=err)
    optim = config_from_dict(OptimConfig, data.get("optim", {}), where="optim", err=err)
    validate_train(train, err)
    validate_optim(optim, err)
    if hasattr(method, "validate_config"):
        method.validate_config(model, err)
    return RunConfig(method=name, model=model, train=train, optim=optim)


def load_run_config(path: str | os.PathLike, *, overrides: dict | None = None) -> RunConfig:
    """Read a run config from a TOML file (``overrides``: dotted keys, e.g. ``{"train.steps": 10}``)."""
    from sim.datasets.config import _load_toml

    data = _load_toml(path)
    return run_config_from_dict(apply_overrides(data, overrides or {}), source=path)


def apply_overrides(data: dict, overrides: dict) -> dict:
    """Copy of ``data`` with dotted-key ``overrides`` set (``"train.steps": 5``)."""
    import copy

    out = copy.deepcopy(data)
    for key, value in overrides.items():
        node = out
        *parents, last = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = value
    return out


def config_differences(a: dict, b: dict, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two config dicts."""
    out = []
    for k in sorted(set(a) | set(b)):
        key = f"{prefix}{k}"
        va, vb = a.get(k, "<missing>"), b.get(k, "<missing>")
        if isinstance(va, dict) and isinstance(vb, dict):
            out += config_differences(va, vb, key + ".")
        elif va != vb:
            out.append(key)
    return out
