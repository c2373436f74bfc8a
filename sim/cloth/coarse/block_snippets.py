"""CUDA C snippets of the coarse level's block kernels (``sim.cloth.coarse.block``).

One instance's coarse system ``A dx = rhs``, solved by a thread block: ``A = L D L^T`` (unit lower
``L``, right-looking, one column per step) in shared memory; band rows as in
``band_kernels.band_solve_kernel`` (row ``r`` holds ``A[r, r - t]`` at ``t = 0 .. b``), the
right-hand side after them, 3 floats per row, then the index table of the block below a column.
The snippets are put together from these parts: the whole solve (``SOLVE``), the factor alone
(``FACTOR``: no right-hand side; the band goes to global memory) and the substitutions with that
factor (``SUBSTITUTE``). The split gives the same floats as the whole solve: both run the same
substitutions (``FORWARD``, ``BACK``) on the same scaled factor. Upper-case words inside a
snippet are placeholders, replaced by C expressions when the parts are put together.
"""

HEAD = r"""
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
LOAD_BAND = r"""
    for (int q = lane; q < n * w; q += T) {
        const int r = q / w;
        L[q] = (q - r * w == 0) ? diag[start + order[start + r]] : band_k[base + q];
    }
"""
LOAD_RHS = r"""
    for (int r = lane; r < n; r += T) {
        const wp::vec3 v = rhs[start + order[start + r]];
        u[3 * r] = v.c[0];
        u[3 * r + 1] = v.c[1];
        u[3 * r + 2] = v.c[2];
    }
"""
# the elimination, one column per step: every thread decodes its first two entries (s, t) of the
# block below a column once and keeps them for every step (more entries, for bands whose block
# outnumbers twice the threads, come from the index table); the forward substitution follows the
# elimination (``FORWARD``), and the columns are scaled to the unit L after the last step (nothing
# reads a column after its own step)
ELIMINATE = r"""
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
ENTRY = r"""{
            const int a_ = jw + (S_) * w1;
            const float la_ = L[a_];
            const float lt_ = L[jw + (T_) * w1];
            const float le_ = L[a_ - (T_)];
            L[a_ - (T_)] = le_ - la_ * lt_ * inv;
        }"""


def entry(s: str, t: str) -> str:
    """``ENTRY`` for the entry (``s``, ``t``) (C expressions)."""
    return ENTRY.replace("S_", s).replace("T_", t)


ELIMINATE = (ELIMINATE.replace("ENTRY_FIRST", entry("s0", "t0"))
             .replace("ENTRY_SECOND", entry("s1", "t1"))
             .replace("ENTRY_TABLE", entry("st >> 16", "st & 0xffff")))


# the back substitutions' first part (u scaled by D^-1, rows split among the warp's lanes) and
# last (the solution out, in node order)
SCALE_D = r"""
        for (int r = lane; r < n; r += 32) {
            const float ir = 1.0f / fmaxf(L[r * w], 1.0e-30f);
            u[3 * r] *= ir;
            u[3 * r + 1] *= ir;
            u[3 * r + 2] *= ir;
        }
        __syncwarp();
"""
STORE_DX = r"""
        for (int r = lane; r < n; r += 32)
            dx_out[start + order[start + r]] = wp::vec3(u[3 * r], u[3 * r + 1], u[3 * r + 2]);
"""
# a substitution step's tasks for one warp: u[U(q)] -= L[L(q)] x for the row's entries q < count,
# lane q and q + 32 loading both entries before either store (the compiler keeps the order of
# shared loads and stores that may alias), more entries one by one
ROW_PAIR = r"""{
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


def row_pair(count: str, lidx: str, uidx: str) -> str:
    """``ROW_PAIR`` for a row of ``count`` entries at band index ``lidx`` and right-hand-side
    index ``uidx`` (C expressions of ``q``)."""
    return ROW_PAIR.replace("COUNT", count).replace("LIDX", lidx).replace("UIDX", f"({uidx})")


# the factor: the elimination, then the band to global memory
FACTOR = HEAD + LOAD_BAND + ELIMINATE + r"""
    for (int q = lane; q < n * w; q += T)
        factor_out[base + q] = L[q];
"""
# The substitutions by one warp, two columns (rows) per step: half the barriers of one column per
# step, the same floats (H100: 0.73 against 0.82 ms of substitutions per run frame,
# docs/DECISIONS.md). Every lane takes the pair's first value as final, forms the second from it
# as a one-column step would (lane 0 stores it), and each entry below takes the first column's
# product, then the second's, in the order one-column steps take them. A lane loads its first two
# entries (rows q and q + 32) before storing either. A column left over at the end takes a
# one-column step (``ROW_PAIR``).
# one pair step: rows FIRST (final) and SECOND (final once FIRST's product is taken, pair entry
# L[LPAIR]) leave the COUNT rows ROW (q = 0 ..), whose entries are L[LA] (FIRST's column, where
# q + 2 <= b) and L[LB] (SECOND's); lane 0 stores SECOND after the barrier, when every lane has
# read it and no later step reads it
PAIR_STEP = r"""
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


def pair_step(first: str, second: str, lpair: str, count: str, row: str, la: str, lb: str) -> str:
    """``PAIR_STEP`` for its placeholders (C expressions; ``q`` the row's place, ``t_`` its
    index)."""
    out = PAIR_STEP
    for key, value in (("FIRST", first), ("SECOND", second), ("LPAIR", lpair), ("COUNT", count),
                       ("ROW", row), ("LA", la), ("LB", lb)):
        out = out.replace(key, value)
    return out


# columns j, j + 1 per step while j + 1 <= n - 2, then a last one-column step if one is left
FORWARD = r"""
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
""".replace("PAIR_STEP", pair_step("j", "j + 1", "(j + 1) * w + 1", "min(b, n - 2 - j)", "j + 2 + q",
                                    "t_ * w + q + 2", "t_ * w + q + 1")) \
    .replace("FORWARD_ROW", row_pair("min(b, n - 1 - j)", "(j + q + 1) * w + q + 1", "3 * (j + q + 1)"))
# D^-1, then rows r, r - 1 per step while r >= 2, then a last one-row step if one is left
BACK = r"""
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
""".replace("PAIR_STEP", pair_step("r", "r - 1", "r * w + 1", "min(b, r - 1)", "r - 2 - q", "r * w + q + 2",
                                    "(r - 1) * w + q + 1")) \
    .replace("BACK_ROW", row_pair("min(b, r)", "r * w + q + 1", "3 * (r - q - 1)")) \
    .replace("SCALE_D", SCALE_D).replace("STORE_DX", STORE_DX)
# the whole solve: the factor as above, then both substitutions by one warp (a warp's barrier is
# cheaper than the block's, and the substitutions are chains of short rows)
SOLVE = HEAD + LOAD_BAND + LOAD_RHS + ELIMINATE + FORWARD + BACK
SUBSTITUTE = HEAD + r"""
    for (int q = lane; q < n * w; q += T)
        L[q] = factor[base + q];
""" + LOAD_RHS + r"""
    __syncthreads();
""" + FORWARD + BACK
