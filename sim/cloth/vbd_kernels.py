"""Warp kernels of the Vertex Block Descent cloth solver (Chen et al. 2024, "Vertex Block
Descent", SIGGRAPH). Inputs first, outputs with an ``_out`` suffix; ``x_inout`` is read and
written in place (Gauss-Seidel). Every kernel is a per-particle gather: no atomics, so results
are deterministic on every device.

One substep of length ``h`` minimises the incremental potential (Chen et al. 2024, Eq. 1)
    G(x) = sum_i m_i/(2 h^2) |x_i - y_i|^2 + E_membrane(x) + E_bending(x) + E_contact(x)
         + E_damping + E_friction,    y = x_prev + h v + h^2 g,
by per-vertex Newton steps ``dx_i = H_i^-1 f_i`` (Eq. 9-10) swept colour by colour.
"""

from __future__ import annotations

import warp as wp

from sim.cloth.energies import (
    bending_damped_vertex_force_hessian,
    corotated_damped_vertex_force_hessian,
    dihedral_angle,
    green_strain,
    stvk_damped_vertex_force_hessian,
)
from sim.cloth.self_contact import (
    SelfContactData,
    SolveContactArrays,
    apply_bound,
    contact_view,
    has_pairs,
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

PINNED = wp.constant(1)
MEMBRANE_STVK = wp.constant(0)
MEMBRANE_COROTATED = wp.constant(1)


@wp.kernel
def forward_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    a: wp.array(dtype=wp.vec3),
    flags: wp.array(dtype=wp.int32),
    x_step_start: wp.array(dtype=wp.vec3),
    pin_targets: wp.array(dtype=wp.vec3),
    gravity: wp.vec3,
    h: float,
    pin_alpha: float,
    remember: int,
    x_prev_out: wp.array(dtype=wp.vec3),
    y_out: wp.array(dtype=wp.vec3),
    x_out: wp.array(dtype=wp.vec3),
    snap_out: wp.array(dtype=wp.vec3),
):
    """Start a substep: remember ``x`` (``remember``, the step's first substep: as ``x_prev`` and
    as the step's start ``x_step_start``; the later substeps have ``x_prev`` from
    ``velocity_kernel``), inertial target ``y = x + h v + h^2 g`` (Eq. 2) and the
    initial guess ``x + h v + h^2 a_g g/|g|`` with ``a_g`` the previous substep's acceleration
    along gravity clamped to [0, |g|] (Chen et al. 2024, Sec. 3.7, adaptive initialisation).

    With a truncated iteration count the inertial guess ``y`` biases resting cloth (the fixed
    point of a few sweeps started from ``y`` is not the equilibrium); the adaptive guess is
    ``x`` at rest and ``y`` in free fall. Pinned particles move linearly from their
    step-start position to the pin target. The guess also goes to ``snap_out``, the first
    sweep's snapshot (``solve_color_kernel``).
    """
    i = wp.tid()
    xi = x[i]
    if remember != 0:
        x_prev_out[i] = xi
        x_step_start[i] = xi
    if flags[i] == PINNED:
        s = xi
        if remember == 0:
            s = x_step_start[i]
        p = s + pin_alpha * (pin_targets[i] - s)
        y_out[i] = p
        x_out[i] = p
        snap_out[i] = p
    else:
        vi = v[i]
        y_out[i] = xi + h * vi + (h * h) * gravity
        g_len = wp.length(gravity)
        guess = xi + h * vi
        if g_len > 0.0:
            g_dir = gravity / g_len
            a_g = wp.clamp(wp.dot(a[i], g_dir), 0.0, g_len)
            guess = guess + (h * h * a_g) * g_dir
        x_out[i] = guess
        snap_out[i] = guess


@wp.kernel
def body_contact_kernel(
    x: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    instance_body: wp.array(dtype=wp.uint64),
    margin: float,
    contact_point_out: wp.array(dtype=wp.vec3),
    contact_normal_out: wp.array(dtype=wp.vec3),
    contact_body_velocity_out: wp.array(dtype=wp.vec3),
    contact_active_out: wp.array(dtype=wp.int32),
):
    """Closest body point within ``margin`` of each particle; the contact plane (point, outward
    normal) is then held fixed for the substep's iterations. The sign test (winding / normal)
    tells inside from outside, so a particle the body has moved past by less than its
    half-thickness is still pushed out on the correct side."""
    i = wp.tid()
    contact_active_out[i] = 0
    mesh = instance_body[particle_instance[i]]
    if mesh == wp.uint64(0):
        return
    xi = x[i]
    q = wp.mesh_query_point_sign_normal(mesh, xi, margin)
    if not q.result:
        return
    p = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
    d = xi - p
    dl = wp.length(d)
    n = wp.mesh_eval_face_normal(mesh, q.face)
    if dl > 1.0e-6:
        n = d * (q.sign / dl)
    contact_point_out[i] = p
    contact_normal_out[i] = n
    contact_body_velocity_out[i] = wp.mesh_eval_velocity(mesh, q.face, q.u, q.v)
    contact_active_out[i] = 1


@wp.kernel
def previous_deformation_kernel(
    x_prev: wp.array(dtype=wp.vec3),
    tri_indices: wp.array(dtype=wp.vec3i),
    tri_dm_inv: wp.array(dtype=wp.mat22),
    edge_indices: wp.array(dtype=wp.vec4i),
    tri_count: int,
    tri_strain_out: wp.array(dtype=wp.vec3),
    edge_angle_out: wp.array(dtype=float),
):
    """Green strain of every triangle (threads < tri_count) and dihedral angle of every hinge
    (the rest) at the substep start: the reference of the strain-rate damping."""
    k = wp.tid()
    if k < tri_count:
        t = tri_indices[k]
        tri_strain_out[k] = green_strain(x_prev[t[0]], x_prev[t[1]], x_prev[t[2]], tri_dm_inv[k])
    else:
        e = k - tri_count
        q = edge_indices[e]
        edge_angle_out[e] = dihedral_angle(x_prev[q[0]], x_prev[q[1]], x_prev[q[2]], x_prev[q[3]])


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


@wp.func
def membrane_force_hessian(membrane: int, xa: wp.vec3, xb: wp.vec3, xc: wp.vec3, dm_inv: wp.mat22,
                           area: float, mu: float, lam: float, strain_prev: wp.vec3, kd_over_h: float,
                           local: int):
    """The damped membrane force and Hessian block of corner ``local`` of one triangle."""
    if membrane == MEMBRANE_COROTATED:
        return corotated_damped_vertex_force_hessian(xa, xb, xc, dm_inv, area, mu, lam, strain_prev,
                                                     kd_over_h, local)
    return stvk_damped_vertex_force_hessian(xa, xb, xc, dm_inv, area, mu, lam, strain_prev, kd_over_h, local)


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
def vertex_share_force_hessian(
    i: int,
    lane: int,
    stride: int,
    membrane: int,
    x_prev: wp.array(dtype=wp.vec3),
    tri_indices: wp.array(dtype=wp.vec3i),
    tri_dm_inv: wp.array(dtype=wp.mat22),
    tri_area: wp.array(dtype=float),
    tri_mu: wp.array(dtype=float),
    tri_lam: wp.array(dtype=float),
    tri_damping: wp.array(dtype=float),
    tri_strain_prev: wp.array(dtype=wp.vec3),
    edge_indices: wp.array(dtype=wp.vec4i),
    edge_rest_angle: wp.array(dtype=float),
    edge_stiffness: wp.array(dtype=float),
    edge_damping: wp.array(dtype=float),
    edge_angle_prev: wp.array(dtype=float),
    vertex_tri_offsets: wp.array(dtype=wp.int32),
    vertex_tri_ids: wp.array(dtype=wp.int32),
    vertex_tri_local: wp.array(dtype=wp.int32),
    vertex_edge_offsets: wp.array(dtype=wp.int32),
    vertex_edge_ids: wp.array(dtype=wp.int32),
    vertex_edge_local: wp.array(dtype=wp.int32),
    eps_u: float,
    inv_h: float,
    sc: SelfContactData,
    fused: int,
    x: wp.array(dtype=wp.vec3),
    snap: wp.array(dtype=wp.vec3),
):
    """This lane's share (items ``lane, lane + stride, ...``) of the membrane, bending and
    self-contact force on particle ``i`` and their Hessian blocks, with strain-rate damping
    against the substep-start deformation.

    One loop takes item ``r`` of each kind together: triangle ``r``, hinge ``r`` and gather
    record ``r`` of the vertex. Every load of the three is issued before any of them is used
    (an item a kind does not have reads a valid placeholder: entry 0), so the lane waits for
    one chain of dependent loads (item id, its vertices, their positions) instead of one per
    kind, one kind after the other (session 14, a 5k t-shirt's ~1000 particles per colour: the
    solve of a run frame fell from 23.8 to 20.7 ms). The arrays must not be empty.

    With ``fused`` 0 the kinds are gathered one after the other, each lane loading only items
    it has: where the GPU is full (batches, 4 lanes per particle) the latency is hidden by other
    threads, and the fused loop's placeholder loads cost throughput (session 14: batch 64 ran
    at 339 garment-frames/s fused against 387 split)."""
    f = wp.vec3(0.0)
    H = wp.mat33(0.0)
    if fused == 0:
        for k in range(load_int(vertex_tri_offsets, i) + lane, load_int(vertex_tri_offsets, i + 1), stride):
            t = load_int(vertex_tri_ids, k)
            tri = load_vec3i(tri_indices, t)
            t_packed = load_int(vertex_tri_local, k)
            ta, tb, tc = read_triangle(x, snap, tri, t_packed >> 2)
            fe, he = membrane_force_hessian(membrane, ta, tb, tc, load_mat22(tri_dm_inv, t),
                                            load_float(tri_area, t), load_float(tri_mu, t),
                                            load_float(tri_lam, t), load_vec3(tri_strain_prev, t),
                                            load_float(tri_damping, t) * inv_h,
                                            t_packed & 3)
            f = f + fe
            H = H + he * jacobi_scale(t_packed)
        for k in range(load_int(vertex_edge_offsets, i) + lane, load_int(vertex_edge_offsets, i + 1), stride):
            e = load_int(vertex_edge_ids, k)
            q = load_vec4i(edge_indices, e)
            packed = load_int(vertex_edge_local, k)
            h0, h1, h2, h3 = read_positions(x, snap, q, packed >> 2)
            fb, hb = bending_damped_vertex_force_hessian(h0, h1, h2, h3, load_float(edge_rest_angle, e),
                                                         load_float(edge_stiffness, e),
                                                         load_float(edge_angle_prev, e),
                                                         load_float(edge_damping, e) * inv_h, packed & 3)
            f = f + fb
            H = H + hb
        if sc.enabled != 0:
            fs, hs = self_contact_force_hessian(i, lane, stride, x, snap, x_prev, tri_indices,
                                                vertex_tri_offsets, vertex_tri_ids, vertex_tri_local, sc,
                                                eps_u)
            f = f + fs
            H = H + hs
        return f, H
    tri_begin = load_int(vertex_tri_offsets, i)
    tri_n = load_int(vertex_tri_offsets, i + 1) - tri_begin
    edge_begin = load_int(vertex_edge_offsets, i)
    edge_n = load_int(vertex_edge_offsets, i + 1) - edge_begin
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
    for r in range(lane, wp.max(wp.max(tri_n, edge_n), rec_n), stride):
        kt = wp.where(r < tri_n, tri_begin + r, 0)
        ke = wp.where(r < edge_n, edge_begin + r, 0)
        kr = wp.where(r < rec_n, rec_begin + r, 0)
        t = load_int(vertex_tri_ids, kt)
        t_local = load_int(vertex_tri_local, kt)
        e = load_int(vertex_edge_ids, ke)
        e_packed = load_int(vertex_edge_local, ke)
        q = load_vec4i(sc.pair_verts, kr)
        packed = load_int(sc.pair_role, kr)
        ref = load_vec3(sc.pair_ref, kr)
        tri = load_vec3i(tri_indices, t)
        dm_inv = load_mat22(tri_dm_inv, t)
        area = load_float(tri_area, t)
        mu = load_float(tri_mu, t)
        lam = load_float(tri_lam, t)
        t_damp = load_float(tri_damping, t)
        strain_prev = load_vec3(tri_strain_prev, t)
        hinge = load_vec4i(edge_indices, e)
        rest_angle = load_float(edge_rest_angle, e)
        k_edge = load_float(edge_stiffness, e)
        e_damp = load_float(edge_damping, e)
        angle_prev = load_float(edge_angle_prev, e)
        xa, xb, xc = read_triangle(x, snap, tri, t_local >> 2)
        h0, h1, h2, h3 = read_positions(x, snap, hinge, e_packed >> 2)
        y0, y1, y2, y3 = read_positions(x, snap, q, packed >> 4)
        z0 = load_vec3(x_prev, q[0])
        z1 = load_vec3(x_prev, q[1])
        z2 = load_vec3(x_prev, q[2])
        z3 = load_vec3(x_prev, q[3])
        if r < tri_n:
            fe, he = membrane_force_hessian(membrane, xa, xb, xc, dm_inv, area, mu, lam, strain_prev,
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
    if lists:
        fs, hs = self_contact_list_force_hessian(i, lane, stride, x, snap, x_prev, tri_indices,
                                                 vertex_tri_offsets, vertex_tri_ids, vertex_tri_local, sc,
                                                 eps_u)
        f = f + fs
        H = H + hs
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
    bound: float
    reference: wp.vec3


@wp.func
def load_particle_step(
    i: int,
    x_prev: wp.array(dtype=wp.vec3),
    y: wp.array(dtype=wp.vec3),
    mass: wp.array(dtype=float),
    flags: wp.array(dtype=wp.int32),
    particle_instance: wp.array(dtype=wp.int32),
    contact_point: wp.array(dtype=wp.vec3),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_body_velocity: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    instance_thickness: wp.array(dtype=float),
    instance_friction: wp.array(dtype=float),
    sc: SelfContactData,
    x: wp.array(dtype=wp.vec3),
):
    p = ParticleStep()
    inst = load_int(particle_instance, i)
    p.x = load_vec3(x, i)
    p.x_prev = load_vec3(x_prev, i)
    p.y = load_vec3(y, i)
    p.mass = load_float(mass, i)
    p.flags = load_int(flags, i)
    p.contact_active = load_int(contact_active, i)
    p.contact_point = load_vec3(contact_point, i)
    p.contact_normal = load_vec3(contact_normal, i)
    p.contact_body_velocity = load_vec3(contact_body_velocity, i)
    p.thickness = load_float(instance_thickness, inst)
    p.friction = load_float(instance_friction, inst)
    p.bound = float(0.0)
    p.reference = wp.vec3(0.0)
    if sc.enabled != 0 and sc.use_bounds != 0:
        p.bound = sc.bound[i]
        p.reference = sc.reference[inst]
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
def bound_step(p: ParticleStep, x_new: wp.vec3, h: float, sc: SelfContactData, body_wins: int) -> wp.vec3:
    """``x_new``, a particle's move from ``p.x``, truncated to its self-contact displacement
    bound (``sim.cloth.self_contact``: the cloth stays intersection-free) where the bound holds it;
    ``body_wins`` (the Newton step): not where the body presses the particle. The coarse
    correction's prolongation bounds every move: it is no push of the body."""
    bounded = sc.enabled != 0 and sc.use_bounds != 0
    # the bound limits motion relative to the body surface nearby (the skin's displacement over
    # the substep), so layers riding on a moving limb together are not held back; elsewhere
    # relative to the instance's reference velocity (the frame the detection searched in)
    x_ref = p.x_prev
    if p.contact_active != 0:
        x_ref = p.x_prev + h * p.contact_body_velocity
        # a particle the body is pushing is not held by the self-contact bound: where the body
        # squeezes cloth layers together (armpits, between the legs) the body wins
        if body_wins != 0 and wp.dot(p.contact_normal, p.x - p.contact_point) < p.thickness + sc.radius:
            bounded = False
    elif bounded:
        x_ref = p.x_prev + h * p.reference
    if bounded:
        return apply_bound(x_new, x_ref, p.bound)
    return x_new


@wp.func
def vertex_newton_step(
    p: ParticleStep,
    f: wp.vec3,
    H: wp.mat33,
    k_contact: float,
    eps_u: float,
    h: float,
    air_damping: float,
    sc: SelfContactData,
) -> wp.vec3:
    """Take the Newton step ``x += H^-1 f`` of a particle (Chen et al. 2024, Eq. 9-10) with its
    gathered ``f``, ``H`` completed by ``vertex_system``: its new position."""
    xi = p.x
    f, H = vertex_system(p, f, H, k_contact, eps_u, h, air_damping)
    # the block is symmetric positive definite (inertia + PSD terms); guard tiny determinants
    x_new = xi
    if wp.abs(wp.determinant(H)) > 1.0e-20:
        x_new = xi + wp.inverse(H) * f
    return bound_step(p, x_new, h, sc, 1)


@wp.struct
class SolveArrays:
    """Every array the solve kernel reads besides ``x``/``snap``/``snap_out``, as ``Span``s
    (``sim.cloth.spans``: ~100 array arguments filled the constant cache). ``SolverVBD`` builds
    it (``solve_arrays``) and keeps it while the arrays live."""

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


_SOLVE_KERNELS: dict = {}
FUSED_LANES = 8  # lanes per particle from which the solve gathers with the fused loop


def solve_color_kernel(particles: int, lanes: int, fused: bool | None = None, max_registers: int = 0,
                       evaluate: bool = False, fast_math: bool = False):
    """The per-colour VBD kernel (Chen et al. 2024, Alg. 1) for blocks of ``particles`` x
    ``lanes`` threads: launch it with ``wp.launch_tiled(kernel, dim=[ceil(count / particles)],
    block_dim=particles * lanes)`` (on the CPU, where a block is one thread: 1 x 1).

    The ``lanes`` threads of a particle each sum a share of its elements and contacts; one
    block reduction (``tile_sum`` over the lanes axis of a particles x lanes tile) gives every
    particle its 3x3 system, which its lane 0 solves. Lanes turn the long serial gather of a
    particle (a latency chain of dependent loads) into short ones; several particles per block
    fill the 32-thread warps and the SM's block slots (a 16-thread block leaves half of every
    warp idle and caps occupancy at a quarter). One kernel per (particles, lanes, gather, register
    cap), compiled in its own module and cached. ``fused``: the gather of
    ``vertex_share_force_hessian`` (None: fused from ``FUSED_LANES`` lanes per particle).
    ``max_registers`` > 0 caps the CUDA registers per thread (``__maxnreg__``; the compiler
    spills what does not fit): more resident warps for batches, where the uncapped 4-lane
    kernel's 146 registers allow three 128-thread blocks per SM (H100, session 19).

    Same-colour neighbours (session 15): the colouring separates the vertices of every
    triangle, but a bending hinge's two opposite vertices may share a colour
    (``vertex_edge_local`` bits 2-5), and a self-contact pair found at run time can join any two
    vertices (``pair_role`` bits 4-7). A thread reading such a neighbour's ``x`` while the
    neighbour's thread writes it made CUDA runs timing-dependent, so these neighbours are read
    from ``snap``, the positions at the start of the sweep (a Jacobi step for that coupling);
    every solved particle writes its new position to ``snap_out``, the next sweep's snapshot
    (the solver alternates the two). Neighbours of other colours are read from ``x``
    (Gauss-Seidel). The step does not depend on the order of the threads: every layout, gather
    and device takes the same step up to round-off.

    ``evaluate``: the kernel instead writes each particle's residual force ``-dG/dx_i`` at ``x``
    (``vertex_system``; zero for pinned particles) to ``snap_out`` and leaves ``x`` alone, so
    one launch over all colours at once (``color_start`` 0, ``count`` all particles, no heavy
    blocks: light blocks take the heavy particles too) evaluates the whole residual at one
    configuration (``snap`` must hold ``x``). The coarse-level correction (``sim.cloth.coarse``)
    restricts it."""
    if fused is None:
        fused = lanes >= FUSED_LANES
    key = (int(particles), int(lanes), bool(fused), int(max_registers), bool(evaluate), bool(fast_math))
    if key in _SOLVE_KERNELS:
        return _SOLVE_KERNELS[key]
    P, L, FUSED, EVAL = int(particles), int(lanes), int(fused), int(evaluate)

    def solve(
        count: int,
        color: int,
        light_blocks: int,
        membrane: int,
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
        color_vertices = ints(a.color_vertices)
        x_prev = vec3s(a.x_prev)
        y = vec3s(a.y)
        mass = floats(a.mass)
        flags = ints(a.flags)
        particle_instance = ints(a.particle_instance)
        tri_indices = vec3is(a.tri_indices)
        tri_dm_inv = mat22s(a.tri_dm_inv)
        tri_area = floats(a.tri_area)
        tri_mu = floats(a.tri_mu)
        tri_lam = floats(a.tri_lam)
        tri_damping = floats(a.tri_damping)
        tri_strain_prev = vec3s(a.tri_strain_prev)
        edge_indices = vec4is(a.edge_indices)
        edge_rest_angle = floats(a.edge_rest_angle)
        edge_stiffness = floats(a.edge_stiffness)
        edge_damping = floats(a.edge_damping)
        edge_angle_prev = floats(a.edge_angle_prev)
        vertex_tri_offsets = ints(a.vertex_tri_offsets)
        vertex_tri_ids = ints(a.vertex_tri_ids)
        vertex_tri_local = ints(a.vertex_tri_local)
        vertex_edge_offsets = ints(a.vertex_edge_offsets)
        vertex_edge_ids = ints(a.vertex_edge_ids)
        vertex_edge_local = ints(a.vertex_edge_local)
        contact_point = vec3s(a.contact_point)
        contact_normal = vec3s(a.contact_normal)
        contact_body_velocity = vec3s(a.contact_body_velocity)
        contact_active = ints(a.contact_active)
        instance_thickness = floats(a.instance_thickness)
        instance_friction = floats(a.instance_friction)
        sc = contact_view(a.contact)
        block, thread = wp.tid()
        local = thread // wp.static(L)
        lane = thread - local * wp.static(L)
        share = lane
        stride = wp.static(L)
        i = int(-1)
        heavy_block = block >= light_blocks
        if heavy_block:
            # one heavy vertex per block, its items shared by all the block's threads; a block
            # without one leaves as a whole (no thread waits at the reductions)
            hb = block - light_blocks
            nh = sc.heavy_count[color]
            if nh > sc.heavy_cap or hb >= nh:
                return
            i = sc.heavy_list[color_start + hb]
            share = thread
            stride = wp.static(P * L)
        else:
            slot = block * wp.static(P) + local
            if slot < count:
                i = load_int(color_vertices, color_start + slot)
                # solved by a heavy block (when its colour's heavy vertices all have one); an
                # evaluation has no heavy blocks: it is launched once over all colours
                if wp.static(EVAL == 0):
                    if sc.heavy_cap > 0:
                        if sc.heavy[i] != 0 and sc.heavy_count[color] <= sc.heavy_cap:
                            i = -1
        # the solving thread's particle inputs, loaded first so their loads overlap the gather's
        step = ParticleStep()
        solver = lane == 0 and i >= 0
        if heavy_block:
            solver = thread == 0
        if solver:
            step = load_particle_step(i, x_prev, y, mass, flags, particle_instance, contact_point,
                                      contact_normal, contact_body_velocity, contact_active,
                                      instance_thickness, instance_friction, sc, x_inout)
        f = wp.vec3(0.0)
        H = wp.mat33(0.0)
        if i >= 0:
            f, H = vertex_share_force_hessian(
                i, share, stride, membrane, x_prev, tri_indices, tri_dm_inv, tri_area, tri_mu, tri_lam,
                tri_damping, tri_strain_prev, edge_indices, edge_rest_angle, edge_stiffness, edge_damping,
                edge_angle_prev, vertex_tri_offsets, vertex_tri_ids, vertex_tri_local, vertex_edge_offsets,
                vertex_edge_ids, vertex_edge_local, eps_u, 1.0 / h, sc, wp.static(FUSED), x_inout, snap)
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
        if not solver:
            return
        if wp.static(EVAL):
            # the residual force -dG/dx_i at x (zero for pinned particles); x is not written
            r = wp.vec3(0.0)
            if step.flags != PINNED:
                r, H = vertex_system(step, f, H, k_contact, eps_u, h, air_damping)
            snap_out[i] = r
        else:
            x_new = step.x
            if step.flags != PINNED:
                x_new = vertex_newton_step(step, f, H, k_contact, eps_u, h, air_damping, sc)
                x_inout[i] = x_new
            snap_out[i] = x_new

    regs = f"_r{int(max_registers)}" if max_registers > 0 else ""
    name = f"solve_color_p{P}_l{L}{'_fused' if FUSED else ''}{regs}{'_eval' if EVAL else ''}"
    name += "_fm" if fast_math else ""
    solve.__name__ = solve.__qualname__ = name
    options = {"cuda_max_registers": int(max_registers)} if max_registers > 0 else {}
    if fast_math:
        options["module_options"] = {"fast_math": True}
    kernel = wp.kernel(solve, enable_backward=False, module="unique", **options)
    _SOLVE_KERNELS[key] = kernel
    return kernel


@wp.kernel
def chebyshev_kernel(
    omega: float,
    flags: wp.array(dtype=wp.int32),
    x_inout: wp.array(dtype=wp.vec3),
    prev1_inout: wp.array(dtype=wp.vec3),
    prev2_inout: wp.array(dtype=wp.vec3),
    snap_out: wp.array(dtype=wp.vec3),
):
    """Chebyshev semi-iterative acceleration of the sweeps (Wang 2015; Chen et al. 2024,
    Sec. 3.8): ``x_k = x_{k-2} + omega_k (xbar_k - x_{k-2})`` with ``xbar_k`` the sweep's
    result; ``prev1``/``prev2`` hold ``x_{k-1}``/``x_{k-2}`` and are shifted. Pinned particles
    keep the sweep's (prescribed) position. The result also goes to ``snap_out`` (the next
    sweep's snapshot, ``solve_color_kernel``)."""
    i = wp.tid()
    xb = x_inout[i]
    p1 = prev1_inout[i]
    p2 = prev2_inout[i]
    xa = xb
    if flags[i] != PINNED:
        xa = p2 + omega * (xb - p2)
    prev2_inout[i] = p1
    prev1_inout[i] = xa
    x_inout[i] = xa
    snap_out[i] = xa


@wp.kernel
def strain_limit_kernel(
    limit: float,
    x_in: wp.array(dtype=wp.vec3),
    rest: wp.array(dtype=wp.vec3),
    mass: wp.array(dtype=float),
    flags: wp.array(dtype=wp.int32),
    edges: wp.array(dtype=wp.vec2i),
    vertex_edge_offsets: wp.array(dtype=wp.int32),
    vertex_edge_ids: wp.array(dtype=wp.int32),
    vertex_edge_local: wp.array(dtype=wp.int32),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    x_out: wp.array(dtype=wp.vec3),
):
    """One Jacobi pass of edge strain limiting (Provot 1995): every mesh edge stretched past
    ``(1 + limit)`` times its rest length is shortened to it, each end moving its inverse-mass
    share along the edge (pinned ends do not move); a particle's corrections from its edges are
    averaged. A particle in body contact keeps only the part of its correction that does not
    point into the body (its contact normal): the body carries it. Reads ``x_in``, writes
    ``x_out`` (the passes ping-pong), so the result does not depend on thread order."""
    i = wp.tid()
    xi = x_in[i]
    if flags[i] == PINNED:
        x_out[i] = xi
        return
    wi = 1.0 / mass[i]
    ri = rest[i]
    corr = wp.vec3(0.0)
    count = int(0)
    for k in range(vertex_edge_offsets[i], vertex_edge_offsets[i + 1]):
        e = edges[vertex_edge_ids[k]]
        j = e[1 - vertex_edge_local[k]]
        d = x_in[j] - xi
        length = wp.length(d)
        l_max = (1.0 + limit) * wp.length(rest[j] - ri)
        if length > l_max:
            wj = 0.0
            if flags[j] != PINNED:
                wj = 1.0 / mass[j]
            corr = corr + d * ((length - l_max) / length * wi / (wi + wj))
            count += 1
    if count > 0:
        corr = corr / float(count)
        if contact_active[i] != 0:
            n = contact_normal[i]
            corr = corr - wp.min(wp.dot(corr, n), 0.0) * n
        xi = xi + corr
    x_out[i] = xi


@wp.kernel
def velocity_kernel(
    x: wp.array(dtype=wp.vec3),
    x_prev: wp.array(dtype=wp.vec3),
    inv_h: float,
    sc: SelfContactData,
    v_inout: wp.array(dtype=wp.vec3),
    a_out: wp.array(dtype=wp.vec3),
    pair_flags_out: wp.array(dtype=wp.int32),
):
    """Implicit-Euler velocity ``v = (x - x_prev) / h``; acceleration of the substep (for the
    next initial guess); ``x`` becomes ``x_prev``, the next substep's start (``forward_kernel``
    need not write it, so the next substep's detection and body contact, which read it, can
    start beside its forward step). Where ``pair_flags_out`` is not empty: whether each
    particle has pairs in ``sc`` (the substep's pairs, for the next substep's early coarse
    diagonal, ``VBDConfig.coarse_early``)."""
    i = wp.tid()
    if pair_flags_out.shape[0] > 0:
        pair_flags_out[i] = wp.where(has_pairs(sc, i), 1, 0)
    xi = x[i]
    v_new = (xi - x_prev[i]) * inv_h
    a_out[i] = (v_new - v_inout[i]) * inv_h
    v_inout[i] = v_new
    x_prev[i] = xi
