"""Self-contact detection (sim.cloth.self_contact: bvh_broadphase, cluster_broadphase, lists;
sim.cloth.clusters): the stored pairs against brute force, full lists keeping the closest, a
fold in contact a ring away, each instance's own subtree roots, and the clusters finding the
trees' pairs."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from sim.cloth import ClothMaterialParams, ClothModelBuilder
from sim.cloth.self_contact import SelfContact
from tests.self_contact_scenes import (
    all_lists,
    closest_point_triangle_np,
    detect_at,
    folded_sheet,
    jittered_sheets,
    point_triangle_distance_np,
    segment_distance_np,
    three_pieces,
)
from tests.test_cloth_solver import grid

CONTACT = dict(radius=0.003, stiffness=1e4, friction=0.0, speed_factor=2.5)
SEP = 2e-5  # pairs this close to a radius are left out of brute-force comparisons (float32 detection)


def _classify(d: float, r_query: float, r_list: float, want: set, away: set, key) -> None:
    """Put ``key`` in ``want`` (stored) or ``away`` (not stored), unless at a threshold."""
    if abs(d - r_query) > SEP and abs(d - r_list) > SEP:
        (want if d < min(r_query, r_list) else away).add(key)


def _brute_force_vertex_triangle(x, f, vel, speed, radius):
    """The VT and TV pairs (as (vertex, triangle) / (triangle, vertex)) that must and must not be
    stored: within the query radius of the querying primitive's speed and the list radius of the
    pair's relative speed (one velocity per sheet)."""
    want, away, tv_want, tv_away = set(), set(), set(), set()
    for i in range(len(x)):
        for t, tri in enumerate(f):
            if i in tri:
                continue
            d = point_triangle_distance_np(x[i], *x[tri])
            r_list = radius(np.linalg.norm(vel[i] - vel[tri[0]]))
            _classify(d, radius(speed[i]), r_list, want, away, (i, t))
            _classify(d, radius(speed[tri].max()), r_list, tv_want, tv_away, (t, i))
    return want, away, tv_want, tv_away


def _brute_force_edges(x, edges, vel, speed, radius):
    """The EE pairs that must and must not be stored (edges sharing no vertex)."""
    want, away = set(), set()
    for a, (p, q) in enumerate(edges):
        for c, (s_, t_) in enumerate(edges):
            if len({p, q, s_, t_}) < 4:
                continue
            d = segment_distance_np(x[p], x[q], x[s_], x[t_])
            r_list = radius(np.linalg.norm(vel[p] - vel[s_]))
            _classify(d, radius(speed[[p, q]].max()), r_list, want, away, (a, c))
    return want, away


@pytest.mark.slow
@pytest.mark.parametrize("motion,frame", [("still", 0.0), ("together", 0.0), ("sliding", 0.0),
                                          ("together", 3.0), ("sliding", 3.0)])
def test_detection_finds_exactly_the_pairs_within_the_query_radius(device, motion, frame):
    """Pair detection against brute force: a flat sheet and a jittered sheet 2-8 mm above it
    (one instance, two pieces), still, moving together at 3 m/s, or the upper one sliding over
    the lower at 3 m/s, searched in the frame moving at ``frame`` m/s along x (the instance's
    reference velocity). A primitive's query radius is ``max(margin, 2.5 |v - v_ref| h)`` of its
    own speed in that frame; of the pairs within it, exactly those closer than the radius of
    their relative speed ``max(margin, 2.5 |v_a - v_b| h)`` are stored (layers moving together
    keep only the 6 mm pairs, a sliding layer the 25 mm ones), never an incident pair."""
    r, h, sf, cap = 0.006, 1.0 / 300.0, 2.5, 128
    v, f = jittered_sheets(7, 6, 0.012, seed=5)
    half = len(v) // 2
    vel = np.zeros_like(v)
    if motion != "still":
        vel[half:] = (3.0, 0.0, 0.0)
    if motion == "together":
        vel[:half] = (3.0, 0.0, 0.0)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams())
    m = b.finalize(device)
    sc = SelfContact(m, margin=r, capacity=cap, **CONTACT)
    ref = np.array([frame, 0.0, 0.0], np.float32)
    detect_at(sc, v, vel, h, reference=wp.array(ref[None], dtype=wp.vec3, device=device))
    x = v.astype(np.float64)
    speed = np.linalg.norm(vel - ref, axis=1)

    def radius(s):
        return max(r, sf * s * h)

    def lists(count, ids, rows):
        c, ids = count.numpy(), ids.numpy().reshape(rows, cap)
        assert c.max() < cap
        return {(a, int(o)) for a in range(rows) for o in ids[a, :c[a]]}

    want, away, tv_want, tv_away = _brute_force_vertex_triangle(x, f, vel, speed, radius)
    found = lists(sc.data.vt_count, sc.data.vt_tri, len(v))
    tv_found = lists(sc.data.tv_count, sc.data.tv_vertex, len(f))
    assert len(want) > 50 and len(tv_want) > 50
    assert want <= found and not (found & away)
    assert tv_want <= tv_found and not (tv_found & tv_away)
    edges = m.mesh_edge_indices.numpy()
    ee_want, ee_away = _brute_force_edges(x, edges, vel, speed, radius)
    ee_found = lists(sc.data.ee_count, sc.data.ee_edge, len(edges))
    assert len(ee_want) > 50
    assert ee_want <= ee_found and not (ee_found & ee_away)
    if motion == "together":  # no relative motion: only the pairs within the margin
        assert all(point_triangle_distance_np(x[i], *x[f[t]]) < r + SEP for i, t in found)


def test_full_pair_lists_keep_the_closest_pairs(device):
    """With room for 2 pairs, a vertex lying over many triangles keeps the 2 closest, whatever
    order the BVH finds them in (first-found lists would let a crumple's near neighbours crowd
    out the layer that is actually touching)."""
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
    sc = SelfContact(m, margin=0.012, capacity=2, **CONTACT)
    detect_at(sc, x)
    i = len(v)  # the probe triangle's first vertex, 4 mm over the sheet
    count = int(sc.data.vt_count.numpy()[i])
    kept = sc.data.vt_tri.numpy().reshape(-1, 2)[i, :count]
    faces = np.asarray(f)
    d_all = np.array([closest_point_triangle_np(x[i].astype(np.float64), *x[faces[t]].astype(np.float64))[1]
                      for t in range(len(faces))])
    assert (d_all < 0.012).sum() > 2  # more candidates than room
    assert count == 2
    np.testing.assert_allclose(np.sort(d_all[kept]), np.sort(d_all)[:2], atol=2e-4)


def test_a_fold_of_one_sheet_is_in_contact_a_ring_away(device):
    """A sheet folded flat onto itself (zero fold radius at column ``m``): the vertex one
    column past the fold lies 2 mm above the column before it, two edges away on the surface.
    It is a contact pair (pairs are told apart by their own rest distance, not by a few edge
    lengths: a sleeve that crumples is two rings meeting); the fold line's vertices are never
    paired with their own triangles."""
    nx, ny, mid = 11, 4, 5
    v, folded, f, col = folded_sheet(nx, ny, 0.02, mid, 0.002)
    b = ClothModelBuilder()
    b.add_cloth(v.astype(np.float32), f, ClothMaterialParams())
    m = b.finalize(device)
    sc = SelfContact(m, margin=0.01, capacity=16, **CONTACT)
    detect_at(sc, folded)
    count = sc.data.vt_count.numpy()
    tri = sc.data.vt_tri.numpy().reshape(len(v), 16)
    faces = np.asarray(f)
    for j in range(1, ny - 1):
        i = j * nx + mid + 1  # one column past the fold, above column mid - 1
        partners = faces[tri[i, :count[i]]]
        assert count[i] > 0, "a vertex folded onto its own sheet two edges away must be in contact"
        assert np.all(col[partners] <= mid)  # the layer below
        assert not np.any(partners == i)  # never its own triangles
    for j in range(ny):
        i = j * nx + mid
        assert not np.any(faces[tri[i, :count[i]]] == i)


@wp.kernel
def _group_roots_direct(bvh: wp.uint64, out: wp.array(dtype=wp.int32)):
    g = wp.tid()
    out[g] = wp.bvh_get_group_root(bvh, g)


def test_instance_roots_found_at_rebuilds_give_each_instance_its_own_pairs(device):
    """The detection queries start at each instance's subtree root, found once per tree build
    (``group_roots_kernel``) instead of by every query thread. Three instances of two layers in
    contact: the roots equal Warp's per-thread ``bvh_get_group_root``, and each instance's pair
    counts equal those of the same layers detected alone, as built and after rebuilds at other
    positions (a group's root index depends only on the groups' sizes in Warp 1.19; the
    equality after rebuilds is what would catch a builder that numbers its nodes otherwise)."""
    nx, e = 7, 0.012
    v1, f1 = grid(nx, nx, (nx - 1) * e, (nx - 1) * e, plane="xz")
    layers = np.concatenate([v1, v1 + np.array([0.4 * e, 0.003, 0.3 * e], np.float32)]).astype(np.float32)
    faces = np.concatenate([f1, f1 + len(v1)]).astype(np.int32)
    n = len(layers)

    def detect(parts, rebuild=False):
        b = ClothModelBuilder()
        for p in parts:
            b.add_cloth(p, faces, ClothMaterialParams())
        m = b.finalize(device)
        sc = SelfContact(m, margin=0.006, capacity=32, **CONTACT)
        if rebuild:  # build at other positions, then detect (and rebuild) where the parts are
            detect_at(sc, np.concatenate(parts) * 0.5, rebuild=True)
        detect_at(sc, m.particle_q.numpy(), rebuild=rebuild)
        for k, bvh in enumerate(sc.broadphase.trees):
            direct = wp.zeros(m.instance_count, dtype=wp.int32, device=device)
            wp.launch(_group_roots_direct, dim=m.instance_count, inputs=[bvh.id], outputs=[direct],
                      device=device)
            np.testing.assert_array_equal(sc.broadphase.roots[k].numpy(), direct.numpy())
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


@pytest.mark.parametrize("size,relative,split", [(8, True, 1), (32, True, 1), (64, True, 1), (8, False, 1),
                                                 (32, False, 1), (8, False, 3), (32, True, 4)])
@pytest.mark.parametrize("motion", ["still", "sliding"])
def test_cluster_broadphase_finds_the_pairs_of_the_trees(device, size, relative, split, motion):
    """The cluster broadphase hands each query exactly the primitives whose boxes meet its query
    box, as the trees do: on the flat and the jittered sheet (two instances, so clusters must
    keep to their instance), with every vertex at its own random velocity or the upper sheet
    sliding at 3 m/s, with a smaller piece of another topology as a third instance, the three
    kinds of lists hold the same pairs (lists large enough that none fills: a full list's ties
    depend on the order), and so do the gather records per vertex. With relative lists the
    clusters cull by relative speed (``clusters.reach_radius``); split over several threads per
    primitive and merged (``split``), the same again."""
    m, vel = three_pieces(device, motion)
    found = {}
    for broadphase in ("bvh", "clusters"):
        sc = SelfContact(m, margin=0.006, capacity=200, broadphase=broadphase, cluster_size=size,
                         cluster_split=split, relative_lists=relative, **CONTACT)
        detect_at(sc, m.particle_q.numpy(), vel)
        for count in (sc.data.vt_count, sc.data.tv_count, sc.data.ee_count):
            assert count.numpy().max() < 200
        found[broadphase] = all_lists(sc, m)
    assert len(found["bvh"]["vt"]) > 300 and len(found["bvh"]["ee"]) > 1000
    # pairs between the two instances, which overlap in space, would show up as partners
    # outside the owner's instance
    assert found["clusters"] == found["bvh"]


def test_clusters_culled_by_relative_speed_search_fewer_clusters(device):
    """Each sheet of the sliding scene moves as one: with relative lists the clusters within a
    sheet are culled at the margin, not at the 25 mm the upper sheet's speed gives its queries,
    so a query searches fewer clusters (``ClusterLayout.marked``) than one culled by its query
    radius."""
    m, vel = three_pieces(device, "sliding")
    marked = {}
    for relative in (False, True):
        sc = SelfContact(m, margin=0.006, capacity=200, broadphase="clusters", cluster_size=8,
                         relative_lists=relative, **CONTACT)
        assert sc.clusters.marked() is None
        detect_at(sc, m.particle_q.numpy(), vel)
        marked[relative] = sum(sc.clusters.marked())
    assert marked[False] > marked[True] > 0


def _lane_data(device, m, vel, size: int, lanes: bool):
    """A cluster detection with or without lane shuffles: its clusters' data and its lists, after
    a second detection on the first one's outputs has given the same lists and record count
    (the fused kernel zeroes the record counters itself, no memsets)."""
    sc = SelfContact(m, margin=0.006, capacity=200, broadphase="clusters", cluster_size=size,
                     cluster_lanes=lanes, relative_lists=False, **CONTACT)
    assert sc.clusters.lanes == lanes
    detect_at(sc, m.particle_q.numpy(), vel)
    cl = sc.clusters.arrays
    data = {name: getattr(cl, name).numpy() for name in (
        "lo", "hi", "radius", "octet_lo", "octet_hi", "octet_radius", "octet_count", "octet_vel",
        "octet_spread", "cluster_lo", "cluster_hi", "cluster_radius", "cluster_vel", "cluster_spread",
        "masks")}
    lists = all_lists(sc, m)
    cursor = sc.data.pair_cursor.numpy().copy()
    detect_at(sc, m.particle_q.numpy(), vel)
    assert all_lists(sc, m) == lists
    np.testing.assert_array_equal(sc.data.pair_cursor.numpy(), cursor)
    return sc, data, lists


@pytest.mark.parametrize("size", [8, 16, 32])
@pytest.mark.parametrize("motion", ["still", "sliding"])
def test_cluster_lanes_bound_the_octets_and_clusters_as_their_own_launches_do(device, size, motion):
    """On CUDA the octets' and clusters' boxes, radii, velocities and spreads come from lane
    shuffles in the slots' launch (``cluster_bounds_fused_kernel``): the boxes and the radii
    are those of the separate launches to the bit, and so are the masks (culled by the query
    radii, relative lists off), split over four lanes per word (``clusters.MASK_PARTS``); the
    mean velocities agree to round-off (summed in another order), every spread holds each
    member's corner velocities within it of its mean (numpy, from the slots), and the query
    finds the same lists."""
    if device != "cuda":
        pytest.skip("lane shuffles are CUDA only (the CPU runs the separate launches)")
    m, vel = three_pieces(device, motion)
    _, a, lists_a = _lane_data(device, m, vel, size, False)
    sc, b, lists_b = _lane_data(device, m, vel, size, True)
    for name in ("lo", "hi", "radius", "octet_lo", "octet_hi", "octet_radius", "octet_count", "cluster_lo",
                 "cluster_hi", "cluster_radius", "masks"):
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    for name in ("octet_vel", "octet_spread", "cluster_vel", "cluster_spread"):
        np.testing.assert_allclose(a[name], b[name], rtol=1e-5, atol=1e-5, err_msg=name)
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
    assert lists_a == lists_b and len(lists_b["ee"]) > 1000


def test_cluster_layout_cuts_each_instance_into_compact_clusters():
    """``cluster_layout`` puts every primitive in exactly one slot, never mixes instances in a
    cluster, pads only an instance's last cluster, and follows the Morton curve: on a 40 x 40
    grid, clusters of 16 vertices span a few edge lengths (a random order spans the sheet).
    Grown over the mesh's edges (``grow_clusters``) the patches span less than the curve's runs."""
    from sim.cloth.clusters import cluster_layout
    from sim.cloth.model import mesh_edges

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
    order2, _, _ = cluster_layout(v, np.zeros(len(v), np.int64), 1, 16, mesh_edges(f_grid))
    assert sorted(order2[order2 >= 0].tolist()) == list(range(len(v)))
    patches = order2.reshape(-1, 16)
    span2 = [np.ptp(v[r[r >= 0]], axis=0).max() for r in patches if (r >= 0).sum() == 16]
    assert np.mean(span2) < np.mean(span) and np.mean(span2) < 0.05
    shuffled = np.random.default_rng(0).permutation(len(v))[:1600].reshape(100, 16)
    assert np.mean([np.ptp(v[r], axis=0).max() for r in shuffled]) > 0.3
    with pytest.raises(ValueError, match="group ids"):
        cluster_layout(pts, groups + 1, 2, 16)
