"""Kernels that move between the particles and the coarse nodes: the restriction of the residual
and of the contact stiffness to the coarse right-hand side and diagonal, and the prolongation of
the coarse solution back to the particles, limited where a move could cross something. Every
kernel is a gather (no atomics): deterministic on every device."""

from __future__ import annotations

import warp as wp

from sim.cloth.lanes import lane_mask, lane_read, lane_read_vec3
from sim.cloth.self_contact import SelfContactData, has_pairs
from sim.cloth.vbd_kernels import PINNED

RESTRICT_LANES = wp.constant(8)
"""Threads that share one coarse node's restriction: a node gathers 30-60 particles, which one
thread would read one after another."""

# what the restriction forms (bits): the right-hand side, the diagonal
RESTRICT_RHS = wp.constant(1)
RESTRICT_DIAGONAL = wp.constant(2)

SELF_CONTACT_CAP = wp.constant(0.25)
"""Largest move of a correction at a particle with self-contact pairs, in self-contact radii:
self-contact is not in the coarse system's geometry, so two capped neighbours across a gap close
it by less than the radius the penalty keeps between them."""


@wp.func
def restrict_lane(
    parts: int,
    tid: int,
    c: int,
    r: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    contact_point: wp.array(dtype=wp.vec3),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    instance_thickness: wp.array(dtype=float),
    k_contact: float,
    sc: SelfContactData,
    pair_flags: wp.array(dtype=wp.int32),
):
    """Lane ``tid % RESTRICT_LANES``'s shares of node ``c``'s ``P^T r`` (``parts`` bit
    ``RESTRICT_RHS``) and ``P^T k`` (bit ``RESTRICT_DIAGONAL``): entries ``l, l + RESTRICT_LANES,
    ...`` of the node's row of ``P^T`` (CSR ``offsets, ids, weights``). ``k`` is the body contact's
    penalty ``k_contact`` at particles of ``x`` pressed onto the body (closer to the contact plane
    than the thickness) plus the self-contact penalty at particles with pairs in ``sc``, or where
    ``pair_flags`` is not empty at those it flags (``CoarseLevel.prepare``'s early diagonal: the
    pairs at the previous substep's end)."""
    s = wp.vec3(0.0)
    kc = float(0.0)
    rhs = (parts & RESTRICT_RHS) != 0
    diagonal = (parts & RESTRICT_DIAGONAL) != 0
    for k in range(offsets[c] + tid % RESTRICT_LANES, offsets[c + 1], RESTRICT_LANES):
        i = ids[k]
        w = weights[k]
        if rhs:
            s = s + w * r[i]
        if diagonal:
            if contact_active[i] != 0:
                th = instance_thickness[particle_instance[i]]
                if wp.dot(contact_normal[i], x[i] - contact_point[i]) < th:
                    kc = kc + w * k_contact
            flagged = False
            if pair_flags.shape[0] > 0:
                flagged = pair_flags[i] != 0
            else:
                flagged = has_pairs(sc, i)
            if flagged:
                kc = kc + w * sc.stiffness
    return s, kc


@wp.kernel
def restrict_lanes_kernel(
    parts: int,
    r: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    contact_point: wp.array(dtype=wp.vec3),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    instance_thickness: wp.array(dtype=float),
    k_contact: float,
    sc: SelfContactData,
    pair_flags: wp.array(dtype=wp.int32),
    node_mass: wp.array(dtype=float),
    node_stiffness: wp.array(dtype=float),
    inertia: float,
    threads: int,
    rhs_out: wp.array(dtype=wp.vec3),
    diag_out: wp.array(dtype=float),
):
    """``restrict_kernel`` and ``restrict_sum_kernel`` in one launch (of ``threads``), on CUDA: a
    node's ``RESTRICT_LANES`` consecutive threads are a segment of a warp, and its first lane
    reads the others' shares by shuffles and adds them in lane order, as the sum kernel does
    (the same floats, one launch fewer on the correction's critical path)."""
    tid = wp.tid()
    c = tid // RESTRICT_LANES
    s, kc = restrict_lane(parts, tid, c, r, offsets, ids, weights, x, particle_instance, contact_point,
                          contact_normal, contact_active, instance_thickness, k_contact, sc, pair_flags)
    mask = lane_mask(tid, threads)
    first = (tid % 32) - tid % RESTRICT_LANES
    total = wp.vec3(0.0)
    k_total = float(0.0)
    for lane in range(RESTRICT_LANES):
        total = total + lane_read_vec3(s, first + lane, mask)
        k_total = k_total + lane_read(kc, first + lane, mask)
    if tid % RESTRICT_LANES == 0:
        if (parts & RESTRICT_RHS) != 0:
            rhs_out[c] = total
        if (parts & RESTRICT_DIAGONAL) != 0:
            diag_out[c] = node_mass[c] * inertia + node_stiffness[c] + k_total


@wp.kernel
def restrict_kernel(
    parts: int,
    r: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    contact_point: wp.array(dtype=wp.vec3),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    instance_thickness: wp.array(dtype=float),
    k_contact: float,
    sc: SelfContactData,
    pair_flags: wp.array(dtype=wp.int32),
    rhs_part_out: wp.array(dtype=wp.vec3),
    k_part_out: wp.array(dtype=float),
):
    """Lane ``l`` of node ``c``'s shares of ``P^T r`` and ``P^T k`` (``restrict_lane``; thread
    ``c * RESTRICT_LANES + l``; ``restrict_sum_kernel`` adds the lanes)."""
    tid = wp.tid()
    c = tid // RESTRICT_LANES
    s, kc = restrict_lane(parts, tid, c, r, offsets, ids, weights, x, particle_instance, contact_point,
                          contact_normal, contact_active, instance_thickness, k_contact, sc, pair_flags)
    if (parts & RESTRICT_RHS) != 0:
        rhs_part_out[tid] = s
    if (parts & RESTRICT_DIAGONAL) != 0:
        k_part_out[tid] = kc


@wp.kernel
def restrict_sum_kernel(
    parts: int,
    rhs_part: wp.array(dtype=wp.vec3),
    k_part: wp.array(dtype=float),
    node_mass: wp.array(dtype=float),
    node_stiffness: wp.array(dtype=float),
    inertia: float,
    rhs_out: wp.array(dtype=wp.vec3),
    diag_out: wp.array(dtype=float),
):
    """``rhs = P^T r`` and the coarse diagonal ``m_c (1/h^2 + alpha/h) + K_c,JJ + P^T k`` of node
    ``c`` (the ``parts`` of ``restrict_kernel``; ``inertia = 1/h^2 + alpha/h``) from its lanes,
    summed in lane order (one node per thread)."""
    c = wp.tid()
    if (parts & RESTRICT_RHS) != 0:
        s = wp.vec3(0.0)
        for lane in range(RESTRICT_LANES):
            s = s + rhs_part[c * RESTRICT_LANES + lane]
        rhs_out[c] = s
    if (parts & RESTRICT_DIAGONAL) != 0:
        kc = float(0.0)
        for lane in range(RESTRICT_LANES):
            kc = kc + k_part[c * RESTRICT_LANES + lane]
        diag_out[c] = node_mass[c] * inertia + node_stiffness[c] + kc


@wp.func
def clamp_length(v: wp.vec3, cap: float) -> wp.vec3:
    """``v`` shortened to length ``cap`` where longer."""
    vl = wp.length(v)
    if vl > cap:
        return v * (cap / vl)
    return v


@wp.kernel
def prolong_kernel(
    dx: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    contact_point: wp.array(dtype=wp.vec3),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    flags: wp.array(dtype=wp.int32),
    particle_instance: wp.array(dtype=wp.int32),
    instance_thickness: wp.array(dtype=float),
    instance_body: wp.array(dtype=wp.uint64),
    contact_margin: float,
    sc: SelfContactData,
    x_inout: wp.array(dtype=wp.vec3),
    snap_out: wp.array(dtype=wp.vec3),
):
    """``x += P dx_c`` for free particles (``P`` as CSR ``offsets, ids, weights``), the result also
    to ``snap_out``. The coarse system is linear and blind to geometry, so the move is limited
    where it could cross something: at a particle with self-contact pairs to
    ``SELF_CONTACT_CAP`` contact radii; at a particle of an instance with a body but off it
    (further than the contact margin as the substep began) to half the margin's room, so the body
    contact found at the substep's start still covers it; at a particle on the body to the
    margin's room (unlimited, a sewn tank top's first correction throws a particle on the shoulder
    13 cm at a 1.3 mm contact distance and the run blows up; in a coarse t-shirt's walk the
    largest such move is 11 mm) and no deeper into the body than it is or than its thickness shell."""
    i = wp.tid()
    xi = x_inout[i]
    if flags[i] != PINNED:
        s = wp.vec3(0.0)
        for k in range(offsets[i], offsets[i + 1]):
            s = s + weights[k] * dx[ids[k]]
        if has_pairs(sc, i):
            s = clamp_length(s, SELF_CONTACT_CAP * sc.radius)
        inst = particle_instance[i]
        thickness = instance_thickness[inst]
        active = contact_active[i]
        if instance_body[inst] != wp.uint64(0):
            room = wp.max(contact_margin - thickness, 0.0)
            s = clamp_length(s, wp.where(active == 0, 0.5 * room, room))
        x_new = xi + s
        if active != 0:
            normal = contact_normal[i]
            point = contact_point[i]
            floor = wp.min(wp.dot(normal, xi - point), thickness)
            depth = wp.dot(normal, x_new - point)
            if depth < floor:
                x_new = x_new + (floor - depth) * normal
        xi = x_new
        x_inout[i] = xi
    snap_out[i] = xi
