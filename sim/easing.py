"""Easing curves: ramps from 0 to 1 on [0, 1], clamped outside, with flat ends.

``smoothstep`` (cubic, C1) eases procedural motions, the body's shape morph and the garment
templates' blends between rows; ``smootherstep`` (quintic, C2: zero acceleration at the ends
too) eases a motion in from the rest pose: a motion file's blend (``sim.motions.blend``) and the
procedural motions' lead-ins.
"""

from __future__ import annotations

import numpy as np


def smoothstep(x: np.ndarray | float) -> np.ndarray:
    """Cubic ramp 3x² - 2x³ of x clipped to [0, 1], in float64: zero slope at both ends."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def smootherstep(t: np.ndarray) -> np.ndarray:
    """Quintic ramp 6t⁵ - 15t⁴ + 10t³ of t clipped to [0, 1] (Horner form, in ``t``'s dtype):
    zero slope and zero acceleration at both ends."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * t * (t * (6.0 * t - 15.0) + 10.0)
