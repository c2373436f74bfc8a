"""The ``Garment`` type (DESIGN.md, Core types)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.materials import Material
from sim.memo import LRU, content_key, read_only
from sim.types import face_layers_array

REST_LENGTHS_CACHE = 64
"""Meshes whose ``Garment.rest_edge_lengths`` a process keeps (least recently used dropped first)."""
_REST_LENGTHS = LRU(REST_LENGTHS_CACHE)


@dataclass(frozen=True)
class Garment:
    """A garment at rest: a triangle mesh with UVs, panels, a material and attachment sets.

    Attributes:
        rest_vertices: positions [m], shape (V, 3), float32, body rest pose (Y up, facing +Z).
        faces: triangle vertex indices, shape (F, 3), int32, outward-facing (counter-clockwise).
        uvs: texture coordinates in [0, 1]², shape (U, 2), float32; UV vertices are split
            along seams, so U >= V in general.
        uv_faces: per-corner indices into ``uvs``, shape (F, 3), int32.
        material: the cloth.
        attachments: named vertex index sets (int32 arrays), e.g. "waistband", "shoulders".
        category: template category ("straight_skirt", ...) or "imported".
        name: garment name (USD prim name).
        panel_ids: sewing-pattern panel of each face, shape (F,), int32.
        panel_names: name of each panel id.
        face_layers: layers of fabric per face, shape (F,), float32, >= 1: 3 in a template's
            hems (``sim.garments.hems``), 1 elsewhere and everywhere in an imported garment
            (None: all 1). The simulator scales a face's mass, membrane and bending by it.
        repairs: what reading a garment file repaired (``load_garment``), as counts: vertices
            merged, collapsed faces, faces given twice and faces of tiny pieces dropped; empty
            for a template.
        uv_scale: metres of flat cloth per UV unit when the UVs are the garment's flat sewing
            pattern (every panel at one scale, unmirrored: a sewn design); the simulator then
            takes the cloth's rest shape from the pattern (``flat_corners``). None: the UVs are
            only a texture layout and ``rest_vertices`` is the rest shape.
    """

    rest_vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    uv_faces: np.ndarray
    material: Material
    attachments: dict[str, np.ndarray] = field(default_factory=dict)
    category: str = "imported"
    name: str = "garment"
    panel_ids: np.ndarray | None = None
    panel_names: tuple[str, ...] = ()
    face_layers: np.ndarray | None = None
    repairs: dict[str, int] = field(default_factory=dict)
    uv_scale: float | None = None

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.rest_vertices, dtype=np.float32)
        f = np.ascontiguousarray(self.faces, dtype=np.int32)
        uv = np.ascontiguousarray(self.uvs, dtype=np.float32)
        uf = np.ascontiguousarray(self.uv_faces, dtype=np.int32)
        where = f"garment {self.name!r}"
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
            raise WrinklesInputError(f"{where}: rest_vertices must be (V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1 or f.min() < 0 or f.max() >= len(v):
            raise WrinklesInputError(f"{where}: faces must be (F, 3) indices into {len(v)} vertices")
        if uf.shape != f.shape or uv.ndim != 2 or uv.shape[1] != 2 or uf.min() < 0 or uf.max() >= len(uv):
            raise WrinklesInputError(f"{where}: uv_faces must be (F, 3) indices into uvs (U, 2)")
        pid = np.zeros(len(f), np.int32) if self.panel_ids is None else np.asarray(self.panel_ids, np.int32)
        if pid.shape != (len(f),):
            raise WrinklesInputError(f"{where}: panel_ids must have shape ({len(f)},), got {pid.shape}")
        try:
            layers = face_layers_array(self.face_layers, len(f), where).astype(np.float32)
        except ValueError as e:
            raise WrinklesInputError(str(e)) from None
        att = {str(k): np.asarray(a, dtype=np.int32).reshape(-1) for k, a in self.attachments.items()}
        for k, a in att.items():
            if a.size and (a.min() < 0 or a.max() >= len(v)):
                raise WrinklesInputError(f"{where}: attachment {k!r} has indices outside [0, {len(v) - 1}]")
        arrays = (("rest_vertices", v), ("faces", f), ("uvs", uv), ("uv_faces", uf), ("panel_ids", pid),
                  ("face_layers", layers))
        for name, arr in arrays:
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "attachments", att)
        if self.uv_scale is not None and not float(self.uv_scale) > 0.0:
            raise WrinklesInputError(f"{where}: uv_scale must be > 0 m per UV unit, got {self.uv_scale}")
        names = tuple(self.panel_names) or tuple(f"panel{i}" for i in range(int(pid.max()) + 1))
        object.__setattr__(self, "panel_names", names)

    def flat_corners(self) -> np.ndarray | None:
        """Each face's corners in its flat pattern panel [m], (F, 3, 2); None without ``uv_scale``."""
        if self.uv_scale is None:
            return None
        return self.uvs[self.uv_faces].astype(np.float64) * float(self.uv_scale)

    def rest_edge_lengths(self) -> np.ndarray:
        """Rest length [m] of every edge (``sim.quality.unique_edges`` order), float64 (E,),
        read-only: in the flat pattern when there is one (``flat_corners``; a seam edge takes the
        mean of its two sides), else between the ``rest_vertices``. Made once per mesh content
        (a batch's screen, its quality reports and a dataset's edge strain each ask for every
        sequence's: ~45 ms for 20k vertices on a 2-core host)."""
        key = content_key(self.uv_scale, self.rest_vertices, self.faces, self.uvs, self.uv_faces)
        return _REST_LENGTHS.get_or_make(key, lambda: read_only(self._rest_edge_lengths()))

    def _rest_edge_lengths(self) -> np.ndarray:
        from sim.quality import unique_edges

        edges = unique_edges(self.faces)
        flat = self.flat_corners()
        if flat is None:
            return np.linalg.norm(self.rest_vertices[edges[:, 1]] - self.rest_vertices[edges[:, 0]],
                                  axis=1).astype(np.float64)
        a = self.faces.astype(np.int64)
        pairs = np.concatenate([a[:, [0, 1]], a[:, [1, 2]], a[:, [2, 0]]])
        lengths = np.concatenate([np.linalg.norm(flat[:, j] - flat[:, i], axis=1)
                                  for i, j in ((0, 1), (1, 2), (2, 0))])
        n = len(self.rest_vertices)
        key = np.sort(pairs, axis=1) @ np.array([n, 1])
        order = np.searchsorted(edges[:, 0].astype(np.int64) * n + edges[:, 1], key)
        total = np.bincount(order, weights=lengths, minlength=len(edges))
        return total / np.bincount(order, minlength=len(edges))

    @property
    def num_vertices(self) -> int:
        return int(self.rest_vertices.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])
