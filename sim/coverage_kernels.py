"""Warp kernels of the skin coverage test (see ``sim/coverage.py``).

Kernel arguments: inputs first, outputs with an ``_out`` suffix.
"""

from __future__ import annotations

import warp as wp

from sim import coverage

INSIDE = wp.constant(coverage.INSIDE)
THROUGH = wp.constant(coverage.THROUGH)
EXPOSED = wp.constant(coverage.EXPOSED)


@wp.func
def on_border(flags: int, u: float, v: float, eps: float) -> bool:
    """Whether the point of barycentric coordinates (u, v, 1 - u - v) on a face with border
    ``flags`` lies on the garment's open border: on a border edge (bit k: the edge opposite
    corner k) or at a border vertex (bit 3 + k: corner k)."""
    w = wp.vec3(u, v, 1.0 - u - v)
    hit = bool(False)
    for k in range(3):
        if w[k] < eps and ((flags >> k) & 1) == 1:
            hit = True
        if w[k] > 1.0 - eps and ((flags >> (3 + k)) & 1) == 1:
            hit = True
    return hit


@wp.kernel
def covered_kernel(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    border: wp.array(dtype=int),
    reach: float,
    eps: float,
    covered_out: wp.array(dtype=int),
):
    """1 where a body point is under the garment: its closest garment point is within ``reach``,
    off the open border, with the point on the inner side (angle-weighted pseudo-normal), and
    the ray along the body's outward normal meets the garment within ``reach``."""
    i = wp.tid()
    p = points[i]
    covered = int(0)
    q = wp.mesh_query_point_sign_normal(mesh, p, reach)
    if q.result:
        if q.sign < 0.0 and not on_border(border[q.face], q.u, q.v, eps):
            r = wp.mesh_query_ray(mesh, p, normals[i], reach)
            if r.result:
                covered = 1
    covered_out[i] = covered


@wp.kernel
def side_kernel(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    ids: wp.array(dtype=int),
    border: wp.array(dtype=int),
    max_dist: float,
    eps: float,
    side_out: wp.array(dtype=int),
    distance_out: wp.array(dtype=float),
):
    """Where body point ``ids[i]`` is against the garment: ``INSIDE`` (inner side of its closest
    garment point), ``THROUGH`` (outer side) or ``EXPOSED`` (its closest garment point on the open
    border, or no garment within ``max_dist``), and its signed distance to that point (positive
    outside; NaN where exposed)."""
    i = wp.tid()
    p = points[ids[i]]
    side = int(EXPOSED)
    distance = wp.nan
    q = wp.mesh_query_point_sign_normal(mesh, p, max_dist)
    if q.result:
        if not on_border(border[q.face], q.u, q.v, eps):
            distance = q.sign * wp.length(p - wp.mesh_eval_position(mesh, q.face, q.u, q.v))
            side = INSIDE
            if q.sign > 0.0:
                side = THROUGH
    side_out[i] = side
    distance_out[i] = distance
