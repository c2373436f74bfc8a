"""Warp kernels for the simulation quality gates (see ``sim/quality.py``).

Kernel arguments: inputs first, outputs with an ``_out`` suffix.
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def edge_strain_kernel(
    x: wp.array2d(dtype=wp.vec3),
    edges: wp.array2d(dtype=int),
    rest_length: wp.array(dtype=float),
    strain_out: wp.array2d(dtype=float),
):
    """Engineering strain l / l0 - 1 of each edge in each frame. x: (T, V); out: (T, E)."""
    t, e = wp.tid()
    d = x[t, edges[e, 1]] - x[t, edges[e, 0]]
    strain_out[t, e] = wp.length(d) / rest_length[e] - 1.0


@wp.kernel
def inside_mesh_kernel(
    mesh: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    max_dist: float,
    inside_out: wp.array(dtype=int),
):
    """1 where a point is inside the (closed, outward-wound) mesh, by its angle-weighted
    pseudo-normal sign; points farther than ``max_dist`` from the surface count as outside."""
    i = wp.tid()
    q = wp.mesh_query_point_sign_normal(mesh, x[i], max_dist)
    inside = int(0)
    if q.result:
        if q.sign < 0.0:
            inside = 1
    inside_out[i] = inside


@wp.kernel
def push_outside_kernel(
    mesh: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    max_dist: float,
    clearance: float,
    out: wp.array(dtype=wp.vec3),
):
    """Points inside the closed mesh, or outside but closer than ``clearance``, go to their
    closest surface point plus ``clearance`` along that face's outward normal; the rest stay."""
    i = wp.tid()
    p = x[i]
    y = p
    q = wp.mesh_query_point_sign_normal(mesh, p, max_dist)
    if q.result:
        c = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        if q.sign < 0.0 or wp.length(p - c) < clearance:
            y = c + clearance * wp.mesh_eval_face_normal(mesh, q.face)
    out[i] = y


@wp.func
def segment_hits_triangle(p: wp.vec3, q: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> int:
    """Moller-Trumbore for the segment p-q against triangle abc (1 on a proper crossing)."""
    d = q - p
    e1 = b - a
    e2 = c - a
    h = wp.cross(d, e2)
    det = wp.dot(e1, h)
    # (near-)coplanar segment and triangle: no transversal crossing (relative threshold)
    if wp.abs(det) <= 1.0e-6 * wp.length(d) * wp.length(e1) * wp.length(e2):
        return 0
    inv = 1.0 / det
    s = p - a
    u = inv * wp.dot(s, h)
    if u < 0.0 or u > 1.0:
        return 0
    qv = wp.cross(s, e1)
    v = inv * wp.dot(d, qv)
    if v < 0.0 or u + v > 1.0:
        return 0
    t = inv * wp.dot(e2, qv)
    if t < 0.0 or t > 1.0:
        return 0
    return 1


@wp.kernel
def self_intersection_kernel(
    mesh: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    edges: wp.array2d(dtype=int),
    faces: wp.array2d(dtype=int),
    edge_hit_out: wp.array(dtype=int),
):
    """Per edge, its crossings through non-adjacent faces of the same mesh.

    One thread per edge; candidate faces from the mesh BVH over the edge's bounding box. A pair
    of intersecting triangles produces at least two edge-face crossings.
    """
    e = wp.tid()
    i0 = edges[e, 0]
    i1 = edges[e, 1]
    p = x[i0]
    q = x[i1]
    lo = wp.min(p, q)
    hi = wp.max(p, q)
    query = wp.mesh_query_aabb(mesh, lo, hi)
    f = int(0)
    hits = int(0)
    while wp.mesh_query_aabb_next(query, f):
        a = faces[f, 0]
        b = faces[f, 1]
        c = faces[f, 2]
        if a != i0 and a != i1 and b != i0 and b != i1 and c != i0 and c != i1:
            hits += segment_hits_triangle(p, q, x[a], x[b], x[c])
    edge_hit_out[e] = hits


@wp.kernel
def screen_particles_kernel(
    x: wp.array(dtype=wp.vec3),
    x_prev: wp.array(dtype=wp.vec3),
    instance: wp.array(dtype=int),
    roots: wp.array(dtype=wp.vec3),
    max_distance: float,
    fps: float,
    max_speed: float,
    flags_out: wp.array(dtype=int),
):
    """Flag a particle's instance (``flags_out[instance] = 1``) where its position is not finite,
    farther than ``max_distance`` [m] from the instance's root ``roots[instance]``, or faster than
    ``max_speed`` [m/s] since ``x_prev``, a frame (1 / ``fps`` [s]) before (the tests of
    ``sim.simulate.screening.FrameChecker``)."""
    i = wp.tid()
    k = instance[i]
    p = x[i]
    bad = not (wp.isfinite(p[0]) and wp.isfinite(p[1]) and wp.isfinite(p[2]))
    if not (wp.length(p - roots[k]) <= max_distance):
        bad = True
    if not (wp.length(p - x_prev[i]) * fps <= max_speed):
        bad = True
    if bad:
        flags_out[k] = 1


@wp.kernel
def screen_edges_kernel(
    x: wp.array(dtype=wp.vec3),
    edges: wp.array(dtype=wp.vec2i),
    rest_length: wp.array(dtype=float),
    instance: wp.array(dtype=int),
    max_stretch: float,
    flags_out: wp.array(dtype=int),
):
    """Flag an edge's instance where the edge is longer than ``max_stretch`` times its rest length
    (or its length is not finite)."""
    e = wp.tid()
    a = edges[e][0]
    if not (wp.length(x[edges[e][1]] - x[a]) / rest_length[e] <= max_stretch):
        flags_out[instance[a]] = 1
