"""Warp-lane shuffles for kernels whose threads cooperate in aligned segments of a CUDA warp: a
reduction over a segment's lanes inside one launch instead of a second launch that reads the
lanes' partial results back.

CUDA only: the kernels that use them are launched on CUDA alone (their callers keep a
separate-launch path for the CPU, where Warp runs a block's threads one after another). On the
CPU the snippets return their argument, so that the modules still compile there. ``mask``: the
warp's lanes that take part (``lane_mask``); every lane of a segment being reduced must be
among them, and each must reach the shuffle (no early return before it).
"""

from __future__ import annotations

import warp as wp

_XOR = """
#if defined(__CUDA_ARCH__)
return __shfl_xor_sync((unsigned)mask, x, lanes);
#else
return x;
#endif
"""

_READ = """
#if defined(__CUDA_ARCH__)
return __shfl_sync((unsigned)mask, x, lane);
#else
return x;
#endif
"""


@wp.func_native(_XOR)
def lane_xor(x: float, lanes: int, mask: int) -> float: ...


@wp.func_native(_XOR)
def lane_xor_int(x: int, lanes: int, mask: int) -> int: ...


@wp.func
def lane_xor_vec3(x: wp.vec3, lanes: int, mask: int) -> wp.vec3:
    """``x`` of the lane whose index differs from this one's in the bits ``lanes``."""
    return wp.vec3(lane_xor(x[0], lanes, mask), lane_xor(x[1], lanes, mask), lane_xor(x[2], lanes, mask))


@wp.func_native(_READ)
def lane_read(x: float, lane: int, mask: int) -> float: ...


@wp.func
def lane_read_vec3(x: wp.vec3, lane: int, mask: int) -> wp.vec3:
    """``x`` of lane ``lane`` (0-31) of this warp."""
    return wp.vec3(lane_read(x[0], lane, mask), lane_read(x[1], lane, mask), lane_read(x[2], lane, mask))


@wp.func
def lane_mask(t: int, n: int) -> int:
    """The lanes of thread ``t``'s warp (32 consecutive threads from a multiple of 32) that a
    launch of ``n`` threads runs, as a shuffle mask."""
    active = n - (t - t % 32)
    if active >= 32:
        return -1
    return (1 << active) - 1
