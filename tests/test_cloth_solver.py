"""Cloth solver (sim/cloth): energies against finite differences, and physics with exact or
analytic answers (free fall, hanging strip, pins, body contact, batching, determinism)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth import (
    BodyCollider,
    ClothMaterialParams,
    ClothModelBuilder,
    SolverVBD,
    VBDConfig,
)
from sim.cloth.coloring import (
    _tabu_recolor,
    compact_coloring,
    dsatur_coloring,
    greedy_coloring,
    validate_coloring,
    vertex_adjacency,
)
from sim.cloth.model import build_hinges, dihedral_angles, triangle_rest_data
from sim.device import warp

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


def uv_sphere(center, radius: float, n_lat: int = 16, n_lon: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Closed, outward-oriented sphere mesh."""
    v = [(0.0, radius, 0.0)]
    for i in range(1, n_lat):
        th = np.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * np.pi * j / n_lon
            s = radius * np.sin(th)
            v.append((s * np.cos(ph), radius * np.cos(th), s * np.sin(ph)))
    v.append((0.0, -radius, 0.0))
    f = []
    bottom = len(v) - 1
    for j in range(n_lon):
        f.append((0, 1 + (j + 1) % n_lon, 1 + j))
    for i in range(n_lat - 2):
        r0, r1 = 1 + i * n_lon, 1 + (i + 1) * n_lon
        for j in range(n_lon):
            j1 = (j + 1) % n_lon
            f += [(r0 + j, r0 + j1, r1 + j), (r0 + j1, r1 + j1, r1 + j)]
    r = 1 + (n_lat - 2) * n_lon
    for j in range(n_lon):
        f.append((bottom, r + j, r + (j + 1) % n_lon))
    v = np.asarray(v, dtype=np.float32) + np.asarray(center, dtype=np.float32)
    f = np.asarray(f, dtype=np.int32)
    # outward orientation: positive signed volume
    a, b, c = (v[f[:, k]].astype(np.float64) - np.asarray(center) for k in range(3))
    assert np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) > 0
    return v, f


def simulate(model, solver, control, steps: int, dt: float, *, body=None, body_path=None):
    state = model.state()
    frames = []
    for k in range(steps):
        if body is not None and body_path is not None:
            body.set_frame(body_path(k), body_path(k + 1))
        solver.step(state, state, control, dt)
        frames.append(state.positions.numpy().copy())
    return np.stack(frames)


# --- energies against finite differences (numpy float64 references) ---------------------

def stvk_energy_np(x: np.ndarray, dm_inv: np.ndarray, area: float, mu: float, lam: float) -> float:
    ds = np.stack([x[1] - x[0], x[2] - x[0]], axis=1)
    F = ds @ dm_inv
    E = 0.5 * (F.T @ F - np.eye(2))
    return area * (mu * np.sum(E * E) + 0.5 * lam * np.trace(E) ** 2)


def bending_energy_np(x: np.ndarray, rest_angle: float, k: float) -> float:
    th = dihedral_angles(x, np.array([[0, 1, 2, 3]]))[0]
    d = (th - rest_angle + np.pi) % (2 * np.pi) - np.pi  # the short way round
    return 0.5 * k * d**2


def fd_gradient_hessian(energy, x: np.ndarray, vertex: int, h: float = 1e-5):
    """Central differences of ``energy`` in float64: gradient (3,), Hessian block (3, 3)."""
    grad = np.zeros(3)
    hess = np.zeros((3, 3))

    def e_at(da, db):
        y = x.copy()
        y[vertex] += da + db
        return energy(y)

    eye = np.eye(3) * h
    for a in range(3):
        grad[a] = (e_at(eye[a], 0) - e_at(-eye[a], 0)) / (2 * h)
        for b in range(3):
            hess[a, b] = (e_at(eye[a], eye[b]) - e_at(eye[a], -eye[b]) - e_at(-eye[a], eye[b])
                          + e_at(-eye[a], -eye[b])) / (4 * h * h)
    return grad, hess


def test_membrane_force_and_hessian_match_finite_differences(device):
    from sim.cloth import energies

    wp = warp()
    rest = np.array([[0, 0, 0], [0.1, 0, 0], [0.03, 0.08, 0]], dtype=np.float64)
    dm_inv, area = triangle_rest_data(rest, np.array([[0, 1, 2]]))
    mu, lam = 300.0, 120.0
    # stretched (tension in both directions, so the compression clamp is inactive) and rotated
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    jitter = np.array([[0, 0, 0], [0, 0.004, 0.003], [0.002, 0, -0.004]])
    x = (rest @ np.diag([1.12, 1.08, 1.0]) + jitter) @ q.T
    x32 = wp.array(x.astype(np.float32), dtype=wp.vec3, device=device)
    f_out = wp.zeros(3, dtype=wp.vec3, device=device)
    h_out = wp.zeros(3, dtype=wp.mat33, device=device)
    wp.launch(energies.membrane_vertex_derivatives_kernel, dim=3,
              inputs=[x32, wp.mat22(*dm_inv[0].astype(np.float32).ravel()), float(area[0]), mu, lam],
              outputs=[f_out, h_out], device=device)
    e_out = wp.zeros(1, dtype=float, device=device)
    wp.launch(energies.membrane_energy_kernel, dim=1,
              inputs=[x32, wp.array([[0, 1, 2]], dtype=wp.vec3i, device=device),
                      wp.array(dm_inv.astype(np.float32), dtype=wp.mat22, device=device),
                      wp.array(area.astype(np.float32), dtype=float, device=device),
                      wp.array([mu], dtype=float, device=device),
                      wp.array([lam], dtype=float, device=device)],
              outputs=[e_out], device=device)

    def energy(y):
        return stvk_energy_np(y, dm_inv[0], area[0], mu, lam)

    np.testing.assert_allclose(e_out.numpy()[0], energy(x), rtol=1e-4)
    forces, hessians = f_out.numpy(), h_out.numpy()
    for k in range(3):
        grad, hess = fd_gradient_hessian(energy, x, k)
        scale = np.abs(grad).max()
        np.testing.assert_allclose(forces[k], -grad, rtol=1e-3, atol=1e-3 * scale)
        np.testing.assert_allclose(hessians[k], hess, rtol=1e-3, atol=1e-3 * np.abs(hess).max())


def corotated_energy_np(x: np.ndarray, dm_inv: np.ndarray, area: float, mu: float, lam: float) -> float:
    """A (mu |F - R|^2 + lam/2 (tr S - 2)^2) with F = R S from an SVD (float64 reference)."""
    F = np.stack([x[1] - x[0], x[2] - x[0]], axis=1) @ dm_inv
    u, sv, vt = np.linalg.svd(F, full_matrices=False)
    R = u @ vt
    return area * (mu * np.sum((F - R) ** 2) + 0.5 * lam * (sv.sum() - 2.0) ** 2)


@pytest.mark.parametrize("scale", [(1.12, 1.08), (0.7, 0.85), (1.1, 0.8)])
def test_corotated_membrane_force_matches_finite_differences(device, scale):
    """Stretched, compressed and mixed: the force is the exact gradient; the Hessian block is
    the documented positive semi-definite approximation and agrees with the exact one in the
    triangle's plane."""
    from sim.cloth import energies

    wp = warp()
    rest = np.array([[0, 0, 0], [0.1, 0, 0], [0.03, 0.08, 0]], dtype=np.float64)
    dm_inv, area = triangle_rest_data(rest, np.array([[0, 1, 2]]))
    mu, lam = 300.0, 120.0
    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    x = (rest @ np.diag([scale[0], scale[1], 1.0])) @ q.T
    out = [wp.zeros(3, dtype=t, device=device) for t in (wp.vec3, wp.mat33, float)]
    wp.launch(energies.corotated_vertex_derivatives_kernel, dim=3,
              inputs=[wp.array(x.astype(np.float32), dtype=wp.vec3, device=device),
                      wp.mat22(*dm_inv[0].astype(np.float32).ravel()), float(area[0]), mu, lam],
              outputs=out, device=device)
    forces, hessians, energies_k = (o.numpy() for o in out)

    def energy(y):
        return corotated_energy_np(y, dm_inv[0], area[0], mu, lam)

    np.testing.assert_allclose(energies_k[0], energy(x), rtol=1e-3, atol=1e-9)
    for k in range(3):
        grad, _ = fd_gradient_hessian(energy, x, k)
        np.testing.assert_allclose(forces[k], -grad, rtol=2e-3, atol=2e-3 * np.abs(grad).max() + 1e-9)
        h = hessians[k].astype(np.float64)
        np.testing.assert_allclose(h, h.T, atol=1e-6 * np.abs(h).max())
        assert np.linalg.eigvalsh(h).min() > -1e-6 * np.abs(h).max()


def test_bending_force_and_hessian_match_finite_differences(device):
    from sim.cloth import energies

    wp = warp()
    # hinge (o0, o1, a, b): triangles (a, b, o0) and (b, a, o1), folded out of plane
    x = np.array([[0.05, 0.09, 0.02], [0.06, -0.08, 0.03], [0.0, 0.0, 0.0], [0.1, 0.01, 0.0]])
    theta = dihedral_angles(x, np.array([[0, 1, 2, 3]]))[0]
    assert abs(theta) > 0.2
    k = 2e-3
    f_out = wp.zeros(4, dtype=wp.vec3, device=device)
    h_out = wp.zeros(4, dtype=wp.mat33, device=device)
    x32 = wp.array(x.astype(np.float32), dtype=wp.vec3, device=device)
    # gradient away from the rest angle
    rest_angle = theta - 0.3
    wp.launch(energies.bending_vertex_derivatives_kernel, dim=4, inputs=[x32, float(rest_angle), k],
              outputs=[f_out, h_out], device=device)
    for v in range(4):
        grad, _ = fd_gradient_hessian(lambda y: bending_energy_np(y, rest_angle, k), x, v)
        np.testing.assert_allclose(f_out.numpy()[v], -grad, rtol=1e-3, atol=1e-3 * np.abs(grad).max())
    np.testing.assert_allclose(f_out.numpy().sum(axis=0), 0.0, atol=1e-6)  # translation invariance
    # the Gauss-Newton Hessian is exact at the rest angle
    wp.launch(energies.bending_vertex_derivatives_kernel, dim=4, inputs=[x32, float(theta), k],
              outputs=[f_out, h_out], device=device)
    for v in range(4):
        _, hess = fd_gradient_hessian(lambda y: bending_energy_np(y, theta, k), x, v, h=1e-4)
        np.testing.assert_allclose(h_out.numpy()[v], hess, rtol=2e-3, atol=2e-3 * np.abs(hess).max())


def hinge_folded(phi: float) -> np.ndarray:
    """A hinge (o0, o1, a, b) along x whose wing o1 is turned by ``phi`` [rad] about the hinge
    from flat (0) towards folded onto wing o0 (pi)."""
    return np.array([[0.05, 0.08, 0.0], [0.06, -0.08 * np.cos(phi), 0.08 * np.sin(phi)],
                     [0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])


def test_a_hinge_folded_at_rest_resists_folding_past_flat_the_short_way(device):
    """A crease folded at rest (170 degrees, a seam or a hairpin) folded 20 degrees further, so
    past flat, where the signed dihedral angle jumps from +pi to -pi: the bending energy is that
    of a 20-degree bend, not of a 340-degree one, and the force turns the wing back the short
    way (until session 17 it drove it on round through the other wing). Forces match finite
    differences of the wrapped energy."""
    from sim.cloth import energies

    wp = warp()
    hinge = np.array([[0, 1, 2, 3]])
    rest = dihedral_angles(hinge_folded(np.radians(170.0)), hinge)[0]
    x = hinge_folded(np.radians(190.0))
    theta = dihedral_angles(x, hinge)[0]
    assert abs(abs(rest) - np.radians(170.0)) < 1e-6 and np.sign(theta) != np.sign(rest)  # wrapped
    k = 2e-3
    x32 = wp.array(x.astype(np.float32), dtype=wp.vec3, device=device)
    e_out = wp.zeros(1, dtype=float, device=device)
    wp.launch(energies.bending_energy_kernel, dim=1,
              inputs=[x32, wp.array(hinge, dtype=wp.vec4i, device=device),
                      wp.array([rest], dtype=float, device=device),
                      wp.array([k], dtype=float, device=device)],
              outputs=[e_out], device=device)
    np.testing.assert_allclose(e_out.numpy()[0], 0.5 * k * np.radians(20.0) ** 2, rtol=1e-4)
    f_out = wp.zeros(4, dtype=wp.vec3, device=device)
    h_out = wp.zeros(4, dtype=wp.mat33, device=device)
    wp.launch(energies.bending_vertex_derivatives_kernel, dim=4, inputs=[x32, float(rest), k],
              outputs=[f_out, h_out], device=device)
    for v in range(4):
        grad, _ = fd_gradient_hessian(lambda y: bending_energy_np(y, rest, k), x, v)
        np.testing.assert_allclose(f_out.numpy()[v], -grad, rtol=1e-3, atol=1e-3 * np.abs(grad).max())
    # the wing o1 is pushed back towards 170 degrees: along d x1 / d phi with phi decreasing
    back = -(hinge_folded(np.radians(190.0) + 1e-6)[1] - x[1])
    assert np.dot(f_out.numpy()[1], back) > 0.0


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


def test_compact_coloring_needs_fewer_colours_than_greedy_on_a_tshirt():
    """Every colour is one launch per sweep: the t-shirt template's triangle graph (the model's
    colouring since session 15; with the hinge diagonals too it needed 6) gets 4 colours where
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
    cfg = VBDConfig(substeps=4, iterations=3, air_damping=0.0)
    steps, dt = 12, 1.0 / 30.0
    x = simulate(m, SolverVBD(m, cfg), m.control(), steps, dt)[-1]
    n = steps * cfg.substeps
    h = dt / cfg.substeps
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
    solver = SolverVBD(m, VBDConfig(substeps=substeps, iterations=3, air_damping=alpha))
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
    """Analytic elongation [m] of a hanging StVK strip under its own weight (uniaxial, laterally
    free): nominal stress s * E (s^2 - 1)/2 = rho g (L - Y) at rest depth Y below the pin,
    E = 4 mu (mu + lam) / (2 mu + lam) (2D Young's modulus). With ``top_layers`` n, the upper
    half is n layers: n times the mass and stiffness, so there n E (s^3 - s)/2 carries the
    weight below, rho g (n (L/2 - Y) + L/2)."""
    E = 4 * mu * (mu + lam) / (2 * mu + lam)
    Y = np.linspace(0.0, L, 2001)
    s = np.empty_like(Y)
    for k, y in enumerate(Y):
        n = top_layers if y < L / 2 else 1.0
        load = rho * G * (L - y if y >= L / 2 else top_layers * (L / 2 - y) + L / 2)
        r = np.roots([n * E / 2, 0.0, -n * E / 2, -load])
        s[k] = np.max(r[np.abs(r.imag) < 1e-9].real)
    return float(np.trapezoid(s - 1.0, Y))


def hanging_strip(device, mat, max_colors: int = 0, top_layers: float = 1.0):
    """A 0.1 x 1 m strip (3 x 21 vertices) pinned along its top edge, its upper half of
    ``top_layers`` layers: (model, rest vertices)."""
    v, f = grid(3, 21, 0.1, 1.0)
    b = ClothModelBuilder(max_colors=max_colors)
    layers = np.where(v[f].mean(axis=1)[:, 1] > -0.5, top_layers, 1.0)
    b.add_cloth(v, f, mat, pinned=np.arange(3), face_layers=layers)
    return b.finalize(device), v


def test_hanging_strip_reaches_analytic_stretch(device):
    L, nx = 1.0, 3
    mat = ClothMaterialParams(density=0.2, mu=15.0, lam=10.0, bending=1e-7, damping=1e-3, friction=0.0)
    m, v = hanging_strip(device, mat)
    # the asymmetric triangulation makes the stretched strip sway; still air (alpha = 2/s) stops it.
    # The analytic value is StVK's.
    cfg = VBDConfig(substeps=5, iterations=10, air_damping=2.0, membrane="stvk")
    x = simulate(m, SolverVBD(m, cfg), m.control(), 150,
                 1.0 / 30.0)
    delta_sim = -(x[-1, -nx:, 1].mean()) - L
    delta = hanging_elongation(L, mat.density, mat.mu, mat.lam)
    assert 0.01 < delta < 0.05
    np.testing.assert_allclose(delta_sim, delta, rtol=0.04)
    # at rest: the last two frames agree
    np.testing.assert_allclose(x[-1], x[-2], atol=2e-4)


def test_a_strip_doubled_in_its_upper_half_hangs_at_the_layered_stretch(device):
    """Two layers (a hem's) over the upper half: twice the weight there, carried by twice the
    stiffness. The strip hangs at the analytic elongation of that layering, a quarter less than the
    plain strip's (``hanging_elongation`` with ``top_layers``)."""
    L, nx = 1.0, 3
    mat = ClothMaterialParams(density=0.2, mu=15.0, lam=10.0, bending=1e-7, damping=1e-3, friction=0.0)
    m, v = hanging_strip(device, mat, top_layers=2.0)
    cfg = VBDConfig(substeps=5, iterations=10, air_damping=2.0, membrane="stvk")
    x = simulate(m, SolverVBD(m, cfg), m.control(), 150, 1.0 / 30.0)
    delta_sim = -(x[-1, -nx:, 1].mean()) - L
    layered = hanging_elongation(L, mat.density, mat.mu, mat.lam, top_layers=2.0)
    plain = hanging_elongation(L, mat.density, mat.mu, mat.lam)
    assert layered < 0.92 * plain
    np.testing.assert_allclose(delta_sim, layered, rtol=0.04)
    # the lower half stretches as the plain strip's lower half does: it carries the same weight
    # (a plain strip of half the length: the same weight below every point)
    middle = np.flatnonzero(np.abs(v[:, 1] + 0.5) < 1e-6)
    lower_sim = x[-1, middle, 1].mean() - x[-1, -nx:, 1].mean() - 0.5
    np.testing.assert_allclose(lower_sim, hanging_elongation(L / 2, mat.density, mat.mu, mat.lam), rtol=0.06)
    np.testing.assert_allclose(x[-1], x[-2], atol=2e-4)


@pytest.mark.parametrize("max_colors", [2])
def test_hanging_strip_with_jacobi_couplings_reaches_the_same_stretch(device, max_colors):
    """Same-coloured neighbours (a 2-colouring of the strip leaves a third of its edges inside a
    colour) change how the sweeps get to the equilibrium, not the equilibrium: the strip of
    ``test_hanging_strip_reaches_analytic_stretch`` hangs at the analytic elongation."""
    L, nx = 1.0, 3
    mat = ClothMaterialParams(density=0.2, mu=15.0, lam=10.0, bending=1e-7, damping=1e-3, friction=0.0)
    m, v = hanging_strip(device, mat, max_colors)
    assert m.color_count == max_colors and (m.vertex_tri_local.numpy() >> 2).any()
    cfg = VBDConfig(substeps=5, iterations=10, air_damping=2.0, membrane="stvk")
    x = simulate(m, SolverVBD(m, cfg), m.control(), 150, 1.0 / 30.0)
    assert np.isfinite(x).all()
    delta_sim = -(x[-1, -nx:, 1].mean()) - L
    np.testing.assert_allclose(delta_sim, hanging_elongation(L, mat.density, mat.mu, mat.lam), rtol=0.04)
    np.testing.assert_allclose(x[-1], x[-2], atol=2e-4)


def strain_limit_np(x, rest, mass, pinned, edges, limit, normal=None, active=None):
    """numpy reference of one ``strain_limit_kernel`` pass (float64)."""
    out = x.astype(np.float64).copy()
    corr = np.zeros_like(out)
    count = np.zeros(len(x))
    inv = np.where(pinned, 0.0, 1.0 / mass)
    for a, b in edges:
        d = x[b].astype(np.float64) - x[a]
        length = np.linalg.norm(d)
        l_max = (1.0 + limit) * np.linalg.norm(rest[b].astype(np.float64) - rest[a])
        if length > l_max:
            for i, j, s in ((a, b, 1.0), (b, a, -1.0)):
                if inv[i] > 0:
                    corr[i] += s * d * (length - l_max) / length * inv[i] / (inv[i] + inv[j])
                count[i] += 1
    for i in range(len(x)):
        if pinned[i] or count[i] == 0:
            continue
        c = corr[i] / count[i]
        if active is not None and active[i]:
            c = c - min(np.dot(c, normal[i]), 0.0) * normal[i]
        out[i] += c
    return out


def test_strain_limit_pass_matches_numpy_and_caps_strain(device):
    """One Jacobi pass of the strain limit against a numpy reference on a randomly stretched
    sheet with unequal masses, a pinned vertex and body-contact normals; repeated passes bring
    every edge to at most the limit (the stretch goes to slack edges); a sheet within the limit
    is left exactly as it is; and a lone stretched edge of two free particles comes out at the
    limit with its centre of mass unmoved."""
    from sim.cloth import vbd_kernels as K

    wp = warp()
    v, f = grid(7, 6, 0.3, 0.25)
    rng = np.random.default_rng(5)
    x = (v * np.array([1.25, 1.1, 1.0]) + rng.normal(0, 0.01, v.shape)).astype(np.float32)
    pinned = np.zeros(len(v), bool)
    pinned[3] = True
    b = ClothModelBuilder()
    b.add_cloth(x, f, ClothMaterialParams(), pinned=pinned, rest_vertices=v)
    m = b.finalize(device)
    mass = m.particle_mass.numpy() * rng.uniform(0.5, 2.0, len(v)).astype(np.float32)
    m.particle_mass.assign(mass)
    normal = rng.normal(size=v.shape)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    active = (rng.uniform(size=len(v)) < 0.3).astype(np.int32)
    edges = m.mesh_edge_indices.numpy()

    def run(xin, passes, contact=True):
        a = wp.array(xin, dtype=wp.vec3, device=device)
        touching = active if contact else np.zeros_like(active)
        o = wp.zeros_like(a)
        for _ in range(passes):
            wp.launch(K.strain_limit_kernel, dim=len(xin),
                      inputs=[0.1, a, m.particle_rest, m.particle_mass, m.particle_flags, m.mesh_edge_indices,
                              m.vertex_mesh_edge_offsets, m.vertex_mesh_edge_ids, m.vertex_mesh_edge_local,
                              wp.array(normal.astype(np.float32), dtype=wp.vec3, device=device),
                              wp.array(touching, dtype=wp.int32, device=device)], outputs=[o], device=device)
            a, o = o, a
        return a.numpy()

    def max_strain(xs):
        return float((np.linalg.norm(xs[edges[:, 1]] - xs[edges[:, 0]], axis=1)
                      / np.linalg.norm(v[edges[:, 1]] - v[edges[:, 0]], axis=1)).max() - 1.0)

    np.testing.assert_allclose(run(x, 1), strain_limit_np(x, v, mass, pinned, edges, 0.1, normal, active),
                               atol=2e-6)
    assert max_strain(x) > 0.3
    out = run(x, 200, contact=False)
    assert max_strain(out) < 0.105  # from > 0.3 (averaged Jacobi converges slowly at the end)
    np.testing.assert_array_equal(out[3], x[3])  # pinned
    within = (v * 1.05).astype(np.float32)
    np.testing.assert_array_equal(run(within, 3), within)
    # in contact a particle keeps only the part of its correction that leaves the body
    moved = run(x, 1) - x
    touching = active.astype(bool) & ~pinned
    assert np.all(np.einsum("ij,ij->i", moved[touching], normal[touching]) > -1e-6)
    # a lone edge: exactly at the limit, centre of mass kept
    two = ClothModelBuilder()
    tv = np.array([[0, 0, 0], [0.1, 0, 0], [0.075, 0.2, 0]], np.float32)
    two.add_cloth(tv, [[0, 1, 2]], ClothMaterialParams())
    m2 = two.finalize(device)
    lone = np.array([[0, 0, 0], [0.15, 0, 0], [0.075, 0.2, 0]], np.float32)  # only edge 0-1 past the limit
    masses = np.array([1.0, 3.0, 1.0], np.float32)
    m2.particle_mass.assign(masses)
    a = wp.array(lone, dtype=wp.vec3, device=device)
    o = wp.zeros_like(a)
    wp.launch(K.strain_limit_kernel, dim=3,
              inputs=[0.1, a, m2.particle_rest, m2.particle_mass, m2.particle_flags, m2.mesh_edge_indices,
                      m2.vertex_mesh_edge_offsets, m2.vertex_mesh_edge_ids, m2.vertex_mesh_edge_local,
                      wp.zeros(3, dtype=wp.vec3, device=device), wp.zeros(3, dtype=wp.int32, device=device)],
              outputs=[o], device=device)
    y = o.numpy()
    np.testing.assert_allclose(np.linalg.norm(y[1] - y[0]), 0.11, rtol=1e-5)
    np.testing.assert_allclose(masses[:2] @ y[:2], masses[:2] @ lone[:2], atol=1e-7)
    np.testing.assert_array_equal(y[2], lone[2])


def test_a_strain_limited_strip_hangs_near_the_limit(device):
    """A soft strip that would hang stretched ~40 % at its top (StVK, few sweeps) hangs with its
    edges near the 10 % limit when the substeps end with strain-limit passes, nearer with more
    passes (the averaged Jacobi passes move stretch down the strip a ring at a time), and at
    rest."""
    mat = ClothMaterialParams(density=0.2, mu=1.5, lam=1.0, bending=1e-7, damping=1e-3, friction=0.0)
    m, v = hanging_strip(device, mat)
    edges = m.mesh_edge_indices.numpy()
    rest = np.linalg.norm(v[edges[:, 1]] - v[edges[:, 0]], axis=1)
    out = {}
    for limit, passes in ((0.0, 4), (0.1, 8), (0.1, 40)):
        cfg = VBDConfig(substeps=5, iterations=10, air_damping=2.0, membrane="stvk", strain_limit=limit,
                        strain_limit_passes=passes)
        x = simulate(m, SolverVBD(m, cfg), m.control(), 120, 1.0 / 30.0)
        strain = np.linalg.norm(x[-1, edges[:, 1]] - x[-1, edges[:, 0]], axis=1) / rest - 1.0
        out[limit, passes] = strain.max()
        if limit:
            np.testing.assert_allclose(x[-1], x[-2], atol=3e-4)
    assert out[0.0, 4] > 0.3
    assert 0.1 < out[0.1, 40] < out[0.1, 8] < 0.16
    assert out[0.1, 40] < 0.115
    with pytest.raises(ValueError, match="strain_limit"):
        VBDConfig(strain_limit=-0.1)


def test_pinned_vertices_stay_exactly_put(device):
    v, f = grid(8, 8, 0.5, 0.5, plane="xz")
    pins = np.array([0, 7, 3])
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(), pinned=pins)
    m = b.finalize(device)
    x = simulate(m, SolverVBD(m, VBDConfig(substeps=3, iterations=3)), m.control(), 15, 1.0 / 30.0)
    np.testing.assert_array_equal(x[:, pins], np.broadcast_to(v[pins], x[:, pins].shape))
    assert x[-1, :, 1].min() < -0.2  # the rest swings down


def drop_on_sphere(device, steps: int = 30):
    v, f = grid(13, 13, 0.6, 0.6, plane="xz")
    v = v + np.array([-0.3, 0.25, -0.3], dtype=np.float32)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(bending=1e-5, friction=0.5, thickness=0.005))
    m = b.finalize(device)
    sv, sf = uv_sphere((0.0, 0.0, 0.0), 0.2)
    body = BodyCollider(sv, sf, device=device)
    control = m.control()
    control.set_body(0, body)
    solver = SolverVBD(m, VBDConfig(substeps=5, iterations=5))
    return m, solver, control, body, sv


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
    sv, sf = uv_sphere((0.0, 0.0, 0.0), 0.12)
    start = np.array([0.0, 0.6, -0.3], dtype=np.float32)
    dt, speed = 1.0 / 30.0, 5.0

    def path(k):
        return sv + start + np.array([0.0, 0.0, min(speed * dt * k, 0.6)], dtype=np.float32)

    body = BodyCollider(path(0), sf, device=device)
    control = m.control()
    control.set_body(0, body)
    solver = SolverVBD(m, VBDConfig(substeps=10, iterations=5))
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
    sv, sf = uv_sphere((0.0, 0.0, 0.0), 0.2)
    cfg = VBDConfig(substeps=3, iterations=4)

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
    with pytest.raises(ValueError, match="substeps"):
        VBDConfig(substeps=0)


def test_chebyshev_acceleration_converges_further_per_sweep(device):
    """One stiff implicit step of a long hanging strip (slow to converge: the load travels 40
    rows): with Chebyshev weights the sweeps end closer to the converged solution than the same
    number of plain sweeps; the weights follow the recursion to ``2 / (1 + sqrt(1 - rho^2))``."""
    from sim.cloth.solver_vbd import chebyshev_omegas

    rho = 0.95
    om = chebyshev_omegas(rho, 60)
    assert om[0] == 1.0 and om[1] == pytest.approx(2.0 / (2.0 - rho**2))
    assert om[-1] == pytest.approx(2.0 / (1.0 + np.sqrt(1.0 - rho**2)), rel=1e-3)
    assert chebyshev_omegas(0.0, 10) == []
    for bad in ({"chebyshev_rho": 1.0}, {"chebyshev_rho": -0.1}, {"particles_per_block": 0},
                {"particles_per_block": 128, "lanes": 16}, {"lanes": -1}, {"lanes": 257}):
        with pytest.raises(ValueError):
            VBDConfig(**bad)
    nx, ny = 3, 41
    mat = ClothMaterialParams(density=0.2, mu=200.0, lam=100.0, bending=1e-7, damping=0.0, friction=0.0)
    v, f = grid(nx, ny, 0.1, 1.0)
    b = ClothModelBuilder()
    b.add_cloth(v, f, mat, pinned=np.arange(nx))
    m = b.finalize(device)

    def step(iterations: int, rho: float) -> np.ndarray:
        cfg = VBDConfig(substeps=1, iterations=iterations, chebyshev_rho=rho, air_damping=0.0)
        return simulate(m, SolverVBD(m, cfg), m.control(), 1, 1.0 / 30.0)[-1]

    ref = step(1000, 0.0)
    plain = np.abs(step(20, 0.0) - ref).max()
    accel = np.abs(step(20, rho) - ref).max()
    assert plain > 1e-3  # far from converged: the comparison means something
    assert accel < 0.9 * plain
    np.testing.assert_array_equal(step(20, rho)[:nx], v[:nx])  # pins untouched


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
    first = SolverVBD(m, VBDConfig(substeps=4, iterations=4, self_contact=True))
    state = m.state()
    for frame in range(12):
        first.step(state, state, m.control(), 1.0 / 30.0)
        if frame >= 2 and first.self_contact.data.pair_count.numpy().mean() > 0.5:
            break
    assert first.self_contact.data.pair_count.numpy().mean() > 0.5  # the layers are in contact
    return m, state.positions.numpy().copy(), state.velocities.numpy().copy()


def one_step_from(m, start, **config):
    """Positions after one 1/120 s step (1 substep, 4 sweeps) from ``start`` (positions,
    velocities) with self-contact and the solver settings ``config``; and the solver."""
    solver = SolverVBD(m, VBDConfig(substeps=1, iterations=4, self_contact=True, **config))
    s = m.state()
    s.positions.assign(start[0])
    s.velocities.assign(start[1])
    solver.step(s, s, m.control(), 1.0 / 120.0)
    warp().synchronize()
    return s.positions.numpy().copy(), solver


def test_the_solve_does_not_depend_on_its_lanes(device):
    """Every (lanes, particles per block) layout of the tiled solve and either gather (fused or
    split) computes the same Gauss-Seidel step: from one state of two draped sheets in
    self-contact, a step with the automatic layout (16 x 8 at this size), with 4 x 32 (the layout
    of large batches) and with 1 x 64 ends at the same positions to float32 round-off (the lanes
    and the gather only change the summation order). One step from a shared state: over several
    frames contact switching amplifies round-off into centimetres, which says nothing about the
    layouts. On the CPU every layout is one thread
    per particle: the steps must match exactly but for the gather, which orders a particle's
    sums by kind (split) or by item (fused)."""
    from sim.cloth.solver_vbd import AUTO_LANES_PARTICLES, auto_lanes

    assert auto_lanes(AUTO_LANES_PARTICLES - 1) == (16, 8) and auto_lanes(AUTO_LANES_PARTICLES) == (4, 32)
    m, *start = draped_layers_in_contact(device)
    layouts = ({}, {"lanes": 4, "particles_per_block": 32}, {"lanes": 1, "particles_per_block": 64},
               {"gather": "fused"}, {"gather": "split"},
               {"lanes": 4, "particles_per_block": 32, "gather": "fused"})
    out = [one_step_from(m, start, **layout)[0] for layout in layouts]
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


@pytest.mark.parametrize("max_colors", [0, 2])
def test_the_step_does_not_depend_on_the_order_of_a_colours_vertices(device, max_colors):
    """The threads of one colour launch run in any order on a GPU. Contact pairs found at run
    time can join two vertices of one colour; the solve reads such partners from the sweep's
    snapshot, not from the positions their threads are writing, so the step must not depend on
    the order in which a colour's vertices are solved: reversing every colour's vertex list
    gives the same step bit for bit (before session 15 a vertex read a same-colour partner's
    new position if its thread had run first: on the CPU the order changed the step, on CUDA
    the timing did)."""
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


@pytest.mark.parametrize("pipeline", [False, True])
def test_self_contact_runs_are_bit_identical(device, pipeline):
    """Same inputs, same result, with self-contact on, on every device (issue 3's "same seed,
    same result"): two 4-frame runs of the draped sheets from one contact state end at the same
    positions bit for bit. On CUDA this held only without self-contact before session 15 (the
    Gauss-Seidel race on same-colour contact partners). With the pipelined detection the next
    substep's pairs are found on a side stream while the sweeps run: a sweep reading the lists
    being written would make the runs differ."""
    m, *start = draped_layers_in_contact(device)
    runs = []
    for _ in range(2):
        solver = SolverVBD(m, VBDConfig(substeps=4, iterations=4, self_contact=True,
                                        self_contact_pipeline=pipeline))
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


def test_pipelined_detection_takes_the_in_order_step(device):
    """``self_contact_pipeline``: substep ``s + 1``'s pairs are detected during substep ``s``,
    from ``s``'s start over two substeps of motion, on a side stream (CUDA). The step must be the
    one the same detections give run in order on one stream, in plain launches and captured in
    a CUDA graph (a join in the wrong place lets a sweep read half-written lists, or the
    detection read positions the next substep already moved). Both pair-list slots are used,
    and the substeps after the first find their pairs without a detection of their own."""
    from sim.device import SideStreams

    wp = warp()
    m, *start = draped_layers_in_contact(device)
    out = []
    for mode in ("in order", "plain", "graph"):
        solver = SolverVBD(m, VBDConfig(substeps=4, iterations=3, self_contact=True,
                                        self_contact_pipeline=True))
        if mode == "in order":
            solver._pipe = SideStreams("cpu", 1)  # no streams: the detections run where they are issued
        s = m.state()
        s.positions.assign(start[0])
        s.velocities.assign(start[1])
        if mode == "graph" and device == "cuda":
            with wp.ScopedCapture(device=device) as cap:
                solver.step(s, s, m.control(), 1.0 / 30.0)
            wp.capture_launch(cap.graph)
        else:
            solver.step(s, s, m.control(), 1.0 / 30.0)
        wp.synchronize()
        assert all(d.pair_count.numpy().sum() > 0 for d in solver.self_contact.datas)
        out.append(s.positions.numpy().copy())
    moved = np.abs(out[0] - start[0]).max()
    assert moved > 1e-3
    for k in (1, 2):
        np.testing.assert_allclose(out[k], out[0], atol=1e-5 * moved if device == "cuda" else 0.0)
    with pytest.raises(ValueError, match="pipeline"):
        VBDConfig(self_contact_pipeline=True, self_contact_interval=2)
    with pytest.raises(ValueError, match="pipeline"):
        VBDConfig(self_contact_pipeline=True, self_contact_bounds=True)


def test_heavy_vertices_solved_by_whole_blocks_take_the_same_step(device):
    """Vertices with more gather records than lanes may each get a whole thread block
    (``self_contact_heavy_cap``): the step must be the lanes layout's, whether every colour's
    heavy vertices fit under the cap, only some colours' do (the others solve theirs in the
    lanes layout), or none is heavy (cap 0). A vertex solved twice or skipped changes it. On the
    CPU (one lane, one thread per block) the orders agree and the steps match exactly. On CUDA
    the block sums a heavy vertex's items in another order than its lanes do: the steps agree
    to round-off (session 14, before same-colour contact partners were read from the sweep's
    snapshot, only to 3 % of the motion: heavy blocks run last and saw more moved partners)."""
    m, *start = draped_layers_in_contact(device)
    layout = {"lanes": 4, "particles_per_block": 32} if device == "cuda" else {}
    ref, _ = one_step_from(m, start, self_contact_heavy_cap=0, **layout)
    moved = np.abs(ref - start[0]).max()
    assert moved > 1e-4
    caps = [100000]
    for cap in caps:
        x, solver = one_step_from(m, start, self_contact_heavy_cap=cap, **layout)
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


EARLY_COARSE = {"coarse_sweeps": (1,), "coarse_prefactor": True, "coarse_early": True}


@pytest.mark.parametrize("config", [{}, EARLY_COARSE], ids=["plain", "coarse_early"])
def test_a_step_captured_in_a_cuda_graph_takes_the_plain_step(device, config):
    """On CUDA the step forks the bodies' placement and contact, the forward step and the
    previous deformation, and the self-contact detection's chains onto side streams
    (``sim.device.SideStreams``; since session 41 the next substep's placement beside the
    sweeps, and the forward step beside the detection) and joins them before the sweeps:
    captured in a CUDA graph (as ``sim.simulate`` runs it), and in plain launches, the step must
    be the one every launch run in order on one stream gives, a moving body in contact and the
    layers in self-contact (a fork left unjoined fails the capture; a join in the wrong place
    lets the sweeps read half-written contacts, or the placement move the body under a contact
    query). With ``coarse_early`` (session 42) the coarse system's preparation forks beside the
    detection, after the forward step and the body contact on their side streams. CUDA only:
    the CPU has no graphs and one stream."""
    from sim.device import SideStreams

    if device != "cuda":
        pytest.skip("CUDA graphs and streams only")
    wp = warp()
    m, *start = draped_layers_in_contact(device)
    centre = start[0].mean(axis=0) - np.array([0.0, 0.012, 0.0], np.float32)
    sphere_v, sphere_f = uv_sphere(centre, 0.01)
    out = []
    for mode in ("in order", "plain", "graph"):
        solver = SolverVBD(m, VBDConfig(substeps=3, iterations=4, self_contact=True, **config))
        if mode == "in order":  # every launch on the one stream, where it is issued
            for name in ("_side", "_placing", "_pipe", "_coarse_side"):
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
    """``VBDConfig.max_registers`` -1 (auto) caps the solve's registers where the automatic
    layout is the batch one (4 lanes, split gather), never for single garments (16 lanes) or a
    layout the user chose; 0 and an explicit cap are passed through; out-of-range caps raise."""
    from sim.cloth.solver_vbd import AUTO_BATCH_MAX_REGISTERS, AUTO_LANES_PARTICLES, solve_layout

    big, small = AUTO_LANES_PARTICLES, 1500
    assert solve_layout(VBDConfig(), small) == (16, 8, 0)
    assert solve_layout(VBDConfig(), big) == (4, 32, AUTO_BATCH_MAX_REGISTERS)
    assert solve_layout(VBDConfig(max_registers=0), big) == (4, 32, 0)
    assert solve_layout(VBDConfig(max_registers=96), small) == (16, 8, 96)
    assert solve_layout(VBDConfig(lanes=4, particles_per_block=32), big) == (4, 32, 0)
    for bad in (-2, 1, 23, 256):
        with pytest.raises(ValueError, match="max_registers"):
            VBDConfig(max_registers=bad)


def test_fast_math_takes_the_step_to_round_off(device):
    """``fast_math`` compiles the CUDA solve with approximate division and square roots: from a
    state of two draped sheets in self-contact, one step moves the cloth as the precise kernel
    does to within 0.1 % of the step (the lanes' summation order alone: 0.01 %), in both layouts,
    and repeats bit for bit. On the CPU it changes nothing."""
    m, *start = draped_layers_in_contact(device)
    for layout in ({}, {"lanes": 4, "particles_per_block": 32}):
        ref, _ = one_step_from(m, start, **layout)
        moved = np.abs(ref - start[0]).max()
        assert moved > 1e-4
        fast, _ = one_step_from(m, start, fast_math=True, **layout)
        again, _ = one_step_from(m, start, fast_math=True, **layout)
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
    layout = {"lanes": 4, "particles_per_block": 32} if device == "cuda" else {}
    ref, _ = one_step_from(m, start, max_registers=0, **layout)
    assert np.abs(ref - start[0]).max() > 1e-4
    for cap in (128, 64):
        x, solver = one_step_from(m, start, max_registers=cap, **layout)
        assert solver._max_registers == (cap if device == "cuda" else 0)
        np.testing.assert_array_equal(x, ref, err_msg=str(cap))
