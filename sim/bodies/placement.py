"""Placing a posed body in the world: standing it on the floor (y = 0)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sim.types import BodyFrames


def floor_offset(frames: BodyFrames, *, frame: int = 0) -> float:
    """Vertical shift [m] that puts the lowest vertex of ``frame`` on the floor y = 0."""
    return float(-frames.vertices[frame, :, 1].min())


def translate_frames(frames: BodyFrames, offset: np.ndarray) -> BodyFrames:
    """The same sequence moved by ``offset`` [m], shape (3,)."""
    off = np.asarray(offset, dtype=np.float32).reshape(3)
    tf = frames.transforms.copy()
    tf[:, :, :3, 3] += off
    return replace(frames, vertices=frames.vertices + off, joints=frames.joints + off, transforms=tf)


def ground(frames: BodyFrames) -> tuple[BodyFrames, float]:
    """Stand the sequence on the floor: shift so frame 0's lowest vertex is at y = 0.

    Returns:
        (shifted frames, the vertical shift [m]).
    """
    dy = floor_offset(frames)
    return translate_frames(frames, np.array([0.0, dy, 0.0])), dy
