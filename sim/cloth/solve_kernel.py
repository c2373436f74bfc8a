"""The per-colour solve of Vertex Block Descent (Chen et al. 2024, Alg. 1): every particle of a
colour gathers the membrane, bending and self-contact forces and Hessian blocks of its elements,
adds inertia, air damping and body contact (``vertex_system``) and takes its Newton step
(``vertex_newton_step``).

The ``lanes`` threads of a particle each sum a share of its elements and contacts; one block
reduction (``tile_sum`` over the lanes axis of a particles x lanes tile) gives every particle its
3x3 system, which its lane 0 solves. Lanes turn the long serial gather of a particle (a latency
chain of dependent loads) into short ones; several particles per block fill the 32-thread warps
and the SM's block slots (a 16-thread block leaves half of every warp idle and caps occupancy at
a quarter).

Same-colour neighbours: the colouring separates the vertices of every triangle, but a bending
hinge's two opposite vertices may share a colour (``vertex_edge_local`` bits 2-5), a colouring
with fewer colours than a proper one leaves some triangle corners same-coloured
(``vertex_tri_local`` bits 2-4), and a self-contact pair found at run time can join any two
vertices (``pair_role`` bits 4-7). These neighbours are read from ``snap``, the positions at the
start of the sweep (a Jacobi step for that coupling), so no thread reads a position another
thread of its launch is writing; every solved particle writes its new position to ``snap_out``,
the next sweep's snapshot (the solver alternates the two). Neighbours of other colours are read
from ``x`` (Gauss-Seidel). The step does not depend on the order of the threads: every layout,
gather and device takes the same step up to round-off.
"""

from __future__ import annotations

import warp as wp

from sim.cloth.energies import bending_damped_vertex_force_hessian, corotated_damped_vertex_force_hessian
from sim.cloth.self_contact import (
    SelfContactData,
    SolveContactArrays,
    contact_view,
    read_positions,
    read_triangle,
    record_force_hessian,
    self_contact_force_hessian,
    self_contact_list_force_hessian,
)
from sim.cloth.spans import (
    Span,
    floats,
    ints,
    load_float,
    load_int,
    load_mat22,
    load_vec3,
    load_vec3i,
    load_vec4i,
    mat22s,
    vec3is,
    vec3s,
    vec4is,
)
from sim.cloth.vbd_kernels import PINNED

FUSED_LANES = 8
"""Lanes per particle from which the solve gathers with the fused loop (``fused_share``)."""


@wp.struct
class SolveArrays:
    """Every array the solve kernel reads besides ``x``/``snap``/``snap_out``, as ``Span``s
    (``sim.cloth.spans``: ~100 array arguments filled the constant cache). ``SolverVBD`` builds
    it and keeps it while the arrays live."""

    color_vertices: Span
    x_prev: Span
    y: Span
    mass: Span
    flags: Span
    particle_instance: Span
    tri_indices: Span
    tri_dm_inv: Span
    tri_area: Span
    tri_mu: Span
    tri_lam: Span
    tri_damping: Span
    tri_strain_prev: Span
    edge_indices: Span
    edge_rest_angle: Span
    edge_stiffness: Span
    edge_damping: Span
    edge_angle_prev: Span
    vertex_tri_offsets: Span
    vertex_tri_ids: Span
    vertex_tri_local: Span
    vertex_edge_offsets: Span
    vertex_edge_ids: Span
    vertex_edge_local: Span
    contact_point: Span
    contact_normal: Span
    contact_body_velocity: Span
    contact_active: Span
    instance_thickness: Span
    instance_friction: Span
    contact: SolveContactArrays


SOLVE_ARRAYS = (
    "color_vertices", "x_prev", "y", "mass", "flags", "particle_instance", "tri_indices", "tri_dm_inv",
    "tri_area", "tri_mu", "tri_lam", "tri_damping", "tri_strain_prev", "edge_indices",
    "edge_rest_angle", "edge_stiffness", "edge_damping", "edge_angle_prev", "vertex_tri_offsets",
    "vertex_tri_ids", "vertex_tri_local", "vertex_edge_offsets", "vertex_edge_ids", "vertex_edge_local",
    "contact_point", "contact_normal", "contact_body_velocity", "contact_active", "instance_thickness",
    "instance_friction"
)
"""The ``SolveArrays`` fields filled from arrays (``sim.cloth.spans.fill_spans``), in order."""


@wp.func
def contact_force_hessian(
    xi: wp.vec3,
    xi_prev: wp.vec3,
    p: wp.vec3,
    n: wp.vec3,
    body_v: wp.vec3,
    thickness: float,
    k_contact: float,
    mu: float,
    eps_u: float,
    h: float,
):
    """One-sided quadratic penalty ``k/2 (thickness - n.(x - p))^2`` and smoothed Coulomb
    friction on the tangential displacement relative to the body (Chen et al. 2024, Sec. 4.2,
    IPC's lazy friction: normal force and tangent basis fixed over the substep)."""
    f = wp.vec3(0.0)
    H = wp.mat33(0.0)
    d = wp.dot(n, xi - p)
    pen = thickness - d
    if pen > 0.0:
        lam_n = k_contact * pen
        f = n * lam_n
        H = k_contact * wp.outer(n, n)
        if mu > 0.0:
            T = wp.identity(n=3, dtype=float) - wp.outer(n, n)
            u = T * ((xi - xi_prev) - h * body_v)
            ul = wp.length(u)
            # f1(u)/u with f1 the C1 ramp of IPC (Li et al. 2020, Eq. 13)
            c = 1.0 / wp.max(ul, 1.0e-12)
            if ul < eps_u:
                c = 2.0 / eps_u - ul / (eps_u * eps_u)
            f = f - (mu * lam_n * c) * u
            H = H + (mu * lam_n * c) * T
    return f, H


@wp.struct
class ParticleStep:
    """What the Newton step of one particle reads besides its gathered force and Hessian: loaded
    before the block's reductions (``load_particle_step``), so the loads overlap them."""

    x: wp.vec3
    x_prev: wp.vec3
    y: wp.vec3
    mass: float
    flags: int
    contact_active: int
    contact_point: wp.vec3
    contact_normal: wp.vec3
    contact_body_velocity: wp.vec3
    thickness: float
    friction: float


@wp.func
def load_particle_step(i: int, a: SolveArrays, x: wp.array(dtype=wp.vec3)) -> ParticleStep:
    """Particle ``i``'s ``ParticleStep`` from the solve's arrays and positions ``x``."""
    p = ParticleStep()
    inst = load_int(ints(a.particle_instance), i)
    p.x = load_vec3(x, i)
    p.x_prev = load_vec3(vec3s(a.x_prev), i)
    p.y = load_vec3(vec3s(a.y), i)
    p.mass = load_float(floats(a.mass), i)
    p.flags = load_int(ints(a.flags), i)
    p.contact_active = load_int(ints(a.contact_active), i)
    p.contact_point = load_vec3(vec3s(a.contact_point), i)
    p.contact_normal = load_vec3(vec3s(a.contact_normal), i)
    p.contact_body_velocity = load_vec3(vec3s(a.contact_body_velocity), i)
    p.thickness = load_float(floats(a.instance_thickness), inst)
    p.friction = load_float(floats(a.instance_friction), inst)
    return p


@wp.func
def vertex_system(
    p: ParticleStep,
    f: wp.vec3,
    H: wp.mat33,
    k_contact: float,
    eps_u: float,
    h: float,
    air_damping: float,
):
    """Add inertia, air damping and body contact to the gathered ``f``, ``H`` of a particle:
    the force ``-dG/dx_i`` and Hessian block of the substep's incremental potential at ``p.x``."""
    xi = p.x
    inv_h = 1.0 / h
    # inertia m/h^2 (y - x), Hessian m/h^2 I; mass-proportional (air) damping alpha m (x - x_prev)/h
    mh = p.mass * inv_h * inv_h
    ca = air_damping * p.mass * inv_h
    f = f + mh * (p.y - xi) - ca * (xi - p.x_prev)
    H = H + (mh + ca) * wp.identity(n=3, dtype=float)
    if p.contact_active != 0:
        fc, hc = contact_force_hessian(xi, p.x_prev, p.contact_point, p.contact_normal,
                                       p.contact_body_velocity, p.thickness, k_contact, p.friction, eps_u, h)
        f = f + fc
        H = H + hc
    return f, H


@wp.func
def vertex_newton_step(
    p: ParticleStep,
    f: wp.vec3,
    H: wp.mat33,
    k_contact: float,
    eps_u: float,
    h: float,
    air_damping: float,
) -> wp.vec3:
    """Take the Newton step ``x += H^-1 f`` of a particle (Chen et al. 2024, Eq. 9-10) with its
    gathered ``f``, ``H`` completed by ``vertex_system``: its new position."""
    xi = p.x
    f, H = vertex_system(p, f, H, k_contact, eps_u, h, air_damping)
    # the block is symmetric positive definite (inertia + PSD terms); guard tiny determinants
    x_new = xi
    if wp.abs(wp.determinant(H)) > 1.0e-20:
        x_new = xi + wp.inverse(H) * f
    return x_new


@wp.func
def jacobi_scale(t_packed: int) -> float:
    """Hessian scale of a triangle term in a vertex's Newton step: 2 where another corner has
    the vertex's colour (``model.local_packed``): both corners then move in the same
    launch against each other's sweep-start position (a Jacobi coupling), and taking the whole
    step each would overshoot by up to twice; 1 otherwise (Gauss-Seidel)."""
    if (t_packed >> 2) != 0:
        return 2.0
    return 1.0


@wp.func
def triangle_term(a: SolveArrays, k: int, inv_h: float, x: wp.array(dtype=wp.vec3),
                  snap: wp.array(dtype=wp.vec3)):
    """Damped co-rotated membrane force and Jacobi-scaled Hessian block of entry ``k`` of the
    vertex -> triangle adjacency at the vertex it belongs to."""
    t = load_int(ints(a.vertex_tri_ids), k)
    tri = load_vec3i(vec3is(a.tri_indices), t)
    t_packed = load_int(ints(a.vertex_tri_local), k)
    ta, tb, tc = read_triangle(x, snap, tri, t_packed >> 2)
    fe, he = corotated_damped_vertex_force_hessian(
        ta, tb, tc, load_mat22(mat22s(a.tri_dm_inv), t), load_float(floats(a.tri_area), t),
        load_float(floats(a.tri_mu), t), load_float(floats(a.tri_lam), t),
        load_vec3(vec3s(a.tri_strain_prev), t), load_float(floats(a.tri_damping), t) * inv_h, t_packed & 3)
    return fe, he * jacobi_scale(t_packed)


@wp.func
def hinge_term(a: SolveArrays, k: int, inv_h: float, x: wp.array(dtype=wp.vec3),
               snap: wp.array(dtype=wp.vec3)):
    """Damped bending force and Hessian block of entry ``k`` of the vertex -> hinge adjacency."""
    e = load_int(ints(a.vertex_edge_ids), k)
    q = load_vec4i(vec4is(a.edge_indices), e)
    packed = load_int(ints(a.vertex_edge_local), k)
    h0, h1, h2, h3 = read_positions(x, snap, q, packed >> 2)
    fb, hb = bending_damped_vertex_force_hessian(
        h0, h1, h2, h3, load_float(floats(a.edge_rest_angle), e), load_float(floats(a.edge_stiffness), e),
        load_float(floats(a.edge_angle_prev), e), load_float(floats(a.edge_damping), e) * inv_h, packed & 3)
    return fb, hb


@wp.func
def split_share(i: int, lane: int, stride: int, a: SolveArrays, sc: SelfContactData, eps_u: float,
                inv_h: float, x: wp.array(dtype=wp.vec3), snap: wp.array(dtype=wp.vec3)):
    """This lane's share (items ``lane, lane + stride, ...``) of particle ``i``'s triangles,
    hinges and self-contact pairs, one kind after the other, each lane loading only the items it
    has: where the GPU is full (batches, 4 lanes per particle) other threads hide the latency,
    and the fused loop's placeholder loads cost throughput (H100, batch 64: 387 against 339
    garment-frames/s fused, docs/BENCHMARKS.md)."""
    tri_offsets = ints(a.vertex_tri_offsets)
    edge_offsets = ints(a.vertex_edge_offsets)
    f = wp.vec3(0.0)
    H = wp.mat33(0.0)
    for k in range(load_int(tri_offsets, i) + lane, load_int(tri_offsets, i + 1), stride):
        fe, he = triangle_term(a, k, inv_h, x, snap)
        f = f + fe
        H = H + he
    for k in range(load_int(edge_offsets, i) + lane, load_int(edge_offsets, i + 1), stride):
        fb, hb = hinge_term(a, k, inv_h, x, snap)
        f = f + fb
        H = H + hb
    if sc.enabled != 0:
        fs, hs = self_contact_force_hessian(i, lane, stride, x, snap, vec3s(a.x_prev), vec3is(a.tri_indices),
                                            tri_offsets, ints(a.vertex_tri_ids), ints(a.vertex_tri_local), sc,
                                            eps_u)
        f = f + fs
        H = H + hs
    return f, H


@wp.func
def fused_item(r: int, tri_k: int, tri_n: int, edge_k: int, edge_n: int, rec_k: int, rec_n: int,
               a: SolveArrays, sc: SelfContactData, eps_u: float, inv_h: float, x: wp.array(dtype=wp.vec3),
               snap: wp.array(dtype=wp.vec3), f: wp.vec3, H: wp.mat33):
    """``f``, ``H`` plus item ``r`` of each kind: triangle ``tri_k`` (of ``tri_n``), hinge
    ``edge_k`` (of ``edge_n``) and gather record ``rec_k`` (of ``rec_n``) of a vertex. Every
    load of the three is issued before any of them is used (an index past a kind's count reads
    the valid placeholder entry 0), so the lane waits for one chain of dependent loads (item id,
    its vertices, their positions) instead of one per kind."""
    x_prev = vec3s(a.x_prev)
    t = load_int(ints(a.vertex_tri_ids), tri_k)
    t_local = load_int(ints(a.vertex_tri_local), tri_k)
    e = load_int(ints(a.vertex_edge_ids), edge_k)
    e_packed = load_int(ints(a.vertex_edge_local), edge_k)
    q = load_vec4i(sc.pair_verts, rec_k)
    packed = load_int(sc.pair_role, rec_k)
    ref = load_vec3(sc.pair_ref, rec_k)
    tri = load_vec3i(vec3is(a.tri_indices), t)
    dm_inv = load_mat22(mat22s(a.tri_dm_inv), t)
    area = load_float(floats(a.tri_area), t)
    mu = load_float(floats(a.tri_mu), t)
    lam = load_float(floats(a.tri_lam), t)
    t_damp = load_float(floats(a.tri_damping), t)
    strain_prev = load_vec3(vec3s(a.tri_strain_prev), t)
    hinge = load_vec4i(vec4is(a.edge_indices), e)
    rest_angle = load_float(floats(a.edge_rest_angle), e)
    k_edge = load_float(floats(a.edge_stiffness), e)
    e_damp = load_float(floats(a.edge_damping), e)
    angle_prev = load_float(floats(a.edge_angle_prev), e)
    xa, xb, xc = read_triangle(x, snap, tri, t_local >> 2)
    h0, h1, h2, h3 = read_positions(x, snap, hinge, e_packed >> 2)
    y0, y1, y2, y3 = read_positions(x, snap, q, packed >> 4)
    z0 = load_vec3(x_prev, q[0])
    z1 = load_vec3(x_prev, q[1])
    z2 = load_vec3(x_prev, q[2])
    z3 = load_vec3(x_prev, q[3])
    if r < tri_n:
        fe, he = corotated_damped_vertex_force_hessian(xa, xb, xc, dm_inv, area, mu, lam, strain_prev,
                                                       t_damp * inv_h, t_local & 3)
        f = f + fe
        H = H + he * jacobi_scale(t_local)
    if r < edge_n:
        fb, hb = bending_damped_vertex_force_hessian(h0, h1, h2, h3, rest_angle, k_edge, angle_prev,
                                                     e_damp * inv_h, e_packed & 3)
        f = f + fb
        H = H + hb
    if r < rec_n:
        fs, hs = record_force_hessian(y0, y1, y2, y3, z0, z1, z2, z3, ref, packed, sc, eps_u)
        f = f + fs
        H = H + hs
    return f, H


@wp.func
def fused_share(i: int, lane: int, stride: int, a: SolveArrays, sc: SelfContactData, eps_u: float,
                inv_h: float, x: wp.array(dtype=wp.vec3), snap: wp.array(dtype=wp.vec3)):
    """``split_share`` with one loop that takes item ``r`` of each kind together
    (``fused_item``): single garments, whose launches are latency-bound (H100, a 5k t-shirt's
    ~1000 particles per colour: 20.7 against 23.8 ms per run frame's solve, docs/BENCHMARKS.md).
    The arrays must not be empty."""
    tri_offsets = ints(a.vertex_tri_offsets)
    edge_offsets = ints(a.vertex_edge_offsets)
    tri_begin = load_int(tri_offsets, i)
    tri_n = load_int(tri_offsets, i + 1) - tri_begin
    edge_begin = load_int(edge_offsets, i)
    edge_n = load_int(edge_offsets, i + 1) - edge_begin
    rec_begin = int(0)
    rec_n = int(0)
    lists = False
    if sc.enabled != 0:
        rec_begin = load_int(sc.pair_first, i)
        rec_n = load_int(sc.pair_count, i)
        if rec_begin < 0:  # no gather records: the pair lists, after the loop
            lists = True
            rec_begin = 0
            rec_n = 0
    f = wp.vec3(0.0)
    H = wp.mat33(0.0)
    for r in range(lane, wp.max(wp.max(tri_n, edge_n), rec_n), stride):
        tri_k = wp.where(r < tri_n, tri_begin + r, 0)
        edge_k = wp.where(r < edge_n, edge_begin + r, 0)
        rec_k = wp.where(r < rec_n, rec_begin + r, 0)
        f, H = fused_item(r, tri_k, tri_n, edge_k, edge_n, rec_k, rec_n, a, sc, eps_u, inv_h, x, snap, f, H)
    if lists:
        fs, hs = self_contact_list_force_hessian(i, lane, stride, x, snap, vec3s(a.x_prev),
                                                 vec3is(a.tri_indices), tri_offsets, ints(a.vertex_tri_ids),
                                                 ints(a.vertex_tri_local), sc, eps_u)
        f = f + fs
        H = H + hs
    return f, H


@wp.func
def light_particle(a: SolveArrays, sc: SelfContactData, block: int, local: int, particles: int, count: int,
                   color: int, color_start: int, evaluate: int) -> int:
    """The particle of slot ``local`` of light block ``block`` (-1: none): the colour's particles
    in order, ``particles`` per block, less those a heavy block solves (when the colour's heavy
    vertices all have one; an evaluation has no heavy blocks: it is launched once over all
    colours)."""
    i = int(-1)
    slot = block * particles + local
    if slot < count:
        i = load_int(ints(a.color_vertices), color_start + slot)
        if evaluate == 0:
            if sc.heavy_cap > 0:
                if sc.heavy[i] != 0 and sc.heavy_count[color] <= sc.heavy_cap:
                    i = -1
    return i


@wp.func
def heavy_particle(sc: SelfContactData, block: int, light_blocks: int, color: int, color_start: int) -> int:
    """The particle of heavy block ``block`` (one heavy vertex per block, its items shared by all
    the block's threads; -1: none, and the block leaves as a whole, so no thread waits at the
    reductions)."""
    hb = block - light_blocks
    nh = sc.heavy_count[color]
    if nh > sc.heavy_cap or hb >= nh:
        return -1
    return sc.heavy_list[color_start + hb]


@wp.func
def finish_particle(step: ParticleStep, f: wp.vec3, H: wp.mat33, k_contact: float, eps_u: float, h: float,
                    air_damping: float, evaluate: int, i: int, x_inout: wp.array(dtype=wp.vec3),
                    snap_out: wp.array(dtype=wp.vec3)):
    """Write particle ``i``'s result: with ``evaluate`` its residual force ``-dG/dx_i`` at ``x``
    (zero for pinned particles) to ``snap_out``, ``x`` unchanged; else its Newton step to
    ``x_inout`` (pinned particles stay) and its new position to ``snap_out``."""
    if evaluate != 0:
        r = wp.vec3(0.0)
        if step.flags != PINNED:
            r, H = vertex_system(step, f, H, k_contact, eps_u, h, air_damping)
        snap_out[i] = r
    else:
        x_new = step.x
        if step.flags != PINNED:
            x_new = vertex_newton_step(step, f, H, k_contact, eps_u, h, air_damping)
            x_inout[i] = x_new
        snap_out[i] = x_new


_SOLVE_KERNELS: dict = {}


def solve_color_kernel(particles: int, lanes: int, fused: bool | None = None, max_registers: int = 0,
                       evaluate: bool = False, fast_math: bool = False):
    """The per-colour VBD kernel for blocks of ``particles`` x ``lanes`` threads: launch it with
    ``wp.launch_tiled(kernel, dim=[ceil(count / particles) + heavy blocks],
    block_dim=particles * lanes)`` (on the CPU, where a block is one thread: 1 x 1). One kernel
    per (particles, lanes, gather, register cap, evaluate, fast math), compiled in its own module
    and cached.

    Args:
        particles: particles per block.
        lanes: threads per particle.
        fused: the gather (``fused_share`` or ``split_share``; None: fused from ``FUSED_LANES``
            lanes per particle).
        max_registers: > 0 caps the CUDA registers per thread (``__maxnreg__``; the compiler
            spills what does not fit): more resident warps for batches.
        evaluate: write each particle's residual force ``-dG/dx_i`` at ``x`` to ``snap_out`` and
            leave ``x`` alone (``finish_particle``), so one launch over all colours at once
            (``color_start`` 0, ``count`` all particles, no heavy blocks) evaluates the whole
            residual at one configuration (``snap`` must hold ``x``); the coarse-level correction
            (``sim.cloth.coarse``) restricts it.
        fast_math: compile the CUDA kernel with fast math.
    """
    if fused is None:
        fused = lanes >= FUSED_LANES
    key = (int(particles), int(lanes), bool(fused), int(max_registers), bool(evaluate), bool(fast_math))
    if key not in _SOLVE_KERNELS:
        _SOLVE_KERNELS[key] = _make_solve_kernel(*key)
    return _SOLVE_KERNELS[key]


def _make_solve_kernel(particles: int, lanes: int, fused: bool, max_registers: int, evaluate: bool,
                       fast_math: bool):
    """Compile the kernel ``solve_color_kernel`` describes."""
    P, L, FUSED, EVAL = int(particles), int(lanes), int(fused), int(evaluate)

    def solve(
        count: int,
        color: int,
        light_blocks: int,
        color_start: int,
        k_contact: float,
        eps_u: float,
        h: float,
        air_damping: float,
        a: SolveArrays,
        snap: wp.array(dtype=wp.vec3),
        x_inout: wp.array(dtype=wp.vec3),
        snap_out: wp.array(dtype=wp.vec3),
    ):
        sc = contact_view(a.contact)
        block, thread = wp.tid()
        local = thread // wp.static(L)
        lane = thread - local * wp.static(L)
        share = lane
        stride = wp.static(L)
        i = int(-1)
        heavy_block = block >= light_blocks
        if heavy_block:
            i = heavy_particle(sc, block, light_blocks, color, color_start)
            if i < 0:
                return
            share = thread
            stride = wp.static(P * L)
        else:
            i = light_particle(a, sc, block, local, wp.static(P), count, color, color_start, wp.static(EVAL))
        # the solving thread's particle inputs, loaded first so their loads overlap the gather's
        step = ParticleStep()
        solver = lane == 0 and i >= 0
        if heavy_block:
            solver = thread == 0
        if solver:
            step = load_particle_step(i, a, x_inout)
        f = wp.vec3(0.0)
        H = wp.mat33(0.0)
        if i >= 0:
            if wp.static(FUSED):
                f, H = fused_share(i, share, stride, a, sc, eps_u, 1.0 / h, x_inout, snap)
            else:
                f, H = split_share(i, share, stride, a, sc, eps_u, 1.0 / h, x_inout, snap)
        # every thread of the block reaches the reductions
        shape = (wp.static(P), wp.static(L))
        f_sum = wp.tile_sum(wp.tile_reshape(wp.tile(f, preserve_type=True), shape=shape), axis=1)
        H_sum = wp.tile_sum(wp.tile_reshape(wp.tile(H, preserve_type=True), shape=shape), axis=1)
        f = wp.tile_extract(f_sum, local)
        H = wp.tile_extract(H_sum, local)
        if heavy_block:  # the same for the whole block: the P partial sums are all vertex i's
            for k in range(1, wp.static(P)):
                f = f + wp.tile_extract(f_sum, (local + k) % wp.static(P))
                H = H + wp.tile_extract(H_sum, (local + k) % wp.static(P))
        if solver:
            finish_particle(step, f, H, k_contact, eps_u, h, air_damping, wp.static(EVAL), i, x_inout,
                            snap_out)

    regs = f"_r{int(max_registers)}" if max_registers > 0 else ""
    name = f"solve_color_p{P}_l{L}{'_fused' if FUSED else ''}{regs}{'_eval' if EVAL else ''}"
    name += "_fm" if fast_math else ""
    solve.__name__ = solve.__qualname__ = name
    options = {"cuda_max_registers": int(max_registers)} if max_registers > 0 else {}
    if fast_math:
        options["module_options"] = {"fast_math": True}
    return wp.kernel(solve, enable_backward=False, module="unique", **options)
