"""Body-conditioned coarse garment: a virtual skeleton driven by a CVAE (Guo et al. 2024, Sec. 3.3).

The garment (one topology: a dataset made with ``[garments] fit = "reference"`` and fixed
template parameters) is rigged with a *virtual skeleton*: ``k`` rigid bones and sparse skinning
weights fitted by SSDR (Le & Deng 2012, ``sim.skinning.ssdr``) to the base surfaces
(``fine/base``, the smoothed simulation, as the paper's curved-Hessian-smoothed meshes) of the
training split, in the body's root frame (root translation removed). Every training frame is
labelled with the skeleton's transforms ``gamma`` (6 DoF per bone: a rotation as the 6D
representation of Zhou et al. 2019 and a translation; ``fit_bone_transforms``).

A conditional VAE learns ``p(gamma | theta, beta)``: the encoder maps ``(gamma, c)`` to
``q(z | gamma, c)``, the decoder ``G_phi(z, c)`` (Eq. 9) maps a latent and the condition
``c = (6D joint rotations of the SMPL pose, betas)`` back to ``gamma``; the base mesh is LBS of the
rest garment with the fitted weights (Eq. 8), plus the root translation. Loss: transform
reconstruction (standardised) + vertex positions of the skinned base against the data's base on a
random vertex subset + ``kl_weight`` KL(q || N(0, I)), plus (our addition, ``prior_weight``) the
same reconstruction terms decoded from ``z = 0``. Inference decodes ``z = 0`` (the mode of the prior;
``sample_latent`` draws ``z ~ N(0, I)`` instead, for variety).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from learn.methods.base import LossOutput, Method, Prediction
from sim.errors import WrinklesInputError

NUM_JOINTS = 24
GAMMA = 9  # 6D rotation + translation per bone


@dataclass(frozen=True)
class SkeletonCVAEConfig:
    """Virtual skeleton and CVAE settings."""

    garments: tuple[str, ...] = ()
    """Garment category to train on (empty: the dataset's; it must have one topology)."""
    num_bones: int = 64
    """Virtual bones k (Guo et al.: 64)."""
    max_influences: int = 4
    """Non-zero skinning weights per vertex."""
    ssdr_frames: int = 400
    """Training frames (evenly spread) the SSDR weights are fitted on."""
    ssdr_iterations: int = 12
    """SSDR alternations."""
    latent: int = 32
    """Size of z."""
    hidden: int = 512
    """Width of the encoder and decoder MLPs."""
    layers: int = 3
    """Hidden layers of the encoder and of the decoder."""
    num_betas: int = 10
    """Body shape coefficients in the condition (zero-padded)."""
    kl_weight: float = 1e-3
    """Weight of the KL term."""
    vertex_weight: float = 1.0
    """Weight of the vertex term (per cm², so 1 mm error = 0.01)."""
    vertices_per_item: int = 2048
    """Garment vertices compared per training item."""
    prior_weight: float = 1.0
    """Weight of the same reconstruction terms decoded from the prior mean z = 0 (what inference
    uses); without it a decoder that leans on z fits the posterior and misses at z = 0."""


def pose_condition(poses: np.ndarray, betas: np.ndarray, num_betas: int) -> np.ndarray:
    """Condition vectors (T, 144 + num_betas): 6D rotations of the 24 joints and the betas."""
    from learn.methods.skinned_mlp import rotation_features
    from sim.rotations import axis_angle_to_matrix

    p = np.asarray(poses, np.float32).reshape(-1, NUM_JOINTS, 3)
    local = axis_angle_to_matrix(p.reshape(-1, 3)).reshape(len(p), NUM_JOINTS, 3, 3)
    b = np.zeros(num_betas, np.float32)
    src = np.asarray(betas, np.float32).reshape(-1)[:num_betas]
    b[: len(src)] = src
    return np.concatenate([rotation_features(local), np.broadcast_to(b, (len(p), num_betas))], axis=1).astype(
        np.float32
    )


def gamma_of(rot: np.ndarray, tr: np.ndarray) -> np.ndarray:
    """Bone transforms (T, J, 3, 3), (T, J, 3) -> gamma (T, J * 9): 6D columns + translation."""
    six = np.concatenate([rot[..., :, 0], rot[..., :, 1]], axis=-1)
    return np.concatenate([six, tr], axis=-1).reshape(len(rot), -1).astype(np.float32)


def _mlp(d_in: int, hidden: int, layers: int, d_out: int) -> nn.Sequential:
    mods: list[nn.Module] = []
    for _ in range(layers):
        mods += [nn.Linear(d_in, hidden), nn.SiLU()]
        d_in = hidden
    return nn.Sequential(*mods, nn.Linear(d_in, d_out))


class SkeletonCVAE(nn.Module):
    """CVAE over virtual-bone transforms plus the skeleton (rest garment and weights) as buffers."""

    def __init__(self, cfg: SkeletonCVAEConfig, state: Mapping[str, torch.Tensor]):
        super().__init__()
        self.cfg = cfg
        for k in ("rest", "weight_idx", "weight_val", "gamma_mean", "gamma_std"):
            self.register_buffer(k, torch.as_tensor(state[k]).clone())
        self.num_bones = int(self.weight_idx.max()) + 1
        d_gamma = self.num_bones * GAMMA
        d_cond = 6 * NUM_JOINTS + cfg.num_betas
        self.encoder = _mlp(d_gamma + d_cond, cfg.hidden, cfg.layers, 2 * cfg.latent)
        self.decoder = _mlp(cfg.latent + d_cond, cfg.hidden, cfg.layers, d_gamma)

    def encode(self, gamma_n: torch.Tensor, cond: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mu, logvar = self.encoder(torch.cat([gamma_n, cond], dim=-1)).chunk(2, dim=-1)
        return mu, logvar.clamp(-12.0, 8.0)

    def decode(self, z: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """Standardised gamma (B, J * 9) from latents (B, latent) and conditions (B, d_cond)."""
        return self.decoder(torch.cat([z, cond], dim=-1))

    def skin(self, gamma_n: torch.Tensor, vertices: torch.Tensor | None = None) -> torch.Tensor:
        """Root-frame base positions [m] (B, N, 3) of standardised transforms (B, J * 9), at all
        vertices, the indices ``vertices`` (N,), or one index set per sample (B, N) (Guo et al.
        Eq. 8)."""
        from learn.skinning import rotation_6d_to_matrix

        g = (gamma_n.float() * self.gamma_std + self.gamma_mean).reshape(len(gamma_n), self.num_bones, GAMMA)
        R = rotation_6d_to_matrix(g[..., :6])  # (B, J, 3, 3)
        t = g[..., 6:]
        v = torch.arange(len(self.rest), device=R.device) if vertices is None else vertices
        v = v.expand(len(g), -1) if v.ndim == 1 else v  # (B, N)
        idx, w, rest = self.weight_idx[v], self.weight_val[v], self.rest[v]  # (B, N, K), (B, N, K), (B, N, 3)
        b = torch.arange(len(g), device=R.device)[:, None, None]
        moved = torch.einsum("bnkij,bnj->bnki", R[b, idx], rest) + t[b, idx]
        return (moved * w[..., None]).sum(dim=2)

    def forward(self, gamma_n: torch.Tensor, cond: torch.Tensor, noise: torch.Tensor):
        mu, logvar = self.encode(gamma_n, cond)
        z = mu + noise * (0.5 * logvar).exp()
        return self.decode(z, cond), mu, logvar


class _Frames(torch.utils.data.Dataset):
    def __init__(self, method: SkeletonCVAEMethod, root):
        self.method = method
        self.ds, self.labels = method.labelled_frames(root)

    def __len__(self) -> int:
        return len(self.ds)

    def __getitem__(self, key) -> dict:
        index, seed = key
        sid, t = self.ds.locate(index)
        f = self.ds.open_sequence(sid)
        m = self.method
        cond = pose_condition(f["body/poses"][t : t + 1], f["body/betas"], m.config.num_betas)[0]
        V = f.shape("fine/base")[1]
        n = min(m.config.vertices_per_item, V)
        sub = np.sort(np.random.default_rng(seed).choice(V, n, replace=False))
        target = np.asarray(f["fine/base"][t], np.float32)[sub] - np.asarray(f["body/trans"][t], np.float32)
        g = (self.labels[sid][t] - m.state["gamma_mean"].numpy()) / m.state["gamma_std"].numpy()
        return {
            "gamma": torch.from_numpy(g.astype(np.float32)),
            "cond": torch.from_numpy(cond),
            "vertices": torch.from_numpy(sub.astype(np.int64)),
            "target": torch.from_numpy(target),
        }


class SkeletonCVAEMethod(Method):
    """Guo et al. 2024's coarse garment model (see the module docstring)."""

    name = "skeleton_cvae"
    Config = SkeletonCVAEConfig

    @classmethod
    def validate_config(cls, config: SkeletonCVAEConfig, err) -> None:
        if not 1 <= config.max_influences <= min(8, config.num_bones):
            raise err(f"max_influences must be in [1, min(8, num_bones)], got {config.max_influences}")
        if (
            min(
                config.num_bones,
                config.ssdr_frames,
                config.ssdr_iterations,
                config.latent,
                config.hidden,
                config.layers,
                config.vertices_per_item,
            )
            < 1
        ):
            raise err(
                "num_bones, ssdr_frames, ssdr_iterations, latent, hidden, layers and vertices_per_item "
                "must be >= 1"
            )

    def _dataset(self, root):
        from learn.data import GarmentSequenceDataset

        keys = [
            "fine/base",
            "fine/rest_vertices",
            "fine/faces",
            "fine/uvs",
            "fine/uv_faces",
            "body/poses",
            "body/trans",
            "body/betas",
        ]
        ds = GarmentSequenceDataset(root, "train", keys=keys, garments=self.config.garments or None)
        if len(ds) == 0:
            raise WrinklesInputError("no training frames", path=ds.root)
        faces = None
        for sid in ds.sequence_ids:
            f = np.asarray(ds.open_sequence(sid)["fine/faces"])
            if faces is None:
                faces, first = f, sid
            elif f.shape != faces.shape or not np.array_equal(f, faces):
                raise WrinklesInputError(
                    f"sequences {first} and {sid} have different garment meshes; the virtual skeleton "
                    "needs one "
                    'topology: generate with [garments] fit = "reference", fixed template parameters and '
                    "one category (or set model.garments)",
                    path=ds.root,
                )
        return ds

    @staticmethod
    def _root_frames(f, ts) -> np.ndarray:
        return (
            np.asarray(f["fine/base"][ts], np.float32) - np.asarray(f["body/trans"][ts], np.float32)[:, None]
        )

    def prepare(self, root) -> dict:
        """Fit the virtual skeleton (SSDR) and the transform statistics on the training split."""
        from sim.skinning.ssdr import fit_ssdr

        cfg = self.config
        ds = self._dataset(root)
        f0 = ds.open_sequence(ds.sequence_ids[0])
        rest = np.asarray(f0["fine/rest_vertices"], np.float32)
        pick = np.unique(np.linspace(0, len(ds) - 1, min(cfg.ssdr_frames, len(ds))).round().astype(int))
        by_seq: dict[str, list[int]] = {}
        for i in pick:
            sid, t = ds.locate(int(i))
            by_seq.setdefault(sid, []).append(t)
        frames = np.concatenate([self._root_frames(ds.open_sequence(s), ts) for s, ts in by_seq.items()])
        sk = fit_ssdr(
            rest,
            frames,
            num_bones=cfg.num_bones,
            max_influences=cfg.max_influences,
            iterations=cfg.ssdr_iterations,
            seed=0,
        )
        e0 = ds.entries[ds.sequence_ids[0]]
        state = {
            "rest": torch.from_numpy(rest.copy()),
            "weight_idx": torch.from_numpy(sk.weight_idx.astype(np.int64)),
            "weight_val": torch.from_numpy(sk.weight_val.copy()),
            "faces": torch.from_numpy(np.array(f0["fine/faces"], np.int32)),
            "uvs": torch.from_numpy(np.array(f0["fine/uvs"], np.float32)),
            "uv_faces": torch.from_numpy(np.array(f0["fine/uv_faces"], np.int32)),
            "ssdr_rmse": float(sk.rmse),
            "garment": str(e0.get("garment")),
            "garment_params": dict(e0.get("garment_params") or {}),
            "body_model": str((ds.generator_config.get("bodies") or {}).get("model", "default")),
        }
        if "fine/face_layers" in f0:  # hems, where the dataset stores them: carried to the USD it animates
            state["face_layers"] = torch.from_numpy(np.array(f0["fine/face_layers"], np.float32))
        self.state = state
        _, labels = self.labelled_frames(root, ds=ds)
        allg = np.concatenate(list(labels.values()))
        state["gamma_mean"] = torch.from_numpy(allg.mean(0).astype(np.float32))
        state["gamma_std"] = torch.from_numpy(np.maximum(allg.std(0), 1e-4).astype(np.float32))
        return state

    def labelled_frames(self, root, *, ds=None):
        """The training frames and their skeleton transforms gamma (T, J * 9) per sequence
        (computed once per method instance)."""
        from sim.skinning.ssdr import fit_bone_transforms

        if getattr(self, "_labels", None) is not None and ds is None:
            return self._labels
        ds = ds or self._dataset(root)
        rest = self.state["rest"].numpy()
        idx, val = self.state["weight_idx"].numpy(), self.state["weight_val"].numpy()
        labels = {}
        for sid in ds.sequence_ids:
            f = ds.open_sequence(sid)
            T = f.shape("fine/base")[0]
            rot, tr = fit_bone_transforms(rest, idx, val, self._root_frames(f, np.arange(T)), iterations=3)
            labels[sid] = gamma_of(rot, tr)
        self._labels = (ds, labels)
        return self._labels

    def build_model(self) -> torch.nn.Module:
        if not self.state:
            raise ValueError("skeleton_cvae: prepare() or load_state() before build_model()")
        return SkeletonCVAE(self.config, self.state)

    def train_dataset(self, root) -> torch.utils.data.Dataset:
        return _Frames(self, root)

    def training_loss(self, model, batch, generator: torch.Generator) -> LossOutput:
        net = model.module if hasattr(model, "module") else model
        cfg = self.config
        gamma, cond = batch["gamma"], batch["cond"]
        noise = torch.randn((len(gamma), cfg.latent), generator=generator, device=generator.device).to(
            gamma.device
        )
        recon, mu, logvar = model(gamma, cond, noise)
        verts = batch["vertices"]  # (B, N): per-item subsets

        def terms(g_hat):
            l_gamma = ((g_hat.float() - gamma) ** 2).mean()
            pred = net.skin(g_hat, verts)
            return l_gamma, ((pred - batch["target"]) ** 2).sum(-1).mean() * 1e4  # cm^2

        l_gamma, l_vert = terms(recon)
        kl = (-0.5 * (1 + logvar - mu**2 - logvar.exp()).sum(-1)).mean()
        loss = l_gamma + cfg.vertex_weight * l_vert + cfg.kl_weight * kl
        scalars = {
            "gamma_mse": l_gamma.detach(),
            "vertex_cm2": l_vert.detach(),
            "kl": kl.detach(),
            "vertex_rmse_mm": l_vert.detach().sqrt() * 10.0,
        }
        if cfg.prior_weight > 0:  # the prior's mean z = 0 must decode to the data too (inference)
            p_gamma, p_vert = terms(net.decode(torch.zeros_like(mu), cond))
            loss = loss + cfg.prior_weight * (p_gamma + cfg.vertex_weight * p_vert)
            scalars["prior_vertex_rmse_mm"] = p_vert.detach().sqrt() * 10.0
        return LossOutput(loss, scalars)

    # ------------------------------------------------------------------ inference
    def base_from_body(
        self,
        model,
        poses: np.ndarray,
        trans: np.ndarray,
        betas: np.ndarray,
        *,
        device: torch.device | str = "cpu",
        sample_latent: bool = False,
        seed: int = 0,
        batch: int = 256,
    ) -> np.ndarray:
        """Base garment [m] (T, V, 3) for a body motion: poses (T, 24, 3) axis-angle, root
        translation (T, 3) as the body is placed (grounded), betas (B,)."""
        device = torch.device(device)
        cond = torch.from_numpy(pose_condition(poses, betas, self.config.num_betas)).to(device)
        gen = torch.Generator(device=device).manual_seed(int(seed))
        out = []
        with torch.no_grad():
            for s in range(0, len(cond), batch):
                c = cond[s : s + batch]
                z = (
                    torch.randn((len(c), self.config.latent), generator=gen, device=device)
                    if sample_latent
                    else torch.zeros((len(c), self.config.latent), device=device)
                )
                out.append(model.skin(model.decode(z, c)).cpu().numpy())
        return (np.concatenate(out) + np.asarray(trans, np.float32)[:, None]).astype(np.float32)

    def predict_sequence(
        self, model, sequence: Mapping[str, np.ndarray], *, device: torch.device
    ) -> Prediction:
        faces = np.asarray(sequence["fine/faces"])
        if faces.shape != tuple(self.state["faces"].shape) or not np.array_equal(
            faces, self.state["faces"].numpy()
        ):
            raise WrinklesInputError(
                f"this coarse model rigs a {self.state.get('garment')} of "
                f"{len(self.state['rest'])} vertices; the sequence's garment differs"
            )
        base = self.base_from_body(
            model,
            np.asarray(sequence["body/poses"]),
            np.asarray(sequence["body/trans"]),
            np.asarray(sequence["body/betas"]),
            device=device,
        )
        return Prediction(base)
