"""Cloth self-contact for the VBD solver: vertex-triangle and edge-edge proximity, penalty
energies, and per-vertex displacement bounds that keep the cloth intersection-free.

Method (after Chen et al. 2024, "Vertex Block Descent", Sec. 4, and the conservative bounds
of Chen et al. 2025, "Offset Geometric Contact"):

* Detection, once per substep at the substep-start positions ``x0`` (intersection-free):
  three grouped BVHs (one group per cloth instance, so batched instances never collide) over
  triangle and edge bounding boxes and over the vertices (points): vertices query triangles,
  triangles query vertices, edges query edges. For every vertex, every triangle and every edge a query
  with radius ``r = max(margin, speed_factor |v - v_ref| h)`` finds the nearest non-incident
  primitive distance ``d_min`` and records the pairs whose own relative motion can bring them
  within the contact radius ``r_c`` during the substep's iterations: closer than ``max(margin,
  speed_factor |v_a - v_b| h)`` with ``v_a - v_b`` the relative velocity of the closest points
  (``relative_lists``; off: every pair within ``r``). ``v_ref`` is the instance's reference
  velocity (``ClothControl.instance_velocity``; ``sim.simulate``: its body's mean velocity):
  contact depends on relative motion only, so the search runs in the frame moving with it. A
  run carries the whole t-shirt forward at 3.5 m/s, which made the absolute radius 14 mm for
  the median vertex against 4 mm in the body's frame (session 13). The query radius must
  cover a vertex's speed in that frame (the bounds), but cloth riding on a running limb moves with its surface
  neighbours: storing every neighbour 1-2 edge lengths away filled 88 % of the edges' lists on
  the t-shirt run with pairs that never act, and the solve evaluated them every iteration:
  per vertex its triangles (VT), per triangle its vertices (TV, the same pairs seen from the
  triangle), per edge its edges (EE). Gathering from both sides makes the solve a per-vertex gather without
  atomics (deterministic on every device).
* Energy of a pair at distance ``d`` (closest points recomputed from the current positions
  each iteration): ``k/2 (r_c - d)^2`` for ``d < r_c``, with lazy IPC friction on the relative
  tangential displacement over the substep.
* Side memory (``side_memory``, off by default): every stored pair carries the separation
  vector it had when first found, updated at each detection while the pair stays on the same
  side (``diff . ref >= 0``) and kept when it flipped. A pair that a stronger force (body
  contact, a fast fold) pushed through is therefore pushed back at later substeps instead of
  being held in the crossed state, which is what a side taken from each substep's start would
  do: without it a crossing, once made, persists to the end of the sequence. Off, each pair's
  side is its separation at the detection (the substep start). Measured on the t-shirt
  (session 10): it clears the run's persistent sleeve crossing (3/3 runs pass, 0/3 without)
  but the walk then fails more often (crossings in 5 of 6 runs): a pair whose closest-point
  direction turns by more than 90 degrees between detections without crossing (around a
  boundary edge, or an edge sliding past an edge's end) is taken for a crossing and pushed
  back.
* Bound: vertex ``i`` may move at most ``b_i = gamma min(d_min(i), d_min(incident triangles),
  d_min(incident edges))`` from ``x0`` during the substep, ``gamma < 1/2``. Two primitives at
  distance ``d`` then move together by at most ``2 gamma d < d``: no vertex crosses a
  triangle and no edge crosses an edge, provided the substep started intersection-free.
  The query radius grows with a vertex's speed, so fast cloth with space around it is not
  held back.
"""

from __future__ import annotations

import numpy as np
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
from sim.cloth.spans import (
    Span,
    fill_spans,
    floats,
    ints,
    load_int,
    load_vec2i,
    load_vec3,
    load_vec3i,
    load_vec4i,
    vec2is,
    vec3s,
    vec4is,
)
from sim.device import SideStreams, warp

# closest points with every barycentric weight (VT) or edge parameter (EE) above this are
# interior: only there is a reversed separation a crossing (``track_side``)
INTERIOR = wp.constant(1.0e-3)


# cluster slots up to which ``SelfContact(cluster_split=0)`` splits the cluster query (one
# garment of up to ~20k vertices; a batch of them fills the GPU without)
SPLIT_SLOTS = 131072

# a candidate query's sweep [substeps] (``SelfContactData.candidates``): the next substep's
# start, reached at the velocities this one starts with, with half again for acceleration
LOOKAHEAD_SWEEP = 1.5


@wp.struct
class SelfContactData:
    """Self-contact buffers and settings passed to the solve kernel as one argument.

    ``enabled`` 0 turns everything off (the arrays may then be empty). ``heavy`` (per particle),
    ``heavy_list`` (per colour slot) and ``heavy_count`` (per colour): the vertices with more
    than ``heavy_threshold`` gather records, which the solve gives a whole thread block each
    when their colour has at most ``heavy_cap`` of them (``vertex_summary_kernel``; cap 0:
    off). ``particle_color`` / ``color_start``: each particle's colour, each colour's first
    slot in the model's ``color_vertices``."""

    enabled: int
    use_bounds: int
    side_memory: int
    relative_lists: int
    ee_interior: int
    candidates: float
    radius: float
    stiffness: float
    friction: float
    weight_floor: float
    vt_capacity: int
    tv_capacity: int
    ee_capacity: int
    vt_count: wp.array(dtype=wp.int32)
    vt_tri: wp.array(dtype=wp.int32)
    tv_count: wp.array(dtype=wp.int32)
    tv_vertex: wp.array(dtype=wp.int32)
    ee_count: wp.array(dtype=wp.int32)
    ee_edge: wp.array(dtype=wp.int32)
    vt_dist: wp.array(dtype=float)
    tv_dist: wp.array(dtype=float)
    ee_dist: wp.array(dtype=float)
    vt_ref: wp.array(dtype=wp.vec3)
    tv_ref: wp.array(dtype=wp.vec3)
    ee_ref: wp.array(dtype=wp.vec3)
    vt_rk: wp.array(dtype=wp.int32)
    tv_rk: wp.array(dtype=wp.int32)
    ee_rk: wp.array(dtype=wp.int32)
    vt_count_prev: wp.array(dtype=wp.int32)
    vt_tri_prev: wp.array(dtype=wp.int32)
    vt_ref_prev: wp.array(dtype=wp.vec3)
    tv_count_prev: wp.array(dtype=wp.int32)
    tv_vertex_prev: wp.array(dtype=wp.int32)
    tv_ref_prev: wp.array(dtype=wp.vec3)
    ee_count_prev: wp.array(dtype=wp.int32)
    ee_edge_prev: wp.array(dtype=wp.int32)
    ee_ref_prev: wp.array(dtype=wp.vec3)
    tv_total: wp.array(dtype=wp.int32)
    ee_total: wp.array(dtype=wp.int32)
    tv_first: wp.array(dtype=wp.int32)
    ee_first: wp.array(dtype=wp.int32)
    pair_first: wp.array(dtype=wp.int32)
    pair_count: wp.array(dtype=wp.int32)
    pair_verts: wp.array(dtype=wp.vec4i)
    pair_role: wp.array(dtype=wp.int32)
    pair_ref: wp.array(dtype=wp.vec3)
    pair_cursor: wp.array(dtype=wp.int32)
    pool_size: int
    heavy: wp.array(dtype=wp.int32)
    heavy_list: wp.array(dtype=wp.int32)
    heavy_count: wp.array(dtype=wp.int32)
    heavy_threshold: int
    heavy_cap: int
    particle_color: wp.array(dtype=wp.int32)
    color_start: wp.array(dtype=wp.int32)
    mesh_edges: wp.array(dtype=wp.vec2i)
    vertex_edge_offsets: wp.array(dtype=wp.int32)
    vertex_edge_ids: wp.array(dtype=wp.int32)
    vertex_edge_local: wp.array(dtype=wp.int32)
    bound: wp.array(dtype=float)
    rest: wp.array(dtype=wp.vec3)
    component: wp.array(dtype=wp.int32)
    exclusion: float
    ring_exclusion: int
    coarse_exclusion: float
    coarse_pairs: wp.array(dtype=wp.int32)
    reference: wp.array(dtype=wp.vec3)



@wp.struct
class SolveContactArrays:
    """The part of ``SelfContactData`` the solve kernel reads, its arrays as ``Span``s
    (``sim.cloth.spans``: a struct of 55 array descriptors as a kernel argument filled the
    constant cache). Built by ``solve_contact_arrays``; the kernel rebuilds a ``SelfContactData``
    with these fields set (``contact_view``; the others are empty)."""

    enabled: int
    use_bounds: int
    radius: float
    stiffness: float
    friction: float
    vt_capacity: int
    tv_capacity: int
    ee_capacity: int
    heavy_cap: int
    weight_floor: float
    pair_first: Span
    pair_count: Span
    pair_verts: Span
    pair_role: Span
    pair_ref: Span
    heavy: Span
    heavy_list: Span
    heavy_count: Span
    bound: Span
    reference: Span
    vt_count: Span
    vt_tri: Span
    vt_ref: Span
    tv_total: Span
    tv_first: Span
    tv_vertex: Span
    tv_ref: Span
    ee_total: Span
    ee_first: Span
    ee_edge: Span
    ee_ref: Span
    vt_rk: Span
    tv_rk: Span
    ee_rk: Span
    mesh_edges: Span
    particle_color: Span
    vertex_edge_offsets: Span
    vertex_edge_ids: Span
    vertex_edge_local: Span


SOLVE_CONTACT_SCALARS = (
    "enabled", "use_bounds", "radius", "stiffness", "friction", "vt_capacity", "tv_capacity",
    "ee_capacity", "heavy_cap", "weight_floor"
)
SOLVE_CONTACT_ARRAYS = (
    "pair_first", "pair_count", "pair_verts", "pair_role", "pair_ref", "heavy", "heavy_list",
    "heavy_count", "bound", "reference", "vt_count", "vt_tri", "vt_ref", "tv_total", "tv_first",
    "tv_vertex", "tv_ref", "ee_total", "ee_first", "ee_edge", "ee_ref", "vt_rk", "tv_rk", "ee_rk",
    "mesh_edges", "particle_color",
    "vertex_edge_offsets", "vertex_edge_ids", "vertex_edge_local"
)


def solve_contact_key(sc: SelfContactData) -> tuple:
    """What ``solve_contact_arrays(sc)`` depends on: the scalars and the array addresses."""
    return (tuple(getattr(sc, n) for n in SOLVE_CONTACT_SCALARS)
            + tuple(getattr(sc, n).ptr for n in SOLVE_CONTACT_ARRAYS))


def solve_contact_arrays(sc: SelfContactData) -> SolveContactArrays:
    """The ``SolveContactArrays`` of ``sc`` (its arrays must stay alive while it is used)."""
    a = SolveContactArrays()
    for n in SOLVE_CONTACT_SCALARS:
        setattr(a, n, getattr(sc, n))
    fill_spans(a, {n: getattr(sc, n) for n in SOLVE_CONTACT_ARRAYS})
    return a


@wp.func
def contact_view(a: SolveContactArrays) -> SelfContactData:
    """The ``SelfContactData`` the solve's functions take, rebuilt from ``a`` inside a kernel."""
    sc = SelfContactData()
    sc.enabled = a.enabled
    sc.use_bounds = a.use_bounds
    sc.radius = a.radius
    sc.stiffness = a.stiffness
    sc.friction = a.friction
    sc.vt_capacity = a.vt_capacity
    sc.tv_capacity = a.tv_capacity
    sc.ee_capacity = a.ee_capacity
    sc.heavy_cap = a.heavy_cap
    sc.weight_floor = a.weight_floor
    sc.pair_first = ints(a.pair_first)
    sc.pair_count = ints(a.pair_count)
    sc.pair_verts = vec4is(a.pair_verts)
    sc.pair_role = ints(a.pair_role)
    sc.pair_ref = vec3s(a.pair_ref)
    sc.heavy = ints(a.heavy)
    sc.heavy_list = ints(a.heavy_list)
    sc.heavy_count = ints(a.heavy_count)
    sc.bound = floats(a.bound)
    sc.reference = vec3s(a.reference)
    sc.vt_count = ints(a.vt_count)
    sc.vt_tri = ints(a.vt_tri)
    sc.vt_ref = vec3s(a.vt_ref)
    sc.tv_total = ints(a.tv_total)
    sc.tv_first = ints(a.tv_first)
    sc.tv_vertex = ints(a.tv_vertex)
    sc.tv_ref = vec3s(a.tv_ref)
    sc.ee_total = ints(a.ee_total)
    sc.ee_first = ints(a.ee_first)
    sc.ee_edge = ints(a.ee_edge)
    sc.ee_ref = vec3s(a.ee_ref)
    sc.vt_rk = ints(a.vt_rk)
    sc.tv_rk = ints(a.tv_rk)
    sc.ee_rk = ints(a.ee_rk)
    sc.mesh_edges = vec2is(a.mesh_edges)
    sc.particle_color = ints(a.particle_color)
    sc.vertex_edge_offsets = ints(a.vertex_edge_offsets)
    sc.vertex_edge_ids = ints(a.vertex_edge_ids)
    sc.vertex_edge_local = ints(a.vertex_edge_local)
    return sc


@wp.func
def has_pairs(sc: SelfContactData, i: int) -> bool:
    """Whether particle ``i`` takes part in a stored self-contact pair (VT, TV or EE) that holds
    back the coarse correction (``coarse_pairs``, ``vertex_summary_kernel``: one at least
    ``coarse_exclusion`` apart at rest); the pair arrays are read only when self-contact is on.
    Not on a ``contact_view`` (the solve's part of the data has no ``coarse_pairs``)."""
    if sc.enabled != 0:
        return sc.coarse_pairs[i] > 0
    return False


@wp.func
def triangle_closest_bary(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec3:
    """Barycentric weights (of a, b, c) of the point of triangle abc closest to ``p``
    (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        return wp.vec3(1.0, 0.0, 0.0)
    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    if d3 >= 0.0 and d4 <= d3:
        return wp.vec3(0.0, 1.0, 0.0)
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return wp.vec3(1.0 - v, v, 0.0)
    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    if d6 >= 0.0 and d5 <= d6:
        return wp.vec3(0.0, 0.0, 1.0)
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return wp.vec3(1.0 - w, 0.0, w)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return wp.vec3(0.0, 1.0 - w, w)
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    return wp.vec3(1.0 - v - w, v, w)


@wp.func
def pair_force_hessian(diff: wp.vec3, diff0: wp.vec3, rel_disp: wp.vec3, w: float, radius: float, k: float,
                       mu: float, eps_u: float, w_floor: float):
    """Force on and Hessian block of a vertex taking part with signed weight ``w`` in a contact
    pair whose closest points differ by ``diff = p_a - p_b`` now; ``diff0`` is the pair's
    tracked side (``track_side``: the separation when it was found, followed while it stays
    on that side) (``w > 0`` on side a, ``< 0`` on side b). Energy ``k/2 (radius - d)^2`` for
    ``d < radius``, with ``d`` the distance signed by that side: a pair that crossed (``diff .
    diff0 < 0``), in this substep or an earlier one while it stayed in the lists, is pushed
    back, not further through.
    Friction opposes the tangential part of the pair's relative displacement ``rel_disp`` over
    the substep (lazy IPC friction, smoothed below ``eps_u``).

    The Hessian takes ``|w| max(|w|, w_floor)`` for the exact ``w^2``: a vertex taking part
    with a small weight (an edge end far from the closest point, a triangle corner far from the
    point) would otherwise, in its own Newton step, move ``(radius - d) / w`` to clear the
    whole penetration alone, and a light rim vertex left a fresh contact at 12 m/s (session 17:
    a hairpin thrown onto itself at 1.1 m/s gained 10x its energy). With the floor no single
    pair's step exceeds ``(radius - d) / w_floor`` (``w_floor`` 0.5: twice the penetration),
    and a vertex with weight 0 still gets nothing. The force, so the converged state, is
    unchanged: a larger Hessian only shortens the step."""
    f = wp.vec3(0.0)
    H = wp.mat33(0.0)
    d = wp.length(diff)
    n = wp.vec3(0.0)
    if d > 1.0e-9:
        n = diff / d
    else:
        l0 = wp.length(diff0)
        if l0 < 1.0e-9:
            return f, H
        n = diff0 / l0
    if wp.dot(diff, diff0) < 0.0:
        n = -n
        d = -d
    if d >= radius:
        return f, H
    lam = k * (radius - d)
    f = (w * lam) * n
    ww = wp.abs(w) * wp.max(wp.abs(w), w_floor)
    H = (ww * k) * wp.outer(n, n)
    if mu > 0.0:
        T = wp.identity(n=3, dtype=float) - wp.outer(n, n)
        u = T * rel_disp
        ul = wp.length(u)
        c = 1.0 / wp.max(ul, 1.0e-12)
        if ul < eps_u:
            c = 2.0 / eps_u - ul / (eps_u * eps_u)
        f = f - (w * mu * lam * c) * u
        H = H + (ww * mu * lam * c) * T
    return f, H


@wp.func
def point_triangle_pair_values(xu: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3, xu0: wp.vec3, a0: wp.vec3,
                               b0: wp.vec3, c0: wp.vec3, ref: wp.vec3, role: int, radius: float,
                               sc: SelfContactData, eps_u: float):
    """Force and Hessian block of the vertex with ``role`` in the pair of point ``xu`` and
    triangle ``abc`` (``..0``: their substep-start positions): role 0 the point, role 1-3 the
    triangle's corner ``role - 1``; ``ref`` the pair's side reference, ``radius`` its contact
    distance (``pair_radius``)."""
    w = triangle_closest_bary(xu, a, b, c)
    p = w[0] * a + w[1] * b + w[2] * c
    p0 = w[0] * a0 + w[1] * b0 + w[2] * c0
    wi = 1.0
    if role > 0:
        wi = -w[role - 1]
    return pair_force_hessian(xu - p, ref, (xu - xu0) - (p - p0), wi, radius, sc.stiffness, sc.friction,
                              eps_u, sc.weight_floor)


@wp.func
def edge_edge_pair_values(p1: wp.vec3, q1: wp.vec3, p2: wp.vec3, q2: wp.vec3, p10: wp.vec3, q10: wp.vec3,
                          p20: wp.vec3, q20: wp.vec3, ref: wp.vec3, end: int, radius: float,
                          sc: SelfContactData, eps_u: float):
    """Force and Hessian block of end ``end`` (0, 1) of edge ``p1 q1`` in its pair with edge
    ``p2 q2`` (``..0``: their substep-start positions); ``ref`` the pair's side reference,
    ``radius`` its contact distance (``pair_radius``)."""
    st = wp.closest_point_edge_edge(p1, q1, p2, q2, 1.0e-12)
    pa = p1 + st[0] * (q1 - p1)
    pb = p2 + st[1] * (q2 - p2)
    pa0 = (1.0 - st[0]) * p10 + st[0] * q10
    pb0 = (1.0 - st[1]) * p20 + st[1] * q20
    we = 1.0 - st[0]
    if end == 1:
        we = st[0]
    return pair_force_hessian(pa - pb, ref, (pa - pa0) - (pb - pb0), we, radius, sc.stiffness, sc.friction,
                              eps_u, sc.weight_floor)


RADIUS_CODES = 255


@wp.func
def reduced_radius_code(rest_distance: float, radius: float) -> int:
    """Bits 8-15 of the ``pair_role`` of a pair of one piece of cloth that was ``rest_distance``
    < ``radius`` apart in the rest shape (not incident: a crease folded at rest, panels meeting
    at a seam): ``k`` in 1..255 with ``pair_radius = radius (1 - k / 255)`` at most half the
    rest distance, so the pair exerts nothing at rest and stops the two from passing through
    each other. 0 (every other pair): the full ``radius``."""
    k = int(wp.ceil(float(RADIUS_CODES) * (1.0 - 0.5 * rest_distance / radius)))
    return wp.clamp(k, 1, RADIUS_CODES)


@wp.func
def pair_radius(radius: float, packed: int) -> float:
    """The contact distance of a pair whose ``pair_role`` is ``packed`` (``reduced_radius_code``
    in bits 8-15)."""
    return radius * (1.0 - float((packed >> 8) & 255) / float(RADIUS_CODES))


@wp.func
def record_force_hessian(y0: wp.vec3, y1: wp.vec3, y2: wp.vec3, y3: wp.vec3, z0: wp.vec3, z1: wp.vec3,
                         z2: wp.vec3, z3: wp.vec3, ref: wp.vec3, packed: int, sc: SelfContactData,
                         eps_u: float):
    """Force and Hessian block of a gather record's vertex: the record's four vertices at ``y``
    (now) and ``z`` (substep start); ``packed`` its ``pair_role``: role (bits 0-3) 0-3 a
    point-triangle pair (point, corners), 4-5 an end of the first edge of an edge-edge pair;
    the pair's radius code in bits 8-15 (``pair_radius``)."""
    role = packed & 15
    radius = pair_radius(sc.radius, packed)
    if role < 4:
        return point_triangle_pair_values(y0, y1, y2, y3, z0, z1, z2, z3, ref, role, radius, sc, eps_u)
    return edge_edge_pair_values(y0, y1, y2, y3, z0, z1, z2, z3, ref, role - 4, radius, sc, eps_u)


@wp.func
def read_position(x: wp.array(dtype=wp.vec3), snap: wp.array(dtype=wp.vec3), j: int, same: int) -> wp.vec3:
    """Vertex ``j``'s position as the solve of a colour sees it: from ``snap`` (the sweep-start
    positions) where ``same`` is set (``j`` has the solved vertex's colour, so its own thread may
    be writing ``x[j]`` in this launch), else the current ``x`` (Gauss-Seidel)."""
    if same != 0:
        return load_vec3(snap, j)
    return load_vec3(x, j)


@wp.func
def read_positions(x: wp.array(dtype=wp.vec3), snap: wp.array(dtype=wp.vec3), q: wp.vec4i, same: int):
    """``read_position`` of the four vertices ``q``, vertex ``q[k]`` from ``snap`` where bit ``k``
    of ``same`` is set."""
    return (read_position(x, snap, q[0], same & 1), read_position(x, snap, q[1], same & 2),
            read_position(x, snap, q[2], same & 4), read_position(x, snap, q[3], same & 8))


@wp.func
def read_triangle(x: wp.array(dtype=wp.vec3), snap: wp.array(dtype=wp.vec3), tri: wp.vec3i, same: int):
    """``read_position`` of a triangle's three corners, corner ``k`` from ``snap`` where bit ``k``
    of ``same`` is set (``model.local_packed``)."""
    return (read_position(x, snap, tri[0], same & 1), read_position(x, snap, tri[1], same & 2),
            read_position(x, snap, tri[2], same & 4))


@wp.func
def same_color_mask(color: wp.array(dtype=wp.int32), c: int, q: wp.vec4i) -> int:
    """Bit ``k`` set where vertex ``q[k]`` has colour ``c``."""
    mask = int(0)
    for k in range(4):
        if color[q[k]] == c:
            mask = mask | (1 << k)
    return mask


@wp.func
def packed_role(role: int, color: wp.array(dtype=wp.int32), c: int, q: wp.vec4i) -> int:
    """A record's ``pair_role``: ``role`` (0-5) in bits 0-3, ``same_color_mask`` of its vertices
    ``q`` against colour ``c`` (the owner's) in bits 4-7."""
    return role | (same_color_mask(color, c, q) << 4)


@wp.func
def record_force_hessian_at(x: wp.array(dtype=wp.vec3), snap: wp.array(dtype=wp.vec3),
                            x0: wp.array(dtype=wp.vec3), q: wp.vec4i, ref: wp.vec3, role: int,
                            sc: SelfContactData, eps_u: float):
    """``record_force_hessian`` of the pair of vertices ``q`` (a record, or a pair from the lists
    laid out as one); ``role`` packed as in ``pair_role`` (the role in bits 0-3, the
    same-colour mask in bits 4-7: those vertices are read from ``snap``, ``read_position``; the
    radius code above)."""
    y0, y1, y2, y3 = read_positions(x, snap, q, (role >> 4) & 15)
    return record_force_hessian(y0, y1, y2, y3, load_vec3(x0, q[0]), load_vec3(x0, q[1]), load_vec3(x0, q[2]),
                                load_vec3(x0, q[3]), ref, role, sc, eps_u)


@wp.func
def self_contact_list_force_hessian(
    i: int,
    lane: int,
    stride: int,
    x: wp.array(dtype=wp.vec3),
    snap: wp.array(dtype=wp.vec3),
    x0: wp.array(dtype=wp.vec3),
    tri_indices: wp.array(dtype=wp.vec3i),
    vertex_tri_offsets: wp.array(dtype=wp.int32),
    vertex_tri_ids: wp.array(dtype=wp.int32),
    vertex_tri_local: wp.array(dtype=wp.int32),
    sc: SelfContactData,
    eps_u: float,
):
    """``self_contact_force_hessian`` of a vertex without gather records, from the pair lists
    themselves: the same pairs in the same order per kind (lanes split each list), but each
    pair a chain of dependent loads (list count, the owning triangle or edge, its indices, the
    partner's indices) in three loops one after the other (session 12: 24 us per solve launch
    against 10 us without self-contact)."""
    f = wp.vec3(0.0)
    H = wp.mat33(0.0)
    c = sc.particle_color[i]
    # i as the point of vertex-triangle pairs
    for s in range(lane, sc.vt_count[i], stride):
        tri = tri_indices[sc.vt_tri[i * sc.vt_capacity + s]]
        ref = sc.vt_ref[i * sc.vt_capacity + s]
        q = wp.vec4i(i, tri[0], tri[1], tri[2])
        role = packed_role(0, sc.particle_color, c, q) | (sc.vt_rk[i * sc.vt_capacity + s] << 8)
        fc, hc = record_force_hessian_at(x, snap, x0, q, ref, role, sc, eps_u)
        f = f + fc
        H = H + hc
    # i as a corner of triangles that vertices are close to: the lanes split the flattened list
    # of stored pairs of i's triangles (``tv_first``: each triangle's first pair in it)
    cap = sc.tv_capacity
    tri_end = vertex_tri_offsets[i + 1]
    for j in range(lane, sc.tv_total[i], stride):
        kk = vertex_tri_offsets[i]
        while kk + 1 < tri_end and sc.tv_first[kk + 1] <= j:
            kk += 1
        t = vertex_tri_ids[kk]
        s = j - sc.tv_first[kk]
        tri = tri_indices[t]
        q = wp.vec4i(sc.tv_vertex[t * cap + s], tri[0], tri[1], tri[2])
        role = (packed_role(1 + (vertex_tri_local[kk] & 3), sc.particle_color, c, q)
                | (sc.tv_rk[t * cap + s] << 8))
        fc, hc = record_force_hessian_at(x, snap, x0, q, sc.tv_ref[t * cap + s], role, sc, eps_u)
        f = f + fc
        H = H + hc
    # i as an end of edges close to other edges (lanes split the flattened stored pairs alike)
    ecap = sc.ee_capacity
    edge_end = sc.vertex_edge_offsets[i + 1]
    for j in range(lane, sc.ee_total[i], stride):
        kk = sc.vertex_edge_offsets[i]
        while kk + 1 < edge_end and sc.ee_first[kk + 1] <= j:
            kk += 1
        e = sc.vertex_edge_ids[kk]
        s = j - sc.ee_first[kk]
        ea = sc.mesh_edges[e]
        eb = sc.mesh_edges[sc.ee_edge[e * ecap + s]]
        q = wp.vec4i(ea[0], ea[1], eb[0], eb[1])
        role = (packed_role(4 + sc.vertex_edge_local[kk], sc.particle_color, c, q)
                | (sc.ee_rk[e * ecap + s] << 8))
        fc, hc = record_force_hessian_at(x, snap, x0, q, sc.ee_ref[e * ecap + s], role, sc, eps_u)
        f = f + fc
        H = H + hc
    return f, H


@wp.func
def self_contact_force_hessian(
    i: int,
    lane: int,
    stride: int,
    x: wp.array(dtype=wp.vec3),
    snap: wp.array(dtype=wp.vec3),
    x0: wp.array(dtype=wp.vec3),
    tri_indices: wp.array(dtype=wp.vec3i),
    vertex_tri_offsets: wp.array(dtype=wp.int32),
    vertex_tri_ids: wp.array(dtype=wp.int32),
    vertex_tri_local: wp.array(dtype=wp.int32),
    sc: SelfContactData,
    eps_u: float,
):
    """Sum of the self-contact forces on vertex ``i`` and their Hessian blocks: as the point
    of its VT pairs, as a corner of its triangles' TV pairs, as an end of its edges' EE pairs.
    This lane's share only: items ``lane, lane + stride, ...`` of the vertex's pairs.

    The pairs come from the vertex's gather records (``pair_records_kernel``: the pair's
    vertices, the vertex's role and the side reference in one place), so a pair costs one
    record load, then its positions. (The solve's split gather calls this; its fused gather reads
    the records in its own loop, ``vbd_kernels.vertex_share_force_hessian``.) A vertex
    whose records did not fit in the pool (``pair_first < 0``) is gathered from the lists
    (``self_contact_list_force_hessian``)."""
    f = wp.vec3(0.0)
    H = wp.mat33(0.0)
    first = load_int(sc.pair_first, i)
    if first < 0:
        return self_contact_list_force_hessian(i, lane, stride, x, snap, x0, tri_indices, vertex_tri_offsets,
                                               vertex_tri_ids, vertex_tri_local, sc, eps_u)
    for j in range(first + lane, first + load_int(sc.pair_count, i), stride):
        fc, hc = record_force_hessian_at(x, snap, x0, load_vec4i(sc.pair_verts, j), load_vec3(sc.pair_ref, j),
                                         load_int(sc.pair_role, j), sc, eps_u)
        f = f + fc
        H = H + hc
    return f, H


@wp.func
def point_triangle_separation(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec3:
    """``p`` minus its closest point on triangle ``abc``."""
    w = triangle_closest_bary(p, a, b, c)
    return p - (w[0] * a + w[1] * b + w[2] * c)


@wp.func
def point_triangle_distance(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> float:
    return wp.length(point_triangle_separation(p, a, b, c))


FAR = wp.constant(1.0e30)
NEAR_REST = wp.constant(256)
"""Bit of a stored pair's ``rk`` (above its radius code, bits 0-7) marking a pair closer than
``coarse_exclusion`` at rest, which leaves the coarse correction alone (``has_pairs``); masked
off wherever the code is read."""


@wp.func
def rest_distance_triangle(sc: SelfContactData, v: int, tri: wp.vec3i) -> float:
    """Distance of vertex ``v`` from triangle ``tri`` in the rest shape where both are of one
    connected piece of cloth, else ``FAR`` (separate pieces have no rest distance)."""
    if sc.component[v] != sc.component[tri[0]]:
        return FAR
    return point_triangle_distance(sc.rest[v], sc.rest[tri[0]], sc.rest[tri[1]], sc.rest[tri[2]])


@wp.func
def rest_distance_edges(sc: SelfContactData, ea: wp.vec2i, eb: wp.vec2i) -> float:
    """Distance of edges ``ea`` and ``eb`` in the rest shape where both are of one connected
    piece, else ``FAR``."""
    if sc.component[ea[0]] != sc.component[eb[0]]:
        return FAR
    st = wp.closest_point_edge_edge(sc.rest[ea[0]], sc.rest[ea[1]], sc.rest[eb[0]], sc.rest[eb[1]], 1.0e-12)
    return st[2]


@wp.func
def adjacent(sc: SelfContactData, u: int, c: int) -> bool:
    """Whether a mesh edge joins vertices ``u`` and ``c``."""
    for k in range(sc.vertex_edge_offsets[u], sc.vertex_edge_offsets[u + 1]):
        e = sc.mesh_edges[sc.vertex_edge_ids[k]]
        if e[0] == c or e[1] == c:
            return True
    return False


@wp.func
def ring_triangle(sc: SelfContactData, u: int, tri: wp.vec3i) -> bool:
    """Whether the non-incident triangle ``tri`` has a corner joined to vertex ``u`` by an edge
    (it lies in ``u``'s second ring: about 0.87 edge lengths away on a flat regular mesh), with
    the ring exclusion on (the test's loads cost the 5k t-shirt 0.5 ms per frame)."""
    if sc.ring_exclusion == 0:
        return False
    return adjacent(sc, u, tri[0]) or adjacent(sc, u, tri[1]) or adjacent(sc, u, tri[2])


@wp.func
def ring_edges(sc: SelfContactData, ea: wp.vec2i, eb: wp.vec2i) -> bool:
    """Whether edges ``ea`` and ``eb`` (sharing no end) have ends joined by an edge, with the
    ring exclusion on."""
    if sc.ring_exclusion == 0:
        return False
    return (adjacent(sc, ea[0], eb[0]) or adjacent(sc, ea[0], eb[1]) or adjacent(sc, ea[1], eb[0])
            or adjacent(sc, ea[1], eb[1]))


@wp.func
def rest_class(sc: SelfContactData, rest_distance: float, ring: bool) -> int:
    """How a non-incident pair found by detection is treated by its rest distance and whether
    its primitives are joined by an edge (``ring``, ``ring_triangle`` / ``ring_edges``): -1 left
    to the elastic forces (closer than ``rest_exclusion``, 0 by default, or with
    ``ring_exclusion`` a ring pair at least the radius apart at rest); 0 a contact with the full
    radius; ``reduced_radius_code`` for a pair of one piece closer than the radius at rest, ring
    or not (it does not lower the displacement bounds' ``d_min`` either: at rest it is already
    that close)."""
    if rest_distance < sc.exclusion:
        return -1
    if rest_distance < sc.radius:
        return reduced_radius_code(rest_distance, sc.radius)
    if ring:
        return -1
    return 0


@wp.func
def apply_bound(x_new: wp.vec3, x_start: wp.vec3, bound: float) -> wp.vec3:
    """Truncate the displacement from the substep start to ``bound`` [m]."""
    dx = x_new - x_start
    dl = wp.length(dx)
    if dl > bound:
        return x_start + dx * (bound / dl)
    return x_new


@wp.func
def query_radius(margin: float, speed: float, h: float, speed_factor: float) -> float:
    return wp.max(margin, speed_factor * speed * h)


@wp.func
def triangle_speed(v: wp.array(dtype=wp.vec3), tri: wp.vec3i, vr: wp.vec3) -> float:
    """The largest speed of a triangle's corners relative to ``vr``."""
    return wp.max(wp.max(wp.length(load_vec3(v, tri[0]) - vr), wp.length(load_vec3(v, tri[1]) - vr)),
                  wp.length(load_vec3(v, tri[2]) - vr))


@wp.func
def edge_speed(v: wp.array(dtype=wp.vec3), ea: wp.vec2i, vr: wp.vec3) -> float:
    """The larger speed of an edge's ends relative to ``vr``."""
    return wp.max(wp.length(load_vec3(v, ea[0]) - vr), wp.length(load_vec3(v, ea[1]) - vr))


@wp.func
def skip_radius(sc: SelfContactData, r: float) -> float:
    """The distance from which a query's hits are skipped: the query radius ``r``, or for a
    candidate query (``candidates``) none (``list_pair``'s relative radius alone decides)."""
    if sc.candidates > 0.0:
        return 1.0e30
    return r


@wp.func
def swept(lo: wp.vec3, hi: wp.vec3, p: wp.vec3, vel: wp.vec3, vr: wp.vec3, sweep: float):
    """The box ``lo``, ``hi`` grown to hold ``p`` moved by ``sweep`` [s] at velocity ``vel``
    relative to ``vr``."""
    q = p + sweep * (vel - vr)
    return wp.min(lo, q), wp.max(hi, q)


@wp.func
def list_pair(sc: SelfContactData, d: float, v_rel: wp.vec3, margin: float, speed_factor: float,
              h: float) -> bool:
    """Whether a pair found at distance ``d`` < the query radius is stored for the solve: with
    ``relative_lists``, only if ``d`` is under the radius of its own relative speed ``|v_rel|``
    (the motion that can close it within the substep), not the absolute speed the query covers.
    Cloth riding on a running limb moves at metres per second, but its neighbours on the
    surface move with it: they stay 1-2 edge lengths apart and never act. A candidate query
    (``candidates`` > 0, ``SelfContact.query_candidates``) adds the relative motion over
    ``candidates`` substeps: the pairs that radius can reach by the next substep's start."""
    if sc.relative_lists == 0:
        return True
    speed = wp.length(v_rel)
    return d < query_radius(margin, speed, h, speed_factor) + sc.candidates * speed * h


@wp.func
def keep_closest(ids: wp.array(dtype=wp.int32), dist: wp.array(dtype=float), base: int, count: int,
                 capacity: int, item: int, d: float):
    """Add pair ``item`` at distance ``d`` to the list ``ids[base : base + capacity]``; when the
    list is full, it replaces the farthest stored pair if closer. Returns the new count and the
    slot written (-1: not stored). (Keeping the first pairs found would let a crumpled region's
    nearby neighbours crowd out the layer that is actually closest.)"""
    if count < capacity:
        ids[base + count] = item
        dist[base + count] = d
        return count + 1, count
    far = int(0)
    far_d = dist[base]
    for k in range(1, capacity):
        if dist[base + k] > far_d:
            far_d = dist[base + k]
            far = k
    if d < far_d:
        ids[base + far] = item
        dist[base + far] = d
        return count, far
    return count, -1


@wp.func
def side_reference(diff: wp.vec3, old: wp.vec3, interior: bool) -> wp.vec3:
    """The side reference of a pair with separation ``diff`` now and reference ``old``: ``old``
    where the closest points are ``interior`` and the separation turned by more than 90 degrees
    (the pair crossed), else ``diff`` (``track_side`` says why only interior pairs)."""
    if interior and wp.dot(diff, old) < 0.0:
        return old
    return diff


@wp.func
def track_side(prev_ids: wp.array(dtype=wp.int32), prev_ref: wp.array(dtype=wp.vec3),
               prev_counts: wp.array(dtype=wp.int32), k: int, side_memory: int, base: int, item: int,
               diff: wp.vec3, interior: bool) -> wp.vec3:
    """The side reference of pair ``item`` with separation ``diff`` now: ``diff`` for a pair
    that is new or still on the side it had at the previous detection, the previous reference
    for one that crossed since (so the penalty pushes it back); without side memory
    ``diff``. The previous list of ``item``'s owner ``k`` starts at ``base``.

    A turn of the separation by more than 90 degrees is taken for a crossing only where the
    closest points are ``interior`` (inside the triangle, inside both edges): there the
    separation can only reverse by passing through. At a triangle's rim or an edge's end it
    also turns when a point slides past the rim or an edge past the other's end, without any
    crossing, and holding the old side there pushed such pairs the wrong way (session 10: the
    walk failed more often with side memory); there the new side is taken."""
    if side_memory == 0:
        return diff
    for j in range(prev_counts[k]):
        if prev_ids[base + j] == item:
            return side_reference(diff, prev_ref[base + j], interior)
    return diff


@wp.func
def store_pair(ids: wp.array(dtype=wp.int32), dist: wp.array(dtype=float), ref: wp.array(dtype=wp.vec3),
               rk: wp.array(dtype=wp.int32), prev_ids: wp.array(dtype=wp.int32),
               prev_ref: wp.array(dtype=wp.vec3),
               prev_counts: wp.array(dtype=wp.int32), side_memory: int, owner: int, capacity: int, count: int,
               item: int, d: float, diff: wp.vec3, interior: bool, code: int, radius: float,
               flags: int) -> int:
    """Put pair ``item`` (distance ``d``, separation ``diff``, closest points ``interior`` or
    not, radius code ``code`` of ``rest_class``) in the list of ``owner`` (``keep_closest``)
    with its side reference (``track_side``) and ``code | flags`` as its ``rk`` (``NEAR_REST``);
    returns the list's new count. The list keeps the
    pairs nearest their own contact distance: a pair with a reduced radius ranks by ``d`` plus
    the reduction, so seam neighbours resting inside the radius do not crowd out layers that
    met."""
    base = owner * capacity
    key = d
    if code > 0:
        key = d + (radius - pair_radius(radius, code << 8))
    count, slot = keep_closest(ids, dist, base, count, capacity, item, key)
    if slot >= 0:
        ref[base + slot] = track_side(prev_ids, prev_ref, prev_counts, owner, side_memory, base, item, diff,
                                      interior)
        rk[base + slot] = code | flags
    return count


@wp.func
def vertex_triangle_candidate(sc: SelfContactData, x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
                              u: int, tri: wp.vec3i, r: float, margin: float, speed_factor: float, h: float,
                              dmin: float, count: int, ids: wp.array(dtype=wp.int32),
                              dist: wp.array(dtype=float), ref: wp.array(dtype=wp.vec3),
                              rk: wp.array(dtype=wp.int32), prev_ids: wp.array(dtype=wp.int32),
                              prev_ref: wp.array(dtype=wp.vec3), prev_counts: wp.array(dtype=wp.int32),
                              owner: int, capacity: int, item: int):
    """A vertex ``u`` / triangle ``tri`` candidate of a box query (pair ``item`` of list ``owner``:
    the vertex's triangle or the triangle's vertex): the nearest distance so far and the list's
    count after it. It lowers ``dmin`` unless it was as close at rest (``rest_class``), and is
    stored (``store_pair``) if ``list_pair`` says so. Distance first: most candidates lie beyond
    ``r``, where they change neither ``dmin`` (which starts at ``r``) nor the list, and skip the
    rest-shape test."""
    a = load_vec3(x, tri[0])
    b = load_vec3(x, tri[1])
    c = load_vec3(x, tri[2])
    xu = load_vec3(x, u)
    w = triangle_closest_bary(xu, a, b, c)
    diff = xu - (w[0] * a + w[1] * b + w[2] * c)
    d = wp.length(diff)
    if d >= r:
        return dmin, count
    v_rel = load_vec3(v, u) - (w[0] * load_vec3(v, tri[0]) + w[1] * load_vec3(v, tri[1])
                               + w[2] * load_vec3(v, tri[2]))
    stored = list_pair(sc, d, v_rel, margin, speed_factor, h)
    if not stored and d >= dmin:
        return dmin, count
    rest = rest_distance_triangle(sc, u, tri)
    code = rest_class(sc, rest, ring_triangle(sc, u, tri))
    if code < 0:
        return dmin, count
    if stored:
        interior = wp.min(wp.min(w[0], w[1]), w[2]) > INTERIOR
        count = store_pair(ids, dist, ref, rk, prev_ids, prev_ref, prev_counts, sc.side_memory, owner,
                           capacity, count, item, d, diff, interior, code, sc.radius,
                           wp.where(rest < sc.coarse_exclusion, NEAR_REST, 0))
    if code > 0:
        return dmin, count
    return wp.min(dmin, d), count


@wp.func
def edge_edge_candidate(sc: SelfContactData, x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), e: int,
                        ea: wp.vec2i, p1: wp.vec3, q1: wp.vec3, e2: int, eb: wp.vec2i, r: float,
                        margin: float, speed_factor: float, h: float, dmin: float, count: int):
    """An edge ``e`` (ends ``ea`` at ``p1``, ``q1``) / edge ``e2`` (ends ``eb``, sharing none)
    candidate, as ``vertex_triangle_candidate`` for a vertex and a triangle: the nearest distance
    so far and ``e``'s list count after it."""
    p2 = load_vec3(x, eb[0])
    q2 = load_vec3(x, eb[1])
    st = wp.closest_point_edge_edge(p1, q1, p2, q2, 1.0e-12)
    d = st[2]
    if d >= r:
        return dmin, count
    v_rel = wp.lerp(load_vec3(v, ea[0]), load_vec3(v, ea[1]), st[0]) - wp.lerp(load_vec3(v, eb[0]),
                                                                              load_vec3(v, eb[1]), st[1])
    stored = list_pair(sc, d, v_rel, margin, speed_factor, h)
    if stored and sc.ee_interior != 0:
        # closest point at an edge's end: a point-edge or point-point distance, which the
        # vertex-triangle pairs of that end already hold (``SelfContact``, ``ee_interior``)
        stored = st[0] > 0.0 and st[0] < 1.0 and st[1] > 0.0 and st[1] < 1.0
    if not stored and d >= dmin:
        return dmin, count
    rest = rest_distance_edges(sc, ea, eb)
    code = rest_class(sc, rest, ring_edges(sc, ea, eb))
    if code < 0:
        return dmin, count
    if code == 0:
        dmin = wp.min(dmin, d)
    if stored:
        diff = (p1 + st[0] * (q1 - p1)) - (p2 + st[1] * (q2 - p2))
        interior = wp.min(wp.min(st[0], 1.0 - st[0]), wp.min(st[1], 1.0 - st[1])) > INTERIOR
        count = store_pair(sc.ee_edge, sc.ee_dist, sc.ee_ref, sc.ee_rk, sc.ee_edge_prev, sc.ee_ref_prev,
                           sc.ee_count_prev, sc.side_memory, e, sc.ee_capacity, count, e2, d, diff,
                           interior, code, sc.radius, wp.where(rest < sc.coarse_exclusion, NEAR_REST, 0))
    return dmin, count


@wp.kernel
def primitive_bounds_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    reference: wp.array(dtype=wp.vec3),
    sweep: float,
    expand: float,
    tri_indices: wp.array(dtype=wp.vec3i),
    mesh_edges: wp.array(dtype=wp.vec2i),
    tri_count: int,
    edge_count: int,
    lowers_tri_out: wp.array(dtype=wp.vec3),
    uppers_tri_out: wp.array(dtype=wp.vec3),
    lowers_edge_out: wp.array(dtype=wp.vec3),
    uppers_edge_out: wp.array(dtype=wp.vec3),
    lowers_point_out: wp.array(dtype=wp.vec3),
    uppers_point_out: wp.array(dtype=wp.vec3),
):
    """Axis-aligned boxes of every triangle (threads < tri_count) and edge (the next
    edge_count), and the vertices (the rest: points). For a candidate query's trees (``sweep``
    > 0) each box also holds its vertices moved by ``sweep`` [s] at their velocity relative to
    their instance's ``reference`` (``swept``), and is grown by ``expand`` [s] times its
    largest such speed: the primitive's own reach (``SelfContact.query_candidates``)."""
    k = wp.tid()
    ids = wp.vec3i()
    corners = int(3)
    if k >= tri_count + edge_count:
        ids = wp.vec3i(k - tri_count - edge_count, 0, 0)
        corners = 1
    elif k < tri_count:
        ids = tri_indices[k]
    else:
        e = mesh_edges[k - tri_count]
        ids = wp.vec3i(e[0], e[1], 0)
        corners = 2
    lo = x[ids[0]]
    hi = lo
    for c in range(1, corners):
        lo = wp.min(lo, x[ids[c]])
        hi = wp.max(hi, x[ids[c]])
    if sweep > 0.0:
        vr = reference[particle_instance[ids[0]]]
        speed = float(0.0)
        for c in range(corners):
            lo, hi = swept(lo, hi, x[ids[c]], v[ids[c]], vr, sweep)
            speed = wp.max(speed, wp.length(v[ids[c]] - vr))
        lo = lo - wp.vec3(expand * speed)
        hi = hi + wp.vec3(expand * speed)
    if k >= tri_count + edge_count:
        lowers_point_out[k - tri_count - edge_count] = lo
        uppers_point_out[k - tri_count - edge_count] = hi
    elif k < tri_count:
        lowers_tri_out[k] = lo
        uppers_tri_out[k] = hi
    else:
        lowers_edge_out[k - tri_count] = lo
        uppers_edge_out[k - tri_count] = hi


@wp.kernel
def group_roots_kernel(bvh: wp.uint64, roots_out: wp.array(dtype=wp.int32)):
    """Each group's (instance's) subtree root of ``bvh``, for the detection queries. Warp's
    ``bvh_get_group_root`` finds it by two binary searches over the leaves (each step three
    dependent loads) and a walk up from two leaves to their common ancestor: ~100 dependent
    loads that every query thread paid before its traversal. The tree's topology only changes
    when it is rebuilt, so the roots are found once then (session 31)."""
    g = wp.tid()
    roots_out[g] = wp.bvh_get_group_root(bvh, g)


@wp.kernel
def detect_vertex_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    tri_indices: wp.array(dtype=wp.vec3i),
    tri_bvh: wp.uint64,
    tri_roots: wp.array(dtype=wp.int32),
    margin: float,
    speed_factor: float,
    h: float,
    sc: SelfContactData,
    dmin_out: wp.array(dtype=float),
):
    """Per vertex: nearest non-incident triangle distance and the VT pairs within the radius
    (``tri_roots``: each instance's subtree root, ``group_roots_kernel``)."""
    i = wp.tid()
    xi = x[i]
    inst = particle_instance[i]
    vr = sc.reference[inst]
    r = query_radius(margin, wp.length(v[i] - vr), h, speed_factor)
    lo = xi
    hi = xi
    if sc.candidates > 0.0:  # a candidate query: the box swept over the substep (``SelfContact``)
        lo, hi = swept(lo, hi, xi, v[i], vr, sc.candidates * h)
    query = wp.bvh_query_aabb(tri_bvh, lo - wp.vec3(r), hi + wp.vec3(r), tri_roots[inst])
    t = int(0)
    rs = skip_radius(sc, r)
    dmin = rs
    count = int(0)
    while wp.bvh_query_next(query, t):
        tri = load_vec3i(tri_indices, t)
        if tri[0] == i or tri[1] == i or tri[2] == i:
            continue
        if load_int(particle_instance, tri[0]) != inst:
            continue
        dmin, count = vertex_triangle_candidate(sc, x, v, i, tri, rs, margin, speed_factor, h, dmin, count,
                                                sc.vt_tri, sc.vt_dist, sc.vt_ref, sc.vt_rk, sc.vt_tri_prev,
                                                sc.vt_ref_prev, sc.vt_count_prev, i, sc.vt_capacity, t)
    sc.vt_count[i] = count
    dmin_out[i] = dmin


@wp.kernel
def detect_triangle_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    tri_indices: wp.array(dtype=wp.vec3i),
    vertex_bvh: wp.uint64,
    vertex_roots: wp.array(dtype=wp.int32),
    margin: float,
    speed_factor: float,
    h: float,
    sc: SelfContactData,
    dmin_out: wp.array(dtype=float),
):
    """Per triangle: nearest non-incident vertex distance and the TV pairs within the radius.
    Candidate vertices come straight from the vertex BVH (session 13; through the triangle BVH
    each vertex was one of ~3 candidate triangles' corners, found again at its other
    triangles and skipped there: 6.5 of the run's 13.7 ms of detection per frame)."""
    t = wp.tid()
    tri = tri_indices[t]
    a = x[tri[0]]
    b = x[tri[1]]
    c = x[tri[2]]
    inst = particle_instance[tri[0]]
    vr = sc.reference[inst]
    r = query_radius(margin, triangle_speed(v, tri, vr), h, speed_factor)
    lo = wp.min(wp.min(a, b), c)
    hi = wp.max(wp.max(a, b), c)
    if sc.candidates > 0.0:
        sweep = sc.candidates * h
        lo, hi = swept(lo, hi, a, v[tri[0]], vr, sweep)
        lo, hi = swept(lo, hi, b, v[tri[1]], vr, sweep)
        lo, hi = swept(lo, hi, c, v[tri[2]], vr, sweep)
    query = wp.bvh_query_aabb(vertex_bvh, lo - wp.vec3(r), hi + wp.vec3(r), vertex_roots[inst])
    u = int(0)
    rs = skip_radius(sc, r)
    dmin = rs
    count = int(0)
    while wp.bvh_query_next(query, u):
        if u == tri[0] or u == tri[1] or u == tri[2] or load_int(particle_instance, u) != inst:
            continue
        dmin, count = vertex_triangle_candidate(sc, x, v, u, tri, rs, margin, speed_factor, h, dmin, count,
                                                sc.tv_vertex, sc.tv_dist, sc.tv_ref, sc.tv_rk,
                                                sc.tv_vertex_prev, sc.tv_ref_prev, sc.tv_count_prev, t,
                                                sc.tv_capacity, u)
    sc.tv_count[t] = count
    dmin_out[t] = dmin


@wp.kernel
def detect_edge_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    edge_bvh: wp.uint64,
    edge_roots: wp.array(dtype=wp.int32),
    margin: float,
    speed_factor: float,
    h: float,
    sc: SelfContactData,
    dmin_out: wp.array(dtype=float),
):
    """Per edge: nearest edge (sharing no vertex) distance and the EE pairs within the radius."""
    e = wp.tid()
    ea = sc.mesh_edges[e]
    p1 = x[ea[0]]
    q1 = x[ea[1]]
    inst = particle_instance[ea[0]]
    vr = sc.reference[inst]
    r = query_radius(margin, edge_speed(v, ea, vr), h, speed_factor)
    lo = wp.min(p1, q1)
    hi = wp.max(p1, q1)
    if sc.candidates > 0.0:
        lo, hi = swept(lo, hi, p1, v[ea[0]], vr, sc.candidates * h)
        lo, hi = swept(lo, hi, q1, v[ea[1]], vr, sc.candidates * h)
    query = wp.bvh_query_aabb(edge_bvh, lo - wp.vec3(r), hi + wp.vec3(r), edge_roots[inst])
    e2 = int(0)
    rs = skip_radius(sc, r)
    dmin = rs
    count = int(0)
    while wp.bvh_query_next(query, e2):
        eb = load_vec2i(sc.mesh_edges, e2)
        if eb[0] == ea[0] or eb[0] == ea[1] or eb[1] == ea[0] or eb[1] == ea[1]:
            continue
        if load_int(particle_instance, eb[0]) != inst:
            continue
        dmin, count = edge_edge_candidate(sc, x, v, e, ea, p1, q1, e2, eb, rs, margin, speed_factor, h, dmin,
                                          count)
    sc.ee_count[e] = count
    dmin_out[e] = dmin


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
    """Cluster slot ``s``'s box, query radius, corners' mean velocity and spread
    (``member_bounds_kernel``); a padding slot's: an empty box, radius 0, spread -1."""
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
    cl: ClusterArrays,
):
    """Per cluster slot (``sim.cloth.clusters``): its primitive's box (a vertex's point, a
    triangle's or an edge's box), the query radius the detection kernels give it (its fastest
    corner's speed in its instance's frame, ``query_radius``), and its corners' mean velocity
    and spread (``corner_spread``); a padding slot gets an empty box, radius 0, spread -1."""
    s = wp.tid()
    lo, hi, r, mean, spread = slot_bounds(s, x, v, particle_instance, tri_indices, margin, speed_factor, h,
                                          sc, cl)
    cl.lo[s] = lo
    cl.hi[s] = hi
    cl.radius[s] = r
    cl.vel[s] = mean
    cl.spread[s] = spread


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
    sc: SelfContactData,
    cl: ClusterArrays,
):
    """``member_bounds_kernel``, ``clusters.octet_bounds_kernel`` and
    ``clusters.cluster_bounds_kernel`` in one launch, on CUDA, for clusters of up to 32 slots
    (``clusters.LANE_SIZES``): a cluster is a segment of a warp, so its octets' and its own
    boxes, radii, mean velocities and spreads come from lane shuffles, not from two more
    launches (session 41: three chains of ~10 us each on every substep's critical path). The
    boxes and radii are the same; the means are summed in another order, which the spreads,
    measured from them, still bound. The slots' own velocities and spreads, which only the
    octet kernel reads, are not written. Thread 0 also zeroes the counters the detection's
    gather records count with (``SelfContact._records``: two memset nodes fewer on the critical
    path)."""
    s = wp.tid()
    n = cl.order.shape[0]
    if s == 0:
        sc.pair_cursor[0] = 0
        for colour in range(sc.heavy_count.shape[0]):
            sc.heavy_count[colour] = 0
    mask = lane_mask(s, n)
    lo, hi, r, mean, spread = slot_bounds(s, x, v, particle_instance, tri_indices, margin, speed_factor, h,
                                          sc, cl)
    valid = float(0.0)
    if spread >= 0.0:
        valid = 1.0
    cl.lo[s] = lo
    cl.hi[s] = hi
    cl.radius[s] = r
    # the octet (lanes differing in bits 1, 2, 4)
    o_lo, o_hi, o_r, o_total, o_count = reduce_lanes(lo, hi, r, valid * mean, valid, 1, 4, mask)
    o_mean = o_total / wp.max(o_count, 1.0)
    reach = float(0.0)
    if valid > 0.0:
        reach = wp.length(mean - o_mean) + spread
    o_reach = max_lanes(reach, 1, 4, mask)
    if s % 8 == 0:
        store_octet(cl, s / 8, o_lo, o_hi, o_r, o_mean, o_count, o_reach)
    # the cluster (lanes differing in bits 8 to size / 2, each holding its octet's data)
    c_lo, c_hi, c_r, c_total, c_count = reduce_lanes(o_lo, o_hi, o_r, o_count * o_mean, o_count, 8,
                                                     cl.size / 2, mask)
    # summed over the octets' lanes: every lane of an octet holds its octet's sums
    c_mean = c_total / wp.max(c_count, 1.0)
    c_reach = float(0.0)
    if o_count > 0.0:
        c_reach = wp.length(o_mean - c_mean) + o_reach
    c_reach = max_lanes(c_reach, 8, cl.size / 2, mask)
    if s % cl.size == 0:
        store_cluster(cl, s / cl.size, c_lo, c_hi, c_r, c_mean, c_reach)


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
    sc: SelfContactData,
    split: int,
    dmin_vertex: wp.array(dtype=float),
    dmin_triangle: wp.array(dtype=float),
    dmin_edge: wp.array(dtype=float),
):
    """The three detection queries (``detect_vertex_kernel``, ``detect_triangle_kernel``,
    ``detect_edge_kernel``) over the clusters (``sim.cloth.clusters``) instead of the trees: one
    thread per cluster slot, whose primitive meets the members of each target cluster that its
    cluster's masks mark. The same candidates, tests and lists; the candidates come in cluster
    order. A thread skips the octets (8 slots) of a marked cluster that its own box misses by
    its reach: its query radius, or with ``relative`` (``clusters.cluster_masks_kernel``) no
    more than the radius of the largest relative speed it can have to a member of that cluster
    (its corners' distance from the cluster's mean velocity plus the cluster's spread). With
    ``relative`` the pairs stored are still exactly the trees'; the nearest distances, which
    only the bounds read, may be larger.

    With ``split`` > 1 each slot has ``split`` threads (thread ``f * slots + s``), thread ``f``
    taking every ``split``-th marked cluster, into its own lists: those of owner ``f * count +
    p`` in ``sc``'s arrays (``count`` primitives of the kind), which ``merge_split_kernel`` merges.
    A query's chain of loads is what takes the time (a few warps per SM), and this cuts it."""
    t = wp.tid()
    slots = cl.order.shape[0]
    f = t / slots
    s = t - f * slots
    p = cl.order[s]
    if p < 0:
        return
    a = s / cl.size
    k = slot_kind(a, cl.kind_clusters)
    tk = 1 - k
    if k == 2:
        tk = 2
    g = cl.cluster_group[a]
    t0 = cl.group_first[tk * (cl.groups + 1) + g]
    r = cl.radius[s]
    p_lo = cl.lo[s]
    p_hi = cl.hi[s]
    corners = slot_corners(k, p, tri_indices, sc.mesh_edges)
    v0 = load_vec3(v, corners[0])
    v1 = load_vec3(v, corners[1])
    v2 = load_vec3(v, corners[2])
    rs = skip_radius(sc, r)
    dmin = rs
    count = int(0)
    i = int(-1)
    tri = wp.vec3i()
    ea = wp.vec2i()
    p1 = wp.vec3()
    q1 = wp.vec3()
    if k == 0:
        i = p
    elif k == 1:
        tri = tri_indices[p]
    else:
        ea = sc.mesh_edges[p]
        p1 = x[ea[0]]
        q1 = x[ea[1]]
    w_count = cl.words[k]
    mask_base = cl.mask_first[k] + (a - cl.kind_clusters[k]) * w_count
    meets = int(0)
    owner = p
    if split > 1:
        n_kind = sc.vt_count.shape[0] / split
        if k == 1:
            n_kind = sc.tv_count.shape[0] / split
        elif k == 2:
            n_kind = sc.ee_count.shape[0] / split
        owner = f * n_kind + p
    nth = int(-1)
    n_octets = cl.size / 8
    octet_bits = (1 << n_octets) - 1
    for w in range(w_count):
        bits = cl.masks[mask_base + w]
        b = int(0)
        while bits != 0:
            if (bits & 1) != 0:
                nth += 1
            if (bits & 1) != 0 and nth % split == f:
                target = cl.target_first[k] + t0 + w * 32 + b
                first = target * cl.size
                u = load_vec3(cl.cluster_vel, target)
                fastest = wp.max(wp.max(wp.length(v0 - u), wp.length(v1 - u)), wp.length(v2 - u))
                spread = cl.cluster_spread[target]
                reach = reach_radius(r, relative, margin, speed_factor, h, fastest + spread)
                q_lo = p_lo - wp.vec3(reach)
                q_hi = p_hi + wp.vec3(reach)
                octets = meet_mask8(q_lo, q_hi, cl.octet_lo, cl.octet_hi, target * n_octets) & octet_bits
                for j in range(cl.size):
                    if j % 8 == 0:
                        meets = int(0)
                        if ((octets >> (j / 8)) & 1) != 0:
                            meets = meet_mask8(q_lo, q_hi, cl.lo, cl.hi, first + j)
                    if ((meets >> (j % 8)) & 1) == 0:
                        continue
                    item = load_int(cl.order, first + j)
                    if k == 0:
                        t_item = load_vec3i(tri_indices, item)
                        if t_item[0] == i or t_item[1] == i or t_item[2] == i:
                            continue
                        dmin, count = vertex_triangle_candidate(sc, x, v, i, t_item, rs, margin, speed_factor,
                                                                h, dmin, count, sc.vt_tri, sc.vt_dist,
                                                                sc.vt_ref, sc.vt_rk, sc.vt_tri_prev,
                                                                sc.vt_ref_prev, sc.vt_count_prev, owner,
                                                                sc.vt_capacity, item)
                    elif k == 1:
                        if item == tri[0] or item == tri[1] or item == tri[2]:
                            continue
                        dmin, count = vertex_triangle_candidate(sc, x, v, item, tri, rs, margin, speed_factor,
                                                                h, dmin, count, sc.tv_vertex, sc.tv_dist,
                                                                sc.tv_ref, sc.tv_rk, sc.tv_vertex_prev,
                                                                sc.tv_ref_prev, sc.tv_count_prev, owner,
                                                                sc.tv_capacity, item)
                    else:
                        eb = load_vec2i(sc.mesh_edges, item)
                        if eb[0] == ea[0] or eb[0] == ea[1] or eb[1] == ea[0] or eb[1] == ea[1]:
                            continue
                        dmin, count = edge_edge_candidate(sc, x, v, owner, ea, p1, q1, item, eb, rs, margin,
                                                          speed_factor, h, dmin, count)
            bits = (bits >> 1) & 0x7FFFFFFF
            b += 1
    if k == 0:
        sc.vt_count[owner] = count
        dmin_vertex[owner] = dmin
    elif k == 1:
        sc.tv_count[owner] = count
        dmin_triangle[owner] = dmin
    else:
        sc.ee_count[owner] = count
        dmin_edge[owner] = dmin


@wp.func
def merge_lists(split: int, n: int, o: int, capacity: int, counts: wp.array(dtype=wp.int32),
                ids: wp.array(dtype=wp.int32), dist: wp.array(dtype=float), ref: wp.array(dtype=wp.vec3),
                rk: wp.array(dtype=wp.int32), dmins: wp.array(dtype=float), out_ids: wp.array(dtype=wp.int32),
                out_dist: wp.array(dtype=float), out_ref: wp.array(dtype=wp.vec3),
                out_rk: wp.array(dtype=wp.int32)):
    """Owner ``o``'s ``split`` partial lists (owners ``f * n + o``) merged in order into one list
    of ``capacity`` (``keep_closest`` on their keys); returns its count and the smallest of the
    partial nearest distances."""
    count = int(0)
    dmin = float(1.0e30)
    for f in range(split):
        src = f * n + o
        dmin = wp.min(dmin, dmins[src])
        for j in range(counts[src]):
            at = src * capacity + j
            count, slot = keep_closest(out_ids, out_dist, o * capacity, count, capacity, ids[at], dist[at])
            if slot >= 0:
                out_ref[o * capacity + slot] = ref[at]
                out_rk[o * capacity + slot] = rk[at]
    return count, dmin


@wp.kernel
def merge_split_kernel(
    split: int,
    n_vertices: int,
    n_triangles: int,
    n_edges: int,
    part: SelfContactData,
    part_dmin_vertex: wp.array(dtype=float),
    part_dmin_triangle: wp.array(dtype=float),
    part_dmin_edge: wp.array(dtype=float),
    sc: SelfContactData,
    dmin_vertex: wp.array(dtype=float),
    dmin_triangle: wp.array(dtype=float),
    dmin_edge: wp.array(dtype=float),
):
    """Per vertex, triangle and edge: its lists from the ``split`` partial lists of
    ``detect_clustered_kernel`` (``part``), in order, and its nearest distance. The lists hold
    what one thread would have kept; with ties at a full list, which of the tied pairs."""
    t = wp.tid()
    if t < n_vertices:
        c, d = merge_lists(split, n_vertices, t, sc.vt_capacity, part.vt_count, part.vt_tri, part.vt_dist,
                           part.vt_ref, part.vt_rk, part_dmin_vertex, sc.vt_tri, sc.vt_dist, sc.vt_ref,
                           sc.vt_rk)
        sc.vt_count[t] = c
        dmin_vertex[t] = d
    elif t < n_vertices + n_triangles:
        o = t - n_vertices
        c, d = merge_lists(split, n_triangles, o, sc.tv_capacity, part.tv_count, part.tv_vertex, part.tv_dist,
                           part.tv_ref, part.tv_rk, part_dmin_triangle, sc.tv_vertex, sc.tv_dist, sc.tv_ref,
                           sc.tv_rk)
        sc.tv_count[o] = c
        dmin_triangle[o] = d
    else:
        o = t - n_vertices - n_triangles
        c, d = merge_lists(split, n_edges, o, sc.ee_capacity, part.ee_count, part.ee_edge, part.ee_dist,
                           part.ee_ref, part.ee_rk, part_dmin_edge, sc.ee_edge, sc.ee_dist, sc.ee_ref,
                           sc.ee_rk)
        sc.ee_count[o] = c
        dmin_edge[o] = d


@wp.kernel
def remeasure_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    tri_indices: wp.array(dtype=wp.vec3i),
    particle_count: int,
    tri_count: int,
    margin: float,
    speed_factor: float,
    h: float,
    cand: SelfContactData,
    sc: SelfContactData,
    dmin_vertex: wp.array(dtype=float),
    dmin_tri: wp.array(dtype=float),
    dmin_edge: wp.array(dtype=float),
):
    """The detection of ``detect_vertex_kernel``, ``detect_triangle_kernel`` and
    ``detect_edge_kernel`` at ``x`` with ``v``, over the candidate pairs in ``cand``'s lists
    instead of a tree query (``SelfContact.lookahead``): threads below ``particle_count`` the
    vertices, then the triangles, then the edges. Each candidate goes through the same test
    (``vertex_triangle_candidate``, ``edge_edge_candidate``) with the same query radius, so
    where the candidates hold every pair the query would find, the lists hold the same pairs
    (in the candidates' order)."""
    k = wp.tid()
    if k < particle_count:
        inst = load_int(particle_instance, k)
        r = query_radius(margin, wp.length(load_vec3(v, k) - sc.reference[inst]), h, speed_factor)
        dmin = r
        count = int(0)
        for j in range(cand.vt_count[k]):
            t = cand.vt_tri[k * cand.vt_capacity + j]
            dmin, count = vertex_triangle_candidate(sc, x, v, k, load_vec3i(tri_indices, t), r, margin,
                                                    speed_factor, h, dmin, count, sc.vt_tri, sc.vt_dist,
                                                    sc.vt_ref, sc.vt_rk, sc.vt_tri_prev, sc.vt_ref_prev,
                                                    sc.vt_count_prev, k, sc.vt_capacity, t)
        sc.vt_count[k] = count
        dmin_vertex[k] = dmin
    elif k < particle_count + tri_count:
        t = k - particle_count
        tri = load_vec3i(tri_indices, t)
        r = query_radius(margin, triangle_speed(v, tri, sc.reference[load_int(particle_instance, tri[0])]), h,
                         speed_factor)
        dmin = r
        count = int(0)
        for j in range(cand.tv_count[t]):
            u = cand.tv_vertex[t * cand.tv_capacity + j]
            dmin, count = vertex_triangle_candidate(sc, x, v, u, tri, r, margin, speed_factor, h, dmin, count,
                                                    sc.tv_vertex, sc.tv_dist, sc.tv_ref, sc.tv_rk,
                                                    sc.tv_vertex_prev, sc.tv_ref_prev, sc.tv_count_prev, t,
                                                    sc.tv_capacity, u)
        sc.tv_count[t] = count
        dmin_tri[t] = dmin
    else:
        e = k - particle_count - tri_count
        ea = load_vec2i(sc.mesh_edges, e)
        p1 = load_vec3(x, ea[0])
        q1 = load_vec3(x, ea[1])
        r = query_radius(margin, edge_speed(v, ea, sc.reference[load_int(particle_instance, ea[0])]), h,
                         speed_factor)
        dmin = r
        count = int(0)
        for j in range(cand.ee_count[e]):
            e2 = cand.ee_edge[e * cand.ee_capacity + j]
            dmin, count = edge_edge_candidate(sc, x, v, e, ea, p1, q1, e2, load_vec2i(sc.mesh_edges, e2), r,
                                              margin, speed_factor, h, dmin, count)
        sc.ee_count[e] = count
        dmin_edge[e] = dmin


@wp.func
def pair_separation(x: wp.array(dtype=wp.vec3), q: wp.vec4i, role: int):
    """A pair's separation at ``x`` as a detection measures it, and whether its closest points
    are interior (``INTERIOR``): point ``q[0]`` minus its closest point on triangle ``q[1:4]``
    (``role`` < 4), or the closest points' difference of edges ``q[0] q[1]`` and ``q[2] q[3]``
    (``role`` >= 4)."""
    if role < 4:
        a = x[q[1]]
        b = x[q[2]]
        c = x[q[3]]
        w = triangle_closest_bary(x[q[0]], a, b, c)
        return x[q[0]] - (w[0] * a + w[1] * b + w[2] * c), wp.min(wp.min(w[0], w[1]), w[2]) > INTERIOR
    p1 = x[q[0]]
    q1 = x[q[1]]
    p2 = x[q[2]]
    q2 = x[q[3]]
    st = wp.closest_point_edge_edge(p1, q1, p2, q2, 1.0e-12)
    interior = wp.min(wp.min(st[0], 1.0 - st[0]), wp.min(st[1], 1.0 - st[1])) > INTERIOR
    return (p1 + st[0] * (q1 - p1)) - (p2 + st[1] * (q2 - p2)), interior


@wp.func
def refreshed_side(x: wp.array(dtype=wp.vec3), q: wp.vec4i, role: int, old: wp.vec3) -> wp.vec3:
    """The side reference of pair ``q`` (``role``, as ``pair_separation``) at ``x``, its
    reference ``old`` from the detection: the separation now, or ``old`` where the closest points
    are interior and the separation turned by more than 90 degrees since (the pair crossed:
    ``side_reference``)."""
    diff, interior = pair_separation(x, q, role)
    return side_reference(diff, old, interior)


@wp.kernel
def refresh_sides_kernel(
    x: wp.array(dtype=wp.vec3),
    tri_indices: wp.array(dtype=wp.vec3i),
    particle_count: int,
    tri_count: int,
    edge_count: int,
    sc: SelfContactData,
):
    """Every stored pair's side reference (``pair_force_hessian``'s ``diff0``) brought to ``x``
    (``refreshed_side``): threads below ``particle_count`` the vertices' VT lists, then the
    triangles' TV lists, the edges' EE lists, and the rest the gather records
    (``SelfContact.refresh_sides``)."""
    k = wp.tid()
    lists = particle_count + tri_count + edge_count
    if k >= lists:
        r = k - lists
        if r < wp.min(sc.pair_cursor[0], sc.pool_size):
            sc.pair_ref[r] = refreshed_side(x, sc.pair_verts[r], sc.pair_role[r] & 15, sc.pair_ref[r])
    elif k < particle_count:
        for s in range(sc.vt_count[k]):
            j = k * sc.vt_capacity + s
            tri = tri_indices[sc.vt_tri[j]]
            sc.vt_ref[j] = refreshed_side(x, wp.vec4i(k, tri[0], tri[1], tri[2]), 0, sc.vt_ref[j])
    elif k < particle_count + tri_count:
        t = k - particle_count
        tri = tri_indices[t]
        for s in range(sc.tv_count[t]):
            j = t * sc.tv_capacity + s
            q = wp.vec4i(sc.tv_vertex[j], tri[0], tri[1], tri[2])
            sc.tv_ref[j] = refreshed_side(x, q, 0, sc.tv_ref[j])
    else:
        e = k - particle_count - tri_count
        ea = sc.mesh_edges[e]
        for s in range(sc.ee_count[e]):
            j = e * sc.ee_capacity + s
            eb = sc.mesh_edges[sc.ee_edge[j]]
            sc.ee_ref[j] = refreshed_side(x, wp.vec4i(ea[0], ea[1], eb[0], eb[1]), 4, sc.ee_ref[j])


@wp.func
def held_pairs(rk: wp.array(dtype=wp.int32), base: int, n: int) -> int:
    """How many of the ``n`` stored pairs of a list from ``base`` hold back the coarse correction
    (no ``NEAR_REST`` bit in their ``rk``)."""
    held = int(0)
    for s in range(n):
        if (rk[base + s] & NEAR_REST) == 0:
            held += 1
    return held


@wp.kernel
def vertex_summary_kernel(
    dmin_vertex: wp.array(dtype=float),
    dmin_tri: wp.array(dtype=float),
    dmin_edge: wp.array(dtype=float),
    vertex_tri_offsets: wp.array(dtype=wp.int32),
    vertex_tri_ids: wp.array(dtype=wp.int32),
    relaxation: float,
    sc: SelfContactData,
):
    """Per vertex, once per detection: the bound ``b_i = gamma min(d_min(i), d_min(incident
    triangles), d_min(incident edges))``; the number of stored pairs of its triangles (TV) and
    of its edges (EE); how many of all its pairs hold back the coarse correction
    (``coarse_pairs``: those not marked ``NEAR_REST``), and for each
    incident triangle / edge the number of pairs before it (the
    offsets of the vertex's flattened pair lists, for the list fallback of the solve); and the
    place of the vertex's gather records in the shared pool, a block of ``pair_count`` records
    from ``pair_first`` (-1 where the pool is full; the solve then reads the lists), which
    ``pair_records_kernel`` fills: every pair the vertex takes part in (its VT pairs, its
    triangles' TV pairs, its edges' EE pairs, in that order) as the pair's four vertices, the
    vertex's role in it (bits 0-3 of ``pair_role``; bits 4-7 which of the four vertices have
    the vertex's colour, ``read_position``; bits 8-15 the pair's radius code,
    ``reduced_radius_code``) and the pair's side reference. The block's place in the pool
    depends on the threads' order, its contents do not: the solve's sums are deterministic.

    With ``heavy_cap`` > 0 (``heavy_count`` zeroed before) it also marks the vertices with more
    than ``heavy_threshold`` records and lists them in their colour's range of ``heavy_list``
    (a separate launch until session 15). The solve gives each a whole thread block
    (``vbd_kernels.solve_color_kernel``) when the colour has at most ``heavy_cap`` of them, so
    the few vertices of a dense fold (session 13: up to 160 records against a mean of 2-6) no
    longer set the length of every launch at a round of records per 16 lanes. The list's order
    follows the threads' order; which vertices are in it does not, and each is solved the same
    wherever it sits."""
    i = wp.tid()
    b = dmin_vertex[i]
    # pairs that hold back the coarse correction (``has_pairs``): all but those near at rest
    # (read only with an exclusion: without one every pair holds it, and the loads are saved)
    near = sc.coarse_exclusion > 0.0
    vt = sc.vt_count[i]
    held = int(0)
    if near:
        held += held_pairs(sc.vt_rk, i * sc.vt_capacity, vt)
    tv = int(0)
    for k in range(vertex_tri_offsets[i], vertex_tri_offsets[i + 1]):
        t = vertex_tri_ids[k]
        b = wp.min(b, dmin_tri[t])
        sc.tv_first[k] = tv
        tv += sc.tv_count[t]
        if near:
            held += held_pairs(sc.tv_rk, t * sc.tv_capacity, sc.tv_count[t])
    ee = int(0)
    for k in range(sc.vertex_edge_offsets[i], sc.vertex_edge_offsets[i + 1]):
        e = sc.vertex_edge_ids[k]
        b = wp.min(b, dmin_edge[e])
        sc.ee_first[k] = ee
        ee += sc.ee_count[e]
        if near:
            held += held_pairs(sc.ee_rk, e * sc.ee_capacity, sc.ee_count[e])
    sc.bound[i] = relaxation * b
    sc.tv_total[i] = tv
    sc.ee_total[i] = ee
    total = vt + tv + ee
    if not near:
        held = total
    sc.coarse_pairs[i] = held
    sc.pair_count[i] = total
    first = int(0)
    sc.heavy[i] = 0
    if total > 0:
        first = wp.atomic_add(sc.pair_cursor, 0, total)
        if first + total > sc.pool_size:
            sc.pair_first[i] = -1
            return
    sc.pair_first[i] = first
    c = sc.particle_color[i]
    if sc.heavy_cap > 0 and total > sc.heavy_threshold:
        k = wp.atomic_add(sc.heavy_count, c, 1)
        sc.heavy[i] = 1
        if k < sc.heavy_cap:
            sc.heavy_list[sc.color_start[c] + k] = i


@wp.func
def put_record(sc: SelfContactData, at: int, q: wp.vec4i, role: int, c: int, code: int, ref: wp.vec3):
    """Gather record ``at`` of the pool: the pair's vertices ``q``, the owner's ``role`` (0 VT
    vertex, 1-3 TV corner, 4+ EE end) with the same-colour mask of ``q`` against the owner's
    colour ``c`` and the radius ``code`` (``pair_role``'s bits), and the side reference."""
    sc.pair_verts[at] = q
    sc.pair_role[at] = packed_role(role, sc.particle_color, c, q) | (code << 8)
    sc.pair_ref[at] = ref


@wp.kernel
def pair_records_kernel(
    tri_indices: wp.array(dtype=wp.vec3i),
    tri_slot: wp.array(dtype=wp.int32),
    edge_slot: wp.array(dtype=wp.int32),
    n: int,
    nt: int,
    sc: SelfContactData,
):
    """The gather records of ``vertex_summary_kernel``'s blocks, one thread per list (the
    vertices' VT lists, then the triangles' TV lists, then the edges' EE lists): a stored pair's
    record goes to the block of every vertex it belongs to (a VT pair to its vertex, a TV pair
    to the triangle's three corners, an EE pair to the edge's two ends), at the place the
    vertex's order gives it (its VT pairs, its triangles' TV pairs, its edges' EE pairs;
    ``tv_first`` / ``ee_first`` count the pairs before each incident triangle / edge).
    ``tri_slot`` / ``edge_slot``: where a triangle's corner / an edge's end sits in that vertex's
    incidence list. (Session 32: one thread per vertex wrote all of its records, and the few
    vertices of a dense fold, with up to 160, set the launch's length; a list holds at most its
    capacity.)"""
    j = wp.tid()
    if j < n:
        first = sc.pair_first[j]
        if first < 0:
            return
        c = sc.particle_color[j]
        for s in range(sc.vt_count[j]):
            k = j * sc.vt_capacity + s
            tri = tri_indices[sc.vt_tri[k]]
            put_record(sc, first + s, wp.vec4i(j, tri[0], tri[1], tri[2]), 0, c, sc.vt_rk[k], sc.vt_ref[k])
        return
    if j < n + nt:
        t = j - n
        count = sc.tv_count[t]
        if count == 0:
            return
        tri = tri_indices[t]
        for corner in range(3):
            v = tri[corner]
            first = sc.pair_first[v]
            if first >= 0:
                base = first + sc.vt_count[v] + sc.tv_first[tri_slot[3 * t + corner]]
                c = sc.particle_color[v]
                for s in range(count):
                    k = t * sc.tv_capacity + s
                    put_record(sc, base + s, wp.vec4i(sc.tv_vertex[k], tri[0], tri[1], tri[2]), 1 + corner, c,
                               sc.tv_rk[k], sc.tv_ref[k])
        return
    e = j - n - nt
    count = sc.ee_count[e]
    if count == 0:
        return
    ea = sc.mesh_edges[e]
    for end in range(2):
        v = ea[end]
        first = sc.pair_first[v]
        if first >= 0:
            slot = edge_slot[2 * e + end]
            base = first + sc.vt_count[v] + sc.tv_total[v] + sc.ee_first[slot]
            role = 4 + sc.vertex_edge_local[slot]
            c = sc.particle_color[v]
            for s in range(count):
                k = e * sc.ee_capacity + s
                eb = sc.mesh_edges[sc.ee_edge[k]]
                put_record(sc, base + s, wp.vec4i(ea[0], ea[1], eb[0], eb[1]), role, c, sc.ee_rk[k],
                           sc.ee_ref[k])


def incidence_slots(ids: np.ndarray, local: np.ndarray, corners: int, count: int) -> np.ndarray:
    """For each of ``count`` primitives (triangles: ``corners`` 3, edges: 2) and corner ``c``, the
    index ``k`` of that corner's entry in the vertices' incidence CSR (``ids``: the primitive of
    each entry, ``local``: the vertex's corner in it), as a flat array ``[corners * p + c]``."""
    ids, local = ids.astype(np.int64), local.astype(np.int64)
    if len(ids) != corners * count or np.any((local < 0) | (local >= corners)):
        raise ValueError(f"incidence_slots: {len(ids)} incidence entries for {count} primitives of "
                         f"{corners} corners, or a corner outside 0..{corners - 1}")
    slots = np.full(corners * count, -1, np.int64)
    slots[corners * ids + local] = np.arange(len(ids))
    if count and slots.min() < 0:
        raise ValueError("incidence_slots: a primitive corner has no incidence entry (or two have one)")
    return slots.astype(np.int32)


class SelfContact:
    """Self-contact buffers, BVHs and detection for one ``ClothModel``.

    Args:
        model: the cloth model.
        radius: contact distance [m] between cloth surfaces (pairs closer are pushed apart).
        margin: minimum query radius [m] of the displacement bounds.
        stiffness: penalty stiffness [N/m].
        friction: cloth-cloth Coulomb friction coefficient.
        relaxation: gamma of the bounds, < 0.5.
        rest_exclusion: pairs (vertex-triangle, edge-edge) of one connected piece closer than
            this [m] in the rest shape are left to the elastic forces (default 0: none but the
            incident ones). A pair of one piece closer than ``radius`` at rest (a crease folded at
            rest, panels meeting at a seam) is in contact at half its rest distance
            (``reduced_radius_code``): nothing acts at rest, and it cannot pass through (until
            session 18 such pairs were excluded, and a fine t-shirt's sleeve caps and trousers'
            crotch seams had no self-contact). Pairs farther apart at rest, even a ring or two
            away, are in contact at ``radius`` when a fold brings them together.
        ring_exclusion: leave to the elastic forces the pairs at least ``radius`` apart at rest
            whose primitives an edge joins (a triangle with a corner next to the vertex, edges
            with neighbouring ends: about 0.87 edge lengths apart on a flat regular mesh). Off by
            default: those pairs keep tight folds of coarse meshes from passing through
            themselves. On fine meshes (5.5 mm edges) they lie within the 4 mm query margin as
            soon as the cloth moves, and mark most particles as in contact, where the coarse
            correction is capped (``VBDConfig.self_contact_ring_exclusion``, session 50).
        coarse_exclusion: pairs of one piece closer than this [m] at rest leave the coarse
            correction alone (``has_pairs``: no capped move, no self-contact stiffness in the
            coarse diagonal for them); they are in contact as ever. 0 (default here): every
            stored pair holds it back, as until session 50. On fine meshes the neighbours an edge
            or two apart (4-6 mm at 5.5 mm edges) lie within the 4 mm query margin as soon as
            the cloth moves, and nearly every particle had pairs: the correction was left out of
            most of the garment (``VBDConfig.self_contact_coarse_exclusion``).
        speed_factor: the query radius is at least ``speed_factor |v| h``.
        bounds: apply the displacement bounds (intersection-free guarantee); off: penalty only.
        capacity: pairs kept per vertex / triangle / edge.
        side_memory: keep the side a pair was found on across detections (see the module
            docstring); off: each detection takes the side from the positions it sees.
        relative_lists: store a pair only within the query radius of its relative speed (see
            the module docstring); off: every pair within the query radius.
        pool: gather records per vertex on average (``vertex_summary_kernel``); a vertex whose
            records do not fit is gathered from the lists, slower but the same forces.
        heavy_cap: vertices per colour with more than ``heavy_threshold`` records that the solve
            gives a thread block each (``vertex_summary_kernel``); 0: none.
        heavy_threshold: records above which a vertex is heavy (the solve's lanes per particle:
            more takes a vertex more than one round of its lanes).
        weight_floor: smallest pair weight the Hessian takes (``pair_force_hessian``): a
            vertex's Newton step is at most ``1 / weight_floor`` times a pair's penetration;
            0: the exact Gauss-Newton Hessian.
        ee_interior: store an edge-edge pair only where its closest points lie inside both
            edges. Where one lies at an edge's end the distance is that end vertex's distance to
            the other edge (or its end), and the vertex-triangle pairs of that vertex with the
            triangles at the other edge are at most as far: they are found by the same query
            radius and push the same way. Counting such a pair twice doubles the contact's
            stiffness there and, on a folded t-shirt, made ~80 % of the stored edge pairs
            (session 21), which the solve evaluates every iteration. The bounds' ``d_min``
            still takes every edge pair.
        slots: sets of detection outputs (pair lists, gather records, bounds) that ``detect``
            can fill in turn (``SelfContact.datas``; ``data`` is slot 0), so one detection can
            run while the solve reads another's (``VBDConfig.self_contact_pipeline``). The BVHs
            are shared: detections must not overlap each other.
        lookahead: None (default) or the widening [m] of the candidate queries' margin
            (``VBDConfig.self_contact_lookahead``): ``query_candidates`` stores the candidate pairs
            of a query whose boxes are swept over the substep's motion, beside the solve, and
            ``remeasure`` then forms each substep's lists from them without a tree query. Needs
            bounds off, relative lists and one slot.
        broadphase: ``"bvh"`` (three trees, refitted and queried) or ``"clusters"`` (the flat
            two-level culling of ``sim.cloth.clusters``: no trees, no lookahead). Both find the
            same pairs.
        cluster_size: primitives per cluster of the ``"clusters"`` broadphase.
        cluster_split: threads per primitive of the ``"clusters"`` query (``detect_clustered_kernel``;
            0: 2 up to ``SPLIT_SLOTS`` cluster slots, else 1). Needs side memory off.
        cluster_lanes: the clusters' octet and cluster data from lane shuffles in the slots' own
            launch (``cluster_bounds_fused_kernel``; CUDA, sizes ``clusters.LANE_SIZES``); None:
            wherever they can.
    """

    def __init__(self, model, *, radius: float, margin: float, stiffness: float, friction: float,
                 relaxation: float, speed_factor: float, capacity: int, rest_exclusion: float = 0.0,
                 ring_exclusion: bool = False, coarse_exclusion: float = 0.0, bounds: bool = True,
                 side_memory: bool = False,
                 relative_lists: bool = True,
                 pool: int = 16, heavy_cap: int = 0, heavy_threshold: int = 16, weight_floor: float = 0.5,
                 ee_interior: bool = False, slots: int = 1, lookahead: float | None = None,
                 broadphase: str = "bvh", cluster_size: int = 32, cluster_split: int = 1,
                 cluster_lanes: bool | None = None):
        w = warp()
        d = model.device
        self.model = model
        self.margin = float(margin)
        self.relaxation = float(relaxation)
        self.speed_factor = float(speed_factor)
        n, nt, ne = model.particle_count, model.tri_count, model.mesh_edge_indices.shape[0]
        sc = SelfContactData()
        sc.enabled = 1
        sc.use_bounds = 1 if bounds else 0
        sc.side_memory = 1 if side_memory else 0
        sc.relative_lists = 1 if relative_lists else 0
        sc.ee_interior = 1 if ee_interior else 0
        sc.candidates = 0.0
        sc.radius = float(radius)
        sc.stiffness = float(stiffness)
        sc.friction = float(friction)
        if not 0.0 <= weight_floor <= 1.0:
            raise ValueError(f"SelfContact: weight_floor must be in [0, 1], got {weight_floor}")
        sc.weight_floor = float(weight_floor)
        sc.vt_capacity = sc.tv_capacity = sc.ee_capacity = int(capacity)
        sc.vt_count = w.zeros(n, dtype=w.int32, device=d)
        sc.vt_tri = w.zeros(n * capacity, dtype=w.int32, device=d)
        sc.tv_count = w.zeros(nt, dtype=w.int32, device=d)
        sc.tv_vertex = w.zeros(nt * capacity, dtype=w.int32, device=d)
        sc.ee_count = w.zeros(ne, dtype=w.int32, device=d)
        sc.ee_edge = w.zeros(ne * capacity, dtype=w.int32, device=d)
        sc.vt_dist = w.zeros(n * capacity, dtype=float, device=d)
        sc.tv_dist = w.zeros(nt * capacity, dtype=float, device=d)
        sc.ee_dist = w.zeros(ne * capacity, dtype=float, device=d)
        # each pair's side reference; with side memory also the previous detection's lists
        # (without, one-element placeholders that track_side never reads)
        for name, ids, size in (("vt", "tri", n), ("tv", "vertex", nt), ("ee", "edge", ne)):
            keep = size if side_memory else 1
            setattr(sc, f"{name}_ref", w.zeros(size * capacity, dtype=w.vec3, device=d))
            setattr(sc, f"{name}_rk", w.zeros(size * capacity, dtype=w.int32, device=d))
            setattr(sc, f"{name}_ref_prev", w.zeros(keep * capacity, dtype=w.vec3, device=d))
            setattr(sc, f"{name}_count_prev", w.zeros(keep, dtype=w.int32, device=d))
            setattr(sc, f"{name}_{ids}_prev", w.zeros(keep * capacity, dtype=w.int32, device=d))
        sc.mesh_edges = model.mesh_edge_indices
        sc.vertex_edge_offsets = model.vertex_mesh_edge_offsets
        sc.vertex_edge_ids = model.vertex_mesh_edge_ids
        sc.vertex_edge_local = model.vertex_mesh_edge_local
        sc.bound = w.zeros(n, dtype=float, device=d)
        sc.tv_total = w.zeros(n, dtype=w.int32, device=d)
        sc.ee_total = w.zeros(n, dtype=w.int32, device=d)
        sc.tv_first = w.zeros(model.vertex_tri_ids.shape[0], dtype=w.int32, device=d)
        sc.ee_first = w.zeros(model.vertex_mesh_edge_ids.shape[0], dtype=w.int32, device=d)
        sc.pool_size = int(pool) * n
        sc.pair_first = w.zeros(n, dtype=w.int32, device=d)
        sc.pair_count = w.zeros(n, dtype=w.int32, device=d)
        sc.pair_verts = w.zeros(max(sc.pool_size, 1), dtype=w.vec4i, device=d)
        sc.pair_role = w.zeros(max(sc.pool_size, 1), dtype=w.int32, device=d)
        sc.pair_ref = w.zeros(max(sc.pool_size, 1), dtype=w.vec3, device=d)
        sc.pair_cursor = w.zeros(1, dtype=w.int32, device=d)
        if heavy_cap < 0 or heavy_threshold < 0:
            raise ValueError(f"SelfContact: heavy_cap and heavy_threshold must be >= 0, got {heavy_cap}, "
                             f"{heavy_threshold}")
        offsets = np.asarray(model.color_offsets, dtype=np.int32)
        sc.heavy_cap = int(heavy_cap) if pool > 0 else 0
        sc.heavy_threshold = int(heavy_threshold)
        sc.heavy = w.zeros(n, dtype=w.int32, device=d)
        sc.heavy_list = w.zeros(n, dtype=w.int32, device=d)
        sc.heavy_count = w.zeros(max(len(offsets) - 1, 1), dtype=w.int32, device=d)
        color = np.zeros(n, dtype=np.int32)
        color[model.color_vertices.numpy()] = np.repeat(np.arange(len(offsets) - 1, dtype=np.int32),
                                                        np.diff(offsets))
        sc.particle_color = w.array(color, dtype=w.int32, device=d)
        sc.color_start = w.array(offsets[:-1], dtype=w.int32, device=d)
        sc.rest = model.particle_rest
        sc.component = w.array(self._components(model), dtype=w.int32, device=d)
        if rest_exclusion < 0.0:
            raise ValueError(f"SelfContact: rest_exclusion must be >= 0, got {rest_exclusion}")
        sc.exclusion = float(rest_exclusion)
        sc.ring_exclusion = 1 if ring_exclusion else 0
        if coarse_exclusion < 0.0:
            raise ValueError(f"SelfContact: coarse_exclusion must be >= 0, got {coarse_exclusion}")
        sc.coarse_exclusion = float(coarse_exclusion)
        sc.coarse_pairs = w.zeros(n, dtype=w.int32, device=d)
        sc.reference = w.zeros(model.instance_count, dtype=w.vec3, device=d)
        if slots < 1 or (slots > 1 and side_memory):
            raise ValueError(f"SelfContact: slots must be >= 1, and 1 with side_memory (a detection's "
                             f"previous lists are its own slot's), got {slots}")
        self.datas = [sc] + [self._copy_outputs(sc, DETECTION_OUTPUTS) for _ in range(slots - 1)]
        self.data = sc
        self._dmins = tuple(w.zeros(size, dtype=float, device=d) for size in (n, nt, ne))
        # the lookahead's candidate lists and their own nearest distances (a candidate query runs
        # beside the solve, which reads the substep's lists and bounds)
        self.lookahead = lookahead
        self.candidates = None
        if lookahead is not None:
            if lookahead < 0.0:
                raise ValueError(f"SelfContact: lookahead must be >= 0 (or None: off), got {lookahead}")
            if bounds or slots > 1 or not relative_lists:
                raise ValueError("SelfContact: lookahead needs bounds off, relative lists and one slot (its "
                                 "lists are re-measured from candidates found by relative speed)")
            self.candidates = self._copy_outputs(sc, LIST_OUTPUTS)
            self.candidates.side_memory = 0
            self.candidates.ee_interior = 0
            self.candidates.candidates = LOOKAHEAD_SWEEP
            self._candidate_dmins = tuple(w.zeros(size, dtype=float, device=d) for size in (n, nt, ne))
        self._lo_t = w.zeros(nt, dtype=w.vec3, device=d)
        self._hi_t = w.zeros(nt, dtype=w.vec3, device=d)
        self._lo_e = w.zeros(ne, dtype=w.vec3, device=d)
        self._hi_e = w.zeros(ne, dtype=w.vec3, device=d)
        self._lo_p = w.zeros(n, dtype=w.vec3, device=d)
        self._hi_p = w.zeros(n, dtype=w.vec3, device=d)
        # where each triangle corner / edge end sits in its vertex's incidence list
        # (``pair_records_kernel``)
        self._tri_slot = w.array(incidence_slots(model.vertex_tri_ids.numpy(),
                                                 model.vertex_tri_local.numpy() & 3, 3, nt),
                                 dtype=w.int32, device=d)
        self._edge_slot = w.array(incidence_slots(model.vertex_mesh_edge_ids.numpy(),
                                                  model.vertex_mesh_edge_local.numpy(), 2, ne),
                                  dtype=w.int32, device=d)
        if broadphase not in ("bvh", "clusters"):
            raise ValueError(f"SelfContact: broadphase must be 'bvh' or 'clusters', got {broadphase!r}")
        if broadphase == "clusters" and lookahead is not None:
            raise ValueError("SelfContact: the lookahead's swept queries need broadphase 'bvh'")
        self.clusters = (ClusterLayout(model, cluster_size, cluster_lanes) if broadphase == "clusters"
                         else None)
        if cluster_split < 0:
            raise ValueError(f"SelfContact: cluster_split must be >= 0 (0: auto), got {cluster_split}")
        if cluster_split == 0:
            # one garment's query has a few warps per SM: split it; a batch fills the GPU anyway
            cluster_split = 2 if self.clusters is not None and self.clusters.slots <= SPLIT_SLOTS else 1
        if cluster_split > 1 and side_memory:
            raise ValueError("SelfContact: cluster_split > 1 needs side_memory off (the partial lists have "
                             "no previous lists)")
        self.cluster_split = int(cluster_split) if self.clusters is not None else 1
        self._split_arrays = {}
        self._split_dmins = ()
        if self.cluster_split > 1:
            f = self.cluster_split
            for name in LIST_OUTPUTS:
                a = getattr(sc, name)
                self._split_arrays[name] = w.zeros(a.shape[0] * f, dtype=a.dtype, device=d)
            self._split_dmins = tuple(w.zeros(size * f, dtype=float, device=d) for size in (n, nt, ne))
        self.tri_bvh = self.edge_bvh = self.vertex_bvh = None
        self._roots = []
        if self.clusters is None:
            self._update_bounds(model.particle_q)
            self.tri_bvh = w.Bvh(self._lo_t, self._hi_t, groups=model.tri_instance)
            self.edge_bvh = w.Bvh(self._lo_e, self._hi_e, groups=model.mesh_edge_instance)
            self.vertex_bvh = w.Bvh(self._lo_p, self._hi_p, groups=model.particle_instance)
            # each instance's subtree root per tree (triangles, vertices, edges), refound at rebuilds
            self._roots = [w.zeros(model.instance_count, dtype=w.int32, device=d) for _ in range(3)]
            self.find_roots()
        self._side = SideStreams(d, 3)

    @property
    def bvhs(self) -> tuple:
        """The three cloth BVHs in the order of their queries' roots: triangles (the vertex
        query's), vertices (the triangle query's), edges (the edge query's); none with the
        cluster broadphase."""
        if self.clusters is not None:
            return ()
        return self.tri_bvh, self.vertex_bvh, self.edge_bvh

    def find_roots(self) -> None:
        """Refind every instance's subtree roots; needed after rebuilding a tree outside
        ``detect`` (which refinds a tree's roots when it rebuilds it)."""
        for k, bvh in enumerate(self.bvhs):
            self._find_roots(k, bvh)

    def _find_roots(self, k: int, bvh) -> None:
        """Each instance's subtree root of ``bvh`` into ``_roots[k]`` (``group_roots_kernel``)."""
        warp().launch(group_roots_kernel, dim=self.model.instance_count, inputs=[bvh.id],
                      outputs=[self._roots[k]], device=self.model.device)

    @staticmethod
    def _copy_outputs(sc: SelfContactData, outputs: frozenset) -> SelfContactData:
        """A ``SelfContactData`` with ``sc``'s settings and model arrays and its own (zeroed)
        arrays ``outputs`` (``DETECTION_OUTPUTS``, ``LIST_OUTPUTS``)."""
        w = warp()
        out = SelfContactData()
        for name in SelfContactData.vars:
            value = getattr(sc, name)
            setattr(out, name, w.zeros_like(value) if name in outputs else value)
        return out

    @staticmethod
    def _components(model) -> np.ndarray:
        """Connected-component id of every particle (separate pieces of cloth, e.g. layers)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        e = model.mesh_edge_indices.numpy()
        n = model.particle_count
        adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
        return connected_components(adj, directed=False)[1].astype(np.int32)

    def _update_bounds(self, x, v=None, sweep: float = 0.0, expand: float = 0.0) -> None:
        """The trees' boxes at ``x`` (``primitive_bounds_kernel``); with ``sweep`` > 0 [s] (a
        candidate query's) swept over ``sweep`` at the velocities ``v`` and grown by ``expand``
        [s] times each primitive's speed."""
        m = self.model
        ne = self._lo_e.shape[0]
        warp().launch(primitive_bounds_kernel, dim=m.tri_count + ne + m.particle_count,
                      inputs=[x, x if v is None else v, m.particle_instance, self.data.reference,
                              float(sweep), float(expand), m.tri_indices, m.mesh_edge_indices, m.tri_count,
                              ne],
                      outputs=[self._lo_t, self._hi_t, self._lo_e, self._hi_e, self._lo_p, self._hi_p],
                      device=m.device)

    def _query(self, k: int, x0, v, h: float, data: SelfContactData, margin: float, out) -> None:
        """Detection kernel ``k`` (0 vertices, 1 triangles, 2 edges: ``detect_vertex_kernel``,
        ``detect_triangle_kernel``, ``detect_edge_kernel``) at ``x0`` (the BVHs must be fitted to
        it) with query margin ``margin``: the pairs into ``data``'s lists, the nearest distances
        into ``out``."""
        if self.clusters is not None:
            raise ValueError("SelfContact: the single queries need broadphase 'bvh' (the clusters' query "
                             "runs all three at once: detect)")
        m = self.model
        kernel, dim, inputs = (
            (detect_vertex_kernel, m.particle_count, [m.tri_indices, self.tri_bvh.id, self._roots[0]]),
            (detect_triangle_kernel, m.tri_count, [m.tri_indices, self.vertex_bvh.id, self._roots[1]]),
            (detect_edge_kernel, self._lo_e.shape[0], [self.edge_bvh.id, self._roots[2]]))[k]
        warp().launch(kernel, dim=dim, inputs=[x0, v, m.particle_instance, *inputs, margin, self.speed_factor,
                                               h, data], outputs=[out], device=m.device)

    def query_vertices(self, x0, v, h: float, slot: int = 0) -> None:
        """``detect_vertex_kernel``: each vertex's VT pairs and nearest triangle distance."""
        self._query(0, x0, v, h, self.datas[slot], self.margin, self._dmins[0])

    def query_triangles(self, x0, v, h: float, slot: int = 0) -> None:
        """``detect_triangle_kernel``: each triangle's TV pairs and nearest vertex distance."""
        self._query(1, x0, v, h, self.datas[slot], self.margin, self._dmins[1])

    def query_edges(self, x0, v, h: float, slot: int = 0) -> None:
        """``detect_edge_kernel``: each edge's EE pairs and nearest edge distance."""
        self._query(2, x0, v, h, self.datas[slot], self.margin, self._dmins[2])

    def refresh_sides(self, x0, slot: int = 0) -> None:
        """Bring the side reference of every pair in slot ``slot`` to ``x0``
        (``refresh_sides_kernel``), for lists detected at earlier positions: a pair's side is the
        one it has when the substep that uses it starts, unless it crossed since the detection
        (``refreshed_side``), as ``track_side`` decides. Kept whole from a substep earlier, the
        separation of a vertex sliding past a triangle's rim turns by more than 90 degrees
        without any crossing, and the penalty then pushed it the wrong way (the stacked-layer
        drop blew up); taken whole from ``x0``, a pair that crossed in the substep between is
        held crossed."""
        m = self.model
        sc = self.datas[slot]
        ne = self._lo_e.shape[0]
        warp().launch(refresh_sides_kernel, dim=m.particle_count + m.tri_count + ne + sc.pool_size,
                      inputs=[x0, m.tri_indices, m.particle_count, m.tri_count, ne, sc], device=m.device)

    def detect(self, x0, v, h: float, rebuild: bool = False, reference=None, slot: int = 0) -> None:
        """Refit (``rebuild``: rebuild) the BVHs at ``x0`` (substep start) and find pairs and
        bounds; ``v`` [m/s] are the velocities the substep starts with, ``reference`` each
        instance's reference velocity (vec3 (I,), ``ClothControl.instance_velocity``; None:
        the one set last, zeros at first). The outputs go to ``datas[slot]``."""
        sc = self._start_detection(reference, slot)
        zeroed = self._tree_queries(x0, v, h, rebuild, sc, self.margin, self._dmins)
        self._records(sc, zeroed=zeroed)

    def _set_reference(self, reference) -> None:
        """The instances' reference velocities for every detection (None: kept)."""
        if reference is not None:
            for data in self.datas:
                data.reference = reference
            if self.candidates is not None:
                self.candidates.reference = reference

    def _start_detection(self, reference, slot: int = 0) -> SelfContactData:
        """Slot ``slot``'s data, with the instances' ``reference`` velocities set (None: kept)
        and, with side memory, its lists kept as the previous ones."""
        w = warp()
        sc = self.datas[slot]
        self._set_reference(reference)
        for name, ids in (("vt", "tri"), ("tv", "vertex"), ("ee", "edge")) if sc.side_memory else ():
            w.copy(getattr(sc, f"{name}_count_prev"), getattr(sc, f"{name}_count"))
            w.copy(getattr(sc, f"{name}_{ids}_prev"), getattr(sc, f"{name}_{ids}"))
            w.copy(getattr(sc, f"{name}_ref_prev"), getattr(sc, f"{name}_ref"))
        return sc

    def _tree_queries(self, x0, v, h: float, rebuild: bool, data: SelfContactData, margin: float,
                      dmins: tuple) -> bool:
        """Fit (``rebuild``: build) the trees to ``x0`` and run the three queries (``_query``); for
        ``data`` of a candidate query, to the boxes swept over the substep and grown by each
        primitive's own reach (``primitive_bounds_kernel``), so that a slow primitive's query
        meets a fast one coming. Returns whether ``data``'s record counters were zeroed on the
        way (``_cluster_queries``)."""
        if self.clusters is not None:
            return self._cluster_queries(x0, v, h, data, margin, dmins)
        self._update_bounds(x0, v, data.candidates * h, self.speed_factor * h)
        # three independent chains (refit a tree, query it), each on its own stream on CUDA:
        # the queries are latency-bound (a few thousand threads), so they overlap almost fully
        for k, bvh in enumerate(self.bvhs):
            with self._side.on(k):
                if rebuild:
                    bvh.rebuild()
                    self._find_roots(k, bvh)
                else:
                    bvh.refit()
                self._query(k, x0, v, h, data, margin, dmins[k])
        self._side.join()
        return False

    def _cluster_queries(self, x0, v, h: float, data: SelfContactData, margin: float, dmins: tuple) -> bool:
        """The three queries over the clusters (``sim.cloth.clusters``): the slots' boxes and
        radii, the clusters' boxes and masks, then one query launch for every primitive. Returns
        whether ``data``'s record counters were zeroed (by ``cluster_bounds_fused_kernel``)."""
        w = warp()
        m = self.model
        cl = self.clusters
        if cl.slots == 0:
            return False
        w.launch(cluster_bounds_fused_kernel if cl.lanes else member_bounds_kernel, dim=cl.slots,
                 inputs=[x0, v, m.particle_instance, m.tri_indices, margin, self.speed_factor, h, data,
                         cl.arrays],
                 device=m.device)
        # with bounds off and relative lists, only the pairs within the radius of their relative
        # speed matter (the nearest distances feed only the bounds)
        relative = data.use_bounds == 0 and data.relative_lists != 0 and data.candidates == 0.0
        cl.update(relative, margin, self.speed_factor, h)
        split = self.cluster_split
        part, part_dmins = data, dmins
        if split > 1:
            part, part_dmins = self._split_lists(data), self._split_dmins
        w.launch(detect_clustered_kernel, dim=cl.slots * split,
                 inputs=[x0, v, m.tri_indices, cl.arrays, int(relative), margin, self.speed_factor, h, part,
                         split],
                 outputs=list(part_dmins), device=m.device)
        if split > 1:
            n, nt, ne = (len(dm) for dm in dmins)
            w.launch(merge_split_kernel, dim=n + nt + ne,
                     inputs=[split, n, nt, ne, part, *part_dmins, data], outputs=list(dmins), device=m.device)
        return cl.lanes

    def _split_lists(self, data: SelfContactData) -> SelfContactData:
        """``data`` with the partial lists of a split cluster query in place of its lists. Every
        other field is taken from ``data`` at each call: ``detect`` may have set new reference
        velocities on it."""
        out = SelfContactData()
        for name in SelfContactData.vars:
            setattr(out, name, self._split_arrays.get(name, getattr(data, name)))
        return out

    def query_candidates(self, x0, v, h: float, rebuild: bool = False, reference=None) -> None:
        """The lookahead's candidate pairs (``lookahead`` set) for ``remeasure`` at this substep's
        start ``x0`` and the next one's, ``h`` [s] later, into ``candidates``' lists: a detection
        whose boxes are swept over ``LOOKAHEAD_SWEEP`` substeps at the velocities ``v``, the
        trees' also grown by each primitive's own reach, with the margin widened by
        ``lookahead`` [m], keeping every hit closer than the relative-speed radius plus that
        sweep's relative motion (``list_pair``)."""
        if self.candidates is None:
            raise ValueError("SelfContact.query_candidates needs a lookahead")
        self._set_reference(reference)
        self._tree_queries(x0, v, h, rebuild, self.candidates, self.margin + self.lookahead,
                           self._candidate_dmins)

    def remeasure(self, x0, v, h: float) -> None:
        """``detect`` at ``x0`` over the candidate pairs of the last ``query_candidates``
        (``remeasure_kernel``) instead of the trees: the same tests, radii and records, one
        thread per primitive and no traversal. The lists equal a detection's as long as the
        candidates hold every pair it would find (the cloth moved less since the candidate
        query than its widened radius covers)."""
        if self.candidates is None:
            raise ValueError("SelfContact.remeasure needs a lookahead")
        m = self.model
        sc = self._start_detection(None)
        warp().launch(remeasure_kernel, dim=m.particle_count + m.tri_count + self._lo_e.shape[0],
                      inputs=[x0, v, m.particle_instance, m.tri_indices, m.particle_count, m.tri_count,
                              self.margin, self.speed_factor, h, self.candidates, sc],
                      outputs=list(self._dmins), device=m.device)
        self._records(sc)

    def _records(self, sc: SelfContactData, zeroed: bool = False) -> None:
        """The bounds and gather records of ``sc``'s lists (``vertex_summary_kernel``,
        ``pair_records_kernel``); ``zeroed``: the detection zeroed their counters already
        (``cluster_bounds_fused_kernel``)."""
        w = warp()
        m = self.model
        d = m.device
        if not zeroed:
            sc.pair_cursor.zero_()
            if sc.heavy_cap > 0:
                sc.heavy_count.zero_()
        w.launch(vertex_summary_kernel, dim=m.particle_count,
                 inputs=[*self._dmins, m.vertex_tri_offsets, m.vertex_tri_ids,
                         self.relaxation, sc], device=d)
        nt, ne = m.tri_count, self._lo_e.shape[0]
        w.launch(pair_records_kernel, dim=m.particle_count + nt + ne,
                 inputs=[m.tri_indices, self._tri_slot, self._edge_slot, m.particle_count, nt, sc], device=d)


# the SelfContactData arrays a detection writes (each ``SelfContact`` slot has its own)
DETECTION_OUTPUTS = frozenset((
    "vt_count", "vt_tri", "tv_count", "tv_vertex", "ee_count", "ee_edge", "vt_dist", "tv_dist", "ee_dist",
    "vt_ref", "tv_ref", "ee_ref", "vt_rk", "tv_rk", "ee_rk", "tv_total", "ee_total", "tv_first", "ee_first",
    "pair_first", "pair_count", "pair_verts", "pair_role", "pair_ref", "pair_cursor", "heavy", "heavy_list",
    "heavy_count", "bound", "coarse_pairs"))
# the pair lists (``SelfContact.candidates`` has its own)
LIST_OUTPUTS = frozenset(f"{kind}_{name}" for kind, ids in (("vt", "tri"), ("tv", "vertex"), ("ee", "edge"))
                         for name in ("count", ids, "dist", "ref", "rk"))


def disabled_data(device) -> SelfContactData:
    """A ``SelfContactData`` with ``enabled = 0`` and empty arrays."""
    w = warp()
    sc = SelfContactData()
    sc.enabled = 0
    sc.use_bounds = 0
    sc.side_memory = 0
    sc.relative_lists = 0
    sc.ee_interior = 0
    sc.candidates = 0.0
    sc.radius = 0.0
    sc.stiffness = 0.0
    sc.weight_floor = 0.0
    sc.friction = 0.0
    sc.vt_capacity = sc.tv_capacity = sc.ee_capacity = 0
    empty_i = w.zeros(1, dtype=w.int32, device=device)
    sc.vt_count = sc.vt_tri = sc.tv_count = sc.tv_vertex = sc.ee_count = sc.ee_edge = empty_i
    sc.vt_rk = sc.tv_rk = sc.ee_rk = empty_i
    sc.vertex_edge_offsets = sc.vertex_edge_ids = sc.vertex_edge_local = empty_i
    sc.tv_total = sc.ee_total = sc.tv_first = sc.ee_first = empty_i
    sc.pair_first = sc.pair_count = sc.pair_role = sc.pair_cursor = empty_i
    sc.pair_verts = w.zeros(1, dtype=w.vec4i, device=device)
    sc.pool_size = 0
    sc.heavy = sc.heavy_list = sc.heavy_count = empty_i
    sc.heavy_threshold = 0
    sc.heavy_cap = 0
    sc.particle_color = sc.color_start = empty_i
    sc.mesh_edges = w.zeros(1, dtype=w.vec2i, device=device)
    sc.bound = w.zeros(1, dtype=float, device=device)
    sc.vt_dist = sc.tv_dist = sc.ee_dist = sc.bound
    sc.vt_count_prev = sc.vt_tri_prev = sc.tv_count_prev = sc.tv_vertex_prev = empty_i
    sc.ee_count_prev = sc.ee_edge_prev = empty_i
    sc.vt_ref = sc.tv_ref = sc.ee_ref = w.zeros(1, dtype=w.vec3, device=device)
    sc.vt_ref_prev = sc.tv_ref_prev = sc.ee_ref_prev = sc.vt_ref
    sc.rest = w.zeros(1, dtype=w.vec3, device=device)
    sc.pair_ref = sc.rest
    sc.component = w.zeros(1, dtype=w.int32, device=device)
    sc.exclusion = 0.0
    sc.ring_exclusion = 0
    sc.coarse_exclusion = 0.0
    sc.coarse_pairs = empty_i
    sc.reference = sc.rest
    return sc
