"""Warp kernels of the body's part separation (see ``sim/bodies/intersections.py``).

Kernel arguments: inputs first, outputs with an ``_out`` / ``_inout`` suffix.
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def frame_points_kernel(
    vertices: wp.array2d(dtype=wp.vec3),
    loop_vertices: wp.array(dtype=wp.int32),
    loop_starts: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.vec3),
    points_out: wp.array(dtype=wp.vec3),
):
    """The solids' points of every frame t side by side: the body's vertices (i < V), then each
    cap's centre, the mean of its boundary loop's vertices (i = V + c), moved by ``offsets[t]``
    to ``points_out[t * (V + C) + i]``."""
    t, i = wp.tid()
    n = vertices.shape[1]
    stride = n + loop_starts.shape[0] - 1
    p = wp.vec3(0.0)
    if i < n:
        p = vertices[t, i]
    else:
        c = i - n
        for k in range(loop_starts[c], loop_starts[c + 1]):
            p += vertices[t, loop_vertices[k]]
        p = p / float(loop_starts[c + 1] - loop_starts[c])
    points_out[t * stride + i] = p + offsets[t]


@wp.func
def skin_point(solid: wp.uint64, skin_faces: int, solid_faces: int, p: wp.vec3, max_depth: float):
    """The closest point of a part's solid to ``p`` within ``max_depth`` and the signed distance
    to it (< 0 inside). The solids' meshes carry no winding-number data, so Warp's query takes
    the sign from the closest hits of three axis-aligned rays (a majority vote); the sign of the
    closest point's normal instead left parts 4 cm in each other where the skin folds through
    itself (the default body's squat). The solid's mesh holds it in several frames,
    ``solid_faces`` triangles each, skin faces first. A point whose closest point lies on a cap
    (its face's index within the frame ``>= skin_faces``) is in the joint where two parts meet,
    not in the part's flesh, and a point farther than ``max_depth`` is not near it: both get
    ``found`` 0."""
    q = wp.mesh_query_point_sign_winding_number(solid, p, max_depth)
    found = int(0)
    c = p
    n = wp.vec3(0.0)
    dist = float(0.0)
    if q.result:
        if q.face % solid_faces < skin_faces:
            found = 1
            c = wp.mesh_eval_position(solid, q.face, q.u, q.v)
            d = p - c
            dl = wp.length(d)
            dist = q.sign * dl
            n = wp.mesh_eval_face_normal(solid, q.face)
            if dl > 1.0e-7:
                n = d * (q.sign / dl)
    return found, c, n, dist


@wp.kernel
def penetration_kernel(
    solids: wp.array(dtype=wp.uint64),
    skin_faces: wp.array(dtype=wp.int32),
    solid_faces: wp.array(dtype=wp.int32),
    movers: wp.array(dtype=wp.int32),
    mover_pair: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3),
    stride: int,
    active: wp.array(dtype=wp.int32),
    max_depth: float,
    depth_out: wp.array2d(dtype=float),
):
    """How deep [m] each mover vertex lies inside the solid of its pair's other part (0
    outside, near a cap, deeper than ``max_depth`` or in a frame not ``active``): one thread per
    (frame, task); frame t's points begin at ``t * stride``."""
    t, k = wp.tid()
    depth_out[t, k] = 0.0
    if active[t] == 0:
        return
    j = mover_pair[k]
    p = points[t * stride + movers[k]]
    found, c, n, dist = skin_point(solids[j], skin_faces[j], solid_faces[j], p, max_depth)
    if found == 1 and dist < 0.0:
        depth_out[t, k] = -dist


@wp.kernel
def displacement_kernel(
    solids: wp.array(dtype=wp.uint64),
    skin_faces: wp.array(dtype=wp.int32),
    solid_faces: wp.array(dtype=wp.int32),
    movers: wp.array(dtype=wp.int32),
    mover_pair: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3),
    stride: int,
    active: wp.array(dtype=wp.int32),
    max_depth: float,
    clearance: float,
    tolerance: float,
    delta_out: wp.array2d(dtype=wp.vec3),
):
    """Per (frame, task) of the ``active`` frames: a vertex inside the solid of its pair's other
    part, or nearer its skin than ``clearance`` [m] by more than ``tolerance`` [m], goes to
    ``clearance`` off the closest skin point along the outward direction from it
    (``skin_point``); ``delta_out`` is that displacement, else 0."""
    t, k = wp.tid()
    delta_out[t, k] = wp.vec3(0.0)
    if active[t] == 0:
        return
    j = mover_pair[k]
    p = points[t * stride + movers[k]]
    found, c, n, dist = skin_point(solids[j], skin_faces[j], solid_faces[j], p, max_depth)
    if found == 1 and dist < clearance - tolerance:
        delta_out[t, k] = c + clearance * n - p


@wp.kernel
def apply_displacements_kernel(
    vertices: wp.array(dtype=wp.int32),
    starts: wp.array(dtype=wp.int32),
    delta: wp.array2d(dtype=wp.vec3),
    x_inout: wp.array2d(dtype=wp.vec3),
    moved_out: wp.array(dtype=wp.int32),
):
    """Each moving vertex of each frame takes the sum of its pairs' displacements, in the pairs'
    order (its entries of ``delta[t]`` are ``starts[u] .. starts[u + 1]``): the same sum on
    every device, where atomic adds would sum in the threads' order. ``moved_out[t]`` becomes 1
    where one moves."""
    t, u = wp.tid()
    s = wp.vec3(0.0)
    for k in range(starts[u], starts[u + 1]):
        s += delta[t, k]
    if wp.length_sq(s) > 0.0:
        i = vertices[u]
        x_inout[t, i] = x_inout[t, i] + s
        moved_out[t] = 1
