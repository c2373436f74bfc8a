"""The tree broadphase of the cloth self-contact detection (``SelfContact(broadphase="bvh")``):
three grouped BVHs (one group per cloth instance, so batched instances never collide) over the
triangles' and the edges' bounding boxes and over the vertices. Vertices query triangles
(VT lists), triangles query vertices (TV), edges query edges (EE)."""

from __future__ import annotations

import warp as wp

from sim.cloth.self_contact.data import SelfContactData
from sim.cloth.self_contact.lists import (
    edge_edge_candidate,
    edge_speed,
    query_radius,
    triangle_speed,
    vertex_triangle_candidate,
)
from sim.cloth.spans import load_int, load_vec2i, load_vec3i
from sim.device import SideStreams, warp


@wp.kernel
def primitive_bounds_kernel(
    x: wp.array(dtype=wp.vec3),
    tri_indices: wp.array(dtype=wp.vec3i),
    mesh_edges: wp.array(dtype=wp.vec2i),
    tri_count: int,
    edge_count: int,
    lowers_tri_out: wp.array(dtype=wp.vec3),
    uppers_tri_out: wp.array(dtype=wp.vec3),
    lowers_edge_out: wp.array(dtype=wp.vec3),
    uppers_edge_out: wp.array(dtype=wp.vec3),
    lowers_point_out: wp.array(dtype=wp.vec3),
    uppers_point_out: wp.array(dtype=wp.vec3),
):
    """Axis-aligned boxes of every triangle (threads < tri_count) and edge (the next
    edge_count), and the vertices (the rest: points)."""
    k = wp.tid()
    ids = wp.vec3i()
    corners = int(3)
    if k >= tri_count + edge_count:
        ids = wp.vec3i(k - tri_count - edge_count, 0, 0)
        corners = 1
    elif k < tri_count:
        ids = tri_indices[k]
    else:
        e = mesh_edges[k - tri_count]
        ids = wp.vec3i(e[0], e[1], 0)
        corners = 2
    lo = x[ids[0]]
    hi = lo
    for c in range(1, corners):
        lo = wp.min(lo, x[ids[c]])
        hi = wp.max(hi, x[ids[c]])
    if k >= tri_count + edge_count:
        lowers_point_out[k - tri_count - edge_count] = lo
        uppers_point_out[k - tri_count - edge_count] = hi
    elif k < tri_count:
        lowers_tri_out[k] = lo
        uppers_tri_out[k] = hi
    else:
        lowers_edge_out[k - tri_count] = lo
        uppers_edge_out[k - tri_count] = hi


@wp.kernel
def group_roots_kernel(bvh: wp.uint64, roots_out: wp.array(dtype=wp.int32)):
    """Each group's (instance's) subtree root of ``bvh``, for the detection queries. Warp's
    ``bvh_get_group_root`` finds it by two binary searches over the leaves (each step three
    dependent loads) and a walk up from two leaves to their common ancestor: ~100 dependent
    loads that every query thread would pay before its traversal. The tree's topology only
    changes when it is rebuilt, so the roots are found once then."""
    g = wp.tid()
    roots_out[g] = wp.bvh_get_group_root(bvh, g)


@wp.kernel
def detect_vertex_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    tri_indices: wp.array(dtype=wp.vec3i),
    tri_bvh: wp.uint64,
    tri_roots: wp.array(dtype=wp.int32),
    margin: float,
    speed_factor: float,
    h: float,
    sc_inout: SelfContactData,
):
    """Per vertex: the VT pairs within the query radius of its speed in its instance's frame
    (``tri_roots``: each instance's subtree root, ``group_roots_kernel``)."""
    i = wp.tid()
    xi = x[i]
    inst = particle_instance[i]
    r = query_radius(margin, wp.length(v[i] - sc_inout.reference[inst]), h, speed_factor)
    query = wp.bvh_query_aabb(tri_bvh, xi - wp.vec3(r), xi + wp.vec3(r), tri_roots[inst])
    t = int(0)
    count = int(0)
    while wp.bvh_query_next(query, t):
        tri = load_vec3i(tri_indices, t)
        if tri[0] == i or tri[1] == i or tri[2] == i:
            continue
        if load_int(particle_instance, tri[0]) != inst:
            continue
        count = vertex_triangle_candidate(sc_inout, x, v, i, tri, r, margin, speed_factor, h, count,
                                          sc_inout.vt_tri, sc_inout.vt_dist, sc_inout.vt_ref, sc_inout.vt_rk,
                                          i, sc_inout.vt_capacity, t)
    sc_inout.vt_count[i] = count


@wp.kernel
def detect_triangle_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    tri_indices: wp.array(dtype=wp.vec3i),
    vertex_bvh: wp.uint64,
    vertex_roots: wp.array(dtype=wp.int32),
    margin: float,
    speed_factor: float,
    h: float,
    sc_inout: SelfContactData,
):
    """Per triangle: the TV pairs within the query radius of its fastest corner. Candidate
    vertices come straight from the vertex BVH: through the triangle BVH each vertex would be
    one of ~3 candidate triangles' corners, found again at its other triangles and skipped."""
    t = wp.tid()
    tri = tri_indices[t]
    a = x[tri[0]]
    b = x[tri[1]]
    c = x[tri[2]]
    inst = particle_instance[tri[0]]
    r = query_radius(margin, triangle_speed(v, tri, sc_inout.reference[inst]), h, speed_factor)
    lo = wp.min(wp.min(a, b), c)
    hi = wp.max(wp.max(a, b), c)
    query = wp.bvh_query_aabb(vertex_bvh, lo - wp.vec3(r), hi + wp.vec3(r), vertex_roots[inst])
    u = int(0)
    count = int(0)
    while wp.bvh_query_next(query, u):
        if u == tri[0] or u == tri[1] or u == tri[2] or load_int(particle_instance, u) != inst:
            continue
        count = vertex_triangle_candidate(sc_inout, x, v, u, tri, r, margin, speed_factor, h, count,
                                          sc_inout.tv_vertex, sc_inout.tv_dist, sc_inout.tv_ref,
                                          sc_inout.tv_rk, t, sc_inout.tv_capacity, u)
    sc_inout.tv_count[t] = count


@wp.kernel
def detect_edge_kernel(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    edge_bvh: wp.uint64,
    edge_roots: wp.array(dtype=wp.int32),
    margin: float,
    speed_factor: float,
    h: float,
    sc_inout: SelfContactData,
):
    """Per edge: the EE pairs (edges sharing no vertex) within the query radius of its faster
    end."""
    e = wp.tid()
    ea = sc_inout.mesh_edges[e]
    p1 = x[ea[0]]
    q1 = x[ea[1]]
    inst = particle_instance[ea[0]]
    r = query_radius(margin, edge_speed(v, ea, sc_inout.reference[inst]), h, speed_factor)
    lo = wp.min(p1, q1)
    hi = wp.max(p1, q1)
    query = wp.bvh_query_aabb(edge_bvh, lo - wp.vec3(r), hi + wp.vec3(r), edge_roots[inst])
    e2 = int(0)
    count = int(0)
    while wp.bvh_query_next(query, e2):
        eb = load_vec2i(sc_inout.mesh_edges, e2)
        if eb[0] == ea[0] or eb[0] == ea[1] or eb[1] == ea[0] or eb[1] == ea[1]:
            continue
        if load_int(particle_instance, eb[0]) != inst:
            continue
        count = edge_edge_candidate(sc_inout, x, v, e, ea, p1, q1, e2, eb, r, margin, speed_factor, h, count)
    sc_inout.ee_count[e] = count


class BvhBroadphase:
    """The three trees of a ``ClothModel`` (built at its ``particle_q``), their boxes and each
    instance's subtree roots.

    ``trees`` in the order of the queries they serve: triangles (the vertex query's), vertices
    (the triangle query's), edges (the edge query's); ``roots[k]`` each instance's subtree root
    of ``trees[k]``."""

    def __init__(self, model):
        w = warp()
        d = model.device
        n, nt, ne = model.particle_count, model.tri_count, model.mesh_edge_indices.shape[0]
        self.model = model
        self._lo_t, self._hi_t = w.zeros(nt, dtype=w.vec3, device=d), w.zeros(nt, dtype=w.vec3, device=d)
        self._lo_e, self._hi_e = w.zeros(ne, dtype=w.vec3, device=d), w.zeros(ne, dtype=w.vec3, device=d)
        self._lo_p, self._hi_p = w.zeros(n, dtype=w.vec3, device=d), w.zeros(n, dtype=w.vec3, device=d)
        self.fit_boxes(model.particle_q)
        self.trees = (w.Bvh(self._lo_t, self._hi_t, groups=model.tri_instance),
                      w.Bvh(self._lo_p, self._hi_p, groups=model.particle_instance),
                      w.Bvh(self._lo_e, self._hi_e, groups=model.mesh_edge_instance))
        self.roots = [w.zeros(model.instance_count, dtype=w.int32, device=d) for _ in range(3)]
        self.find_roots()
        self._side = SideStreams(d, 3)

    def fit_boxes(self, x) -> None:
        """The trees' boxes at ``x`` (``primitive_bounds_kernel``); the trees see them at their
        next refit or rebuild."""
        m = self.model
        ne = self._lo_e.shape[0]
        warp().launch(primitive_bounds_kernel, dim=m.tri_count + ne + m.particle_count,
                      inputs=[x, m.tri_indices, m.mesh_edge_indices, m.tri_count, ne],
                      outputs=[self._lo_t, self._hi_t, self._lo_e, self._hi_e, self._lo_p, self._hi_p],
                      device=m.device)

    def find_roots(self, k: int | None = None) -> None:
        """Each instance's subtree root of tree ``k`` (None: of every tree) into ``roots[k]``
        (``group_roots_kernel``); needed after a rebuild (``detect`` refinds them itself)."""
        for j in range(3) if k is None else (k,):
            warp().launch(group_roots_kernel, dim=self.model.instance_count, inputs=[self.trees[j].id],
                          outputs=[self.roots[j]], device=self.model.device)

    def query(self, k: int, x0, v, h: float, margin: float, speed_factor: float, sc: SelfContactData) -> None:
        """Detection kernel ``k`` (0 vertices, 1 triangles, 2 edges: ``detect_vertex_kernel``,
        ``detect_triangle_kernel``, ``detect_edge_kernel``) at ``x0`` (the trees must be fitted to
        it): its lists into ``sc``."""
        m = self.model
        kernel, dim, inputs = (
            (detect_vertex_kernel, m.particle_count, [m.tri_indices]),
            (detect_triangle_kernel, m.tri_count, [m.tri_indices]),
            (detect_edge_kernel, self._lo_e.shape[0], []))[k]
        warp().launch(kernel, dim=dim, inputs=[x0, v, m.particle_instance, *inputs, self.trees[k].id,
                                               self.roots[k], margin, speed_factor, h],
                      outputs=[sc], device=m.device)

    def detect(self, x0, v, h: float, rebuild: bool, margin: float, speed_factor: float,
               sc: SelfContactData) -> bool:
        """Fit (``rebuild``: build) the trees to ``x0`` and run the three queries into ``sc``'s
        lists. Three independent chains (refit a tree, query it), each on its own stream on
        CUDA: the queries are latency-bound (a few thousand threads), so they overlap almost
        fully. Returns False: the record counters are the caller's to zero."""
        self.fit_boxes(x0)
        for k, bvh in enumerate(self.trees):
            with self._side.on(k):
                if rebuild:
                    bvh.rebuild()
                    self.find_roots(k)
                else:
                    bvh.refit()
                self.query(k, x0, v, h, margin, speed_factor, sc)
        self._side.join()
        return False
