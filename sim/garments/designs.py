"""Garment designs: a sewing pattern drafted from the body's measurements, meshed, sewn on the
rest body and turned into a ``Garment`` (``sew_garment``).

The garment's UVs are its flat pattern (every panel one chart, one common scale, packed into
[0, 1]², ``sim.garments.uv.pack_uvs``); ``Garment.panel_ids`` names the panel of each face; its
attachment sets are the vertices along labelled pattern edges (``ATTACHMENT_LABELS``); its hems
are the ``hem_width`` bands along its openings, as for every garment (``sim.garments.hems``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.garments.hems import HEM_LAYERS, HEM_WIDTH, hem_face_layers
from sim.garments.materials import Material, get_material
from sim.garments.pattern import Pattern
from sim.garments.sewing import SewingConfig, SewnPattern, sew_pattern
from sim.garments.types import Garment
from sim.garments.uv import pack_uvs

ATTACHMENT_LABELS = {"hem": "hem", "cuff": "cuffs", "waistband": "waistband", "neckline": "neckline",
                     "shoulder": "shoulders"}
"""Pattern edge label -> the garment attachment set its vertices join."""
EDGE_LENGTHS = {"coarse": 0.018, "fine": 0.0065}
"""Target edge lengths [m] of the named resolutions (coarse ~15-20 mm, fine ~6-7 mm)."""


@dataclass(frozen=True)
class BodyParts:
    """What drafting reads from a body at rest: measurements, vertices, joints, region masks."""

    measurements: object
    vertices: np.ndarray
    joints: np.ndarray
    faces: np.ndarray
    torso_mask: np.ndarray
    arm_masks: dict

    @classmethod
    def of(cls, body, betas: np.ndarray | None = None) -> BodyParts:
        from sim.garments.body_measurements import measure_body
        from sim.garments.measure import ARM_JOINTS

        w = np.asarray(body.weights)
        left = [j for j in ARM_JOINTS if j % 2 == 0]
        right = [j for j in ARM_JOINTS if j % 2 == 1]
        return cls(measure_body(body, betas), np.asarray(body.rest_mesh(betas), np.float64),
                   np.asarray(body.rest_joints(betas), np.float64), np.asarray(body.faces, np.int32),
                   w[:, list(ARM_JOINTS)].sum(axis=1) < 0.5,
                   {"l": w[:, left].sum(axis=1) > 0.5, "r": w[:, right].sum(axis=1) > 0.5})


def edge_length(resolution: str | float) -> float:
    """Target edge length [m] of "coarse", "fine" or a number of metres."""
    if isinstance(resolution, str):
        if resolution not in EDGE_LENGTHS:
            raise ValueError(f"unknown resolution {resolution!r}; expected coarse, fine or metres")
        return EDGE_LENGTHS[resolution]
    return float(resolution)


def attachments_of(pattern: Pattern, sewn: SewnPattern) -> dict[str, np.ndarray]:
    """Vertex sets of the garment along labelled edges (``ATTACHMENT_LABELS``)."""
    out: dict[str, list[np.ndarray]] = {}
    for label, name in ATTACHMENT_LABELS.items():
        for ref in pattern.labelled(label):
            out.setdefault(name, []).append(sewn.mesh.groups[sewn.mesh.edge_vertices[ref]])
    return {k: np.unique(np.concatenate(v)).astype(np.int32) for k, v in out.items()}


def garment_of(pattern: Pattern, sewn: SewnPattern, material: Material, *, category: str, name: str,
               hem_width: float = HEM_WIDTH, hem_layers: float = HEM_LAYERS) -> Garment:
    """The ``Garment`` of a sewn pattern: UVs = the flat pattern packed into [0, 1]²."""
    mesh = sewn.mesh
    uvs = pack_uvs(mesh.flat, mesh.vertex_panel)
    edges = mesh.triangles[:, [0, 1]]
    scale = float(np.median(np.linalg.norm(np.diff(mesh.flat[edges], axis=1)[:, 0], axis=1)
                            / np.linalg.norm(np.diff(uvs[edges].astype(np.float64), axis=1)[:, 0], axis=1)))
    return Garment(rest_vertices=sewn.vertices, faces=sewn.faces, uvs=uvs, uv_faces=mesh.triangles,
                   material=material, attachments=attachments_of(pattern, sewn), category=category,
                   name=name, panel_ids=mesh.face_panel, panel_names=tuple(p.name for p in pattern.panels),
                   face_layers=hem_face_layers(sewn.vertices, sewn.faces, hem_width, hem_layers),
                   uv_scale=scale)


def sew_garment(pattern: Pattern, parts: BodyParts, *, resolution: str | float = "coarse",
                material: str | Material = "cotton", category: str | None = None, name: str | None = None,
                config: SewingConfig | None = None, device: str | None = None) -> Garment:
    """Mesh ``pattern`` at ``resolution``, sew it on the body of ``parts`` and return the garment."""
    mat = get_material(material)
    sewn = sew_pattern(pattern, parts.vertices, parts.faces, edge_length(resolution), mat, config=config,
                       device=device)
    return garment_of(pattern, sewn, mat, category=category or pattern.name, name=name or pattern.name)
