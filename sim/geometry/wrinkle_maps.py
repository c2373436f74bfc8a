"""UV maps of one garment for the wrinkle models: conditioning maps of a base surface, wrinkle
maps of a wrinkled one, and the way back from a generated wrinkle map to a wrinkled mesh.

Guo et al. 2024 (Sec. 3.1-3.2) work in the garment's UV space: the strain field ``c`` of the base
mesh and the wrinkle field ``x_0`` (fine minus base, in the base's local frame, Eq. 2) are images
over the UV layout. :class:`WrinkleMaps` builds the operators of one layout once (rasterizer,
local frames, strain) and then maps any number of frames:

- conditioning maps of a base surface: ``strain_norm`` (the paper's default, identical to the
  dataset's ``images/strain_norm``), ``strain_tensor`` (E11, E22, E12 in UV-aligned face frames,
  averaged per UV vertex, i.e. within a panel) and ``normal`` (unit base normals, world frame,
  renormalised per pixel) —
  the three conditioning variants of the paper's ablation;
- ``wrinkle``: the wrinkle field of a fine surface over its base (the dataset's ``images/wrinkle``);
- ``decode``: a wrinkle map back to vertex positions, ``base + sum_i w_i t_i`` (Eq. 2 inverted),
  each UV vertex reading the map bilinearly inside its own chart and every 3D vertex taking the
  mean of its UV copies, so the two sides of a seam move together;
- ``displacement`` / ``decode_global``: the same in the world frame (the LFGD-style baseline's
  representation, which is not rotation invariant).
"""

from __future__ import annotations

import numpy as np

from sim.errors import WrinklesInputError

CONDITIONINGS = {"strain_norm": 1, "strain_tensor": 3, "normal": 3}
"""Conditioning variants (Guo et al. 2024, Sec. 4.3 ablation) and their channel counts."""


class WrinkleMaps:
    """UV-map operators of one garment layout (see the module docstring).

    Args:
        rest_vertices: rest positions [m], shape (V, 3).
        faces: (F, 3) int.
        uvs: (U, 2) in [0, 1]^2, split along seams.
        uv_faces: (F, 3) int into ``uvs``.
        resolution: image side [px] (H = W).
        device: Warp device.
    """

    def __init__(self, rest_vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, uv_faces: np.ndarray,
                 resolution: int, *, device: str | None = None):
        from sim.geometry.frames import SurfaceFrames, uv_scale
        from sim.geometry.strain import GreenStrain
        from sim.geometry.uv_raster import UVRasterizer

        rest = np.asarray(rest_vertices, np.float32)
        self.faces = np.asarray(faces, np.int32)
        self.uvs = np.asarray(uvs, np.float32)
        self.uv_faces = np.asarray(uv_faces, np.int32)
        self.num_vertices = len(rest)
        self.resolution = int(resolution)
        self.raster = UVRasterizer(self.uvs, self.uv_faces, self.resolution, device=device)
        scale = uv_scale(rest, self.faces, self.uvs, self.uv_faces)
        self.frames = SurfaceFrames(len(rest), self.faces, self.uvs, self.uv_faces, scale, device=device)
        self.strain = GreenStrain(rest, self.faces, device=device)
        self._uv_strain = None
        self._rest, self._device = rest, device
        self.uv_vertex = np.maximum(self.frames.uv_vertex, 0)

    @classmethod
    def from_garment(cls, garment, resolution: int, *, device: str | None = None) -> WrinkleMaps:
        """The maps of a ``Garment``."""
        return cls(garment.rest_vertices, garment.faces, garment.uvs, garment.uv_faces, resolution,
                   device=device)

    @classmethod
    def from_sequence(cls, seq, resolution: int, *, device: str | None = None) -> WrinkleMaps:
        """The maps of a dataset sequence's fine garment (``fine/rest_vertices`` ... arrays)."""
        return cls(np.asarray(seq["fine/rest_vertices"]), np.asarray(seq["fine/faces"]),
                   np.asarray(seq["fine/uvs"]), np.asarray(seq["fine/uv_faces"]), resolution, device=device)

    @property
    def mask(self) -> np.ndarray:
        """UV coverage, (H, W) bool."""
        return self.raster.mask

    def _frames(self, x: np.ndarray, what: str) -> np.ndarray:
        a = np.asarray(x, np.float32)
        if a.ndim != 3 or a.shape[1:] != (self.num_vertices, 3):
            raise WrinklesInputError(f"{what} must have shape (T, {self.num_vertices}, 3), got {a.shape}")
        return a

    def conditioning(self, base: np.ndarray, kind: str = "strain_norm") -> np.ndarray:
        """Conditioning maps of base surfaces [m] (T, V, 3): (T, H, W, C) float32, C from
        :data:`CONDITIONINGS`."""
        if kind not in CONDITIONINGS:
            raise WrinklesInputError(f"conditioning {kind!r}: expected one of {', '.join(CONDITIONINGS)}")
        b = self._frames(base, "base")
        if kind == "strain_norm":  # as sim.datasets.derive: per-vertex mean of the face norms
            st = self.strain.compute(b)
            return self.raster.rasterize(st.vertex_norm[:, self.uv_vertex, None], per="uv")
        if kind == "strain_tensor":
            # GreenStrain over the UV mesh (UV vertices at their 3D rest positions): UV-aligned face
            # frames, and its rest-area-weighted vertex mean is the mean per UV vertex (within a panel)
            if self._uv_strain is None:
                from sim.geometry.strain import GreenStrain

                self._uv_strain = GreenStrain(self._rest[self.uv_vertex], self.uv_faces, uvs=self.uvs,
                                              uv_faces=self.uv_faces, device=self._device)
            return self.raster.rasterize(self._uv_strain.compute(b[:, self.uv_vertex]).vertex, per="uv")
        n = self.raster.rasterize(self.frames.normals(b)[:, self.uv_vertex], per="uv")
        length = np.linalg.norm(n, axis=-1, keepdims=True)
        return np.where(length > 1e-6, n / np.maximum(length, 1e-6), 0.0).astype(np.float32)

    def wrinkle(self, fine: np.ndarray, base: np.ndarray) -> np.ndarray:
        """Wrinkle maps [m] (T, H, W, 3) of ``fine`` over ``base`` (both (T, V, 3))."""
        w = self.frames.encode(self._frames(fine, "fine"), self._frames(base, "base"))
        return self.raster.rasterize(w, per="uv")

    def decode(self, maps: np.ndarray, base: np.ndarray) -> np.ndarray:
        """Wrinkled positions [m] (T, V, 3): ``base`` plus the wrinkle ``maps`` (T, H, W, 3) [m]
        read at every UV vertex and lifted along the base's local frame."""
        b = self._frames(base, "base")
        w = self.raster.sample(np.asarray(maps, np.float32))
        return self.frames.decode(w, b).astype(np.float32)

    def displacement(self, fine: np.ndarray, base: np.ndarray) -> np.ndarray:
        """World-frame displacement maps ``fine - base`` [m], (T, H, W, 3)."""
        d = self._frames(fine, "fine") - self._frames(base, "base")
        return self.raster.rasterize(d[:, self.uv_vertex], per="uv")

    def positions(self, x: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """Position maps ``x - origin_t`` [m], (T, H, W, 3), for positions (T, V, 3) and (T, 3)."""
        p = self._frames(x, "positions") - np.asarray(origin, np.float32)[:, None]
        return self.raster.rasterize(p[:, self.uv_vertex], per="uv")

    def decode_global(self, maps: np.ndarray, base: np.ndarray) -> np.ndarray:
        """``base`` plus world-frame displacement maps (T, H, W, 3) [m], seams averaged."""
        b = self._frames(base, "base")
        return (b + self.raster.sample_vertices(np.asarray(maps, np.float32), self.faces)).astype(np.float32)
