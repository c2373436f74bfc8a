"""Per-frame quantities of a simulated sequence (``sim.datasets.schema``): base surface,
wrinkle field in the base's local frame, Green-Lagrange strain, normals and UV images.

Frames are processed in chunks of ``CHUNK`` so a thousand-frame, 30k-vertex sequence never
holds more than a chunk of frames, normal frames and images in memory at once.
"""

from __future__ import annotations

import numpy as np

from sim.datasets.config import DeriveConfig
from sim.geometry.frames import tangent_basis, to_tangent
from sim.profiling import phase

CHUNK = 64


class Deriver:
    """Everything derived from one garment's simulated frames (operators built once).

    Args:
        garment: the fine ``Garment`` (rest mesh, UV layout).
        config: smoothing length and image resolution.
        device: Warp device.
    """

    def __init__(self, garment, config: DeriveConfig, *, device: str | None = None):
        from sim.device import device_name
        from sim.geometry.frames import SurfaceFrames
        from sim.geometry.smoothing import BaseSmoother
        from sim.geometry.strain import GreenStrain

        self.garment = garment
        self.config = config
        self.smoother = BaseSmoother(garment.rest_vertices, garment.faces, length=config.smoothing_length,
                                     device=device_name(device))
        self.frames = SurfaceFrames.from_garment(garment, device=device)
        self.strain = GreenStrain(garment.rest_vertices, garment.faces, device=device)
        self.raster = None
        if config.image_resolution:
            from sim.geometry.uv_raster import UVRasterizer

            self.raster = UVRasterizer(garment.uvs, garment.uv_faces, config.image_resolution, device=device)
        self.uv_vertex = self.frames.uv_vertex

    def __call__(self, fine: np.ndarray) -> dict[str, np.ndarray]:
        """The per-frame arrays of ``sim.datasets.schema`` (fine/*, images/*) for positions
        ``fine`` [m], shape (T, V, 3)."""
        T = fine.shape[0]
        parts: dict[str, list[np.ndarray]] = {}
        for s in range(0, T, CHUNK):
            for k, v in self._chunk(np.ascontiguousarray(fine[s:s + CHUNK], dtype=np.float32)).items():
                parts.setdefault(k, []).append(v)
        g = self.garment
        out = {k: np.concatenate(v, axis=0) for k, v in parts.items()}
        out.update({"fine/rest_vertices": g.rest_vertices, "fine/faces": g.faces, "fine/uvs": g.uvs,
                    "fine/uv_faces": g.uv_faces, "fine/face_layers": g.face_layers})
        if self.raster is not None:
            out["images/mask"] = self.raster.mask.astype(np.uint8)
        return out

    def _chunk(self, fine: np.ndarray) -> dict[str, np.ndarray]:
        with phase("base"):
            base = self.smoother.smooth(fine)
        with phase("wrinkle"):
            wrinkle = self.frames.encode(fine, base)
        with phase("strain"):
            st = self.strain.compute(base)
        with phase("normals"):
            normals = self.frames.normals(fine)
        out = {"fine/vertices": fine, "fine/base": base.astype(np.float32), "fine/wrinkle": wrinkle,
               "fine/strain": st.face, "fine/strain_norm": st.face_norm, "fine/normals": normals}
        if self.raster is None:
            return out
        with phase("images"):
            out.update(self._images(base, wrinkle, st, normals))
        return out

    def _images(self, base: np.ndarray, wrinkle: np.ndarray, st, normals: np.ndarray) -> dict:
        """``images/*`` of a chunk: strain, wrinkle and normals rasterised in UV space (f16)."""
        out = {}
        uvv = np.maximum(self.uv_vertex, 0)
        basis = tangent_basis(self.frames.frames(base))  # (T, U, 3, 3): columns t1, n x t1, n
        nf = normals[:, uvv]  # fine normals at each UV vertex
        tangent = to_tangent(basis, nf)
        r = self.raster
        f16 = np.float16
        out["images/strain_norm"] = r.rasterize(st.vertex_norm[:, uvv, None], per="uv").astype(f16)
        out["images/wrinkle"] = r.rasterize(wrinkle, per="uv").astype(f16)
        out["images/normal_world"] = r.rasterize(nf, per="uv").astype(f16)
        out["images/normal_tangent"] = r.rasterize(tangent.astype(np.float32), per="uv").astype(f16)
        return out


def coarse_arrays(garment, vertices: np.ndarray, *, device: str | None = None) -> dict[str, np.ndarray]:
    """``coarse/*`` arrays of a simulated coarse garment, positions [m] (T, Vc, 3)."""
    from sim.geometry.strain import GreenStrain

    gs = GreenStrain(garment.rest_vertices, garment.faces, device=device)
    norm = np.concatenate([gs.compute(vertices[s:s + CHUNK]).face_norm
                           for s in range(0, len(vertices), CHUNK)])
    return {"coarse/vertices": np.asarray(vertices, np.float32), "coarse/strain_norm": norm,
            "coarse/rest_vertices": garment.rest_vertices, "coarse/faces": garment.faces,
            "coarse/uvs": garment.uvs, "coarse/uv_faces": garment.uv_faces}
