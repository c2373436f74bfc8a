"""DeepWrinkles' UV normal maps (Lähner et al. 2018, Sec. 4) on a sequence's fine garment layout.

The global shape lives on the template (the coarse garment); the maps live on the fine garment's
UV layout, the garment a renderer shows. Each fine vertex has a fixed place on the template
through the shared sewing pattern (``layout_locations``), so any template configuration becomes
a fine-topology surface, with normals interpolated from the template's vertex normals (smooth,
not the facets of the coarse triangles).

Two maps per frame, both in tangent space:

- **LR** (the cGAN's input): the global shape's normals in the tangent frames of the template
  rigidly skinned to the frame's pose. It holds the global folds relative to the skinned
  garment and, unlike world normals, does not change when the body turns or walks on (the
  paper's LR maps would be flat in the global shape's own tangent space, so they are taken
  against the skinned template instead).
- **HR** (the cGAN's target and output): the fine garment's normals in the tangent frames of the
  global shape: the wrinkles the global shape lacks, as a tangent-space normal map that any
  renderer applies on the global shape — on any body shape (Sec. 5.3, Fig. 12).

Tangent frames are ``sim.geometry.frames.tangent_basis``: t1 the UV u-direction made orthogonal
to the normal, then n x t1, n. Maps are (H, W, 3) float32 unit vectors, 0 outside the charts.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from sim.errors import WrinklesInputError
from sim.geometry.frames import unit_vectors


class DetailMaps:
    """LR and HR normal maps of one garment layout (module docstring).

    Args:
        seq: the sequence's arrays: ``fine/faces``, ``fine/uvs``, ``fine/uv_faces``,
            ``fine/rest_vertices``, ``coarse/faces``, ``coarse/uvs``, ``coarse/uv_faces``.
        resolution: image side [px] (256 or 512 in the paper).
        device: Warp device of the rasterizer and frames.
    """

    def __init__(self, seq: Mapping[str, np.ndarray], resolution: int, *, device: str | None = None):
        from sim.garments.correspondence import layout_locations
        from sim.geometry.wrinkle_maps import WrinkleMaps

        self.maps = WrinkleMaps.from_sequence(seq, resolution, device=device)
        self.template_faces = np.asarray(seq["coarse/faces"], np.int32)
        self.faces = np.asarray(seq["fine/faces"], np.int32)
        self.on_template = layout_locations(
            self.faces,
            np.asarray(seq["fine/uvs"]),
            np.asarray(seq["fine/uv_faces"]),
            np.asarray(seq["coarse/uvs"]),
            np.asarray(seq["coarse/uv_faces"]),
        )
        self.uv_vertex = self.maps.uv_vertex

    @property
    def mask(self) -> np.ndarray:
        """UV coverage (H, W) bool."""
        return self.maps.mask

    def surface(self, template: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Template configurations [m] (T, Vc, 3) as fine-topology surfaces: positions (T, V, 3)
        and unit normals interpolated from the template's vertex normals (T, V, 3)."""
        from sim.geometry.frames import vertex_normals

        x = np.asarray(template, np.float32)
        if x.ndim != 3 or x.shape[-1] != 3:
            raise WrinklesInputError(f"template configurations must be (T, Vc, 3), got {x.shape}")
        n = vertex_normals(x, self.template_faces, device="cpu")
        return (
            self.on_template.evaluate(self.template_faces, x),
            unit_vectors(self.on_template.evaluate(self.template_faces, n)),
        )

    def bases(self, template: np.ndarray) -> np.ndarray:
        """Tangent bases (T, U, 3, 3) at every UV vertex of the fine surfaces of template
        configurations (T, Vc, 3)."""
        from sim.geometry.frames import tangent_basis

        x, n = self.surface(template)
        return tangent_basis(self.maps.frames.frames(x), n[:, self.uv_vertex])

    def encode(self, normals: np.ndarray, template: np.ndarray) -> np.ndarray:
        """Maps (T, H, W, 3) of per-fine-vertex unit normals (T, V, 3) in the tangent frames of
        template configurations (T, Vc, 3)."""
        from sim.geometry.frames import to_tangent

        nt = to_tangent(self.bases(template), np.asarray(normals, np.float32)[:, self.uv_vertex])
        return unit_vectors(self.maps.raster.rasterize(nt, per="uv")) * self.mask[..., None]

    def lr(self, global_shape: np.ndarray, skinned: np.ndarray) -> np.ndarray:
        """LR maps: the global shapes' (T, Vc, 3) normals against the skinned template (T, Vc, 3)."""
        _, n = self.surface(global_shape)
        return self.encode(n, skinned)

    def hr(self, fine: np.ndarray, global_shape: np.ndarray) -> np.ndarray:
        """HR maps: the fine garment's normals (from positions (T, V, 3)) against the global
        shapes (T, Vc, 3)."""
        n = self.maps.frames.normals(np.asarray(fine, np.float32))
        return self.encode(n, global_shape)

    def decode(self, maps: np.ndarray, global_shape: np.ndarray) -> np.ndarray:
        """World unit normals (T, V, 3) at the fine vertices from tangent-space maps (T, H, W, 3)
        on the global shapes (T, Vc, 3); a vertex on a seam averages its UV copies."""
        from sim.geometry.frames import from_tangent

        m = np.asarray(maps, np.float32)
        world = from_tangent(self.bases(global_shape), unit_vectors(self.maps.raster.sample(m)))
        V = self.maps.num_vertices
        out = np.zeros((len(m), V, 3), np.float32)
        uvv = self.maps.frames.uv_vertex
        used = uvv >= 0
        np.add.at(out, (slice(None), uvv[used]), world[:, used])
        return unit_vectors(out)
