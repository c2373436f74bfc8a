"""Warp kernels of the virtual depth-camera ring (``sim/scans/scanner.py``).

Kernel arguments: inputs first, outputs with an ``_out`` suffix.
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def first_hits_kernel(
    garment: wp.uint64,
    body: wp.uint64,
    has_body: int,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    max_t: float,
    t_out: wp.array(dtype=float),
    face_out: wp.array(dtype=int),
    bary_out: wp.array(dtype=wp.vec2),
    normal_out: wp.array(dtype=wp.vec3),
):
    """Per ray, the garment's first hit unless the body is hit before it: its distance along
    the unit ray, face (-1: none), barycentrics (u, v) of corners 0 and 1, and face normal."""
    i = wp.tid()
    o = origins[i]
    d = directions[i]
    face_out[i] = -1
    r = wp.mesh_query_ray(garment, o, d, max_t)
    if r.result:
        blocked = bool(False)
        if has_body == 1:
            b = wp.mesh_query_ray(body, o, d, r.t)
            if b.result:
                blocked = b.t < r.t
        if not blocked:
            t_out[i] = r.t
            face_out[i] = r.face
            bary_out[i] = wp.vec2(r.u, r.v)
            normal_out[i] = r.normal
