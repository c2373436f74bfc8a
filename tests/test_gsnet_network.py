"""GSNet's network (learn.gsnet.network): equivariance, batching, the untrained network's skinning."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learn.graph import mesh_edges
from learn.gsnet.data import Template, garment_batch
from learn.gsnet.features import TEMPLATE_FEATURES
from learn.gsnet.network import (
    OFFSET_SCALE,
    RATE_SCALE,
    GarmentEncoder,
    GSNet,
    apply_transforms,
    blend,
    project_out,
    temporal_features,
)
from sim.rotations import axis_angle_to_matrix
from tests.test_graph import grid_faces

PARENTS = np.array([-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21])


def template(nx: int, ny: int, seed: int) -> Template:
    rng = np.random.default_rng(seed)
    faces = grid_faces(nx, ny).astype(np.int32)
    n = nx * ny
    rest = np.stack(np.meshgrid(np.linspace(0, 0.4, nx), np.linspace(0, 0.3, ny)), -1).reshape(-1, 2)
    rest = np.concatenate([rest, 0.05 * rng.normal(size=(n, 1))], 1).astype(np.float32)
    w = rng.random((n, 24)).astype(np.float32) ** 4
    feats = rng.normal(size=(n, TEMPLATE_FEATURES)).astype(np.float32)
    return Template(feats, rest, faces, mesh_edges(faces), w / w.sum(1, keepdims=True))


def motion(frames: int, garments: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    rng = np.random.default_rng(seed)
    rot = axis_angle_to_matrix(0.3 * rng.normal(size=(garments * frames * 24, 3))).astype(np.float32)
    a = np.concatenate([rot, 0.05 * rng.normal(size=(rot.shape[0], 3, 1)).astype(np.float32)], -1)
    roots = np.cumsum(0.02 * rng.normal(size=(garments, frames, 3)), 1).astype(np.float32)
    return torch.from_numpy(a.reshape(garments, frames, 24, 3, 4)), torch.from_numpy(roots)


def net(**kw) -> GSNet:
    torch.manual_seed(0)
    return GSNet(TEMPLATE_FEATURES, width=32, node=8, parents=PARENTS, **kw)


def randomise_heads(model: GSNet) -> None:
    """Give the zero-initialised last layers values, so every path of the network matters."""
    g = torch.Generator().manual_seed(5)
    for head in [model.skinning.head[-1], *([model.regression.head[-1]] if model.regression else [])]:
        with torch.no_grad():
            head.weight.copy_(0.05 * torch.randn(head.weight.shape, generator=g))


def square_garment_scene(frames: int, seed: int, **kw):
    """A 4 x 4 grid garment, a network with every path live (``randomise_heads``) and a motion of
    ``frames`` frames: (model, garment batch, transforms, roots)."""
    model = net(**kw)
    randomise_heads(model)
    a, roots = motion(frames, 1, seed)
    return model, garment_batch([template(4, 4, 0)]), a, roots


def permuted(t: Template, perm: np.ndarray) -> Template:
    """The same garment with vertex i renamed inv[i] (new vertex k is old vertex perm[k])."""
    inv = np.argsort(perm)
    faces = inv[t.faces].astype(np.int32)
    return Template(t.features[perm], t.rest[perm], faces, mesh_edges(faces), t.skin_weights[perm])


@pytest.mark.parametrize("operator", ["laplacian", "adjacency"])
def test_encoder_is_permutation_equivariant(operator):
    t = template(5, 4, 0)
    perm = np.random.default_rng(1).permutation(t.num_vertices)
    model = net(operator=operator)
    outs = []
    for tt in (t, permuted(t, perm)):
        enc = model.encode(garment_batch([tt]))
        outs.append(enc.features)
    torch.testing.assert_close(outs[1], outs[0][perm], atol=1e-5, rtol=1e-5)


def test_rollout_is_permutation_equivariant():
    t = template(5, 4, 0)
    perm = np.random.default_rng(2).permutation(t.num_vertices)
    model = net()
    randomise_heads(model)
    a, roots = motion(5, 1, 3)
    outs = [model(garment_batch([tt]), a, roots, None)[1] for tt in (t, permuted(t, perm))]
    torch.testing.assert_close(outs[1], outs[0][:, perm], atol=1e-5, rtol=1e-5)


def test_a_batch_of_topologies_equals_each_garment_alone():
    ts = [template(5, 4, 0), template(3, 6, 1), template(7, 2, 2)]
    model = net()
    randomise_heads(model)
    a, roots = motion(4, 3, 4)
    together = model(garment_batch(ts), a, roots, None)[1]
    offsets = np.cumsum([0] + [t.num_vertices for t in ts])
    for i, t in enumerate(ts):
        alone = model(garment_batch([t]), a[i:i + 1], roots[i:i + 1], None)[1]
        torch.testing.assert_close(together[:, offsets[i]:offsets[i + 1]], alone, atol=1e-5, rtol=1e-5)


def test_untrained_network_is_blend_skinning_with_its_learned_edges():
    t = template(4, 4, 0)
    model = net()
    a, roots = motion(4, 1, 5)
    g = garment_batch([t])
    skinned, final = model(g, a, roots, None)
    enc = model.encode(g)
    torch.testing.assert_close(enc.joint_edges.sum(1), torch.ones(16))  # a softmax over the joints
    for k in range(2, 4):
        ref = apply_transforms(blend(enc.joint_edges, a[:, k], g.segment), g.rest) + roots[0, k]
        torch.testing.assert_close(skinned[k - 2], ref)
    torch.testing.assert_close(final, skinned)


def test_without_learned_edges_the_prior_is_the_bodys_skinning():
    t = template(4, 4, 0)
    model = net(learned_edges=False)
    a, roots = motion(3, 1, 6)
    g = garment_batch([t])
    skinned, _ = model(g, a, roots, None)
    w = torch.from_numpy(t.skin_weights)
    ref = torch.einsum("nj,jab->nab", w, a[0, 2])
    torch.testing.assert_close(skinned[0], apply_transforms(ref, g.rest) + roots[0, 2])


def test_regression_moves_only_the_filtered_vertices():
    model, g, a, roots = square_garment_scene(3, 7)
    inside = torch.zeros(16, dtype=torch.bool)
    inside[[1, 5, 9]] = True

    def anchors(x, k):  # a plane through each vertex, facing away for the "inside" ones
        n = torch.zeros_like(x)
        n[:, 1] = torch.where(inside, 1.0, -1.0)
        return x - 0.01 * n * torch.where(inside, -1.0, 1.0)[:, None], n

    skinned, final = model(g, a, roots, None, anchors=anchors, eps=0.0)
    moved = (final[0] - skinned[0]).norm(dim=1) > 0
    assert moved.tolist() == inside.tolist()


def test_forward_is_deterministic():
    t = template(5, 5, 0)
    a, roots = motion(5, 1, 8)
    outs = []
    for _ in range(2):
        model = net()
        randomise_heads(model)
        outs.append(model(garment_batch([t]), a, roots, None)[1])
    assert torch.equal(outs[0], outs[1])


def test_encoder_features_concatenate_the_global_maximum():
    torch.manual_seed(0)
    enc = GarmentEncoder(TEMPLATE_FEATURES, 16)
    g = garment_batch([template(4, 3, 0), template(3, 3, 1)])
    from learn.graph import normalised_operator

    w = torch.ones(g.mesh[0].shape[0])
    out = enc(normalised_operator(g.mesh[0], g.mesh[1], w, 21), g.features, g.segment, 2)
    local, glob, raw = out[:, :16], out[:, 16:32], out[:, 32:]
    torch.testing.assert_close(glob[:12], local[:12].max(0).values.expand(12, 16))
    torch.testing.assert_close(glob[12:], local[12:].max(0).values.expand(9, 16))
    torch.testing.assert_close(raw, g.features)  # the skip: template features unfiltered


def test_joint_topk_keeps_each_vertexs_strongest_joints():
    t = template(4, 4, 0)
    g = garment_batch([t])
    dense, sparse = net(), net(joint_topk=4)
    sparse.load_state_dict(dense.state_dict())
    e_dense, e_sparse = dense.encode(g), sparse.encode(g)
    assert ((e_sparse.joint_edges > 0).sum(1) == 4).all()
    torch.testing.assert_close(e_sparse.joint_edges.sum(1), torch.ones(16))
    kept = e_sparse.joint_edges > 0
    strongest = e_dense.joint_edges.topk(4, dim=1).indices
    assert kept.gather(1, strongest).all()
    ratio = e_sparse.joint_edges[kept] / e_dense.joint_edges[kept]  # the same weights, renormalised
    torch.testing.assert_close(ratio.reshape(16, 4), ratio.reshape(16, 4)[:, :1].expand(16, 4))
    # 4 vertex-joint edges each way per vertex instead of 24
    assert e_dense.graph.src.shape[0] - e_sparse.graph.src.shape[0] == 2 * 16 * 20
    # with all 24 kept the network is the dense one
    full = net(joint_topk=24)
    full.load_state_dict(dense.state_dict())
    a, roots = motion(3, 1, 9)
    torch.testing.assert_close(full(g, a, roots, None)[1], dense(g, a, roots, None)[1])


def test_positions_stay_float32_under_mixed_precision():
    """bfloat16 rounds a 1.2 m coordinate to 8 mm steps; the skinning keeps float32 under autocast
    (what differs is the network's own bfloat16 arithmetic: its joint weights, 0.2 mm here)."""
    t = template(5, 4, 0)
    t.rest[:] += np.float32([0.1, 1.2, 0.05])  # where a garment sits on a standing body
    model = net()
    a, roots = motion(4, 1, 10)
    g = garment_batch([t])
    ref = model(g, a, roots, None)[0]
    with torch.autocast("cpu", dtype=torch.bfloat16):
        low = model(g, a, roots, None)[0]
    assert low.dtype == torch.float32 and (low - ref).abs().max() < 5e-4


def test_previous_transforms_carry_the_roots_motion():
    """A body that only walks forward: frame k-1's bones, seen from frame k's root, sit behind by
    the root's step."""
    from learn.gsnet.network import previous_transforms

    a, _ = motion(3, 2, 11)
    a[:, 1] = a[:, 2]  # the same pose at k-1 and k
    roots = torch.zeros(2, 3, 3)
    roots[:, 2, 2] = 0.05  # the root moved 5 cm along z
    prev = previous_transforms(a, roots, 2)
    torch.testing.assert_close(prev[..., :3], a[:, 2, ..., :3])
    torch.testing.assert_close(prev[..., 3] - a[:, 2, ..., 3], torch.tensor([0, 0, -0.05]).expand(2, 24, 3))


def test_temporal_features_are_offsets_from_the_prior_bounded():
    small = torch.tensor([[1e-3, -2e-3, 0.0]])
    f = temporal_features([torch.zeros(1, 3), small], fps=30.0)
    # offsets of mm pass nearly unchanged (tanh(x) = x - x^3/3: 1.3e-4 relative at 2 mm); the rate
    # is the offset's change * fps
    torch.testing.assert_close(f[:, :3], small, atol=1e-9, rtol=2e-4)
    torch.testing.assert_close(f[:, 3:], RATE_SCALE * torch.tanh(small * 30.0 / RATE_SCALE))
    huge = torch.tensor([[5.0, -1e6, 3e3]])
    f = temporal_features([-huge, huge], fps=30.0)
    bound = torch.tensor([OFFSET_SCALE] * 3 + [RATE_SCALE] * 3)  # float32, as the features
    assert bool((f.abs() <= bound).all())
    torch.testing.assert_close(f[:, :3].abs(), torch.full((1, 3), OFFSET_SCALE))


def test_a_diverged_history_cannot_push_the_rollout_further():
    """The output depends on its past only through bounded features: histories 1 km and 1,000 km
    from the body give the same frames (to 1 mm: float32 offsets of 1,000 km keep 6 cm steps, and
    the rate of two of them differs), near the body."""
    model, g, a, roots = square_garment_scene(6, 9)
    far = [model(g, a, roots, torch.full((2, 16, 3), d))[1] for d in (1e3, 1e6)]
    torch.testing.assert_close(far[0], far[1], atol=1e-3, rtol=0)
    prior = model(g, a, roots, None)[0]
    assert (far[1] - prior).norm(dim=-1).max() < 1.0


def test_projection_puts_vertices_the_margin_outside_the_body_and_leaves_the_rest():
    n = torch.tensor([[0.0, 0.0, 1.0]] * 3)
    anchors = torch.zeros(3, 3)
    x = torch.tensor([[0.1, 0.2, -0.05], [0.0, 0.3, 0.001], [0.4, 0.0, 0.01]])  # inside, close, clear
    y = project_out(x, anchors, n, 2e-3)
    torch.testing.assert_close(y[:2, 2], torch.full((2,), 2e-3))
    torch.testing.assert_close(y[:2, :2], x[:2, :2])  # moved along the normal only
    torch.testing.assert_close(y[2], x[2])


def test_rollout_with_a_margin_keeps_every_vertex_outside():
    model, g, a, roots = square_garment_scene(5, 10, regression=False)

    def anchors(x, k):  # a floor through the garment's mean height, facing up
        n = torch.zeros_like(x)
        n[:, 2] = 1.0
        return x.mean(0).expand_as(x), n

    skinned, final = model(g, a, roots, None, anchors=anchors, margin=0.01)
    for s, f in zip(skinned, final, strict=True):
        height = s[:, 2].mean()
        assert bool((f[:, 2] >= height + 0.01 - 1e-6).all())
        torch.testing.assert_close(f[s[:, 2] > height + 0.01], s[s[:, 2] > height + 0.01])


def test_inference_products_give_the_training_rollout():
    """Under no_grad the graph products go through CSR matrices: the same frames."""
    ts = [template(4, 4, 0), template(3, 5, 1)]
    model = net()
    randomise_heads(model)
    a, roots = motion(5, 2, 11)
    g = garment_batch(ts)
    trained = model(g, a, roots, None)[1]
    with torch.no_grad():
        inferred = model(g, a, roots, None)[1]
    torch.testing.assert_close(inferred, trained.detach(), atol=1e-6, rtol=1e-5)


def test_a_rollout_continued_from_its_own_frames_gives_the_same_frames():
    """The offsets carried from frame to frame are those a history of the same positions gives."""
    model, g, a, roots = square_garment_scene(7, 12)
    whole = model(g, a, roots, None)[1]  # frames 2 .. 6
    tail = model(g, a[:, 2:], roots[:, 2:], whole[:2])[1]  # frames 4 .. 6 from frames 2, 3
    torch.testing.assert_close(tail, whole[2:], atol=1e-5, rtol=1e-5)


def test_an_animation_and_a_cold_start_begin_on_the_prior_whatever_came_before():
    """No offset, no rate at the start: frame 0's pose and a cold item's history change nothing."""
    model, g, a, roots = square_garment_scene(5, 13)
    start = model(g, a, roots, None)[1]
    other = a.clone()
    other[:, 0] = motion(1, 1, 14)[0][:, 0]
    torch.testing.assert_close(model(g, other, roots, None)[1], start)
    cold = model(g, a, roots, torch.full((2, 16, 3), 5.0), cold=torch.tensor([True]))[1]
    torch.testing.assert_close(cold, start)
