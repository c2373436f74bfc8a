"""The self-contact data the kernels take: ``SelfContactData`` (settings, pair lists, gather
records, one kernel argument), its solve-side view ``SolveContactArrays`` (the arrays as
``Span``s), and their builders."""

from __future__ import annotations

import numpy as np
import warp as wp

from sim.cloth.spans import Span, fill_spans, ints, vec2is, vec3s, vec4is
from sim.device import warp


@wp.struct
class SelfContactData:
    """Self-contact settings and buffers passed to the kernels as one argument.

    ``enabled`` 0 turns everything off (the arrays may then be empty). Per kind of list (``vt``:
    per vertex its triangles, ``tv``: per triangle its vertices, ``ee``: per edge its edges)
    ``*_count`` pairs stored, each with its partner (``vt_tri``, ``tv_vertex``, ``ee_edge``), its
    ranking distance (``*_dist``, ``store_pair``), its side reference (``*_ref``: the separation
    at the detection) and ``*_rk`` (radius code, ``NEAR_REST`` bit), ``capacity`` slots per owner.
    ``tv_first`` / ``ee_first``: per vertex incidence entry the pairs of the vertex's triangles /
    edges before it; ``tv_total`` / ``ee_total`` their sums. The gather records: per vertex
    ``pair_count`` records from ``pair_first`` (-1: the pool was full) in the pool
    ``pair_verts`` / ``pair_role`` / ``pair_ref`` of ``pool_size`` (``records``).

    ``heavy`` (per particle), ``heavy_list`` (per colour slot) and ``heavy_count`` (per colour):
    the vertices with more than ``heavy_threshold`` gather records, which the solve gives a whole
    thread block each when their colour has at most ``heavy_cap`` of them (0: off).
    ``particle_color`` / ``color_start``: each particle's colour, each colour's first slot in the
    model's ``color_vertices``. ``rest`` / ``component``: rest positions and connected piece of
    every particle (pairs of one piece close at rest get a reduced radius); ``panel`` / ``flat``:
    where it lies in its sewing pattern, for the rest distance along the cloth
    (``sim.cloth.pattern_distance``). ``coarse_pairs``: per
    particle the pairs that hold back the coarse correction (``has_pairs``). ``reference``: each
    instance's reference velocity, the frame the detection searches in."""

    enabled: int
    relative_lists: int
    radius: float
    stiffness: float
    friction: float
    weight_floor: float
    vt_capacity: int
    tv_capacity: int
    ee_capacity: int
    vt_count: wp.array(dtype=wp.int32)
    vt_tri: wp.array(dtype=wp.int32)
    tv_count: wp.array(dtype=wp.int32)
    tv_vertex: wp.array(dtype=wp.int32)
    ee_count: wp.array(dtype=wp.int32)
    ee_edge: wp.array(dtype=wp.int32)
    vt_dist: wp.array(dtype=float)
    tv_dist: wp.array(dtype=float)
    ee_dist: wp.array(dtype=float)
    vt_ref: wp.array(dtype=wp.vec3)
    tv_ref: wp.array(dtype=wp.vec3)
    ee_ref: wp.array(dtype=wp.vec3)
    vt_rk: wp.array(dtype=wp.int32)
    tv_rk: wp.array(dtype=wp.int32)
    ee_rk: wp.array(dtype=wp.int32)
    tv_total: wp.array(dtype=wp.int32)
    ee_total: wp.array(dtype=wp.int32)
    tv_first: wp.array(dtype=wp.int32)
    ee_first: wp.array(dtype=wp.int32)
    pair_first: wp.array(dtype=wp.int32)
    pair_count: wp.array(dtype=wp.int32)
    pair_verts: wp.array(dtype=wp.vec4i)
    pair_role: wp.array(dtype=wp.int32)
    pair_ref: wp.array(dtype=wp.vec3)
    pair_cursor: wp.array(dtype=wp.int32)
    pool_size: int
    heavy: wp.array(dtype=wp.int32)
    heavy_list: wp.array(dtype=wp.int32)
    heavy_count: wp.array(dtype=wp.int32)
    heavy_threshold: int
    heavy_cap: int
    particle_color: wp.array(dtype=wp.int32)
    color_start: wp.array(dtype=wp.int32)
    mesh_edges: wp.array(dtype=wp.vec2i)
    vertex_edge_offsets: wp.array(dtype=wp.int32)
    vertex_edge_ids: wp.array(dtype=wp.int32)
    vertex_edge_local: wp.array(dtype=wp.int32)
    rest: wp.array(dtype=wp.vec3)
    panel: wp.array(dtype=wp.int32)
    flat: wp.array(dtype=wp.vec3)
    component: wp.array(dtype=wp.int32)
    coarse_exclusion: float
    coarse_pairs: wp.array(dtype=wp.int32)
    reference: wp.array(dtype=wp.vec3)


# the pair lists a detection writes (a split cluster query has its own partial ones)
LIST_OUTPUTS = tuple(f"{kind}_{name}" for kind, ids in (("vt", "tri"), ("tv", "vertex"), ("ee", "edge"))
                     for name in ("count", ids, "dist", "ref", "rk"))


@wp.struct
class SolveContactArrays:
    """The part of ``SelfContactData`` the solve kernel reads, its arrays as ``Span``s
    (``sim.cloth.spans``: a Warp array descriptor is 56 bytes against a span's 16, and the
    solve kernel's arguments live in the constant cache). Built by ``solve_contact_arrays``; the
    kernel rebuilds a ``SelfContactData`` with these fields set (``contact_view``; the others are
    empty)."""

    enabled: int
    radius: float
    stiffness: float
    friction: float
    vt_capacity: int
    tv_capacity: int
    ee_capacity: int
    heavy_cap: int
    weight_floor: float
    pair_first: Span
    pair_count: Span
    pair_verts: Span
    pair_role: Span
    pair_ref: Span
    heavy: Span
    heavy_list: Span
    heavy_count: Span
    vt_count: Span
    vt_tri: Span
    vt_ref: Span
    tv_total: Span
    tv_first: Span
    tv_vertex: Span
    tv_ref: Span
    ee_total: Span
    ee_first: Span
    ee_edge: Span
    ee_ref: Span
    vt_rk: Span
    tv_rk: Span
    ee_rk: Span
    mesh_edges: Span
    particle_color: Span
    vertex_edge_offsets: Span
    vertex_edge_ids: Span
    vertex_edge_local: Span


SOLVE_CONTACT_SCALARS = tuple(n for n, v in SolveContactArrays.vars.items() if v.type is not Span)
SOLVE_CONTACT_ARRAYS = tuple(n for n, v in SolveContactArrays.vars.items() if v.type is Span)


def solve_contact_key(sc: SelfContactData) -> tuple:
    """What ``solve_contact_arrays(sc)`` depends on: the scalars and the array addresses."""
    return (tuple(getattr(sc, n) for n in SOLVE_CONTACT_SCALARS)
            + tuple(getattr(sc, n).ptr for n in SOLVE_CONTACT_ARRAYS))


def solve_contact_arrays(sc: SelfContactData) -> SolveContactArrays:
    """The ``SolveContactArrays`` of ``sc`` (its arrays must stay alive while it is used)."""
    a = SolveContactArrays()
    for n in SOLVE_CONTACT_SCALARS:
        setattr(a, n, getattr(sc, n))
    fill_spans(a, {n: getattr(sc, n) for n in SOLVE_CONTACT_ARRAYS})
    return a


@wp.func
def contact_view(a: SolveContactArrays) -> SelfContactData:
    """The ``SelfContactData`` the solve's functions take, rebuilt from ``a`` inside a kernel
    (every field of ``SolveContactArrays``, tests/test_self_contact_data.py checks)."""
    sc = SelfContactData()
    sc.enabled = a.enabled
    sc.radius = a.radius
    sc.stiffness = a.stiffness
    sc.friction = a.friction
    sc.vt_capacity = a.vt_capacity
    sc.tv_capacity = a.tv_capacity
    sc.ee_capacity = a.ee_capacity
    sc.heavy_cap = a.heavy_cap
    sc.weight_floor = a.weight_floor
    sc.pair_first = ints(a.pair_first)
    sc.pair_count = ints(a.pair_count)
    sc.pair_verts = vec4is(a.pair_verts)
    sc.pair_role = ints(a.pair_role)
    sc.pair_ref = vec3s(a.pair_ref)
    sc.heavy = ints(a.heavy)
    sc.heavy_list = ints(a.heavy_list)
    sc.heavy_count = ints(a.heavy_count)
    sc.vt_count = ints(a.vt_count)
    sc.vt_tri = ints(a.vt_tri)
    sc.vt_ref = vec3s(a.vt_ref)
    sc.tv_total = ints(a.tv_total)
    sc.tv_first = ints(a.tv_first)
    sc.tv_vertex = ints(a.tv_vertex)
    sc.tv_ref = vec3s(a.tv_ref)
    sc.ee_total = ints(a.ee_total)
    sc.ee_first = ints(a.ee_first)
    sc.ee_edge = ints(a.ee_edge)
    sc.ee_ref = vec3s(a.ee_ref)
    sc.vt_rk = ints(a.vt_rk)
    sc.tv_rk = ints(a.tv_rk)
    sc.ee_rk = ints(a.ee_rk)
    sc.mesh_edges = vec2is(a.mesh_edges)
    sc.particle_color = ints(a.particle_color)
    sc.vertex_edge_offsets = ints(a.vertex_edge_offsets)
    sc.vertex_edge_ids = ints(a.vertex_edge_ids)
    sc.vertex_edge_local = ints(a.vertex_edge_local)
    return sc


@wp.func
def has_pairs(sc: SelfContactData, i: int) -> bool:
    """Whether particle ``i`` takes part in a stored self-contact pair (VT, TV or EE) that holds
    back the coarse correction (``coarse_pairs``, ``records.vertex_summary_kernel``: one at least
    ``coarse_exclusion`` apart at rest); the pair arrays are read only when self-contact is on.
    Not on a ``contact_view`` (the solve's part of the data has no ``coarse_pairs``)."""
    if sc.enabled != 0:
        return sc.coarse_pairs[i] > 0
    return False


def connected_components(model) -> np.ndarray:
    """Connected-component id of every particle (separate pieces of cloth, e.g. layers)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as components

    e = model.mesh_edge_indices.numpy()
    n = model.particle_count
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    return components(adj, directed=False)[1].astype(np.int32)


def _pair_lists(sc: SelfContactData, model, capacity: int) -> None:
    """Zeroed pair lists of ``capacity`` per vertex, triangle and edge into ``sc``, and the
    per-vertex offsets into them (``tv_first``, ``ee_first``, ``tv_total``, ``ee_total``)."""
    w = warp()
    d = model.device
    n, nt, ne = model.particle_count, model.tri_count, model.mesh_edge_indices.shape[0]
    sc.vt_capacity = sc.tv_capacity = sc.ee_capacity = int(capacity)
    for name, ids, size in (("vt", "tri", n), ("tv", "vertex", nt), ("ee", "edge", ne)):
        setattr(sc, f"{name}_count", w.zeros(size, dtype=w.int32, device=d))
        setattr(sc, f"{name}_{ids}", w.zeros(size * capacity, dtype=w.int32, device=d))
        setattr(sc, f"{name}_dist", w.zeros(size * capacity, dtype=float, device=d))
        setattr(sc, f"{name}_ref", w.zeros(size * capacity, dtype=w.vec3, device=d))
        setattr(sc, f"{name}_rk", w.zeros(size * capacity, dtype=w.int32, device=d))
    sc.tv_total = w.zeros(n, dtype=w.int32, device=d)
    sc.ee_total = w.zeros(n, dtype=w.int32, device=d)
    sc.tv_first = w.zeros(model.vertex_tri_ids.shape[0], dtype=w.int32, device=d)
    sc.ee_first = w.zeros(model.vertex_mesh_edge_ids.shape[0], dtype=w.int32, device=d)


def _gather_records(sc: SelfContactData, model, pool: int, heavy_cap: int, heavy_threshold: int) -> None:
    """The pool of ``pool`` gather records per vertex on average, the heavy-vertex lists and the
    particles' colours into ``sc``."""
    w = warp()
    d = model.device
    n = model.particle_count
    sc.pool_size = int(pool) * n
    sc.pair_first = w.zeros(n, dtype=w.int32, device=d)
    sc.pair_count = w.zeros(n, dtype=w.int32, device=d)
    sc.pair_verts = w.zeros(max(sc.pool_size, 1), dtype=w.vec4i, device=d)
    sc.pair_role = w.zeros(max(sc.pool_size, 1), dtype=w.int32, device=d)
    sc.pair_ref = w.zeros(max(sc.pool_size, 1), dtype=w.vec3, device=d)
    sc.pair_cursor = w.zeros(1, dtype=w.int32, device=d)
    offsets = np.asarray(model.color_offsets, dtype=np.int32)
    sc.heavy_cap = int(heavy_cap) if pool > 0 else 0
    sc.heavy_threshold = int(heavy_threshold)
    sc.heavy = w.zeros(n, dtype=w.int32, device=d)
    sc.heavy_list = w.zeros(n, dtype=w.int32, device=d)
    sc.heavy_count = w.zeros(max(len(offsets) - 1, 1), dtype=w.int32, device=d)
    color = np.zeros(n, dtype=np.int32)
    color[model.color_vertices.numpy()] = np.repeat(np.arange(len(offsets) - 1, dtype=np.int32),
                                                    np.diff(offsets))
    sc.particle_color = w.array(color, dtype=w.int32, device=d)
    sc.color_start = w.array(offsets[:-1], dtype=w.int32, device=d)


def self_contact_data(model, *, radius: float, stiffness: float, friction: float, capacity: int,
                      coarse_exclusion: float, relative_lists: bool, pool: int, heavy_cap: int,
                      heavy_threshold: int, weight_floor: float) -> SelfContactData:
    """The ``SelfContactData`` of ``model``, its lists and records zeroed (``SelfContact`` says
    what each setting does)."""
    if not 0.0 <= weight_floor <= 1.0:
        raise ValueError(f"SelfContact: weight_floor must be in [0, 1], got {weight_floor}")
    if heavy_cap < 0 or heavy_threshold < 0:
        raise ValueError(f"SelfContact: heavy_cap and heavy_threshold must be >= 0, got {heavy_cap}, "
                         f"{heavy_threshold}")
    if coarse_exclusion < 0.0:
        raise ValueError(f"SelfContact: coarse_exclusion must be >= 0, got {coarse_exclusion}")
    w = warp()
    d = model.device
    sc = SelfContactData()
    sc.enabled = 1
    sc.relative_lists = 1 if relative_lists else 0
    sc.radius = float(radius)
    sc.stiffness = float(stiffness)
    sc.friction = float(friction)
    sc.weight_floor = float(weight_floor)
    _pair_lists(sc, model, capacity)
    _gather_records(sc, model, pool, heavy_cap, heavy_threshold)
    sc.mesh_edges = model.mesh_edge_indices
    sc.vertex_edge_offsets = model.vertex_mesh_edge_offsets
    sc.vertex_edge_ids = model.vertex_mesh_edge_ids
    sc.vertex_edge_local = model.vertex_mesh_edge_local
    sc.rest = model.particle_rest
    sc.panel = model.particle_panel
    sc.flat = model.particle_flat
    sc.component = w.array(connected_components(model), dtype=w.int32, device=d)
    sc.coarse_exclusion = float(coarse_exclusion)
    sc.coarse_pairs = w.zeros(model.particle_count, dtype=w.int32, device=d)
    sc.reference = w.zeros(model.instance_count, dtype=w.vec3, device=d)
    return sc


def disabled_data(device) -> SelfContactData:
    """A ``SelfContactData`` with ``enabled = 0``, zero settings and one-element arrays."""
    w = warp()
    sc = SelfContactData()
    empty = {wp.int32: w.zeros(1, dtype=w.int32, device=device),
             float: w.zeros(1, dtype=float, device=device),
             wp.vec2i: w.zeros(1, dtype=w.vec2i, device=device),
             wp.vec3: w.zeros(1, dtype=w.vec3, device=device),
             wp.vec4i: w.zeros(1, dtype=w.vec4i, device=device)}
    for name, var in SelfContactData.vars.items():
        if isinstance(var.type, wp.array):
            dtype = var.type.dtype
            setattr(sc, name, empty[float if dtype is wp.float32 else dtype])
        else:
            setattr(sc, name, 0.0 if var.type is wp.float32 else 0)
    return sc
