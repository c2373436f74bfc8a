"""The coarse level (``sim.cloth.coarse``) on its own: aggregates, operators, the restriction, the
exact and two-grid solves. The correction inside the solver: ``test_coarse_correction.py``."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth import ClothMaterialParams, ClothModelBuilder
from sim.cloth.coarse import (
    AUTO_MAX_NODES,
    CoarseLevel,
    aggregate,
    aggregate_graph,
    auto_aggregate,
    band_solve_kernel,
    mesh_edge_graph,
)
from sim.cloth.config import BodyContact, Stepping
from sim.cloth.model import mesh_edges
from sim.device import warp
from tests.conftest import DEVICES
from tests.test_cloth_solver import grid

STIFF = ClothMaterialParams(density=0.2, mu=200.0, lam=100.0, bending=1e-7, damping=0.0, friction=0.0)


def strip(device, nx: int = 11, ny: int = 41):
    """A 0.25 x 1 m strip pinned along its top row (slow for sweeps: the load travels 40 rows)."""
    v, f = grid(nx, ny, 0.25, 1.0)
    b = ClothModelBuilder()
    b.add_cloth(v, f, STIFF, pinned=np.arange(nx))
    return b.finalize(device), v


def coarse_level(model, spacing: int, levels: int = 2, smoothing: int = 2) -> tuple[CoarseLevel, dict]:
    """The coarse level of ``model`` (two levels unless told: the coarse system solved exactly)
    with the job's body contact and air damping, and the per-particle arrays it reads (inertial
    targets and body contact planes: none active)."""
    wp = warp()
    n, d = model.particle_count, model.device
    arrays = {"targets": wp.zeros(n, dtype=wp.vec3, device=d), "point": wp.zeros(n, dtype=wp.vec3, device=d),
              "normal": wp.zeros(n, dtype=wp.vec3, device=d), "active": wp.zeros(n, dtype=wp.int32, device=d)}
    level = CoarseLevel(model, *arrays.values(), k_contact=BodyContact().stiffness,
                        contact_margin=BodyContact().margin, air_damping=Stepping().air_damping,
                        spacing=spacing, levels=levels, smoothing=smoothing)
    return level, arrays


def two_sheets(big: int, small: tuple[int, int] = (15, 15)):
    """A model of a ``big`` x ``big`` sheet of 1 m and a small 0.3 m one beside it."""
    b = ClothModelBuilder()
    v1, f1 = grid(big, big, 1.0, 1.0)
    v2, f2 = grid(*small, 0.3, 0.3)
    b.add_cloth(v1, f1, ClothMaterialParams())
    b.add_cloth(v2 + 2.0, f2, ClothMaterialParams())
    return b.finalize("cpu"), (v1, f1), (v2, f2)


def test_aggregates_are_connected_cells_around_spaced_seeds():
    v, f = grid(15, 15, 0.3, 0.3)
    adj = mesh_edge_graph(len(v), f)
    from scipy.sparse.csgraph import connected_components, shortest_path

    dist = shortest_path(adj, unweighted=True)
    for spacing in (1, 2, 3):
        agg, seeds = aggregate(adj, spacing)
        cells = agg.max() + 1
        assert 1 < cells < len(v) and len(seeds) == cells
        np.testing.assert_array_equal(agg[seeds], np.arange(cells))
        assert dist[np.ix_(seeds, seeds)][~np.eye(cells, dtype=bool)].min() > spacing
        for c in range(cells):
            members = np.flatnonzero(agg == c)
            assert connected_components(adj[members][:, members], directed=False)[0] == 1
        # nearest seed: no vertex is closer to another seed than to its own
        own = dist[np.arange(len(v)), seeds[agg]]
        np.testing.assert_array_equal(own, dist[:, seeds].min(axis=1))


@pytest.mark.slow
def test_automatic_spacing_is_the_least_from_4_that_fits_the_node_cap():
    """Spacing 0 with two levels: a small sheet keeps spacing 4; a 9k-vertex sheet, which has ~370
    nodes at 4, gets the least larger spacing with at most ``AUTO_MAX_NODES`` (the search starts
    from an estimate, so both sides of it are checked against plain ``aggregate``); a model's
    instances each get their own spacing."""
    for side, expect_min in ((15, True), (95, False)):
        v, f = grid(side, side, 1.0, 1.0)
        adj = mesh_edge_graph(len(v), f)
        agg, seeds = auto_aggregate(adj)
        counts = {s: len(aggregate(adj, s)[1]) for s in range(4, 14)}
        least = min(s for s, c in counts.items() if c <= AUTO_MAX_NODES)
        assert (least == 4) == expect_min
        ref_agg, ref_seeds = aggregate(adj, least)
        np.testing.assert_array_equal(seeds, ref_seeds)
        np.testing.assert_array_equal(agg, ref_agg)
    m, _, (v2, f2) = two_sheets(95)
    level, _ = coarse_level(m, spacing=0)
    assert level.levels == 2
    nodes = sorted(len(t.mass) for t in level.templates)
    assert nodes == sorted([len(aggregate(mesh_edge_graph(len(v2), f2), 4)[1]), counts[least]])


@pytest.mark.slow
def test_automatic_levels_add_an_inner_level_where_spacing_4_has_too_many_nodes():
    """Spacing 0 and levels 0 (the job's): spacing 4 everywhere; the 9k-vertex sheet's ~370 nodes
    get an inner level of at most ``AUTO_MAX_NODES`` on their aggregate graph (the least spacing
    from 1), the small sheet none. The model then runs three levels, and the small sheet's
    instance takes itself as its inner level; a small garment alone keeps two."""
    m, (v1, f1), (v2, f2) = two_sheets(95)
    level, _ = coarse_level(m, spacing=0, levels=0)
    big, small = sorted(level.templates, key=lambda t: -len(t.mass))
    adj = mesh_edge_graph(len(v1), f1)
    agg, seeds = aggregate(adj, 4)
    assert len(big.mass) == len(seeds) > AUTO_MAX_NODES
    graph = aggregate_graph(adj, agg)
    inner_agg, inner_seeds = auto_aggregate(graph, min_spacing=1)
    assert 0.1 * len(seeds) < len(big.inner.mass) == len(inner_seeds) <= AUTO_MAX_NODES
    np.testing.assert_allclose(big.inner.stiffness.toarray(),
                               (big.inner.prolongation.T @ big.stiffness @ big.inner.prolongation).toarray())
    # the inner prolongation's rows sum to one: a uniform coarse move is reproduced
    np.testing.assert_allclose(np.asarray(big.inner.prolongation.sum(axis=1)).ravel(), 1.0, rtol=1e-12)
    # neighbours in the aggregate graph share a mesh edge
    rows, cols = graph.nonzero()
    e = set(map(tuple, mesh_edges(f1).tolist()))  # (low, high) vertex pairs
    for a, c in list(zip(rows, cols, strict=True))[:200]:
        members_a, members_c = np.flatnonzero(agg == a), np.flatnonzero(agg == c)
        assert any((min(i, j), max(i, j)) in e for i in members_a for j in members_c)
    assert small.inner is None and len(small.mass) == len(aggregate(mesh_edge_graph(len(v2), f2), 4)[1])
    assert level.levels == 3 and level.exact_node_count == len(big.inner.mass) + len(small.mass)
    assert not level.prefactor  # three levels form the diagonal at each correction
    b = ClothModelBuilder()
    b.add_cloth(v2, f2, ClothMaterialParams())
    alone, _ = coarse_level(b.finalize("cpu"), spacing=0, levels=0)
    assert alone.levels == 2 and alone.prefactor


def test_prolongation_rows_sum_to_one_and_pins_do_not_move():
    m, _ = strip("cpu")
    level, _ = coarse_level(m, spacing=3)
    rows = np.asarray(level.prolongation.sum(axis=1)).ravel()
    np.testing.assert_allclose(rows[11:], 1.0, rtol=1e-12)
    np.testing.assert_array_equal(rows[:11], 0.0)
    assert 10 < level.node_count < 60


def test_settings_are_checked():
    m, _ = strip("cpu")
    for bad, match in (({"spacing": -1}, "spacing"), ({"levels": 1}, "levels"), ({"levels": 4}, "levels"),
                       ({"smoothing": 0}, "smoothing")):
        with pytest.raises(ValueError, match=match):
            coarse_level(m, **{"spacing": 3, **bad})


def press_half(level, arrays, x: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Contact planes under ``x`` along +z, 40 % of them active, at random gaps from below the
    thickness (pressed) to twice it: (active flags, gaps [m])."""
    n = len(x)
    rng = np.random.default_rng(seed)
    thickness = float(level.model.instance_thickness.numpy()[0])
    active = (rng.uniform(size=n) < 0.4).astype(np.int32)
    gap = rng.uniform(-0.5, 2.0, n) * thickness
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    arrays["point"].assign((x - gap[:, None] * normal).astype(np.float32))
    arrays["normal"].assign(normal.astype(np.float32))
    arrays["active"].assign(active)
    return active, gap


def test_restriction_matches_its_sparse_matrix_form(device):
    """``restrict`` (8 lanes per coarse node, summed in lane order) against scipy: ``P^T r`` and
    the diagonal ``m_c (1/h^2 + alpha/h) + K_c,JJ + P^T k`` with ``k`` the contact penalty at
    particles pressed onto the body closer than the thickness, none elsewhere. CUDA sums a node's
    lanes by shuffles in the same launch: the same floats as the separate sum launch, for each
    part alone too."""
    from sim.cloth.coarse import RESTRICT_DIAGONAL, RESTRICT_RHS
    from sim.cloth.self_contact import disabled_data

    wp = warp()
    v, f = grid(21, 31, 0.4, 0.6)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(damping=0.02), pinned=np.arange(21))
    m = b.finalize(device)
    level, arrays = coarse_level(m, spacing=2)
    x = np.asarray(v, dtype=np.float64)
    active, gap = press_half(level, arrays, x, seed=3)
    r = np.random.default_rng(3).normal(size=(m.particle_count, 3))
    level.residual.assign(r.astype(np.float32))
    h = 1.0 / 150.0
    xw = wp.array(x.astype(np.float32), dtype=wp.vec3, device=device)
    level.restrict(h, xw, disabled_data(device))
    p = level.prolongation
    thickness = float(m.instance_thickness.numpy()[0])
    k = np.where((active != 0) & (gap < thickness), BodyContact().stiffness, 0.0)
    inertia = 1.0 / h**2 + Stepping().air_damping / h
    diag = level.node_mass.numpy() * inertia + p.T @ k + level.templates[0].stiffness.diagonal()
    assert (p.T @ k).max() > 0.0 and (p.T @ k).min() == 0.0
    np.testing.assert_allclose(level.rhs.numpy(), p.T @ r, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(level.diag.numpy(), diag, rtol=1e-5)
    assert level.restrict_lanes == (device == "cuda")
    if device != "cuda":
        return
    for parts in (RESTRICT_RHS | RESTRICT_DIAGONAL, RESTRICT_RHS, RESTRICT_DIAGONAL):
        out = {}
        for lanes in (True, False):
            level.restrict_lanes = lanes
            level.rhs.zero_()
            level.diag.zero_()
            level.restrict(h, xw, disabled_data(device), int(parts))
            out[lanes] = (level.rhs.numpy(), level.diag.numpy())
        np.testing.assert_array_equal(out[True][0], out[False][0])
        np.testing.assert_array_equal(out[True][1], out[False][1])
        assert np.abs(out[True][0]).max() > 0 or not parts & RESTRICT_RHS


@pytest.mark.parametrize("levels", [2, 3])
def test_body_contact_stiffness_is_taken_at_the_inertial_targets_with_two_levels(device, levels):
    """Two levels: ``prepare`` forms the diagonal at the substep start with the body contact's
    stiffness at particles pressed at the inertial targets ``y``, and a correction keeps it.
    Three levels form the diagonal at each correction, at the positions it corrects."""
    from sim.cloth.self_contact import disabled_data

    wp = warp()
    v, f = grid(21, 31, 0.4, 0.6)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(), pinned=np.arange(21))
    m = b.finalize(device)
    x = np.asarray(v, dtype=np.float64)
    n = m.particle_count
    active = (np.random.default_rng(7).uniform(size=n) < 0.4).astype(np.int32)
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    h = 1.0 / 420.0
    sc = disabled_data(device)
    xw = wp.array(x.astype(np.float32), dtype=wp.vec3, device=device)
    level, arrays = coarse_level(m, spacing=2, levels=levels)
    assert level.levels == levels and level.prefactor == (levels == 2)
    arrays["targets"].assign((x - 0.03 * normal).astype(np.float32))  # y sinks 1 cm under the planes
    arrays["point"].assign((x - 0.02 * normal).astype(np.float32))  # x is 2 cm out: pressed only at y
    arrays["normal"].assign(normal.astype(np.float32))
    arrays["active"].assign(active)
    level.residual.zero_()
    level.prepare(h, sc)
    level.correct(h, xw, wp.zeros_like(xw), sc, wp.zeros(1, dtype=wp.uint64, device=device))
    inertia = 1.0 / h**2 + Stepping().air_damping / h
    base = level.node_mass.numpy() * inertia + level.templates[0].stiffness.diagonal()
    pressed = level.prolongation.T @ (active * BodyContact().stiffness)
    assert pressed.max() > 0.0
    np.testing.assert_allclose(level.diag.numpy(), base + pressed if levels == 2 else base, rtol=1e-5)
    np.testing.assert_array_equal(xw.numpy(), x.astype(np.float32))  # no residual: nothing moved


def dense_system(level, seed: int, spread: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A coarse system of ``level``: its block-diagonal stiffness with a positive mass / contact
    share of up to ``spread`` on the diagonal, and a random right-hand side; set as the level's
    diagonal and right-hand side. Returns (dense matrix, diagonal, right-hand side)."""
    import scipy.sparse as sp

    rng = np.random.default_rng(seed)
    dense = sp.block_diag([t.stiffness for t in level.templates]).toarray()
    diag = np.diag(dense) + rng.uniform(1.0, spread, level.node_count)
    np.fill_diagonal(dense, diag)
    rhs = rng.normal(size=(level.node_count, 3))
    level.diag.assign(diag.astype(np.float32))
    level.rhs.assign(rhs.astype(np.float32))
    return dense, diag, rhs


def test_band_solve_matches_a_dense_solve_for_every_instance(device):
    """Two instances of different templates in one model: the banded factor of each coarse system
    ``K_c + diag`` (CUDA: the block kernels, factor and substitutions; CPU: one thread per
    instance) gives numpy's dense solution, and so does the one-thread kernel on CUDA."""
    wp = warp()
    b = ClothModelBuilder()
    v1, f1 = grid(11, 21, 0.25, 0.5)
    v2, f2 = grid(7, 9, 0.2, 0.2)
    b.add_cloth(v1, f1, STIFF, pinned=np.arange(11))
    b.add_cloth(v2 + 1.0, f2, ClothMaterialParams())
    m = b.finalize(device)
    level, _ = coarse_level(m, spacing=2)
    assert len(level.templates) == 2
    dense, _, rhs = dense_system(level, seed=0, spread=1e4)
    assert (level.substitute_kernel is not None) == device.startswith("cuda")
    level.factor()
    level.solve()
    exact = np.linalg.solve(dense, rhs)
    np.testing.assert_allclose(level.dx.numpy(), exact, rtol=2e-3, atol=2e-3 * np.abs(exact).max())
    assert_split_equals_whole_block_solve(level, device)
    if device.startswith("cuda"):
        serial = wp.zeros_like(level.dx)
        bands = level.bands
        wp.launch(band_solve_kernel, dim=2, inputs=[level.rhs, level.diag, *bands.inst, bands.order,
                                                    bands.stiffness],
                  outputs=[bands.factor, bands.forward, serial], device=device)
        np.testing.assert_allclose(serial.numpy(), exact, rtol=2e-3, atol=2e-3 * np.abs(exact).max())


def assert_split_equals_whole_block_solve(level, device):
    """On CUDA, two levels substitute with ``factor``'s factor (two launches); the whole block
    solve (one launch, as three levels run it) gives the same floats (``coarse.block``)."""
    if level.substitute_kernel is None:
        return
    from sim.cloth.coarse import block

    wp = warp()
    bands = level.bands
    need = max(block.shared_floats(int(c), int(w)) for c, w in zip(bands.counts, bands.widths, strict=True))
    whole = wp.zeros_like(level.dx)
    wp.launch_tiled(block.block_kernel(need, "solve"), dim=[level.model.instance_count],
                    block_dim=level.block_threads,
                    inputs=[level.rhs, level.diag, *bands.inst, bands.order, bands.stiffness],
                    outputs=[whole], device=device)
    np.testing.assert_array_equal(level.dx.numpy(), whole.numpy())


def two_grid_reference(templates, rhs, diag, smoothing):
    """numpy float64 of ``CoarseLevel.solve`` with three levels on the coarse system ``A`` (the
    templates' stiffness with ``diag`` on its diagonal): ``smoothing`` l1-Jacobi passes from zero,
    the exact solve of the residual on the inner level (Galerkin: ``P2^T A P2``), its
    prolongation, ``smoothing`` passes again. A template without an inner level is its own."""
    import scipy.sparse as sp

    k = sp.block_diag([t.stiffness for t in templates], format="csr").toarray()
    a = k.copy()
    np.fill_diagonal(a, diag)
    dl = diag + np.abs(k - np.diag(np.diag(k))).sum(axis=1)
    p2 = sp.block_diag([t.inner.prolongation if t.inner is not None else sp.identity(len(t.mass))
                        for t in templates], format="csr").toarray()
    x = rhs / dl[:, None]
    for _ in range(smoothing - 1):
        x = x + (rhs - a @ x) / dl[:, None]
    x = x + p2 @ np.linalg.solve(p2.T @ a @ p2, p2.T @ (rhs - a @ x))
    for _ in range(smoothing):
        x = x + (rhs - a @ x) / dl[:, None]
    return x, a


def energy_norm_errors(x, exact, a, blocks) -> list[float]:
    """Relative energy-norm error of ``x`` against ``exact`` on each block of rows of ``a``."""
    out = []
    for rows in blocks:
        e, sub = (x - exact)[rows], a[np.ix_(rows, rows)]
        out.append(float(np.sqrt(np.sum(e * (sub @ e)) / np.sum(exact[rows] * (sub @ exact[rows])))))
    return out


def test_three_level_solve_matches_its_numpy_two_grid_cycle(device):
    """Three levels on a model of a 2.4k-vertex sheet (~300 nodes at spacing 2: an inner level)
    and a small sheet (none: taken as its own inner level), with body contact on a patch of the
    sheet: for 1 and 3 smoothing passes the kernels give the numpy two-grid cycle to float
    round-off; the cycle solves the coarse system to a few percent in the energy norm, better
    with more smoothing, and exactly on the instance without an inner level."""
    b = ClothModelBuilder()
    v1, f1 = grid(49, 49, 1.0, 1.0)
    v2, f2 = grid(9, 11, 0.2, 0.25)
    b.add_cloth(v1, f1, ClothMaterialParams(), pinned=np.arange(49))
    b.add_cloth(v2 + 2.0, f2, ClothMaterialParams())
    m = b.finalize(device)
    errors = []
    for smoothing in (1, 3):
        level, _ = coarse_level(m, spacing=2, levels=0, smoothing=smoothing)
        big, small = level.templates
        assert level.levels == 3 and big.inner is not None and small.inner is None
        nc, n1 = level.node_count, len(big.mass)
        inertia = (30.0 * 14) ** 2
        mass = level.node_mass.numpy()
        centres = np.concatenate([np.asarray(t.prolongation.T @ v) / np.asarray(t.prolongation.sum(0)).T
                                  for t, v in ((big, v1), (small, v2))])
        contact = np.where(centres[:, 0] > 0.6, 20.0, 0.0) * mass * inertia  # a pressed patch
        diag = level.node_stiffness.numpy() + mass * inertia + contact
        rhs = np.sin(3.0 * centres) + 0.1 * np.random.default_rng(5).normal(size=(nc, 3))  # smooth + noise
        level.rhs.assign(rhs.astype(np.float32))
        level.diag.assign(diag.astype(np.float32))
        level.solve()
        ref, a = two_grid_reference(level.templates, rhs, diag, smoothing)
        np.testing.assert_allclose(level.dx.numpy(), ref, rtol=1e-3, atol=1e-3 * np.abs(ref).max())
        rel = energy_norm_errors(ref, np.linalg.solve(a, rhs), a, (np.arange(n1), np.arange(n1, nc)))
        assert rel[1] < 1e-10  # the small sheet: its own inner level, solved exactly
        errors.append(rel[0])
    assert 1e-3 < errors[1] < errors[0] < 0.15


@pytest.mark.parametrize("side, spacing, task_per_thread", [(71, 3, True), (81, 2, False)])
def test_block_solve_matches_a_dense_solve_at_garment_size(side, spacing, task_per_thread):
    """CUDA: the block kernels on a 5k-6.5k-vertex sheet's coarse level (hundreds of nodes, a band
    tens wide) against numpy's dense solve, on both of their paths: one task per thread for the
    whole factorization (band 19), and threads looping over the entries (band 47, whose 1,128
    entries under a column outnumber a block's 1,024 threads)."""
    if "cuda" not in DEVICES:
        pytest.skip("no CUDA device here")
    from sim.cloth.coarse.block import threads

    v, f = grid(side, side, 1.0, 1.0)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams())
    level, _ = coarse_level(b.finalize("cuda"), spacing=spacing)
    assert level.substitute_kernel is not None and level.node_count > 250
    width = level.templates[0].band.shape[1] - 1
    assert width > 15
    assert (level.block_threads >= width * (width + 1) // 2) == task_per_thread
    assert level.block_threads == threads(width)
    dense, _, rhs = dense_system(level, seed=1, spread=1e3)
    level.factor()
    level.solve()
    exact = np.linalg.solve(dense, rhs)
    np.testing.assert_allclose(level.dx.numpy(), exact, rtol=2e-3, atol=2e-3 * np.abs(exact).max())
    assert_split_equals_whole_block_solve(level, "cuda")
