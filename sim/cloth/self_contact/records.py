"""The gather records of the cloth self-contact: after each detection, every pair a vertex takes
part in (its VT pairs, its triangles' TV pairs, its edges' EE pairs, in that order) written to
the vertex's block of a shared pool as the pair's four vertices, the vertex's role and the side
reference, so the solve reads a pair with one record load (``gather``)."""

from __future__ import annotations

import numpy as np
import warp as wp

from sim.cloth.self_contact.data import SelfContactData
from sim.cloth.self_contact.gather import packed_role
from sim.cloth.self_contact.lists import NEAR_REST


@wp.func
def held_pairs(rk: wp.array(dtype=wp.int32), base: int, n: int) -> int:
    """How many of the ``n`` stored pairs of a list from ``base`` hold back the coarse correction
    (no ``NEAR_REST`` bit in their ``rk``)."""
    held = int(0)
    for s in range(n):
        if (rk[base + s] & NEAR_REST) == 0:
            held += 1
    return held


@wp.func
def incident_pairs(i: int, offsets: wp.array(dtype=wp.int32), ids: wp.array(dtype=wp.int32),
                   counts: wp.array(dtype=wp.int32), rk: wp.array(dtype=wp.int32), capacity: int,
                   first_out: wp.array(dtype=wp.int32), near: bool, held: int):
    """The pairs of vertex ``i``'s incident triangles (TV lists) or edges (EE lists): writes each
    incident entry's offset among them (``first_out``: ``tv_first`` / ``ee_first``), returns
    their number and ``held`` plus those that hold back the coarse correction (counted with
    ``near`` only)."""
    n = int(0)
    for k in range(offsets[i], offsets[i + 1]):
        o = ids[k]
        first_out[k] = n
        n += counts[o]
        if near:
            held += held_pairs(rk, o * capacity, counts[o])
    return n, held


@wp.func
def reserve_records(i: int, total: int, sc: SelfContactData):
    """Vertex ``i``'s block of ``total`` records in the pool (``pair_first``; -1 where the pool is
    full: the solve then reads the lists), and with ``heavy_cap`` > 0 its mark and place in its
    colour's ``heavy_list`` when it has more than ``heavy_threshold`` records."""
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


@wp.kernel
def vertex_summary_kernel(
    vertex_tri_offsets: wp.array(dtype=wp.int32),
    vertex_tri_ids: wp.array(dtype=wp.int32),
    sc_inout: SelfContactData,
):
    """Per vertex, once per detection: the number of stored pairs of its triangles (TV) and of
    its edges (EE), and for each incident triangle / edge the number of pairs before it (the
    offsets of the vertex's flattened pair lists, for the list fallback of the solve); how many
    of all its pairs hold back the coarse correction (``coarse_pairs``: those not marked
    ``NEAR_REST``); the place of its gather records in the shared pool (``reserve_records``),
    which ``pair_records_kernel`` fills. The block's place in the pool depends on the threads'
    order, its contents do not: the solve's sums are deterministic.

    The heavy vertices (``heavy_cap`` > 0, ``heavy_count`` zeroed before) get a whole thread
    block each in the solve when their colour has at most ``heavy_cap`` of them, so the few
    vertices of a dense fold (up to 160 records against a mean of 2-6 on a t-shirt run) do not
    set the length of every launch at a round of records per 16 lanes. The list's order follows
    the threads' order; which vertices are in it does not, and each is solved the same wherever
    it sits."""
    i = wp.tid()
    # pairs that hold back the coarse correction (``has_pairs``): all but those near at rest
    # (read only with an exclusion: without one every pair holds it, and the loads are saved)
    near = sc_inout.coarse_exclusion > 0.0
    vt = sc_inout.vt_count[i]
    held = int(0)
    if near:
        held += held_pairs(sc_inout.vt_rk, i * sc_inout.vt_capacity, vt)
    tv, held = incident_pairs(i, vertex_tri_offsets, vertex_tri_ids, sc_inout.tv_count, sc_inout.tv_rk,
                              sc_inout.tv_capacity, sc_inout.tv_first, near, held)
    ee, held = incident_pairs(i, sc_inout.vertex_edge_offsets, sc_inout.vertex_edge_ids, sc_inout.ee_count,
                              sc_inout.ee_rk, sc_inout.ee_capacity, sc_inout.ee_first, near, held)
    sc_inout.tv_total[i] = tv
    sc_inout.ee_total[i] = ee
    total = vt + tv + ee
    if not near:
        held = total
    sc_inout.coarse_pairs[i] = held
    sc_inout.pair_count[i] = total
    reserve_records(i, total, sc_inout)


@wp.func
def put_record(sc: SelfContactData, at: int, q: wp.vec4i, role: int, c: int, code: int, ref: wp.vec3):
    """Gather record ``at`` of the pool: the pair's vertices ``q``, the owner's ``role`` (0 VT
    vertex, 1-3 TV corner, 4+ EE end) with the same-colour mask of ``q`` against the owner's
    colour ``c`` and the radius ``code`` (``pair_role``'s bits, ``gather.record_force_hessian_at``),
    and the side reference."""
    sc.pair_verts[at] = q
    sc.pair_role[at] = packed_role(role, sc.particle_color, c, q) | (code << 8)
    sc.pair_ref[at] = ref


@wp.func
def vertex_records(j: int, tri_indices: wp.array(dtype=wp.vec3i), sc: SelfContactData):
    """Vertex ``j``'s VT pairs: the first records of its own block."""
    first = sc.pair_first[j]
    if first < 0:
        return
    c = sc.particle_color[j]
    for s in range(sc.vt_count[j]):
        k = j * sc.vt_capacity + s
        tri = tri_indices[sc.vt_tri[k]]
        put_record(sc, first + s, wp.vec4i(j, tri[0], tri[1], tri[2]), 0, c, sc.vt_rk[k], sc.vt_ref[k])


@wp.func
def triangle_records(t: int, tri_indices: wp.array(dtype=wp.vec3i), tri_slot: wp.array(dtype=wp.int32),
                     sc: SelfContactData):
    """Triangle ``t``'s TV pairs, to the block of each of its three corners."""
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


@wp.func
def edge_records(e: int, edge_slot: wp.array(dtype=wp.int32), sc: SelfContactData):
    """Edge ``e``'s EE pairs, to the block of each of its two ends."""
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


@wp.kernel
def pair_records_kernel(
    tri_indices: wp.array(dtype=wp.vec3i),
    tri_slot: wp.array(dtype=wp.int32),
    edge_slot: wp.array(dtype=wp.int32),
    n: int,
    nt: int,
    sc_inout: SelfContactData,
):
    """The gather records of ``vertex_summary_kernel``'s blocks, one thread per list (the
    vertices' VT lists, then the triangles' TV lists, then the edges' EE lists): a stored pair's
    record goes to the block of every vertex it belongs to (a VT pair to its vertex, a TV pair
    to the triangle's three corners, an EE pair to the edge's two ends), at the place the
    vertex's order gives it (its VT pairs, its triangles' TV pairs, its edges' EE pairs;
    ``tv_first`` / ``ee_first`` count the pairs before each incident triangle / edge).
    ``tri_slot`` / ``edge_slot``: where a triangle's corner / an edge's end sits in that vertex's
    incidence list (``incidence_slots``). A thread per list, not per vertex: a list holds at
    most its capacity, where the few vertices of a dense fold have up to 160 records and would
    set the launch's length."""
    j = wp.tid()
    if j < n:
        vertex_records(j, tri_indices, sc_inout)
    elif j < n + nt:
        triangle_records(j - n, tri_indices, tri_slot, sc_inout)
    else:
        edge_records(j - n - nt, edge_slot, sc_inout)


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
