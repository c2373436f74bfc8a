"""The coarse level's CUDA block kernels (``sim.cloth.coarse.block``) on the CPU: their snippets
compiled by the system's C++ compiler, each block emulated by OS threads with barriers
(``tests/block_emulator.py``). This is where the snippets' logic (indices, barriers, the split
into factor and substitutions) is checked on a machine without a GPU; the CUDA tests in
``test_coarse.py`` check the same kernels on a device."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth.coarse import block
from sim.cloth.coarse import block_snippets as snip
from tests import block_emulator as emu

pytestmark = pytest.mark.skipif(emu.compiler() is None, reason="no C++ compiler for the block emulation")

# (nodes, band width) per instance: a band wider than its instance, a tridiagonal one, a
# diagonal one, a single node, the 5k t-shirt's coarse level (200 nodes, band 44) and the 19k
# one's (249, 44), bands whose entries under a column outnumber 1,024 threads (50: 1,275) and
# 2,048 (64: 2,080, the index table's path at ``threads``)
SIZES = [[(37, 5), (60, 12), (9, 12), (25, 1), (6, 0), (1, 3)], [(200, 44)], [(249, 44), (120, 30)],
         [(150, 50)], [(80, 64)]]
# the garment-sized cases take 3-13 s each in the emulation
SLOW_CASES = {1, 2, 3}


def cases(sizes: list) -> list:
    """One pytest parameter per case of ``sizes``, the garment-sized ones marked slow."""
    return [pytest.param(i, marks=pytest.mark.slow) if i in SLOW_CASES else i for i in range(len(sizes))]

# A reference for the two-column substitutions: one column (row) per warp step. Forward: row j is
# final once the columns before it are done, then leaves rows j+1 .. j+b; back: D^-1, then row r
# final, leaving rows r-1 .. r-b, last row first.
ONE_COLUMN_FORWARD = r"""
    if (lane < 32) {
        for (int j = 0; j < n - 1; ++j) {
            const float x0 = u[3 * j], x1 = u[3 * j + 1], x2 = u[3 * j + 2];
            FORWARD_ROW
            __syncwarp();
        }
    }
""".replace("FORWARD_ROW", snip.row_pair("min(b, n - 1 - j)", "(j + q + 1) * w + q + 1", "3 * (j + q + 1)"))
ONE_COLUMN_BACK = r"""
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
""".replace("BACK_ROW", snip.row_pair("min(b, r)", "r * w + q + 1", "3 * (r - q - 1)")) \
    .replace("SCALE_D", snip.SCALE_D).replace("STORE_DX", snip.STORE_DX)
SOLVE_ONE_COLUMN = (snip.HEAD + snip.LOAD_BAND + snip.LOAD_RHS + snip.ELIMINATE + ONE_COLUMN_FORWARD
                    + ONE_COLUMN_BACK)


def snippets(solve: str = snip.SOLVE) -> dict[str, str]:
    """The emulated kinds' texts, the whole solve replaced by ``solve``."""
    return {"solve": solve, "factor": snip.FACTOR, "substitute": snip.SUBSTITUTE}


@pytest.fixture(scope="module")
def lib():
    return emu.build(snippets())


def dense_solution(system: dict) -> np.ndarray:
    """Each instance's system solved by numpy, per node (float64)."""
    out = np.zeros(system["rhs"].shape)
    for i, a in enumerate(system["dense"]):
        s0, n = system["start"][i], system["count"][i]
        rows = system["order"][s0:s0 + n] + s0  # band row r is node order[r]
        out[rows] = np.linalg.solve(a, system["rhs"][rows].astype(np.float64))
    return out


def capacity(sizes) -> int:
    return max(block.shared_floats(n, b) for n, b in sizes)


def assert_solves(dx: np.ndarray, system: dict, rtol: float = 5e-5) -> None:
    """``dx`` is the systems' dense solution to ``rtol`` of its largest entry."""
    exact = dense_solution(system)
    np.testing.assert_allclose(dx, exact, rtol=0.0, atol=rtol * np.abs(exact).max())


@pytest.mark.parametrize("case", cases(SIZES))
def test_block_solve_matches_a_dense_solve(lib, case):
    """The whole solve (one block per instance, nodes in a permuted band order) equals numpy's
    dense solve to float precision, at the block size ``threads`` picks and at 256 threads,
    where threads loop over several entries per column (the index-table path)."""
    sizes = SIZES[case]
    system = emu.band_system(sizes, seed=case)
    for threads in sorted({256, block.threads(max(b for _, b in sizes))}):
        dx, _ = emu.run(lib, "solve", threads, capacity(sizes), system)
        assert_solves(dx, system)


# two more cases for the two-column substitutions: rows whose band reaches 64+ entries past a
# column (a lane's third entry on), and instances of odd and even node counts down to two
TWO_COLUMN_SIZES = SIZES + [[(100, 70), (7, 2), (2, 1), (8, 3)]]


@pytest.mark.parametrize("case", cases(TWO_COLUMN_SIZES))
def test_two_column_substitutions_give_the_one_column_floats(lib, case):
    """The substitutions that finish two rows per warp step give exactly the floats of one row
    per step (``SOLVE_ONE_COLUMN``, the reference here), with half the warp barriers: every entry
    takes the same products in the same order."""
    sizes = TWO_COLUMN_SIZES[case]
    one_column = emu.build(snippets(SOLVE_ONE_COLUMN))
    system = emu.band_system(sizes, seed=20 + case)
    threads = block.threads(max(b for _, b in sizes))
    two, _ = emu.run(lib, "solve", threads, capacity(sizes), system)
    one, _ = emu.run(one_column, "solve", threads, capacity(sizes), system)
    assert np.abs(one).max() > 0.0
    np.testing.assert_array_equal(two, one)
    assert_solves(two, system)


@pytest.mark.parametrize("case", cases(SIZES))
def test_split_solve_gives_the_whole_solves_floats(lib, case):
    """The split (the factor to a global band at the substep start, then the substitutions with
    it at each correction) gives the whole solve's floats exactly, and runs repeat to the bit (a
    race between threads that the barriers leave unordered would show as run-to-run
    differences)."""
    sizes = SIZES[case]
    system = emu.band_system(sizes, seed=10 + case)
    threads = block.threads(max(b for _, b in sizes))
    whole, _ = emu.run(lib, "solve", threads, capacity(sizes), system)
    _, factor = emu.run(lib, "factor", threads, capacity(sizes), system)
    split, _ = emu.run(lib, "substitute", block.SUBSTITUTE_THREADS, capacity(sizes), system, factor=factor)
    np.testing.assert_array_equal(split, whole)
    again, _ = emu.run(lib, "solve", threads, capacity(sizes), system)
    np.testing.assert_array_equal(again, whole)


def test_factor_is_the_unit_ldlt_of_the_band(lib):
    """The factor kernel's band holds ``D`` on the diagonal and the unit ``L`` below it, with
    ``L D L^T`` equal to the instance's matrix (rows in band order)."""
    sizes = [(60, 7)]
    system = emu.band_system(sizes, seed=3)
    _, factor = emu.run(lib, "factor", 256, capacity(sizes), system)
    n, b = sizes[0]
    band = factor[: n * (b + 1)].reshape(n, b + 1).astype(np.float64)
    lower = np.eye(n)
    for t in range(1, b + 1):
        lower[np.arange(t, n), np.arange(n - t)] = band[t:, t]
    ldlt = lower @ np.diag(band[:, 0]) @ lower.T
    a = system["dense"][0]
    np.testing.assert_allclose(ldlt, a, rtol=1e-5, atol=1e-5 * np.abs(a).max())


def test_a_missing_barrier_is_caught():
    """The emulation orders threads only by the snippets' barriers: the solve with its
    elimination step's barrier removed goes wrong (so the tests above can fail on a race)."""
    sizes = [(200, 44)]
    system = emu.band_system(sizes, seed=2)
    step_end = "        __syncthreads();\n    }\n    // the unit L"
    assert step_end in snip.SOLVE
    racy = emu.build(snippets(snip.SOLVE.replace(step_end, "    }\n    // the unit L")))
    exact = dense_solution(system)
    dx, _ = emu.run(racy, "solve", block.threads(44), capacity(sizes), system)
    assert np.abs(dx - exact).max() > 1e-2 * np.abs(exact).max()


def test_a_barrier_some_threads_never_reach_fails_instead_of_hanging(lib):
    """A snippet whose barrier only the first warp reaches (a ``__syncthreads`` inside ``lane <
    32``, a deadlock on a GPU) makes the emulation raise after its timeout, not hang the tests."""
    sizes = [(20, 3)]
    system = emu.band_system(sizes, seed=4)
    warp_only = "    if (lane < 32) {\n"
    text = snip.SOLVE.replace(warp_only, warp_only + "        __syncthreads();\n", 1)
    assert text != snip.SOLVE
    stuck = emu.build(snippets(text))
    with pytest.raises(RuntimeError, match="timed out|never reach"):
        emu.run(stuck, "solve", 64, capacity(sizes), system, timeout=1.0)
    # the library still works afterwards
    dx, _ = emu.run(lib, "solve", 64, capacity(sizes), system)
    assert_solves(dx, system, rtol=1e-4)


def test_block_kernels_fit_a_block_of_1024_threads_in_the_registers():
    """The block solve and factor kernels are launched with up to 1,024 threads (``threads``);
    an SM has 64k registers, so they are compiled with at most 64 per thread (uncapped, the
    block solve does not launch at 992 threads on CUDA, which the CPU emulation cannot see)."""
    assert block.threads(10_000) == 1024
    for kind in ("solve", "factor"):
        kernel = block.block_kernel(1024, kind)
        assert kernel.options["cuda_max_registers"] * block.threads(10_000) <= 65536
