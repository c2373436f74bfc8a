"""Self-contact pair maths and the solve's gather (sim.cloth.self_contact.pairs, .gather,
.records): closest points against brute force, forces against finite differences of the contact
energy, every pair shared once among a vertex's lanes, and the gather records in list order."""

from __future__ import annotations

import numpy as np
import warp as wp

from sim.cloth import (
    ClothMaterialParams,
    ClothModelBuilder,
    CoarseConfig,
    SelfContactConfig,
    SolverVBD,
    Stepping,
    VBDConfig,
)
from sim.cloth.self_contact import (
    SelfContact,
    SelfContactData,
    self_contact_force_hessian,
    triangle_closest_bary,
)
from tests.self_contact_scenes import (
    bary_np,
    closest_point_triangle_np,
    contact_energy_np,
    contact_pairs_np,
    folded_sheet,
    two_layers,
)


@wp.kernel
def _bary_kernel(p: wp.array(dtype=wp.vec3), a: wp.vec3, b: wp.vec3, c: wp.vec3,
                 out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = triangle_closest_bary(p[i], a, b, c)


def test_closest_point_on_triangle_matches_brute_force(device):
    rng = np.random.default_rng(3)
    a, b, c = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.1, 0.0]), np.array([0.3, 0.8, 0.2])
    p = rng.uniform(-0.8, 1.6, size=(200, 3)).astype(np.float32)
    out = wp.zeros(len(p), dtype=wp.vec3, device=device)
    wp.launch(_bary_kernel, dim=len(p), inputs=[wp.array(p, dtype=wp.vec3, device=device), wp.vec3(*a),
                                                 wp.vec3(*b), wp.vec3(*c)], outputs=[out], device=device)
    w = out.numpy().astype(np.float64)
    assert w.min() >= -1e-6
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-5)
    q = w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c
    d = np.linalg.norm(q - p, axis=1)
    d_ref = np.array([closest_point_triangle_np(p[i].astype(np.float64), a, b, c)[1] for i in range(len(p))])
    # the sampled reference is an upper bound within its grid spacing
    assert np.all(d <= d_ref + 1e-5)
    assert np.all(d >= d_ref - 0.01)


def test_closest_point_weights_in_each_voronoi_region(device):
    """Ericson's seven regions of a triangle: a point beyond a corner gets exactly that corner,
    one beyond an edge no weight on the opposite corner, one above the face its projection."""
    a, b, c = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.1, 0.0]), np.array([0.3, 0.8, 0.2])
    up = np.cross(b - a, c - a) / np.linalg.norm(np.cross(b - a, c - a))
    centroid = (a + b + c) / 3.0
    corners = [a + 0.5 * (a - centroid), b + 0.5 * (b - centroid), c + 0.5 * (c - centroid)]
    edges = [(x + y) / 2.0 + 0.4 * ((x + y) / 2.0 - centroid) for x, y in ((a, b), (a, c), (b, c))]
    p = np.array(corners + edges + [centroid + 0.3 * up, 0.2 * a + 0.5 * b + 0.3 * c - 0.1 * up])
    out = wp.zeros(len(p), dtype=wp.vec3, device=device)
    points = wp.array(p.astype(np.float32), dtype=wp.vec3, device=device)
    wp.launch(_bary_kernel, dim=len(p), inputs=[points, wp.vec3(*a), wp.vec3(*b), wp.vec3(*c)], outputs=[out],
              device=device)
    w = out.numpy().astype(np.float64)
    np.testing.assert_array_equal(w[:3], np.eye(3))
    for row, zero in zip(w[3:6], (2, 1, 0), strict=True):
        assert row[zero] == 0.0 and np.delete(row, zero).min() > 0.0
    ref = np.array([bary_np(q, a, b, c) for q in p])
    np.testing.assert_allclose(w, ref, atol=2e-6)


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


def self_contact_forces(m, sc, x, stride: int = 1):
    """Self-contact force on and Hessian block of every vertex of model ``m`` at positions ``x``
    (numpy or a Warp array), summed over ``stride`` lanes."""
    d = m.device
    xw = x if isinstance(x, wp.array) else wp.array(x, dtype=wp.vec3, device=d)
    fo = wp.zeros(xw.shape[0], dtype=wp.vec3, device=d)
    ho = wp.zeros(xw.shape[0], dtype=wp.mat33, device=d)
    wp.launch(_lane_force_kernel, dim=xw.shape[0],
              inputs=[xw, m.tri_indices, m.vertex_tri_offsets, m.vertex_tri_ids, m.vertex_tri_local, sc.data,
                      stride], outputs=[fo, ho], device=d)
    return fo.numpy(), ho.numpy()


def test_self_contact_forces_match_finite_differences(device):
    """The force is minus the gradient of ``k/2 (r - d)^2`` summed over the pairs (finite
    differences in float64); the Hessian block is the Gauss-Newton part: symmetric and
    positive semi-definite."""
    x, faces = two_layers()
    radius, k = 0.004, 1.0e3
    b = ClothModelBuilder()
    b.add_cloth(x, faces, ClothMaterialParams())
    m = b.finalize(device)
    sc = SelfContact(m, radius=radius, margin=0.01, stiffness=k, friction=0.0, speed_factor=2.5, capacity=32)
    xd = wp.array(x, dtype=wp.vec3, device=device)
    sc.detect(xd, wp.zeros_like(xd), 1.0 / 300.0)
    f, hs = (a.astype(np.float64) for a in self_contact_forces(m, sc, xd))
    x64 = x.astype(np.float64)
    pairs = contact_pairs_np(x64, faces, radius + 1e-4)  # farther pairs exert nothing
    assert contact_energy_np(x64, faces, pairs, radius, k) > 0.0  # the layers are in contact
    eps = 1e-6
    checked = 0
    for i in range(len(x)):
        # only the pairs vertex i takes part in change with it
        mine = ([(j, t) for j, t in pairs[0] if j == i or i in faces[t]],
                [(ea, eb) for ea, eb in pairs[1] if i in ea or i in eb])
        g = np.zeros(3)
        for a in range(3):
            xp, xm = x64.copy(), x64.copy()
            xp[i, a] += eps
            xm[i, a] -= eps
            e_p = contact_energy_np(xp, faces, mine, radius, k)
            g[a] = (e_p - contact_energy_np(xm, faces, mine, radius, k)) / (2 * eps)
        np.testing.assert_allclose(f[i], -g, atol=2e-3 * max(1.0, np.abs(g).max()) + 1e-6)
        if np.abs(g).max() > 1e-4:
            checked += 1
            np.testing.assert_allclose(hs[i], hs[i].T, atol=1e-3 * np.abs(hs[i]).max())
            assert np.linalg.eigvalsh(0.5 * (hs[i] + hs[i].T)).min() > -1e-3 * np.abs(hs[i]).max()
    assert checked >= 8


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
    # reservation fits in any atomic order (CUDA), but not all of them: some vertices fall back
    for pool in (0, 128, 2):
        sc = SelfContact(m, radius=0.004, margin=0.006, stiffness=1.0e3, friction=0.3, speed_factor=2.5,
                         capacity=8, pool=pool)
        xd = wp.array(x, dtype=wp.vec3, device=device)
        sc.detect(xd, wp.zeros_like(xd), 1.0 / 300.0)
        counts = np.concatenate([sc.data.tv_count.numpy(), sc.data.ee_count.numpy()])
        assert len(np.unique(counts)) >= 5 and (counts == 0).any()   # uneven lists: the split is exercised
        total = sc.data.pair_count.numpy()
        fell_back = (sc.data.pair_first.numpy() < 0)[total > 0]
        expected = {0: fell_back.all(), 128: not fell_back.any(), 2: 0 < fell_back.mean() < 1}
        assert expected[pool], (pool, fell_back.mean())
        for stride in (1, 3, 16):
            out[pool, stride] = self_contact_forces(m, sc, xm, stride)
    f1, h1 = out[0, 1]
    assert np.abs(f1).max() > 0.0
    for key, (f, hs) in out.items():
        np.testing.assert_allclose(f, f1, rtol=1e-4, atol=1e-5 * np.abs(f1).max(), err_msg=str(key))
        np.testing.assert_allclose(hs, h1, rtol=1e-4, atol=1e-5 * np.abs(h1).max(), err_msg=str(key))


def _expected_records(i: int, a: dict, tris, vt, ve, caps) -> list:
    """Vertex ``i``'s records as the lists give them, in order: (vertices, role, radius code,
    side reference) of its VT pairs, its triangles' TV pairs and its edges' EE pairs."""
    (vt_off, vt_ids, vt_local), (ve_off, ve_ids, ve_local), (cap_vt, cap_tv, cap_ee) = vt, ve, caps
    out = []
    for s in range(a["vt_count"][i]):
        k = i * cap_vt + s
        out.append(((i, *tris[a["vt_tri"][k]]), 0, a["vt_rk"][k], a["vt_ref"][k]))
    for j in range(vt_off[i], vt_off[i + 1]):
        t = vt_ids[j]
        for s in range(a["tv_count"][t]):
            k = t * cap_tv + s
            out.append(((a["tv_vertex"][k], *tris[t]), 1 + (vt_local[j] & 3), a["tv_rk"][k], a["tv_ref"][k]))
    for j in range(ve_off[i], ve_off[i + 1]):
        e = ve_ids[j]
        for s in range(a["ee_count"][e]):
            k = e * cap_ee + s
            eb = a["mesh_edges"][a["ee_edge"][k]]
            out.append(((*a["mesh_edges"][e], *eb), 4 + ve_local[j], a["ee_rk"][k], a["ee_ref"][k]))
    return out


def test_gather_records_hold_each_vertexs_pairs_in_list_order(device):
    """Each vertex's block of gather records (``pair_first`` / ``pair_count``) holds, in order,
    its VT pairs, its triangles' TV pairs and its edges' EE pairs, each as the pair's four
    vertices, the vertex's role (0 VT, 1-3 its corner of the TV triangle, 4-5 its end of the EE
    edge), the same-colour mask of those vertices against its own colour, the radius code and
    the side reference, as read from the detection's lists (numpy here; on the device one
    thread per list writes them, ``records.pair_records_kernel``). Two instances of a sheet
    folded 1 mm onto itself give pairs of all three kinds."""
    _, folded, f, _ = folded_sheet(13, 5, 0.02, 6, 0.001)
    b = ClothModelBuilder()
    for dz in (0.0, 0.5):
        b.add_cloth((folded + [0.0, 0.0, dz]).astype(np.float32), f,
                    ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.001))
    m = b.finalize(device)
    cfg = VBDConfig(stepping=Stepping(substeps=1, iterations=2), coarse=CoarseConfig(sweeps=()),
                    self_contact=SelfContactConfig(radius=0.003, pool=64))  # room for every record
    solver = SolverVBD(m, cfg)
    state = m.state()
    solver.self_contact.detect(state.positions, state.velocities, 1.0 / 300.0)
    sc = solver.self_contact.data
    a = {k: getattr(sc, k).numpy() for k in (
        "pair_first", "pair_count", "pair_verts", "pair_role", "pair_ref", "vt_count", "vt_tri", "vt_rk",
        "vt_ref", "tv_count", "tv_vertex", "tv_rk", "tv_ref", "ee_count", "ee_edge", "ee_rk", "ee_ref",
        "particle_color", "mesh_edges")}
    tris = m.tri_indices.numpy()
    vt = tuple(x.numpy() for x in (m.vertex_tri_offsets, m.vertex_tri_ids, m.vertex_tri_local))
    ve = tuple(x.numpy() for x in (m.vertex_mesh_edge_offsets, m.vertex_mesh_edge_ids,
                                   m.vertex_mesh_edge_local))
    caps = (sc.vt_capacity, sc.tv_capacity, sc.ee_capacity)
    color = a["particle_color"]
    kinds = set()
    for i in range(m.particle_count):
        expect = _expected_records(i, a, tris, vt, ve, caps)
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
