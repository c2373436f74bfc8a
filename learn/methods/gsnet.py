"""GSNet (graph skinning network) as one trainable method, for garments of any topology.

- the model: ``learn.gsnet.network.GSNet`` (garment encoder, deep skinning with learned
  vertex-joint edges, physical regression); no fitted state: the template features are O(1).
- an item: a window of one training sequence, frames t-2 .. t+R-1 (``rollout`` R): its garment's
  template (``learn.gsnet.data.Template``), its body's root-relative bone transforms, roots and
  posed vertices, and the simulated garment (frames t-2, t-1 are the history, with
  ``history_noise``; ``cold_start`` of the items start from the network's own skinning prior
  instead, as an animation does). A batch holds garments of any topologies.
- the loss (GSNet Sec. 3.5): over the R frames of the rollout, each fed the previous outputs,
  the data term (Eq. 5, squared vertex error, a mean over each garment's vertices) of the deep
  skinning and of the final output, plus Eq. 6-8 on the final output: edge lengths against the
  template (a mean over edges), the Laplace-Beltrami of the normals (a mean over vertices) and the
  collision term (a mean over vertices) with ``learn.losses``' Warp terms, one garment at a time.
- ``predict_sequence``: the whole sequence rolled out from the body's motion alone (the history
  of frame 0 is the prior at frame 0, at rest).
"""

from __future__ import annotations

import functools
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from learn.methods.base import LossOutput, Method, Prediction

DEFAULT_MATERIAL = "cotton"
"""The material of a garment whose sequence does not name one."""


@dataclass(frozen=True)
class GSNetConfig:
    """Settings of GSNet (the paper's where it gives them)."""

    width: int = 128
    """Graph feature width (Sec. 3.2-3.3: 128)."""
    node: int = 32
    """Width of the joint graph's node features (the paper's 16 joint attributes, widened)."""
    operator: str = "laplacian"
    """Graph operator (``learn.graph.OPERATORS``): "laplacian" (Eq. 2-3) or "adjacency"."""
    learned_edges: bool = True
    """Learned vertex-joint edges (Sec. 3.3); False: the body's transferred skinning weights."""
    edge_prior: bool = True
    """The learned edges start from the body's skinning weights (their logs offset the logits)."""
    joint_topk: int = 0
    """Joint edges each vertex keeps, its k strongest, renormalised (0: all 24, the paper's dense
    N x 24 edges)."""
    regression: bool = True
    """The physical regression stage (Sec. 3.4)."""
    temporal: bool = True
    """Previous frames of the garment and the body as inputs (Sec. 3.5)."""
    rollout: int = 3
    """Frames each training item rolls out, each fed the previous outputs."""
    history_noise: float = 1.0e-3
    """Standard deviation [m] of the noise added to an item's ground-truth history."""
    cold_start: float = 0.25
    """Share of items whose history is the network's skinning prior (an animation's start)."""
    edge_weight: float = 10.0
    """Weight of Eq. 6 (mean squared edge-length error [m^2]) beside the data term [m^2]."""
    bending_weight: float = 1.0e-4
    """Weight of Eq. 7 (mean |Delta n|^2 [-]; the simulation's wrinkled garments have 0.01-0.04,
    so this term stays a smoothing hint rather than flattening the folds)."""
    collision_weight: float = 10.0
    """Weight of Eq. 8 (mean squared penetration below ``collision_eps`` [m^2])."""
    collision_eps: float = 1.0e-3
    """epsilon of Eq. 8 and of the regression's filter [m]. The simulation's garments touch the
    body: on the sample dataset 6-26 % of their vertices are within 1 mm of the nearest body
    vertex's tangent plane, 15-40 % within 2 mm, so a larger margin would fight the data."""
    projection_margin: float = 2.0e-3
    """[m]: after the regression, vertices closer than this to the nearest body vertex's tangent
    plane move out along its normal to it (``learn.gsnet.network.project_out``; 0: none). At
    inference only: a guarantee the learned stages do not give. On 14 test sequences (one per
    split and design) an H200-trained network put 2-20 % of the vertices inside the body without
    it, 0-0.1 % with it, at the same vertex error (within 0.4 mm). Not in training: there it takes
    the collision term's signal from the regression (after a 60-step overfit the regression no
    longer lifts vertices out of the body)."""
    skin_neighbours: int = 4
    """Body vertices blended into each garment vertex's transferred skinning weights."""
    garments: tuple[str, ...] = ()
    """Garment categories to train on (empty: all in the dataset)."""


class _Losses:
    """The Warp physics terms of one garment (``learn.losses``), built once per topology."""

    def __init__(self, rest: np.ndarray, faces: np.ndarray, body_faces: np.ndarray, eps: float):
        from learn.losses import GSNetBendingLoss, GSNetCollisionLoss, GSNetEdgeLoss
        from sim.losses.topology import garment_topology

        topo = garment_topology(rest, faces)
        self.edge = GSNetEdgeLoss(topo, reduction="none")
        self.bending = GSNetBendingLoss(topo, reduction="none")
        self.collision = GSNetCollisionLoss(topo, body_faces=body_faces, eps=eps, reduction="none")
        # the regression's body search, one frame at a time: an instance of its own, since an
        # instance rebuilds its search structure whenever the batch size changes
        self.search = self.body_search(topo, body_faces, eps)
        self.num_edges, self.num_vertices = len(topo.edges), topo.num_vertices

    @staticmethod
    def body_search(topo, body_faces: np.ndarray, eps: float):
        """The nearest-body-vertex search of the regression's filter and the projection."""
        from learn.losses import GSNetCollisionLoss

        return GSNetCollisionLoss(topo, body_faces=body_faces, eps=eps, reduction="none")


class _TrainItems(torch.utils.data.Dataset):
    """Windows of R + 2 frames of the train split (module docstring)."""

    def __init__(self, method: GSNetMethod, root):
        from learn.data import GarmentSequenceDataset

        self.method = method
        c = method.config
        self.windows = GarmentSequenceDataset(root, "train", window=c.rollout + 2, keys=("fine/vertices",),
                                              garments=c.garments or None)
        self.fps = float(self.windows.generator_config.get("fps") or 30.0)
        self._prepared: dict[str, tuple] = {}

    def __len__(self) -> int:
        return len(self.windows)

    def _prep(self, sid: str) -> tuple:
        if sid not in self._prepared:
            from learn.data import sequence_inputs
            from learn.gsnet.data import make_template, motion_of

            seq = sequence_inputs(self.windows.open_sequence(sid), self.windows.entries[sid],
                                  self.windows.generator_config, self.method.SEQUENCE_KEYS)
            name = str(seq["body/model"])
            body = self.method.body(name)
            material = str(seq["garment/material"]) or DEFAULT_MATERIAL
            template = make_template(seq, body, material, neighbours=self.method.config.skin_neighbours)
            self._prepared[sid] = (template, *motion_of(seq, body), seq, name)
        return self._prepared[sid]

    def __getitem__(self, key: tuple[int, int]) -> dict:
        index, seed = key
        sid, t = self.windows.locate(index)
        template, transforms, roots, seq, name = self._prep(sid)
        w = self.windows.window
        frames = self.windows[index]["fine/vertices"].numpy()
        from sim.skinning.lbs import lbs_reference

        body = self.method.body(name)
        betas = np.asarray(seq["body/betas"], np.float32).reshape(-1)[: body.num_betas]
        # numpy, not Warp: items are made in forked data-loader workers of a process that may
        # hold a CUDA context
        posed, _ = lbs_reference(body, betas, body.full_poses(seq["body/poses"][t + 2:t + w]),
                                 seq["body/trans"][t + 2:t + w])
        rng = np.random.default_rng(seed)
        noise = rng.normal(0.0, self.method.config.history_noise, (2, *frames.shape[1:])).astype(np.float32)
        return {"key": sid, "template": template, "target": frames,
                "history": frames[:2] + noise, "cold": bool(rng.random() < self.method.config.cold_start),
                "transforms": transforms[t:t + w], "roots": roots[t:t + w],
                "body": posed.astype(np.float32), "body_faces": np.asarray(body.faces),
                "fps": self.fps}

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_prepared": {}}


class GSNetMethod(Method):
    """GSNet (module docstring)."""

    name = "gsnet"
    Config = GSNetConfig
    SEQUENCE_KEYS = ("fine/rest_vertices", "fine/faces", "fine/uvs", "fine/uv_faces", "fine/face_layers",
                     "body/betas", "body/poses", "body/joints", "body/trans")
    """Arrays of a sequence the method reads (``fine/face_layers`` where present)."""
    LOSS_CACHE = 256
    """Garments whose physics terms stay built (a dataset of body-fitted garments has one per sequence)."""

    def __init__(self, config: GSNetConfig):
        super().__init__(config)
        self._losses: OrderedDict[str, _Losses] = OrderedDict()

    @classmethod
    def validate_config(cls, config: GSNetConfig, err) -> None:
        from learn.graph import OPERATORS

        for f in ("width", "node", "rollout", "skin_neighbours"):
            if getattr(config, f) < 1:
                raise err(f"model.{f} must be >= 1, got {getattr(config, f)}")
        if config.width % 4:
            raise err(f"model.width must be a multiple of 4, got {config.width}")
        if config.operator not in OPERATORS:
            raise err(f"model.operator must be one of {', '.join(OPERATORS)}, got {config.operator!r}")
        if not 0 <= config.joint_topk <= 24:
            raise err(f"model.joint_topk must be in [0, 24], got {config.joint_topk}")
        if not 0.0 <= config.cold_start <= 1.0:
            raise err(f"model.cold_start must be in [0, 1], got {config.cold_start}")
        for f in ("history_noise", "edge_weight", "bending_weight", "collision_weight", "collision_eps",
                  "projection_margin"):
            if not getattr(config, f) >= 0.0:
                raise err(f"model.{f} must be >= 0, got {getattr(config, f)}")

    @functools.cache  # noqa: B019 - one body model per method object is the point
    def body(self, name: str = "default"):
        """The body model a dataset was simulated on (``"default"`` or a model file)."""
        from sim.bodies import load_body

        return load_body(name)

    def build_model(self) -> nn.Module:
        from learn.gsnet.features import TEMPLATE_FEATURES
        from learn.gsnet.network import GSNet

        c = self.config
        return GSNet(TEMPLATE_FEATURES, width=c.width, node=c.node, operator=c.operator,
                     learned_edges=c.learned_edges, edge_prior=c.edge_prior, regression=c.regression,
                     joint_topk=c.joint_topk, parents=self.body().parents[:24])

    def train_dataset(self, root) -> torch.utils.data.Dataset:
        return _TrainItems(self, root)

    def collate(self, items: list) -> dict:
        """B items -> a batch: ``garments`` (``GarmentBatch``, N vertices in all), ``templates`` and
        ``keys`` (lists), ``target`` and ``history`` (R + 2, N, 3) and (2, N, 3) [m] (garments
        concatenated along the vertex axis), ``cold`` (B,) bool, ``transforms`` (B, R + 2, 24, 3, 4),
        ``roots`` (B, R + 2, 3) [m], ``body`` (B, R, Vb, 3) [m], ``body_faces``, ``fps``."""
        from learn.gsnet.data import garment_batch

        templates = [it["template"] for it in items]
        if len({it["body_faces"].shape for it in items}) > 1:
            raise ValueError("a GSNet batch needs one body model (the collision terms share its faces)")
        return {"keys": [it["key"] for it in items], "garments": garment_batch(templates),
                "templates": templates,
                "target": torch.from_numpy(np.concatenate([it["target"] for it in items], axis=1)),
                "history": torch.from_numpy(np.concatenate([it["history"] for it in items], axis=1)),
                "cold": torch.tensor([it["cold"] for it in items]),
                "transforms": torch.from_numpy(np.stack([it["transforms"] for it in items])),
                "roots": torch.from_numpy(np.stack([it["roots"] for it in items])),
                "body": torch.from_numpy(np.stack([it["body"] for it in items])),
                "body_faces": items[0]["body_faces"], "fps": items[0]["fps"]}

    def losses_of(self, key: str, template, body_faces: np.ndarray) -> _Losses:
        """The physics terms of a garment (cached by ``key``, least recently used dropped)."""
        hit = self._losses.get(key)
        if hit is None:
            hit = _Losses(template.rest, template.faces, body_faces, self.config.collision_eps)
            self._losses[key] = hit
            while len(self._losses) > self.LOSS_CACHE:
                self._losses.popitem(last=False)
        self._losses.move_to_end(key)
        return hit

    def _anchors(self, losses: list[_Losses], garments, body: torch.Tensor, first: int):
        """``anchors(x, k)`` of the rollout: nearest body vertices of each garment's body at frame k."""
        from learn.gsnet.data import split_vertices

        def anchors(x: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
            found = [ls.search.nearest_anchors(xb[None], body[b, k - first][None])
                     for b, (ls, xb) in enumerate(zip(losses, split_vertices(x, garments), strict=True))]
            return torch.cat([a.points[0] for a in found]), torch.cat([a.normals[0] for a in found])
        return anchors

    def training_loss(self, model: nn.Module, batch: dict, generator: torch.Generator) -> LossOutput:
        """The rollout's loss (module docstring) on a ``collate`` batch; scalars: the terms and the
        final output's mean vertex error [m]."""
        from learn.gsnet.data import split_vertices

        c = self.config
        dev = batch["transforms"].device
        g = batch["garments"].to(dev)
        losses = [self.losses_of(k, t, batch["body_faces"])
                  for k, t in zip(batch["keys"], batch["templates"], strict=True)]
        skinned, final = model(g, batch["transforms"], batch["roots"], batch["history"],
                               anchors=self._anchors(losses, g, batch["body"], 2), fps=batch["fps"],
                               temporal=c.temporal, cold=batch["cold"], eps=c.collision_eps)
        target = batch["target"][2:]
        data_skin = _garment_mean((skinned - target).square().sum(-1), g)
        data = _garment_mean((final - target).square().sum(-1), g)
        edge = bend = col = final.new_zeros(())
        for b, (ls, xb) in enumerate(zip(losses, split_vertices(final, g), strict=True)):
            edge = edge + ls.edge.energy(xb).mean() / ls.num_edges
            bend = bend + ls.bending.energy(xb).mean() / ls.num_vertices
            col = col + ls.collision.energy(xb, batch["body"][b]).mean() / ls.num_vertices
        n = len(losses)
        edge, bend, col = edge / n, bend / n, col / n
        loss = data_skin + data + c.edge_weight * edge + c.bending_weight * bend + c.collision_weight * col
        err = (final - target).detach().norm(dim=-1)
        return LossOutput(loss, {"data": data.detach(), "data_skinning": data_skin.detach(),
                                 "edge": edge.detach(), "bending": bend.detach(), "collision": col.detach(),
                                 "vertex_error": _garment_mean(err, g)})

    @property
    def uses_body(self) -> bool:
        """Inference needs the posed body: for the regression's filter or the projection."""
        return self.config.regression or self.config.projection_margin > 0

    @torch.no_grad()
    def predict_sequence(self, model: nn.Module, sequence: Mapping[str, np.ndarray], *,
                         device: torch.device) -> Prediction:
        from learn.gsnet.data import make_template, motion_of

        body = self.body(str(sequence.get("body/model", "default")))
        material = str(sequence.get("garment/material", "") or "") or DEFAULT_MATERIAL
        template = make_template(sequence, body, material, neighbours=self.config.skin_neighbours)
        transforms, roots = motion_of(sequence, body)
        posed = None
        if self.uses_body:
            betas = np.asarray(sequence["body/betas"], np.float32).reshape(-1)[: body.num_betas]
            posed = body.pose(betas, np.asarray(sequence["body/poses"]), np.asarray(sequence["body/trans"]))
        fps = float(np.asarray(sequence.get("fps", 30.0)))
        return Prediction(vertices=self.animate(
            model, template, transforms, roots, fps=fps, device=device,
            body_vertices=None if posed is None else posed.vertices, body_faces=np.asarray(body.faces)))

    @torch.no_grad()
    def animate(self, model: nn.Module, template, transforms: np.ndarray, roots: np.ndarray, *, fps: float,
                device: torch.device, body_vertices: np.ndarray | None = None,
                body_faces: np.ndarray | None = None) -> np.ndarray:
        """A garment rolled out over a whole motion from the body alone, (T, V, 3) [m].

        Args:
            model: the trained network; template: ``learn.gsnet.data.Template`` of the garment.
            transforms, roots: the body's root-relative bone transforms (T, 24, 3, 4) and roots (T, 3)
                (``learn.gsnet.data.motion_of``).
            fps: frame rate of the motion; device: torch device of the model.
            body_vertices, body_faces: the posed body (T, Vb, 3) and its faces for the physical
                regression's filter and the projection (None: neither).
        """
        from learn.gsnet.data import garment_batch

        c = self.config
        # frame 0 twice more in front, the rollout's history: frame 0's output is its first
        transforms = np.concatenate([transforms[:1], transforms[:1], transforms])
        roots = np.concatenate([roots[:1], roots[:1], roots])
        anchors = None
        if self.uses_body and body_vertices is not None:
            from sim.losses.topology import garment_topology

            bodies = torch.from_numpy(np.asarray(body_vertices, np.float32)).to(device)
            search = _Losses.body_search(garment_topology(template.rest, template.faces),
                                         np.asarray(body_faces), c.collision_eps)

            def anchors(x: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
                a = search.nearest_anchors(x[None], bodies[k - 2][None])
                return a.points[0], a.normals[0]
        g = garment_batch([template]).to(device)
        a, r = torch.from_numpy(transforms)[None].to(device), torch.from_numpy(roots)[None].to(device)
        _, final = model(g, a, r, None, anchors=anchors, fps=fps, temporal=c.temporal, eps=c.collision_eps,
                         margin=c.projection_margin)
        return final.float().cpu().numpy()


def _garment_mean(values: torch.Tensor, garments) -> torch.Tensor:
    """Mean over each garment's vertices, then over garments and frames: (R, N) -> ()."""
    g = garments.num_graphs
    counts = torch.bincount(garments.segment, minlength=g).to(values.dtype)
    sums = values.new_zeros(values.shape[0], g).index_add_(1, garments.segment, values)
    return (sums / counts).mean()
