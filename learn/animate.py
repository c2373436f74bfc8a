"""Motion in, wrinkled garment out: Guo et al. 2024's inference pipeline (Fig. 2a).

body (pose, shape) -> CVAE -> virtual-bone transforms -> LBS base mesh (``skeleton_cvae``) ->
Green-Lagrange strain of the base (UV map) -> DDIM wrinkle field (``wrinkle_diffusion``) ->
decoded onto the base -> wrinkled garment. The garment is the coarse model's rig (the mean-shape
cut of its training data); the body is re-posed with the same body model for the output.

Shipped defaults (``pretrained/``, see ``pretrained/MODEL_CARD.md``) are used when no model files
are given: ``pretrained/<category>-coarse.pt`` and ``pretrained/<category>-wrinkles.pt``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from sim.errors import WrinklesInputError

PRETRAINED = Path(__file__).resolve().parent.parent / "pretrained"
"""Folder of the shipped default weights."""


def pretrained_file(category: str, kind: str) -> Path:
    """The shipped release file ``pretrained/<category>-<kind>.pt`` (kind: coarse, wrinkles,
    deepwrinkles)."""
    return PRETRAINED / f"{category}-{kind}.pt"


def pretrained_paths(category: str) -> tuple[Path, Path]:
    """(coarse, wrinkles) release files of a garment category in :data:`PRETRAINED`."""
    return pretrained_file(category, "coarse"), pretrained_file(category, "wrinkles")


def shipped_categories(kind: str) -> list[str]:
    """Garment categories with a shipped ``pretrained/<category>-<kind>.pt``."""
    suffix = f"-{kind}.pt"
    return sorted(p.name[: -len(suffix)] for p in PRETRAINED.glob(f"*{suffix}"))


def available_pretrained() -> list[str]:
    """Garment categories with both shipped models."""
    return sorted(set(shipped_categories("coarse")) & set(shipped_categories("wrinkles")))


@dataclass
class AnimationResult:
    """A wrinkled garment sequence.

    Attributes:
        vertices: wrinkled garment [m], (T, V, 3).
        base: the coarse model's base mesh [m], (T, V, 3).
        faces, uvs, uv_faces: the garment mesh and its UV layout.
        wrinkle_maps: generated wrinkle fields [m], (T, H, W, 3) (None without wrinkles).
        seconds: wall time per stage (``coarse``, ``strain``, ``diffusion``, ``decode``).
    """

    vertices: np.ndarray
    base: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    uv_faces: np.ndarray
    wrinkle_maps: np.ndarray | None
    seconds: dict[str, float] = field(default_factory=dict)


class WrinklePipeline:
    """The two trained stages of one garment, loaded once.

    Args:
        coarse: ``skeleton_cvae`` checkpoint or release file.
        wrinkles: ``wrinkle_diffusion`` checkpoint or release file (None: the base alone).
        device: torch device.
    """

    def __init__(
        self, coarse: str | Path, wrinkles: str | Path | None, *, device: str | torch.device = "cpu"
    ):
        from learn.train.trainer import load_trained

        self.device = torch.device(device)
        self.coarse, self.coarse_model, ck = load_trained(coarse, device=self.device)
        if self.coarse.name != "skeleton_cvae":
            raise WrinklesInputError(f"expected a skeleton_cvae model, got {self.coarse.name}", path=coarse)
        self.wrinkles = self.wrinkles_model = None
        if wrinkles is not None:
            self.wrinkles, self.wrinkles_model, _ = load_trained(wrinkles, device=self.device)
            if self.wrinkles.name != "wrinkle_diffusion":
                raise WrinklesInputError(
                    f"expected a wrinkle_diffusion model, got {self.wrinkles.name}", path=wrinkles
                )
        st = self.coarse.state
        self.category = str(st.get("garment"))
        self.faces = st["faces"].numpy().astype(np.int32)
        self.rest = st["rest"].numpy()
        uvs, uv_faces = st.get("uvs"), st.get("uv_faces")
        if uvs is None:
            raise WrinklesInputError(
                "this coarse model has no UV layout (its checkpoint stores no 'uvs')", path=coarse
            )
        self.uvs, self.uv_faces = uvs.numpy(), uv_faces.numpy().astype(np.int32)
        layers = st.get("face_layers")  # absent where its training data stores none: one layer
        self.face_layers = None if layers is None else layers.numpy().astype(np.float32)
        self._maps = None

    def maps(self):
        from sim.geometry.wrinkle_maps import WrinkleMaps

        if self._maps is None:
            res = int(self.wrinkles.state["resolution"]) if self.wrinkles is not None else 128
            self._maps = WrinkleMaps(self.rest, self.faces, self.uvs, self.uv_faces, res)
        return self._maps

    def __call__(
        self,
        poses: np.ndarray,
        trans: np.ndarray,
        betas: np.ndarray,
        *,
        steps: int | None = None,
        material: str | None = None,
        seed: int = 0,
        sample_latent: bool = False,
        progress=None,
        body_vertices: np.ndarray | None = None,
        body_faces: np.ndarray | None = None,
        clearance: float = 0.002,
    ) -> AnimationResult:
        """Animate the garment for a body motion.

        Args:
            poses: SMPL axis-angle poses [rad], (T, 24, 3).
            trans: root translation [m] of the placed (grounded) body, (T, 3).
            betas: body shape (B,).
            steps: DDIM steps (default: the wrinkle model's config).
            material: material label (default: the first the model knows).
            seed: noise seed.
            sample_latent: draw the CVAE latent instead of using its mean.
            progress: ``progress(frames_done, frames_total)`` of the diffusion.
            body_vertices, body_faces: the posed body (T, Vb, 3) [m] and its faces; with them,
                garment vertices inside the body (or within ``clearance`` [m] of it) are moved
                out, on the base before its strain is taken and on the wrinkled result
                (``sim.quality.push_outside``; 0 or no body: off).
        """
        sec: dict[str, float] = {}

        def outside(x: np.ndarray) -> np.ndarray:
            return self._outside(x, body_vertices, body_faces, clearance, sec)

        t0 = time.perf_counter()
        base = self.coarse.base_from_body(
            self.coarse_model, poses, trans, betas, device=self.device, sample_latent=sample_latent, seed=seed
        )
        sec["coarse"] = time.perf_counter() - t0
        base = outside(base)
        if self.wrinkles is None:
            return AnimationResult(base, base, self.faces, self.uvs, self.uv_faces, None, sec)
        w = self._sample(base, steps=steps, material=material, seed=seed, progress=progress, sec=sec)
        t0 = time.perf_counter()
        fine = self.maps().decode(w, base)
        sec["decode"] = time.perf_counter() - t0
        fine = outside(fine)
        return AnimationResult(fine, base, self.faces, self.uvs, self.uv_faces, w, sec)

    def _outside(self, x: np.ndarray, body_vertices: np.ndarray | None, body_faces: np.ndarray | None,
                 clearance: float, sec: dict[str, float]) -> np.ndarray:
        """``x`` with the vertices inside the body (or within ``clearance``) moved out; ``x``
        itself without a body or at 0 clearance. Its time adds to ``sec["collision"]``."""
        from sim.quality import push_outside

        if body_vertices is None or body_faces is None or not clearance > 0:
            return x
        t1 = time.perf_counter()
        wdev = "cuda" if self.device.type == "cuda" else "cpu"
        y = push_outside(x, body_vertices, body_faces, clearance=clearance, device=wdev)
        sec["collision"] = sec.get("collision", 0.0) + time.perf_counter() - t1
        return y

    def _sample(self, base: np.ndarray, *, steps: int | None, material: str | None, seed: int, progress,
                sec: dict[str, float]) -> np.ndarray:
        """The wrinkle maps (T, H, W, 3) the diffusion model draws for the base's strain; times
        ``sec["strain"]`` and ``sec["diffusion"]``."""
        m = self.maps()
        t0 = time.perf_counter()
        cond = m.conditioning(base, self.wrinkles.config.conditioning)
        sec["strain"] = time.perf_counter() - t0
        if material is None:
            material = self.wrinkles.materials[0] if self.wrinkles.materials else None
        elif material not in self.wrinkles.materials:
            raise WrinklesInputError(
                f"material {material!r}: this wrinkle model knows {', '.join(self.wrinkles.materials)}"
            )
        t0 = time.perf_counter()
        w = self.wrinkles.sample_wrinkles(
            self.wrinkles_model,
            cond,
            m.mask,
            material=material,
            device=self.device,
            steps=steps,
            seed=seed,
            progress=progress,
        )
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        sec["diffusion"] = time.perf_counter() - t0
        return w
