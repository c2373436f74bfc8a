"""GSNet's network (Xu et al., "GSNet: Generating 3D Garment Animation via Graph Skinning Network").

Three stages on a batch of garments of any topologies (``learn.graph`` batches them into one
block-diagonal graph; ``segment`` gives each vertex its garment):

- :class:`GarmentEncoder` (Sec. 3.2): three graph convolutions (Eq. 4) over the garment's mesh with
  the normalised operator (Eq. 2-3) from per-vertex template features, then a max-pooled global
  feature concatenated to every vertex, and the template features again: (N, 2 width + C).
- :class:`DeepSkinning` (Sec. 3.3): three fully connected layers turn the encoder's features into
  the edges between each garment vertex and the 24 body joints (a softmax over joints: learned
  attention, not nearest-bone weights). One graph of the garment's vertices and the joints (mesh
  edges, the learned vertex-joint edges, the skeleton's bones) carries the joints' motion
  features to the vertices, whose own features come from the previous frames (Sec. 3.5's temporal
  input, two fully connected layers). Three graph convolutions, then four fully connected layers
  give each vertex its deformation attributes: a 3 x 4 homogeneous transform (the paper's 16
  numbers are a 4 x 4 matrix whose last row is constant) added to the blend of the joints'
  transforms by the learned edges, applied to the template vertex. The last layer starts at zero,
  so an untrained network is linear blend skinning with the learned edges.
- :class:`PhysicalRegression` (Sec. 3.4): a second graph pass on the same graph corrects the
  vertices that the filter ``d_ij . n_j < eps`` marks as inside the body (``d_ij`` from the
  nearest body vertex j, ``n_j`` its normal); the others keep the skinning result.

Positions are relative to the body's root joint of the current frame [m].
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import torch
from torch import nn

from learn.graph import Graph, GraphConv, normalised_operator, segment_max

NUM_JOINTS = 24
JOINT_FEATURES = 24
"""Raw features of a joint per frame: its 3 x 4 bone transform (root-relative) at t and t-1."""
PREVIOUS_FEATURES = 6
"""Temporal features of a vertex (:func:`temporal_features`): its offset from the skinning prior at
t-1 and that offset's rate of change, each bounded."""
OFFSET_SCALE = 0.1
"""[m]: offsets from the skinning prior enter as ``OFFSET_SCALE * tanh(offset / OFFSET_SCALE)``."""
RATE_SCALE = 1.0
"""[m/s]: the offset's rate of change enters as ``RATE_SCALE * tanh(rate / RATE_SCALE)``."""
EDGE_PRIOR_FLOOR = 1.0e-4
"""Smallest prior weight of a vertex-joint edge (log 1e-4 = -9.2: a joint the body's skinning
ignores can still be learned)."""
REGRESSION_FEATURES = 10
"""Geometric inputs of the regression: position, offset from and normal of the nearest body
vertex, and the signed distance along that normal."""


def mlp(widths: list[int], *, zero_last: bool = False) -> nn.Sequential:
    """Fully connected layers with ReLU between them (none after the last)."""
    layers: list[nn.Module] = []
    for i in range(len(widths) - 1):
        layers.append(nn.Linear(widths[i], widths[i + 1]))
        if i < len(widths) - 2:
            layers.append(nn.ReLU())
    if zero_last:
        nn.init.zeros_(layers[-1].weight)
        nn.init.zeros_(layers[-1].bias)
    return nn.Sequential(*layers)


class GarmentEncoder(nn.Module):
    """Sec. 3.2: template features (N, C) -> per-vertex latent features (N, 2 width + C): the
    three graph convolutions' features, their maximum over the garment, and the template features
    themselves (a skip the paper does not have: the normalised Laplacian nearly cancels what is
    constant over a garment, the material features keep 4 % of their size through one layer)."""

    def __init__(self, in_features: int, width: int = 128):
        super().__init__()
        self.width = width
        self.convs = nn.ModuleList([GraphConv(in_features, width // 2, nn.ReLU()),
                                    GraphConv(width // 2, width, nn.ReLU()),
                                    GraphConv(width, width, nn.ReLU())])

    def forward(self, graph: Graph, x: torch.Tensor, segment: torch.Tensor, num_graphs: int) -> torch.Tensor:
        raw = x
        for conv in self.convs:
            x = conv(graph, x)
        pooled = segment_max(x, segment, num_graphs)
        return torch.cat([x, pooled.index_select(0, segment), raw], dim=1)


def skinning_graph(mesh: tuple[torch.Tensor, torch.Tensor], vertex_joint: torch.Tensor, segment: torch.Tensor,
                   parents: torch.Tensor, num_graphs: int, kind: str,
                   joints: torch.Tensor | None = None) -> Graph:
    """The normalised operator of the graph of garment vertices and body joints (Sec. 3.3).

    Nodes: the N garment vertices, then ``num_graphs`` blocks of 24 joints. Edges (both ways):
    the mesh edges ``mesh`` (src, dst of the batched garments, weight 1), every vertex to the
    joints of its garment's body with weight ``vertex_joint`` (N, 24) (all 24, or the (N, k) joint
    indices ``joints``), and each joint to its parent.
    """
    n = vertex_joint.shape[0]
    dev = vertex_joint.device
    if joints is None:
        joints = torch.arange(NUM_JOINTS, device=dev).expand(n, NUM_JOINTS)
    k = joints.shape[1]
    v = torch.arange(n, device=dev).repeat_interleave(k)
    j = n + segment.repeat_interleave(k) * NUM_JOINTS + joints.reshape(-1)
    w = vertex_joint.gather(1, joints).reshape(-1)
    child = torch.arange(1, NUM_JOINTS, device=dev)
    blocks = n + torch.arange(num_graphs, device=dev)[:, None] * NUM_JOINTS
    bc, bp = (blocks + child).reshape(-1), (blocks + parents[child].to(dev)).reshape(-1)
    bone_w = torch.ones(bc.shape[0], dtype=w.dtype, device=dev)
    mesh_w = torch.ones(mesh[0].shape[0], dtype=w.dtype, device=dev)
    src = torch.cat([mesh[0], v, j, bc, bp])
    dst = torch.cat([mesh[1], j, v, bp, bc])
    weight = torch.cat([mesh_w, w, w, bone_w, bone_w])
    return normalised_operator(src, dst, weight, n + num_graphs * NUM_JOINTS, kind)


class DeepSkinning(nn.Module):
    """Sec. 3.3: encoder features, joint motion and previous frames -> per-vertex transforms."""

    def __init__(self, encoder_features: int, width: int = 128, node: int = 32, *,
                 learned_edges: bool = True):
        super().__init__()
        self.edges = mlp([encoder_features, width, width // 2, NUM_JOINTS]) if learned_edges else None
        self.previous = mlp([PREVIOUS_FEATURES, node, node])
        self.template = nn.Linear(encoder_features, node)
        self.joints = mlp([JOINT_FEATURES, node, node])
        self.convs = nn.ModuleList([GraphConv(node, width, nn.ReLU()), GraphConv(width, width, nn.ReLU()),
                                    GraphConv(width, width, nn.ReLU())])
        self.head = mlp([width, width, width // 2, width // 4, 12], zero_last=True)

    def joint_edges(self, encoded: torch.Tensor, prior: torch.Tensor | None = None) -> torch.Tensor:
        """Learned vertex-joint edge weights (N, 24), a softmax over the joints.

        Args:
            encoded: encoder features (N, C).
            prior: weights (N, 24) whose logarithms offset the logits (the body's skinning weights
                carried to the garment), None: none. With the prior the network learns how the
                garment departs from the body's skinning rather than the skinning itself: an
                untrained network's garment then follows the body instead of the mean of all 24
                bones (on the sample dataset at step 0: 27 mm mean vertex error, 144 mm without).
        """
        if self.edges is None:
            raise RuntimeError("this network's vertex-joint edges are the body's skinning weights")
        logits = self.edges(encoded)
        if prior is not None:
            logits = logits + prior.clamp_min(EDGE_PRIOR_FLOOR).log()
        return torch.softmax(logits, dim=-1)

    def forward(self, graph: Graph, encoded: torch.Tensor, previous: torch.Tensor,
                joints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-vertex transform corrections (N, 3, 4) and the vertices' graph features (N, width).

        Args:
            graph: :func:`skinning_graph` of this batch.
            encoded: encoder features (N, C); previous: temporal features (N, 6);
            joints: joint features of each garment's body (G * 24, 24).
        """
        n = encoded.shape[0]
        h = torch.cat([self.previous(previous) + self.template(encoded), self.joints(joints)])
        for conv in self.convs:
            h = conv(graph, h)
        hv = h[:n]
        return self.head(hv).reshape(n, 3, 4), hv


class PhysicalRegression(nn.Module):
    """Sec. 3.4: a correction (N, 3) [m] for the vertices the body filter marks."""

    def __init__(self, width: int = 128, node: int = 32):
        super().__init__()
        self.vertices = mlp([width + REGRESSION_FEATURES, node, node])
        self.joints = mlp([JOINT_FEATURES, node, node])
        self.convs = nn.ModuleList([GraphConv(node, width // 2, nn.ReLU()),
                                    GraphConv(width // 2, width // 2, nn.ReLU()),
                                    GraphConv(width // 2, width // 2, nn.ReLU())])
        self.head = mlp([width // 2, width // 4, 3], zero_last=True)

    def forward(self, graph: Graph, features: torch.Tensor, geometry: torch.Tensor,
                joints: torch.Tensor) -> torch.Tensor:
        """Corrections [m] (N, 3) from the skinning's vertex features (N, width), the geometry
        (N, ``REGRESSION_FEATURES``) and the joint features (G * 24, 24), on ``graph``."""
        n = features.shape[0]
        h = torch.cat([self.vertices(torch.cat([features, geometry], dim=1)), self.joints(joints)])
        for conv in self.convs:
            h = conv(graph, h)
        return self.head(h[:n])


@dataclass
class GarmentBatch:
    """The static inputs of a batch of G garments (one per sample), vertices concatenated.

    Attributes:
        features: template features of every vertex (N, C) (``learn.gsnet.features``).
        rest: template positions on the rest body [m] (N, 3).
        mesh: batched mesh edges, both directions: ``(src, dst)``, each (2E,) int64.
        segment: each vertex's garment (N,) int64.
        skin_weights: body skinning weights transferred to the vertices (N, 24): the vertex-joint
            edges of the ablation without learned edges.
    """

    features: torch.Tensor
    rest: torch.Tensor
    mesh: tuple[torch.Tensor, torch.Tensor]
    segment: torch.Tensor
    skin_weights: torch.Tensor

    @property
    def num_graphs(self) -> int:
        return int(self.segment[-1]) + 1 if self.segment.numel() else 0

    def to(self, device) -> GarmentBatch:
        return GarmentBatch(self.features.to(device), self.rest.to(device),
                            (self.mesh[0].to(device), self.mesh[1].to(device)), self.segment.to(device),
                            self.skin_weights.to(device))


@dataclass
class Encoded:
    """What the per-frame passes reuse: encoder features, vertex-joint edges, the skinning graph."""

    features: torch.Tensor
    joint_edges: torch.Tensor
    graph: Graph


def blend(weights: torch.Tensor, transforms: torch.Tensor, segment: torch.Tensor) -> torch.Tensor:
    """Per-vertex 3 x 4 transforms ``sum_j w_vj A_j``: weights (N, 24), transforms (G, 24, 3, 4);
    float32 also under autocast (``positions``)."""
    with positions():
        return torch.einsum("nj,njab->nab", weights.float(), transforms.float().index_select(0, segment))


def apply_transforms(m: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``M [p; 1]`` for (N, 3, 4) transforms and (N, 3) points [m], in float32 (``positions``)."""
    with positions():
        m, points = m.float(), points.float()
        return torch.einsum("nab,nb->na", m[..., :3], points) + m[..., 3]


@contextlib.contextmanager
def positions():
    """A context that keeps position arithmetic in float32 under mixed precision: in bfloat16 a
    coordinate of 1.2 m rounds to 8 mm steps (0.8 mm mean, 3.7 mm worst output difference from
    float32 on the sample dataset), the size of the errors being learned."""
    with torch.autocast("cpu", enabled=False):
        if torch.cuda.is_available():
            with torch.autocast("cuda", enabled=False):
                yield
        else:
            yield


def temporal_features(offsets: list[torch.Tensor], fps: float) -> torch.Tensor:
    """A vertex's temporal input (N, 6) from its offsets from the skinning prior at t-2 and t-1
    (N, 3) each [m]: the offset at t-1 and its rate of change [m/s], each squashed by ``tanh`` to
    at most ``OFFSET_SCALE`` / ``RATE_SCALE``.

    Relative to the skinning, the features are zero where the garment follows the body and do not
    grow with the body's own speed; bounded, they keep a rollout's output bounded (the output
    depends on its past only through them). Raw positions and velocities as features feed a
    drifting frame's error back without limit: with them, a network trained on 3-frame rollouts
    diverged on 3 of 14 test sequences within 60 frames."""
    o, rate = offsets[-1], (offsets[-1] - offsets[-2]) * fps
    return torch.cat([OFFSET_SCALE * torch.tanh(o / OFFSET_SCALE),
                      RATE_SCALE * torch.tanh(rate / RATE_SCALE)], dim=1)


def project_out(x: torch.Tensor, anchors: torch.Tensor, normals: torch.Tensor, margin: float) -> torch.Tensor:
    """Positions (N, 3) closer than ``margin`` [m] to their anchor's tangent plane (nearest body
    vertex ``anchors``, unit ``normals``, (N, 3) each), or behind it, moved along the normal onto
    the plane offset by ``margin``; the others unchanged."""
    s = ((x - anchors) * normals).sum(-1, keepdim=True)
    return x + (margin - s).clamp_min(0.0) * normals


def previous_transforms(transforms: torch.Tensor, roots: torch.Tensor, k: int) -> torch.Tensor:
    """Frame k-1's bone transforms relative to frame k's root (G, 24, 3, 4): the joints' motion
    including the root's own between the frames, in the frame the network works in at k."""
    prev = transforms[:, k - 1].clone()
    prev[..., 3] += (roots[:, k - 1] - roots[:, k])[:, None, :]
    return prev


class GSNet(nn.Module):
    """Eq. 1, ``G_t = W(T, G_{t-1}, S(beta, theta_t))``: the three stages (module docstring).

    Args:
        in_features: template features per vertex.
        width: graph feature width (the paper's 128); node: node width of the joint graphs.
        operator: "laplacian" (Eq. 2-3) or "adjacency" (``learn.graph.OPERATORS``).
        learned_edges: False: the vertex-joint edges are the body's transferred skinning weights.
        edge_prior: the learned edges' logits are offset by the log of those weights
            (``DeepSkinning.joint_edges``).
        joint_topk: each vertex keeps its k strongest joint edges (renormalised) in the graph and
            the blend; 0: all 24.
        regression: with the physical regression stage (Sec. 3.4).
        parents: the skeleton's parent indices (24,).
    """

    def __init__(self, in_features: int, *, width: int = 128, node: int = 32, operator: str = "laplacian",
                 learned_edges: bool = True, edge_prior: bool = True, regression: bool = True,
                 joint_topk: int = 0, parents=None):
        super().__init__()
        self.operator = operator
        self.joint_topk = int(joint_topk)
        self.learned_edges = learned_edges
        self.edge_prior = edge_prior
        self.encoder = GarmentEncoder(in_features, width)
        self.skinning = DeepSkinning(2 * width + in_features, width, node, learned_edges=learned_edges)
        self.regression = PhysicalRegression(width, node) if regression else None
        self.register_buffer("parents", torch.as_tensor(parents, dtype=torch.int64), persistent=False)

    def encode(self, garments: GarmentBatch) -> Encoded:
        """The per-garment work of a batch, done once for all its frames."""
        g = garments.num_graphs
        n = garments.features.shape[0]
        feats = garments.features
        w = torch.ones(garments.mesh[0].shape[0], dtype=feats.dtype, device=feats.device)
        mesh_op = normalised_operator(garments.mesh[0], garments.mesh[1], w, n, self.operator)
        encoded = self.encoder(mesh_op, garments.features, garments.segment, g)
        if self.learned_edges:
            edges = self.skinning.joint_edges(encoded, garments.skin_weights if self.edge_prior else None)
        else:
            edges = garments.skin_weights
        joints = None
        if 0 < self.joint_topk < NUM_JOINTS:  # the k strongest joints of each vertex, renormalised
            top, joints = edges.topk(self.joint_topk, dim=1)
            edges = torch.zeros_like(edges).scatter(1, joints, top / top.sum(1, keepdim=True))
        graph = skinning_graph(garments.mesh, edges, garments.segment, self.parents, g, self.operator, joints)
        return Encoded(encoded, edges, graph)

    def prior(self, enc: Encoded, garments: GarmentBatch, transforms: torch.Tensor) -> torch.Tensor:
        """Blend skinning of the templates with the vertex-joint edges (N, 3) [m]: the untrained
        network's output, what the temporal offsets are measured from."""
        return apply_transforms(blend(enc.joint_edges, transforms, garments.segment), garments.rest)

    def skin(self, enc: Encoded, garments: GarmentBatch, transforms: torch.Tensor, joints: torch.Tensor,
             previous: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Deep skinning of one frame: positions (N, 3) [m], the vertices' graph features and the
        frame's skinning prior (``prior``, from the same blend).

        Args:
            transforms: root-relative bone transforms of each garment's body (G, 24, 3, 4).
            joints: joint features (G * 24, 24); previous: temporal features (N, 6).
        """
        delta, hv = self.skinning(enc.graph, enc.features, previous, joints)
        m = blend(enc.joint_edges, transforms, garments.segment)
        return apply_transforms(m + delta, garments.rest), hv, apply_transforms(m, garments.rest)

    def regress(self, enc: Encoded, x: torch.Tensor, features: torch.Tensor, anchors: torch.Tensor,
                normals: torch.Tensor, joints: torch.Tensor, eps: float) -> torch.Tensor:
        """Physical regression: ``x`` (N, 3) with the filtered vertices corrected (Sec. 3.4).

        Positions ``x``, ``anchors`` are relative to the frame's root [m].

        Args:
            anchors, normals: nearest body vertex of each garment vertex and its unit normal (N, 3).
            eps: filter threshold [m]: vertices with ``(x - anchor) . normal < eps`` are corrected.
        """
        if self.regression is None:
            return x
        d = x - anchors
        s = (d * normals).sum(-1, keepdim=True)
        geometry = torch.cat([x, d, normals, s], dim=1)
        fix = self.regression(enc.graph, features, geometry, joints)
        return x + (s < eps).to(x.dtype) * fix

    def forward(self, garments: GarmentBatch, transforms: torch.Tensor, roots: torch.Tensor,
                history: torch.Tensor | None, *, anchors=None, fps: float = 30.0, temporal: bool = True,
                cold: torch.Tensor | None = None, eps: float = 1.0e-3,
                margin: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
        """Roll the garments out over frames 2 .. T-1 of their bodies' motion (Eq. 1, each frame
        fed the previous outputs).

        Args:
            garments: the batch's templates.
            transforms: root-relative bone transforms (G, T, 24, 3, 4); roots: root positions (G, T, 3) [m].
            history: garment positions of frames 0 and 1 (2, N, 3) [m]; None: every garment
                starts on the skinning prior (``prior``), as an animation starts: no offset from
                it, no rate (``temporal_features``).
            anchors: ``anchors(x, k)`` -> nearest body vertices and their normals (N, 3) each for
                positions ``x`` (N, 3) [m] at frame k; None: no regression, no projection.
            fps: frame rate (velocities in m/s); temporal: False: no previous-frame inputs (ablation).
            cold: (G,) bool, garments whose history is replaced by the start of an animation
                (``history`` None's) in training.
            eps: threshold [m] of the regression's filter.
            margin: the final positions are :func:`project_out` of the body by this margin [m]
                (0: not projected; with ``anchors`` only).

        Returns:
            Deep skinning's and the final positions of frames 2 .. T-1, each (T-2, N, 3) [m].
        """
        enc = self.encode(garments)
        seg = garments.segment
        skinned, final = [], []
        offsets = [garments.rest.new_zeros(garments.rest.shape)] * 2  # the start: on the prior
        if temporal and history is not None:  # each history frame's offset from the prior
            offsets = [history[j] - self.prior(enc, garments, transforms[:, j]).detach() - roots[seg, j]
                       for j in (0, 1)]
            if cold is not None:
                c = cold.index_select(0, seg)[:, None]
                offsets = [torch.where(c, 0.0, o) for o in offsets]
        for k in range(2, transforms.shape[1]):
            root = roots[seg, k]
            cur, prev = transforms[:, k], previous_transforms(transforms, roots, k)
            if temporal:
                previous = temporal_features(offsets, fps)
                joints = torch.cat([cur.flatten(-2), prev.flatten(-2)], dim=-1)
            else:
                previous = offsets[0].new_zeros(offsets[0].shape[0], PREVIOUS_FEATURES)
                joints = torch.cat([cur.flatten(-2), torch.zeros_like(prev.flatten(-2))], dim=-1)
            joints = joints.reshape(-1, JOINT_FEATURES)
            x, hv, prior = self.skin(enc, garments, cur, joints, previous)
            skinned.append(x + root)
            if anchors is not None and (self.regression is not None or margin > 0):
                pts, nrm = anchors((x + root).detach(), k)
                x = self.regress(enc, x, hv, pts - root, nrm, joints, eps)
                if margin > 0:
                    x = project_out(x, pts - root, nrm, margin)
            final.append(x + root)
            if temporal and k + 1 < transforms.shape[1]:
                offsets = [offsets[-1], x - prior.detach()]
        return torch.stack(skinned), torch.stack(final)
