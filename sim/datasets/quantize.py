"""Simulated positions stored as 16-bit integers on a per-frame grid (``sim.datasets.schema``).

A frame's positions x (V, 3) [m] are stored as ``q = round((x - origin) / step)`` (int16) with
``origin`` the centre of the frame's bounding box and ``step`` its largest extent / 65533, so
``x ≈ origin + step * q`` with an error of at most step / 2 per coordinate: 9 µm for a
garment 1.2 m across, against wrinkles of millimetres. Half the bytes of float32, and unlike
float16 (whose spacing is 0.5 mm at 1 m from the origin) the error does not grow with the
distance from the world origin. The decoding is the one line above (the netCDF / CF
``scale_factor`` / ``add_offset`` convention), so any safetensors reader gets the positions back.
"""

from __future__ import annotations

import numpy as np

LEVELS = 32767
"""Largest |q|: the grid spans [-LEVELS, LEVELS] steps around the frame's centre."""
SUFFIXES = ("_q", "_origin", "_step")
"""A quantized array ``NAME`` is stored as ``NAME_q`` (T, V, 3) i16, ``NAME_origin`` (T, 3) f32
and ``NAME_step`` (T,) f32."""


def quantize(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (T, V, 3) as ``(q (T, V, 3) int16, origin (T, 3) float32, step (T,) float32)``.

    Raises:
        ValueError: positions that are not finite.
    """
    x = np.asarray(x, np.float64)
    if x.ndim != 3 or x.shape[-1] != 3:
        raise ValueError(f"quantize: positions must be (T, V, 3), got {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError("quantize: positions are not finite")
    if x.shape[1] == 0:
        return (np.zeros(x.shape, np.int16), np.zeros((len(x), 3), np.float32), np.ones(len(x), np.float32))
    lo, hi = x.min(axis=1), x.max(axis=1)
    origin = (0.5 * (lo + hi)).astype(np.float32)
    extent = (hi - lo).max(axis=1)
    # the float32 step, rounded up so that the largest offset stays within LEVELS
    step = np.maximum(extent / (2 * LEVELS - 1), 1e-9).astype(np.float32)
    step = np.nextafter(step, np.float32(np.inf))
    q = np.rint((x - origin[:, None, :].astype(np.float64)) / step[:, None, None].astype(np.float64))
    return np.clip(q, -LEVELS, LEVELS).astype(np.int16), origin, step


def dequantize(q: np.ndarray, origin: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The positions (T, V, 3) float32 of ``quantize``'s output (or of frames sliced from it alike)."""
    out = np.asarray(q, np.float32) * np.asarray(step, np.float32)[:, None, None]
    out += np.asarray(origin, np.float32)[:, None, :]
    return out


def quantized_arrays(name: str, x: np.ndarray) -> dict[str, np.ndarray]:
    """The stored arrays of positions ``x`` named ``name`` (``SUFFIXES``)."""
    return dict(zip((name + s for s in SUFFIXES), quantize(x), strict=True))


class Dequantized:
    """A quantized array read through its three stored parts, decoded only for the frames asked
    for: ``a[start:stop]`` decodes those frames, ``np.asarray(a)`` all of them.

    Args:
        q, origin, step: the stored parts (memory maps or arrays).
    """

    dtype = np.dtype(np.float32)

    def __init__(self, q, origin, step):
        self.q, self.origin, self.step = q, origin, step
        self.shape = tuple(q.shape)
        self.ndim = len(self.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, index):
        """Frames first: ``a[t]``, ``a[t0:t1]``, ``a[frame indices]``, then any index of the
        decoded frames (``a[t0:t1, :100]``). ``...`` and ``None`` are refused."""
        frames, rest = (index[0], index[1:]) if isinstance(index, tuple) else (index, ())
        if frames is Ellipsis or frames is None or any(i is Ellipsis or i is None for i in rest):
            raise TypeError("Dequantized: index the frames first, without ... or None")
        if isinstance(frames, np.ndarray) and frames.ndim == 0:
            frames = int(frames)
        if isinstance(frames, (int, np.integer)):
            if not -self.shape[0] <= frames < self.shape[0]:
                raise IndexError(f"frame {frames} out of range for {self.shape[0]} frames")
            k = int(frames) % self.shape[0]
            out = dequantize(self.q[k:k + 1], self.origin[k:k + 1], self.step[k:k + 1])[0]
            return out[rest] if rest else out
        out = dequantize(self.q[frames], self.origin[frames], self.step[frames])
        return out[(slice(None), *rest)] if rest else out

    def __array__(self, dtype=None, copy=None):
        out = dequantize(self.q, self.origin, self.step)
        return out if dtype is None else out.astype(dtype)
