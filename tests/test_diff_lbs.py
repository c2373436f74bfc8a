"""Differentiable LBS (Warp forward + hand-written adjoint) against torch references, exact
rigid answers and finite differences; weight transfer; 6D rotations."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import learn.skinning as sk
from learn.skinning import (
    LinearBlendSkinning,
    compose_transforms,
    linear_blend_skinning,
    matrix_to_rotation_6d,
    rigid_transforms,
    rotation_6d_to_matrix,
)
from sim.errors import WrinklesInputError
from sim.skinning.lbs import sparse_weights
from sim.skinning.transfer import transfer_skinning_weights

B, V, J = 3, 500, 24
# float32 kernel vs float32 torch reference, both O(1) values: sums of <= 24 terms differ by a few ulps.
RTOL_FWD, ATOL_FWD = 1e-5, 1e-5
# gradients sum up to V = 500 products in a different order than torch: relative 1e-4 of the largest entry.
RTOL_GRAD = 1e-4


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _weights(seed: int = 0) -> np.ndarray:
    """Sparse-ish normalised (V, J) weights, 1..6 influences a vertex (like a body's)."""
    rng = np.random.default_rng(seed)
    w = rng.random((V, J)) ** 8
    w[w < 0.3] = 0.0
    w[np.arange(V), rng.integers(0, J, V)] += 0.5
    return (w / w.sum(axis=1, keepdims=True)).astype(np.float32)


def _problem(device: str, *, seed: int = 0, batched_points: bool = False, homogeneous: bool = True):
    g = _gen(seed)
    points = torch.randn((B, V, 3) if batched_points else (V, 3), generator=g)
    A = torch.randn(B, J, 3, 4, generator=g)
    if homogeneous:
        A = torch.cat((A, torch.tensor([0.0, 0.0, 0.0, 1.0]).expand(B, J, 1, 4)), dim=2)
    return points.to(device), A.to(device), torch.from_numpy(_weights(seed)).to(device)


def _reference(points, A, W):
    """Plain-torch LBS: x = sum_j W_vj (R_j p + t_j), W dense (V, J)."""
    pts = points.expand(A.shape[0], *points.shape[-2:])
    per_bone = torch.einsum("bjrc,bvc->bvjr", A[..., :3, :3], pts) + A[:, None, :, :3, 3]
    return torch.einsum("vj,bvjr->bvr", W, per_bone)


def _sparse(W):
    idx, val = sparse_weights(W.cpu().numpy())
    return torch.from_numpy(idx).to(W.device), torch.from_numpy(val).to(W.device)


def _close(actual, expected, rtol):
    e = expected.detach().cpu().numpy()
    np.testing.assert_allclose(actual.detach().cpu().numpy(), e, rtol=rtol, atol=rtol * np.abs(e).max())


@pytest.mark.parametrize("sparse", [False, True])
@pytest.mark.parametrize("batched_points", [False, True])
def test_forward_matches_reference(device, sparse, batched_points):
    points, A, W = _problem(device, seed=1, batched_points=batched_points)
    ref = _reference(points, A, W)
    if sparse:
        idx, val = _sparse(W)
        out = linear_blend_skinning(points, A, weight_idx=idx, weight_val=val)
    else:
        out = linear_blend_skinning(points, A, W)
    assert out.shape == (B, V, 3) and out.dtype == torch.float32 and out.device == points.device
    np.testing.assert_allclose(out.cpu().numpy(), ref.cpu().numpy(), rtol=RTOL_FWD, atol=ATOL_FWD)
    out34 = linear_blend_skinning(points, A[..., :3, :], W)  # 3x4 transforms give the same
    np.testing.assert_allclose(out34.cpu().numpy(), ref.cpu().numpy(), rtol=RTOL_FWD, atol=ATOL_FWD)


def test_forward_on_a_torch_cuda_stream(device):
    """Launches go on torch's current stream: results are right when torch works on a side stream."""
    if device != "cuda":
        pytest.skip("stream test is for cuda")
    points, A, W = _problem(device, seed=2)
    s = torch.cuda.Stream()
    s.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(s):
        scaled = A * 1.0  # queued on s just before the kernel reads it
        out = linear_blend_skinning(points, scaled, W)
    torch.cuda.current_stream().wait_stream(s)
    _close(out, _reference(points, A, W), RTOL_FWD)


def test_identity_transforms_return_rest_exactly(device):
    """Dyadic weights sum to exactly 1 in float32, so identity bones reproduce the points bitwise."""
    rng = np.random.default_rng(3)
    counts = rng.multinomial(8, np.full(J, 1.0 / J), size=V)  # (V, J), rows sum to 8
    W = torch.from_numpy((counts / 8.0).astype(np.float32)).to(device)
    points = torch.randn(V, 3, generator=_gen(3)).to(device)
    eye = torch.eye(4).expand(B, J, 4, 4).to(device)
    np.testing.assert_array_equal(linear_blend_skinning(points, eye, W).cpu().numpy(),
                                  points.expand(B, V, 3).cpu().numpy())
    idx, val = _sparse(W)
    sparse_out = linear_blend_skinning(points, eye, weight_idx=idx, weight_val=val)
    np.testing.assert_array_equal(sparse_out.cpu().numpy(), points.expand(B, V, 3).cpu().numpy())


def test_common_rigid_transform_moves_mesh_rigidly(device):
    points, _, W = _problem(device, seed=4)
    x6 = torch.randn(B, 6, generator=_gen(4))
    R, t = rotation_6d_to_matrix(x6), torch.randn(B, 3, generator=_gen(5))
    A = rigid_transforms(R, t)[:, None].expand(B, J, 3, 4).to(device)
    expect = torch.einsum("brc,vc->bvr", R, points.cpu()) + t[:, None]
    np.testing.assert_allclose(linear_blend_skinning(points, A, W).cpu().numpy(), expect.numpy(), atol=1e-5)


def _grads(points, A, W, sparse, seed):
    """(ours, reference) gradients wrt points, transforms, weights for a random cotangent."""
    r = torch.randn(B, V, 3, generator=_gen(seed)).to(points.device)
    ins = [t.clone().requires_grad_() for t in (points, A, W)]
    ref = torch.autograd.grad((_reference(*ins) * r).sum(), ins)
    ins = [t.clone().requires_grad_() for t in (points, A, W)]
    if sparse:
        idx, val = _sparse(W)
        val = val.clone().requires_grad_()
        out = linear_blend_skinning(ins[0], ins[1], weight_idx=idx, weight_val=val)
        gp, ga, gv = torch.autograd.grad((out * r).sum(), [ins[0], ins[1], val])
        # dense gradient at the non-zero entries, gathered into the sparse slots
        ref_w = torch.gather(ref[2], 1, idx.long())
        return (gp, ga, gv), (ref[0], ref[1], ref_w)
    out = linear_blend_skinning(*ins)
    return torch.autograd.grad((out * r).sum(), ins), ref


@pytest.mark.parametrize("sparse", [False, True])
@pytest.mark.parametrize("batched_points", [False, True])
def test_gradients_match_torch_autograd(device, sparse, batched_points):
    points, A, W = _problem(device, seed=6, batched_points=batched_points)
    ours, ref = _grads(points, A, W, sparse, seed=7)
    assert ours[0].shape == points.shape and ours[1].shape == A.shape
    np.testing.assert_array_equal(ours[1][:, :, 3].cpu().numpy(), 0.0)  # bottom row of 4x4 is not read
    for a, e in zip(ours, ref, strict=True):
        _close(a, e, RTOL_GRAD)


@pytest.mark.parametrize(("method", "chunks"), [("scatter", 1), ("gather", 1), ("gather", 7)])
def test_every_transform_gradient_kernel(device, monkeypatch, method, chunks):
    """Both Eq. 4 kernels on every device (cpu uses the scatter, cuda the gather by default); 7
    chunks of 72 vertices (the last one short) exercise the two-stage reduction."""
    monkeypatch.setattr(sk, "_transforms_grad_method", lambda _device_type: method)
    monkeypatch.setattr(sk, "_num_chunks", lambda *_args: chunks)
    for sparse in (False, True):
        points, A, W = _problem(device, seed=8, batched_points=sparse)
        ours, ref = _grads(points, A, W, sparse, seed=9)
        _close(ours[1], ref[1], RTOL_GRAD)


def test_gradients_match_central_differences(device):
    """L = <r, lbs(p, A, w)> is linear in each input, so central differences are exact up to
    float32 rounding of L (~1e-5 here) for any step: h = 0.5 keeps that rounding small."""
    points, A, W = _problem(device, seed=10, batched_points=True, homogeneous=False)
    idx, val = _sparse(W)
    r = torch.randn(B, V, 3, generator=_gen(11)).to(device)
    ins = [points.clone().requires_grad_(), A.clone().requires_grad_(), val.clone().requires_grad_()]
    out = linear_blend_skinning(ins[0], ins[1], weight_idx=idx, weight_val=ins[2])
    grads = torch.autograd.grad((out * r).sum(), ins)

    def loss(p, a, v):
        with torch.no_grad():
            return float((linear_blend_skinning(p, a, weight_idx=idx, weight_val=v) * r).double().sum())

    h = 0.5
    for i in range(3):
        for s in range(2):
            d = torch.randn(ins[i].shape, generator=_gen(100 + 10 * i + s)).to(device)
            plus = [t.detach() + (h * d if k == i else 0.0) for k, t in enumerate(ins)]
            minus = [t.detach() - (h * d if k == i else 0.0) for k, t in enumerate(ins)]
            fd = (loss(*plus) - loss(*minus)) / (2.0 * h)
            analytic = float((grads[i].double() * d.double()).sum())
            np.testing.assert_allclose(fd, analytic, rtol=1e-3, atol=1e-2)


def test_needs_input_grad_skips_work(device, monkeypatch):
    launched: list[str] = []
    real = sk._launch

    def spy(kernel, *args):
        launched.append(kernel.key)
        real(kernel, *args)

    monkeypatch.setattr(sk, "_launch", spy)
    points, A, W = _problem(device, seed=12)
    idx, val = _sparse(W)
    A_req = A.clone().requires_grad_()
    out = linear_blend_skinning(points, A_req, weight_idx=idx, weight_val=val)
    launched.clear()
    out.sum().backward()
    if sk._transforms_grad_method(torch.device(device).type) == "scatter":
        assert launched == ["lbs_backward_transforms_scatter_kernel"]
    else:  # the reduce stage runs when the vertices are split into several chunks
        assert launched[0] == "lbs_backward_transforms_partial_kernel"
        assert set(launched[1:]) <= {"lbs_backward_transforms_reduce_kernel"}
    assert A_req.grad is not None and points.grad is None and val.grad is None

    p_req = points.clone().requires_grad_()
    out = linear_blend_skinning(p_req, A, weight_idx=idx, weight_val=val)
    launched.clear()
    (gp,) = torch.autograd.grad(out.sum(), [p_req])
    assert launched == ["lbs_backward_points_weights_kernel"]
    assert gp.shape == (V, 3)

    # the function returns None for inputs that need no gradient
    ctx_out = sk._LinearBlendSkinningFunction.apply(p_req[None].contiguous(), A[..., :3, :].contiguous(),
                                                    val.contiguous(), idx)
    fn = ctx_out.grad_fn
    grads = fn.apply(torch.ones_like(ctx_out))
    assert grads[0] is not None and grads[1] is None and grads[2] is None and grads[3] is None


def test_backward_is_deterministic(device):
    points, A, W = _problem(device, seed=13, batched_points=False)
    a, _ = _grads(points, A, W, True, seed=14)
    b, _ = _grads(points, A, W, True, seed=14)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.cpu().numpy(), y.cpu().numpy())


@pytest.mark.parametrize("sparse", [False, True])
def test_module_matches_function_and_learns_support_only(device, sparse):
    points, A, W = _problem(device, seed=15)
    module = LinearBlendSkinning(W.cpu().numpy(), sparse=sparse, learn_weights=True).to(device)
    out = module(points, A)
    _close(out, _reference(points, A, W), RTOL_FWD)
    np.testing.assert_allclose(module.dense_weights().detach().cpu().numpy(), W.cpu().numpy(), rtol=1e-6)
    out.square().sum().backward()
    g = module.weight_val.grad
    assert g is not None and g.shape == module.weight_val.shape
    if sparse:  # padding slots (zero weight) get no gradient; the support does
        np.testing.assert_array_equal(g[module.support == 0].cpu().numpy(), 0.0)
        assert bool((g[module.support == 1] != 0).all())
    frozen = LinearBlendSkinning(W, sparse=sparse).to(device)
    assert not any(p.requires_grad for p in frozen.parameters())
    np.testing.assert_allclose(frozen(points, A).cpu().numpy(), out.detach().cpu().numpy(),
                               rtol=1e-6, atol=1e-6)


def test_input_errors():
    points, A, W = _problem("cpu", seed=16)
    idx, val = _sparse(W)
    with pytest.raises(WrinklesInputError, match="float32"):
        linear_blend_skinning(points.double(), A, W)
    with pytest.raises(WrinklesInputError, match="bone indices"):
        linear_blend_skinning(points, A, weight_idx=idx + J - 1, weight_val=val)
    with pytest.raises(WrinklesInputError, match="bones"):
        linear_blend_skinning(points, A[:, :5], W)
    with pytest.raises(WrinklesInputError, match="batch"):
        linear_blend_skinning(points.expand(B + 1, V, 3), A, W)
    with pytest.raises(WrinklesInputError, match="missing"):
        linear_blend_skinning(points, A)
    with pytest.raises(WrinklesInputError, match="expected"):
        LinearBlendSkinning(W)(points, A[:, :3])


def test_transfer_weights_rows_sum_to_one_and_copy_on_body_vertices():
    rng = np.random.default_rng(17)
    body = rng.normal(size=(300, 3)).astype(np.float32)
    bw = _weights(18)[:300]
    garment = (body[:50] + rng.normal(size=(50, 3)) * 0.05).astype(np.float32)
    garment[:10] = body[100:110]  # ten garment vertices exactly on body vertices
    w = transfer_skinning_weights(garment, body, bw, k=4)
    assert w.shape == (50, J) and w.dtype == np.float32
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=1e-6)
    assert (w >= 0).all()
    np.testing.assert_allclose(w[:10], bw[100:110], rtol=1e-6, atol=1e-7)
    # midpoint of two isolated body vertices, k = 2: the mean of their weights
    two = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [50.0, 0.0, 0.0]], np.float32)
    tw = np.eye(3, J, dtype=np.float32)
    np.testing.assert_allclose(transfer_skinning_weights(np.array([[0.5, 0.0, 0.0]]), two, tw, k=2)[0],
                               0.5 * (tw[0] + tw[1]), atol=1e-7)
    with pytest.raises(WrinklesInputError):
        transfer_skinning_weights(garment, body, bw[:10])


def test_rotation_6d_round_trip():
    x = torch.randn(64, 6, generator=_gen(19), dtype=torch.float64)
    R = rotation_6d_to_matrix(x)
    eye = torch.eye(3, dtype=torch.float64).expand(64, 3, 3)
    np.testing.assert_allclose((R.transpose(-1, -2) @ R).numpy(), eye.numpy(), atol=1e-12)
    np.testing.assert_allclose(torch.linalg.det(R).numpy(), 1.0, atol=1e-12)
    # first column is the normalised a1 (Zhou et al. 2019: 6D = first two columns)
    np.testing.assert_allclose(R[:, :, 0].numpy(), torch.nn.functional.normalize(x[:, :3], dim=-1).numpy(),
                               atol=1e-12)
    np.testing.assert_allclose(rotation_6d_to_matrix(matrix_to_rotation_6d(R)).numpy(), R.numpy(), atol=1e-12)
    x6 = matrix_to_rotation_6d(R)  # a valid 6D code maps to itself
    x6_again = matrix_to_rotation_6d(rotation_6d_to_matrix(x6))
    np.testing.assert_allclose(x6_again.numpy(), x6.numpy(), atol=1e-12)


def test_rigid_transforms_and_composition(device):
    g = _gen(20)
    R1, R2 = rotation_6d_to_matrix(torch.randn(2, B, 1, 6, generator=g))
    t1, t2 = torch.randn(2, B, 1, 3, generator=g)
    T1, T2 = rigid_transforms(R1, t1).to(device), rigid_transforms(R2, t2).to(device)
    assert T1.shape == (B, 1, 3, 4)
    points = torch.randn(V, 3, generator=g).to(device)
    one = torch.ones(V, 1, device=device)
    # rigid_transforms applies R p + t
    expect = torch.einsum("brc,vc->bvr", R2[:, 0], points.cpu()) + t2[:, 0, None]
    inner = linear_blend_skinning(points, T2, one)
    np.testing.assert_allclose(inner.cpu().numpy(), expect.numpy(), atol=1e-5)
    # skinning with T1 o T2 equals skinning by T2, then by T1
    twice = linear_blend_skinning(inner, T1, one)
    np.testing.assert_allclose(linear_blend_skinning(points, compose_transforms(T1, T2), one).cpu().numpy(),
                               twice.cpu().numpy(), atol=1e-5)
