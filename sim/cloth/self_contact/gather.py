"""The solve's side of the cloth self-contact: the force and Hessian block of every pair a
vertex takes part in, gathered from its records (``records``) or, where the pool was full, from
the pair lists, with same-colour partners read from the sweep's snapshot."""

from __future__ import annotations

import warp as wp

from sim.cloth.self_contact.data import SelfContactData
from sim.cloth.self_contact.pairs import record_force_hessian
from sim.cloth.spans import load_int, load_vec3, load_vec4i


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
    partner's indices) in three loops one after the other, where a record is one load."""
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

    The pairs come from the vertex's gather records (``records.pair_records_kernel``: the
    pair's vertices, the vertex's role and the side reference in one place), so a pair costs one
    record load, then its positions. (The solve's split gather calls this; its fused gather
    reads the records in its own loop, with ``record_force_hessian``.) A vertex
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

