"""Baseline: linear blend skinning of the garment plus a learned pose-dependent displacement.

``x_t = LBS(x_rest + D_theta(x_rest, theta_t, beta), A_t) + trans_t``: the garment's rest
vertices take skinning weights from the nearest body vertices
(``sim.skinning.transfer.transfer_skinning_weights``), ``A_t`` are the body's bone transforms of
frame t, and ``D_theta`` is a per-vertex MLP of the vertex's rest position (Fourier-encoded), the
pose (24 joint rotations, 6D, Zhou et al. 2019) and the body shape. This is the pose-space
deformation family of TailorNet / SNUG reduced to a topology-free point-wise regressor, so one
model covers every size and cut of a garment category. It is the shared trainer's and
evaluation harness's first customer and the "skinning + displacement regressor" baseline of
the method tables; its zero-initialised last layer makes step 0 exactly the skinned garment.

Skinning runs through the Warp LBS kernel with its backward pass (``learn.skinning``): a batch of
garments with different weights is one launch, each sample's bones being its own block of
transforms.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from learn.data import rest_betas
from learn.methods.base import LossOutput, Method, Prediction
from sim.rotations import axis_angle_to_matrix

NUM_JOINTS = 24


@dataclass(frozen=True)
class SkinnedMLPConfig:
    """Network and data settings of the skinned-displacement baseline."""

    hidden: int = 256
    """Width of the hidden layers."""
    layers: int = 4
    """Number of hidden layers."""
    frequencies: int = 6
    """Fourier frequencies of the rest-position encoding (sin/cos of 2^k pi x / scale)."""
    encoding_scale: float = 2.0
    """Length [m] the lowest encoding frequency spans."""
    num_betas: int = 10
    """Body shape coefficients fed to the network (the dataset's first ones; zero-padded)."""
    vertices_per_item: int = 1024
    """Garment vertices drawn per training item (random subset; all when the garment has fewer)."""
    garments: tuple[str, ...] = ()
    """Garment categories to train on (empty: all in the dataset)."""
    skin_neighbours: int = 4
    """Body vertices blended for each garment vertex's skinning weights."""


def pose_transforms(poses: np.ndarray, joints: np.ndarray, rest_joints: np.ndarray,
                    parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bone transforms ``A`` (world from rest pose) and local rotations of a posed body.

    Args:
        poses: axis-angle [rad], (T, 24, 3).
        joints: posed joint positions [m] (world, translation included), (T, 24, 3).
        rest_joints: rest joint positions [m] of the shaped body, (24, 3).
        parents: (24,) parent index, -1 for the root.

    Returns:
        ``A`` (T, 24, 3, 4): ``x_world = R_j x_rest + (joint_j - R_j rest_joint_j)`` for a point
        carried rigidly by joint j (SMPL's skinning matrices), and the local rotations (T, 24, 3, 3).
    """
    T = poses.shape[0]
    local = axis_angle_to_matrix(poses.reshape(-1, 3)).reshape(T, NUM_JOINTS, 3, 3)
    glob = np.empty_like(local)
    for j in range(NUM_JOINTS):
        p = parents[j]
        glob[:, j] = local[:, j] if p < 0 else glob[:, p] @ local[:, j]
    A = np.empty((T, NUM_JOINTS, 3, 4), np.float32)
    A[..., :3] = glob
    A[..., 3] = joints - np.einsum("tjab,jb->tja", glob, rest_joints)
    return A, local.astype(np.float32)


def rotation_features(local: np.ndarray) -> np.ndarray:
    """6D rotation features (first two columns), (T, 24, 3, 3) -> (T, 144)."""
    return np.ascontiguousarray(local[..., :2].transpose(0, 1, 3, 2)).reshape(local.shape[0], -1)


class SkinnedMLP(nn.Module):
    """Per-vertex displacement MLP: (rest position, pose, shape) -> rest-space offset [m]."""

    def __init__(self, cfg: SkinnedMLPConfig):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("freqs", (2.0 ** torch.arange(cfg.frequencies)) * math.pi / cfg.encoding_scale,
                             persistent=False)
        width = 3 + 6 * cfg.frequencies + 6 * NUM_JOINTS + cfg.num_betas
        layers: list[nn.Module] = []
        for _ in range(cfg.layers):
            layers += [nn.Linear(width, cfg.hidden), nn.SiLU()]
            width = cfg.hidden
        head = nn.Linear(width, 3)
        nn.init.zeros_(head.weight)
        nn.init.zeros_(head.bias)
        self.mlp = nn.Sequential(*layers, head)

    def forward(self, rest: torch.Tensor, pose: torch.Tensor, betas: torch.Tensor) -> torch.Tensor:
        """Displacements [m], (B, N, 3), for rest points (B, N, 3), pose features (B, 144) and
        betas (B, num_betas)."""
        ang = rest[..., None] * self.freqs  # (B, N, 3, F)
        enc = torch.cat([rest, ang.sin().flatten(-2), ang.cos().flatten(-2)], dim=-1)
        cond = torch.cat([pose, betas], dim=-1)[:, None].expand(-1, rest.shape[1], -1)
        return self.mlp(torch.cat([enc, cond], dim=-1))


def skin_batch(points: torch.Tensor, weights: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
    """LBS of B point sets with their own weights (B, N, J) and transforms (B, J, 3, 4) in one
    Warp launch: sample b's bones are block b of a (1, B*J) transform array."""
    from learn.skinning import linear_blend_skinning

    B, N, J = weights.shape
    idx = (torch.arange(J, device=points.device, dtype=torch.int32)[None, None]
           + (torch.arange(B, device=points.device, dtype=torch.int32) * J)[:, None, None]).expand(B, N, J)
    out = linear_blend_skinning(points.reshape(1, B * N, 3), transforms.reshape(1, B * J, 3, 4),
                                weight_idx=idx.reshape(B * N, J), weight_val=weights.reshape(B * N, J))
    return out.reshape(B, N, 3)


class _Prepared:
    """Per-sequence arrays the method derives once per process (weights, transforms, features)."""

    def __init__(self, method: SkinnedMLPMethod, seq: Mapping[str, np.ndarray]):
        from sim.skinning.transfer import transfer_skinning_weights

        body = method.body(str(seq.get("body/model", "default")))
        betas = np.asarray(seq["body/betas"], np.float32).reshape(-1)
        made_on = rest_betas(seq, body.num_betas)  # the garment's rest body, carried to the posed joints
        self.rest = np.array(seq["fine/rest_vertices"], np.float32)  # a writable copy
        self.weights = transfer_skinning_weights(self.rest, body.rest_mesh(made_on), body.weights,
                                                 k=method.config.skin_neighbours).astype(np.float32)
        self.A, local = pose_transforms(np.asarray(seq["body/poses"], np.float32),
                                        np.asarray(seq["body/joints"], np.float32),
                                        body.rest_joints(made_on), np.asarray(body.parents))
        # A's translation already holds the root translation (joints are world positions)
        self.pose = rotation_features(local)
        nb = method.config.num_betas
        self.betas = np.zeros(nb, np.float32)
        self.betas[: min(nb, betas.size)] = betas[:nb]


class _TrainItems(torch.utils.data.Dataset):
    """Frames of the train split; item ``(index, seed)`` draws a vertex subset from ``seed``."""

    KEYS = ("fine/vertices", "fine/rest_vertices", "body/poses", "body/joints", "body/betas", "body/trans")

    def __init__(self, method: SkinnedMLPMethod, root):
        from learn.data import GarmentSequenceDataset

        self.method = method
        self.frames = GarmentSequenceDataset(root, "train", window=1, keys=("fine/vertices",),
                                             garments=method.config.garments or None)
        self._prepared: dict[str, _Prepared] = {}

    def __len__(self) -> int:
        return len(self.frames)

    def _prep(self, sid: str) -> _Prepared:
        if sid not in self._prepared:
            from learn.data import sequence_inputs

            keys = [k for k in self.KEYS if k != "fine/vertices"]
            seq = sequence_inputs(self.frames.open_sequence(sid), self.frames.entries[sid],
                                  self.frames.generator_config, keys)
            self._prepared[sid] = _Prepared(self.method, seq)
        return self._prepared[sid]

    def __getitem__(self, key: tuple[int, int]) -> dict:
        index, seed = key
        sid, t = self.frames.locate(index)
        prep = self._prep(sid)
        target = self.frames[index]["fine/vertices"][0].numpy()
        V, n = target.shape[0], self.method.config.vertices_per_item
        rng = np.random.default_rng(seed)
        sel = rng.choice(V, n, replace=V < n)
        return {"rest": torch.from_numpy(prep.rest[sel]), "weights": torch.from_numpy(prep.weights[sel]),
                "transforms": torch.from_numpy(prep.A[t]), "pose": torch.from_numpy(prep.pose[t]),
                "betas": torch.from_numpy(prep.betas), "target": torch.from_numpy(target[sel])}

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_prepared": {}}


class SkinnedMLPMethod(Method):
    """The skinned displacement regressor (module docstring)."""

    name = "skinned_mlp"
    Config = SkinnedMLPConfig

    @classmethod
    def validate_config(cls, config: SkinnedMLPConfig, err) -> None:
        for f in ("hidden", "layers", "vertices_per_item", "skin_neighbours"):
            if getattr(config, f) < 1:
                raise err(f"model.{f} must be >= 1, got {getattr(config, f)}")
        if config.frequencies < 0 or config.num_betas < 0 or not config.encoding_scale > 0:
            raise err("model.frequencies and num_betas must be >= 0, encoding_scale > 0")

    @functools.cache  # noqa: B019 - one body model per method object is the point
    def body(self, name: str = "default"):
        """The body model the dataset was simulated on (``"default"`` or a model file)."""
        from sim.bodies import load_body

        return load_body(name)

    def build_model(self) -> nn.Module:
        return SkinnedMLP(self.config)

    def train_dataset(self, root) -> torch.utils.data.Dataset:
        return _TrainItems(self, root)

    def training_loss(self, model: nn.Module, batch: dict, generator: torch.Generator) -> LossOutput:
        disp = model(batch["rest"], batch["pose"], batch["betas"])
        pred = skin_batch(batch["rest"] + disp.float(), batch["weights"], batch["transforms"])
        err = pred - batch["target"]
        loss = err.square().sum(-1).mean()
        return LossOutput(loss, {"vertex_error": err.detach().norm(dim=-1).mean(),
                                 "displacement": disp.detach().norm(dim=-1).mean()})

    @torch.no_grad()
    def predict_sequence(self, model: nn.Module, sequence: Mapping[str, np.ndarray], *,
                         device: torch.device, chunk: int = 16) -> Prediction:
        from learn.skinning import linear_blend_skinning

        prep = _Prepared(self, sequence)
        T = prep.A.shape[0]
        rest = torch.from_numpy(prep.rest).to(device)
        weights = torch.from_numpy(prep.weights).to(device)
        betas = torch.from_numpy(prep.betas).to(device)
        out = np.empty((T, *prep.rest.shape), np.float32)
        for s in range(0, T, chunk):
            e = min(T, s + chunk)
            pose = torch.from_numpy(prep.pose[s:e]).to(device)
            disp = model(rest[None].expand(e - s, -1, -1), pose, betas[None].expand(e - s, -1))
            x = linear_blend_skinning(rest[None] + disp.float(), torch.from_numpy(prep.A[s:e]).to(device),
                                      weights)
            out[s:e] = x.cpu().numpy()
        return Prediction(vertices=out)
