"""Cloth self-contact (sim.cloth.self_contact): geometry against numpy, forces against finite
differences of the contact energy, and the physics: stacked layers never pass through each
other, the bounds keep the cloth intersection-free, instances in a batch never collide."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from sim.cloth import ClothMaterialParams, ClothModelBuilder, SolverVBD, VBDConfig
from sim.cloth.model import mesh_edges
from sim.cloth.self_contact import (
    SelfContact,
    SelfContactData,
    self_contact_force_hessian,
    triangle_closest_bary,
)
from sim.quality import self_intersections
from tests.test_cloth_solver import grid, simulate


@wp.kernel
def _bary_kernel(p: wp.array(dtype=wp.vec3), a: wp.vec3, b: wp.vec3, c: wp.vec3,
                 out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = triangle_closest_bary(p[i], a, b, c)


def closest_point_triangle_np(p, a, b, c, n=200):
    """Brute force: the closest of a dense barycentric sampling, refined by projection."""
    best, best_d = None, np.inf
    s = np.linspace(0.0, 1.0, n)
    u, v = np.meshgrid(s, s)
    m = u + v <= 1.0
    pts = a + u[m, None] * (b - a) + v[m, None] * (c - a)
    d = np.linalg.norm(pts - p, axis=1)
    k = int(np.argmin(d))
    best, best_d = pts[k], d[k]
    return best, best_d


def test_closest_point_on_triangle_matches_brute_force(device):
    rng = np.random.default_rng(3)
    a, b, c = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.1, 0.0]), np.array([0.3, 0.8, 0.2])
    p = rng.uniform(-0.8, 1.6, size=(200, 3)).astype(np.float32)
    out = wp.zeros(len(p), dtype=wp.vec3, device=device)
    wp.launch(_bary_kernel, dim=len(p), inputs=[wp.array(p, dtype=wp.vec3, device=device), wp.vec3(*a),
                                                 wp.vec3(*b), wp.vec3(*c)], outputs=[out], device=device)
    w = out.numpy().astype(np.float64)
    assert np.all(w >= -1e-6)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-5)
    q = w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c
    for i in range(len(p)):
        _, d_ref = closest_point_triangle_np(p[i].astype(np.float64), a, b, c)
        d = np.linalg.norm(q[i] - p[i])
        # the sampled reference is an upper bound within its grid spacing
        assert d <= d_ref + 1e-5
        assert d >= d_ref - 0.01


def two_layers(n: int = 4, gap: float = 0.002, angle: float = 0.5):
    """A flat square sheet and a smaller, rotated sheet ``gap`` above it (one mesh)."""
    v0, f0 = grid(n, n, 0.04, 0.04, plane="xz")
    v1, f1 = grid(n, n, 0.03, 0.03, plane="xz")
    ca, sa = np.cos(angle), np.sin(angle)
    rot = np.array([[ca, 0, -sa], [0, 1, 0], [sa, 0, ca]], dtype=np.float32)
    v1 = (v1 - v1.mean(axis=0)) @ rot.T + v0.mean(axis=0) + np.array([0.001, gap, 0.002], np.float32)
    return np.concatenate([v0, v1]), np.concatenate([f0, f1 + len(v0)]).astype(np.int32)


def contact_pairs_np(x, faces, reach):
    """Vertex-triangle and edge-edge (no shared vertex) pairs closer than ``reach``."""
    vt = [(i, t) for i in range(len(x)) for t, f in enumerate(faces)
          if i not in f and np.linalg.norm(x[i] - x[f].mean(axis=0)) < reach + 0.015]
    edges = mesh_edges(faces)
    ee = [(a, b) for a in range(len(edges)) for b in range(a + 1, len(edges))
          if not set(edges[a]) & set(edges[b])
          and np.linalg.norm(x[edges[a]].mean(axis=0) - x[edges[b]].mean(axis=0)) < reach + 0.015]
    return vt, [(edges[a], edges[b]) for a, b in ee]


def contact_energy_np(x, faces, pairs, radius, k):
    """Sum over vertex-triangle pairs and unordered edge-edge pairs of ``k/2 (radius - d)^2``
    for ``d < radius``."""
    vt, ee = pairs
    e_total = 0.0
    for i, t in vt:
        f = faces[t]
        w = _bary_np(x[i], x[f[0]], x[f[1]], x[f[2]])
        d = np.linalg.norm(x[i] - (w[0] * x[f[0]] + w[1] * x[f[1]] + w[2] * x[f[2]]))
        if d < radius:
            e_total += 0.5 * k * (radius - d) ** 2
    for ea, eb in ee:
        d = _segment_distance_np(x[ea[0]], x[ea[1]], x[eb[0]], x[eb[1]])
        if d < radius:
            e_total += 0.5 * k * (radius - d) ** 2
    return e_total


def _bary_np(p, a, b, c):
    """Exact closest point (projection + edges) in float64."""
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    q = p - np.dot(p - a, n) * n
    m = np.array([b - a, c - a]).T
    uv, *_ = np.linalg.lstsq(m, q - a, rcond=None)
    if uv[0] >= 0 and uv[1] >= 0 and uv.sum() <= 1:
        return np.array([1 - uv.sum(), uv[0], uv[1]])
    best = None
    for (i, j) in ((0, 1), (1, 2), (2, 0)):
        pts = (a, b, c)
        s = np.clip(np.dot(p - pts[i], pts[j] - pts[i]) / np.dot(pts[j] - pts[i], pts[j] - pts[i]), 0, 1)
        w = np.zeros(3)
        w[i], w[j] = 1 - s, s
        d = np.linalg.norm(p - (pts[i] + s * (pts[j] - pts[i])))
        if best is None or d < best[0]:
            best = (d, w)
    return best[1]


def _segment_distance_np(p1, q1, p2, q2):
    """Exact segment-segment distance (Ericson, Real-Time Collision Detection, 5.1.9)."""
    return _segment_closest_np(p1, q1, p2, q2)[0]


def _segment_closest_np(p1, q1, p2, q2):
    """Segment-segment distance and the closest points' parameters ``s`` on ``p1 q1``, ``t`` on
    ``p2 q2`` (Ericson, Real-Time Collision Detection, 5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = np.dot(d1, d1), np.dot(d2, d2), np.dot(d2, r)
    c, b = np.dot(d1, r), np.dot(d1, d2)
    denom = a * e - b * b
    s = np.clip((b * f - c * e) / denom, 0.0, 1.0) if denom > 1e-18 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, np.clip(-c / a, 0.0, 1.0)
    elif t > 1.0:
        t, s = 1.0, np.clip((b - c) / a, 0.0, 1.0)
    return np.linalg.norm((p1 + s * d1) - (p2 + t * d2)), s, t


@wp.kernel
def _force_kernel(x: wp.array(dtype=wp.vec3), tri_indices: wp.array(dtype=wp.vec3i),
                  vt_off: wp.array(dtype=wp.int32), vt_ids: wp.array(dtype=wp.int32),
                  vt_local: wp.array(dtype=wp.int32), sc: SelfContactData,
                  f_out: wp.array(dtype=wp.vec3), h_out: wp.array(dtype=wp.mat33)):
    i = wp.tid()
    f, h = self_contact_force_hessian(i, 0, 1, x, x, x, tri_indices, vt_off, vt_ids, vt_local, sc, 1.0e-3)
    f_out[i] = f
    h_out[i] = h


def test_self_contact_forces_match_finite_differences(device):
    x, faces = two_layers()
    radius, k = 0.004, 1.0e3
    b = ClothModelBuilder()
    b.add_cloth(x, faces, ClothMaterialParams())
    m = b.finalize(device)
    sc = SelfContact(m, radius=radius, margin=0.01, stiffness=k, friction=0.0, relaxation=0.45,
                     speed_factor=2.5, capacity=32)
    xd = wp.array(x, dtype=wp.vec3, device=device)
    sc.detect(xd, wp.zeros_like(xd), 1.0 / 300.0)
    f = wp.zeros(len(x), dtype=wp.vec3, device=device)
    hs = wp.zeros(len(x), dtype=wp.mat33, device=device)
    wp.launch(_force_kernel, dim=len(x), inputs=[xd, m.tri_indices, m.vertex_tri_offsets, m.vertex_tri_ids,
                                                 m.vertex_tri_local, sc.data], outputs=[f, hs], device=device)
    f, hs = f.numpy().astype(np.float64), hs.numpy().astype(np.float64)
    x64 = x.astype(np.float64)
    pairs = contact_pairs_np(x64, faces, radius)
    assert contact_energy_np(x64, faces, pairs, radius, k) > 0.0  # the layers are in contact
    eps = 1e-6
    checked = 0
    for i in range(len(x)):
        g = np.zeros(3)
        for a in range(3):
            xp, xm = x64.copy(), x64.copy()
            xp[i, a] += eps
            xm[i, a] -= eps
            e_p = contact_energy_np(xp, faces, pairs, radius, k)
            g[a] = (e_p - contact_energy_np(xm, faces, pairs, radius, k)) / (2 * eps)
        np.testing.assert_allclose(f[i], -g, atol=2e-3 * max(1.0, np.abs(g).max()) + 1e-6)
        if np.abs(g).max() > 1e-4:
            checked += 1
            # the Hessian block is the PSD Gauss-Newton part: symmetric, >= 0
            np.testing.assert_allclose(hs[i], hs[i].T, atol=1e-3 * np.abs(hs[i]).max())
            assert np.linalg.eigvalsh(0.5 * (hs[i] + hs[i].T)).min() > -1e-3 * np.abs(hs[i]).max()
    assert checked >= 8


def stacked_layers(device, self_contact: bool, n: int = 13, frames: int = 12, bounds: bool = True,
                   speed: float = 3.0, carry: float = 0.0, reference: bool = False,
                   air_damping: float = VBDConfig.air_damping, **config):
    """A sheet pinned at its corners and a second sheet dropped onto it at ``speed`` (one mesh),
    the whole scene, pins included, carried along x at ``carry`` [m/s] (``reference``: that is
    the instance's reference velocity, else zero); ``config``: further solver settings. Returns
    the positions per frame with the carrying motion taken out, the faces, the vertices per
    sheet and the grid size."""
    v, f = grid(n, n, 0.5, 0.5, plane="xz")
    top = v + np.array([0.011, 0.03, 0.013], np.float32)
    x = np.concatenate([v, top])
    faces = np.concatenate([f, f + len(v)])
    b = ClothModelBuilder()
    b.add_cloth(x, faces, ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.003),
                pinned=[0, n - 1, n * (n - 1), n * n - 1])
    m = b.finalize(device)
    solver = SolverVBD(m, VBDConfig(substeps=5, iterations=5, self_contact=self_contact,
                                    self_contact_bounds=bounds, air_damping=air_damping, **config))
    state = m.state()
    u = np.array([carry, 0.0, 0.0], np.float32)
    vel = np.zeros_like(x) + u
    vel[len(v):, 1] = -speed
    state.velocities.assign(vel)
    control = m.control()
    if reference:
        control.instance_velocity.assign(u[None])
    dt = 1.0 / 30.0
    out = []
    for k in range(frames):
        control.pin_targets.assign(x + u * (k + 1) * dt)
        solver.step(state, state, control, dt)
        out.append(state.positions.numpy() - u * (k + 1) * dt)
    return np.stack(out), faces, len(v), n


def _center_gap(x, nv, n):
    """Height of the top sheet above the bottom one at the centre (same grid index)."""
    c = (n // 2) * n + n // 2
    return x[:, nv + c, 1] - x[:, c, 1]


def test_two_stacked_layers_never_pass_through_each_other(device):
    x, faces, nv, n = stacked_layers(device, True)
    assert np.all(np.isfinite(x))
    assert np.all(self_intersections(x, faces, device=device) == 0)
    gap = _center_gap(x, nv, n)
    assert np.all(gap > 0.0)
    assert gap[-1] > 0.5 * VBDConfig().self_contact_radius
    assert gap[-1] < 0.03  # it did land on the lower sheet
    # without self-contact the same drop goes straight through
    x_off, *_ = stacked_layers(device, False)
    assert _center_gap(x_off, nv, n).min() < -0.02


@pytest.mark.parametrize("config", [{}, {"self_contact_pipeline": True}, {"self_contact_ee_interior": True},
                                    {"self_contact_lookahead": True},
                                    {"self_contact_broadphase": "clusters"}])
def test_penalty_self_contact_holds_a_gently_dropped_layer(device, config):
    """Without the bounds (the default) the penalty alone stops a layer dropped at 1 m/s (the
    rims, where the loose layer folds over the pinned one's edge, may cross: no guarantee); so
    does it with each substep's pairs detected during the substep before (``pipeline``), with
    edge pairs stored only where their closest points are inside both edges, with each
    substep's lists re-measured from candidates found a substep ahead (``lookahead``), and with
    the pairs found through clusters instead of trees (``broadphase``)."""
    x, faces, nv, n = stacked_layers(device, True, bounds=False, speed=1.0, frames=20, **config)
    gap = _center_gap(x, nv, n)
    assert np.all(gap > 0.0) and gap[-1] < 0.03
    x_off, *_ = stacked_layers(device, False, speed=1.0, frames=20)
    assert _center_gap(x_off, nv, n).min() < -0.02


def _layers_in_a_moving_frame(device, velocity, reference: bool):
    """``stacked_layers`` (9 x 9, bounds on, no air drag) carried at ``velocity`` [m/s]."""
    return stacked_layers(device, True, n=9, frames=10, carry=velocity, reference=reference,
                          air_damping=0.0)[0]


def test_a_moving_frame_searched_in_its_own_frame_gives_the_same_cloth(device):
    """Galilean invariance: the stacked-layer drop with the whole scene carried along at 3 m/s,
    and self-contact searched in the instance's frame (``ClothControl.instance_velocity``), is
    the still drop moved along: the same to float rounding in the first frame; once the
    layers press on each other float32 rounding of the shifted coordinates grows into
    millimetres at single vertices (contact onset is not smooth; the CPU and CUDA differ in
    when), but the cloth does not lag (mean offset along the motion < 0.5 mm). Searched in
    the world frame instead, the displacement bounds (absolute per substep) hold the carried
    cloth back by centimetres per frame."""
    still = _layers_in_a_moving_frame(device, 0.0, False)
    carried = _layers_in_a_moving_frame(device, 3.0, True)
    held = _layers_in_a_moving_frame(device, 3.0, False)
    assert np.all(np.isfinite(carried))
    np.testing.assert_allclose(carried[0], still[0], atol=1e-4)
    assert np.abs((carried - still)[..., 0].mean(axis=1)).max() < 5e-4
    assert np.linalg.norm(carried - still, axis=2).mean() < 5e-3
    assert (held - still)[-1, :, 0].mean() < -0.05


@pytest.mark.parametrize("lookahead", [False, True])
def test_instances_do_not_collide_with_each_other(device, lookahead):
    """Two overlapping sheets as separate instances of one model fall through each other
    exactly as alone (self-contact only acts within an instance), with each substep's pairs
    detected or re-measured from candidates found a substep ahead."""
    v, f = grid(7, 7, 0.3, 0.3, plane="xz")
    cfg = VBDConfig(substeps=3, iterations=3, self_contact=True, self_contact_lookahead=lookahead)

    def run(parts):
        b = ClothModelBuilder()
        for vv in parts:
            b.add_cloth(vv, f, ClothMaterialParams())
        m = b.finalize(device)
        return simulate(m, SolverVBD(m, cfg), m.control(), 5, 1.0 / 30.0)

    lower = v
    upper = v + np.array([0.01, 0.005, 0.02], np.float32)
    both = run([lower, upper])
    np.testing.assert_allclose(both[:, :len(v)], run([lower]), atol=1e-6)
    np.testing.assert_allclose(both[:, len(v):], run([upper]), atol=1e-6)


@wp.kernel
def _group_roots_direct(bvh: wp.uint64, out: wp.array(dtype=wp.int32)):
    g = wp.tid()
    out[g] = wp.bvh_get_group_root(bvh, g)


def test_instance_roots_found_at_rebuilds_give_each_instance_its_own_pairs(device):
    """The detection queries start at each instance's subtree root, found once per tree build
    (``group_roots_kernel``) instead of by every query thread. Three instances of two layers in
    contact: the roots equal Warp's per-thread ``bvh_get_group_root``, and each instance's pair
    counts equal those of the same layers detected alone, as built and after rebuilds at other
    positions. (In Warp 1.19 a group's root index depends only on the groups' sizes, so a rebuild
    leaves it where it was; ``detect`` still refinds the roots at every rebuild, and the equality
    with ``bvh_get_group_root`` after rebuilds is what would catch a builder that numbers its
    nodes otherwise.)"""
    nx, e = 7, 0.012
    v1, f1 = grid(nx, nx, (nx - 1) * e, (nx - 1) * e, plane="xz")
    v2 = v1 + np.array([0.4 * e, 0.003, 0.3 * e], np.float32)
    layers = np.concatenate([v1, v2]).astype(np.float32)
    faces = np.concatenate([f1, f1 + len(v1)]).astype(np.int32)
    kw = dict(radius=0.003, margin=0.006, stiffness=1e4, friction=0.0, relaxation=0.45, speed_factor=2.5,
              capacity=32)
    n = len(layers)

    def detect(parts, rebuild=False):
        b = ClothModelBuilder()
        for p in parts:
            b.add_cloth(p, faces, ClothMaterialParams())
        m = b.finalize(device)
        sc = SelfContact(m, **kw)
        if rebuild:  # build at other positions, then detect (and rebuild) where the parts are
            sc.detect(wp.array(np.concatenate(parts) * 0.5, dtype=wp.vec3, device=device),
                      wp.zeros(m.particle_count, dtype=wp.vec3, device=device), 1.0 / 300.0, rebuild=True)
        sc.detect(m.particle_q, wp.zeros(m.particle_count, dtype=wp.vec3, device=device), 1.0 / 300.0,
                  rebuild=rebuild)
        for k, bvh in enumerate(sc.bvhs):
            direct = wp.zeros(m.instance_count, dtype=wp.int32, device=device)
            wp.launch(_group_roots_direct, dim=m.instance_count, inputs=[bvh.id], outputs=[direct],
                      device=device)
            np.testing.assert_array_equal(sc._roots[k].numpy(), direct.numpy())
        d = sc.data
        counts = np.stack([d.vt_count.numpy(), d.tv_total.numpy(), d.ee_total.numpy()], axis=1)
        return [counts[a:a + n].tolist() for a in range(0, m.particle_count, n)]

    for rebuild in (False, True):
        offsets = [np.zeros(3), np.array([0.5, 0.0, 0.0]), np.array([0.0, 0.7, -0.3])]
        parts = [(layers + o).astype(np.float32) for o in offsets]
        alone = detect(parts[:1], rebuild)[0]
        assert sum(sum(t) for t in alone) > 50  # the layers are in contact
        for got in detect(parts, rebuild):
            assert got == alone


def test_self_contact_config_is_checked():
    with pytest.raises(ValueError, match="relaxation"):
        VBDConfig(self_contact_relaxation=0.6)
    with pytest.raises(ValueError, match="margin"):
        VBDConfig(self_contact_radius=0.02, self_contact_margin=0.01)
    # the lookahead re-measures candidates every substep: no interval, no bounds (d_min would
    # only cover candidates), not with the pipeline; its margin is a widening
    for other in ({"self_contact_interval": 2}, {"self_contact_bounds": True},
                  {"self_contact_pipeline": True}):
        with pytest.raises(ValueError, match="self_contact_lookahead needs"):
            VBDConfig(self_contact_lookahead=True, **other)
    with pytest.raises(ValueError, match="lookahead_margin"):
        VBDConfig(self_contact_lookahead=True, self_contact_lookahead_margin=-0.001)
    with pytest.raises(ValueError, match="broadphase"):
        VBDConfig(self_contact_broadphase="grid")
    with pytest.raises(ValueError, match="broadphase 'bvh'"):
        VBDConfig(self_contact_broadphase="clusters", self_contact_lookahead=True)
    with pytest.raises(ValueError, match="cluster_size"):
        VBDConfig(self_contact_cluster_size=0)
    # "auto": the clusters on CUDA for a small model, the trees on the CPU, for large models and
    # wherever the lookahead runs
    from sim.cloth import solver_vbd

    v, f = grid(3, 3, 0.1, 0.1, plane="xz")
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams())
    solver = SolverVBD(b.finalize("cpu"), VBDConfig(self_contact=True))
    assert solver.broadphase(cuda=True) == "clusters" and solver.broadphase(cuda=False) == "bvh"
    assert solver.self_contact.clusters is None
    solver.config = VBDConfig(self_contact=True, self_contact_lookahead=True)
    assert solver.broadphase(cuda=True) == "bvh"
    solver.config = VBDConfig(self_contact=True)
    m = solver.model
    primitives = m.particle_count + m.tri_count + m.mesh_edge_indices.shape[0]
    assert primitives == 9 + 8 + 16  # the 3 x 3 grid's vertices, triangles and edges
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(solver_vbd, "CLUSTER_PRIMITIVES", primitives - 1)
        assert solver.broadphase(cuda=True) == "bvh"
        mp.setattr(solver_vbd, "CLUSTER_PRIMITIVES", primitives)
        assert solver.broadphase(cuda=True) == "clusters"


def folded_sheet(nx: int, ny: int, e: float, mid: int, gap: float):
    """An ``nx`` x ``ny`` grid of spacing ``e`` in the xz plane (its rest shape ``v``) and the
    same sheet folded flat onto itself at column ``mid``: the columns past it lie ``gap``
    above the ones before it. Returns ``v``, the folded positions, the faces and each vertex's
    column."""
    v, f = grid(nx, ny, (nx - 1) * e, (ny - 1) * e, plane="xz")
    col = np.arange(len(v)) % nx
    folded = v.copy()
    over = col > mid
    folded[over, 0] = (2 * mid - col[over]) * e
    folded[over, 1] = gap
    return v, folded, f, col


def test_a_fold_of_one_sheet_is_in_contact_a_ring_away(device):
    """A sheet folded flat onto itself (zero fold radius at column ``m``): the vertex one
    column past the fold lies 2 mm above the column before it, two edges away on the surface.
    It is a contact pair (the exclusion is by the pair's own rest distance, not by a few edge
    lengths: a sleeve that crumples is two rings meeting); pairs incident at the fold, at rest
    distance 0, are not."""
    nx, ny, mid = 11, 4, 5
    v, folded, f, col = folded_sheet(nx, ny, 0.02, mid, 0.002)
    b = ClothModelBuilder()
    b.add_cloth(v.astype(np.float32), f, ClothMaterialParams())
    m = b.finalize(device)
    sc = SelfContact(m, radius=0.003, margin=0.01, stiffness=1e4, friction=0.0, relaxation=0.45,
                     speed_factor=2.5, capacity=16)
    x0 = wp.array(folded.astype(np.float32), dtype=wp.vec3, device=device)
    sc.detect(x0, wp.zeros(len(v), dtype=wp.vec3, device=device), 1.0 / 300.0)
    count = sc.data.vt_count.numpy()
    tri = sc.data.vt_tri.numpy().reshape(len(v), 16)
    faces = np.asarray(f)
    for j in range(1, ny - 1):
        i = j * nx + mid + 1  # one column past the fold, above column mid - 1
        partners = faces[tri[i, :count[i]]]
        assert count[i] > 0, "a vertex folded onto its own sheet two edges away must be in contact"
        assert np.all(col[partners] <= mid)  # the layer below
        assert not np.any(partners == i)  # never its own triangles
    # the fold line itself: close to everything around it, but only through incident or rest-near pairs
    for j in range(ny):
        i = j * nx + mid
        partners = faces[tri[i, :count[i]]]
        assert not np.any(partners == i)


def _stored(sc, owners: int, ids: str, count: str) -> set:
    """The (owner, partner) pairs of one of ``sc``'s lists (``ids`` / ``count``: its arrays)."""
    c = getattr(sc.data, count).numpy()
    table = getattr(sc.data, ids).numpy().reshape(owners, -1)
    return {(k, int(table[k, j])) for k in range(owners) for j in range(c[k])}


def test_edge_pairs_at_an_edge_end_are_left_to_vertex_triangle_pairs(device):
    """``ee_interior``: an edge-edge pair is stored only where its closest points lie inside both
    edges. Two crossing sheets 2.5 mm apart give both kinds. Every pair of the full lists with
    closest points well inside both edges is kept, every one with a closest point at an edge's
    end is dropped, and for each dropped one the end vertex already has a stored vertex-triangle
    pair at most as far (a triangle at the other edge), so no contact is lost."""
    x, faces = two_layers(n=7, gap=0.0025, angle=0.5)
    b = ClothModelBuilder()
    b.add_cloth(x, faces, ClothMaterialParams())
    m = b.finalize(device)
    lists = []
    for interior in (False, True):
        sc = SelfContact(m, radius=0.003, margin=0.004, stiffness=1e4, friction=0.0, relaxation=0.45,
                         speed_factor=2.5, capacity=64, ee_interior=interior)
        sc.detect(m.particle_q, wp.zeros(len(x), dtype=wp.vec3, device=device), 1.0 / 300.0)
        lists.append(sc)
    edges = m.mesh_edge_indices.numpy()
    ne = len(edges)
    every, inside = (_stored(sc, ne, "ee_edge", "ee_count") for sc in lists)
    vt = _stored(lists[1], len(x), "vt_tri", "vt_count")
    assert vt == _stored(lists[0], len(x), "vt_tri", "vt_count")  # vertex-triangle pairs unchanged
    xd = x.astype(np.float64)
    kinds = {"interior": 0, "end": 0}
    for e, f in every:
        (a0, a1), (b0, b1) = edges[e], edges[f]
        d, s, t = _segment_closest_np(xd[a0], xd[a1], xd[b0], xd[b1])
        u, w = xd[a1] - xd[a0], xd[b1] - xd[b0]
        if np.linalg.norm(np.cross(u, w)) < 1e-3 * np.linalg.norm(u) * np.linalg.norm(w):
            continue  # parallel (one sheet's own edges): ends and insides are equally close
        if min(s, 1 - s, t, 1 - t) > 1e-3:
            kinds["interior"] += 1
            assert (e, f) in inside
        elif min(s, 1 - s) == 0.0 or min(t, 1 - t) == 0.0:
            kinds["end"] += 1
            assert (e, f) not in inside
            end = (a0 if s == 0.0 else a1) if min(s, 1 - s) == 0.0 else (b0 if t == 0.0 else b1)
            other = (b0, b1) if min(s, 1 - s) == 0.0 else (a0, a1)
            near = [tri for (i, tri) in vt if i == end and set(other) & set(faces[tri].tolist())]
            assert near, f"edge pair {e}-{f}: its end vertex {end} has no triangle pair at the other edge"
            dist = min(np.linalg.norm(xd[end] - _bary_np(xd[end], *xd[faces[t_]]) @ xd[faces[t_]])
                       for t_ in near)
            assert dist <= d + 1e-6
    assert inside <= every
    assert kinds["interior"] > 5 and kinds["end"] > 5, kinds


def test_detection_slots_hold_separate_lists(device):
    """``SelfContact(slots=2)``: a detection fills only its own slot's lists and gather records,
    the same as a one-slot detection at those positions; the other slot keeps what it had."""
    x, faces = two_layers(n=6, gap=0.002, angle=0.4)
    b = ClothModelBuilder()
    b.add_cloth(x, faces, ClothMaterialParams())
    m = b.finalize(device)
    kw = dict(radius=0.003, margin=0.004, stiffness=1e4, friction=0.0, relaxation=0.45, speed_factor=2.5,
              capacity=16)
    shifted = x.copy()
    shifted[len(x) // 2:, 1] += 0.0015  # the upper sheet 1.5 mm higher: fewer pairs
    states = [wp.array(p, dtype=wp.vec3, device=device) for p in (x, shifted)]
    zeros = wp.zeros(len(x), dtype=wp.vec3, device=device)
    two = SelfContact(m, slots=2, **kw)
    two.detect(states[0], zeros, 1.0 / 300.0, slot=0)
    two.detect(states[1], zeros, 1.0 / 300.0, slot=1)
    names = ("vt_count", "tv_count", "ee_count", "pair_count", "bound")
    for slot, state in enumerate(states):
        one = SelfContact(m, **kw)
        one.detect(state, zeros, 1.0 / 300.0)
        for name in names:
            np.testing.assert_array_equal(getattr(two.datas[slot], name).numpy(),
                                          getattr(one.data, name).numpy(), err_msg=f"slot {slot} {name}")
    assert two.datas[0].pair_count.numpy().sum() > two.datas[1].pair_count.numpy().sum() > 0
    with pytest.raises(ValueError, match="slots"):
        SelfContact(m, slots=2, side_memory=True, **kw)


def test_full_pair_lists_keep_the_closest_pairs(device):
    """With room for 2 pairs, a vertex lying over many triangles keeps the 2 closest, whatever
    order the BVH finds them in (first-found lists let a crumple's near neighbours crowd out the
    layer that is actually touching)."""
    nx, ny, e = 11, 6, 0.01
    v, f = grid(nx, ny, (nx - 1) * e, (ny - 1) * e, plane="xz")
    # one instance, two pieces: the sheet and a small triangle 4 mm over it
    probe = np.array([[0.052, 0.004, 0.021], [0.053, 0.004, 0.021], [0.052, 0.004, 0.022]], np.float32)
    b = ClothModelBuilder()
    b.add_cloth(np.concatenate([v.astype(np.float32), probe]),
                np.concatenate([np.asarray(f), np.array([[len(v), len(v) + 2, len(v) + 1]])]),
                ClothMaterialParams())
    m = b.finalize(device)
    x = m.particle_q.numpy()
    sc = SelfContact(m, radius=0.003, margin=0.012, stiffness=1e4, friction=0.0, relaxation=0.45,
                     speed_factor=2.5, capacity=2)
    sc.detect(m.particle_q, wp.zeros(len(x), dtype=wp.vec3, device=device), 1.0 / 300.0)
    i = len(v)  # the probe triangle's first vertex, 4 mm over the sheet
    count = int(sc.data.vt_count.numpy()[i])
    stored = sc.data.vt_tri.numpy().reshape(-1, 2)[i, :count]
    faces = np.asarray(f)
    d_all = np.array([closest_point_triangle_np(x[i].astype(np.float64), *x[faces[t]].astype(np.float64))[1]
                      for t in range(len(faces))])
    assert (d_all < 0.012).sum() > 2  # more candidates than room
    assert count == 2
    d_stored = np.sort(d_all[stored])
    np.testing.assert_allclose(d_stored, np.sort(d_all)[:2], atol=2e-4)


@wp.kernel
def _lane_force_kernel(x: wp.array(dtype=wp.vec3), tri_indices: wp.array(dtype=wp.vec3i),
                       vt_off: wp.array(dtype=wp.int32), vt_ids: wp.array(dtype=wp.int32),
                       vt_local: wp.array(dtype=wp.int32), sc: SelfContactData, stride: int,
                       f_out: wp.array(dtype=wp.vec3), h_out: wp.array(dtype=wp.mat33)):
    i = wp.tid()
    f = wp.vec3(0.0)
    h = wp.mat33(0.0)
    for lane in range(stride):
        fl, hl = self_contact_force_hessian(i, lane, stride, x, x, x, tri_indices, vt_off, vt_ids, vt_local,
                                            sc, 1.0e-3)
        f = f + fl
        h = h + hl
    f_out[i] = f
    h_out[i] = h


def self_contact_forces(m, sc, x: np.ndarray, device: str) -> np.ndarray:
    """Self-contact force on every vertex of model ``m`` at positions ``x`` (one lane)."""
    xw = wp.array(x, dtype=wp.vec3, device=device)
    fo = wp.zeros(len(x), dtype=wp.vec3, device=device)
    ho = wp.zeros(len(x), dtype=wp.mat33, device=device)
    inputs = [xw, m.tri_indices, m.vertex_tri_offsets, m.vertex_tri_ids, m.vertex_tri_local, sc.data, 1]
    wp.launch(_lane_force_kernel, dim=len(x), inputs=inputs, outputs=[fo, ho], device=device)
    return fo.numpy()


def test_lanes_of_the_tiled_solve_share_every_pair_once(device):
    """The solve splits a vertex's stored pairs over ``stride`` lanes: the lanes' sum must be the
    one-lane total for any stride (a pair skipped or counted twice changes it), on a fold where
    triangles and edges hold different numbers of pairs. The vertices' gather records (pool 128),
    the pair lists (pool 0: every vertex falls back) and a pool that holds only some vertices'
    records must all give the same forces."""
    x, faces = two_layers(n=6, gap=0.0015)
    b = ClothModelBuilder()
    b.add_cloth(x, faces, ClothMaterialParams())
    m = b.finalize(device)
    # move the points a little so friction and the crossing sign see a displacement
    rng = np.random.default_rng(3)
    xm = wp.array(x + rng.normal(0.0, 4e-4, x.shape).astype(np.float32), dtype=wp.vec3, device=device)
    out = {}
    # pool 2 (144 records) holds any one vertex's records (at most 104 here), so the first
    # reservation fits in any atomic order (CUDA), but not all 5,083: some vertices fall back
    for pool in (0, 128, 2):
        sc = SelfContact(m, radius=0.004, margin=0.006, stiffness=1.0e3, friction=0.3, relaxation=0.45,
                         speed_factor=2.5, capacity=8, pool=pool)
        xd = wp.array(x, dtype=wp.vec3, device=device)
        sc.detect(xd, wp.zeros_like(xd), 1.0 / 300.0)
        counts = np.concatenate([sc.data.tv_count.numpy(), sc.data.ee_count.numpy()])
        assert len(np.unique(counts)) >= 5 and (counts == 0).any()   # uneven lists: the split is exercised
        total = sc.data.pair_count.numpy()
        fell_back = (sc.data.pair_first.numpy() < 0)[total > 0]
        expected = {0: fell_back.all(), 128: not fell_back.any(), 2: 0 < fell_back.mean() < 1}
        assert expected[pool], (pool, fell_back.mean())
        for stride in (1, 3, 16):
            f = wp.zeros(len(x), dtype=wp.vec3, device=device)
            hs = wp.zeros(len(x), dtype=wp.mat33, device=device)
            wp.launch(_lane_force_kernel, dim=len(x), inputs=[xm, m.tri_indices, m.vertex_tri_offsets,
                                                              m.vertex_tri_ids, m.vertex_tri_local, sc.data,
                                                              stride], outputs=[f, hs], device=device)
            out[pool, stride] = (f.numpy(), hs.numpy())
    f1, h1 = out[0, 1]
    assert np.abs(f1).max() > 0.0
    for key, (f, hs) in out.items():
        np.testing.assert_allclose(f, f1, rtol=1e-4, atol=1e-5 * np.abs(f1).max(), err_msg=str(key))
        np.testing.assert_allclose(hs, h1, rtol=1e-4, atol=1e-5 * np.abs(h1).max(), err_msg=str(key))


def _point_triangle_distance_np(p, a, b, c):
    """Exact distance: the plane projection when it falls inside, else the nearest edge."""
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    q = p - ((p - a) @ n) * n
    inside = all(np.cross(v1 - v0, q - v0) @ n >= 0.0 for v0, v1 in ((a, b), (b, c), (c, a)))
    if inside:
        return float(abs((p - a) @ n))
    def to_segment(s0, s1):
        t = np.clip((p - s0) @ (s1 - s0) / ((s1 - s0) @ (s1 - s0)), 0.0, 1.0)
        return float(np.linalg.norm(p - (s0 + t * (s1 - s0))))

    return min(to_segment(a, b), to_segment(b, c), to_segment(c, a))


@pytest.mark.parametrize("motion,frame,ring", [("still", 0.0, False), ("together", 0.0, False),
                                               ("sliding", 0.0, False), ("together", 3.0, False),
                                               ("sliding", 3.0, False), ("together", 0.0, True)])
def test_detection_finds_exactly_the_pairs_within_the_query_radius(device, motion, frame, ring):
    """Pair detection against brute force: a flat sheet and a jittered sheet 2-8 mm above it
    (one instance, two pieces), still, moving together at 3 m/s, or the upper one sliding over
    the lower at 3 m/s, searched in the frame moving at ``frame`` m/s along x (the instance's
    reference velocity). A primitive's query radius is ``max(margin, 2.5 |v - v_ref| h)`` of its
    own speed in that frame; of the pairs within it, exactly those closer than the radius of
    their relative speed ``max(margin, 2.5 |v_a - v_b| h)`` are stored (layers moving together
    keep only the 6 mm pairs, a sliding layer the 25 mm ones), never an incident pair, nor with
    ``ring_exclusion`` a pair of surface neighbours an edge apart (at rest >= the contact radius
    apart); the nearest distance is the minimum over every other pair within the query radius,
    stored or not (capped at it). Layers moving together, searched in their own frame, are searched as if
    still: every query radius is the margin."""
    nx, ny, e, r, h, sf = 7, 6, 0.012, 0.006, 1.0 / 300.0, 2.5
    v1, f1 = grid(nx, ny, (nx - 1) * e, (ny - 1) * e, plane="xz")
    rng = np.random.default_rng(5)
    v2 = v1 + np.array([0.4 * e, 0.0, 0.3 * e], np.float32)
    v2[:, 1] = rng.uniform(0.002, 0.008, len(v2))
    v = np.concatenate([v1, v2]).astype(np.float32)
    f = np.concatenate([f1, f1 + len(v1)]).astype(np.int32)
    vel = np.zeros_like(v)
    if motion != "still":
        vel[len(v1):] = (3.0, 0.0, 0.0)
    if motion == "together":
        vel[:len(v1)] = (3.0, 0.0, 0.0)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams())
    m = b.finalize(device)
    cap = 128
    sc = SelfContact(m, radius=0.003, margin=r, stiffness=1e4, friction=0.0, relaxation=0.45,
                     speed_factor=sf, capacity=cap, ring_exclusion=ring)
    ref = np.array([frame, 0.0, 0.0], np.float32)
    sc.detect(m.particle_q, wp.array(vel, dtype=wp.vec3, device=device), h,
              reference=wp.array(ref[None], dtype=wp.vec3, device=device))
    x = v.astype(np.float64)
    sep = 2e-5  # pairs this close to a radius are left out of the comparison (float32 detection)
    speed = np.linalg.norm(vel - ref, axis=1)

    def radius(s):
        return max(r, sf * s * h)

    def classify(d, r_query, r_list, want, away, key):
        """Put ``key`` in ``want`` (stored) or ``away`` (not stored), unless at a threshold."""
        if abs(d - r_query) > sep and abs(d - r_list) > sep:
            (want if d < min(r_query, r_list) else away).add(key)

    def lists(count, ids, rows):
        c, ids = count.numpy(), ids.numpy().reshape(rows, cap)
        assert c.max() < cap
        return {(a, int(o)) for a in range(rows) for o in ids[a, :c[a]]}

    found = lists(sc.data.vt_count, sc.data.vt_tri, len(v))
    tv_found = lists(sc.data.tv_count, sc.data.tv_vertex, len(f))
    want, away, tv_want, tv_away = set(), set(), set(), set()
    dmin = np.array([radius(s) for s in speed])
    edges = m.mesh_edge_indices.numpy()
    joined = {(int(a), int(b)) for a, b in edges} | {(int(b), int(a)) for a, b in edges}
    rest = m.particle_rest.numpy().astype(np.float64)
    ring_pairs = 0
    for i in range(len(v)):
        for t, tri in enumerate(f):
            if i in tri:
                continue
            d = _point_triangle_distance_np(x[i], *x[tri])
            if ring and any((i, int(c)) in joined for c in tri) and \
                    _point_triangle_distance_np(rest[i], *rest[tri]) >= 0.003:
                ring_pairs += d < radius(speed[i])
                continue  # surface neighbours an edge apart: the ring exclusion
            r_list = radius(np.linalg.norm(vel[i] - vel[tri[0]]))  # one velocity per sheet
            if d < dmin[i]:
                dmin[i] = d
            classify(d, radius(speed[i]), r_list, want, away, (i, t))
            classify(d, radius(speed[tri].max()), r_list, tv_want, tv_away, (t, i))
    assert len(want) > 50 and len(tv_want) > 50
    if ring:
        assert ring_pairs > 50  # the 25 mm queries reach the neighbours; none is stored
    assert want <= found and not (found & away)
    assert tv_want <= tv_found and not (tv_found & tv_away)
    np.testing.assert_allclose(sc._dmins[0].numpy(), dmin, atol=2e-5)

    ee_found = lists(sc.data.ee_count, sc.data.ee_edge, len(edges))
    ee_want, ee_away = set(), set()
    for a, (p, q) in enumerate(edges):
        for c, (s_, t_) in enumerate(edges):
            if len({p, q, s_, t_}) < 4:
                continue
            if ring and (any((int(u), int(w)) in joined for u in (p, q) for w in (s_, t_))
                    and _segment_distance_np(rest[p], rest[q], rest[s_], rest[t_]) >= 0.003):
                continue
            d = _segment_distance_np(x[p], x[q], x[s_], x[t_])
            r_list = radius(np.linalg.norm(vel[p] - vel[s_]))
            classify(d, radius(speed[[p, q]].max()), r_list, ee_want, ee_away, (a, c))
    assert len(ee_want) > 50
    assert ee_want <= ee_found and not (ee_found & ee_away)
    if motion == "together":
        assert all(_point_triangle_distance_np(x[i], *x[f[t]]) < r + sep for i, t in found)
        if frame == 0.0:
            # pairs beyond the margin inside the 25 mm query: in d_min, not in the lists
            assert sc._dmins[0].numpy().max() > r + 1e-3
        else:  # in their own frame the layers stand still: every query is the margin
            assert sc._dmins[0].numpy().max() <= r + 1e-6


def sheet_and_probe(probe, device: str):
    """A 3 x 3-cell, 3 cm sheet in the xz plane and a probe triangle (its first corner the tip)
    in one model: (model, the tip's index)."""
    nx, e = 4, 0.01
    v, f = grid(nx, nx, (nx - 1) * e, (nx - 1) * e, plane="xz")
    b = ClothModelBuilder()
    b.add_cloth(np.concatenate([v, np.asarray(probe, np.float32)]),
                np.concatenate([f, np.array([[len(v), len(v) + 2, len(v) + 1]])]), ClothMaterialParams())
    return b.finalize(device), len(v)


def test_a_pair_pushed_through_is_pushed_back_to_the_side_it_was_found_on(device):
    """Side memory: a vertex found 2 mm over a sheet, then pushed 1.5 mm under it (as a
    stronger body contact would), is pushed back up at the next detection; a vertex first found
    under the sheet is pushed further down (its side is where it was found). Without the
    memory, the crossed state at a substep start became the new side and the crossing stayed."""
    m, i = sheet_and_probe([[0.015, 0.002, 0.013], [0.03, 0.02, 0.013], [0.015, 0.02, 0.03]], device)
    above = m.particle_q.numpy()
    below = above.copy()
    below[i, 1] = -0.0015
    zeros = wp.zeros(len(above), dtype=wp.vec3, device=device)

    def force_on_tip(sc, x):
        return self_contact_forces(m, sc, x, device)[i]

    def contact(side_memory=True):
        return SelfContact(m, radius=0.003, margin=0.006, stiffness=1e4, friction=0.0, relaxation=0.45,
                           speed_factor=2.5, capacity=16, side_memory=side_memory)

    tracked = contact()
    tracked.detect(wp.array(above, dtype=wp.vec3, device=device), zeros, 1.0 / 300.0)
    assert tracked.data.vt_count.numpy()[i] > 0
    assert force_on_tip(tracked, above)[1] > 0.0  # 2 mm < 3 mm contact radius: pushed up, away
    tracked.detect(wp.array(below, dtype=wp.vec3, device=device), zeros, 1.0 / 300.0)
    f_back = force_on_tip(tracked, below)
    assert f_back[1] > 0.0, "a vertex pushed through must be pushed back to its side"
    # the penalty acts on the signed distance -1.5 mm: at least k (r_c + 1.5 mm) from the
    # triangle it crossed (more from its neighbours within r_c)
    assert f_back[1] >= 0.999 * 1e4 * (0.003 + 0.0015)
    fresh = contact()
    fresh.detect(wp.array(below, dtype=wp.vec3, device=device), zeros, 1.0 / 300.0)
    assert force_on_tip(fresh, below)[1] < 0.0  # found under the sheet: its side is below
    # without the memory the crossed state is the new side
    forgetful = contact(side_memory=False)
    for x in (above, below):
        forgetful.detect(wp.array(x, dtype=wp.vec3, device=device), zeros, 1.0 / 300.0)
    assert force_on_tip(forgetful, below)[1] < 0.0
    # once back on its side the reference follows the pair again
    tracked.detect(wp.array(above, dtype=wp.vec3, device=device), zeros, 1.0 / 300.0)
    assert force_on_tip(tracked, above)[1] > 0.0


def test_a_vertex_sliding_around_a_rim_is_not_taken_for_a_crossing(device):
    """Side memory only reverses a pair's side where its closest point is inside the triangle.
    A vertex 2 mm over a sheet near its rim that then slides around the rim to 1.5 mm beyond and
    1.5 mm below it has crossed nothing, although its separation turned by more than 90 degrees:
    it must be pushed away from the rim (out and down, by the penalty of its 2.1 mm distance),
    not back up through the sheet as a crossed vertex would be."""
    m, i = sheet_and_probe([[0.029, 0.002, 0.015], [0.06, 0.02, 0.013], [0.06, 0.02, 0.03]], device)
    above = m.particle_q.numpy()
    around = above.copy()
    around[i] = [0.0315, -0.0015, 0.015]
    zeros = wp.zeros(len(above), dtype=wp.vec3, device=device)
    k = 1e4
    sc = SelfContact(m, radius=0.003, margin=0.006, stiffness=k, friction=0.0, relaxation=0.45,
                     speed_factor=2.5, capacity=16, side_memory=True)
    for x in (above, around):
        sc.detect(wp.array(x, dtype=wp.vec3, device=device), zeros, 1.0 / 300.0)
        assert sc.data.vt_count.numpy()[i] > 0
    f_tip = self_contact_forces(m, sc, around, device)[i]
    assert f_tip[0] > 0.0 and f_tip[1] < 0.0, f_tip  # away from the rim, not up through the sheet
    d = np.hypot(0.0015, 0.0015)
    # each stored triangle at the rim pushes with k (r_c - d) along the separation: a crossed pair
    # would push with k (r_c + d) > 5e-2 N per triangle
    assert np.linalg.norm(f_tip) <= sc.data.vt_count.numpy()[i] * k * (0.003 - d) * 1.001


def hairpin_pass(device, gap: float, speed: float = 1.0, frames: int = 8, **config):
    """One sheet folded at rest into a hairpin whose arms lie ``gap`` apart (a crease at a seam,
    as under a t-shirt's arm or at the crotch of trousers), the lower arm pinned and the upper
    one thrown down onto it at ``speed`` [m/s]. Returns, per frame, the mean height [m] of the
    upper arm's interior (away from the fold and the rims) above the lower arm, the largest
    distance [m] of that interior past the fold line (> 0: the arm flipped over the fold, off
    the lower arm) and the kinetic plus gravitational energy [J] of the sheet, with the energy
    at the throw as the last entry."""
    nx, ny, mid, e = 13, 5, 6, 0.02
    _, folded, f, col = folded_sheet(nx, ny, e, mid, gap)
    row = np.arange(len(folded)) // nx
    over = col > mid
    b = ClothModelBuilder()
    b.add_cloth(folded.astype(np.float32), f, ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.001),
                pinned=np.flatnonzero(col < mid))
    m = b.finalize(device)
    solver = SolverVBD(m, VBDConfig(substeps=10, iterations=10, self_contact=True, **config))
    state, control = m.state(), m.control()
    vel = np.zeros_like(folded)
    vel[over, 1] = -speed
    state.velocities.assign(vel.astype(np.float32))
    control.pin_targets.assign(folded.astype(np.float32))
    interior = (col >= mid + 2) & (col <= nx - 3) & (row > 0) & (row < ny - 1)
    mass = m.particle_mass.numpy().astype(np.float64)
    g = -float(m.gravity[1])

    def energy(x, v):
        return float(0.5 * (mass[:, None] * v.astype(np.float64) ** 2).sum() + g * (mass * x[:, 1]).sum())

    e0 = energy(folded, vel)
    heights, flipped, energies = [], [], []
    for _ in range(frames):
        solver.step(state, state, control, 1.0 / 30.0)
        x, v = state.positions.numpy(), state.velocities.numpy()
        assert np.all(np.isfinite(x))
        heights.append(float(x[interior, 1].mean()))
        flipped.append(float(x[interior, 0].max() - mid * e))
        energies.append(energy(x, v))
    return np.array(heights), np.array(flipped), np.array(energies + [e0])


@pytest.mark.parametrize("speed", [1.1, 2.0])
def test_a_hairpin_whose_arms_start_apart_lands_on_itself(device, speed):
    """The scene of the known limitation below with the arms 10 mm apart at rest (outside the
    rest exclusion): the thrown arm lands on the pinned one and stays above it, without flipping
    over the fold, and the contact creates no energy: the sheet starts at rest shape (no elastic
    energy) out of contact and its pins hold still, so its kinetic plus gravitational energy can
    only fall. Without the displacement bounds (``VBDConfig.self_contact_bounds``, before
    session 17) a rim vertex left the first contact at 12 m/s: at 1.1 m/s the sheet gained 10x
    its energy and the arm flipped over the fold and fell past the pinned one."""
    h, flipped, energy = hairpin_pass(device, gap=0.01, speed=speed)
    assert np.all(h > 0.0), h
    assert np.all(flipped < 0.0), flipped
    e0 = energy[-1]
    assert np.all(energy[:-1] <= e0 + 0.02 * abs(e0)), (energy[:-1], e0)


def test_the_exact_contact_hessian_lets_a_thrown_hairpin_gain_energy(device):
    """Why the contact Hessian has a weight floor (``VBDConfig.self_contact_weight_floor``):
    with the exact ``w^2 k`` (floor 0, until session 17) the hairpin above, thrown at 1.1 m/s,
    gains energy in its first contact (a rim vertex with a small weight in its pairs took their
    whole penetration as its own step and left at 12 m/s; the arm then flipped over the fold).
    This keeps the energy check above a test that can fail."""
    _, _, energy = hairpin_pass(device, gap=0.01, speed=1.1, frames=2, self_contact_weight_floor=0.0)
    assert energy[:-1].max() > energy[-1] + 1e-3  # more than a millijoule made
    for bad in (-0.1, 1.5):  # a config error, found when the config is made, not at the first step
        with pytest.raises(ValueError, match="weight_floor"):
            VBDConfig(self_contact_weight_floor=bad)


@pytest.mark.parametrize("gap", [0.001, 0.0004])
def test_parts_of_one_piece_close_at_rest_do_not_pass_through_each_other(device, gap):
    """A crease folded at rest with its arms closer than the 3 mm contact radius (as at a
    t-shirt's underarm seam or the crotch of trousers), the upper arm thrown down at 1 m/s: it
    stays above the lower one. Such pairs are in contact at half their rest distance (until
    session 18 they were excluded, and at 1 mm the arm fell 39 mm through in one frame)."""
    h, flipped, energy = hairpin_pass(device, gap=gap)
    assert np.all(h > 0.0), h
    assert np.all(flipped < 0.0), flipped
    assert np.all(energy[:-1] <= energy[-1] + 0.02 * abs(energy[-1])), energy


def test_pairs_close_at_rest_get_half_their_rest_distance_and_push_nothing_at_rest(device):
    """The folded sheet at rest (arms 1 mm apart): detection stores its facing pairs with a
    radius code (bits 8-15 of the records' role) whose radius is at most half, and at least
    0.49x, the pair's rest distance; a sweep of the sheet at rest moves nothing (no contact
    force at rest). Arms 10 mm apart: no pair within reach, no code."""
    from sim.cloth.self_contact import RADIUS_CODES

    radius = 0.003
    for gap, expect_codes in ((0.001, True), (0.01, False)):
        _, folded, f, col = folded_sheet(13, 5, 0.02, 6, gap)
        b = ClothModelBuilder()
        b.add_cloth(folded.astype(np.float32), f, ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.001))
        m = b.finalize(device)
        solver = SolverVBD(m, VBDConfig(substeps=1, iterations=2, self_contact=True,
                                        self_contact_radius=radius))
        state = m.state()
        sc = solver.self_contact.data
        solver.self_contact.detect(state.positions, state.velocities, 1.0 / 300.0)
        first, count = sc.pair_first.numpy(), sc.pair_count.numpy()
        role, verts = sc.pair_role.numpy(), sc.pair_verts.numpy()
        recs = np.concatenate([np.arange(a, a + c) for a, c in zip(first, count, strict=True) if c > 0] or
                              [np.zeros(0, int)])
        codes = (role[recs] >> 8) & 255
        assert (codes > 0).any() == expect_codes
        if not expect_codes:
            continue
        # every coded record's radius against its rest distance (point-triangle or edge-edge)
        x = folded.astype(np.float64)
        for r in recs[codes > 0]:
            q, kind = verts[r], role[r] & 15
            if kind < 4:
                d = _point_triangle_distance_np(x[q[0]], x[q[1]], x[q[2]], x[q[3]])
            else:
                d = _segment_distance_np(x[q[0]], x[q[1]], x[q[2]], x[q[3]])
            pr = radius * (1.0 - ((role[r] >> 8) & 255) / RADIUS_CODES)
            assert 0.49 * d - 1e-9 <= pr <= 0.5 * d + 1e-9, (d, pr)
        # at rest the solve exerts no contact force: gravity off, no velocity, nothing moves
        b2 = ClothModelBuilder(gravity=(0.0, 0.0, 0.0))
        b2.add_cloth(folded.astype(np.float32), f, ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.001))
        m2 = b2.finalize(device)
        s2 = SolverVBD(m2, VBDConfig(substeps=1, iterations=4, self_contact=True, self_contact_radius=radius))
        st = m2.state()
        s2.step(st, st, m2.control(), 1.0 / 120.0)
        assert s2.self_contact.data.pair_count.numpy().sum() > 0
        np.testing.assert_allclose(st.positions.numpy(), folded, atol=1e-7)


def test_gather_records_hold_each_vertexs_pairs_in_list_order(device):
    """Each vertex's block of gather records (``pair_first`` / ``pair_count``) holds, in order,
    its VT pairs, its triangles' TV pairs and its edges' EE pairs, each as the pair's four
    vertices, the vertex's role (0 VT, 1-3 its corner of the TV triangle, 4-5 its end of the EE
    edge), the same-colour mask of those vertices against its own colour, the radius code and
    the side reference, as read from the detection's lists (numpy here; on the device one
    thread per list writes them, ``pair_records_kernel``). Two instances of a sheet folded
    1 mm onto itself give pairs of all three kinds."""
    _, folded, f, _ = folded_sheet(13, 5, 0.02, 6, 0.001)
    b = ClothModelBuilder()
    for dz in (0.0, 0.5):
        b.add_cloth((folded + [0.0, 0.0, dz]).astype(np.float32), f,
                    ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.001))
    m = b.finalize(device)
    solver = SolverVBD(m, VBDConfig(substeps=1, iterations=2, self_contact=True, self_contact_radius=0.003,
                                    self_contact_pool=64))  # room for every vertex's records
    state = m.state()
    contact = solver.self_contact
    contact.detect(state.positions, state.velocities, 1.0 / 300.0)
    sc = contact.data
    a = {k: getattr(sc, k).numpy() for k in (
        "pair_first", "pair_count", "pair_verts", "pair_role", "pair_ref", "vt_count", "vt_tri", "vt_rk",
        "vt_ref", "tv_count", "tv_vertex", "tv_rk", "tv_ref", "ee_count", "ee_edge", "ee_rk", "ee_ref",
        "particle_color", "mesh_edges")}
    tris = m.tri_indices.numpy()
    vt_off, vt_ids, vt_local = (x.numpy() for x in (m.vertex_tri_offsets, m.vertex_tri_ids,
                                                    m.vertex_tri_local))
    ve_off, ve_ids, ve_local = (x.numpy() for x in (m.vertex_mesh_edge_offsets, m.vertex_mesh_edge_ids,
                                                    m.vertex_mesh_edge_local))
    cap_vt, cap_tv, cap_ee = sc.vt_capacity, sc.tv_capacity, sc.ee_capacity
    color = a["particle_color"]
    kinds = set()
    for i in range(m.particle_count):
        expect = []  # (q, role, rank, ref)
        for s in range(a["vt_count"][i]):
            expect.append(((i, *tris[a["vt_tri"][i * cap_vt + s]]), 0, a["vt_rk"][i * cap_vt + s],
                           a["vt_ref"][i * cap_vt + s]))
        for k in range(vt_off[i], vt_off[i + 1]):
            t = vt_ids[k]
            for s in range(a["tv_count"][t]):
                expect.append(((a["tv_vertex"][t * cap_tv + s], *tris[t]), 1 + (vt_local[k] & 3),
                               a["tv_rk"][t * cap_tv + s], a["tv_ref"][t * cap_tv + s]))
        for k in range(ve_off[i], ve_off[i + 1]):
            e = ve_ids[k]
            for s in range(a["ee_count"][e]):
                eb = a["mesh_edges"][a["ee_edge"][e * cap_ee + s]]
                expect.append(((*a["mesh_edges"][e], *eb), 4 + ve_local[k], a["ee_rk"][e * cap_ee + s],
                               a["ee_ref"][e * cap_ee + s]))
        assert a["pair_count"][i] == len(expect)
        if not expect:
            continue
        first = a["pair_first"][i]
        assert first >= 0
        for r, (q, role, rank, ref) in enumerate(expect, start=first):
            mask = sum(1 << j for j in range(4) if color[q[j]] == color[i])
            np.testing.assert_array_equal(a["pair_verts"][r], q)
            assert a["pair_role"][r] == role | (mask << 4) | (rank << 8)
            np.testing.assert_array_equal(a["pair_ref"][r], ref)
            kinds.add(0 if role == 0 else 1 if role < 4 else 2)
    assert kinds == {0, 1, 2}


def _two_sheets(device, lift: float = 0.0):
    """The detection test's flat sheet and jittered sheet 2-8 mm above it (``lift`` [m] higher)
    as one model, with a SelfContact that has a lookahead: (model, contact, positions)."""
    nx, ny, e = 7, 6, 0.012
    v1, f1 = grid(nx, ny, (nx - 1) * e, (ny - 1) * e, plane="xz")
    v2 = v1 + np.array([0.4 * e, lift, 0.3 * e], np.float32)
    v2[:, 1] = np.random.default_rng(5).uniform(0.002, 0.008, len(v2)) + lift
    v = np.concatenate([v1, v2]).astype(np.float32)
    b = ClothModelBuilder()
    b.add_cloth(v, np.concatenate([f1, f1 + len(v1)]).astype(np.int32), ClothMaterialParams())
    m = b.finalize(device)
    sc = SelfContact(m, radius=0.003, margin=0.006, stiffness=1e4, friction=0.0, relaxation=0.45,
                     speed_factor=2.5, capacity=128, bounds=False, lookahead=0.001)
    return m, sc, v


def _all_lists(sc, m) -> dict:
    """Every list of ``sc`` as a set of (owner, partner) pairs, and each vertex's record count."""
    ne = m.mesh_edge_indices.shape[0]
    return {"vt": _stored(sc, m.particle_count, "vt_tri", "vt_count"),
            "tv": _stored(sc, m.tri_count, "tv_vertex", "tv_count"),
            "ee": _stored(sc, ne, "ee_edge", "ee_count"),
            "records": sc.data.pair_count.numpy().tolist()}


@pytest.mark.parametrize("motion", ["still", "sliding", "approaching"])
def test_lists_remeasured_from_lookahead_candidates_equal_a_detection(device, motion):
    """``remeasure`` re-tests the candidates a query found a substep earlier, without a tree:
    after the cloth moved one substep at its velocity (still, the upper sheet sliding at 3 m/s,
    or coming down at 1 m/s), its lists and gather records are exactly those a full detection at
    the new positions gives (as sets: the order follows the candidates'), and there are many of
    them. The sliding sheet moves 10 mm in the substep, more than the static sheet's 6 mm query
    margin: only the swept boxes let the static vertices' queries meet the triangles coming."""
    m, sc, v = _two_sheets(device)
    h = 1.0 / 300.0
    vel = np.zeros_like(v)
    top = slice(len(v) // 2, None)
    vel[top] = {"still": (0.0, 0.0, 0.0), "sliding": (3.0, 0.0, 0.0), "approaching": (0.0, -1.0, 0.0)}[motion]
    velocities = wp.array(vel, dtype=wp.vec3, device=device)
    sc.query_candidates(m.particle_q, velocities, h)
    moved = wp.array(v + vel * h, dtype=wp.vec3, device=device)
    sc.remeasure(moved, velocities, h)
    remeasured = _all_lists(sc, m)
    sc.detect(moved, velocities, h)
    detected = _all_lists(sc, m)
    assert remeasured == detected
    assert len(detected["vt"]) > 50 and len(detected["tv"]) > 50 and len(detected["ee"]) > 50


def test_remeasure_finds_only_what_the_candidate_query_saw(device):
    """The remeasured lists come from the candidates alone: candidates queried with the upper sheet
    5 cm up hold nothing, so lists remeasured after it came down are empty where a detection at
    the same positions finds the pairs."""
    m, sc, v = _two_sheets(device, lift=0.05)
    h = 1.0 / 300.0
    velocities = wp.zeros(len(v), dtype=wp.vec3, device=device)
    sc.query_candidates(m.particle_q, velocities, h)
    down = v.copy()
    down[len(v) // 2:, 1] -= 0.05
    moved = wp.array(down, dtype=wp.vec3, device=device)
    sc.remeasure(moved, velocities, h)
    assert all(not pairs for key, pairs in _all_lists(sc, m).items() if key != "records")
    sc.detect(moved, velocities, h)
    assert len(_all_lists(sc, m)["vt"]) > 50


def _three_pieces(device, motion: str):
    """Two sheets of two layers each (the second overlapping the first in space) and a smaller
    piece of another topology in between, with every vertex at its own random velocity
    (``motion`` "still") or the upper layers sliding at 3 m/s ("sliding"): the model and the
    velocities (numpy)."""
    nx, ny, e = 9, 8, 0.012
    v1, f1 = grid(nx, ny, (nx - 1) * e, (ny - 1) * e, plane="xz")
    rng = np.random.default_rng(1)
    v2 = v1 + np.array([0.4 * e, 0.0, 0.3 * e], np.float32)
    v2[:, 1] = rng.uniform(0.002, 0.008, len(v2))
    v = np.concatenate([v1, v2]).astype(np.float32)
    f = np.concatenate([f1, f1 + len(v1)]).astype(np.int32)
    b = ClothModelBuilder()
    for offset in ((0.0, 0.0, 0.0), (0.05, 0.003, 0.0)):  # the second overlaps the first in space
        b.add_cloth(v + np.array(offset, np.float32), f, ClothMaterialParams())
    # a third, smaller piece of another topology in between: fewer clusters than the others
    vs, fs = grid(3, 3, 2 * e, 2 * e, plane="xz")
    b.add_cloth(np.concatenate([vs, vs + np.array([0.3 * e, 0.004, 0.2 * e], np.float32)]),
                np.concatenate([fs, fs + len(vs)]).astype(np.int32), ClothMaterialParams())
    m = b.finalize(device)
    if motion == "still":
        vel = rng.normal(0.0, 1.0, (m.particle_count, 3)).astype(np.float32)
    else:
        vel = np.zeros((m.particle_count, 3), np.float32)
        for start in (len(v1), len(v) + len(v1)):
            vel[start:start + len(v2)] = (3.0, 0.0, 0.0)
    return m, vel


@pytest.mark.parametrize("size,bounds,split", [(8, True, 1), (32, True, 1), (64, True, 1), (8, False, 1),
                                               (32, False, 1), (8, True, 3), (32, False, 4)])
@pytest.mark.parametrize("motion", ["still", "sliding"])
def test_cluster_broadphase_finds_the_pairs_of_the_trees(device, size, bounds, split, motion):
    """The cluster broadphase (``sim.cloth.clusters``) hands each query exactly the primitives
    whose boxes meet its query box, as the trees do: on the flat and the jittered sheet (two
    instances, so clusters must keep to their instance), with every vertex at its own random
    velocity or the upper sheet sliding at 3 m/s, with a smaller piece of another topology as a
    third instance, the three kinds of lists hold the same pairs
    (lists large enough that none fills: a full list's ties depend on the order), and so do
    the gather records per vertex. With the bounds on, the nearest distances are equal to the
    bit too; with them off (the default) the clusters cull by relative speed
    (``clusters.reach_radius``), which leaves the lists alone but not the nearest distances.
    Split over several threads per primitive and merged (``split``), the same again."""
    m, vel = _three_pieces(device, motion)
    found, marked = {}, {}
    for broadphase in ("bvh", "clusters"):
        sc = SelfContact(m, radius=0.003, margin=0.006, stiffness=1e4, friction=0.0, relaxation=0.45,
                         speed_factor=2.5, capacity=200, broadphase=broadphase, cluster_size=size,
                         bounds=bounds, cluster_split=split)
        sc.detect(m.particle_q, wp.array(vel, dtype=wp.vec3, device=device), 1.0 / 300.0)
        lists = _all_lists(sc, m)
        for count in (sc.data.vt_count, sc.data.tv_count, sc.data.ee_count):
            assert count.numpy().max() < 200
        if bounds:
            lists["dmin"] = [d.numpy().tolist() for d in sc._dmins]
        found[broadphase] = lists
        if broadphase == "clusters":
            marked[bounds] = sum(sc.clusters.marked())
            if motion == "sliding" and not bounds:
                # each sheet moves as one: within a sheet the clusters are culled at the margin,
                # not at the 25 mm the upper sheet's speed gives its queries
                on = SelfContact(m, radius=0.003, margin=0.006, stiffness=1e4, friction=0.0, relaxation=0.45,
                                 speed_factor=2.5, capacity=200, broadphase=broadphase, cluster_size=size)
                on.detect(m.particle_q, wp.array(vel, dtype=wp.vec3, device=device), 1.0 / 300.0)
                assert sum(on.clusters.marked()) > marked[bounds]
    assert len(found["bvh"]["vt"]) > 300 and len(found["bvh"]["ee"]) > 1000
    # pairs between the two instances, which overlap in space, would show up as partners
    # outside the owner's instance
    assert found["clusters"] == found["bvh"]


@pytest.mark.parametrize("size", [8, 16, 32])
@pytest.mark.parametrize("motion", ["still", "sliding"])
def test_cluster_lanes_bound_the_octets_and_clusters_as_their_own_launches_do(device, size, motion):
    """On CUDA the octets' and clusters' boxes, radii, velocities and spreads come from lane
    shuffles in the slots' launch (``cluster_bounds_fused_kernel``): the boxes and the radii
    are those of the separate launches to the bit, the mean velocities agree to round-off (summed
    in another order), every spread holds each member's corner velocities within it of its mean
    (numpy, from the slots), and the query finds the same lists."""
    if device != "cuda":
        pytest.skip("lane shuffles are CUDA only (the CPU runs the separate launches)")
    m, vel = _three_pieces(device, motion)
    v = wp.array(vel, dtype=wp.vec3, device=device)
    data, lists = {}, {}
    for lanes in (False, True):
        sc = SelfContact(m, radius=0.003, margin=0.006, stiffness=1e4, friction=0.0, relaxation=0.45,
                         speed_factor=2.5, capacity=200, broadphase="clusters", cluster_size=size,
                         cluster_lanes=lanes)
        assert sc.clusters.lanes == lanes
        sc.detect(m.particle_q, v, 1.0 / 300.0)
        cl = sc.clusters.arrays
        data[lanes] = {name: getattr(cl, name).numpy() for name in (
            "lo", "hi", "radius", "octet_lo", "octet_hi", "octet_radius", "octet_count", "octet_vel",
            "octet_spread", "cluster_lo", "cluster_hi", "cluster_radius", "cluster_vel", "cluster_spread",
            "masks")}
        lists[lanes] = _all_lists(sc, m)
        # a second detection on the first one's outputs: the fused kernel zeroes the record
        # counters itself (no memsets), so the records come out the same again
        cursor = sc.data.pair_cursor.numpy().copy()
        sc.detect(m.particle_q, v, 1.0 / 300.0)
        assert _all_lists(sc, m) == lists[lanes]
        np.testing.assert_array_equal(sc.data.pair_cursor.numpy(), cursor)
    a, b = data[False], data[True]
    # the masks too: with the bounds on (the default here) they cull by the query radii alone, and
    # split over four lanes per word (``clusters.MASK_PARTS``) they mark the same clusters
    for name in ("lo", "hi", "radius", "octet_lo", "octet_hi", "octet_radius", "octet_count", "cluster_lo",
                 "cluster_hi", "cluster_radius", "masks"):
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    for name in ("octet_vel", "octet_spread", "cluster_vel", "cluster_spread"):
        np.testing.assert_allclose(a[name], b[name], rtol=1e-5, atol=1e-5, err_msg=name)
    # the spreads bound every member's corner velocities, from the shuffled means
    order = sc.clusters.arrays.order.numpy()
    kinds = sc.clusters.kind_clusters
    tris, edges = m.tri_indices.numpy(), m.mesh_edge_indices.numpy()
    for c in range(len(order) // size):
        members = order[c * size:(c + 1) * size]
        members = members[members >= 0]
        kind = int(np.searchsorted(kinds, c, side="right") - 1)
        corners = members[:, None] if kind == 0 else (tris[members] if kind == 1 else edges[members])
        far = np.linalg.norm(vel[corners.ravel()] - b["cluster_vel"][c], axis=1).max()
        assert far <= b["cluster_spread"][c] * (1 + 1e-5) + 1e-6
    assert lists[True] == lists[False] and len(lists[True]["ee"]) > 1000


def test_cluster_layout_cuts_each_instance_into_compact_clusters():
    """``cluster_layout`` puts every primitive in exactly one slot, never mixes instances in a
    cluster, pads only an instance's last cluster, and follows the Morton curve: on a 40 x 40
    grid, clusters of 16 vertices span a few edge lengths (a random order spans the sheet).
    Grown over the mesh's edges (``grow_clusters``) the patches span less than the curve's runs."""
    from sim.cloth.clusters import cluster_layout

    v, f_grid = grid(40, 40, 0.39, 0.39, plane="xz")
    pts = np.concatenate([v, v[:100]])  # instance 1: 100 points on top of instance 0's
    groups = np.r_[np.zeros(len(v), np.int64), np.ones(100, np.int64)]
    order, cluster_group, first = cluster_layout(pts, groups, 2, 16)
    assert first.tolist() == [0, 100, 107]
    assert sorted(order[order >= 0].tolist()) == list(range(len(pts)))
    slots = order.reshape(-1, 16)
    for c, row in enumerate(slots):
        members = row[row >= 0]
        assert np.all(groups[members] == cluster_group[c])
        if len(members) < 16:  # padding only at the end of an instance
            assert c + 1 in (first[1], first[2]) and np.all(row[len(members):] < 0)
    span = [np.ptp(pts[r[r >= 0]], axis=0).max() for r in slots[:100]]
    assert np.mean(span) < 0.08  # 16 points of a 1 cm grid: a 4 x 4 patch, or a few where the curve jumps
    # cut along the surface (the grid's edges as adjacency), the patches are rounder still
    from sim.cloth.model import mesh_edges as edges_of

    nb = edges_of(f_grid)
    order2, _, first2 = cluster_layout(v, np.zeros(len(v), np.int64), 1, 16, nb)
    assert sorted(order2[order2 >= 0].tolist()) == list(range(len(v)))
    patches = order2.reshape(-1, 16)
    span2 = [np.ptp(v[r[r >= 0]], axis=0).max() for r in patches if (r >= 0).sum() == 16]
    assert np.mean(span2) < np.mean(span) and np.mean(span2) < 0.05
    shuffled = np.random.default_rng(0).permutation(len(v))[:1600].reshape(100, 16)
    assert np.mean([np.ptp(v[r], axis=0).max() for r in shuffled]) > 0.3
    with pytest.raises(ValueError, match="group ids"):
        cluster_layout(pts, groups + 1, 2, 16)


FINE_SHEET = (21, 41, 0.0055)  # columns, rows, edge [m]: a fine garment's edges


def fine_denim_sheet(device, gravity: float = 9.81):
    """A ``FINE_SHEET`` of denim in the plane z = 0 pinned along its top row, under ``gravity``
    [m/s^2]: the model and its rest positions."""
    from sim.cloth.model import as_cloth_params
    from sim.garments.materials import get_material

    nx, ny, e = FINE_SHEET
    v, f = grid(nx, ny, (nx - 1) * e, (ny - 1) * e)
    b = ClothModelBuilder(gravity=(0.0, -gravity, 0.0))
    b.add_cloth(v, f, as_cloth_params(get_material("denim")), pinned=np.arange(nx))
    return b.finalize(device), v


def _hanging_fine_sheet(device, frames: int, **changes):
    """A 21 x 41 sheet of 5.5 mm edges (a fine garment's) in denim hanging from its pinned top row
    for ``frames`` frames at the job's solver default for fine garments (``SimulationConfig.vbd_config``
    of a 20k-vertex garment: 14 x 8, the coarse correction, ``FINE_COARSE_EXCLUSION``), ``changes``
    on top: the bottom row's mean height per frame [m] and the share of particles with stored
    vertex-triangle pairs at the end."""
    import dataclasses

    from sim.simulate import SimulationConfig

    m, v = fine_denim_sheet(device)
    nx = FINE_SHEET[0]
    cfg = dataclasses.replace(SimulationConfig(self_contact=True).vbd_config(20_000), **changes)
    solver = SolverVBD(m, cfg)
    state, control = m.state(), m.control()
    control.pin_targets.assign(v)
    bottom = []
    for _ in range(frames):
        solver.step(state, state, control, 1.0 / 30.0)
        bottom.append(float(state.positions.numpy()[-nx:, 1].mean()))
    share = float((solver.self_contact.data.vt_count.numpy() > 0).mean()) if cfg.self_contact else 0.0
    return np.array(bottom), share


def test_neighbours_near_at_rest_leave_the_coarse_correction_of_a_fine_sheet_alone(device):

    """A flat sheet is never in contact with itself, and on a fine mesh it hangs with self-contact
    on as with it off (22 cm long, its bottom steady 0.1 mm below its rest height from the 6th
    frame). Its neighbours an edge or two apart (3.9-5.5 mm on the 5.5 mm grid) come within the
    4 mm query margin as it moves: nearly every particle holds pairs. Those pairs stay in
    contact but, closer than ``self_contact_coarse_exclusion`` (6 mm for fine garments) at rest,
    no longer hold back the coarse correction (``has_pairs``); while they did (exclusion 0, until
    session 50, and still on coarse garments)
    the correction was capped nearly everywhere and the sheet bounced by centimetres (the fine
    pants sank 12 mm in their settle, against 3 mm without self-contact). With
    ``self_contact_ring_exclusion`` no pair is stored at all, and the sheet hangs the same."""
    from sim.simulate import FINE_COARSE_EXCLUSION

    off, _ = _hanging_fine_sheet(device, 12, self_contact=False)
    assert np.all(np.abs(off[5:] + 0.2201) < 2e-4), off
    default, share = _hanging_fine_sheet(device, 12)
    assert share > 0.9 and FINE_COARSE_EXCLUSION == 0.006
    np.testing.assert_allclose(default, off, atol=1e-4)
    held, held_share = _hanging_fine_sheet(device, 12, self_contact_coarse_exclusion=0.0)
    assert held_share > 0.9
    assert np.abs(held - off).max() > 0.005, held - off
    ring, ring_share = _hanging_fine_sheet(device, 12, self_contact_ring_exclusion=True)
    assert ring_share == 0.0
    np.testing.assert_allclose(ring, off, atol=1e-4)
    with pytest.raises(ValueError, match="coarse_exclusion"):
        VBDConfig(self_contact_coarse_exclusion=-0.001)
