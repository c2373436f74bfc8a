"""GSNet's garments and training windows: templates of any topology, batched into one graph.

A :class:`Template` is what GSNet knows of one garment before any motion: its template features
(``learn.gsnet.features``), rest mesh, unique edges and the body's skinning weights carried over
to its vertices (the ablation without learned edges; ``sim.skinning.transfer``). A training
item is a window of one sequence: frames t-2 .. t+R-1 of its body (root-relative transforms,
roots, posed body vertices for the collision terms) and its simulated garment (the first two
frames are the history, the next R the rollout's targets); :func:`collate` concatenates the
garments of a batch, which may all differ in topology.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch

from learn.data import rest_betas
from learn.graph import mesh_edges, symmetric
from learn.gsnet.features import body_motion, template_features
from learn.gsnet.network import NUM_JOINTS, GarmentBatch


@dataclass
class Template:
    """One garment's static inputs (numpy).

    Attributes:
        features: template features (V, C) float32; rest: rest mesh [m] (V, 3) float32;
        faces: (F, 3) int32; edges: unique edges (E, 2) int64; skin_weights: (V, 24) float32.
    """

    features: np.ndarray
    rest: np.ndarray
    faces: np.ndarray
    edges: np.ndarray
    skin_weights: np.ndarray

    @property
    def num_vertices(self) -> int:
        return int(self.rest.shape[0])


def check_body(body) -> None:
    """GSNet's joints are SMPL's 24 body joints: a body model with more (SMPL-H, SMPL-X: hands,
    jaw, eyes) is refused in one line."""
    from sim.errors import WrinklesInputError

    if body.weights.shape[1] != NUM_JOINTS:
        raise WrinklesInputError(f"GSNet animates garments on 24-joint SMPL bodies; this body model has "
                                 f"{body.weights.shape[1]} joints", path=body.source or body.name)


def make_template(seq: Mapping[str, np.ndarray], body, material, *, neighbours: int = 4) -> Template:
    """The template of a sequence's fine garment on its body (``sim.datasets.schema`` names).

    Args:
        seq: holds ``fine/rest_vertices``, ``fine/faces``, ``fine/uvs``, ``fine/uv_faces``,
            ``body/betas`` (``fine/face_layers`` optional; ``garment/betas``, the shape the garment
            was made on, when it differs from the body's: a reference-fit dataset).
        body: the ``BodyModel`` the garment was made on; material: preset name or ``Material``.
        neighbours: body vertices blended for each garment vertex's skinning weights.
    """
    from sim.skinning.transfer import transfer_skinning_weights

    check_body(body)
    rest = np.array(seq["fine/rest_vertices"], np.float32)
    faces = np.array(seq["fine/faces"], np.int32)
    betas = rest_betas(seq, body.num_betas)
    root = body.rest_joints(betas)[0]
    layers = seq.get("fine/face_layers")
    feats = template_features(rest, faces, np.asarray(seq["fine/uvs"]), np.asarray(seq["fine/uv_faces"]),
                              material, root, None if layers is None else np.asarray(layers))
    weights = transfer_skinning_weights(rest, body.rest_mesh(betas), body.weights, k=neighbours)
    return Template(feats, rest, faces, mesh_edges(faces), np.asarray(weights, np.float32))


def garment_template(garment, body, betas: np.ndarray, *, neighbours: int = 4) -> Template:
    """The template of a ``Garment`` made on (or fitted around) the rest body of shape ``betas``."""
    seq = {"fine/rest_vertices": garment.rest_vertices, "fine/faces": garment.faces, "fine/uvs": garment.uvs,
           "fine/uv_faces": garment.uv_faces, "body/betas": np.asarray(betas, np.float32)}
    if getattr(garment, "face_layers", None) is not None:
        seq["fine/face_layers"] = garment.face_layers
    return make_template(seq, body, garment.material, neighbours=neighbours)


def motion_of(seq: Mapping[str, np.ndarray], body) -> tuple[np.ndarray, np.ndarray]:
    """Root-relative bone transforms (T, 24, 3, 4) and roots (T, 3) of a sequence's body.

    The transforms carry the rest joints of the garment's shape (``rest_betas``) to the posed
    joints, so a garment made on the mean body follows a shaped body's joints.
    """
    return body_motion(np.asarray(seq["body/poses"]), np.asarray(seq["body/joints"]),
                       body.rest_joints(rest_betas(seq, body.num_betas)), np.asarray(body.parents))


def garment_batch(templates: list[Template]) -> GarmentBatch:
    """The templates of a batch as one block-diagonal graph (``learn.graph.batch_graphs``)."""
    offsets = np.cumsum([0] + [t.num_vertices for t in templates])
    edges = torch.from_numpy(np.concatenate([t.edges + o for t, o in zip(templates, offsets, strict=False)]))
    src, dst, _ = symmetric(edges)
    segment = torch.cat([torch.full((t.num_vertices,), i, dtype=torch.int64)
                         for i, t in enumerate(templates)])
    return GarmentBatch(features=torch.from_numpy(np.concatenate([t.features for t in templates])),
                        rest=torch.from_numpy(np.concatenate([t.rest for t in templates])),
                        mesh=(src, dst), segment=segment,
                        skin_weights=torch.from_numpy(np.concatenate([t.skin_weights for t in templates])))


def split_vertices(x: torch.Tensor, garments: GarmentBatch) -> list[torch.Tensor]:
    """Per-garment pieces of a concatenated (..., N, 3) array."""
    sizes = torch.bincount(garments.segment, minlength=garments.num_graphs).tolist()
    return list(torch.split(x, sizes, dim=-2))
