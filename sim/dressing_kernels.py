"""Warp kernels of the dressing step (see ``sim/dressing.py``): closest body-surface points of
garment attachment vertices, and the pin targets that follow the moving body.

Kernel arguments: inputs first, outputs with an ``_out`` suffix.
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def closest_point_kernel(
    mesh: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    max_dist: float,
    face_out: wp.array(dtype=wp.int32),
    bary_out: wp.array(dtype=wp.vec3),
):
    """Closest point on the mesh surface to each ``x``: its face and barycentric weights of the
    face's three corners (-1 where nothing lies within ``max_dist``)."""
    i = wp.tid()
    q = wp.mesh_query_point_no_sign(mesh, x[i], max_dist)
    if q.result:
        face_out[i] = q.face
        # wp.mesh_eval_position: u p0 + v p1 + (1 - u - v) p2
        bary_out[i] = wp.vec3(q.u, q.v, 1.0 - q.u - q.v)
    else:
        face_out[i] = -1
        bary_out[i] = wp.vec3(0.0)


@wp.func
def triangle_frame_point(a: wp.vec3, b: wp.vec3, c: wp.vec3, bary: wp.vec3, offset: wp.vec3):
    """``sum bary_k p_k + offset`` with ``offset`` in the triangle's orthonormal frame
    (t0 along ab, n the unit normal, t1 = n x t0); ``sim.dressing.triangle_frames`` in numpy."""
    e1 = b - a
    t0 = wp.normalize(e1)
    n = wp.normalize(wp.cross(e1, c - a))
    t1 = wp.cross(n, t0)
    p = bary[0] * a + bary[1] * b + bary[2] * c
    return p + offset[0] * t0 + offset[1] * t1 + offset[2] * n


@wp.kernel
def attachment_targets_kernel(
    body_points: wp.array(dtype=wp.vec3),
    corners: wp.array(dtype=wp.vec3i),
    bary: wp.array(dtype=wp.vec3),
    offset: wp.array(dtype=wp.vec3),
    particle: wp.array(dtype=wp.int32),
    targets_out: wp.array(dtype=wp.vec3),
):
    """Pin target of each bound particle: its rest offset carried by its body triangle."""
    k = wp.tid()
    tri = corners[k]
    targets_out[particle[k]] = triangle_frame_point(body_points[tri[0]], body_points[tri[1]],
                                                    body_points[tri[2]], bary[k], offset[k])
