"""Cluster broadphase for the cloth self-contact detection: a flat two-level culling that
replaces the three BVHs' refits and traversals (``SelfContact(broadphase="clusters")``).

Why: on one garment the detection's tree queries are bound by latency, not work. A query
thread walks its tree as a chain of dependent node loads, ~50-60 us per query on the 5k t-shirt
even when it finds nothing, and each refit is another ~32 us chain, on every substep's critical
path. The clusters' launches have no such chains; ``SolverVBD.broadphase`` picks them on CUDA for
single garments (docs/DECISIONS.md gives the batches' and the CPU's figures, where the trees
stay).

Method:

* At construction the vertices, the triangles and the edges of every instance are cut into
  surface patches of at most ``size`` primitives, grown from seeds taken in the Morton order of
  their positions (centroids) (``grow_clusters``); a patch that runs out of neighbours is padded
  with ``-1`` slots. A cluster is a compact patch of the garment, and it stays one as the cloth
  moves (its members are neighbours on the surface, held together by the cloth's elasticity).
  Clusters never mix instances.
* Every detection (one thread each, no dependent chains): each slot's box (a vertex's point,
  a triangle's or an edge's box) and query radius (``member_bounds_kernel`` in
  ``sim.cloth.self_contact.cluster_broadphase``, which owns the radius rule); each cluster's box
  (the union of its members' boxes) and query box (the union of its members' boxes grown by
  their radii), ``cluster_bounds_kernel``; for each query cluster and each run of 32 target
  clusters of its instance, a 32-bit mask of the targets whose box meets its query box,
  ``cluster_masks_kernel``.
* The query (``detect_clustered_kernel``) gives each query primitive one thread; the 32 threads
  of a warp are one cluster, so they read the same masks and the same target boxes (broadcast
  loads) and only their hits differ. A thread tests its own query box against the members of
  every target cluster its mask marks.

The candidates a thread meets are exactly the primitives whose box meets its query box (a
cluster's query box holds each member's, a cluster's box each member's), as a BVH query
returns them, in cluster order: the lists hold the same pairs, in another order.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from sim.cloth.lanes import lane_mask, lane_xor_int
from sim.cloth.spans import load_vec3

# the primitive kinds, in the order of the layout's arrays: vertices (query of the vertex-triangle
# pairs, targets of the triangle query), triangles, edges
KINDS = ("vertex", "triangle", "edge")
# (query kind, target kind) of the three queries: vertices meet triangles, triangles meet
# vertices, edges meet edges
QUERIES = ((0, 1), (1, 0), (2, 2))
# bits of one mask word: target clusters per word
WORD = 32
EMPTY = 1.0e30
# cluster sizes: whole octets (the loads come eight at a time, ``meet_mask8``), at most eight
# of them (a cluster's octet boxes are tested eight at a time too)
CLUSTER_SIZES = (8, 16, 24, 32, 40, 48, 56, 64)
# sizes whose clusters are whole segments of a CUDA warp: their octet and cluster data come from
# lane shuffles inside the slots' own launch (``cluster_bounds_fused_kernel`` in
# ``sim.cloth.self_contact.cluster_broadphase``) instead of two launches more
LANE_SIZES = (8, 16, 32)
# threads per mask word where the lanes are used (``cluster_masks_kernel``: 1, 2 or 4)
MASK_PARTS = 4

def spread_bits(q: np.ndarray) -> np.ndarray:
    """10-bit integers with two zero bits inserted after each bit (one axis of a Morton code)."""
    q = q.astype(np.int64) & 0x3FF
    q = (q | (q << 16)) & 0x030000FF
    q = (q | (q << 8)) & 0x0300F00F
    q = (q | (q << 4)) & 0x030C30C3
    q = (q | (q << 2)) & 0x09249249
    return q


def morton_codes(points: np.ndarray, groups: np.ndarray, n_groups: int) -> np.ndarray:
    """30-bit Morton codes of ``points`` (N, 3), each group's points scaled to its own box."""
    p = np.asarray(points, dtype=np.float64)
    lo = np.full((n_groups, 3), np.inf)
    hi = np.full((n_groups, 3), -np.inf)
    np.minimum.at(lo, groups, p)
    np.maximum.at(hi, groups, p)
    extent = np.maximum((hi - lo).max(axis=1), 1.0e-12)
    q = np.clip(((p - lo[groups]) / extent[groups, None] * 1023.0).astype(np.int64), 0, 1023)
    return spread_bits(q[:, 0]) | (spread_bits(q[:, 1]) << 1) | (spread_bits(q[:, 2]) << 2)


def grow_clusters(points: np.ndarray, neighbours: np.ndarray, size: int) -> np.ndarray:
    """Primitives (centroids ``points``, adjacency ``neighbours``: pairs of primitive ids) cut into
    patches of at most ``size``: from each primitive not yet taken, in Morton order, a patch
    grows over the adjacency to the not-yet-taken primitives nearest its seed. Returns the slot
    order (int64, patches x size, -1 padding a patch that ran out of neighbours).

    Patches follow the surface: a run of a space-filling curve cut into chunks jumps across
    gaps and folds (the 5k t-shirt: chunks of 32 along the Morton curve span 18 cm against the
    patches' 11 cm, and a query meets twice as many of them)."""
    import heapq

    from scipy.sparse import coo_matrix

    n = len(points)
    p = np.asarray(points, dtype=np.float64)
    a = np.asarray(neighbours, dtype=np.int64).reshape(-1, 2)
    adj = coo_matrix((np.ones(2 * len(a)), (np.r_[a[:, 0], a[:, 1]], np.r_[a[:, 1], a[:, 0]])),
                     shape=(n, n)).tocsr()
    ind, ptr = adj.indices, adj.indptr
    seeds = np.argsort(morton_codes(p, np.zeros(n, np.int64), 1), kind="stable") if n else []
    taken = np.zeros(n, dtype=bool)
    out = []
    for seed in seeds:
        if taken[seed]:
            continue
        members = []
        heap = [(0.0, int(seed))]
        queued = {int(seed)}
        while heap and len(members) < size:
            _, u = heapq.heappop(heap)
            if taken[u]:
                continue
            taken[u] = True
            members.append(u)
            for w in ind[ptr[u]:ptr[u + 1]].tolist():
                if not taken[w] and w not in queued:
                    queued.add(w)
                    heapq.heappush(heap, (float(((p[w] - p[seed]) ** 2).sum()), w))
        out.append(members + [-1] * (size - len(members)))
    return np.asarray(out, dtype=np.int64).reshape(-1)


def shared_vertex_pairs(elements: np.ndarray) -> np.ndarray:
    """Pairs (i < j) of elements (rows of vertex ids) that share a vertex."""
    from scipy.sparse import coo_matrix

    e = np.asarray(elements, dtype=np.int64)
    if len(e) == 0:
        return np.zeros((0, 2), np.int64)
    rows = np.repeat(np.arange(len(e)), e.shape[1])
    inc = coo_matrix((np.ones(e.size), (rows, e.reshape(-1)))).tocsr()
    both = (inc @ inc.T).tocoo()
    keep = both.row < both.col
    return np.stack([both.row[keep], both.col[keep]], axis=1)


def cluster_layout(points: np.ndarray, groups: np.ndarray, n_groups: int, size: int,
                   neighbours: np.ndarray | None = None, local_key=None):
    """Primitives (centroids ``points``, instance ``groups``) in clusters of ``size``.

    Returns ``order`` (int32, clusters x size: the primitive of each slot, -1 for padding),
    ``cluster_group`` (int32 per cluster) and ``first`` (int32, n_groups + 1: each group's first
    cluster). With ``neighbours`` (pairs of adjacent primitives, never across groups) each group
    is cut into surface patches (``grow_clusters``); ``local_key(g)`` may name a group's
    topology, and groups with the same key share one cut (a batch of one garment: one cut).
    Without, the primitives follow the Morton curve and are cut every ``size``."""
    groups = np.asarray(groups, dtype=np.int64)
    n = len(groups)
    if size < 1:
        raise ValueError(f"cluster_layout: size must be >= 1, got {size}")
    if n and (groups.min() < 0 or groups.max() >= n_groups):
        raise ValueError(f"cluster_layout: group ids must lie in [0, {n_groups}), got "
                         f"{groups.min()}..{groups.max()}")
    ids_of = np.split(np.argsort(groups, kind="stable"),
                      np.cumsum(np.bincount(groups, minlength=n_groups))[:-1])
    if neighbours is None:
        codes = morton_codes(points, groups, n_groups) if n else np.zeros(0, np.int64)
        cuts = []
        for ids in ids_of:
            seq = ids[np.argsort(codes[ids], kind="stable")]
            pad = -len(seq) % size
            cuts.append(np.r_[seq, np.full(pad, -1, np.int64)])
    else:
        nb = np.asarray(neighbours, dtype=np.int64).reshape(-1, 2)
        local = np.empty(n, np.int64)
        for ids in ids_of:
            local[ids] = np.arange(len(ids))
        nb_of = np.split(nb[np.argsort(groups[nb[:, 0]], kind="stable")],
                         np.cumsum(np.bincount(groups[nb[:, 0]], minlength=n_groups))[:-1])
        cache: dict = {}
        cuts = []
        for g, ids in enumerate(ids_of):
            key = local_key(g) if local_key is not None else None
            if key is None or key not in cache:
                cut = grow_clusters(points[ids], local[nb_of[g]], size)
                if key is not None:
                    cache[key] = cut
            else:
                cut = cache[key]
            cuts.append(np.where(cut >= 0, ids[np.maximum(cut, 0)], -1))
    clusters = np.asarray([len(c) // size for c in cuts], dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(clusters)]).astype(np.int32)
    order = np.concatenate(cuts).astype(np.int32) if cuts else np.zeros(0, np.int32)
    cluster_group = np.repeat(np.arange(n_groups, dtype=np.int32), clusters)
    return order, cluster_group, first


@wp.func
def boxes_meet(lo_a: wp.vec3, hi_a: wp.vec3, lo_b: wp.vec3, hi_b: wp.vec3) -> bool:
    return (lo_a[0] <= hi_b[0] and lo_b[0] <= hi_a[0] and lo_a[1] <= hi_b[1] and lo_b[1] <= hi_a[1]
            and lo_a[2] <= hi_b[2] and lo_b[2] <= hi_a[2])


@wp.func
def meet_mask8(q_lo: wp.vec3, q_hi: wp.vec3, lo: wp.array(dtype=wp.vec3), hi: wp.array(dtype=wp.vec3),
               s: int) -> int:
    """Bit ``j`` set where slot ``s + j``'s box (``lo``, ``hi``; j < 8) meets the box ``q_lo``,
    ``q_hi``. Every load is issued before the first test: the slots' boxes come in one memory
    round trip instead of eight (a query meets hundreds of slots, each a load from L2)."""
    l0 = load_vec3(lo, s)
    l1 = load_vec3(lo, s + 1)
    l2 = load_vec3(lo, s + 2)
    l3 = load_vec3(lo, s + 3)
    l4 = load_vec3(lo, s + 4)
    l5 = load_vec3(lo, s + 5)
    l6 = load_vec3(lo, s + 6)
    l7 = load_vec3(lo, s + 7)
    h0 = load_vec3(hi, s)
    h1 = load_vec3(hi, s + 1)
    h2 = load_vec3(hi, s + 2)
    h3 = load_vec3(hi, s + 3)
    h4 = load_vec3(hi, s + 4)
    h5 = load_vec3(hi, s + 5)
    h6 = load_vec3(hi, s + 6)
    h7 = load_vec3(hi, s + 7)
    m = int(0)
    if boxes_meet(q_lo, q_hi, l0, h0):
        m = m | 1
    if boxes_meet(q_lo, q_hi, l1, h1):
        m = m | 2
    if boxes_meet(q_lo, q_hi, l2, h2):
        m = m | 4
    if boxes_meet(q_lo, q_hi, l3, h3):
        m = m | 8
    if boxes_meet(q_lo, q_hi, l4, h4):
        m = m | 16
    if boxes_meet(q_lo, q_hi, l5, h5):
        m = m | 32
    if boxes_meet(q_lo, q_hi, l6, h6):
        m = m | 64
    if boxes_meet(q_lo, q_hi, l7, h7):
        m = m | 128
    return m


@wp.struct
class ClusterArrays:
    """A ``ClusterLayout``'s settings and arrays, one kernel argument (``ClusterLayout.arrays``).

    ``kind_clusters``: each kind's first cluster and the total; per query ``q`` (``QUERIES``,
    whose query kind is ``q``): ``target_first`` its target kind's first cluster,
    ``target_kind``, ``words`` mask words per query cluster and ``mask_first`` its first word
    (and the end); ``group_first[k * (groups + 1) + g]`` kind ``k``'s first cluster of instance
    ``g`` counted within the kind; then the per-slot, per-octet and per-cluster data."""

    size: int
    groups: int
    kind_clusters: wp.vec4i
    target_first: wp.vec3i
    target_kind: wp.vec3i
    words: wp.vec3i
    mask_first: wp.vec4i
    order: wp.array(dtype=wp.int32)
    group_first: wp.array(dtype=wp.int32)
    cluster_group: wp.array(dtype=wp.int32)
    masks: wp.array(dtype=wp.int32)
    lo: wp.array(dtype=wp.vec3)
    hi: wp.array(dtype=wp.vec3)
    radius: wp.array(dtype=float)
    vel: wp.array(dtype=wp.vec3)
    spread: wp.array(dtype=float)
    octet_lo: wp.array(dtype=wp.vec3)
    octet_hi: wp.array(dtype=wp.vec3)
    octet_radius: wp.array(dtype=float)
    octet_vel: wp.array(dtype=wp.vec3)
    octet_count: wp.array(dtype=float)
    octet_spread: wp.array(dtype=float)
    cluster_lo: wp.array(dtype=wp.vec3)
    cluster_hi: wp.array(dtype=wp.vec3)
    cluster_radius: wp.array(dtype=float)
    cluster_vel: wp.array(dtype=wp.vec3)
    cluster_spread: wp.array(dtype=float)


@wp.func
def store_octet(cl: ClusterArrays, o: int, lo: wp.vec3, hi: wp.vec3, radius: float, vel: wp.vec3,
                count: float, spread: float):
    """Octet ``o``'s box, largest query radius, mean velocity, members and spread."""
    cl.octet_lo[o] = lo
    cl.octet_hi[o] = hi
    cl.octet_radius[o] = radius
    cl.octet_vel[o] = vel
    cl.octet_count[o] = count
    cl.octet_spread[o] = spread


@wp.func
def store_cluster(cl: ClusterArrays, c: int, lo: wp.vec3, hi: wp.vec3, radius: float, vel: wp.vec3,
                  spread: float):
    """Cluster ``c``'s box, largest query radius, mean velocity and spread."""
    cl.cluster_lo[c] = lo
    cl.cluster_hi[c] = hi
    cl.cluster_radius[c] = radius
    cl.cluster_vel[c] = vel
    cl.cluster_spread[c] = spread


@wp.kernel
def octet_bounds_kernel(cl: ClusterArrays):
    """Per octet (8 consecutive slots of a cluster): the union of the slots' boxes, their
    largest query radius, the mean of their velocities (``vel``: each primitive's mean corner
    velocity), the number of slots holding a primitive, and the octet's velocity spread: the
    largest distance of a corner velocity from that mean (``spread``: a slot's own, -1 for
    padding)."""
    o = wp.tid()
    s = 8 * o
    a = wp.vec3(EMPTY)
    b = wp.vec3(-EMPTY)
    r = float(0.0)
    total = wp.vec3()
    count = float(0.0)
    for j in range(8):
        a = wp.min(a, load_vec3(cl.lo, s + j))
        b = wp.max(b, load_vec3(cl.hi, s + j))
        r = wp.max(r, cl.radius[s + j])
        if cl.spread[s + j] >= 0.0:
            total += load_vec3(cl.vel, s + j)
            count += 1.0
    mean = total / wp.max(count, 1.0)
    reach = float(0.0)
    for j in range(8):
        if cl.spread[s + j] >= 0.0:
            reach = wp.max(reach, wp.length(load_vec3(cl.vel, s + j) - mean) + cl.spread[s + j])
    store_octet(cl, o, a, b, r, mean, count, reach)


@wp.kernel
def cluster_bounds_kernel(cl: ClusterArrays):
    """Per cluster, from its octets: the union of their boxes, the largest query radius, the
    mean velocity and the spread (the largest distance of a member's corner velocity from that
    mean, bounded through each octet's mean)."""
    c = wp.tid()
    octets = cl.size / 8
    first = c * octets
    a = wp.vec3(EMPTY)
    b = wp.vec3(-EMPTY)
    r = float(0.0)
    total = wp.vec3()
    count = float(0.0)
    for o in range(octets):
        a = wp.min(a, load_vec3(cl.octet_lo, first + o))
        b = wp.max(b, load_vec3(cl.octet_hi, first + o))
        r = wp.max(r, cl.octet_radius[first + o])
        total += cl.octet_count[first + o] * load_vec3(cl.octet_vel, first + o)
        count += cl.octet_count[first + o]
    mean = total / wp.max(count, 1.0)
    reach = float(0.0)
    for o in range(octets):
        if cl.octet_count[first + o] > 0.0:
            away = wp.length(load_vec3(cl.octet_vel, first + o) - mean)
            reach = wp.max(reach, away + cl.octet_spread[first + o])
    store_cluster(cl, c, a, b, r, mean, reach)


@wp.func
def reach_radius(radius: float, relative: int, margin: float, speed_factor: float, h: float,
                 speed: float) -> float:
    """The distance within which a query of radius ``radius`` can store a pair whose relative
    speed is at most ``speed`` (``self_contact.lists.list_pair``: closer than the radius of that
    speed), with a little slack for round-off; ``relative`` 0: ``radius`` itself."""
    if relative == 0:
        return radius
    return wp.min(radius, wp.max(margin, speed_factor * speed * h) * 1.0001 + 1.0e-7)


@wp.func
def cluster_meets(lo_a: wp.vec3, hi_a: wp.vec3, r_a: float, u_a: wp.vec3, s_a: float, j: int,
                  cl: ClusterArrays,
                  relative: int, margin: float, speed_factor: float, h: float) -> bool:
    """Whether cluster ``j`` lies within the reach of a query cluster (box ``lo_a``, ``hi_a``,
    largest query radius ``r_a``, mean velocity ``u_a``, spread ``s_a``; ``cluster_masks_kernel``)."""
    r = reach_radius(r_a, relative, margin, speed_factor, h,
                     wp.length(u_a - load_vec3(cl.cluster_vel, j)) + s_a + cl.cluster_spread[j])
    return boxes_meet(lo_a - wp.vec3(r), hi_a + wp.vec3(r), load_vec3(cl.cluster_lo, j),
                      load_vec3(cl.cluster_hi, j))


@wp.kernel
def cluster_masks_kernel(cl: ClusterArrays, relative: int, margin: float, speed_factor: float, h: float,
                         parts: int):
    """One thread per (query, query cluster, word) over the three queries (``QUERIES``; query
    ``q``'s words in ``masks`` start at ``mask_first[q]``, a query cluster's ``words[q]`` of them
    in a row): bit ``b`` of the word is set when target cluster ``32 word + b`` of the query
    cluster's instance lies within the query cluster's reach of its box: its largest query
    radius, or with ``relative`` (the pair lists keep only pairs within the radius of their own
    relative speed) the radius of the largest
    relative speed two members can have: the clusters' mean velocities apart plus both spreads
    (``reach_radius``).

    With ``parts`` (1, 2 or 4; more than 1 on CUDA only, ``ClusterLayout.lanes``) each word has
    that many neighbouring threads, each testing ``32 / parts`` of its targets, whose bits are
    joined by lane shuffles: a shorter chain of loads per thread."""
    t_all = wp.tid()
    t = t_all / parts
    part = t_all - t * parts
    q = int(0)
    if t >= cl.mask_first[1]:
        q = 1
    if t >= cl.mask_first[2]:
        q = 2
    w_count = cl.words[q]
    local = t - cl.mask_first[q]
    # the query clusters fastest: a warp's threads (or with ``parts``, its threads of the same
    # part) test the same targets (one load for all)
    n_query = (cl.mask_first[q + 1] - cl.mask_first[q]) / w_count
    w = local / n_query
    a_local = local - w * n_query
    tk = cl.target_first[q]
    a = cl.kind_clusters[q] + a_local
    g = cl.cluster_group[a]
    kind = cl.target_kind[q]
    t0 = cl.group_first[kind * (cl.groups + 1) + g]
    t1 = cl.group_first[kind * (cl.groups + 1) + g + 1]
    lo_a = load_vec3(cl.cluster_lo, a)
    hi_a = load_vec3(cl.cluster_hi, a)
    r_a = cl.cluster_radius[a]
    u_a = load_vec3(cl.cluster_vel, a)
    s_a = cl.cluster_spread[a]
    bits = int(0)
    rounds = WORD / 8 / parts
    for r in range(rounds):
        # eight targets at a time (a loop of constant length is unrolled); only the instance's
        # own: ``words`` fits the instance with the most clusters, and a smaller instance's
        # last word would reach past the arrays' end
        b0 = part * rounds + r
        for b1 in range(8):
            b = 8 * b0 + b1
            j = tk + t0 + w * WORD + b
            if j - tk < t1:
                if cluster_meets(lo_a, hi_a, r_a, u_a, s_a, j, cl, relative, margin, speed_factor, h):
                    bits = bits | (1 << b)
    if parts > 1:
        mask = lane_mask(t_all, parts * cl.mask_first[3])
        m = int(1)
        while m < parts:
            bits = bits | lane_xor_int(bits, m, mask)
            m = 2 * m
    if part == 0:
        cl.masks[cl.mask_first[q] + a_local * w_count + w] = bits


def topology_keys(particle_group: np.ndarray, tris: np.ndarray, tri_group: np.ndarray, n_groups: int) -> list:
    """A key per group (instance) that is equal for groups with the same triangles in local
    vertex numbering, so that ``cluster_layout`` cuts a batch of one garment once; None for a
    group whose vertices are not one contiguous range (cut on its own)."""
    pg = np.asarray(particle_group, dtype=np.int64)
    count = np.bincount(pg, minlength=n_groups)
    first = np.full(n_groups, len(pg), np.int64)
    last = np.full(n_groups, -1, np.int64)
    np.minimum.at(first, pg, np.arange(len(pg)))
    np.maximum.at(last, pg, np.arange(len(pg)))
    tg = np.asarray(tri_group, dtype=np.int64)
    order = np.argsort(tg, kind="stable")
    ends = np.cumsum(np.bincount(tg, minlength=n_groups))
    keys = []
    for g in range(n_groups):
        if last[g] - first[g] + 1 != count[g]:
            keys.append(None)
            continue
        ids = order[ends[g] - (ends[g] - (ends[g - 1] if g else 0)):ends[g]]
        keys.append((int(count[g]), (np.asarray(tris)[ids] - first[g]).astype(np.int64).tobytes()))
    return keys


class ClusterLayout:
    """The clusters of a cloth model and their per-detection buffers (see the module docstring).

    Args:
        model: the cloth model (``particle_q`` gives the positions the clusters are cut from).
        size: primitives per cluster (``CLUSTER_SIZES``; 32: one warp per query cluster on CUDA).
        lanes: whether the octet and cluster data come from lane shuffles in the slots' launch
            (``lanes``: CUDA and a size of ``LANE_SIZES`` only); None: wherever they can.
    """

    def __init__(self, model, size: int = 32, lanes: bool | None = None):
        w = wp
        d = model.device
        if size not in CLUSTER_SIZES:
            raise ValueError(f"ClusterLayout: size must be one of {CLUSTER_SIZES}, got {size}")
        self.size = int(size)
        can = w.get_device(d).is_cuda and self.size in LANE_SIZES
        if lanes and not can:
            raise ValueError(f"ClusterLayout: lanes need CUDA and a size of {LANE_SIZES}, got {d} and {size}")
        self.lanes = can if lanes is None else bool(lanes)
        # threads per mask word with lanes (``cluster_masks_kernel``)
        self.mask_parts = MASK_PARTS
        x = model.particle_q.numpy().astype(np.float64)
        tris = model.tri_indices.numpy()
        edges = model.mesh_edge_indices.numpy()
        n_groups = int(model.instance_count)
        points = (x, x[tris].mean(axis=1) if len(tris) else np.zeros((0, 3)),
                  x[edges].mean(axis=1) if len(edges) else np.zeros((0, 3)))
        groups = (model.particle_instance.numpy(), model.tri_instance.numpy(),
                  model.mesh_edge_instance.numpy())
        neighbours = (edges, shared_vertex_pairs(tris), shared_vertex_pairs(edges))
        keys = topology_keys(groups[0], tris, groups[1], n_groups)
        orders, cluster_groups, firsts = [], [], []
        for p, g, nb in zip(points, groups, neighbours, strict=True):
            o, cg, f = cluster_layout(p, g, n_groups, self.size, nb, keys.__getitem__)
            orders.append(o)
            cluster_groups.append(cg)
            firsts.append(f)
        counts = [len(cg) for cg in cluster_groups]
        self.kind_clusters = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        self.total_clusters = total = int(self.kind_clusters[-1])
        # words per query cluster: the most target clusters any instance has, in words of 32
        self.words = [max(1, -(-int(np.diff(firsts[tk]).max(initial=0)) // WORD)) for _, tk in QUERIES]
        masks = [counts[qk] * wc for (qk, _), wc in zip(QUERIES, self.words, strict=True)]
        self.mask_first = np.concatenate([[0], np.cumsum(masks)]).astype(np.int32)
        self.device = d
        self.masks_current = False
        slots = max(total * self.size, 1)
        octets = total * (self.size // 8)

        def zeros(n: int, dtype):
            return w.zeros(n, dtype=dtype, device=d)

        cl = ClusterArrays()
        cl.size = self.size
        cl.groups = n_groups
        cl.kind_clusters = w.vec4i(*(int(k) for k in self.kind_clusters))
        cl.target_first = w.vec3i(*(int(self.kind_clusters[tk]) for _, tk in QUERIES))
        cl.target_kind = w.vec3i(*(tk for _, tk in QUERIES))
        cl.words = w.vec3i(*self.words)
        cl.mask_first = w.vec4i(*(int(t) for t in self.mask_first))
        cl.order = w.array(np.concatenate(orders), dtype=w.int32, device=d)
        cl.group_first = w.array(np.concatenate(firsts), dtype=w.int32, device=d)
        cl.cluster_group = w.array(np.concatenate(cluster_groups), dtype=w.int32, device=d)
        cl.masks = zeros(max(int(self.mask_first[-1]), 1), w.int32)
        # per slot (``member_bounds_kernel``): box, query radius, mean corner velocity, spread
        cl.lo, cl.hi, cl.vel = (zeros(slots, w.vec3) for _ in range(3))
        cl.radius, cl.spread = (zeros(slots, float) for _ in range(2))
        # per octet, and eight empty ones past the end (a cluster's octets are read eight at a
        # time; the bits of those past its own are masked off)
        cl.octet_lo = w.full(octets + 8, w.vec3(EMPTY), dtype=w.vec3, device=d)
        cl.octet_hi = w.full(octets + 8, w.vec3(-EMPTY), dtype=w.vec3, device=d)
        cl.octet_vel = zeros(octets + 8, w.vec3)
        cl.octet_radius, cl.octet_count, cl.octet_spread = (zeros(octets + 8, float) for _ in range(3))
        # per cluster
        cl.cluster_lo, cl.cluster_hi, cl.cluster_vel = (zeros(max(total, 1), w.vec3) for _ in range(3))
        cl.cluster_radius, cl.cluster_spread = (zeros(max(total, 1), float) for _ in range(2))
        self.arrays = cl

    @property
    def slots(self) -> int:
        return self.total_clusters * self.size

    def update(self, relative: bool, margin: float, speed_factor: float, h: float) -> None:
        """Octet and cluster data and the masks, from the slots' (``lo``, ``hi``, ``radius``,
        ``vel``, ``spread``, filled by the caller; with ``lanes`` the caller's launch filled the
        octets and clusters too); ``relative``: masks by the reach of relative speeds
        (``cluster_masks_kernel``), with the detection's ``margin``, ``speed_factor`` and
        substep ``h``."""
        if self.total_clusters == 0:
            return
        d = self.device
        if not self.lanes:
            octets = self.total_clusters * (self.size // 8)
            wp.launch(octet_bounds_kernel, dim=octets, inputs=[self.arrays], device=d)
            wp.launch(cluster_bounds_kernel, dim=self.total_clusters, inputs=[self.arrays], device=d)
        n = int(self.mask_first[-1])
        self.masks_current = True
        if n:
            parts = self.mask_parts if self.lanes else 1
            wp.launch(cluster_masks_kernel, dim=n * parts,
                      inputs=[self.arrays, int(relative), float(margin), float(speed_factor), float(h),
                              parts],
                      device=d)

    def marked(self) -> list[float] | None:
        """Mean target clusters marked per query cluster, per query (``QUERIES``): how many
        clusters a query thread searches (diagnostics); None before the first detection."""
        if not self.masks_current:
            return None
        m = self.arrays.masks.numpy().view(np.uint32)
        bits = np.unpackbits(m.view(np.uint8)).reshape(-1, 32).sum(axis=1) if len(m) else np.zeros(0)
        out = []
        for q, (qk, _) in enumerate(QUERIES):
            n = int(self.kind_clusters[qk + 1] - self.kind_clusters[qk])
            a = int(self.mask_first[q])
            out.append(float(bits[a:a + n * self.words[q]].sum() / max(n, 1)))
        return out
