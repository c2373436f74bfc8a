"""Block-cooperative solve of the coarse level's banded systems on CUDA (``sim.cloth.coarse``).

One thread per instance (``band_kernels.band_solve_kernel``) is correct everywhere, but on a GPU
its serial factorization takes 20.5 ms per correction for 326 nodes against 0.31 ms for a thread
block (H100, docs/DECISIONS.md). Here a whole thread block solves one instance: the band (``n (b +
1)`` floats) and the right-hand side sit in shared memory, the factorization is a right-looking
``L D L^T`` that eliminates one column per step with every thread updating a share of the ``b (b
+ 1) / 2`` entries below it (one each where the block has enough threads), and one warp does
each substitution, two rows per step (``block_snippets``). That is about ``n`` block barriers
and ``n`` warp barriers per solve instead of ``n b^2 / 2`` serial multiply-adds. The snippets are
checked on the CPU by an emulation of the block (``tests/block_emulator.py``).

The kernels use ``__shared__`` memory and ``__syncthreads`` through a native snippet, so they
exist on CUDA only; the CPU keeps the serial kernel. Shared memory is sized per model (the
largest instance's band); a template too large for one block's shared memory also keeps the
serial kernel. This module has no ``from __future__ import annotations``: Warp reads the
snippet stub's tile annotation, whose size is a closure value.

Three kernels: the whole solve (factor and substitutions in one launch: the three-level cycle's
inner band changes at every correction), and the factor and the substitutions apart (two levels:
the factor at the substep start, ``CoarseLevel.prepare``; a correction only substitutes).
"""

import warp as wp

from sim.cloth.coarse.block_snippets import FACTOR, SOLVE, SUBSTITUTE

COOP_THREADS = 256
"""The least threads of a block solve (``threads``)."""
BLOCK_MAX_REGISTERS = 64
"""Registers per thread of the block solve and factor kernels: a block of up to 1,024 threads
(``threads``) must fit in an SM's 64k registers. Uncapped, the block solve's two-row
substitutions take it past 64, and it does not launch at 992 threads (CUDA error 701, "too many
resources requested")."""
CAPACITY_STEP = 1024
"""Floats of shared memory are allocated in steps of this many (one kernel per size)."""
SUBSTITUTE_THREADS = 256
"""Threads of the substitution kernel: they load the factor into shared memory together, then one
warp substitutes."""

_KERNELS: dict = {}


def shared_floats(count: int, width: int) -> int:
    """Shared floats (4-byte words) one instance of ``count`` nodes and band width ``width``
    needs: its band, its right-hand side and the index table of the block below a column."""
    return count * (width + 1) + 3 * count + width * (width + 1) // 2


def threads(width: int) -> int:
    """Threads of the block that solves a band of width ``width``: one per task of a
    factorization step (the entries of the block under a column, ``block_snippets.ELIMINATE``),
    in whole warps, at least ``COOP_THREADS`` and at most 1024 (threads of wider bands take
    several tasks)."""
    need = width * (width + 1) // 2
    return int(min(1024, max(COOP_THREADS, -(-need // 32) * 32)))


def padded(capacity: int) -> int:
    """``capacity`` [floats] rounded up to the allocation step."""
    return -(-int(capacity) // CAPACITY_STEP) * CAPACITY_STEP


def _solve_kernel(capacity: int):
    @wp.func_native(SOLVE)
    def native(
        smem: wp.tile[float, capacity],
        rhs: wp.array(dtype=wp.vec3),
        diag: wp.array(dtype=float),
        inst_start: wp.array(dtype=wp.int32),
        inst_count: wp.array(dtype=wp.int32),
        inst_width: wp.array(dtype=wp.int32),
        inst_band: wp.array(dtype=wp.int64),
        order: wp.array(dtype=wp.int32),
        band_k: wp.array(dtype=float),
        dx_out: wp.array(dtype=wp.vec3),
        k: int,
        lane: int,
    ): ...

    def block_solve_kernel(
        rhs: wp.array(dtype=wp.vec3),
        diag: wp.array(dtype=float),
        inst_start: wp.array(dtype=wp.int32),
        inst_count: wp.array(dtype=wp.int32),
        inst_width: wp.array(dtype=wp.int32),
        inst_band: wp.array(dtype=wp.int64),
        order: wp.array(dtype=wp.int32),
        band_k: wp.array(dtype=float),
        dx_out: wp.array(dtype=wp.vec3),
    ):
        """Solve instance ``k``'s coarse system with the block (launch with
        ``wp.launch_tiled``, ``dim=[instance_count]``, ``block_dim=threads(width)``); same
        inputs as ``band_kernels.band_solve_kernel`` without its scratch arrays."""
        k, lane = wp.tid()
        smem = wp.tile_empty(shape=capacity, dtype=float, storage="shared")
        native(smem, rhs, diag, inst_start, inst_count, inst_width, inst_band, order, band_k, dx_out, k, lane)

    return wp.kernel(block_solve_kernel, enable_backward=False, module="unique",
                     cuda_max_registers=BLOCK_MAX_REGISTERS)


def _factor_kernel(capacity: int):
    @wp.func_native(FACTOR)
    def native(
        smem: wp.tile[float, capacity],
        diag: wp.array(dtype=float),
        inst_start: wp.array(dtype=wp.int32),
        inst_count: wp.array(dtype=wp.int32),
        inst_width: wp.array(dtype=wp.int32),
        inst_band: wp.array(dtype=wp.int64),
        order: wp.array(dtype=wp.int32),
        band_k: wp.array(dtype=float),
        factor_out: wp.array(dtype=float),
        k: int,
        lane: int,
    ): ...

    def block_factor_kernel(
        diag: wp.array(dtype=float),
        inst_start: wp.array(dtype=wp.int32),
        inst_count: wp.array(dtype=wp.int32),
        inst_width: wp.array(dtype=wp.int32),
        inst_band: wp.array(dtype=wp.int64),
        order: wp.array(dtype=wp.int32),
        band_k: wp.array(dtype=float),
        factor_out: wp.array(dtype=float),
    ):
        """Factor instance ``k``'s coarse system ``L D L^T`` with the block and write it to
        ``factor_out`` (the band layout of ``band_k``: ``D`` on the diagonal entries, the
        unit ``L`` below; launch as ``block_solve_kernel``)."""
        k, lane = wp.tid()
        smem = wp.tile_empty(shape=capacity, dtype=float, storage="shared")
        native(smem, diag, inst_start, inst_count, inst_width, inst_band, order, band_k, factor_out, k, lane)

    return wp.kernel(block_factor_kernel, enable_backward=False, module="unique",
                     cuda_max_registers=BLOCK_MAX_REGISTERS)


def _substitute_kernel(capacity: int):
    @wp.func_native(SUBSTITUTE)
    def native(
        smem: wp.tile[float, capacity],
        rhs: wp.array(dtype=wp.vec3),
        inst_start: wp.array(dtype=wp.int32),
        inst_count: wp.array(dtype=wp.int32),
        inst_width: wp.array(dtype=wp.int32),
        inst_band: wp.array(dtype=wp.int64),
        order: wp.array(dtype=wp.int32),
        factor: wp.array(dtype=float),
        dx_out: wp.array(dtype=wp.vec3),
        k: int,
        lane: int,
    ): ...

    def block_substitute_kernel(
        rhs: wp.array(dtype=wp.vec3),
        inst_start: wp.array(dtype=wp.int32),
        inst_count: wp.array(dtype=wp.int32),
        inst_width: wp.array(dtype=wp.int32),
        inst_band: wp.array(dtype=wp.int64),
        order: wp.array(dtype=wp.int32),
        factor: wp.array(dtype=float),
        dx_out: wp.array(dtype=wp.vec3),
    ):
        """Solve instance ``k``'s coarse system with ``block_factor_kernel``'s ``factor``:
        the forward substitution, ``D^-1`` and the back substitution, each a chain of short
        rows for one warp (launch with ``block_dim=SUBSTITUTE_THREADS``)."""
        k, lane = wp.tid()
        smem = wp.tile_empty(shape=capacity, dtype=float, storage="shared")
        native(smem, rhs, inst_start, inst_count, inst_width, inst_band, order, factor, dx_out, k, lane)

    return wp.kernel(block_substitute_kernel, enable_backward=False, module="unique")


_FACTORIES = {"solve": _solve_kernel, "factor": _factor_kernel, "substitute": _substitute_kernel}


def block_kernel(capacity: int, kind: str):
    """The block kernel ``kind`` ("solve", "factor" or "substitute") with at least ``capacity``
    floats of shared memory (one kernel per kind and padded size)."""
    capacity = padded(capacity)
    key = (kind, capacity)
    if key not in _KERNELS:
        _KERNELS[key] = _FACTORIES[kind](capacity)
    return _KERNELS[key]
