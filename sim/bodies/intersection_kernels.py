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
    frame: int,
    points_out: wp.array(dtype=wp.vec3),
):
    """The solids' points of one frame: the body's vertices (threads < V), then each cap's
    centre, the mean of its boundary loop's vertices (thread V + c)."""
    i = wp.tid()
    n = vertices.shape[1]
    if i < n:
        points_out[i] = vertices[frame, i]
        return
    c = i - n
    s = wp.vec3(0.0)
    for k in range(loop_starts[c], loop_starts[c + 1]):
        s += vertices[frame, loop_vertices[k]]
    points_out[i] = s / float(loop_starts[c + 1] - loop_starts[c])


@wp.func
def skin_point(solid: wp.uint64, skin_faces: int, p: wp.vec3, max_depth: float):
    """The closest point of a part's solid to ``p`` within ``max_depth`` and the signed distance
    to it (< 0 inside), by the generalised winding number (robust where a cap's fan folds over
    itself). A point whose closest point lies on a cap (``face >= skin_faces``) is in the joint
    where two parts meet, not in the part's flesh, and a point farther than ``max_depth`` is not
    near it: both get ``found`` 0."""
    q = wp.mesh_query_point_sign_winding_number(solid, p, max_depth)
    found = int(0)
    c = p
    n = wp.vec3(0.0)
    dist = float(0.0)
    if q.result:
        if q.face < skin_faces:
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
    movers: wp.array(dtype=wp.int32),
    mover_pair: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3),
    max_depth: float,
    depth_out: wp.array(dtype=float),
):
    """How deep [m] each mover vertex lies inside the solid of its pair's other part (0
    outside, near a cap or deeper than ``max_depth``): one thread per (vertex, pair)."""
    k = wp.tid()
    j = mover_pair[k]
    found, c, n, dist = skin_point(solids[j], skin_faces[j], points[movers[k]], max_depth)
    depth_out[k] = 0.0
    if found == 1 and dist < 0.0:
        depth_out[k] = -dist


@wp.kernel
def displacement_kernel(
    solids: wp.array(dtype=wp.uint64),
    skin_faces: wp.array(dtype=wp.int32),
    movers: wp.array(dtype=wp.int32),
    mover_pair: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3),
    max_depth: float,
    clearance: float,
    tolerance: float,
    delta_out: wp.array(dtype=wp.vec3),
):
    """Per (vertex, pair): a vertex inside the solid of its pair's other part, or nearer its
    skin than ``clearance`` [m] by more than ``tolerance`` [m], goes to ``clearance`` off the
    closest skin point along the outward direction from it (``skin_point``); ``delta_out`` is
    that displacement, else 0."""
    k = wp.tid()
    j = mover_pair[k]
    p = points[movers[k]]
    found, c, n, dist = skin_point(solids[j], skin_faces[j], p, max_depth)
    delta_out[k] = wp.vec3(0.0)
    if found == 1 and dist < clearance - tolerance:
        delta_out[k] = c + clearance * n - p


@wp.kernel
def apply_displacements_kernel(
    vertices: wp.array(dtype=wp.int32),
    starts: wp.array(dtype=wp.int32),
    delta: wp.array(dtype=wp.vec3),
    frame: int,
    x_inout: wp.array2d(dtype=wp.vec3),
    moved_out: wp.array(dtype=wp.int32),
):
    """Each moving vertex takes the sum of its pairs' displacements, in the pairs' order (its
    entries of ``delta`` are ``starts[u] .. starts[u + 1]``): the same sum on every device, where
    atomic adds would sum in the threads' order. ``moved_out[frame]`` becomes 1 where one moves."""
    u = wp.tid()
    s = wp.vec3(0.0)
    for k in range(starts[u], starts[u + 1]):
        s += delta[k]
    if wp.length_sq(s) > 0.0:
        i = vertices[u]
        x_inout[frame, i] = x_inout[frame, i] + s
        moved_out[frame] = 1
