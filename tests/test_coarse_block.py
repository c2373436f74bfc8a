"""The coarse level's CUDA block kernels (``sim.cloth.coarse_block``) on the CPU: their snippets
compiled by the system's C++ compiler, each block emulated by OS threads with barriers
(``tests/block_emulator.py``). CI has no GPU, so this is where the snippets' logic (indices,
barriers, the split into factor and substitutions) is checked on every run; the CUDA tests in
``test_coarse.py`` check the same kernels on a device."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth import coarse_block
from tests import block_emulator as emu

pytestmark = pytest.mark.skipif(emu.compiler() is None, reason="no C++ compiler for the block emulation")

# (nodes, band width) per instance: a band wider than its instance, a tridiagonal one, a
# diagonal one, a single node, the 5k t-shirt's coarse level (200 nodes, band 44) and the 19k
# one's (249, 44), bands whose entries under a column outnumber 1,024 threads (50: 1,275) and
# 2,048 (64: 2,080, the index table's path at ``threads``)
SIZES = [[(37, 5), (60, 12), (9, 12), (25, 1), (6, 0), (1, 3)], [(200, 44)], [(249, 44), (120, 30)],
         [(150, 50)], [(80, 64)]]


@pytest.fixture(scope="module")
def lib():
    return emu.build({"solve": coarse_block._SOLVE, "factor": coarse_block._FACTOR,
                      "substitute": coarse_block._SUBSTITUTE})


def dense_solution(system: dict) -> np.ndarray:
    """Each instance's system solved by numpy, per node (float64)."""
    out = np.zeros(system["rhs"].shape)
    for i, a in enumerate(system["dense"]):
        s0, n = system["start"][i], system["count"][i]
        rows = system["order"][s0:s0 + n] + s0  # band row r is node order[r]
        out[rows] = np.linalg.solve(a, system["rhs"][rows].astype(np.float64))
    return out


def capacity(sizes) -> int:
    return max(coarse_block.shared_floats(n, b) for n, b in sizes)


@pytest.mark.parametrize("case", range(len(SIZES)))
def test_block_solve_matches_a_dense_solve(lib, case):
    """The whole solve (one block per instance, nodes in a permuted band order) equals numpy's
    dense solve to float precision, at the block size ``threads`` picks and at 256 threads,
    where threads loop over several entries per column (the index-table path)."""
    sizes = SIZES[case]
    system = emu.band_system(sizes, seed=case)
    exact = dense_solution(system)
    for threads in sorted({256, coarse_block.threads(max(b for _, b in sizes))}):
        dx, _ = emu.run(lib, "solve", threads, capacity(sizes), system)
        err = np.abs(dx - exact).max() / np.abs(exact).max()
        assert err < 5e-5, (sizes, threads, err)


# two more cases for the two-column substitutions: rows whose band reaches 64+ entries past a
# column (a lane's third entry on), and instances of odd and even node counts down to two
TWO_COLUMN_SIZES = SIZES + [[(100, 70), (7, 2), (2, 1), (8, 3)]]


@pytest.mark.parametrize("case", range(len(TWO_COLUMN_SIZES)))
def test_two_column_substitutions_give_the_one_column_floats(lib, case):
    """The substitutions that finish two rows per warp step (session 36) give exactly the floats
    of the one-column substitutions of sessions 32-35, with half the warp barriers: every entry
    takes the same products in the same order."""
    sizes = TWO_COLUMN_SIZES[case]
    one_column = emu.build({"solve": coarse_block.SOLVE_ONE_COLUMN, "factor": coarse_block._FACTOR,
                            "substitute": coarse_block._SUBSTITUTE})
    system = emu.band_system(sizes, seed=20 + case)
    threads = coarse_block.threads(max(b for _, b in sizes))
    two, _ = emu.run(lib, "solve", threads, capacity(sizes), system)
    one, _ = emu.run(one_column, "solve", threads, capacity(sizes), system)
    assert np.abs(one).max() > 0.0
    np.testing.assert_array_equal(two, one)
    err = np.abs(two - dense_solution(system)).max() / np.abs(one).max()
    assert err < 5e-5, (sizes, err)


@pytest.mark.parametrize("case", range(len(SIZES)))
def test_split_solve_gives_the_whole_solves_floats(lib, case):
    """``coarse_prefactor``'s split (the factor to a global band, then the substitutions with it)
    gives the whole solve's floats exactly, and runs repeat to the bit (a race between threads
    that the barriers leave unordered would show as run-to-run differences)."""
    sizes = SIZES[case]
    system = emu.band_system(sizes, seed=10 + case)
    threads = coarse_block.threads(max(b for _, b in sizes))
    whole, _ = emu.run(lib, "solve", threads, capacity(sizes), system)
    _, factor = emu.run(lib, "factor", threads, capacity(sizes), system)
    split, _ = emu.run(lib, "substitute", coarse_block.SUBSTITUTE_THREADS, capacity(sizes), system,
                       factor=factor)
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


def test_a_missing_barrier_is_caught(lib):
    """The emulation orders threads only by the snippets' barriers: the solve with its
    elimination step's barrier removed goes wrong (so the tests above can fail on a race)."""
    sizes = [(200, 44)]
    system = emu.band_system(sizes, seed=2)
    text = coarse_block._SOLVE
    step_end = "        __syncthreads();\n    }\n    // the unit L"
    assert step_end in text
    racy = emu.build({"solve": text.replace(step_end, "    }\n    // the unit L"),
                      "factor": coarse_block._FACTOR, "substitute": coarse_block._SUBSTITUTE})
    exact = dense_solution(system)
    dx, _ = emu.run(racy, "solve", coarse_block.threads(44), capacity(sizes), system)
    assert np.abs(dx - exact).max() > 1e-2 * np.abs(exact).max()


def test_a_barrier_some_threads_never_reach_fails_instead_of_hanging(lib):
    """A snippet whose barrier only the first warp reaches (a ``__syncthreads`` inside ``lane <
    32``, a deadlock on a GPU) makes the emulation raise after its timeout, not hang the tests."""
    sizes = [(20, 3)]
    system = emu.band_system(sizes, seed=4)
    warp_only = "    if (lane < 32) {\n"
    text = coarse_block._SOLVE.replace(warp_only, warp_only + "        __syncthreads();\n", 1)
    assert text != coarse_block._SOLVE
    stuck = emu.build({"solve": text, "factor": coarse_block._FACTOR, "substitute": coarse_block._SUBSTITUTE})
    with pytest.raises(RuntimeError, match="timed out|never reach"):
        emu.run(stuck, "solve", 64, capacity(sizes), system, timeout=1.0)
    # the library still works afterwards
    dx, _ = emu.run(lib, "solve", 64, capacity(sizes), system)
    np.testing.assert_allclose(dx, dense_solution(system), rtol=1e-4, atol=1e-4 * np.abs(dx).max())


def test_block_kernels_fit_a_block_of_1024_threads_in_the_registers():
    """The block solve and factor kernels are launched with up to 1,024 threads (``threads``);
    an SM has 64k registers, so they are compiled with at most 64 per thread. Session 36's
    two-row substitutions took the uncapped block solve past that: on CUDA it no longer
    launched at 992 threads (error 701), which the CPU emulation cannot see."""
    assert coarse_block.threads(10_000) == 1024
    for kind in ("solve", "factor"):
        kernel = coarse_block._kernel(1024, kind)
        assert kernel.options["cuda_max_registers"] * coarse_block.threads(10_000) <= 65536
