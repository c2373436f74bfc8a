"""Warp kernels of a Vertex Block Descent substep (Chen et al. 2024, "Vertex Block Descent",
SIGGRAPH) around the sweeps (``sim.cloth.solve_kernel``: the sweeps' per-particle solve).
Inputs first, outputs with an ``_out`` suffix, arrays read and written in place with ``_inout``.
Every kernel is a per-particle gather: no atomics, so results are deterministic on every device.

One substep of length ``h`` minimises the incremental potential (Chen et al. 2024, Eq. 1)
    G(x) = sum_i m_i/(2 h^2) |x_i - y_i|^2 + E_membrane(x) + E_bending(x) + E_contact(x)
         + E_damping + E_friction,    y = x_prev + h v + h^2 g,
by per-vertex Newton steps ``dx_i = H_i^-1 f_i`` (Eq. 9-10) swept colour by colour.
"""

from __future__ import annotations

import warp as wp

from sim.cloth.energies import dihedral_angle, green_strain
from sim.cloth.self_contact import SelfContactData, has_pairs

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
