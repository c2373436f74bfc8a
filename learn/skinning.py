"""Differentiable linear blend skinning for torch, computed by Warp kernels.

Users: a learned displacement model that skins a garment (rest + displacement, per sample) with
weights transferred from the body (``sim.skinning.transfer.transfer_skinning_weights``), and the
virtual skeleton of Guo et al. 2024 (Sec 3.2): k rigid bones fitted by SSDR whose per-frame
transforms a CVAE predicts (``rotation_6d_to_matrix`` + ``rigid_transforms``). Gradients flow to
the rest points, the bone transforms and, optionally, the weights.

Forward and backward are Warp kernels (``sim.skinning.diff_lbs_kernels``, Eq. 1-4 there) on the
tensors' own memory (``wp.from_torch``, zero copy), on cpu or cuda, launched on torch's current
CUDA stream. The backward is the hand-written adjoint of the bilinear map (no Warp tape), it
skips every input whose ``needs_input_grad`` is false, and it uses no atomics: its sums run in
a fixed order, so gradients are bitwise reproducible on both devices.

Typical use::

    R = rotation_6d_to_matrix(cvae_out[..., :6])            # (B, J, 3, 3)
    A = rigid_transforms(R, cvae_out[..., 6:])              # (B, J, 3, 4)
    skin = LinearBlendSkinning(ssdr_weights)                # (V, J) numpy
    verts = skin(rest_vertices, A)                          # (B, V, 3) [m]
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from sim.device import warp
from sim.errors import WrinklesInputError
from sim.skinning.lbs import sparse_weights

_CUDA_TARGET_THREADS = 1 << 17
"""Stage-1 threads the transform-gradient gather aims for on cuda (enough to fill an H100/H200)."""
_CUDA_MIN_CHUNK = 32
"""Fewest vertices a stage-1 thread sums on cuda (below this, stage 2 costs more than it saves)."""


def _kernels():
    warp()  # initialise Warp quietly before the kernel module imports it
    from sim.skinning import diff_lbs_kernels

    return diff_lbs_kernels


def _launch(kernel, dim, inputs, outputs, device, stream) -> None:
    """``wp.launch`` (a separate function so tests can observe which kernels run)."""
    warp().launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=device, stream=stream)


def _wp(t: torch.Tensor | None, dtype):
    """Zero-copy Warp view of a contiguous tensor (None stays None)."""
    if t is None:
        return None
    return warp().from_torch(t, dtype=dtype, requires_grad=False)


def _device_and_stream(t: torch.Tensor):
    wp = warp()
    if t.device.type == "cuda":
        return wp.device_from_torch(t.device), wp.stream_from_torch(t.device)
    return "cpu", None


def _transforms_grad_method(device_type: str) -> str:
    """Eq. 4 kernel: ``"scatter"`` on cpu (serial launch, J times less work), ``"gather"`` on cuda."""
    return "gather" if device_type == "cuda" else "scatter"


def _num_chunks(device_type: str, num_samples: int, num_vertices: int, num_bones: int) -> int:
    """Vertex chunks of the Eq. 4 gather: enough stage-1 threads on cuda, else 1."""
    if device_type != "cuda":
        return 1
    want = math.ceil(_CUDA_TARGET_THREADS / max(1, num_samples * num_bones))
    return max(1, min(want, math.ceil(num_vertices / _CUDA_MIN_CHUNK)))


class _LinearBlendSkinningFunction(torch.autograd.Function):
    """Eq. 1 forward, Eq. 2-4 backward (``sim.skinning.diff_lbs_kernels``).

    Inputs (all contiguous, float32, one device): points (Bp, V, 3) with Bp in {1, B};
    transforms (B, J, 3, 4); weight_val (V, K); weight_idx int32 (V, K) or None (then weight_val
    is dense (V, J)). Output (B, V, 3).
    """

    @staticmethod
    def forward(ctx, points, transforms, weight_val, weight_idx):
        k = _kernels()
        B, V = transforms.shape[0], points.shape[1]
        out = torch.empty((B, V, 3), dtype=points.dtype, device=points.device)
        device, stream = _device_and_stream(points)
        dense = int(weight_idx is None)
        idx = _dummy_idx(points.device) if weight_idx is None else weight_idx
        _launch(k.lbs_forward_kernel, (B, V),
                [_wp(points, k.wp.vec3), int(points.shape[0] > 1),
                 _wp(transforms, k.mat34), _wp(idx, k.wp.int32), _wp(weight_val, k.wp.float32), dense],
                [_wp(out, k.wp.vec3)], device, stream)
        ctx.save_for_backward(points, transforms, weight_val, weight_idx)
        return out

    @staticmethod
    def backward(ctx, grad_out):
        k = _kernels()
        points, transforms, weight_val, weight_idx = ctx.saved_tensors
        need_p, need_a, need_w = ctx.needs_input_grad[:3]
        grad_p = grad_a = grad_w = None
        if not (need_p or need_a or need_w):
            return None, None, None, None
        grad_out = grad_out.contiguous()
        B, V = grad_out.shape[:2]
        J = transforms.shape[1]
        batched = int(points.shape[0] > 1)
        dense = int(weight_idx is None)
        idx = _dummy_idx(points.device) if weight_idx is None else weight_idx
        device, stream = _device_and_stream(points)
        g_wp, p_wp = _wp(grad_out, k.wp.vec3), _wp(points, k.wp.vec3)
        idx_wp, val_wp = _wp(idx, k.wp.int32), _wp(weight_val, k.wp.float32)
        if need_p or need_w:
            if need_p:
                grad_p = torch.empty_like(points)
            if need_w:
                grad_w = torch.empty_like(weight_val)
            _launch(k.lbs_backward_points_weights_kernel, V,
                    [g_wp, p_wp, batched, _wp(transforms, k.mat34), idx_wp, val_wp, dense,
                     int(need_p), int(need_w)],
                    [_wp(grad_p, k.wp.vec3), _wp(grad_w, k.wp.float32)], device, stream)
        if need_a and _transforms_grad_method(points.device.type) == "scatter":
            grad_a = torch.empty_like(transforms)
            _launch(k.lbs_backward_transforms_scatter_kernel, B, [g_wp, p_wp, batched, idx_wp, val_wp, dense],
                    [_wp(grad_a, k.mat34)], device, stream)
        elif need_a:
            grad_a = torch.empty_like(transforms)
            C = _num_chunks(points.device.type, B, V, J)
            chunk = math.ceil(V / C)
            C = math.ceil(V / chunk)
            partial = grad_a.unsqueeze(1) if C == 1 else grad_a.new_empty((B, C, J, 3, 4))
            _launch(k.lbs_backward_transforms_partial_kernel, (B, C, J),
                    [g_wp, p_wp, batched, idx_wp, val_wp, dense, chunk],
                    [_wp(partial, k.mat34)], device, stream)
            if C > 1:
                _launch(k.lbs_backward_transforms_reduce_kernel, (B, J), [_wp(partial, k.mat34)],
                        [_wp(grad_a, k.mat34)], device, stream)
        return grad_p, grad_a, grad_w, None


_DUMMY_IDX: dict[torch.device, torch.Tensor] = {}


def _dummy_idx(device: torch.device) -> torch.Tensor:
    """(1, 1) int32 placeholder for ``weight_idx`` with dense weights."""
    t = _DUMMY_IDX.get(device)
    if t is None:
        t = _DUMMY_IDX[device] = torch.zeros((1, 1), dtype=torch.int32, device=device)
    return t


def _check_float32(name: str, t: torch.Tensor) -> None:
    if t.dtype != torch.float32:
        raise WrinklesInputError(f"{name}: dtype {t.dtype} is not supported, the kernels take float32 "
                                 "(convert with .float())")


def _skin(vertices: torch.Tensor, transforms: torch.Tensor, weight_val: torch.Tensor,
          weight_idx: torch.Tensor | None, *, check_indices: bool) -> torch.Tensor:
    """Validate shapes, bring inputs to the kernels' layout (in torch, so autograd maps the
    gradients back), and call the autograd function."""
    if not isinstance(vertices, torch.Tensor) or not isinstance(transforms, torch.Tensor):
        raise WrinklesInputError("vertices and transforms must be torch tensors")
    _check_float32("vertices", vertices)
    _check_float32("transforms", transforms)
    _check_float32("weights", weight_val)
    if vertices.ndim not in (2, 3) or vertices.shape[-1] != 3:
        raise WrinklesInputError(f"vertices: shape {tuple(vertices.shape)}, expected (V, 3) or (B, V, 3)")
    if transforms.ndim != 4 or tuple(transforms.shape[-2:]) not in ((3, 4), (4, 4)):
        raise WrinklesInputError(f"transforms: shape {tuple(transforms.shape)}, expected (B, J, 4, 4) "
                                 "or (B, J, 3, 4)")
    B, J = transforms.shape[:2]
    V = vertices.shape[-2]
    if vertices.ndim == 3 and vertices.shape[0] not in (1, B):
        raise WrinklesInputError(f"vertices: batch {vertices.shape[0]} differs from transforms' batch {B}")
    if weight_val.ndim != 2 or weight_val.shape[0] != V:
        raise WrinklesInputError(f"weights: shape {tuple(weight_val.shape)}, expected ({V}, J) dense or "
                                 f"({V}, K) sparse")
    if weight_idx is None and weight_val.shape[1] != J:
        raise WrinklesInputError(f"weights: {weight_val.shape[1]} bones, transforms have {J}")
    devices = {vertices.device, transforms.device, weight_val.device}
    if weight_idx is not None:
        devices.add(weight_idx.device)
    if len(devices) != 1:
        raise WrinklesInputError(f"inputs are on different devices: {sorted(str(d) for d in devices)}")
    if weight_idx is not None:
        if weight_idx.shape != weight_val.shape:
            raise WrinklesInputError(f"weight_idx: shape {tuple(weight_idx.shape)} differs from "
                                     f"weight_val's {tuple(weight_val.shape)}")
        if weight_idx.dtype.is_floating_point or weight_idx.dtype == torch.bool:
            raise WrinklesInputError(f"weight_idx: dtype {weight_idx.dtype}, expected an integer dtype")
        weight_idx = weight_idx.detach().to(torch.int32).contiguous()
        if check_indices and weight_idx.numel() > 0:
            lo, hi = (int(x) for x in torch.aminmax(weight_idx))  # one host sync
            if lo < 0 or hi >= J:
                raise WrinklesInputError(f"weight_idx: bone indices span [{lo}, {hi}], "
                                         f"transforms have {J} bones")
    points = (vertices if vertices.ndim == 3 else vertices.unsqueeze(0)).contiguous()
    if B == 0 or V == 0:  # nothing to launch; keep the graph connected
        return points.expand(B, V, 3) * 0.0 + transforms.sum() * 0.0 + weight_val.sum() * 0.0
    A = transforms[..., :3, :].contiguous()
    return _LinearBlendSkinningFunction.apply(points, A, weight_val.contiguous(), weight_idx)


def linear_blend_skinning(vertices: torch.Tensor, transforms: torch.Tensor,
                          weights: torch.Tensor | None = None, *, weight_idx: torch.Tensor | None = None,
                          weight_val: torch.Tensor | None = None) -> torch.Tensor:
    """Linear blend skinning, differentiable in vertices, transforms and weights.

    ``x_bv = sum_k w_vk (R_{b j_vk} p_bv + t_{b j_vk})`` (SMPL Eq. 3; SSDR Eq. 1), forward and
    backward in Warp kernels (module docstring).

    Args:
        vertices: rest (or displaced rest) points [m], shape (V, 3) or (1, V, 3) shared by every
            sample, or (B, V, 3) per sample. float32.
        transforms: affine bone transforms, world from rest-pose bone space (SMPL's ``A``, which
            already holds the inverse rest transform), shape (B, J, 4, 4) or (B, J, 3, 4). The
            bottom row of a 4x4 is not read (assumed ``[0, 0, 0, 1]``) and gets a zero gradient.
        weights: dense skinning weights, shape (V, J). Give either this or both sparse arrays.
        weight_idx: fixed-width sparse form, bone index of each influence, integer (V, K)
            (``sim.skinning.lbs.sparse_weights``); not differentiable.
        weight_val: weight of each influence, float32 (V, K); differentiable in every slot,
            zero-weight padding slots included (mask them if they must stay zero).

    Returns:
        Skinned points [m], shape (B, V, 3), float32, on the inputs' device.

    Raises:
        WrinklesInputError: bad shapes, dtypes (float32 only), devices or bone indices.
    """
    if weights is not None:
        if weight_idx is not None or weight_val is not None:
            raise WrinklesInputError("give dense weights or weight_idx + weight_val, not both")
        return _skin(vertices, transforms, weights, None, check_indices=False)
    if weight_idx is None or weight_val is None:
        raise WrinklesInputError("skinning weights missing: give weights (V, J) or "
                                 "weight_idx + weight_val (V, K)")
    return _skin(vertices, transforms, weight_val, weight_idx, check_indices=True)


class LinearBlendSkinning(nn.Module):
    """Skinning weights held by a module; ``forward(vertices, transforms)`` skins a batch.

    Args:
        weights: skinning weights, shape (V, J), numpy or tensor (stored as float32).
        sparse: keep the weights in fixed-width sparse form (exact: every non-zero is kept,
            ``sim.skinning.lbs.sparse_weights``); False keeps the dense (V, J) matrix.
        learn_weights: hold the weights as an ``nn.Parameter``. Sparse: only the support
            (the non-zero entries of ``weights``) learns, padding slots stay zero. Dense: every
            entry learns. No constraint (non-negativity, unit row sums) is imposed.
    """

    def __init__(self, weights: np.ndarray | torch.Tensor, *, sparse: bool = True,
                 learn_weights: bool = False):
        super().__init__()
        w = weights.detach().cpu().numpy() if isinstance(weights, torch.Tensor) else np.asarray(weights)
        if w.ndim != 2 or w.shape[0] == 0 or w.shape[1] == 0 or not np.all(np.isfinite(w)):
            raise WrinklesInputError(f"weights: expected a finite (V, J) array, got shape {w.shape}")
        self.num_vertices, self.num_bones = (int(s) for s in w.shape)
        self.sparse = bool(sparse)
        self.learn_weights = bool(learn_weights)
        if self.sparse:
            idx, val = sparse_weights(w.astype(np.float32))
            self.register_buffer("weight_idx", torch.from_numpy(idx))
            val_t = torch.from_numpy(val)
            if self.learn_weights:
                self.register_buffer("support", (val_t != 0).to(torch.float32))
        else:
            self.weight_idx = None
            val_t = torch.from_numpy(w.astype(np.float32))
        if self.learn_weights:
            self.weight_val = nn.Parameter(val_t)
        else:
            self.register_buffer("weight_val", val_t)

    def effective_weights(self) -> torch.Tensor:
        """Weights as the kernels see them: (V, K) sparse values or (V, J) dense."""
        if self.sparse and self.learn_weights:
            return self.weight_val * self.support
        return self.weight_val

    def dense_weights(self) -> torch.Tensor:
        """Current weights as a dense (V, J) tensor (differentiable when learned)."""
        w = self.effective_weights()
        if not self.sparse:
            return w
        out = w.new_zeros((self.num_vertices, self.num_bones))
        return out.scatter_add(1, self.weight_idx.long(), w)

    def forward(self, vertices: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
        """Skin ``vertices`` (V, 3) or (B, V, 3) [m] with ``transforms`` (B, J, 4|3, 4); returns (B, V, 3)."""
        if transforms.ndim != 4 or transforms.shape[1] != self.num_bones:
            raise WrinklesInputError(f"transforms: shape {tuple(transforms.shape)}, expected "
                                     f"(B, {self.num_bones}, 4, 4) or (B, {self.num_bones}, 3, 4)")
        # indices were made from the weights' own columns: in range, no per-call check (no host sync)
        return _skin(vertices, transforms, self.effective_weights(), self.weight_idx, check_indices=False)

    def extra_repr(self) -> str:
        return (f"num_vertices={self.num_vertices}, num_bones={self.num_bones}, sparse={self.sparse}, "
                f"learn_weights={self.learn_weights}")


def rotation_6d_to_matrix(x: torch.Tensor) -> torch.Tensor:
    """Continuous 6D rotation representation to rotation matrices (Zhou et al. 2019, Sec 4.2, Eq. 15-16).

    The six numbers are the first two *columns* ``a1, a2`` of the matrix, as in the paper
    (PyTorch3D uses rows instead); Gram-Schmidt makes them orthonormal and ``b3 = b1 x b2``.

    Args:
        x: shape (..., 6): ``a1 = x[..., 0:3]``, ``a2 = x[..., 3:6]``.

    Returns:
        Rotation matrices ``[b1 b2 b3]`` (columns), shape (..., 3, 3).
    """
    if x.shape[-1] != 6:
        raise WrinklesInputError(f"6D rotations: last dimension is {x.shape[-1]}, expected 6")
    a1, a2 = x[..., 0:3], x[..., 3:6]
    b1 = nn.functional.normalize(a1, dim=-1)
    b2 = nn.functional.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    return torch.stack((b1, b2, b3), dim=-1)


def matrix_to_rotation_6d(matrix: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) to the 6D representation (..., 6): the first two columns."""
    if matrix.shape[-2:] != (3, 3):
        raise WrinklesInputError(f"rotation matrices: shape {tuple(matrix.shape)}, expected (..., 3, 3)")
    return torch.cat((matrix[..., :, 0], matrix[..., :, 1]), dim=-1)


def rigid_transforms(rotations: torch.Tensor, translations: torch.Tensor) -> torch.Tensor:
    """Affine 3x4 bone transforms ``[R | t]`` from rotations and translations.

    Args:
        rotations: shape (..., 3, 3), e.g. (B, J, 3, 3).
        translations: [m], shape (..., 3), e.g. (B, J, 3).

    Returns:
        Transforms, shape (..., 3, 4), differentiable in both inputs.
    """
    if rotations.shape[-2:] != (3, 3) or translations.shape[-1] != 3 \
            or rotations.shape[:-2] != translations.shape[:-1]:
        raise WrinklesInputError(f"rotations {tuple(rotations.shape)} and translations "
                                 f"{tuple(translations.shape)}: expected (..., 3, 3) and (..., 3)")
    return torch.cat((rotations, translations.unsqueeze(-1)), dim=-1)


def compose_transforms(outer: torch.Tensor, inner: torch.Tensor) -> torch.Tensor:
    """Composition ``outer o inner`` of affine transforms, each (..., 3, 4) or (..., 4, 4).

    ``[R1 | t1] o [R2 | t2] = [R1 R2 | R1 t2 + t1]``; returns (..., 3, 4).
    """
    r1, t1 = outer[..., :3, :3], outer[..., :3, 3]
    r2, t2 = inner[..., :3, :3], inner[..., :3, 3]
    return rigid_transforms(r1 @ r2, (r1 @ t2.unsqueeze(-1)).squeeze(-1) + t1)
