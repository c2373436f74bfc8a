"""Block-cooperative solve of the coarse level's banded systems on CUDA (``sim.cloth.coarse``).

``band_solve_kernel`` gives each instance one thread: correct everywhere, but on a GPU its
serial factorization costs about 20 ms per correction for the t-shirt's 326 nodes
(docs/BENCHMARKS.md, session 22). Here a whole thread block solves one instance: the band
(``n (b + 1)`` floats) and the right-hand side sit in shared memory, the factorization is a
right-looking ``L D L^T`` that eliminates one column per step with every thread updating a
share of the ``b (b + 1) / 2`` entries below it (one each where the block has enough threads),
and one warp does each substitution, two rows per step (session 36; one before). That is about
``n`` block barriers and ``n`` warp barriers per solve instead of ``n b^2 / 2`` serial
multiply-adds. The snippets are
checked on the CPU by an emulation of the block (``tests/block_emulator.py``).

The kernel uses ``__shared__`` memory and ``__syncthreads`` through a native snippet, so it
exists on CUDA only; the CPU keeps the serial kernel. Shared memory is sized per model (the
largest instance's band); a template too large for one block's shared memory also keeps the
serial kernel. This module has no ``from __future__ import annotations``: Warp reads the
snippet stub's tile annotation, whose size is a closure value.
"""

import warp as wp

COOP_THREADS = 256  # the least threads of a block solve (``threads``)
# registers per thread of the block solve and factor kernels: a block of up to 1024 threads
# (``threads``) must fit in an SM's 64k registers. Without the cap, session 36's two-row
# substitutions took the block solve past 64 and it no longer launched at 992 threads (CUDA
# error 701, "too many resources requested", session 37).
BLOCK_MAX_REGISTERS = 64
# floats of shared memory are allocated in steps of this many (one kernel per size)
CAPACITY_STEP = 1024

_KERNELS: dict = {}


def shared_floats(count: int, width: int) -> int:
    """Shared floats (4-byte words) one instance of ``count`` nodes and band width ``width``
    needs: its band, its right-hand side and the index table of the block below a column."""
    return count * (width + 1) + 3 * count + width * (width + 1) // 2


def threads(width: int) -> int:
    """Threads of the block that solves a band of width ``width``: one per task of a
    factorization step (the entries of the block under a column, ``_ELIMINATE``), in whole
    warps, at least ``COOP_THREADS`` and at most 1024 (threads of wider bands take several
    tasks)."""
    need = width * (width + 1) // 2
    return int(min(1024, max(COOP_THREADS, -(-need // 32) * 32)))


def padded(capacity: int) -> int:
    """``capacity`` [floats] rounded up to the allocation step."""
    return -(-int(capacity) // CAPACITY_STEP) * CAPACITY_STEP


def _kernel(capacity: int, kind: str):
    """The block kernel ``kind`` ("solve", "factor" or "substitute") with at least ``capacity``
    floats of shared memory (one kernel per kind and padded size)."""
    capacity = padded(capacity)
    key = (kind, capacity)
    if key in _KERNELS:
        return _KERNELS[key]

    if kind == "solve":
        @wp.func_native(_SOLVE)
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
            inputs as ``coarse.band_solve_kernel`` without its scratch arrays."""
            k, lane = wp.tid()
            smem = wp.tile_empty(shape=capacity, dtype=float, storage="shared")
            native(smem, rhs, diag, inst_start, inst_count, inst_width, inst_band, order, band_k, dx_out, k,
                   lane)

        kernel = wp.kernel(block_solve_kernel, enable_backward=False, module="unique",
                           cuda_max_registers=BLOCK_MAX_REGISTERS)
    elif kind == "factor":
        @wp.func_native(_FACTOR)
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
            native(smem, diag, inst_start, inst_count, inst_width, inst_band, order, band_k, factor_out, k,
                   lane)

        kernel = wp.kernel(block_factor_kernel, enable_backward=False, module="unique",
                           cuda_max_registers=BLOCK_MAX_REGISTERS)
    else:
        @wp.func_native(_SUBSTITUTE)
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

        kernel = wp.kernel(block_substitute_kernel, enable_backward=False, module="unique")
    _KERNELS[key] = kernel
    return kernel


def cooperative_kernel(capacity: int):
    """The block solve kernel (factor and solve in one launch) with at least ``capacity`` floats
    of shared memory."""
    return _kernel(capacity, "solve")


def factor_kernel(capacity: int):
    """The block factor kernel (``_kernel``): ``L D L^T`` of each instance to a global band."""
    return _kernel(capacity, "factor")


def substitute_kernel(capacity: int):
    """The substitution kernel (``_kernel``) with a factor from ``factor_kernel``."""
    return _kernel(capacity, "substitute")


# threads of the substitution kernel: they load the factor into shared memory together, then
# one warp substitutes
SUBSTITUTE_THREADS = 256

# One instance's coarse system A dx = rhs, solved by the block: A = L D L^T (unit lower L, right-
# looking, one column per step) in shared memory; band rows as in coarse.band_solve_kernel
# (row r holds A[r, r - t] at t = 0 .. b), the right-hand side after them, 3 floats per row.
# The snippets are put together from these parts: the whole solve (``_SOLVE``), the factor alone
# (``_FACTOR``: no right-hand side; the band goes to global memory) and the substitutions with
# that factor (``_SUBSTITUTE``). The split gives the same floats as the whole solve: both run
# the same substitutions (``_FORWARD``, ``_BACK``) on the same scaled factor.
_HEAD = r"""
    __syncthreads();  // the tile allocation is not a barrier
    float* L = smem.data.ptr;
    const int start = inst_start[k];
    const int n = inst_count[k];
    const int b = inst_width[k];
    const int w = b + 1;
    const long long base = inst_band[k];
    const int T = (int)blockDim.x;
    float* u = L + n * w;  // right-hand side, then solution (3 per row)
"""
_LOAD_BAND = r"""
    for (int q = lane; q < n * w; q += T) {
        const int r = q / w;
        L[q] = (q - r * w == 0) ? diag[start + order[start + r]] : band_k[base + q];
    }
"""
_LOAD_RHS = r"""
    for (int r = lane; r < n; r += T) {
        const wp::vec3 v = rhs[start + order[start + r]];
        u[3 * r] = v.c[0];
        u[3 * r + 1] = v.c[1];
        u[3 * r + 2] = v.c[2];
    }
"""
# the elimination, one column per step: every thread keeps its entries (s, t) of the block below a
# column, decoded once (session 32: before, each step looked its task up in the index table, and
# 88 more tasks per step, the right-hand side's rows and the previous column's scaling, gave some
# threads two tasks at the band of 44). The forward substitution follows the elimination
# (``_FORWARD``), and the columns are scaled to the unit L after the last step (nothing reads a
# column after its own step). Each entry takes the same products in the same column order as
# before, so the floats are the same.
_ELIMINATE = r"""
    // the entries (s, t), 1 <= t <= s <= b, of the block below a column, row by row: s << 16 | t
    int* tri = (int*)(u + 3 * n);
    const int bb = b * (b + 1) / 2;
    for (int q = lane; q < bb; q += T) {
        int s = (int)((sqrtf(8.0f * (float)q + 1.0f) - 1.0f) * 0.5f);
        while ((s + 1) * (s + 2) / 2 <= q) ++s;
        while (s * (s + 1) / 2 > q) --s;
        tri[q] = ((s + 1) << 16) | (q - s * (s + 1) / 2 + 1);
    }
    __syncthreads();
    const int w1 = w + 1;
    // this thread's first two entries (s > b: none); entries q >= 2T come from the table
    int s0 = b + 1, t0 = 1, s1 = b + 1, t1 = 1;
    if (lane < bb) {
        s0 = tri[lane] >> 16;
        t0 = tri[lane] & 0xffff;
    }
    if (lane + T < bb) {
        s1 = tri[lane + T] >> 16;
        t1 = tri[lane + T] & 0xffff;
    }
    for (int j = 0; j < n; ++j) {
        const int jw = j * w;
        const float inv = 1.0f / fmaxf(L[jw], 1.0e-30f);
        const int m = min(b, n - 1 - j);  // rows below column j
        if (s0 <= m) {
            ENTRY_FIRST
        }
        if (s1 <= m) {
            ENTRY_SECOND
        }
        for (int q = lane + 2 * T; q < m * (m + 1) / 2; q += T) {
            const int st = tri[q];
            ENTRY_TABLE
        }
        __syncthreads();
    }
    // the unit L: each column below its diagonal by 1 / d
    for (int q = lane; q < n * b; q += T) {
        const int c = q / b;  // column c, row c + s
        const int s = q - c * b + 1;
        if (s <= n - 1 - c)
            L[(c + s) * w + s] *= 1.0f / fmaxf(L[c * w], 1.0e-30f);
    }
    __syncthreads();
"""
# A[j+s, j+t] -= A[j+s, j] A[j+t, j] / d_j (a is A[j+s, j]; A[j+s, j+t] is t before it), every
# load before the store
_ENTRY = r"""{
            const int a_ = jw + (S_) * w1;
            const float la_ = L[a_];
            const float lt_ = L[jw + (T_) * w1];
            const float le_ = L[a_ - (T_)];
            L[a_ - (T_)] = le_ - la_ * lt_ * inv;
        }"""


def _entry(s: str, t: str) -> str:
    """``_ENTRY`` for the entry (``s``, ``t``) (C expressions)."""
    return _ENTRY.replace("S_", s).replace("T_", t)


_ELIMINATE = (_ELIMINATE.replace("ENTRY_FIRST", _entry("s0", "t0"))
              .replace("ENTRY_SECOND", _entry("s1", "t1"))
              .replace("ENTRY_TABLE", _entry("st >> 16", "st & 0xffff")))


# the back substitutions' first part (u scaled by D^-1, rows split among the warp's lanes) and
# last (the solution out, in node order)
_SCALE_D = r"""
        for (int r = lane; r < n; r += 32) {
            const float ir = 1.0f / fmaxf(L[r * w], 1.0e-30f);
            u[3 * r] *= ir;
            u[3 * r + 1] *= ir;
            u[3 * r + 2] *= ir;
        }
        __syncwarp();
"""
_STORE_DX = r"""
        for (int r = lane; r < n; r += 32)
            dx_out[start + order[start + r]] = wp::vec3(u[3 * r], u[3 * r + 1], u[3 * r + 2]);
"""
# D^-1, then L^T x = D^-1 z: a chain of n short rows for one warp, whose barrier is cheaper
_BACK = r"""
    if (lane < 32) {
SCALE_D
        // last row first: row r is final, then leaves rows r-1 .. r-b
        for (int r = n - 1; r > 0; --r) {
            const float x0 = u[3 * r], x1 = u[3 * r + 1], x2 = u[3 * r + 2];
            BACK_ROW
            __syncwarp();
        }
STORE_DX
    }
"""
# a substitution step's tasks for one warp: u[U(q)] -= L[L(q)] x for the row's entries q < count,
# lane q and q + 32 loading both entries before either store (the compiler keeps the order of
# shared loads and stores that may alias), more entries one by one
_ROW_PAIR = r"""{
                const int cnt_ = COUNT;
                float l_[2], p_[2][3];
                for (int k_ = 0; k_ < 2; ++k_) {
                    const int q = lane + 32 * k_;
                    if (q < cnt_) {
                        l_[k_] = L[LIDX];
                        p_[k_][0] = u[UIDX];
                        p_[k_][1] = u[UIDX + 1];
                        p_[k_][2] = u[UIDX + 2];
                    }
                }
                for (int k_ = 0; k_ < 2; ++k_) {
                    const int q = lane + 32 * k_;
                    if (q < cnt_) {
                        u[UIDX] = p_[k_][0] - l_[k_] * x0;
                        u[UIDX + 1] = p_[k_][1] - l_[k_] * x1;
                        u[UIDX + 2] = p_[k_][2] - l_[k_] * x2;
                    }
                }
                for (int q = lane + 64; q < cnt_; q += 32) {
                    const float l = L[LIDX];
                    u[UIDX] -= l * x0;
                    u[UIDX + 1] -= l * x1;
                    u[UIDX + 2] -= l * x2;
                }
            }"""


def _row_pair(count: str, lidx: str, uidx: str) -> str:
    """``_ROW_PAIR`` for a row of ``count`` entries at band index ``lidx`` and right-hand-side
    index ``uidx`` (C expressions of ``q``)."""
    return _ROW_PAIR.replace("COUNT", count).replace("LIDX", lidx).replace("UIDX", f"({uidx})")


_BACK = (_BACK.replace("BACK_ROW", _row_pair("min(b, r)", "r * w + q + 1", "3 * (r - q - 1)"))
         .replace("SCALE_D", _SCALE_D).replace("STORE_DX", _STORE_DX))


# the factor: the elimination, then the band to global memory
_FACTOR = _HEAD + _LOAD_BAND + _ELIMINATE + r"""
    for (int q = lane; q < n * w; q += T)
        factor_out[base + q] = L[q];
"""
# the forward substitution column by column in one warp: row j is final once the columns before
# it are done, then leaves rows j+1 .. j+b (after a barrier: ``_ELIMINATE`` ends with one, the
# split path's loads get their own)
_FORWARD = r"""
    if (lane < 32) {
        for (int j = 0; j < n - 1; ++j) {
            const float x0 = u[3 * j], x1 = u[3 * j + 1], x2 = u[3 * j + 2];
            FORWARD_ROW
            __syncwarp();
        }
    }
""".replace("FORWARD_ROW", _row_pair("min(b, n - 1 - j)", "(j + q + 1) * w + q + 1", "3 * (j + q + 1)"))
# Two columns (rows) per warp step (session 36): half the steps and barriers of ``_FORWARD`` /
# ``_BACK``, the same floats. Every lane takes the pair's first value as final, forms the second
# from it as the one-column step before would have (lane 0 stores it), and each entry below
# takes the first column's product, then the second's, in the order the one-column steps took
# them. A lane loads its first two entries (rows q and q + 32) before storing either. A column
# left over at the end takes the one-column step.
# one pair step: rows FIRST (final) and SECOND (final once FIRST's product is taken, pair entry
# L[LPAIR]) leave the COUNT rows ROW (q = 0 ..), whose entries are L[LA] (FIRST's column, where
# q + 2 <= b) and L[LB] (SECOND's); lane 0 stores SECOND after the barrier, when every lane has
# read it and no later step reads it
_PAIR_STEP = r"""
            const float x0 = u[3 * (FIRST)], x1 = u[3 * (FIRST) + 1], x2 = u[3 * (FIRST) + 2];
            float y0 = u[3 * (SECOND)], y1 = u[3 * (SECOND) + 1], y2 = u[3 * (SECOND) + 2];
            if (b >= 1) {
                const float l = L[LPAIR];
                y0 = y0 - l * x0;
                y1 = y1 - l * x1;
                y2 = y2 - l * x2;
            }
            const int cnt_ = COUNT;
            float la_[2], lb_[2], p_[2][3];
            for (int k_ = 0; k_ < 2; ++k_) {
                const int q = lane + 32 * k_;
                if (q < cnt_) {
                    const int t_ = ROW;
                    la_[k_] = (q + 2 <= b) ? L[LA] : 0.0f;
                    lb_[k_] = L[LB];
                    p_[k_][0] = u[3 * t_];
                    p_[k_][1] = u[3 * t_ + 1];
                    p_[k_][2] = u[3 * t_ + 2];
                }
            }
            for (int k_ = 0; k_ < 2; ++k_) {
                const int q = lane + 32 * k_;
                if (q < cnt_) {
                    const int t_ = ROW;
                    if (q + 2 <= b) {
                        p_[k_][0] = p_[k_][0] - la_[k_] * x0;
                        p_[k_][1] = p_[k_][1] - la_[k_] * x1;
                        p_[k_][2] = p_[k_][2] - la_[k_] * x2;
                    }
                    u[3 * t_] = p_[k_][0] - lb_[k_] * y0;
                    u[3 * t_ + 1] = p_[k_][1] - lb_[k_] * y1;
                    u[3 * t_ + 2] = p_[k_][2] - lb_[k_] * y2;
                }
            }
            for (int q = lane + 64; q < cnt_; q += 32) {
                const int t_ = ROW;
                float v0 = u[3 * t_], v1 = u[3 * t_ + 1], v2 = u[3 * t_ + 2];
                if (q + 2 <= b) {
                    const float la = L[LA];
                    v0 = v0 - la * x0;
                    v1 = v1 - la * x1;
                    v2 = v2 - la * x2;
                }
                const float lb = L[LB];
                u[3 * t_] = v0 - lb * y0;
                u[3 * t_ + 1] = v1 - lb * y1;
                u[3 * t_ + 2] = v2 - lb * y2;
            }
            __syncwarp();
            if (lane == 0) {
                u[3 * (SECOND)] = y0;
                u[3 * (SECOND) + 1] = y1;
                u[3 * (SECOND) + 2] = y2;
            }
"""


def _pair_step(first: str, second: str, lpair: str, count: str, row: str, la: str, lb: str) -> str:
    """``_PAIR_STEP`` for its placeholders (C expressions; ``q`` the row's place, ``t_`` its
    index)."""
    out = _PAIR_STEP
    for key, value in (("FIRST", first), ("SECOND", second), ("LPAIR", lpair), ("COUNT", count),
                       ("ROW", row), ("LA", la), ("LB", lb)):
        out = out.replace(key, value)
    return out


# columns j, j + 1 per step while j + 1 <= n - 2, then a last one-column step if one is left
_FORWARD2 = r"""
    if (lane < 32) {
        int j = 0;
        for (; j + 1 <= n - 2; j += 2) {
            PAIR_STEP
        }
        for (; j < n - 1; ++j) {
            const float x0 = u[3 * j], x1 = u[3 * j + 1], x2 = u[3 * j + 2];
            FORWARD_ROW
            __syncwarp();
        }
        __syncwarp();  // the last pair's second row
    }
""".replace("PAIR_STEP", _pair_step("j", "j + 1", "(j + 1) * w + 1", "min(b, n - 2 - j)", "j + 2 + q",
                                    "t_ * w + q + 2", "t_ * w + q + 1")) \
    .replace("FORWARD_ROW", _row_pair("min(b, n - 1 - j)", "(j + q + 1) * w + q + 1", "3 * (j + q + 1)"))
# D^-1, then rows r, r - 1 per step while r >= 2, then a last one-row step if one is left
_BACK2 = r"""
    if (lane < 32) {
SCALE_D
        int r = n - 1;
        for (; r >= 2; r -= 2) {
            PAIR_STEP
        }
        for (; r > 0; --r) {
            const float x0 = u[3 * r], x1 = u[3 * r + 1], x2 = u[3 * r + 2];
            BACK_ROW
            __syncwarp();
        }
        __syncwarp();  // the last pair's second row
STORE_DX
    }
""".replace("PAIR_STEP", _pair_step("r", "r - 1", "r * w + 1", "min(b, r - 1)", "r - 2 - q", "r * w + q + 2",
                                    "(r - 1) * w + q + 1")) \
    .replace("BACK_ROW", _row_pair("min(b, r)", "r * w + q + 1", "3 * (r - q - 1)")) \
    .replace("SCALE_D", _SCALE_D).replace("STORE_DX", _STORE_DX)
# the whole solve: the factor as above, then both substitutions by one warp (session 32: the
# forward substitution as tasks of the elimination's diagonal entries made each step longer)
# (two columns per step since session 36; ``SOLVE_ONE_COLUMN`` keeps the one-column substitutions
# for the tests, which check that both give the same floats)
_SOLVE = _HEAD + _LOAD_BAND + _LOAD_RHS + _ELIMINATE + _FORWARD2 + _BACK2
SOLVE_ONE_COLUMN = _HEAD + _LOAD_BAND + _LOAD_RHS + _ELIMINATE + _FORWARD + _BACK
_SUBSTITUTE = _HEAD + r"""
    for (int q = lane; q < n * w; q += T)
        L[q] = factor[base + q];
""" + _LOAD_RHS + r"""
    __syncthreads();
""" + _FORWARD2 + _BACK2
