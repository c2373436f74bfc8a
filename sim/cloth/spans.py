"""Arrays passed to a kernel as raw addresses (``Span``: pointer and length, 16 bytes) instead
of Warp array arguments (56 bytes each: data, grad, shape, strides, ndim).

Why: the per-colour solve kernel reads ~100 arrays (~5.6 KB as Warp array parameters). CUDA
kernel parameters live in constant memory and every array access reads its descriptor from
there; with plain array parameters Nsight Compute puts 30 % of the solve's stall cycles on
immediate-constant cache misses (H100, 5k t-shirt). The kernel takes one struct of spans and
rebuilds the arrays it reads with ``wp.array(ptr=..., shape=..., dtype=...)``. An element access
``a[i]`` on such an array still wraps a negative index and scales by the stride at run time
(Warp's ``index``); the hot loads go through ``load_*`` below instead.

The spans do not own the memory: whoever builds them keeps the arrays alive (the solver holds
its model, buffers and self-contact data for its lifetime)."""

from __future__ import annotations

import warp as wp


@wp.struct
class Span:
    """A 1-D contiguous array as its address and length (``span``)."""

    ptr: wp.uint64
    n: int


def span(a) -> Span:
    """The ``Span`` of a contiguous 1-D Warp array ``a``."""
    if a.ndim != 1 or not a.is_contiguous:
        raise ValueError(f"span: a contiguous 1-D array is needed, got shape {a.shape}")
    s = Span()
    s.ptr = wp.uint64(a.ptr or 0)
    s.n = int(a.shape[0])
    return s


def fill_spans(struct, arrays: dict) -> None:
    """Set the ``Span`` field of ``struct`` named by each key of ``arrays`` to that array's span."""
    for name, a in arrays.items():
        setattr(struct, name, span(a))


# the arrays of a span inside a kernel, one function per element type
@wp.func
def ints(s: Span):
    return wp.array(ptr=s.ptr, shape=(s.n,), dtype=wp.int32)


@wp.func
def floats(s: Span):
    return wp.array(ptr=s.ptr, shape=(s.n,), dtype=float)


@wp.func
def vec3s(s: Span):
    return wp.array(ptr=s.ptr, shape=(s.n,), dtype=wp.vec3)


@wp.func
def vec2is(s: Span):
    return wp.array(ptr=s.ptr, shape=(s.n,), dtype=wp.vec2i)


@wp.func
def vec3is(s: Span):
    return wp.array(ptr=s.ptr, shape=(s.n,), dtype=wp.vec3i)


@wp.func
def vec4is(s: Span):
    return wp.array(ptr=s.ptr, shape=(s.n,), dtype=wp.vec4i)


@wp.func
def mat22s(s: Span):
    return wp.array(ptr=s.ptr, shape=(s.n,), dtype=wp.mat22)


# Element loads without Warp's index arithmetic. ``a[i]`` on a Warp array wraps a
# negative index (``if (i < 0) i += shape[0]``) and scales the index by the runtime stride in
# 64 bits before the load: Nsight Compute put 23 % of the 5k t-shirt solve kernel's executed
# instructions in that code (``array.h``). These read ``a.data[i]`` directly: for the
# non-negative indices of contiguous arrays the same element, so the same floats. ``i`` must
# be in range; nothing checks it.
@wp.func_native("return a.data[i];")
def load_int(a: wp.array(dtype=wp.int32), i: int) -> int: ...


@wp.func_native("return a.data[i];")
def load_float(a: wp.array(dtype=float), i: int) -> float: ...


@wp.func_native("return a.data[i];")
def load_vec3(a: wp.array(dtype=wp.vec3), i: int) -> wp.vec3: ...


@wp.func_native("return a.data[i];")
def load_vec2i(a: wp.array(dtype=wp.vec2i), i: int) -> wp.vec2i: ...


@wp.func_native("return a.data[i];")
def load_vec3i(a: wp.array(dtype=wp.vec3i), i: int) -> wp.vec3i: ...


@wp.func_native("return a.data[i];")
def load_vec4i(a: wp.array(dtype=wp.vec4i), i: int) -> wp.vec4i: ...


@wp.func_native("return a.data[i];")
def load_mat22(a: wp.array(dtype=wp.mat22), i: int) -> wp.mat22: ...
