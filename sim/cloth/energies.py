"""Cloth energies as Warp functions: the co-rotated linear membrane and dihedral-angle bending
the solver integrates, and the StVK membrane energy of the physics losses (``sim.losses``).

The solver's energies come with their per-vertex force and 3x3 Hessian block, the quantities a
Vertex Block Descent iteration needs (Chen et al. 2024, Eq. 9-10), with strain-rate damping.

Conventions:
    * Deformation gradient of a triangle ``F = Ds Dm^-1`` (3x2), Green strain
      ``G = (F^T F - I) / 2``; ``g_i`` is vertex ``i``'s row of the shape derivative
      (``F = sum_i x_i g_i^T``, ``shape_row``); rest area ``A`` [m^2].
    * Co-rotated linear membrane: ``F = R S``, ``E = A (mu |F - R|^2 + lam/2 (tr S - 2)^2)`` [J]
      (``corotated_energy``). It resists compression as stiffly as stretch, so compressed
      cloth buckles out of plane into wrinkles instead of shrinking in plane.
    * StVK membrane: ``psi = mu |G|_F^2 + lam/2 tr(G)^2`` [J/m^2], ``E = A psi`` [J] (Bonet &
      Wood, Nonlinear Continuum Mechanics, Eq. 6.27 restricted to 2D; ``stvk_energy``).
    * Bending (discrete shells, Grinspun et al. 2003; hinge gradient as in Bridson et al.
      2003 / Tamstorf & Grinspun 2013): ``E = k_e/2 (theta - theta_rest)^2`` per interior edge
      with ``k_e = k_b 3 |e|^2 / (A_1 + A_2)`` from the rest shape, ``k_b`` [N m]. This
      approximates ``k_b/2 * integral kappa^2 dA``.

Hinge layout: ``(o0, o1, a, b)``: ``a -> b`` is the shared edge in the orientation of the
triangle ``(a, b, o0)``; the other triangle is ``(b, a, o1)``. ``theta`` is 0 for a flat
hinge.
"""

from __future__ import annotations

import warp as wp


@wp.func
def shape_row(dm_inv: wp.mat22, local: int) -> wp.vec2:
    """Row ``g_i`` of the shape derivative for local vertex ``local`` (F = sum_i x_i g_i^T)."""
    g1 = wp.vec2(dm_inv[0, 0], dm_inv[0, 1])
    g2 = wp.vec2(dm_inv[1, 0], dm_inv[1, 1])
    if local == 1:
        return g1
    if local == 2:
        return g2
    return -(g1 + g2)


@wp.func
def deformation_gradient(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, dm_inv: wp.mat22):
    """The columns ``f0``, ``f1`` of a triangle's deformation gradient ``F = Ds Dm^-1`` (3x2)."""
    f0 = (x1 - x0) * dm_inv[0, 0] + (x2 - x0) * dm_inv[1, 0]
    f1 = (x1 - x0) * dm_inv[0, 1] + (x2 - x0) * dm_inv[1, 1]
    return f0, f1


@wp.func
def stvk_energy(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, dm_inv: wp.mat22, area: float, mu: float,
                lam: float) -> float:
    """StVK membrane energy [J] of one triangle (module docstring)."""
    f0 = (x1 - x0) * dm_inv[0, 0] + (x2 - x0) * dm_inv[1, 0]
    f1 = (x1 - x0) * dm_inv[0, 1] + (x2 - x0) * dm_inv[1, 1]
    g00 = 0.5 * (wp.dot(f0, f0) - 1.0)
    g11 = 0.5 * (wp.dot(f1, f1) - 1.0)
    g01 = 0.5 * wp.dot(f0, f1)
    tr = g00 + g11
    return area * (mu * (g00 * g00 + 2.0 * g01 * g01 + g11 * g11) + 0.5 * lam * tr * tr)


@wp.func
def green_strain(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, dm_inv: wp.mat22) -> wp.vec3:
    """Green-Lagrange strain ``G = (F^T F - I)/2`` of a triangle as ``(G00, G11, G01)``."""
    f0, f1 = deformation_gradient(x0, x1, x2, dm_inv)
    return wp.vec3(0.5 * (wp.dot(f0, f0) - 1.0), 0.5 * (wp.dot(f1, f1) - 1.0), 0.5 * wp.dot(f0, f1))


@wp.func
def viscous_stress_g(strain: wp.vec3, strain_prev: wp.vec3, g: wp.vec2, mu: float, lam: float,
                     kd_over_h: float) -> wp.vec2:
    """``S_v g`` of the strain-rate damping: viscous second Piola stress
    ``S_v = (k_d/h) C:(G - G_prev)`` (``C``: ``2 mu``, ``lam``; strains as (G00, G11, G01))."""
    d00 = strain[0] - strain_prev[0]
    d11 = strain[1] - strain_prev[1]
    d01 = strain[2] - strain_prev[2]
    dtr = d00 + d11
    v00 = kd_over_h * (2.0 * mu * d00 + lam * dtr)
    v11 = kd_over_h * (2.0 * mu * d11 + lam * dtr)
    v01 = kd_over_h * (2.0 * mu * d01)
    return wp.vec2(v00 * g[0] + v01 * g[1], v01 * g[0] + v11 * g[1])


@wp.func
def membrane_material_hessian(f0: wp.vec3, f1: wp.vec3, g: wp.vec2, mu: float, lam: float) -> wp.mat33:
    """Material (stress-free) part of the StVK vertex Hessian block per unit area."""
    fg = f0 * g[0] + f1 * g[1]
    gg = wp.dot(g, g)
    return (mu + lam) * wp.outer(fg, fg) + (mu * gg) * (wp.outer(f0, f0) + wp.outer(f1, f1))


@wp.func
def corotated_frame(f0: wp.vec3, f1: wp.vec3):
    """Rotation of the 3x2 deformation gradient ``F = [f0 f1] = R S``: returns the columns of
    ``R`` (3x2, orthonormal) and ``tr S = tr(R^T F)``.

    Robust to degenerate triangles (collapsed to a segment or a point): ``F`` is written in an
    orthonormal basis ``(u, w)`` of a plane containing both columns, oriented by the normal so
    that the 2x2 matrix has ``det >= 0``, and the 2x2 rotation comes from ``atan2`` (no inverse
    of ``S``).
    """
    # u along the longer column; w = n x u with n = f0 x f1 puts both columns at det >= 0
    ref = f0
    if wp.dot(f1, f1) > wp.dot(f0, f0):
        ref = f1
    lr = wp.length(ref)
    if lr < 1.0e-20:
        return wp.vec3(1.0, 0.0, 0.0), wp.vec3(0.0, 1.0, 0.0), 0.0
    u = ref / lr
    wn = wp.cross(wp.cross(f0, f1), u)
    wl = wp.length(wn)
    w = wp.vec3(0.0)
    if wl > 1.0e-9 * lr * lr:
        w = wn / wl
    else:  # f0 parallel to f1: any plane through u
        axis = wp.vec3(1.0, 0.0, 0.0)
        if wp.abs(u[0]) > 0.9:
            axis = wp.vec3(0.0, 1.0, 0.0)
        w = wp.normalize(wp.cross(wp.cross(u, axis), u))
    # 2x2 F in (u, w): columns f0, f1
    a00 = wp.dot(u, f0)
    a10 = wp.dot(w, f0)
    a01 = wp.dot(u, f1)
    a11 = wp.dot(w, f1)
    sx = a00 + a11
    sy = a10 - a01
    tr_s = wp.sqrt(sx * sx + sy * sy)
    c = 1.0
    s = 0.0
    if tr_s > 1.0e-20:
        c = sx / tr_s
        s = sy / tr_s
    r0 = c * u + s * w
    r1 = -s * u + c * w
    return r0, r1, tr_s


@wp.func
def corotated_energy(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, dm_inv: wp.mat22, area: float, mu: float,
                     lam: float) -> float:
    """Co-rotated linear membrane energy [J]: ``A (mu |F - R|^2 + lam/2 (tr S - 2)^2)``."""
    f0, f1 = deformation_gradient(x0, x1, x2, dm_inv)
    r0, r1, tr_s = corotated_frame(f0, f1)
    d0 = f0 - r0
    d1 = f1 - r1
    return area * (mu * (wp.dot(d0, d0) + wp.dot(d1, d1)) + 0.5 * lam * (tr_s - 2.0) * (tr_s - 2.0))


@wp.func
def corotated_damped_vertex_force_hessian(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, dm_inv: wp.mat22,
                                          area: float, mu: float, lam: float, strain_prev: wp.vec3,
                                          kd_over_h: float, local: int):
    """Co-rotated linear membrane (``corotated_energy``) force and Hessian block plus
    strain-rate damping.

    Damping is Rayleigh stiffness-proportional on the strain rate: the viscous second
    Piola-Kirchhoff stress is ``(k_d/h) C:(G - G_prev)`` (``viscous_stress_g``) with ``C`` the
    elastic tensor (``2 mu``, ``lam``), ``G_prev`` the strain at the substep start and ``k_d``
    [s] the material's damping (``kd_over_h`` is ``k_d/h``). It vanishes for rigid motion (no
    drag on a falling or moving garment; cf. the per-vertex form of Chen et al. 2024, Eq. 14,
    which damps absolute motion and over-damps fine meshes). Its Hessian block is ``k_d/h``
    times the material part of the StVK block (``membrane_material_hessian``, positive
    semi-definite).

    First Piola stress ``P = 2 mu (F - R) + lam (tr S - 2) R``; the Hessian
    block is the positive semi-definite ``A (2 mu |g|^2 T + k_n n n^T + lam (R g)(R g)^T)`` with
    ``T`` the projector onto the triangle's plane (the rotation's derivative dropped) and
    ``k_n = max(0, g^T S2 g)`` the exact out-of-plane stiffness of a stressed triangle (second
    Piola stress ``S2``; 0 under compression).
    """
    f0, f1 = deformation_gradient(x0, x1, x2, dm_inv)
    r0, r1, tr_s = corotated_frame(f0, f1)
    g = shape_row(dm_inv, local)
    fg = f0 * g[0] + f1 * g[1]
    rg = r0 * g[0] + r1 * g[1]
    pg = 2.0 * mu * (fg - rg) + lam * (tr_s - 2.0) * rg
    # viscous part: (k_d/h) C:(G - G_prev) as a second Piola stress, P_v g = F S_v g
    vg = viscous_stress_g(green_strain(x0, x1, x2, dm_inv), strain_prev, g, mu, lam, kd_over_h)
    force = -area * (pg + f0 * vg[0] + f1 * vg[1])
    gg = wp.dot(g, g)
    material = membrane_material_hessian(f0, f1, g, mu, lam)
    nrm = wp.cross(x1 - x0, x2 - x0)
    nl = wp.length(nrm)
    tangent = wp.identity(n=3, dtype=float)
    normal_part = wp.mat33(0.0)
    if nl > 1.0e-20:
        nrm = nrm / nl
        tangent = tangent - wp.outer(nrm, nrm)
        # out of plane the triangle's own stress is the stiffness (a string under tension):
        # F -> F + d n g^T changes C by d^2 g g^T, so d2E/dd2 = A g^T S2 g with the second Piola
        # stress S2 = 2 mu I + (lam (tr S - 2) - 2 mu) S^-1; clamped at 0 (compressed cloth
        # buckles: no stiffness). Without it a taut triangle's Newton step overshoots.
        s00 = wp.dot(r0, f0)
        s11 = wp.dot(r1, f1)
        s01 = 0.5 * (wp.dot(r0, f1) + wp.dot(r1, f0))
        det_s = wp.max(s00 * s11 - s01 * s01, 1.0e-4)
        g_sinv_g = (s11 * g[0] * g[0] - 2.0 * s01 * g[0] * g[1] + s00 * g[1] * g[1]) / det_s
        kn = 2.0 * mu * gg + (lam * (tr_s - 2.0) - 2.0 * mu) * g_sinv_g
        normal_part = wp.max(kn, 0.0) * wp.outer(nrm, nrm)
    hess = area * ((2.0 * mu * gg) * tangent + normal_part + lam * wp.outer(rg, rg) + kd_over_h * material)
    return force, hess


@wp.func
def dihedral_angle(xo0: wp.vec3, xo1: wp.vec3, xa: wp.vec3, xb: wp.vec3) -> float:
    """Signed dihedral angle [rad] of the hinge ``(o0, o1, a, b)``; 0 when flat."""
    e = xb - xa
    na = wp.cross(e, xo0 - xa)
    nb = wp.cross(xa - xb, xo1 - xb)
    la = wp.length(na)
    lb = wp.length(nb)
    le = wp.length(e)
    if la < 1.0e-12 or lb < 1.0e-12 or le < 1.0e-12:
        return 0.0
    na = na / la
    nb = nb / lb
    return wp.atan2(wp.dot(wp.cross(na, nb), e / le), wp.dot(na, nb))


@wp.func
def angle_difference(a: float, b: float) -> float:
    """``a - b`` wrapped into [-pi, pi) [rad]. A hinge's signed angle (``dihedral_angle``) jumps
    by 2 pi where a fold passes flat (+-pi): against a rest angle near +-pi (a crease folded at
    rest, a seam) the plain difference would read a small further fold as almost a full turn
    and drive the hinge around the long way, through the cloth. Wrapped, the jump sits half a
    turn from the rest angle."""
    d = a - b
    return d - 2.0 * wp.pi * wp.floor((d + wp.pi) / (2.0 * wp.pi))


@wp.func
def bending_energy(xo0: wp.vec3, xo1: wp.vec3, xa: wp.vec3, xb: wp.vec3, rest_angle: float,
                   k_edge: float) -> float:
    """Hinge bending energy ``k_e/2 (theta - theta_rest)^2`` [J], the difference wrapped into
    [-pi, pi) (``angle_difference``)."""
    d = angle_difference(dihedral_angle(xo0, xo1, xa, xb), rest_angle)
    return 0.5 * k_edge * d * d


@wp.func
def dihedral_angle_gradient(xo0: wp.vec3, xo1: wp.vec3, xa: wp.vec3, xb: wp.vec3, local: int) -> wp.vec3:
    """``d theta / d x_local`` for local index 0..3 = (o0, o1, a, b).

    Opposite vertices: ``-n / h`` (unit normal over height above the hinge); hinge vertices
    take the complementary barycentric share, so the four gradients sum to zero.
    """
    e = xb - xa
    le = wp.length(e)
    na = wp.cross(e, xo0 - xa)
    nb = wp.cross(xa - xb, xo1 - xb)
    la = wp.length(na)
    lb = wp.length(nb)
    if la < 1.0e-12 or lb < 1.0e-12 or le < 1.0e-12:
        return wp.vec3(0.0)
    # n/h = n_unnormalised |e| / |n|^2   (h = |n| / |e|)
    ga = -na * (le / (la * la))
    gb = -nb * (le / (lb * lb))
    if local == 0:
        return ga
    if local == 1:
        return gb
    ta = wp.dot(xo0 - xa, e) / (le * le)
    tb = wp.dot(xo1 - xa, e) / (le * le)
    if local == 2:
        return -(1.0 - ta) * ga - (1.0 - tb) * gb
    return -ta * ga - tb * gb


@wp.func
def bending_damped_vertex_force_hessian(xo0: wp.vec3, xo1: wp.vec3, xa: wp.vec3, xb: wp.vec3,
                                        rest_angle: float, k_edge: float, angle_prev: float,
                                        kd_over_h: float, local: int):
    """Hinge force and Gauss-Newton Hessian plus damping of the angle rate:
    ``f_d = -(k_d/h) k_e (theta - theta_prev) dtheta/dx``, Hessian ``(k_d/h) k_e g g^T`` (both
    differences wrapped, ``angle_difference``)."""
    theta = dihedral_angle(xo0, xo1, xa, xb)
    g = dihedral_angle_gradient(xo0, xo1, xa, xb, local)
    f = -k_edge * (angle_difference(theta, rest_angle) + kd_over_h * angle_difference(theta, angle_prev)) * g
    return f, (k_edge * (1.0 + kd_over_h)) * wp.outer(g, g)
