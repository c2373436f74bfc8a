"""Pair maths of the cloth self-contact: closest points, the penalty force and Hessian block of a
vertex-triangle or edge-edge pair, and the reduced contact radius of pairs close at rest."""

from __future__ import annotations

import warp as wp

from sim.cloth.self_contact.data import SelfContactData

# largest radius code of a pair close at rest (``reduced_radius_code``: 8 bits of ``pair_role``)
RADIUS_CODES = 255


@wp.func
def triangle_closest_bary(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec3:
    """Barycentric weights (of a, b, c) of the point of triangle abc closest to ``p``
    (Ericson, Real-Time Collision Detection, 5.1.5: the Voronoi regions in his order, corner a,
    corner b, edge ab, corner c, edge ac, edge bc, interior). Branch-free, each region's weights
    computed as Ericson does and the first region that holds selected: the same floats as his
    early returns. Inlined into a BVH query loop, the early returns make the CUDA compiler
    reconverge the warp after every leaf the traversal finds, and the self-contact vertex and
    triangle queries took 2.5x as long (H200, 128 t-shirts; docs/DECISIONS.md)."""
    ab = b - a
    ac = c - a
    ap = p - a
    bp = p - b
    cp = p - c
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    on_ab = vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0
    on_ac = vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0
    # the parameter along the edge of whichever edge region holds: one division
    num = wp.where(on_ab, d1, wp.where(on_ac, d2, d4 - d3))
    t = num / wp.where(on_ab, d1 - d3, wp.where(on_ac, d2 - d6, (d4 - d3) + (d5 - d6)))
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    out = wp.vec3(1.0 - v - w, v, w)
    out = wp.where(va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0, wp.vec3(0.0, 1.0 - t, t), out)
    out = wp.where(on_ac, wp.vec3(1.0 - t, 0.0, t), out)
    out = wp.where(d6 >= 0.0 and d5 <= d6, wp.vec3(0.0, 0.0, 1.0), out)
    out = wp.where(on_ab, wp.vec3(1.0 - t, t, 0.0), out)
    out = wp.where(d3 >= 0.0 and d4 <= d3, wp.vec3(0.0, 1.0, 0.0), out)
    return wp.where(d1 <= 0.0 and d2 <= 0.0, wp.vec3(1.0, 0.0, 0.0), out)


@wp.func
def point_triangle_separation(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec3:
    """``p`` minus its closest point on triangle ``abc``."""
    w = triangle_closest_bary(p, a, b, c)
    return p - (w[0] * a + w[1] * b + w[2] * c)


@wp.func
def point_triangle_distance(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> float:
    return wp.length(point_triangle_separation(p, a, b, c))


@wp.func
def pair_force_hessian(diff: wp.vec3, diff0: wp.vec3, rel_disp: wp.vec3, w: float, radius: float, k: float,
                       mu: float, eps_u: float, w_floor: float):
    """Force on and Hessian block of a vertex taking part with signed weight ``w`` in a contact
    pair whose closest points differ by ``diff = p_a - p_b`` now (``w > 0`` on side a, ``< 0`` on
    side b); ``diff0`` is the pair's side reference, its separation at the detection. Energy
    ``k/2 (radius - d)^2`` for ``d < radius`` (Chen et al. 2024, Sec. 4), with ``d`` the distance
    signed by that side: a pair that crossed since the detection (``diff . diff0 < 0``) is pushed
    back, not further through. Friction opposes the tangential part of the pair's relative
    displacement ``rel_disp`` over the substep (lazy IPC friction, smoothed below ``eps_u``).

    The Hessian takes ``|w| max(|w|, w_floor)`` for the exact ``w^2``: a vertex taking part
    with a small weight (an edge end far from the closest point, a triangle corner far from the
    point) would otherwise, in its own Newton step, move ``(radius - d) / w`` to clear the
    whole penetration alone (with floor 0 a hairpin thrown onto itself at 1.1 m/s gains energy
    in its first contact: tests/test_self_contact_physics.py). With the floor no single pair's
    step exceeds ``(radius - d) / w_floor`` (``w_floor`` 0.5: twice the penetration), and a
    vertex with weight 0 still gets nothing. The force, so the converged state, is unchanged: a
    larger Hessian only shortens the step."""
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
