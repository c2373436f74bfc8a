"""DeepWrinkles' global shape of a sequence (Lähner et al. 2018, Sec. 3.2-3.3, Eq. 3 and 5).

A registered frame R_t is pose-normalised by inverse skinning and brought to the reference body
shape by removing the template's shape offset (Eq. 5: the mean shape plus the body's offsets),
``R̄_t = S^-1(R_t, θ_t) - o``, ``o = rest_shaped - rest_reference``; the subspace models R̄, and a
coefficient vector goes back to the sequence's world by ``S(M̄ + Σ λ_l V_l + o, θ_t)``.

Registrations are the expensive part (a scan and an ICP registration per frame), so they are
cached per sequence and settings: ``DIR/derived/deepwrinkles/`` beside a writable dataset's
``sequences/`` folder, else ``$WRINKLES_CACHE/deepwrinkles`` by data checksum; each file is
written atomically. ``register_every`` > 1 registers every k-th frame and fills the frames in
between by linear interpolation of the pose-normalised registrations (the global shape varies
smoothly at 30 fps).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from learn.deepwrinkles.registrations import RegisteredSequence, SequenceRig

CACHE_DIR = "deepwrinkles"
CACHE_VERSION = 1
"""Bumped when what a cache file holds changes meaning."""


@dataclass(frozen=True)
class RegistrationSettings:
    """What a sequence's cached registrations depend on.

    Attributes:
        source: "registration" (scan + Eq. 1 registration, the paper) or "simulation" (the
            template's true places on the simulated frames: a perfect registration).
        register_every: register every k-th frame (and the last).
        tracking: start a frame from the previous registration.
        seed: the scans' noise.
    """

    source: str = "registration"
    register_every: int = 1
    tracking: bool = True
    seed: int = 0

    def digest(self) -> str:
        """Of the settings and of the scanner and registration configs the registrations use."""
        from learn.deepwrinkles.registrations import garment_registration
        from sim.scans.scanner import ScanConfig

        record = {
            "settings": asdict(self),
            "scan": asdict(ScanConfig()),
            "registration": asdict(garment_registration()),
            "version": CACHE_VERSION,
        }
        return hashlib.sha256(json.dumps(record, sort_keys=True, default=str).encode()).hexdigest()[:16]


def registered_frames(T: int, every: int) -> np.ndarray:
    """The frames registered of a T-frame sequence: every k-th and the last."""
    return np.unique(np.r_[np.arange(0, T, max(1, int(every))), T - 1])


def cache_path(sf, settings: RegistrationSettings) -> Path:
    """Where a sequence file's registrations with ``settings`` are kept (module docstring)."""
    from sim.datasets.fields import data_digest, local_derived_dir, user_cache_dir

    local = local_derived_dir(sf)
    if local is not None:
        return local / CACHE_DIR / f"{sf.path.stem}-{settings.digest()}.npz"
    return user_cache_dir() / CACHE_DIR / f"{data_digest(sf)[:24]}-{settings.digest()}.npz"


def _write_npz(path: Path, **arrays) -> None:
    """``arrays`` as an .npz file at ``path``, written atomically."""
    import io

    from sim.datasets.storage import atomic_write_bytes

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getbuffer())


def registrations(
    sf,
    seq: Mapping[str, np.ndarray],
    body,
    settings: RegistrationSettings,
    *,
    device: str | None = None,
    progress: Callable[[int], None] | None = None,
    rig: SequenceRig | None = None,
) -> RegisteredSequence:
    """A sequence's registrations (``RegisteredSequence``), from the cache or made and cached
    (``rig``: the sequence's template rig when the caller has it)."""
    from learn.deepwrinkles.registrations import register_sequence, template_truth

    path = cache_path(sf, settings)
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as z:
                return RegisteredSequence(
                    frames=z["frames"], vertices=z["vertices"], truth=z["truth"], pairs=z["pairs"]
                )
        except (OSError, KeyError, ValueError):
            pass  # a damaged cache file is made again
    T = int(np.asarray(seq["fine/vertices"]).shape[0])
    frames = registered_frames(T, settings.register_every)
    if settings.source == "simulation":
        truth = template_truth(seq).evaluate(
            np.asarray(seq["fine/faces"]), np.asarray(seq["fine/vertices"])[frames]
        )
        reg = RegisteredSequence(
            frames=frames, vertices=truth, truth=truth, pairs=np.zeros(len(frames), np.int64)
        )
        if progress is not None:
            progress(len(frames))
    else:
        reg = register_sequence(
            seq,
            body,
            frames=frames,
            tracking=settings.tracking,
            seed=settings.seed,
            device=device,
            progress=progress,
            rig=rig,
        )
    _write_npz(path, frames=reg.frames, vertices=reg.vertices, truth=reg.truth, pairs=reg.pairs)
    return reg


def shape_offset(rig: SequenceRig, reference_rest: np.ndarray) -> np.ndarray:
    """o of Eq. 5: the template's rest on the sequence's body minus its reference rest (Vc, 3)."""
    return (rig.rest - np.asarray(reference_rest, np.float32)).astype(np.float32)


def normalise(rig: SequenceRig, reference_rest: np.ndarray, reg: RegisteredSequence, T: int) -> np.ndarray:
    """Pose- and shape-normalised registrations R̄ of every frame (T, Vc, 3): registered frames
    unposed, minus the shape offset; frames between registered ones linearly interpolated."""
    from learn.deepwrinkles.subspace import unpose

    bar = unpose(reg.vertices, rig.weights, rig.transforms[reg.frames]) - shape_offset(rig, reference_rest)
    if len(reg.frames) == T:
        return bar.astype(np.float32)
    t = np.arange(T)
    hi = np.clip(np.searchsorted(reg.frames, t), 1, len(reg.frames) - 1)
    lo = hi - 1
    w = ((t - reg.frames[lo]) / np.maximum(reg.frames[hi] - reg.frames[lo], 1))[:, None, None]
    return ((1.0 - w) * bar[lo] + w * bar[hi]).astype(np.float32)


def pose(rig: SequenceRig, reference_rest: np.ndarray, normalised: np.ndarray) -> np.ndarray:
    """World positions (T, Vc, 3) of pose-normalised shapes (T, Vc, 3): ``S(R̄ + o, θ_t)``."""
    from learn.deepwrinkles.subspace import repose

    return repose(
        np.asarray(normalised, np.float32) + shape_offset(rig, reference_rest), rig.weights, rig.transforms
    )
