"""Checkpoints: state dicts plus the resolved run config, written atomically, read safely.

A checkpoint file (``torch.save`` zip) holds plain containers and tensors only:

- ``format``: ``"wrinkles-checkpoint"``, ``version``: 1;
- ``config``: the resolved run config as a dict (``learn.train.config.config_to_dict``);
- ``step``: optimizer steps done;
- ``model``: the model's state dict; ``ema``: the EMA state (or absent);
- ``optimizer``, ``scaler``: optimizer and gradient-scaler states (absent in exported weights);
- ``rng``: torch CPU/CUDA generator states (as uint8 tensors);
- ``versions``: package versions (``sim.versions.package_versions``), for the model card.

It is loaded with ``torch.load(..., weights_only=True)``, which refuses anything that would run
code; a refusal says what the file holds, never torch's advice to load it unsafely. Writing goes
to a temporary name in the same directory, then ``os.replace`` (atomic), so a kill never leaves
a truncated checkpoint behind.
"""

from __future__ import annotations

import os
import pickle
import re
import tempfile
import warnings
from pathlib import Path
from typing import Any

import torch

from sim.errors import NEVER_UNPICKLED, WrinklesInputError

FORMAT = "wrinkles-checkpoint"
VERSION = 1


def save_checkpoint(path: str | os.PathLike, payload: dict[str, Any]) -> None:
    """Write ``payload`` (plus format markers) to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save({"format": FORMAT, "version": VERSION, **payload}, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def load_checkpoint(path: str | os.PathLike, *, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint without executing code (``weights_only=True``).

    Raises:
        WrinklesInputError: missing, unreadable, or not a wrinkles checkpoint.
    """
    path = Path(path)
    if not path.is_file():
        raise WrinklesInputError("checkpoint not found", path=path)
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols of files it refuses
            warnings.simplefilter("ignore")
            ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:  # zip errors, unpickling refusals, truncated files
        raise WrinklesInputError(f"not a readable checkpoint: {_load_failure(e)}", path=path) from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise WrinklesInputError("not a wrinkles checkpoint (no 'format' marker)", path=path)
    if ckpt.get("version") != VERSION:
        raise WrinklesInputError(f"checkpoint format version {ckpt.get('version')} is not supported "
                                 f"(this wrinkles reads version {VERSION})", path=path)
    for key in ("config", "model", "step"):
        if key not in ckpt:
            raise WrinklesInputError(f"checkpoint lacks '{key}'", path=path)
    return ckpt


def _load_failure(e: Exception) -> str:
    """What ``torch.load(weights_only=True)``'s exception says is wrong with a file, in our words:
    torch's own text advises loading it with ``weights_only=False`` or allowing its classes."""
    text = str(e)
    name = re.search(r"Unsupported global: GLOBAL ([\w.]+)", text)
    if name:
        return (f"it holds a pickled Python object ({name.group(1)}), where a wrinkles checkpoint holds "
                f"tensors and plain containers only; {NEVER_UNPICKLED}")
    if isinstance(e, pickle.UnpicklingError) or "Unpickler" in text or "weights_only" in text:
        return ("its contents are not tensors and plain containers (another program's file, or pickled "
                f"Python objects); {NEVER_UNPICKLED}")
    if "zip archive" in text or "PytorchStreamReader" in text:
        return "the archive is truncated or corrupted (an interrupted copy or download?)"
    return "the file is not in PyTorch's format"


def check_state_dict(model: torch.nn.Module, state: dict[str, torch.Tensor], *, path: str | os.PathLike,
                     what: str = "model") -> None:
    """Refuse a state dict that does not fit ``model``, naming what differs.

    Raises:
        WrinklesInputError: missing or unexpected keys, or a shape/dtype mismatch.
    """
    own = model.state_dict()
    missing = [k for k in own if k not in state]
    extra = [k for k in state if k not in own]
    shapes = [f"{k} is {tuple(state[k].shape)} in the checkpoint, {tuple(v.shape)} here"
              for k, v in own.items() if k in state and tuple(state[k].shape) != tuple(v.shape)]
    problems = []
    if missing:
        problems.append(f"missing {len(missing)} tensor(s) (e.g. {missing[0]})")
    if extra:
        problems.append(f"{len(extra)} unexpected tensor(s) (e.g. {extra[0]})")
    if shapes:
        problems.append(f"{len(shapes)} shape mismatch(es): {shapes[0]}")
    if problems:
        raise WrinklesInputError(f"the checkpoint's {what} does not match this model: " + "; ".join(problems)
                                 + " (a checkpoint of another method or model config?)", path=path)
