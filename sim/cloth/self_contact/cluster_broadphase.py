"""The cluster broadphase of the cloth self-contact detection
(``SelfContact(broadphase="clusters")``): the detection's three queries over the fixed clusters
of ``sim.cloth.clusters`` (which says why and how) instead of three trees. Each primitive's
thread meets the members of the target clusters its cluster's masks mark; the candidates and
the lists' tests are the trees' (``lists``)."""

from __future__ import annotations

import warp as wp

from sim.cloth.clusters import (
    ClusterArrays,
    ClusterLayout,
    meet_mask8,
    reach_radius,
    store_cluster,
    store_octet,
)
from sim.cloth.lanes import lane_mask, lane_xor, lane_xor_vec3
from sim.cloth.self_contact.data import LIST_OUTPUTS, SelfContactData
from sim.cloth.self_contact.lists import (
    edge_edge_candidate,
    merge_split_kernel,
    query_radius,
    vertex_triangle_candidate,
)
from sim.cloth.spans import load_int, load_vec2i, load_vec3, load_vec3i
from sim.device import warp

# cluster slots up to which ``cluster_split=0`` splits the cluster query in two (one garment of
# up to ~20k vertices: a few warps per SM, so a query's chain of loads sets the time; a batch of
# them fills the GPU without)
SPLIT_SLOTS = 131072


@wp.func
def corner_spread(v: wp.array(dtype=wp.vec3), c0: int, c1: int, c2: int):
    """The mean of three corner velocities (a vertex: one corner three times, an edge: its ends
    with one twice) and the largest distance of a corner's from it."""
    a = load_vec3(v, c0)
    b = load_vec3(v, c1)
    c = load_vec3(v, c2)
    mean = (a + b + c) / 3.0
    return mean, wp.max(wp.max(wp.length(a - mean), wp.length(b - mean)), wp.length(c - mean))


@wp.func
def slot_corners(k: int, p: int, tri_indices: wp.array(dtype=wp.vec3i), edges: wp.array(dtype=wp.vec2i)):
    """The corners of primitive ``p`` of kind ``k`` (0 vertex, 1 triangle, 2 edge; ``sim.cloth.clusters``)
    as three vertex ids (repeated where it has fewer)."""
    if k == 0:
        return wp.vec3i(p, p, p)
    if k == 1:
        return load_vec3i(tri_indices, p)
    e = load_vec2i(edges, p)
    return wp.vec3i(e[0], e[1], e[1])


@wp.func
def slot_kind(c: int, kind_clusters: wp.vec4i) -> int:
    """The kind of cluster ``c`` (0 vertices, 1 triangles, 2 edges)."""
    k = int(0)
    if c >= kind_clusters[1]:
        k = 1
    if c >= kind_clusters[2]:
        k = 2
    return k


@wp.func
def slot_bounds(s: int, x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
                particle_instance: wp.array(dtype=wp.int32), tri_indices: wp.array(dtype=wp.vec3i),
                margin: float, speed_factor: float, h: float, sc: SelfContactData, cl: ClusterArrays):
    """Cluster slot ``s``'s box, query radius (its fastest corner's speed in its instance's frame,
    ``query_radius``), corners' mean velocity and spread (``corner_spread``); a padding slot's: an
    empty box, radius 0, spread -1."""
    p = cl.order[s]
    if p < 0:
        return wp.vec3(1.0e30), wp.vec3(-1.0e30), 0.0, wp.vec3(), -1.0
    k = slot_kind(s / cl.size, cl.kind_clusters)
    q = slot_corners(k, p, tri_indices, sc.mesh_edges)
    a = load_vec3(x, q[0])
    b = load_vec3(x, q[1])
    c = load_vec3(x, q[2])
    vr = sc.reference[particle_instance[q[0]]]
    speed = wp.max(wp.max(wp.length(load_vec3(v, q[0]) - vr), wp.length(load_vec3(v, q[1]) - vr)),
                   wp.length(load_vec3(v, q[2]) - vr))
    mean, spread = corner_spread(v, q[0], q[1], q[2])
    r = query_radius(margin, speed, h, speed_factor)
    return wp.min(wp.min(a, b), c), wp.max(wp.max(a, b), c), r, mean, spread


@wp.kernel
def member_bounds_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    tri_indices: wp.array(dtype=wp.vec3i),
    margin: float,
    speed_factor: float,
    h: float,
    sc: SelfContactData,
    cl_inout: ClusterArrays,
):
    """Per cluster slot: its primitive's box (a vertex's point, a triangle's or an edge's box),
    query radius, corners' mean velocity and spread (``slot_bounds``) into ``cl_inout``."""
    s = wp.tid()
    lo, hi, r, mean, spread = slot_bounds(s, x, v, particle_instance, tri_indices, margin, speed_factor, h,
                                          sc, cl_inout)
    cl_inout.lo[s] = lo
    cl_inout.hi[s] = hi
    cl_inout.radius[s] = r
    cl_inout.vel[s] = mean
    cl_inout.spread[s] = spread


@wp.func
def reduce_lanes(lo: wp.vec3, hi: wp.vec3, r: float, total: wp.vec3, count: float, first: int, last: int,
                 mask: int):
    """The union of the boxes, largest radius and sums of ``total`` and ``count`` over the lanes
    that differ from this one in bits ``first`` to ``last`` (powers of two; shuffles)."""
    m = first
    while m <= last:
        lo = wp.min(lo, lane_xor_vec3(lo, m, mask))
        hi = wp.max(hi, lane_xor_vec3(hi, m, mask))
        r = wp.max(r, lane_xor(r, m, mask))
        total = total + lane_xor_vec3(total, m, mask)
        count = count + lane_xor(count, m, mask)
        m = 2 * m
    return lo, hi, r, total, count


@wp.func
def max_lanes(x: float, first: int, last: int, mask: int) -> float:
    m = first
    while m <= last:
        x = wp.max(x, lane_xor(x, m, mask))
        m = 2 * m
    return x


@wp.kernel
def cluster_bounds_fused_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    tri_indices: wp.array(dtype=wp.vec3i),
    margin: float,
    speed_factor: float,
    h: float,
    sc_inout: SelfContactData,
    cl_inout: ClusterArrays,
):
    """``member_bounds_kernel``, ``clusters.octet_bounds_kernel`` and
    ``clusters.cluster_bounds_kernel`` in one launch, on CUDA, for clusters of up to 32 slots
    (``clusters.LANE_SIZES``): a cluster is a segment of a warp, so its octets' and its own
    boxes, radii, mean velocities and spreads come from lane shuffles, not from two more
    launches on every substep's critical path. The boxes and radii are the same; the means are
    summed in another order, which the spreads, measured from them, still bound. The slots' own
    velocities and spreads, which only the octet kernel reads, are not written. Thread 0 also
    zeroes the counters the gather records count with (``records``: two memset nodes fewer on
    the critical path)."""
    s = wp.tid()
    n = cl_inout.order.shape[0]
    if s == 0:
        sc_inout.pair_cursor[0] = 0
        for colour in range(sc_inout.heavy_count.shape[0]):
            sc_inout.heavy_count[colour] = 0
    mask = lane_mask(s, n)
    lo, hi, r, mean, spread = slot_bounds(s, x, v, particle_instance, tri_indices, margin, speed_factor, h,
                                          sc_inout, cl_inout)
    valid = float(0.0)
    if spread >= 0.0:
        valid = 1.0
    cl_inout.lo[s] = lo
    cl_inout.hi[s] = hi
    cl_inout.radius[s] = r
    # the octet (lanes differing in bits 1, 2, 4)
    o_lo, o_hi, o_r, o_total, o_count = reduce_lanes(lo, hi, r, valid * mean, valid, 1, 4, mask)
    o_mean = o_total / wp.max(o_count, 1.0)
    reach = float(0.0)
    if valid > 0.0:
        reach = wp.length(mean - o_mean) + spread
    o_reach = max_lanes(reach, 1, 4, mask)
    if s % 8 == 0:
        store_octet(cl_inout, s / 8, o_lo, o_hi, o_r, o_mean, o_count, o_reach)
    # the cluster (lanes differing in bits 8 to size / 2, each holding its octet's data)
    c_lo, c_hi, c_r, c_total, c_count = reduce_lanes(o_lo, o_hi, o_r, o_count * o_mean, o_count, 8,
                                                     cl_inout.size / 2, mask)
    # summed over the octets' lanes: every lane of an octet holds its octet's sums
    c_mean = c_total / wp.max(c_count, 1.0)
    c_reach = float(0.0)
    if o_count > 0.0:
        c_reach = wp.length(o_mean - c_mean) + o_reach
    c_reach = max_lanes(c_reach, 8, cl_inout.size / 2, mask)
    if s % cl_inout.size == 0:
        store_cluster(cl_inout, s / cl_inout.size, c_lo, c_hi, c_r, c_mean, c_reach)


@wp.struct
class SlotQuery:
    """The query of one cluster slot's primitive (``slot_query``): its ``kind`` (0 vertex, 1
    triangle, 2 edge), the list it fills (``owner``), the primitive (``vertex``; ``tri``; ``edge``
    with its ends at ``p1``, ``q1``), its box, its corners' velocities and its query radius."""

    kind: int
    owner: int
    vertex: int
    tri: wp.vec3i
    edge: wp.vec2i
    p1: wp.vec3
    q1: wp.vec3
    lo: wp.vec3
    hi: wp.vec3
    v0: wp.vec3
    v1: wp.vec3
    v2: wp.vec3
    radius: float


@wp.func
def slot_query(s: int, p: int, f: int, split: int, x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
               tri_indices: wp.array(dtype=wp.vec3i), cl: ClusterArrays, sc: SelfContactData) -> SlotQuery:
    """The query of slot ``s`` (primitive ``p``) for its thread ``f`` of ``split``: with
    ``split`` > 1 the thread's own partial lists, those of owner ``f * count + p`` in ``sc``'s
    arrays (``count`` primitives of the kind)."""
    q = SlotQuery()
    k = slot_kind(s / cl.size, cl.kind_clusters)
    q.kind = k
    q.radius = cl.radius[s]
    q.lo = cl.lo[s]
    q.hi = cl.hi[s]
    corners = slot_corners(k, p, tri_indices, sc.mesh_edges)
    q.v0 = load_vec3(v, corners[0])
    q.v1 = load_vec3(v, corners[1])
    q.v2 = load_vec3(v, corners[2])
    q.vertex = -1
    if k == 0:
        q.vertex = p
    elif k == 1:
        q.tri = tri_indices[p]
    else:
        q.edge = sc.mesh_edges[p]
        q.p1 = x[q.edge[0]]
        q.q1 = x[q.edge[1]]
    q.owner = p
    if split > 1:
        n_kind = sc.vt_count.shape[0] / split
        if k == 1:
            n_kind = sc.tv_count.shape[0] / split
        elif k == 2:
            n_kind = sc.ee_count.shape[0] / split
        q.owner = f * n_kind + p
    return q


@wp.func
def member_candidate(q: SlotQuery, item: int, count: int, x: wp.array(dtype=wp.vec3),
                     v: wp.array(dtype=wp.vec3), tri_indices: wp.array(dtype=wp.vec3i), margin: float,
                     speed_factor: float, h: float, sc: SelfContactData) -> int:
    """Target member ``item`` as a candidate of query ``q`` (a vertex meets a triangle, a
    triangle a vertex, an edge an edge; incident ones are skipped): the list's count after it."""
    if q.kind == 0:
        t_item = load_vec3i(tri_indices, item)
        if t_item[0] == q.vertex or t_item[1] == q.vertex or t_item[2] == q.vertex:
            return count
        return vertex_triangle_candidate(sc, x, v, q.vertex, t_item, q.radius, margin, speed_factor, h, count,
                                         sc.vt_tri, sc.vt_dist, sc.vt_ref, sc.vt_rk, q.owner, sc.vt_capacity,
                                         item)
    if q.kind == 1:
        if item == q.tri[0] or item == q.tri[1] or item == q.tri[2]:
            return count
        return vertex_triangle_candidate(sc, x, v, item, q.tri, q.radius, margin, speed_factor, h, count,
                                         sc.tv_vertex, sc.tv_dist, sc.tv_ref, sc.tv_rk, q.owner,
                                         sc.tv_capacity, item)
    ea = q.edge
    eb = load_vec2i(sc.mesh_edges, item)
    if eb[0] == ea[0] or eb[0] == ea[1] or eb[1] == ea[0] or eb[1] == ea[1]:
        return count
    return edge_edge_candidate(sc, x, v, q.owner, ea, q.p1, q.q1, item, eb, q.radius, margin, speed_factor, h,
                               count)


@wp.func
def target_candidates(q: SlotQuery, target: int, count: int, relative: int, x: wp.array(dtype=wp.vec3),
                      v: wp.array(dtype=wp.vec3), tri_indices: wp.array(dtype=wp.vec3i), margin: float,
                      speed_factor: float, h: float, cl: ClusterArrays, sc: SelfContactData) -> int:
    """The members of target cluster ``target`` that query ``q`` meets, each a candidate
    (``member_candidate``): its reach is its query radius, or with ``relative``
    (``clusters.cluster_masks_kernel``) no more than the radius of the largest relative speed it
    can have to a member (its corners' distance from the cluster's mean velocity plus the
    cluster's spread). The octets (8 slots) its box grown by the reach misses are skipped.
    Returns the list's count after them."""
    first = target * cl.size
    u = load_vec3(cl.cluster_vel, target)
    fastest = wp.max(wp.max(wp.length(q.v0 - u), wp.length(q.v1 - u)), wp.length(q.v2 - u))
    spread = cl.cluster_spread[target]
    reach = reach_radius(q.radius, relative, margin, speed_factor, h, fastest + spread)
    q_lo = q.lo - wp.vec3(reach)
    q_hi = q.hi + wp.vec3(reach)
    n_octets = cl.size / 8
    octets = meet_mask8(q_lo, q_hi, cl.octet_lo, cl.octet_hi, target * n_octets) & ((1 << n_octets) - 1)
    meets = int(0)
    for j in range(cl.size):
        if j % 8 == 0:
            meets = int(0)
            if ((octets >> (j / 8)) & 1) != 0:
                meets = meet_mask8(q_lo, q_hi, cl.lo, cl.hi, first + j)
        if ((meets >> (j % 8)) & 1) != 0:
            count = member_candidate(q, load_int(cl.order, first + j), count, x, v, tri_indices, margin,
                                     speed_factor, h, sc)
    return count


@wp.kernel
def detect_clustered_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    tri_indices: wp.array(dtype=wp.vec3i),
    cl: ClusterArrays,
    relative: int,
    margin: float,
    speed_factor: float,
    h: float,
    split: int,
    sc_inout: SelfContactData,
):
    """The three detection queries of ``bvh_broadphase`` over the clusters: one thread per
    cluster slot, whose primitive meets the members of each target cluster that its cluster's
    masks mark (``target_candidates``). The same candidates, tests and lists; the candidates come
    in cluster order, so the lists hold the same pairs in another order.

    With ``split`` > 1 each slot has ``split`` threads (thread ``f * slots + s``), thread ``f``
    taking every ``split``-th marked cluster, into its own partial lists (``slot_query``), which
    ``lists.merge_split_kernel`` merges. A query's chain of loads is what takes the time (a few
    warps per SM), and this cuts it."""
    t = wp.tid()
    slots = cl.order.shape[0]
    f = t / slots
    s = t - f * slots
    p = cl.order[s]
    if p < 0:
        return
    q = slot_query(s, p, f, split, x, v, tri_indices, cl, sc_inout)
    k = q.kind
    a = s / cl.size
    tk = 1 - k
    if k == 2:
        tk = 2
    t0 = cl.group_first[tk * (cl.groups + 1) + cl.cluster_group[a]]
    w_count = cl.words[k]
    mask_base = cl.mask_first[k] + (a - cl.kind_clusters[k]) * w_count
    count = int(0)
    nth = int(-1)
    for w in range(w_count):
        bits = cl.masks[mask_base + w]
        b = int(0)
        while bits != 0:
            if (bits & 1) != 0:
                nth += 1
            if (bits & 1) != 0 and nth % split == f:
                count = target_candidates(q, cl.target_first[k] + t0 + w * 32 + b, count, relative, x, v,
                                          tri_indices, margin, speed_factor, h, cl, sc_inout)
            bits = (bits >> 1) & 0x7FFFFFFF
            b += 1
    if k == 0:
        sc_inout.vt_count[q.owner] = count
    elif k == 1:
        sc_inout.tv_count[q.owner] = count
    else:
        sc_inout.ee_count[q.owner] = count


class ClusterBroadphase:
    """The clusters of a ``ClothModel`` (``ClusterLayout``) and the partial lists of a split query.

    Args:
        model: the cloth model.
        sc: its ``SelfContactData`` (the partial lists take its lists' shapes).
        size: primitives per cluster (``clusters.CLUSTER_SIZES``).
        split: threads per primitive of the query (``detect_clustered_kernel``; 0: 2 up to
            ``SPLIT_SLOTS`` cluster slots, else 1).
        lanes: the clusters' octet and cluster data from lane shuffles in the slots' own launch
            (``cluster_bounds_fused_kernel``; CUDA, sizes ``clusters.LANE_SIZES``); None:
            wherever they can.
    """

    def __init__(self, model, sc: SelfContactData, size: int = 32, split: int = 1, lanes: bool | None = None):
        w = warp()
        self.model = model
        self.layout = ClusterLayout(model, size, lanes)
        if split < 0:
            raise ValueError(f"SelfContact: cluster_split must be >= 0 (0: auto), got {split}")
        if split == 0:
            split = 2 if self.layout.slots <= SPLIT_SLOTS else 1
        self.split = int(split)
        self._partial = {}
        if self.split > 1:
            for name in LIST_OUTPUTS:
                a = getattr(sc, name)
                self._partial[name] = w.zeros(a.shape[0] * self.split, dtype=a.dtype, device=model.device)

    def _partial_lists(self, sc: SelfContactData) -> SelfContactData:
        """``sc`` with the partial lists of a split query in place of its lists. Every other
        field is taken from ``sc`` at each call (the reference velocities change)."""
        out = SelfContactData()
        for name in SelfContactData.vars:
            setattr(out, name, self._partial.get(name, getattr(sc, name)))
        return out

    def detect(self, x0, v, h: float, rebuild: bool, margin: float, speed_factor: float,
               sc: SelfContactData) -> bool:
        """The three queries at ``x0`` into ``sc``'s lists: the slots' boxes and radii, the
        clusters' boxes and masks, then one query launch for every primitive (``rebuild`` has
        nothing to rebuild: the clusters are fixed). Returns whether ``sc``'s record counters were
        zeroed (by ``cluster_bounds_fused_kernel``)."""
        w = warp()
        m = self.model
        cl = self.layout
        if cl.slots == 0:
            return False
        w.launch(cluster_bounds_fused_kernel if cl.lanes else member_bounds_kernel, dim=cl.slots,
                 inputs=[x0, v, m.particle_instance, m.tri_indices, margin, speed_factor, h, sc, cl.arrays],
                 device=m.device)
        # with relative lists only the pairs within the radius of their relative speed are stored
        relative = sc.relative_lists != 0
        cl.update(relative, margin, speed_factor, h)
        part = self._partial_lists(sc) if self.split > 1 else sc
        w.launch(detect_clustered_kernel, dim=cl.slots * self.split,
                 inputs=[x0, v, m.tri_indices, cl.arrays, int(relative), margin, speed_factor, h, self.split],
                 outputs=[part], device=m.device)
        if self.split > 1:
            n, nt, ne = m.particle_count, m.tri_count, m.mesh_edge_indices.shape[0]
            w.launch(merge_split_kernel, dim=n + nt + ne, inputs=[self.split, n, nt, ne, part], outputs=[sc],
                     device=m.device)
        return cl.lanes
