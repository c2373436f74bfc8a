"""The pair lists of the cloth self-contact detection: which candidate a broadphase hands over
is stored (``vertex_triangle_candidate``, ``edge_edge_candidate``), with what radius and side,
and how a full list keeps the closest pairs."""

from __future__ import annotations

import warp as wp

from sim.cloth.self_contact.data import SelfContactData
from sim.cloth.self_contact.pairs import (
    pair_radius,
    point_triangle_distance,
    reduced_radius_code,
    triangle_closest_bary,
)
from sim.cloth.spans import load_vec3

FAR = wp.constant(1.0e30)
NEAR_REST = wp.constant(256)
"""Bit of a stored pair's ``rk`` (above its radius code, bits 0-7) marking a pair closer than
``coarse_exclusion`` at rest, which leaves the coarse correction alone (``has_pairs``); masked
off wherever the code is read."""


@wp.func
def flat_point(sc: SelfContactData, v: int) -> wp.vec3:
    """Particle ``v`` in the plane of its flat panel."""
    f = sc.flat[v]
    return wp.vec3(f[0], f[1], 0.0)


@wp.func
def rest_distance_triangle(sc: SelfContactData, v: int, tri: wp.vec3i) -> float:
    """Distance along the cloth at rest of vertex ``v`` from triangle ``tri`` where both are of
    one connected piece, else ``FAR`` (separate pieces have no rest distance): in the flat panel
    when all four lie inside one, else the rest shape's distance, at least the way from each
    side to a seam (``sim.cloth.pattern_distance``)."""
    if sc.component[v] != sc.component[tri[0]]:
        return FAR
    p = sc.panel[v]
    if p >= 0 and sc.panel[tri[0]] == p and sc.panel[tri[1]] == p and sc.panel[tri[2]] == p:
        return point_triangle_distance(flat_point(sc, v), flat_point(sc, tri[0]), flat_point(sc, tri[1]),
                                       flat_point(sc, tri[2]))
    d = point_triangle_distance(sc.rest[v], sc.rest[tri[0]], sc.rest[tri[1]], sc.rest[tri[2]])
    seams = sc.flat[v][2] + wp.min(sc.flat[tri[0]][2], wp.min(sc.flat[tri[1]][2], sc.flat[tri[2]][2]))
    return wp.max(d, seams)


@wp.func
def rest_distance_edges(sc: SelfContactData, ea: wp.vec2i, eb: wp.vec2i) -> float:
    """Distance along the cloth at rest of edges ``ea`` and ``eb`` where both are of one
    connected piece, else ``FAR`` (as ``rest_distance_triangle``)."""
    if sc.component[ea[0]] != sc.component[eb[0]]:
        return FAR
    p = sc.panel[ea[0]]
    if p >= 0 and sc.panel[ea[1]] == p and sc.panel[eb[0]] == p and sc.panel[eb[1]] == p:
        st = wp.closest_point_edge_edge(flat_point(sc, ea[0]), flat_point(sc, ea[1]), flat_point(sc, eb[0]),
                                        flat_point(sc, eb[1]), 1.0e-12)
        return st[2]
    st = wp.closest_point_edge_edge(sc.rest[ea[0]], sc.rest[ea[1]], sc.rest[eb[0]], sc.rest[eb[1]], 1.0e-12)
    seams = wp.min(sc.flat[ea[0]][2], sc.flat[ea[1]][2]) + wp.min(sc.flat[eb[0]][2], sc.flat[eb[1]][2])
    return wp.max(st[2], seams)


@wp.func
def rest_radius_code(sc: SelfContactData, rest_distance: float) -> int:
    """The radius code of a non-incident pair ``rest_distance`` apart at rest:
    ``reduced_radius_code`` for a pair of one piece closer than the radius at rest (a crease
    folded at rest, panels meeting at a seam), else 0 (the full radius). Every other pair, a
    ring or two away on the surface included, is a contact at the full radius when a fold
    brings it together: a sleeve that crumples is two rings meeting."""
    if rest_distance < sc.radius:
        return reduced_radius_code(rest_distance, sc.radius)
    return 0


@wp.func
def query_radius(margin: float, speed: float, h: float, speed_factor: float) -> float:
    """The radius of a query for a primitive at ``speed`` [m/s]: the margin, or the distance
    ``speed_factor`` substeps ``h`` of that motion cover."""
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
def list_pair(sc: SelfContactData, d: float, v_rel: wp.vec3, margin: float, speed_factor: float,
              h: float) -> bool:
    """Whether a pair found at distance ``d`` < the query radius is stored for the solve: with
    ``relative_lists``, only if ``d`` is under the radius of its own relative speed ``|v_rel|``
    (the motion that can close it within the substep), not the absolute speed the query covers.
    Cloth riding on a running limb moves at metres per second, but its neighbours on the
    surface move with it: they stay 1-2 edge lengths apart and never act."""
    if sc.relative_lists == 0:
        return True
    speed = wp.length(v_rel)
    return d < query_radius(margin, speed, h, speed_factor)


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
def store_pair(ids: wp.array(dtype=wp.int32), dist: wp.array(dtype=float), ref: wp.array(dtype=wp.vec3),
               rk: wp.array(dtype=wp.int32), owner: int, capacity: int, count: int, item: int, d: float,
               diff: wp.vec3, code: int, radius: float, flags: int) -> int:
    """Put pair ``item`` (distance ``d``, separation ``diff``, radius code ``code`` of
    ``rest_radius_code``) in the list of ``owner`` (``keep_closest``) with ``diff`` as its side
    reference and ``code | flags`` as its ``rk`` (``NEAR_REST``); returns the list's new count.
    The list keeps the pairs nearest their own contact distance: a pair with a reduced radius
    ranks by ``d`` plus the reduction, so seam neighbours resting inside the radius do not crowd
    out layers that met."""
    base = owner * capacity
    key = d
    if code > 0:
        key = d + (radius - pair_radius(radius, code << 8))
    count, slot = keep_closest(ids, dist, base, count, capacity, item, key)
    if slot >= 0:
        ref[base + slot] = diff
        rk[base + slot] = code | flags
    return count


@wp.func
def vertex_triangle_candidate(sc: SelfContactData, x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
                              u: int, tri: wp.vec3i, r: float, margin: float, speed_factor: float, h: float,
                              count: int, ids: wp.array(dtype=wp.int32), dist: wp.array(dtype=float),
                              ref: wp.array(dtype=wp.vec3), rk: wp.array(dtype=wp.int32), owner: int,
                              capacity: int, item: int) -> int:
    """A vertex ``u`` / triangle ``tri`` candidate of a box query (pair ``item`` of list ``owner``:
    the vertex's triangle or the triangle's vertex): the list's count after it is stored
    (``store_pair``) if closer than the query radius ``r`` and ``list_pair`` says so. Distance
    first: most candidates lie beyond ``r`` and skip the rest."""
    a = load_vec3(x, tri[0])
    b = load_vec3(x, tri[1])
    c = load_vec3(x, tri[2])
    xu = load_vec3(x, u)
    w = triangle_closest_bary(xu, a, b, c)
    diff = xu - (w[0] * a + w[1] * b + w[2] * c)
    d = wp.length(diff)
    if d >= r:
        return count
    v_rel = load_vec3(v, u) - (w[0] * load_vec3(v, tri[0]) + w[1] * load_vec3(v, tri[1])
                               + w[2] * load_vec3(v, tri[2]))
    if not list_pair(sc, d, v_rel, margin, speed_factor, h):
        return count
    rest = rest_distance_triangle(sc, u, tri)
    return store_pair(ids, dist, ref, rk, owner, capacity, count, item, d, diff, rest_radius_code(sc, rest),
                      sc.radius, wp.where(rest < sc.coarse_exclusion, NEAR_REST, 0))


@wp.func
def edge_edge_candidate(sc: SelfContactData, x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), e: int,
                        ea: wp.vec2i, p1: wp.vec3, q1: wp.vec3, e2: int, eb: wp.vec2i, r: float,
                        margin: float, speed_factor: float, h: float, count: int) -> int:
    """An edge ``e`` (ends ``ea`` at ``p1``, ``q1``) / edge ``e2`` (ends ``eb``, sharing none)
    candidate, as ``vertex_triangle_candidate`` for a vertex and a triangle: ``e``'s list count
    after it."""
    p2 = load_vec3(x, eb[0])
    q2 = load_vec3(x, eb[1])
    st = wp.closest_point_edge_edge(p1, q1, p2, q2, 1.0e-12)
    d = st[2]
    if d >= r:
        return count
    v_rel = wp.lerp(load_vec3(v, ea[0]), load_vec3(v, ea[1]), st[0]) - wp.lerp(load_vec3(v, eb[0]),
                                                                              load_vec3(v, eb[1]), st[1])
    if not list_pair(sc, d, v_rel, margin, speed_factor, h):
        return count
    rest = rest_distance_edges(sc, ea, eb)
    diff = (p1 + st[0] * (q1 - p1)) - (p2 + st[1] * (q2 - p2))
    flags = wp.where(rest < sc.coarse_exclusion, NEAR_REST, 0)
    return store_pair(sc.ee_edge, sc.ee_dist, sc.ee_ref, sc.ee_rk, e, sc.ee_capacity, count, e2, d, diff,
                      rest_radius_code(sc, rest), sc.radius, flags)


@wp.func
def merge_lists(split: int, n: int, o: int, capacity: int, counts: wp.array(dtype=wp.int32),
                ids: wp.array(dtype=wp.int32), dist: wp.array(dtype=float), ref: wp.array(dtype=wp.vec3),
                rk: wp.array(dtype=wp.int32), out_ids: wp.array(dtype=wp.int32),
                out_dist: wp.array(dtype=float), out_ref: wp.array(dtype=wp.vec3),
                out_rk: wp.array(dtype=wp.int32)) -> int:
    """Owner ``o``'s ``split`` partial lists (owners ``f * n + o``) merged in order into one list
    of ``capacity`` (``keep_closest`` on their keys); returns its count."""
    count = int(0)
    for f in range(split):
        src = f * n + o
        for j in range(counts[src]):
            at = src * capacity + j
            count, slot = keep_closest(out_ids, out_dist, o * capacity, count, capacity, ids[at], dist[at])
            if slot >= 0:
                out_ref[o * capacity + slot] = ref[at]
                out_rk[o * capacity + slot] = rk[at]
    return count


@wp.kernel
def merge_split_kernel(
    split: int,
    n_vertices: int,
    n_triangles: int,
    n_edges: int,
    part: SelfContactData,
    sc_inout: SelfContactData,
):
    """Per vertex, triangle and edge: its lists from the ``split`` partial lists of a split
    cluster query (``part``, ``cluster_broadphase.detect_clustered_kernel``), in order. The
    lists hold what one thread would have kept; with ties at a full list, which of the tied
    pairs."""
    t = wp.tid()
    if t < n_vertices:
        sc_inout.vt_count[t] = merge_lists(split, n_vertices, t, sc_inout.vt_capacity, part.vt_count,
                                           part.vt_tri, part.vt_dist, part.vt_ref, part.vt_rk,
                                           sc_inout.vt_tri, sc_inout.vt_dist, sc_inout.vt_ref, sc_inout.vt_rk)
    elif t < n_vertices + n_triangles:
        o = t - n_vertices
        sc_inout.tv_count[o] = merge_lists(split, n_triangles, o, sc_inout.tv_capacity, part.tv_count,
                                           part.tv_vertex, part.tv_dist, part.tv_ref, part.tv_rk,
                                           sc_inout.tv_vertex, sc_inout.tv_dist, sc_inout.tv_ref,
                                           sc_inout.tv_rk)
    else:
        o = t - n_vertices - n_triangles
        sc_inout.ee_count[o] = merge_lists(split, n_edges, o, sc_inout.ee_capacity, part.ee_count,
                                           part.ee_edge, part.ee_dist, part.ee_ref, part.ee_rk,
                                           sc_inout.ee_edge, sc_inout.ee_dist, sc_inout.ee_ref,
                                           sc_inout.ee_rk)
