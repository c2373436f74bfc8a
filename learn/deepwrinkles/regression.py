"""DeepWrinkles' pose-to-shape prediction (Lähner et al. 2018, Sec. 3.3): a map f from the body's
control vector Θ to the garment subspace's coefficients Λ (``learn.deepwrinkles.subspace``).

Θ per frame (``control_vectors``): every joint's rotation as the continuous 6D representation
(Zhou et al. 2019; the root's with its heading about the vertical taken out, since turning on
the spot does not change a pose-normalised garment but tilting against gravity does), and the
root's velocity and acceleration in the heading frame (finite differences at the motion's frame
rate), as the paper composes Θ from the joint poses plus the root's velocity and acceleration.

Two maps, as in the paper: the linear regression ``F = Λ Θ†`` (``LinearPoseToShape``, the
Moore-Penrose inverse through a least-squares solve, with a bias), and a sequence-to-sequence
encoder-decoder of LSTM layers (``PoseToShapeLSTM``: 4 layers of 256 units by default) that reads
the control vectors of a short window of frames (3) and emits the coefficients of each, so the
folds can depend on the direction and speed of the motion and not only on the pose.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from learn.methods.skinned_mlp import rotation_features
from sim.errors import WrinklesInputError
from sim.rotations import axis_angle_to_matrix

ROOT_MOTION = 6
"""Control-vector entries after the joints' 6D rotations: root velocity [m/s], acceleration [m/s²]."""


CONTROL_JOINTS = {
    "all": None,
    "upper": (0, 3, 6, 9, 12, 13, 14, 16, 17, 18, 19),
    "lower": (0, 1, 2, 3, 4, 5, 7, 8),
}
"""Joints whose rotations enter Θ (SMPL order: pelvis, spine 1-3, neck, collars, shoulders, elbows
for "upper"; pelvis, hips, spine 1, knees, ankles for "lower"; None: every joint). Sec. 5.3:
the joint parameters are restricted to those of the piece of clothing (the upper body for
shirts) to lower the regression's dimension."""


def control_columns(joints: str, num_joints: int) -> np.ndarray:
    """Columns of the control vectors of ``control_vectors`` (``num_joints`` joints) that a
    ``CONTROL_JOINTS`` set keeps: the 6D rotations of its joints and the root motion."""
    keep = CONTROL_JOINTS[joints]
    if keep is None:
        return np.arange(6 * num_joints + ROOT_MOTION)
    if max(keep) >= num_joints:
        raise WrinklesInputError(f"control joints {joints!r} need {max(keep) + 1} joints, "
                                 f"the motion has {num_joints}")
    rot = (6 * np.asarray(keep)[:, None] + np.arange(6)).ravel()
    return np.concatenate([rot, 6 * num_joints + np.arange(ROOT_MOTION)])


def heading_rotations(root: np.ndarray) -> np.ndarray:
    """Rotations about +Y (up) that carry +Z to each root rotation's forward axis projected on the
    ground, (T, 3, 3), from root rotations (T, 3, 3); +Z where the forward axis points up or down."""
    f = root[:, :, 2]
    yaw = np.arctan2(f[:, 0], f[:, 2])
    yaw = np.where(np.hypot(f[:, 0], f[:, 2]) < 1e-9, 0.0, yaw)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((len(root), 3, 3))
    out[:, 0, 0], out[:, 0, 2], out[:, 1, 1], out[:, 2, 0], out[:, 2, 2] = c, s, 1.0, -s, c
    return out


def control_vectors(poses: np.ndarray, trans: np.ndarray, fps: float) -> np.ndarray:
    """Θ of every frame of a motion, float32 (T, 6 J + 6).

    Args:
        poses: axis-angle joint rotations [rad], (T, J, 3) (SMPL order, the root first).
        trans: root translation [m], (T, 3).
        fps: frame rate [1/s] of the finite differences.
    """
    p = np.asarray(poses, np.float64)
    x = np.asarray(trans, np.float64)
    if p.ndim != 3 or p.shape[-1] != 3 or x.shape != (len(p), 3) or len(p) == 0:
        raise WrinklesInputError(f"control_vectors: poses {p.shape} and trans {x.shape}: "
                                 "expected (T, J, 3), (T, 3)")
    if fps <= 0:
        raise WrinklesInputError(f"control_vectors: fps must be > 0, got {fps}")
    rot = axis_angle_to_matrix(p.reshape(-1, 3)).reshape(*p.shape[:2], 3, 3)
    head = heading_rotations(rot[:, 0])
    rot[:, 0] = np.einsum("tba,tbc->tac", head, rot[:, 0])  # heading removed: head^T R_root
    six = rotation_features(rot)
    vel = np.gradient(x, axis=0) * fps if len(x) > 1 else np.zeros_like(x)
    acc = np.gradient(vel, axis=0) * fps if len(x) > 1 else np.zeros_like(x)
    local = np.einsum("tba,tnb->tna", head, np.stack([vel, acc], axis=1)).reshape(len(p), ROOT_MOTION)
    return np.concatenate([six, local], axis=1).astype(np.float32)


@dataclass(frozen=True)
class LinearPoseToShape:
    """``Λ = F [Θ; 1]``: the least-squares linear map from control vectors to coefficients.

    Attributes:
        matrix: F, float64 (k, C + 1), the last column the bias.
    """

    matrix: np.ndarray

    @classmethod
    def fit(cls, controls: np.ndarray, coefficients: np.ndarray, *, ridge: float = 0.0) -> LinearPoseToShape:
        """F minimising ``|Λ - F [Θ; 1]|²`` (+ ``ridge`` |F|² without the bias) over frames:
        controls (n, C), coefficients (n, k)."""
        th = np.asarray(controls, np.float64)
        lam = np.asarray(coefficients, np.float64)
        if ridge < 0:
            raise WrinklesInputError(f"LinearPoseToShape.fit: ridge must be >= 0, got {ridge}")
        if th.ndim != 2 or lam.ndim != 2 or len(th) != len(lam) or len(th) == 0:
            raise WrinklesInputError(f"LinearPoseToShape.fit: controls {th.shape} and coefficients "
                                     f"{lam.shape} need the same number of frames")
        a = np.concatenate([th, np.ones((len(th), 1))], axis=1)
        if ridge > 0.0:
            reg = np.sqrt(ridge) * np.eye(a.shape[1])[:-1]
            a, lam = np.concatenate([a, reg]), np.concatenate([lam, np.zeros((len(reg), lam.shape[1]))])
        f, *_ = np.linalg.lstsq(a, lam, rcond=None)  # the Moore-Penrose solution
        return cls(np.ascontiguousarray(f.T))

    def __call__(self, controls: np.ndarray) -> np.ndarray:
        """Λ of control vectors (T, C): float32 (T, k)."""
        th = np.asarray(controls, np.float64)
        if th.ndim != 2 or th.shape[1] + 1 != self.matrix.shape[1]:
            raise WrinklesInputError(f"LinearPoseToShape: controls {th.shape}, "
                                     f"expected (T, {self.matrix.shape[1] - 1})")
        return (th @ self.matrix[:, :-1].T + self.matrix[:, -1]).astype(np.float32)

    def save(self, path: str | Path) -> None:
        """Write F to ``path`` (.npz, no pickles)."""
        np.savez(path, matrix=self.matrix)

    @classmethod
    def load(cls, path: str | Path) -> LinearPoseToShape:
        """Read a map written by ``save``."""
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(z["matrix"])
        except (OSError, KeyError, ValueError) as e:
            raise WrinklesInputError(f"not a linear pose-to-shape file: {e}", path=path) from None


class PoseToShapeLSTM(nn.Module):
    """Sequence-to-sequence LSTM encoder-decoder from control vectors to subspace coefficients.

    The encoder reads a window's control vectors (B, W, C); the decoder, started from the
    encoder's state, reads them again and emits each frame's coefficients (B, W, k) through a
    linear head. Every output sees the whole window; the last frame's, which a sequence's
    prediction uses (``windows``), depends on the motion up to that frame only.

    Args:
        controls: C, the control vector's size. coefficients: k.
        hidden: units per LSTM layer. layers: LSTM layers of the encoder and of the decoder.
    """

    def __init__(self, controls: int, coefficients: int, *, hidden: int = 256, layers: int = 4):
        super().__init__()
        self.controls, self.coefficients = int(controls), int(coefficients)
        self.encoder = nn.LSTM(controls, hidden, num_layers=layers, batch_first=True)
        self.decoder = nn.LSTM(controls, hidden, num_layers=layers, batch_first=True)
        self.head = nn.Linear(hidden, coefficients)

    def forward(self, controls: torch.Tensor) -> torch.Tensor:
        if controls.ndim != 3 or controls.shape[-1] != self.controls:
            raise WrinklesInputError(f"PoseToShapeLSTM: controls {tuple(controls.shape)}, "
                                     f"expected (B, W, {self.controls})")
        _, state = self.encoder(controls)
        out, _ = self.decoder(controls, state)
        return self.head(out)


def windows(controls: np.ndarray, length: int = 3) -> np.ndarray:
    """The window of ``length`` frames ending at each frame of a sequence's control vectors
    (T, C): float32 (T, length, C), the first frames padded by repeating frame 0."""
    th = np.asarray(controls, np.float32)
    if th.ndim != 2 or length < 1:
        raise WrinklesInputError(f"windows: controls {th.shape} (expected (T, C)) and length {length} (>= 1)")
    pad = np.concatenate([np.repeat(th[:1], length - 1, axis=0), th])
    idx = np.arange(len(th))[:, None] + np.arange(length)[None]
    return pad[idx]
