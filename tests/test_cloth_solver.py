"""Cloth solver (sim/cloth): the vertex colouring, and physics with exact or analytic answers
(free fall, hanging strip, pins, body contact, batching, determinism); the solve's layouts and
streams take the same step."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth import (
    BodyCollider,
    ClothMaterialParams,
    ClothModelBuilder,
    CoarseConfig,
    KernelLayout,
    SelfContactConfig,
    SolverVBD,
    Stepping,
    VBDConfig,
)
from sim.cloth.coloring import (
    _tabu_recolor,
    compact_coloring,
    dsatur_coloring,
    greedy_coloring,
    validate_coloring,
    vertex_adjacency,
    wheel_bound,
)
from sim.cloth.model import dihedral_angles
from sim.cloth.topology import build_hinges
from sim.device import warp
from sim.geometry.primitives import uv_sphere

G = 9.81


def grid(nx: int, ny: int, width: float, length: float, *,
         plane: str = "xy") -> tuple[np.ndarray, np.ndarray]:
    """Regular triangulated sheet: x in [0, width], second axis from 0 to -length (xy) or
    0 to +length (xz, horizontal). Faces point to +z (xy) or +y (xz)."""
    xs = np.linspace(0.0, width, nx)
    ys = np.linspace(0.0, length, ny)
    X, Y = np.meshgrid(xs, ys)
    if plane == "xy":
        v = np.stack([X.ravel(), -Y.ravel(), np.zeros(X.size)], axis=1)
    else:
        v = np.stack([X.ravel(), np.zeros(X.size), Y.ravel()], axis=1)
    f = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a = j * nx + i
            b, c = a + 1, a + nx
            f += [(a, c, b), (b, c, c + 1)]
    return v.astype(np.float32), np.asarray(f, dtype=np.int32)


def plain_config(substeps: int, iterations: int, air_damping: float = 0.5, **sections) -> VBDConfig:
    """Solver settings of ``substeps`` x ``iterations`` without self-contact, coarse correction
    or fast math, unless ``sections`` (``VBDConfig`` sections) say otherwise."""
    base = {"stepping": Stepping(substeps, iterations, air_damping),
            "self_contact": SelfContactConfig(enabled=False), "coarse": CoarseConfig(sweeps=()),
            "layout": KernelLayout(fast_math=False)}
    return VBDConfig(**{**base, **sections})


def simulate(model, solver, control, steps: int, dt: float, *, body=None, body_path=None):
    state = model.state()
    frames = []
    for k in range(steps):
        if body is not None and body_path is not None:
            body.set_frame(body_path(k), body_path(k + 1))
        solver.step(state, state, control, dt)
        frames.append(state.positions.numpy().copy())
    return np.stack(frames)


def test_hinges_and_coloring():
    v, f = grid(6, 5, 0.5, 0.4)
    hinges = build_hinges(f)
    assert len(hinges) == (3 * len(f) - (2 * 5 + 2 * 4)) // 2  # interior edges
    np.testing.assert_allclose(dihedral_angles(v, hinges), 0.0, atol=1e-6)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams())
    m = b.finalize("cpu")
    no_hinges = np.zeros((0, 4), np.int64)
    assert validate_coloring(vertex_adjacency(len(v), f, no_hinges), m.colors)
    # the hinges' opposite vertices may share a colour: bits 2-5 of vertex_edge_local say which
    # of a hinge's vertices have the vertex's colour (the solve reads those from its snapshot)
    offsets = m.vertex_edge_offsets.numpy()
    ids, packed = m.vertex_edge_ids.numpy(), m.vertex_edge_local.numpy()
    shared = 0
    for i in range(len(v)):
        for k in range(offsets[i], offsets[i + 1]):
            q = hinges[ids[k]]
            local = packed[k] & 3
            assert q[local] == i
            expect = sum(1 << j for j in range(4) if j != local and m.colors[q[j]] == m.colors[i])
            assert packed[k] >> 2 == expect
            if expect:
                assert local in (0, 1) and expect == 1 << (1 - local)  # only the other opposite vertex
                shared += 1
    assert shared > 0  # the case the snapshot serves occurs


@pytest.mark.slow
def test_compact_coloring_needs_fewer_colours_than_greedy_on_a_tshirt():
    """Every colour is one launch per sweep: the t-shirt template's triangle graph (the model's
    colouring; with the hinge diagonals too it needs 6) gets 4 colours where
    degree-ordered greedy needs 6."""
    from sim.bodies.default import load_default_body
    from sim.garments import make_garment

    g = make_garment("t_shirt", load_default_body(), None, resolution=0.04)
    nb = vertex_adjacency(len(g.rest_vertices), g.faces, np.zeros((0, 4), np.int64))
    greedy, dsatur, compact = greedy_coloring(nb), dsatur_coloring(nb), compact_coloring(nb)
    for c in (greedy, dsatur, compact):
        assert validate_coloring(nb, c)
    assert compact.max() + 1 == 4 < greedy.max() + 1
    assert compact.max() <= dsatur.max()
    sizes = np.bincount(compact)
    assert np.all(sizes > 0) and np.all(np.diff(sizes) <= 0)  # no empty launch, largest first
    np.testing.assert_array_equal(compact, compact_coloring(nb))  # deterministic
    # a clashing colouring is caught
    bad = compact.copy()
    v = int(np.flatnonzero(compact == 0)[0])
    bad[nb[v][0]] = bad[v]
    assert not validate_coloring(nb, bad)


@pytest.mark.slow
def test_colourings_with_fewer_colours_mark_their_same_coloured_corners():
    """``max_colors`` below what a proper colouring needs: the t-shirt's 4 colours become 3 with
    few same-coloured neighbours (TabuCol's best), deterministically, and the model marks every
    triangle corner that has its vertex's colour in ``vertex_tri_local`` (bits 2-4), where the
    solve reads it from the sweep's snapshot; with a proper colouring no corner is marked."""
    from sim.bodies.default import load_default_body
    from sim.garments import make_garment

    g = make_garment("t_shirt", load_default_body(), None, resolution=0.04)
    nb = vertex_adjacency(len(g.rest_vertices), g.faces, np.zeros((0, 4), np.int64))
    three = compact_coloring(nb, max_colors=3)
    np.testing.assert_array_equal(three, compact_coloring(nb, max_colors=3))
    edges = sum(len(x) for x in nb) // 2
    conflicts = sum(int(np.sum(three[x] == three[v])) for v, x in enumerate(nb)) // 2
    assert three.max() == 2 and 0 < conflicts < 0.05 * edges
    np.testing.assert_array_equal(compact_coloring(nb, max_colors=4), compact_coloring(nb))  # enough
    for max_colors in (0, 3):
        b = ClothModelBuilder(max_colors=max_colors)
        b.add_cloth(g.rest_vertices, g.faces, ClothMaterialParams())
        m = b.finalize("cpu")
        assert m.color_count == (4 if max_colors == 0 else 3)
        offsets, ids = m.vertex_tri_offsets.numpy(), m.vertex_tri_ids.numpy()
        packed = m.vertex_tri_local.numpy()
        owner = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
        corners = g.faces[ids]
        local = packed & 3
        assert np.all(corners[np.arange(len(ids)), local] == owner)
        same = (m.colors[corners] == m.colors[owner][:, None]) & (np.arange(3)[None, :] != local[:, None])
        np.testing.assert_array_equal(packed >> 2, (same * np.array([1, 2, 4])).sum(axis=1))
        assert (packed >> 2).any() == (max_colors == 3)
    with pytest.raises(ValueError, match="max_colors"):
        ClothModelBuilder(max_colors=1)


def _fan(n: int) -> np.ndarray:
    """A closed fan of n triangles round vertex 0 (rim 1..n): vertex 0's link is an n-cycle."""
    return np.array([(0, 1 + i, 1 + (i + 1) % n) for i in range(n)], np.int64)


def test_wheel_bound_is_a_lower_bound_and_met_by_compact_colouring():
    """An interior vertex of odd valence is the hub of an odd wheel: 4 colours, as the exact
    search (TabuCol) confirms by failing at 3; even wheels, open fans and a grid whose interior
    vertices all have valence 6 are 3-colourable; stopping at the bound changes no colouring."""
    assert wheel_bound(6, _fan(5)) == 4
    assert _tabu_recolor(vertex_adjacency(6, _fan(5), np.zeros((0, 4))), np.zeros(6, np.int32), 3,
                         max_moves=5000, seed=0) is None
    assert wheel_bound(7, _fan(6)) == 3
    assert compact_coloring(vertex_adjacency(7, _fan(6), np.zeros((0, 4)))).max() + 1 == 3
    assert wheel_bound(6, _fan(5)[:4]) == 3  # open: vertex 0 is on the border
    v, f = grid(8, 6, 1.0, 1.0)
    assert wheel_bound(len(v), f) == 3 and wheel_bound(3, np.array([[0, 1, 2]])) == 3
    odd = np.concatenate([f, _fan(5) + len(v)])  # a grid beside an odd wheel
    nb = vertex_adjacency(len(v) + 6, odd, np.zeros((0, 4)))
    np.testing.assert_array_equal(compact_coloring(nb, floor=wheel_bound(len(v) + 6, odd)),
                                  compact_coloring(nb))


def test_tabu_recolor_repairs_a_colouring_down_to_the_chromatic_number():
    """The hinged grid contains K4 (a triangle plus the opposite vertex of a hinge), so it needs
    4 colours; TabuCol finds a 4-colouring from a random 7-colouring, and reports failure for 3."""
    v, f = grid(12, 9, 1.0, 1.0)
    nb = vertex_adjacency(len(v), f, build_hinges(f))
    start = np.random.default_rng(3).integers(0, 7, len(v)).astype(np.int32)
    four = _tabu_recolor(nb, start, 4, max_moves=20000, seed=0)
    assert four is not None and validate_coloring(nb, four) and four.max() == 3
    assert _tabu_recolor(nb, start, 3, max_moves=2000, seed=0) is None


# --- physics -------------------------------------------------------------------------------

@pytest.mark.parametrize("mesh", ["grid", "lone triangle"])
def test_free_fall_matches_implicit_euler_and_half_g_t2(device, mesh):
    """A rigid fall; a lone triangle has no hinges (the solve reads placeholders for them)."""
    v, f = grid(6, 6, 0.5, 0.5)
    if mesh == "lone triangle":
        v, f = v[[0, 1, 6]], np.array([[0, 1, 2]], np.int32)
    b = ClothModelBuilder()
    # the material's damping acts on strain and bending rates only: a rigid fall is undamped
    b.add_cloth(v, f, ClothMaterialParams(damping=5e-3, bending=1e-4))
    m = b.finalize(device)
    cfg = plain_config(4, 3, air_damping=0.0)
    steps, dt = 12, 1.0 / 30.0
    x = simulate(m, SolverVBD(m, cfg), m.control(), steps, dt)[-1]
    n = steps * cfg.stepping.substeps
    h = dt / cfg.stepping.substeps
    drop_discrete = G * h * h * n * (n + 1) / 2  # implicit Euler: x_n = x_0 - g h^2 n(n+1)/2
    t = steps * dt
    np.testing.assert_allclose(v[:, 1] - x[:, 1], drop_discrete, rtol=1e-4)
    np.testing.assert_allclose(x[:, [0, 2]], v[:, [0, 2]], atol=1e-5)  # rigid translation: no elastic force
    np.testing.assert_allclose(v[:, 1] - x[:, 1], 0.5 * G * t * t, rtol=1.5 / n)  # O(h) from 1/2 g t^2


def test_air_damping_follows_the_implicit_drag_law(device):
    """With air damping alpha a falling sheet's velocity follows implicit Euler of
    dv/dt = g - alpha v: v_{n+1} = (v_n + h g) / (1 + alpha h), towards terminal g/alpha."""
    v, f = grid(5, 5, 0.3, 0.3, plane="xz")
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(damping=2e-3))
    m = b.finalize(device)
    alpha, substeps, dt, steps = 3.0, 5, 1.0 / 30.0, 20
    solver = SolverVBD(m, plain_config(substeps, 3, air_damping=alpha))
    state = m.state()
    for _ in range(steps):
        solver.step(state, state, m.control(), dt)
    h = dt / substeps
    vel = 0.0
    for _ in range(steps * substeps):
        vel = (vel + h * G) / (1.0 + alpha * h)
    np.testing.assert_allclose(-state.velocities.numpy()[:, 1], vel, rtol=1e-4)
    assert 0.5 * G / alpha < vel < G / alpha


def hanging_elongation(L: float, rho: float, mu: float, lam: float, top_layers: float = 1.0) -> float:
    """Analytic elongation [m] of a hanging strip of the co-rotated linear membrane under its own
    weight (uniaxial, laterally free): the lateral stretch ``s_2 - 1 = -lam / (2 mu + lam) (s -
    1)`` leaves the nominal stress ``E (s - 1) = rho g (L - Y)`` at rest depth Y below the pin,
    ``E = 4 mu (mu + lam) / (2 mu + lam)`` (2D Young's modulus). With ``top_layers`` n, the
    upper half is n layers: n times the mass and stiffness, so there n E (s - 1) carries the
    weight below, rho g (n (L/2 - Y) + L/2)."""
    E = 4 * mu * (mu + lam) / (2 * mu + lam)
    Y = np.linspace(0.0, L, 2001)
    n = np.where(Y < L / 2, top_layers, 1.0)
    load = rho * G * np.where(Y >= L / 2, L - Y, top_layers * (L / 2 - Y) + L / 2)
    return float(np.trapezoid(load / (n * E), Y))


def hanging_strip(device, mat, max_colors: int = 0, top_layers: float = 1.0):
    """A 0.1 x 1 m strip (3 x 21 vertices) pinned along its top edge, its upper half of
    ``top_layers`` layers: (model, rest vertices)."""
    v, f = grid(3, 21, 0.1, 1.0)
    b = ClothModelBuilder(max_colors=max_colors)
    layers = np.where(v[f].mean(axis=1)[:, 1] > -0.5, top_layers, 1.0)
    b.add_cloth(v, f, mat, pinned=np.arange(3), face_layers=layers)
    return b.finalize(device), v


@pytest.mark.slow
def test_hanging_strip_reaches_analytic_stretch(device):
    L, nx = 1.0, 3
    mat = ClothMaterialParams(density=0.2, mu=15.0, lam=10.0, bending=1e-7, damping=1e-3, friction=0.0)
    m, v = hanging_strip(device, mat)
    # the asymmetric triangulation makes the stretched strip sway; still air (alpha = 2/s) stops it
    cfg = plain_config(5, 10, air_damping=2.0)
    x = simulate(m, SolverVBD(m, cfg), m.control(), 150,
                 1.0 / 30.0)
    delta_sim = -(x[-1, -nx:, 1].mean()) - L
    delta = hanging_elongation(L, mat.density, mat.mu, mat.lam)
    assert 0.01 < delta < 0.05
    np.testing.assert_allclose(delta_sim, delta, rtol=0.01)
    # at rest: the last two frames agree
    np.testing.assert_allclose(x[-1], x[-2], atol=2e-4)


@pytest.mark.slow
def test_a_strip_doubled_in_its_upper_half_hangs_at_the_layered_stretch(device):
    """Two layers (a hem's) over the upper half: twice the weight there, carried by twice the
    stiffness. The strip hangs at the analytic elongation of that layering, a quarter less than the
    plain strip's (``hanging_elongation`` with ``top_layers``)."""
    L, nx = 1.0, 3
    mat = ClothMaterialParams(density=0.2, mu=15.0, lam=10.0, bending=1e-7, damping=1e-3, friction=0.0)
    m, v = hanging_strip(device, mat, top_layers=2.0)
    cfg = plain_config(5, 10, air_damping=2.0)
    x = simulate(m, SolverVBD(m, cfg), m.control(), 150, 1.0 / 30.0)
    delta_sim = -(x[-1, -nx:, 1].mean()) - L
    layered = hanging_elongation(L, mat.density, mat.mu, mat.lam, top_layers=2.0)
    plain = hanging_elongation(L, mat.density, mat.mu, mat.lam)
    assert layered < 0.92 * plain
    np.testing.assert_allclose(delta_sim, layered, rtol=0.01)
    # the lower half stretches as the plain strip's lower half does: it carries the same weight
    # (a plain strip of half the length: the same weight below every point)
    middle = np.flatnonzero(np.abs(v[:, 1] + 0.5) < 1e-6)
    lower_sim = x[-1, middle, 1].mean() - x[-1, -nx:, 1].mean() - 0.5
    np.testing.assert_allclose(lower_sim, hanging_elongation(L / 2, mat.density, mat.mu, mat.lam), rtol=0.02)
    np.testing.assert_allclose(x[-1], x[-2], atol=2e-4)


@pytest.mark.slow
@pytest.mark.parametrize("max_colors", [2])
def test_hanging_strip_with_jacobi_couplings_reaches_the_same_stretch(device, max_colors):
    """Same-coloured neighbours (a 2-colouring of the strip leaves a third of its edges inside a
    colour) change how the sweeps get to the equilibrium, not the equilibrium: the strip of
    ``test_hanging_strip_reaches_analytic_stretch`` hangs at the analytic elongation."""
    L, nx = 1.0, 3
    mat = ClothMaterialParams(density=0.2, mu=15.0, lam=10.0, bending=1e-7, damping=1e-3, friction=0.0)
    m, v = hanging_strip(device, mat, max_colors)
    assert m.color_count == max_colors and (m.vertex_tri_local.numpy() >> 2).any()
    cfg = plain_config(5, 10, air_damping=2.0)
    x = simulate(m, SolverVBD(m, cfg), m.control(), 150, 1.0 / 30.0)
    assert np.isfinite(x).all()
    delta_sim = -(x[-1, -nx:, 1].mean()) - L
    np.testing.assert_allclose(delta_sim, hanging_elongation(L, mat.density, mat.mu, mat.lam), rtol=0.01)
    np.testing.assert_allclose(x[-1], x[-2], atol=2e-4)


def test_pinned_vertices_stay_exactly_put(device):
    v, f = grid(8, 8, 0.5, 0.5, plane="xz")
    pins = np.array([0, 7, 3])
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(), pinned=pins)
    m = b.finalize(device)
    x = simulate(m, SolverVBD(m, plain_config(3, 3)), m.control(), 15, 1.0 / 30.0)
    np.testing.assert_array_equal(x[:, pins], np.broadcast_to(v[pins], x[:, pins].shape))
    assert x[-1, :, 1].min() < -0.2  # the rest swings down


def drop_on_sphere(device, steps: int = 30, contact_offset: float = 0.0):
    v, f = grid(13, 13, 0.6, 0.6, plane="xz")
    v = v + np.array([-0.3, 0.25, -0.3], dtype=np.float32)
    b = ClothModelBuilder(contact_offset=contact_offset)
    b.add_cloth(v, f, ClothMaterialParams(bending=1e-5, friction=0.5, thickness=0.005))
    m = b.finalize(device)
    sv, sf = uv_sphere(0.2)
    body = BodyCollider(sv, sf, device=device)
    control = m.control()
    control.set_body(0, body)
    solver = SolverVBD(m, plain_config(5, 5))
    return m, solver, control, body, sv


def test_contact_offset_keeps_the_cloth_that_much_farther_from_the_body(device):
    rest = {}
    for offset in (0.0, 0.006):
        m, solver, control, body, _ = drop_on_sphere(device, contact_offset=offset)
        np.testing.assert_allclose(m.instance_thickness.numpy(), 0.005 + offset, rtol=1e-6)
        x = simulate(m, solver, control, 30, 1.0 / 30.0)[-1]
        top = np.abs(x[:, 0]) + np.abs(x[:, 2]) < 0.05
        rest[offset] = body.signed_distance(x[top]).mean()
    # the penalty contact rests a little inside its distance; the offset shifts it by itself
    assert rest[0.006] - rest[0.0] == pytest.approx(0.006, abs=0.0015)


def test_cloth_dropped_on_sphere_settles_outside(device):
    m, solver, control, body, _ = drop_on_sphere(device)
    x = simulate(m, solver, control, 30, 1.0 / 30.0)
    for frame in x:
        assert body.signed_distance(frame).min() > 0.0
    top = np.abs(x[-1, :, 0]) + np.abs(x[-1, :, 2]) < 0.05
    # resting on top of the (polyhedral, radius 0.2 m) sphere at about the thickness
    assert top.any()
    assert np.all(x[-1, top, 1] > 0.19)
    assert np.all(x[-1, top, 1] < 0.215)


def test_fast_sphere_through_hanging_cloth_does_not_tunnel(device):
    """A sphere at 5 m/s hits a hanging curtain; no cloth vertex is ever inside it."""
    v, f = grid(15, 15, 0.8, 0.8)
    v = v + np.array([-0.4, 1.0, 0.0], dtype=np.float32)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(mu=200.0, lam=100.0, friction=0.3, thickness=0.005),
                pinned=np.arange(15))
    m = b.finalize(device)
    sv, sf = uv_sphere(0.12)
    start = np.array([0.0, 0.6, -0.3], dtype=np.float32)
    dt, speed = 1.0 / 30.0, 5.0

    def path(k):
        return sv + start + np.array([0.0, 0.0, min(speed * dt * k, 0.6)], dtype=np.float32)

    body = BodyCollider(path(0), sf, device=device)
    control = m.control()
    control.set_body(0, body)
    solver = SolverVBD(m, plain_config(10, 5))
    state = m.state()
    for k in range(8):
        body.set_frame(path(k), path(k + 1))
        solver.step(state, state, control, dt)
        assert body.signed_distance(state.positions).min() > 0.0, f"frame {k}: a vertex is inside the body"
    x = state.positions.numpy()
    # body ends at z = +0.3 (moved 0.6 m at 5 m/s): the curtain wraps round its front
    assert x[:, 2].max() > 0.3
    assert np.all(np.isfinite(x))


def test_determinism_bit_identical(device):
    runs = []
    for _ in range(2):
        m, solver, control, _, _ = drop_on_sphere(device)
        runs.append(simulate(m, solver, control, 6, 1.0 / 30.0))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_batched_instances_match_separate_runs(device):
    mat_a = ClothMaterialParams(mu=100.0, lam=50.0, bending=1e-5, friction=0.4)
    mat_b = ClothMaterialParams(density=0.3, mu=300.0, lam=80.0, bending=5e-5, damping=5e-3)
    va, fa = grid(9, 7, 0.4, 0.3, plane="xz")
    va = va + np.array([-0.2, 0.22, -0.15], dtype=np.float32)
    vb, fb = grid(6, 10, 0.3, 0.5)
    sv, sf = uv_sphere(0.2)
    cfg = plain_config(3, 4)

    def build(parts):
        b = ClothModelBuilder()
        for vv, ff, mat, pins in parts:
            b.add_cloth(vv, ff, mat, pinned=pins)
        m = b.finalize(device)
        control = m.control()
        body = BodyCollider(sv, sf, device=device)
        for i, (vv, *_rest) in enumerate(parts):
            if vv is va:
                control.set_body(i, body)
        return m, control

    part_a = (va, fa, mat_a, None)
    part_b = (vb, fb, mat_b, np.array([0, 5]))
    m, c = build([part_a, part_b])
    both = simulate(m, SolverVBD(m, cfg), c, 8, 1.0 / 30.0)
    for i, part in enumerate([part_a, part_b]):
        ms, cs = build([part])
        alone = simulate(ms, SolverVBD(ms, cfg), cs, 8, 1.0 / 30.0)
        np.testing.assert_array_equal(both[:, m.instance_slice(i)], alone)


def test_invalid_inputs_raise():
    v, f = grid(3, 3, 0.1, 0.1)
    with pytest.raises(ValueError, match="faces"):
        ClothModelBuilder().add_cloth(v, f + 100, ClothMaterialParams())
    with pytest.raises(ValueError, match="missing field 'density'"):
        ClothModelBuilder().add_cloth(v, f, object())
    with pytest.raises(ValueError, match="stepping.substeps"):
        Stepping(substeps=0)


def draped_layers_in_contact(device, max_colors: int = 0):
    """Two 12 x 12 sheets 6 mm apart, pinned at two corners, after 3 or more frames of draping
    into self-contact (the first frame from the third on where they are): (model, positions,
    velocities). ``max_colors``: the model's colouring (``ClothModelBuilder``)."""
    n = 12
    v, f = grid(n, n, 0.3, 0.3, plane="xz")
    x = np.concatenate([v, v + np.array([0.004, 0.006, 0.003], np.float32)])
    faces = np.concatenate([f, f + len(v)])
    b = ClothModelBuilder(max_colors=max_colors)
    b.add_cloth(x, faces, ClothMaterialParams(), pinned=[0, n - 1])
    m = b.finalize(device)
    first = SolverVBD(m, plain_config(4, 4, self_contact=SelfContactConfig()))
    state = m.state()
    for frame in range(12):
        first.step(state, state, m.control(), 1.0 / 30.0)
        if frame >= 2 and first.self_contact.data.pair_count.numpy().mean() > 0.5:
            break
    assert first.self_contact.data.pair_count.numpy().mean() > 0.5  # the layers are in contact
    return m, state.positions.numpy().copy(), state.velocities.numpy().copy()


def one_step_from(m, start, **sections):
    """Positions after one 1/120 s step (1 substep, 4 sweeps) from ``start`` (positions,
    velocities) with self-contact and the solver settings ``sections`` (``VBDConfig`` sections
    over ``plain_config``'s); and the solver."""
    solver = SolverVBD(m, plain_config(1, 4, **{"self_contact": SelfContactConfig(), **sections}))
    s = m.state()
    s.positions.assign(start[0])
    s.velocities.assign(start[1])
    solver.step(s, s, m.control(), 1.0 / 120.0)
    warp().synchronize()
    return s.positions.numpy().copy(), solver


def layout(**fields) -> dict[str, KernelLayout]:
    """``one_step_from``'s keywords for the ``KernelLayout`` of ``fields`` (without fast math
    unless they say so)."""
    return {"layout": KernelLayout(**{"fast_math": False, **fields})}


def test_the_solve_does_not_depend_on_its_lanes(device):
    """Every (lanes, particles per block) layout of the tiled solve and either gather (fused or
    split) computes the same Gauss-Seidel step: from one state of two draped sheets in
    self-contact, a step with the automatic layout (16 x 8 at this size), with 4 x 32 (the layout
    of large batches) and with 1 x 64 ends at the same positions to float32 round-off (the lanes
    and the gather only change the summation order). One step from a shared state: over several
    frames contact switching amplifies round-off into centimetres, which says nothing about the
    layouts. On the CPU every layout is one thread per particle: the steps must match exactly
    but for the gather, which orders a particle's sums by kind (split) or by item (fused)."""
    from sim.cloth.solver_vbd import AUTO_LANES_PARTICLES, auto_lanes

    assert auto_lanes(AUTO_LANES_PARTICLES - 1) == (16, 8) and auto_lanes(AUTO_LANES_PARTICLES) == (4, 32)
    m, *start = draped_layers_in_contact(device)
    layouts = ({}, {"lanes": 4, "particles_per_block": 32}, {"lanes": 1, "particles_per_block": 64},
               {"gather": "fused"}, {"gather": "split"},
               {"lanes": 4, "particles_per_block": 32, "gather": "fused"})
    out = [one_step_from(m, start, **layout(**fields))[0] for fields in layouts]
    moved = np.abs(out[0] - start[0]).max()
    assert moved > 1e-4  # the step did work
    for k, o in enumerate(out[1:], 1):
        exact = device == "cpu" and layouts[k].get("gather") != "fused"  # the CPU default: split
        np.testing.assert_allclose(o, out[0], atol=0.0 if exact else 1e-4 * moved, err_msg=str(layouts[k]))


def same_color_partner_records(solver) -> int:
    """Gather records of ``solver``'s last detection in which a partner vertex (not the record's
    owner) has the owner's colour: the pairs a Gauss-Seidel sweep could race on."""
    sc = solver.self_contact.data
    color = sc.particle_color.numpy()
    first, count = sc.pair_first.numpy(), sc.pair_count.numpy()
    verts = sc.pair_verts.numpy()
    n = 0
    for i in np.flatnonzero((first >= 0) & (count > 0)):
        q = verts[first[i]:first[i] + count[i]]
        n += int(((color[q] == color[i]) & (q != i)).any(axis=1).sum())
    return n


@pytest.mark.parametrize("max_colors", [0, pytest.param(2, marks=pytest.mark.slow)])
def test_the_step_does_not_depend_on_the_order_of_a_colours_vertices(device, max_colors):
    """The threads of one colour launch run in any order on a GPU. Contact pairs found at run
    time can join two vertices of one colour; the solve reads such partners from the sweep's
    snapshot, not from the positions their threads are writing, so the step must not depend on
    the order in which a colour's vertices are solved: reversing every colour's vertex list
    gives the same step bit for bit (a vertex that read a same-colour partner's new position
    where its thread ran first would make the step depend on the order on the CPU, on the
    timing on CUDA)."""
    m, *start = draped_layers_in_contact(device, max_colors)
    x_ref, solver = one_step_from(m, start)
    assert same_color_partner_records(solver) > 0  # the race the snapshot removes is there
    if max_colors:  # two colours: triangles with two corners of one colour (Jacobi couplings)
        assert m.color_count == 2 and (m.vertex_tri_local.numpy() >> 2).any()
    assert np.abs(x_ref - start[0]).max() > 1e-4
    order = m.color_vertices.numpy()
    offsets = list(m.color_offsets)
    for a, b in zip(offsets[:-1], offsets[1:], strict=True):
        order[a:b] = order[a:b][::-1].copy()
    m.color_vertices.assign(order)
    x, _ = one_step_from(m, start)
    np.testing.assert_array_equal(x, x_ref)


def test_self_contact_runs_are_bit_identical(device):
    """Same inputs, same result, with self-contact on, on every device: two 4-frame runs of the
    draped sheets from one contact state end at the same positions bit for bit (a Gauss-Seidel
    race on same-colour contact partners would make CUDA runs differ)."""
    m, *start = draped_layers_in_contact(device)
    runs = []
    for _ in range(2):
        solver = SolverVBD(m, plain_config(4, 4, self_contact=SelfContactConfig()))
        s = m.state()
        s.positions.assign(start[0])
        s.velocities.assign(start[1])
        for _ in range(4):
            solver.step(s, s, m.control(), 1.0 / 30.0)
        warp().synchronize()
        runs.append(s.positions.numpy().copy())
    assert same_color_partner_records(solver) > 0
    assert np.abs(runs[0] - start[0]).max() > 1e-3
    np.testing.assert_array_equal(runs[1], runs[0])


def test_heavy_vertices_solved_by_whole_blocks_take_the_same_step(device):
    """Vertices with more gather records than lanes may each get a whole thread block
    (``SelfContactConfig.heavy_cap``): the step must be the lanes layout's, whether every colour's
    heavy vertices fit under the cap, only some colours' do (the others solve theirs in the
    lanes layout), or none is heavy (cap 0). A vertex solved twice or skipped changes it. On the
    CPU (one lane, one thread per block) the orders agree and the steps match exactly. On CUDA
    the block sums a heavy vertex's items in another order than its lanes do: the steps agree
    to round-off."""
    m, *start = draped_layers_in_contact(device)
    lanes = layout(lanes=4, particles_per_block=32) if device == "cuda" else {}
    ref, _ = one_step_from(m, start, self_contact=SelfContactConfig(heavy_cap=0), **lanes)
    moved = np.abs(ref - start[0]).max()
    assert moved > 1e-4
    caps = [100000]
    for cap in caps:
        x, solver = one_step_from(m, start, self_contact=SelfContactConfig(heavy_cap=cap), **lanes)
        sc = solver.self_contact.data
        heavy = sc.heavy_count.numpy()
        flagged = sc.heavy.numpy()
        assert flagged.sum() == heavy.sum() > 0  # the heavy path is taken
        records = sc.pair_count.numpy()
        assert (records[flagged == 1] > sc.heavy_threshold).all()
        assert (records[flagged == 0] <= sc.heavy_threshold).all()
        if len(caps) == 1:  # next a cap that the colour with the fewest heavy vertices fits under
            assert heavy.min() < heavy.max(), heavy
            caps.append(int(heavy.min()))
        np.testing.assert_allclose(x, ref, atol=1e-4 * moved if device == "cuda" else 0.0, err_msg=str(cap))


@pytest.mark.parametrize("coarse", [CoarseConfig(sweeps=()), CoarseConfig(sweeps=(1,), early=True)],
                         ids=["plain", "coarse_early"])
def test_a_step_captured_in_a_cuda_graph_takes_the_plain_step(device, coarse):
    """On CUDA the step forks the bodies' placement and contact, the forward step and the
    previous deformation, and the self-contact detection's chains onto side streams
    (``sim.device.SideStreams``; the next substep's placement beside the sweeps, and the
    forward step beside the detection) and joins them before the sweeps:
    captured in a CUDA graph (as ``sim.simulate`` runs it), and in plain launches, the step must
    be the one every launch run in order on one stream gives, a moving body in contact and the
    layers in self-contact (a fork left unjoined fails the capture; a join in the wrong place
    lets the sweeps read half-written contacts, or the placement move the body under a contact
    query). With ``CoarseConfig.early`` the coarse system's preparation forks beside the
    detection, after the forward step and the body contact on their side streams. CUDA only:
    the CPU has no graphs and one stream."""
    from sim.device import SideStreams

    if device != "cuda":
        pytest.skip("CUDA graphs and streams only")
    wp = warp()
    m, *start = draped_layers_in_contact(device)
    centre = start[0].mean(axis=0) - np.array([0.0, 0.012, 0.0], np.float32)
    sphere_v, sphere_f = uv_sphere(0.01, center=centre)
    out = []
    for mode in ("in order", "plain", "graph"):
        solver = SolverVBD(m, plain_config(3, 4, self_contact=SelfContactConfig(), coarse=coarse))
        if mode == "in order":  # every launch on the one stream, where it is issued
            for name in ("_side", "_placing", "_coarse_side"):
                setattr(solver, name, SideStreams("cpu", len(getattr(solver, name).streams)))
            if getattr(solver.self_contact, "_side", None) is not None:
                solver.self_contact._side = SideStreams("cpu", 3)
        body = BodyCollider(sphere_v, sphere_f, device=device)
        body.set_frame(sphere_v, sphere_v + np.array([0.0, 0.003, 0.0], np.float32))  # rising 3 mm
        control = m.control()
        control.set_body(0, body)
        s = m.state()
        s.positions.assign(start[0])
        s.velocities.assign(start[1])
        if mode == "graph":
            with wp.ScopedCapture(device=device) as cap:  # records the launches, runs none
                solver.step(s, s, control, 1.0 / 120.0)
            wp.capture_launch(cap.graph)
        else:
            solver.step(s, s, control, 1.0 / 120.0)
        wp.synchronize()
        assert solver._contact_active.numpy().sum() > 0  # the body touches the cloth
        out.append(s.positions.numpy().copy())
    moved = np.abs(out[0] - start[0]).max()
    assert moved > 1e-4
    for k in (1, 2):
        np.testing.assert_allclose(out[k], out[0], atol=1e-4 * moved)


def test_solve_layout_caps_registers_only_in_the_automatic_batch_layout():
    """``KernelLayout.max_registers`` -1 (auto) caps the solve's registers where the automatic
    layout is the batch one (4 lanes, split gather), never for single garments (16 lanes) or a
    layout the user chose; 0 and an explicit cap are passed through; out-of-range caps raise."""
    from sim.cloth.solver_vbd import AUTO_BATCH_MAX_REGISTERS, AUTO_LANES_PARTICLES, solve_layout

    big, small = AUTO_LANES_PARTICLES, 1500
    assert solve_layout(KernelLayout(), small) == (16, 8, 0)
    assert solve_layout(KernelLayout(), big) == (4, 32, AUTO_BATCH_MAX_REGISTERS)
    assert solve_layout(KernelLayout(max_registers=0), big) == (4, 32, 0)
    assert solve_layout(KernelLayout(max_registers=96), small) == (16, 8, 96)
    assert solve_layout(KernelLayout(lanes=4, particles_per_block=32), big) == (4, 32, 0)
    for bad in (-2, 1, 23, 256):
        with pytest.raises(ValueError, match="layout.max_registers"):
            KernelLayout(max_registers=bad)


def test_fast_math_takes_the_step_to_round_off(device):
    """``fast_math`` compiles the CUDA solve with approximate division and square roots: from a
    state of two draped sheets in self-contact, one step moves the cloth as the precise kernel
    does to within 0.1 % of the step (the lanes' summation order alone: 0.01 %), in both layouts,
    and repeats bit for bit. On the CPU it changes nothing."""
    m, *start = draped_layers_in_contact(device)
    for fields in ({}, {"lanes": 4, "particles_per_block": 32}):
        ref, _ = one_step_from(m, start, **layout(**fields))
        moved = np.abs(ref - start[0]).max()
        assert moved > 1e-4
        fast, _ = one_step_from(m, start, **layout(fast_math=True, **fields))
        again, _ = one_step_from(m, start, **layout(fast_math=True, **fields))
        np.testing.assert_array_equal(fast, again)
        if device == "cuda":
            assert np.abs(fast - ref).max() < 1e-3 * moved
        else:
            np.testing.assert_array_equal(fast, ref)


def test_register_cap_takes_the_same_step(device):
    """A register cap changes only where the solve keeps its values (registers or spilled to
    local memory), not its arithmetic: the step from a state with self-contact is the
    uncapped one. On the CPU the cap is ignored."""
    m, *start = draped_layers_in_contact(device)
    lanes = {"lanes": 4, "particles_per_block": 32} if device == "cuda" else {}
    ref, _ = one_step_from(m, start, **layout(max_registers=0, **lanes))
    assert np.abs(ref - start[0]).max() > 1e-4
    for cap in (128, 64):
        x, solver = one_step_from(m, start, **layout(max_registers=cap, **lanes))
        assert solver._max_registers == (cap if device == "cuda" else 0)
        np.testing.assert_array_equal(x, ref, err_msg=str(cap))
