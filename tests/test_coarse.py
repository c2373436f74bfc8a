"""Coarse-level correction of the VBD sweeps (``sim.cloth.coarse``)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth import ClothMaterialParams, ClothModelBuilder, SolverVBD, VBDConfig
from sim.cloth.coarse import (
    AUTO_MAX_NODES,
    COARSE_OVERSHOOT,
    aggregate,
    aggregate_graph,
    auto_aggregate,
    band_solve_kernel,
    mesh_edge_graph,
)
from sim.cloth.model import mesh_edges
from sim.device import warp
from sim.quality import self_intersections
from tests.conftest import DEVICES
from tests.test_cloth_solver import drop_on_sphere, grid, one_step_from, simulate
from tests.test_self_contact import _center_gap, fine_denim_sheet, stacked_layers

STIFF = ClothMaterialParams(density=0.2, mu=200.0, lam=100.0, bending=1e-7, damping=0.0, friction=0.0)


def strip(device, nx: int = 11, ny: int = 41):
    """A 0.25 x 1 m strip pinned along its top row (slow for sweeps: the load travels 40 rows)."""
    v, f = grid(nx, ny, 0.25, 1.0)
    b = ClothModelBuilder()
    b.add_cloth(v, f, STIFF, pinned=np.arange(nx))
    return b.finalize(device), v


def overshoot_guard(level, h: float) -> np.ndarray:
    """Each coarse node's overshoot guard ``s = max(1, (1 + k_d/h) r / COARSE_OVERSHOOT)`` (module
    docstring of ``sim.cloth.coarse``) from the level's per-node ``(k_d, r / COARSE_OVERSHOOT)``."""
    kd, ratio = level.node_overshoot[:, 0], level.node_overshoot[:, 1]
    return np.maximum(1.0, (1.0 + kd / h) * ratio)


def coarse_level(model, spacing: int, levels: int = 2, smoothing: int = 2, prefactor: bool = False):
    """The coarse level a solver with corrections builds for ``model`` (two levels unless told:
    the coarse system solved exactly)."""
    return SolverVBD(model, VBDConfig(coarse_sweeps=(0,), coarse_spacing=spacing, coarse_levels=levels,
                                      coarse_smoothing=smoothing, coarse_prefactor=prefactor)).coarse


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
        assert np.all(own <= dist[:, seeds].min(axis=1))


def test_automatic_spacing_is_the_least_from_4_that_fits_the_node_cap():
    """``coarse_spacing`` 0 with two levels: a small sheet keeps spacing 4; a 9k-vertex sheet,
    which has ~370 nodes at 4, gets the least larger spacing with at most ``AUTO_MAX_NODES`` (the
    search starts from an estimate, so both sides of it are checked against plain
    ``aggregate``)."""
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
    # a model's instances each get their own spacing
    b = ClothModelBuilder()
    v1, f1 = grid(95, 95, 1.0, 1.0)
    v2, f2 = grid(15, 15, 0.3, 0.3)
    b.add_cloth(v1, f1, ClothMaterialParams())
    b.add_cloth(v2 + 2.0, f2, ClothMaterialParams())
    level = coarse_level(b.finalize("cpu"), spacing=0)
    assert level.levels == 2
    nodes = sorted(len(t.mass) for t in level.templates)
    assert nodes == sorted([len(aggregate(mesh_edge_graph(len(v2), f2), 4)[1]), counts[least]])


def test_automatic_levels_add_an_inner_level_where_spacing_4_has_too_many_nodes():
    """``coarse_spacing`` 0 and ``coarse_levels`` 0 (the job default): spacing 4 everywhere; the
    9k-vertex sheet's ~370 nodes get an inner level of at most ``AUTO_MAX_NODES`` on their
    aggregate graph (the least spacing from 1), the small sheet none. The model then runs three
    levels, and the small sheet's instance takes itself as its inner level."""
    b = ClothModelBuilder()
    v1, f1 = grid(95, 95, 1.0, 1.0)
    v2, f2 = grid(15, 15, 0.3, 0.3)
    b.add_cloth(v1, f1, ClothMaterialParams())
    b.add_cloth(v2 + 2.0, f2, ClothMaterialParams())
    level = coarse_level(b.finalize("cpu"), spacing=0, levels=0)
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
    # a small garment alone keeps two levels
    b = ClothModelBuilder()
    b.add_cloth(v2, f2, ClothMaterialParams())
    assert coarse_level(b.finalize("cpu"), spacing=0, levels=0).levels == 2


def test_prolongation_rows_sum_to_one_and_pins_do_not_move():
    m, _ = strip("cpu")
    level = coarse_level(m, spacing=3)
    p = level.prolongation
    rows = np.asarray(p.sum(axis=1)).ravel()
    np.testing.assert_allclose(rows[11:], 1.0, rtol=1e-12)
    np.testing.assert_array_equal(rows[:11], 0.0)
    assert 10 < level.node_count < 60


def test_restriction_matches_its_sparse_matrix_form(device):
    """``restrict`` (8 lanes per coarse node, summed in lane order) against scipy: ``P^T r / s``
    and the diagonal ``(m_c (1/h^2 + alpha/h) + P^T k) / s + K_c,JJ`` with ``k`` the contact
    penalty at particles pressed onto the body closer than the thickness, none elsewhere, and
    ``s = max(1, (1 + k_d/h) r / 1.8)``, ``r = 2 (lambda + mu) / (lambda + 2 mu)`` (the overshoot
    guard: the coarse system divided by the stiffening that keeps its overshoot at 1.8)."""
    from sim.cloth.self_contact import disabled_data

    v, f = grid(21, 31, 0.4, 0.6)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(damping=0.02), pinned=np.arange(21))
    m = b.finalize(device)
    level = coarse_level(m, spacing=2)
    n = m.particle_count
    rng = np.random.default_rng(3)
    r = rng.normal(size=(n, 3))
    x = np.asarray(v, dtype=np.float64)
    thickness = float(m.instance_thickness.numpy()[0])
    active = (rng.uniform(size=n) < 0.4).astype(np.int32)
    gap = rng.uniform(-0.5, 2.0, n) * thickness  # below the thickness: pressed
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    point = x - gap[:, None] * normal
    _, _, cp, cn, _, ca = level._particles
    cp.assign(point.astype(np.float32))
    cn.assign(normal.astype(np.float32))
    ca.assign(active)
    level.residual.assign(r.astype(np.float32))
    h = 1.0 / 150.0
    xw = warp().array(x.astype(np.float32), dtype=warp().vec3, device=device)
    level.restrict(h, xw, disabled_data(device))
    p = level.prolongation
    k = np.where((active != 0) & (gap < thickness), level._k_contact, 0.0)
    inertia = 1.0 / h**2 + level._air_damping / h
    mp = ClothMaterialParams()
    s = max(1.0, (1.0 + 0.02 / h) * 2.0 * (mp.lam + mp.mu) / (mp.lam + 2.0 * mp.mu) / COARSE_OVERSHOOT)
    assert COARSE_OVERSHOOT == 1.8 and s > 1.5
    diag = (level._mass.numpy() * inertia + p.T @ k) / s + level.templates[0].stiffness.diagonal()
    assert (p.T @ k).max() > 0.0 and (p.T @ k).min() == 0.0
    np.testing.assert_allclose(level._rhs.numpy(), p.T @ r / s, rtol=1e-5, atol=1e-5 / s)
    np.testing.assert_allclose(level._diag.numpy(), diag, rtol=1e-5)
    # CUDA sums a node's lanes by shuffles in the same launch (session 41): the same floats as
    # the separate sum launch, for each part alone too
    assert level.restrict_lanes == (device == "cuda")
    if device == "cuda":
        from sim.cloth.coarse import RESTRICT_DIAGONAL, RESTRICT_RHS

        for parts in (RESTRICT_RHS | RESTRICT_DIAGONAL, RESTRICT_RHS, RESTRICT_DIAGONAL):
            out = {}
            for lanes in (True, False):
                level.restrict_lanes = lanes
                level._rhs.zero_()
                level._diag.zero_()
                level.restrict(h, xw, disabled_data(device), int(parts))
                out[lanes] = (level._rhs.numpy(), level._diag.numpy())
            np.testing.assert_array_equal(out[True][0], out[False][0])
            np.testing.assert_array_equal(out[True][1], out[False][1])
            assert np.abs(out[True][0]).max() > 0 or not parts & RESTRICT_RHS


def test_prefactor_takes_the_contact_stiffness_at_the_inertial_targets(device):
    """``coarse_prefactor``: ``prepare`` forms the diagonal at the substep start, with the body
    contact's stiffness at particles pressed at the inertial targets ``y``, and the corrections
    keep it; without it each correction forms the diagonal at the positions it corrects."""
    from sim.cloth.self_contact import disabled_data

    wp = warp()
    v, f = grid(21, 31, 0.4, 0.6)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(), pinned=np.arange(21))
    m = b.finalize(device)
    x = np.asarray(v, dtype=np.float64)
    n = m.particle_count
    rng = np.random.default_rng(7)
    active = (rng.uniform(size=n) < 0.4).astype(np.int32)
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    y = x - 0.03 * normal  # the inertial targets sink 1 cm under the contact planes
    h = 1.0 / 420.0
    sc = disabled_data(device)
    xw = wp.array(x.astype(np.float32), dtype=wp.vec3, device=device)
    snap = wp.zeros_like(xw)
    bodies = wp.zeros(1, dtype=wp.uint64, device=device)
    diags = {}
    for prefactor in (True, False):
        level = coarse_level(m, spacing=2, prefactor=prefactor)
        assert level.prefactor == prefactor
        _, yw, cp, cn, _, ca = level._particles
        yw.assign(y.astype(np.float32))
        cp.assign((x - 0.02 * normal).astype(np.float32))  # x is 2 cm out: pressed only at y
        cn.assign(normal.astype(np.float32))
        ca.assign(active)
        level.residual.zero_()
        level.prepare(h, sc)
        level.correct(h, xw, snap, sc, bodies)
        diags[prefactor] = level._diag.numpy()
    p = level.prolongation
    inertia = 1.0 / h**2 + level._air_damping / h
    scale = overshoot_guard(level, h)
    base = level._mass.numpy() * inertia / scale + level.templates[0].stiffness.diagonal()
    np.testing.assert_allclose(diags[False], base, rtol=1e-5)
    pressed = p.T @ (active * level._k_contact) / scale
    assert pressed.max() > 0.0
    np.testing.assert_allclose(diags[True], base + pressed, rtol=1e-5)
    np.testing.assert_array_equal(xw.numpy(), x.astype(np.float32))  # no residual: nothing moved


def test_band_solve_matches_a_dense_solve_for_every_instance(device):
    """Two instances of different templates in one model: the banded Cholesky of each coarse
    system ``K_c + diag`` gives numpy's dense solution."""
    wp = warp()
    b = ClothModelBuilder()
    v1, f1 = grid(11, 21, 0.25, 0.5)
    v2, f2 = grid(7, 9, 0.2, 0.2)
    b.add_cloth(v1, f1, STIFF, pinned=np.arange(11))
    b.add_cloth(v2 + 1.0, f2, ClothMaterialParams())
    m = b.finalize(device)
    level = coarse_level(m, spacing=2, prefactor=True)
    assert len(level.templates) == 2
    rng = np.random.default_rng(0)
    nc = level.node_count
    kc = [t.stiffness.toarray() for t in level.templates]
    dense = np.zeros((nc, nc))
    dense[:len(kc[0]), :len(kc[0])] = kc[0]
    dense[len(kc[0]):, len(kc[0]):] = kc[1]
    diag = np.diag(dense) + rng.uniform(1.0, 1e4, nc)  # mass / contact share: positive
    np.fill_diagonal(dense, diag)
    rhs = rng.normal(size=(nc, 3))
    level._diag.assign(diag.astype(np.float32))
    level._rhs.assign(rhs.astype(np.float32))
    # the block kernel on CUDA (sim.cloth.coarse_block), one thread per instance on the CPU
    assert (level.block_kernel is not None) == device.startswith("cuda")
    level.factor()
    level.solve()
    exact = np.linalg.solve(dense, rhs)
    np.testing.assert_allclose(level._dx.numpy(), exact, rtol=2e-3, atol=2e-3 * np.abs(exact).max())
    assert_split_equals_whole_block_solve(level, device)
    if level.block_kernel is not None:
        serial = wp.zeros_like(level._dx)
        wp.launch(band_solve_kernel, dim=2, inputs=[level._rhs, level._diag, *level._inst, level._order,
                                                    level._band_k],
                  outputs=[level._band, level._y, serial], device=device)
        np.testing.assert_allclose(serial.numpy(), exact, rtol=2e-3, atol=2e-3 * np.abs(exact).max())


def assert_split_equals_whole_block_solve(level, device):
    """On CUDA with two levels and ``prefactor`` ``solve`` substitutes with ``factor``'s factor
    (two launches); the whole block solve (one launch) must give the same floats
    (``coarse_block``)."""
    if level.block_kernel is None:
        return
    assert level.substitute_kernel is not None and level.factor_kernel is not None
    wp = warp()
    whole = wp.zeros_like(level._dx)
    wp.launch_tiled(level.block_kernel, dim=[level.model.instance_count], block_dim=level.block_threads,
                    inputs=[level._rhs, level._diag, *level._inst, level._order, level._band_k],
                    outputs=[whole], device=device)
    np.testing.assert_array_equal(level._dx.numpy(), whole.numpy())


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
        level = coarse_level(m, spacing=2, levels=0, smoothing=smoothing)
        big, small = level.templates
        assert level.levels == 3 and big.inner is not None and small.inner is None
        nc, n1 = level.node_count, len(big.mass)
        rng = np.random.default_rng(5)
        inertia = (30.0 * 14) ** 2
        mass = level._mass.numpy()
        centres = np.concatenate([np.asarray(t.prolongation.T @ v) / np.asarray(t.prolongation.sum(0)).T
                                  for t, v in ((big, v1), (small, v2))])
        contact = np.where(centres[:, 0] > 0.6, 20.0, 0.0) * mass * inertia  # a pressed patch
        diag = level._kdiag.numpy() + mass * inertia + contact
        rhs = np.sin(3.0 * centres) + 0.1 * rng.normal(size=(nc, 3))  # a smooth load plus noise
        level._rhs.assign(rhs.astype(np.float32))
        level._diag.assign(diag.astype(np.float32))
        level.solve()
        ref, a = two_grid_reference(level.templates, rhs, diag, smoothing)
        np.testing.assert_allclose(level._dx.numpy(), ref, rtol=1e-3, atol=1e-3 * np.abs(ref).max())
        exact = np.linalg.solve(a, rhs)
        rel = []
        for rows in (np.arange(n1), np.arange(n1, nc)):
            e, sub = (ref - exact)[rows], a[np.ix_(rows, rows)]
            rel.append(np.sqrt(np.sum(e * (sub @ e)) / np.sum(exact[rows] * (sub @ exact[rows]))))
        assert rel[1] < 1e-10  # the small sheet: its own inner level, solved exactly
        errors.append(rel[0])
    assert 1e-3 < errors[1] < errors[0] < 0.15


@pytest.mark.parametrize("levels", [2, 3])
def test_coarse_correction_converges_far_further_per_sweep(device, levels):
    """One stiff implicit step of the long strip: 20 sweeps with a coarse correction before
    every second sweep end an order of magnitude closer to the converged step than 20 plain
    sweeps; pins stay put; a single correction before the first sweep already helps. The same
    with three levels (the coarse system solved by the two-grid cycle, not exactly)."""
    m, v = strip(device)

    def step(iterations: int, sweeps=()) -> np.ndarray:
        cfg = VBDConfig(substeps=1, iterations=iterations, air_damping=0.0, coarse_sweeps=sweeps,
                        coarse_levels=levels)
        solver = SolverVBD(m, cfg)
        assert solver.coarse is None or solver.coarse.levels == levels
        return simulate(m, solver, m.control(), 1, 1.0 / 30.0)[-1]

    ref = step(200, tuple(range(1, 200, 2)))
    plain = np.abs(step(20) - ref).max()
    coarse = step(20, tuple(range(1, 20, 2)))
    assert plain > 5e-3  # far from converged: the comparison means something
    assert np.abs(coarse - ref).max() < 0.1 * plain
    assert np.abs(step(20, (0,)) - ref).max() < 0.2 * plain
    np.testing.assert_array_equal(coarse[:11], v[:11])
    # the converged step is the same with and without corrections (they change the path only)
    np.testing.assert_allclose(step(3000), ref, atol=0.15 * plain)


def _denim_sheet_frames(device, gravity: float, frames: int, **config) -> tuple[np.ndarray, np.ndarray]:
    """Positions per frame of a 21 x 41 denim sheet of 5.5 mm edges (a fine garment's,
    ``fine_denim_sheet``) hanging from its pinned top row, at rest to start, under ``gravity``
    [m/s^2], stepped at 30 fps with a coarse correction before the second of 5 sweeps and
    ``config``; and its rest positions."""
    m, v = fine_denim_sheet(device, gravity)
    solver = SolverVBD(m, VBDConfig(iterations=5, coarse_sweeps=(1,), **config))
    control = m.control()
    control.pin_targets.assign(v)
    return simulate(m, solver, control, frames, 1.0 / 30.0), v


@pytest.mark.parametrize("spacing, levels", [(2, 2), (3, 2), (2, 3)])
def test_a_damped_sheet_with_no_load_stays_at_rest(device, spacing, levels):
    """Nothing acts on a flat sheet at rest without gravity, so it must stay at rest: the coarse
    correction may only remove error, never amplify round-off. Denim's strain-rate damping makes
    the sweeps' membrane Hessian ``1 + k_d/h`` = 2.1 times the elastic one at 12 substeps; with
    the coarse system holding the elastic stiffness alone (``coarse_guard`` off, until session
    51) each correction overshot by that factor (times up to 1.25 more in a dilation) in the
    stiff modes of small aggregates, and the sheet left rest by itself within 15 frames, at
    metres per second. With the overshoot guard (at most 1.8) it stays within round-off, and at
    24 substeps under gravity (the old coarse system gave NaN) it hangs as it rests."""
    layout = {"coarse_spacing": spacing, "coarse_levels": levels}
    still, rest = _denim_sheet_frames(device, 0.0, 15, substeps=12, **layout)
    assert np.abs(still - rest).max() < 1e-5
    old, _ = _denim_sheet_frames(device, 0.0, 15, substeps=12, coarse_guard=False, **layout)
    assert not np.all(np.isfinite(old)) or np.abs(old - rest).max() > 1e-3
    hanging, _ = _denim_sheet_frames(device, 9.81, 15, substeps=24, **layout)
    assert np.all(np.isfinite(hanging)) and np.abs(hanging[-5:] - rest).max() < 1e-3


@pytest.mark.parametrize("levels, prefactor", [(2, False), (3, False), (2, True)])
def test_coarse_correction_keeps_cloth_on_a_sphere_outside(device, levels, prefactor):
    """The contact penalty is part of the coarse system: corrections do not pull cloth resting
    on a sphere into it (without it they did, and blew the t-shirt up), and a correction moves
    no cloth on the body deeper into it than it is or than its 5 mm thickness: the cloth stays
    more than half its thickness out (without that clamp it came within 0.3 mm). The same with
    three levels, whose inner level takes the contact terms through its Galerkin product, and
    with ``coarse_prefactor`` (the contact stiffness at the inertial targets, the factor from
    the substep start: the system of both corrections of a substep)."""
    m, _, control, body, _ = drop_on_sphere(device)
    solver = SolverVBD(m, VBDConfig(substeps=5, iterations=5, coarse_sweeps=(0, 2), coarse_levels=levels,
                                    coarse_prefactor=prefactor))
    assert solver.coarse.levels == levels and solver.coarse.prefactor == prefactor
    x = simulate(m, solver, control, 30, 1.0 / 30.0)
    assert np.isfinite(x).all()
    for frame in x:
        assert body.signed_distance(frame).min() > 0.0025
    top = np.abs(x[-1, :, 0]) + np.abs(x[-1, :, 2]) < 0.05
    assert top.any()  # the cloth is still on the sphere's top (a cloth thrown off it fails here)
    assert np.all(x[-1, top, 1] > 0.19)
    assert np.all(x[-1, top, 1] < 0.215)


def test_coarse_config_is_checked():
    for bad in ({"iterations": 4, "coarse_sweeps": (4,)}, {"coarse_sweeps": (1, 1)},
                {"coarse_sweeps": (-1,)}, {"coarse_spacing": -1},
                {"coarse_sweeps": (1,), "chebyshev_rho": 0.5}, {"coarse_levels": 1}, {"coarse_levels": 4},
                {"coarse_smoothing": 0}):
        with pytest.raises(ValueError, match="coarse"):
            VBDConfig(**bad)
    assert VBDConfig(coarse_sweeps=[0, 3]).coarse_sweeps == (0, 3)


@pytest.mark.parametrize(("bounds", "speed"), [(True, 3.0), (False, 1.0)])
@pytest.mark.parametrize("sweeps", [(0, 2, 4), (0, 1, 2, 3, 4)])
def test_coarse_corrections_carry_no_layer_through_another(device, sweeps, bounds, speed):
    """A sheet dropped onto a pinned one (``test_self_contact``'s stacked layers) with corrections
    before the sweeps. The self-contact penalty is part of the coarse system at particles with
    pairs (without it the residual's contact forces met no stiffness there and the sheets blew
    up to metres in 4 frames), the prolongated moves are held by the sweeps' displacement bounds
    (``bounds``, 3 m/s) and capped near pairs (penalty only, 1 m/s, the speed the penalty alone
    holds): the sheets never cross and the top one lands on the other."""
    x, faces, nv, n = stacked_layers(device, True, bounds=bounds, speed=speed, frames=12 if bounds else 20,
                                     coarse_sweeps=sweeps)
    assert_layers_kept_apart(x, faces, nv, n, device, landed=0.03)


def assert_layers_kept_apart(x, faces, nv, n, device, landed: float) -> None:
    """The stacked layers' run ``x``: finite, never crossing, the top sheet always above the
    bottom one at the centre and at most ``landed`` [m] above it at the end."""
    assert np.all(np.isfinite(x))
    assert np.all(self_intersections(x, faces, device=device) == 0)
    gap = _center_gap(x, nv, n)
    assert np.all(gap > 0.0)
    assert gap[-1] < landed


@pytest.mark.parametrize("side, spacing, task_per_thread", [(71, 3, True), (81, 2, False)])
def test_block_solve_matches_a_dense_solve_at_garment_size(side, spacing, task_per_thread):
    """CUDA: the block kernel on a 5k-6.5k-vertex sheet's coarse level (hundreds of nodes, a band
    tens wide) against numpy's dense solve, on both of its paths: one task per thread for the
    whole factorization (band 19), and threads looping over the entries (band 47, whose 1,128
    entries under a column outnumber a block's 1,024 threads)."""
    if "cuda" not in DEVICES:
        pytest.skip("no CUDA device here")
    from sim.cloth.coarse_block import threads

    v, f = grid(side, side, 1.0, 1.0)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams())
    m = b.finalize("cuda")
    level = coarse_level(m, spacing=spacing, prefactor=True)
    assert level.block_kernel is not None
    nc = level.node_count
    assert nc > 250
    width = level.templates[0].band.shape[1] - 1
    assert width > 15
    assert (level.block_threads >= width * (width + 1) // 2) == task_per_thread
    assert level.block_threads == threads(width)
    rng = np.random.default_rng(1)
    dense = level.templates[0].stiffness.toarray()
    diag = np.diag(dense) + rng.uniform(1.0, 1e3, nc)
    np.fill_diagonal(dense, diag)
    rhs = rng.normal(size=(nc, 3))
    level._diag.assign(diag.astype(np.float32))
    level._rhs.assign(rhs.astype(np.float32))
    level.factor()
    level.solve()
    exact = np.linalg.solve(dense, rhs)
    np.testing.assert_allclose(level._dx.numpy(), exact, rtol=2e-3, atol=2e-3 * np.abs(exact).max())
    assert_split_equals_whole_block_solve(level, "cuda")


def test_early_diagonal_takes_the_previous_substeps_pairs(device):
    """``coarse_early``: the velocity kernel flags the particles with pairs at a substep's end,
    and the next substep's ``prepare`` (beside the detection) gives exactly those the
    self-contact stiffness: the step's diagonal is ``prepare``'s from the flags it found, the
    flags give the same diagonal as the pair lists they came from, bit for bit, and without
    them the diagonal is smaller by ``P^T`` of the stiffness at exactly the flagged particles (over
    the overshoot guard, as the whole system)."""
    from tests.test_cloth_solver import draped_layers_in_contact

    wp = warp()
    m, *start = draped_layers_in_contact(device)
    h = 1.0 / 120.0
    solver = SolverVBD(m, VBDConfig(substeps=1, iterations=4, self_contact=True, coarse_sweeps=(1,),
                                    coarse_prefactor=True, coarse_early=True))
    s = m.state()
    s.positions.assign(start[0])
    s.velocities.assign(start[1])
    control = m.control()
    solver.step(s, s, control, h)
    sc = solver.self_contact.data
    counts = sc.vt_count.numpy() + sc.tv_total.numpy() + sc.ee_total.numpy()
    flags = solver._pair_flags.numpy()
    assert flags.shape == (m.particle_count,) and set(np.unique(flags)) == {0, 1}
    np.testing.assert_array_equal(flags, (counts > 0).astype(np.int32))
    # the next step's diagonal is made from the flags it starts with, whatever its own pairs:
    # flag every other particle instead, step, and form the diagonal from those by hand
    planted = np.zeros_like(flags)
    planted[::2] = 1
    solver._pair_flags.assign(planted)
    solver.step(s, s, control, h)
    level = solver.coarse
    stepped = level._diag.numpy().copy()
    level.prepare(h, sc, wp.array(planted, dtype=wp.int32, device=device))
    np.testing.assert_array_equal(level._diag.numpy(), stepped)
    diags = {}
    flags = solver._pair_flags.numpy()  # the second step's pairs
    assert flags.any()
    for name, pair_flags in (("lists", None), ("flags", solver._pair_flags),
                             ("none", wp.zeros_like(solver._pair_flags))):
        level.prepare(h, sc, pair_flags)
        diags[name] = level._diag.numpy().copy()
    np.testing.assert_array_equal(diags["flags"], diags["lists"])
    assert not np.array_equal(stepped, diags["flags"])  # the planted flags are not the pairs
    added = level.prolongation.T @ (flags * sc.stiffness) / overshoot_guard(level, h)
    assert added.max() > 0.0
    np.testing.assert_allclose(diags["lists"] - diags["none"], added, rtol=1e-4, atol=1e-6 * added.max())
    # off (the solver default): no flags written, the diagonal from the lists
    _, plain = one_step_from(m, start, coarse_sweeps=(1,), coarse_prefactor=True)
    assert plain._pair_flags.shape[0] == 0


def test_early_coarse_corrections_carry_no_layer_through_another(device):
    """The stacked layers of ``test_coarse_corrections_carry_no_layer_through_another`` with the
    coarse system prepared beside the detection (``coarse_early``, the CUDA job default since
    session 42): the diagonal lags the pairs by a substep, and still the sheets never cross
    and the top one lands on the other."""
    x, faces, nv, n = stacked_layers(device, True, frames=12, coarse_sweeps=(0, 2, 4), coarse_prefactor=True,
                                     coarse_early=True)
    # landed: within a third of the 3 cm drop (with the flags zeroed, i.e. no self-contact
    # stiffness in the coarse diagonal, the top sheet bounced to 5.4 cm and ended at 2.9)
    assert_layers_kept_apart(x, faces, nv, n, device, landed=0.01)
