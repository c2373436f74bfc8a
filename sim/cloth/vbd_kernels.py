"""Warp kernels of a Vertex Block Descent substep (Chen et al. 2024, "Vertex Block Descent",
SIGGRAPH) around the sweeps, and the per-particle Newton step they share with the coarse level.
Inputs first, outputs with an ``_out`` suffix, arrays read and written in place with ``_inout``.
Every kernel is a per-particle gather: no atomics, so results are deterministic on every device.

One substep of length ``h`` minimises the incremental potential (Chen et al. 2024, Eq. 1)
    G(x) = sum_i m_i/(2 h^2) |x_i - y_i|^2 + E_membrane(x) + E_bending(x) + E_contact(x)
         + E_damping + E_friction,    y = x_prev + h v + h^2 g,
by per-vertex Newton steps ``dx_i = H_i^-1 f_i`` (Eq. 9-10) swept colour by colour
(``sim.cloth.solve_kernel``).
"""

from __future__ import annotations

import warp as wp

from sim.cloth.energies import dihedral_angle, green_strain
from sim.cloth.self_contact import SelfContactData, apply_bound, has_pairs
from sim.cloth.spans import load_float, load_int, load_vec3

PINNED = wp.constant(1)


@wp.kernel
def forward_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    a: wp.array(dtype=wp.vec3),
    flags: wp.array(dtype=wp.int32),
    pin_targets: wp.array(dtype=wp.vec3),
    gravity: wp.vec3,
    h: float,
    pin_alpha: float,
    remember: int,
    x_step_start_inout: wp.array(dtype=wp.vec3),
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
    sweep's snapshot (``solve_kernel.solve_color_kernel``).
    """
    i = wp.tid()
    xi = x[i]
    if remember != 0:
        x_prev_out[i] = xi
        x_step_start_inout[i] = xi
    if flags[i] == PINNED:
        s = xi
        if remember == 0:
            s = x_step_start_inout[i]
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


@wp.kernel
def velocity_kernel(
    x: wp.array(dtype=wp.vec3),
    inv_h: float,
    sc: SelfContactData,
    x_prev_inout: wp.array(dtype=wp.vec3),
    v_inout: wp.array(dtype=wp.vec3),
    a_out: wp.array(dtype=wp.vec3),
    pair_flags_out: wp.array(dtype=wp.int32),
):
    """Implicit-Euler velocity ``v = (x - x_prev) / h``; acceleration of the substep (for the
    next initial guess); ``x`` becomes ``x_prev``, the next substep's start (``forward_kernel``
    need not write it, so the next substep's detection and body contact, which read it, can
    start beside its forward step). Where ``pair_flags_out`` is not empty: whether each
    particle has pairs in ``sc`` (the substep's pairs, for the next substep's early coarse
    diagonal, ``CoarseConfig.early``)."""
    i = wp.tid()
    if pair_flags_out.shape[0] > 0:
        pair_flags_out[i] = wp.where(has_pairs(sc, i), 1, 0)
    xi = x[i]
    v_new = (xi - x_prev_inout[i]) * inv_h
    a_out[i] = (v_new - v_inout[i]) * inv_h
    v_inout[i] = v_new
    x_prev_inout[i] = xi


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
    bound where the self-contact data holds bounds (``use_bounds``); ``body_wins``: not where the
    body presses the particle."""
    bounded = sc.enabled != 0 and sc.use_bounds != 0
    x_ref = p.x_prev
    if p.contact_active != 0:
        x_ref = p.x_prev + h * p.contact_body_velocity
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
