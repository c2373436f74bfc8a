"""Coarse-level correction of the VBD sweeps (two-level smoothed aggregation).

A Gauss-Seidel sweep moves a stiff membrane's force about one ring of edges, so within a
substep the sweeps cannot carry a running sleeve's pull across the 20-30 rings of a shoulder
strap (docs/BENCHMARKS.md, session 21). This module adds the missing long reach: between
sweeps, the residual of the substep's incremental potential is restricted to a coarse level
of about one node per 15 vertices, a linear coarse system is solved exactly, and its
solution is prolongated back as a displacement of every free particle.

Setup (numpy/scipy, once per distinct garment template, shared by its instances):

- **aggregates**: seeds picked greedily at graph distance > ``spacing`` from each other on the
  mesh's edge graph, every vertex joined to its nearest seed (a graph Voronoi cell, connected);
- **prolongation** ``P = S A``: ``A`` the aggregate indicator, smoothed once by ``S`` (each
  vertex averages its own and its neighbours' aggregates), so the correction has no jumps at
  aggregate borders; rows of pinned particles are zero (they do not move);
- **fine operator** ``K``: a scalar proxy of the membrane's stiffness, the P1 finite-element
  Laplacian (cotangent weights) times the longitudinal modulus ``lambda + 2 mu`` [N/m] of each
  triangle. Along a stretch it is the membrane's true stiffness; in shear and out of plane it is
  stiffer than the cloth, so the correction errs on the short side there (bending, contact and
  self-contact are left to the sweeps that follow);
- **coarse system** ``A_c = (1/h^2 + alpha/h) M_c + s K_c + C_c`` with ``K_c = P^T K P``
  (Galerkin, sparse), ``s`` the overshoot guard below, ``M_c = P^T m`` (lumped) and
  ``C_c = P^T c``, ``c`` the body contact's
  penalty stiffness at particles pressed onto the body plus the self-contact penalty stiffness
    at particles with cloth-cloth pairs (``has_pairs``: not those only in pairs closer than
    ``coarse_exclusion`` at rest, session 50), pressed at the correction (with ``prefactor``: at the
  substep's inertial targets, ``CoarseLevel.prepare``). The residual holds both contacts'
  forces; without their stiffness in ``A_c`` the correction answers them with the membrane
  alone: it pulled supported cloth into the body and blew the t-shirt up (session 22), and it
  threw stacked layers metres apart within 4 frames (session 23). Contact pins cloth as firmly
  as a pin does, so the coarse level must know where it holds.
  Its sparsity pattern is fixed, so its rows are put in reverse Cuthill-McKee order once (the
  t-shirt's 326 nodes: bandwidth 60) and each correction factors the band exactly.
- **overshoot guard** ``s = max(1, (1 + k_d/h) r / COARSE_OVERSHOOT)`` per instance (session 51,
  ``guard``): the proxy is softer than the sweeps' Hessian in two ways. The strain-rate damping
  (``k_d`` [s]) makes that Hessian ``1 + k_d/h`` times the elastic one
  (``energies.stvk_damped_vertex_force_hessian``): 1.7-1.8 for cotton at 12-14 substeps, 2.2-3.5
  at the retries' 20-42. And in a pure dilation the membrane is ``r = 2 (lambda + mu) / (lambda +
  2 mu)`` times stiffer than ``lambda + 2 mu`` (1.30 for cotton). Where stiffness outweighs
  inertia (small aggregates, short substeps) an exact correction overshoots by their product,
  and one that overshoots more than twice amplifies the error it should remove: without the
  guard a denim sheet at rest, no gravity, aggregates 2-3 edges apart, left rest by round-off
  alone (``tests/test_coarse.py``). The guard stiffens the proxy just enough to hold the
  overshoot at ``COARSE_OVERSHOOT``, no more: the proxy is already far stiffer than the cloth in
  shear, bending and rigid rotation (a scalar Laplacian is not rotation-invariant), and the
  full factor ``1 + k_d/h`` left the fine long sleeve's swinging sleeves crumpled (session 51).
  Even the guard raised the fine walks' strain on the CPU, so the job keeps it off
  (``sim.simulate.JOB_COARSE_GUARD``); a bare ``VBDConfig`` has it on.
  The system solved is ``A_c / s`` for ``P^T r / s`` (the same solution): its off-diagonal part
  stays ``K_c``'s, and only the diagonal and the right-hand side change with ``h``.

Per correction (``CoarseLevel.correct``): the solve kernel's evaluate variant writes the residual
``r = -dG/dx`` at ``x`` (inertia, membrane, bending, damping, body and self-contact);
``restrict_kernel`` forms ``P^T r`` and the diagonal (with ``prefactor``, two levels, the
diagonal is formed per substep instead, by ``CoarseLevel.prepare`` from the substep-start
contacts and the inertial targets beside the first sweeps, and on CUDA a thread block per
instance factors each system there, ``sim.cloth.coarse_block``); ``CoarseLevel.solve`` solves
each instance's system: on CUDA a thread block per instance factors and solves it (0.31 ms for
326 nodes on an H100 against 20 ms for one thread; with ``prefactor`` one warp substitutes with
the prepared factor),
on the CPU one thread per instance (``band_solve_kernel``, banded Cholesky);
``prolong_kernel`` adds ``P dx_c`` to ``x`` and to the next sweep's snapshot. The prolongated
move is limited where a move could cross something, since the coarse system is linear and
blind to geometry: at a particle with self-contact pairs (``has_pairs``) to a quarter of the contact radius
(``SELF_CONTACT_CAP``) and to the sweeps' displacement bound when bounds are on; at a particle
on the body not deeper than it is or than its thickness shell; at a particle of an instance
with a body but outside the contact margin to half the margin's room. Every kernel is a gather
(no atomics): deterministic on every device.

Three levels (``levels``; automatic where a garment's coarse level has more than
``AUTO_MAX_NODES`` nodes, whose band would not fit a CUDA block): an inner level aggregates the
coarse level's own graph (``aggregate_graph``), and ``CoarseLevel.solve`` runs a symmetric
two-grid cycle on the coarse system: l1-Jacobi passes (``level_pass_kernel``), the inner level's exact
solve of the restricted residual with the Galerkin operator ``P2^T A_c P2`` (its mass and contact
part added to the inner band at each correction, ``galerkin_band_kernel``), the prolongation
(``prolong_level_kernel``) and as many passes again.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from sim.cloth import coarse_block
from sim.cloth.lanes import lane_mask, lane_read, lane_read_vec3
from sim.cloth.model import mesh_edges
from sim.cloth.self_contact import SelfContactData, has_pairs
from sim.cloth.vbd_kernels import PINNED, bound_step, load_particle_step


def mesh_edge_graph(vertex_count: int, faces: np.ndarray):
    """Symmetric CSR adjacency (scipy) of the mesh's edge graph (``model.mesh_edges``)."""
    import scipy.sparse as sp

    e = mesh_edges(faces)
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(vertex_count, vertex_count))
    return (g + g.T).tocsr()


def aggregate(adjacency, spacing: int) -> tuple[np.ndarray, np.ndarray]:
    """(aggregate index of every vertex, the aggregates' seed vertices): seeds chosen greedily
    in index order at graph distance ``> spacing`` from each other, each vertex joined to its
    nearest seed (ties: the seed found first by ``scipy.sparse.csgraph.dijkstra``). Every
    component gets at least one seed, and every aggregate is connected."""
    from scipy.sparse.csgraph import dijkstra

    n = adjacency.shape[0]
    indptr, indices = adjacency.indptr, adjacency.indices
    blocked = np.zeros(n, dtype=bool)
    seeds = []
    for v in range(n):
        if blocked[v]:
            continue
        seeds.append(v)
        # block the seed's ball of radius ``spacing`` (breadth-first)
        frontier = [v]
        blocked[v] = True
        for _ in range(spacing):
            nxt = []
            for u in frontier:
                for w in indices[indptr[u]:indptr[u + 1]]:
                    if not blocked[w]:
                        blocked[w] = True
                        nxt.append(w)
            frontier = nxt
    seeds = np.asarray(seeds, dtype=np.int64)
    _, _, sources = dijkstra(adjacency, directed=False, indices=seeds, unweighted=True, min_only=True,
                             return_predecessors=True)
    lookup = np.full(n, -1, dtype=np.int64)
    lookup[seeds] = np.arange(len(seeds))
    return lookup[sources], seeds


# automatic spacing (``spacing`` 0): the least spacing, from ``AUTO_MIN_SPACING`` on, that gives
# a template at most ``AUTO_MAX_NODES`` coarse nodes. The t-shirt's 4,925 vertices take spacing 4
# (202 nodes, band 37: the issue setting, docs/BENCHMARKS.md sessions 23-24). A finer garment
# keeps spacing 4 and gets a third level instead (``coarse_template``): its 20k vertices give 808
# nodes, whose band (87) would not fit a CUDA block's shared memory (``coarse_block``); the
# coarser spacing that would fit (8) gave higher worst strains than three levels (session 26).
AUTO_MIN_SPACING = 4
AUTO_MAX_NODES = 256


def auto_aggregate(adjacency, min_spacing: int = AUTO_MIN_SPACING,
                   max_nodes: int = AUTO_MAX_NODES) -> tuple[np.ndarray, np.ndarray]:
    """``aggregate`` at the least spacing from ``min_spacing`` that gives at most ``max_nodes``
    seeds. An aggregate of spacing ``s`` holds about ``1.5 s^2`` vertices of a near-uniform
    triangle mesh, so the search starts there and grows the spacing until the seeds fit."""
    n = adjacency.shape[0]
    spacing = max(min_spacing, int(np.sqrt(n / (1.5 * max_nodes))))
    while True:
        agg, seeds = aggregate(adjacency, spacing)
        if len(seeds) <= max_nodes:
            return agg, seeds
        spacing += 1


def aggregate_graph(adjacency, agg: np.ndarray):
    """Symmetric CSR adjacency of the aggregates: two are neighbours where an edge of
    ``adjacency`` joins their members (the coarse level's own mesh graph)."""
    import scipy.sparse as sp

    n, nc = adjacency.shape[0], int(agg.max()) + 1
    indicator = sp.csr_matrix((np.ones(n), (np.arange(n), agg)), shape=(n, nc))
    g = (indicator.T @ adjacency @ indicator).tocsr()
    g.setdiag(0.0)
    g.eliminate_zeros()
    g.data[:] = 1.0
    return g


def cotangent_stiffness(rest: np.ndarray, faces: np.ndarray, modulus: np.ndarray, vertex_count: int):
    """Scalar P1 stiffness matrix ``K`` (scipy CSR, [N/m]) of ``sum_t modulus_t/2 int |grad u|^2``
    on the rest mesh: edge weights ``modulus/2 cot`` of the opposite corners, summed over the
    edge's triangles and clamped at zero (an obtuse pair would make it indefinite)."""
    import scipy.sparse as sp

    rows, cols, vals = [], [], []
    for k in range(3):
        a, b, c = faces[:, k], faces[:, (k + 1) % 3], faces[:, (k + 2) % 3]
        u, v = rest[b] - rest[a], rest[c] - rest[a]
        cot = np.einsum("ij,ij->i", u, v) / np.maximum(np.linalg.norm(np.cross(u, v), axis=1), 1e-20)
        rows.append(np.minimum(b, c))
        cols.append(np.maximum(b, c))
        vals.append(0.5 * modulus * cot)
    w = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(vertex_count, vertex_count)).tocsr()
    w.sum_duplicates()
    w.data = np.maximum(w.data, 0.0)
    w = w + w.T
    return (sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w).tocsr()


@dataclass
class CoarseTemplate:
    """One coarse level of a garment template (local indices), built on the level below it."""

    prolongation: Any  # scipy CSR (n, nc): rows of pinned particles are zero
    stiffness: Any  # scipy CSR (nc, nc): K_c = P^T K P [N/m]
    mass: np.ndarray  # (nc,) lumped P^T m [kg]
    order: np.ndarray  # (nc,) band row -> node (reverse Cuthill-McKee of K_c)
    band: np.ndarray  # (nc, b + 1) lower band of K_c in that order, band[r, t] = K_c[r, r - t]
    # a coarser level on this one's nodes (its ``prolongation`` maps them to its own): this
    # level's system is then smoothed around an exact solve of the inner one's (``CoarseLevel``)
    inner: CoarseTemplate | None = None


def galerkin_level(adjacency, stiffness, mass: np.ndarray, free: np.ndarray, agg: np.ndarray,
                   overlap: bool = False) -> CoarseTemplate:
    """The coarse level of the aggregates ``agg`` of a level with edge graph ``adjacency``,
    stiffness ``stiffness`` (scipy, [N/m]), lumped ``mass`` [kg] and ``free`` (bool) nodes:
    smoothed-aggregation prolongation, Galerkin stiffness, lumped mass and the stiffness's
    lower band in reverse Cuthill-McKee order; ``overlap``: the band also covers every pair of
    nodes whose prolongations overlap (the pattern of ``P^T D P``, ``D`` diagonal)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    n = adjacency.shape[0]
    nc = int(agg.max()) + 1
    indicator = sp.csr_matrix((np.ones(n), (np.arange(n), agg)), shape=(n, nc))
    smooth = adjacency + sp.identity(n, format="csr")
    smooth = sp.diags(1.0 / np.asarray(smooth.sum(axis=1)).ravel()) @ smooth
    p = (sp.diags(free.astype(float)) @ smooth @ indicator).tocsr()
    p.eliminate_zeros()
    kc = (p.T @ stiffness @ p).tocsr()
    kc.eliminate_zeros()
    mc = np.asarray(p.T @ mass.astype(np.float64)).ravel()
    pattern = (abs(kc) + abs(p.T @ p)).tocsr() if overlap else kc
    order = np.asarray(reverse_cuthill_mckee(pattern, symmetric_mode=True), dtype=np.int64)
    kp = kc[order][:, order].tocoo()
    pp = pattern[order][:, order].tocoo() if overlap else kp
    width = int((pp.row - pp.col).max()) if pp.nnz else 0
    lower = kp.row >= kp.col
    band = np.zeros((nc, width + 1))
    band[kp.row[lower], (kp.row - kp.col)[lower]] = kp.data[lower]
    return CoarseTemplate(p, kc, mc, order, band)


def coarse_template(rest: np.ndarray, faces: np.ndarray, mass: np.ndarray, pinned: np.ndarray,
                    modulus: np.ndarray, spacing: int, levels: int = 0) -> CoarseTemplate:
    """Build the coarse level of one garment (module docstring): ``rest`` (n, 3) [m], ``faces``
    (F, 3), ``mass`` (n,) [kg], ``pinned`` (n,) bool, ``modulus`` (F,) ``lambda + 2 mu`` [N/m].

    ``spacing`` 0: ``AUTO_MIN_SPACING`` with ``levels`` 0 or 3, ``auto_aggregate`` with 2.
    ``levels``: 2 solves the coarse level exactly; 3 adds an inner level on its aggregate graph
    (``auto_aggregate`` from spacing 1, at most ``AUTO_MAX_NODES`` nodes) whose solve, between
    smoothing passes, solves this one; 0 picks 3 where the coarse level has more than
    ``AUTO_MAX_NODES`` nodes."""
    n = len(rest)
    adjacency = mesh_edge_graph(n, faces)
    if spacing == 0:
        agg, _ = auto_aggregate(adjacency) if levels == 2 else aggregate(adjacency, AUTO_MIN_SPACING)
    else:
        agg, _ = aggregate(adjacency, spacing)
    k = cotangent_stiffness(rest.astype(np.float64), faces, modulus.astype(np.float64), n)
    level = galerkin_level(adjacency, k, mass, ~pinned, agg)
    nc = len(level.mass)
    if levels == 3 or (levels == 0 and nc > AUTO_MAX_NODES):
        graph = aggregate_graph(adjacency, agg)
        inner, _ = auto_aggregate(graph, min_spacing=1)
        level.inner = galerkin_level(graph, level.stiffness, level.mass, np.ones(nc, dtype=bool), inner,
                                     overlap=True)
    return level


def galerkin_slots(exact: list) -> Any:
    """Where ``P2^T diag(d) P2`` adds to the inner levels' bands: a scipy CSR matrix with a row per
    slot of the flat band arrays (the instances' ``exact`` templates' bands, in order; diagonal
    slots stay empty) and a column per coarse node ``J`` of the instances, holding ``P2_Ja P2_Jb``
    for the slot of nodes ``a``, ``b``."""
    import scipy.sparse as sp

    slots, nodes, values = [], [], []
    node_off = band_off = 0
    local: dict[int, tuple] = {}
    for e in exact:
        n1, n2 = e.prolongation.shape
        w = e.band.shape[1]
        if id(e) not in local:
            p2 = e.prolongation.tocsr()
            rank = np.empty(n2, dtype=np.int64)
            rank[e.order] = np.arange(n2)
            ls, ln, lv = [], [], []
            for j in range(n1):
                cols = rank[p2.indices[p2.indptr[j]:p2.indptr[j + 1]]]
                vals = p2.data[p2.indptr[j]:p2.indptr[j + 1]]
                ra, rb = np.meshgrid(cols, cols, indexing="ij")
                va = np.outer(vals, vals)
                low = ra > rb
                if np.any(ra[low] - rb[low] >= w):
                    raise ValueError("galerkin_slots: a prolongation overlap lies outside the inner band")
                ls.append(ra[low] * w + (ra[low] - rb[low]))
                ln.append(np.full(int(low.sum()), j))
                lv.append(va[low])
            local[id(e)] = (np.concatenate(ls), np.concatenate(ln), np.concatenate(lv))
        ls, ln, lv = local[id(e)]
        slots.append(ls + band_off)
        nodes.append(ln + node_off)
        values.append(lv)
        node_off += n1
        band_off += n2 * w
    m = sp.coo_matrix((np.concatenate(values), (np.concatenate(slots), np.concatenate(nodes))),
                      shape=(band_off, node_off)).tocsr()
    m.sum_duplicates()
    return m


COARSE_OVERSHOOT = 1.8
"""The most a coarse correction may overshoot the sweeps' own Hessian in its stiffest mode, as a
factor (``CoarseLevel`` ``guard``; session 51). An exact correction that overshoots by ``w``
leaves ``1 - w`` of the error it removes, so ``w`` must stay under 2; 1.8 leaves room for the
membrane's stiffening under stretch."""

# largest move of a correction at a particle with self-contact pairs, in self-contact radii
# (bounds off, the default, nothing else keeps a correction from carrying a layer through another)
SELF_CONTACT_CAP = wp.constant(0.25)


def _template_key(*arrays: np.ndarray) -> str:
    h = hashlib.sha1()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
        h.update(str(a.shape).encode())
    return h.hexdigest()


class CoarseLevel:
    """The coarse level of every instance of a ``ClothModel`` on its device (module docstring).

    Args:
        model: the cloth model.
        particles: the solver's per-particle arrays a Newton step loads besides the model's
            (``vbd_kernels.load_particle_step``): substep start positions, inertial targets and
            the body contact's point, normal, body velocity and active flag, read at each
            correction.
        k_contact: the body contact's penalty stiffness [N/m].
        contact_margin: the body contact's detection margin [m].
        air_damping: the solver's air damping [1/s].
        spacing: seed spacing of the aggregates [edges]; 3 gives about 15 vertices per coarse
            node on a near-uniform mesh; 0: per template, the least from ``AUTO_MIN_SPACING``
            that gives at most ``AUTO_MAX_NODES`` nodes (``auto_aggregate``) with ``levels`` 2,
            else ``AUTO_MIN_SPACING``.
        levels: 2, 3 or 0 (automatic; ``coarse_template``).
        smoothing: l1-Jacobi passes before and after the inner solve (three levels).
        prefactor: with two levels, the diagonal and (CUDA) the factor at the substep start
            (``prepare``) instead of at each correction (``VBDConfig.coarse_prefactor``).
        guard: the overshoot guard (module docstring; ``VBDConfig.coarse_guard``); off:
            ``K_c`` alone, as before session 51.
    """

    def __init__(self, model, particles: tuple, k_contact: float, contact_margin: float, air_damping: float,
                 spacing: int = 3, levels: int = 0, smoothing: int = 2, prefactor: bool = False,
                 guard: bool = True):
        import scipy.sparse as sp

        if spacing < 0:
            raise ValueError(f"CoarseLevel: spacing must be >= 1 (0: automatic), got {spacing}")
        if levels not in (0, 2, 3):
            raise ValueError(f"CoarseLevel: levels must be 2, 3 or 0 (automatic), got {levels}")
        if smoothing < 1:
            raise ValueError(f"CoarseLevel: smoothing must be >= 1, got {smoothing}")
        d = model.device
        rest = model.particle_rest.numpy().astype(np.float64)
        mass = model.particle_mass.numpy().astype(np.float64)
        pinned = model.particle_flags.numpy() == PINNED
        modulus = model.tri_lam.numpy().astype(np.float64) + 2.0 * model.tri_mu.numpy().astype(np.float64)
        faces = np.asarray(model.faces)
        starts = np.asarray(model.instance_starts)
        tri_inst = np.searchsorted(starts, faces[:, 0], side="right") - 1
        tri_starts = np.searchsorted(tri_inst, np.arange(model.instance_count + 1))
        templates: dict[str, CoarseTemplate] = {}
        blocks = []
        for k in range(model.instance_count):
            v0, v1 = int(starts[k]), int(starts[k + 1])
            f = faces[tri_starts[k]:tri_starts[k + 1]] - v0
            parts = (rest[v0:v1], f, mass[v0:v1], pinned[v0:v1], modulus[tri_starts[k]:tri_starts[k + 1]])
            key = _template_key(*parts)
            if key not in templates:
                templates[key] = coarse_template(*parts, spacing=spacing, levels=levels)
            blocks.append(templates[key])
        self.templates = list(templates.values())
        p = sp.block_diag([b.prolongation for b in blocks], format="csr")
        mc = np.concatenate([b.mass for b in blocks])
        self.node_count = len(mc)
        self.prolongation = p
        kc = sp.block_diag([b.stiffness for b in blocks], format="csr")

        def arr(a, dtype):
            return wp.array(np.ascontiguousarray(a), dtype=dtype, device=d)

        def csr(m):
            return (arr(m.indptr.astype(np.int32), wp.int32), arr(m.indices.astype(np.int32), wp.int32),
                    arr(m.data.astype(np.float32), float))

        self._p, self._r = csr(p), csr(p.T.tocsr())
        self._mass = arr(mc.astype(np.float32), float)
        self._kdiag = arr(kc.diagonal().astype(np.float32), float)
        # each node's instance's largest strain-rate damping k_d [s] and largest dilation ratio
        # 2 (lambda + mu) / (lambda + 2 mu) over ``COARSE_OVERSHOOT`` (both 0: ``guard`` off)
        per_inst = np.zeros((model.instance_count, 2))
        if guard:
            tri_damping = model.tri_damping.numpy().astype(np.float64)
            lam, mu = model.tri_lam.numpy().astype(np.float64), model.tri_mu.numpy().astype(np.float64)
            dilation = 2.0 * (lam + mu) / np.maximum(lam + 2.0 * mu, 1e-30)
            for k in range(model.instance_count):
                tris = slice(tri_starts[k], tri_starts[k + 1])
                per_inst[k] = (tri_damping[tris].max(initial=0.0),
                               dilation[tris].max(initial=0.0) / COARSE_OVERSHOOT)
        self.node_overshoot = np.repeat(per_inst, [len(b.mass) for b in blocks], axis=0)
        self._node_overshoot = arr(self.node_overshoot.astype(np.float32), wp.vec2)
        nc = self.node_count
        self._rhs = wp.zeros(nc, dtype=wp.vec3, device=d)
        self._rhs_part = wp.zeros(nc * RESTRICT_LANES, dtype=wp.vec3, device=d)
        self._k_part = wp.zeros(nc * RESTRICT_LANES, dtype=float, device=d)
        self._diag = wp.zeros(nc, dtype=float, device=d)
        self._dx = wp.zeros(nc, dtype=wp.vec3, device=d)
        # three levels where any template has an inner level; a template without one then
        # takes itself as its inner level (identity prolongation), whose exact solve the
        # smoothing passes leave exact
        self.levels = 3 if any(b.inner is not None for b in blocks) else 2
        self.smoothing = int(smoothing)
        if self.levels == 3:
            own = {id(b): CoarseTemplate(sp.identity(len(b.mass), format="csr"), b.stiffness, b.mass, b.order,
                                         b.band) for b in blocks if b.inner is None}
            exact = [b.inner if b.inner is not None else own[id(b)] for b in blocks]
            p2 = sp.block_diag([e.prolongation for e in exact], format="csr")
            off = (kc - sp.diags(kc.diagonal())).tocsr()
            off.eliminate_zeros()
            self._p2, self._r2, self._off = csr(p2), csr(p2.T.tocsr()), csr(off)
            # l1-Jacobi: the diagonal plus the off-diagonal's absolute row sum, a convergent
            # smoother for any symmetric positive definite level matrix
            self._l1 = arr(np.asarray(abs(off).sum(axis=1)).ravel().astype(np.float32), float)
            self._x1 = wp.zeros(nc, dtype=wp.vec3, device=d)
            self._res1 = wp.zeros(nc, dtype=wp.vec3, device=d)
            kc2 = sp.block_diag([e.stiffness for e in exact], format="csr")
            self._kdiag2 = arr(kc2.diagonal().astype(np.float32), float)
            nc2 = kc2.shape[0]
            self._exact = (wp.zeros(nc2, dtype=wp.vec3, device=d), wp.zeros(nc2, dtype=float, device=d),
                           wp.zeros(nc2, dtype=wp.vec3, device=d))
            self._galerkin = csr(galerkin_slots(exact))
        else:
            self._galerkin = None
            exact = blocks
            self._exact = (self._rhs, self._diag, self._dx)
        self.exact_node_count = len(self._exact[0])
        # banded Cholesky of each instance's exactly solved system: band rows in RCM order, per
        # instance (node start, node count, band width, offset of its band in the flat band arrays)
        widths = np.array([e.band.shape[1] - 1 for e in exact], dtype=np.int64)
        counts = np.array([len(e.mass) for e in exact], dtype=np.int64)
        band_off = np.concatenate([[0], np.cumsum(counts * (widths + 1))])
        node_off = np.concatenate([[0], np.cumsum(counts)])
        self._inst = (arr(node_off[:-1].astype(np.int32), wp.int32), arr(counts.astype(np.int32), wp.int32),
                      arr(widths.astype(np.int32), wp.int32), arr(band_off[:-1].astype(np.int64), wp.int64))
        self._order = arr(np.concatenate([e.order for e in exact]).astype(np.int32), wp.int32)
        self._band_k = arr(np.concatenate([e.band.ravel() for e in exact]).astype(np.float32), float)
        self._band = wp.zeros(int(band_off[-1]), dtype=float, device=d)
        # three levels: the inner band's values at each correction (``galerkin_band_kernel``)
        self._band_a = wp.zeros_like(self._band_k) if self.levels == 3 else self._band_k
        self._y = wp.zeros(int(node_off[-1]), dtype=wp.vec3, device=d)
        self.residual = wp.zeros(model.particle_count, dtype=wp.vec3, device=d)
        self.model = model
        self._particles = tuple(particles)
        self._k_contact = float(k_contact)
        self._contact_margin = float(contact_margin)
        self._air_damping = float(air_damping)
        # CUDA: a thread block per instance (sim.cloth.coarse_block) where its band fits in
        # one block's shared memory
        self.block_kernel = None
        self.block_threads = coarse_block.threads(int(widths.max()))
        # with two levels and ``prefactor`` the system's matrix is known at the substep start
        # (``prepare``), so the block path splits: the factor there (beside the sweeps), the
        # substitutions at each correction; the three-level path's inner band changes at each
        # correction
        self.prefactor = bool(prefactor) and self.levels == 2
        self.factor_kernel = self.substitute_kernel = None
        device = wp.get_device(d)
        # CUDA: a node's lanes summed by shuffles in the restriction's own launch
        # (``restrict_lanes_kernel``; session 41); the CPU adds them in a second launch
        self.restrict_lanes = device.is_cuda
        self._no_flags = wp.zeros(0, dtype=wp.int32, device=d)  # ``restrict``: the pairs of ``sc_data``
        if device.is_cuda:
            need = max(coarse_block.shared_floats(int(c), int(b))
                       for c, b in zip(counts, widths, strict=True))
            if 4 * coarse_block.padded(need) <= device.max_shared_memory_per_block - 1024:
                self.block_kernel = coarse_block.cooperative_kernel(need)
                if self.prefactor:
                    self.factor_kernel = coarse_block.factor_kernel(need)
                    self.substitute_kernel = coarse_block.substitute_kernel(need)

    def prepare(self, h: float, sc_data, pair_flags=None) -> None:
        """With ``prefactor``: what every correction of a substep of length ``h`` [s] shares,
        made from the substep's start: the coarse diagonal (``diagonal``) with the body contacts
        pressed at the inertial targets ``y`` (where the cloth goes if nothing holds it; the
        solver's substep-start contact planes) and ``sc_data``'s pairs (``restrict``), and on the
        split block path each instance's factor (``factor``). It reads nothing a sweep writes, so
        the solver runs it beside the first sweeps (on a side stream on CUDA; with
        ``coarse_early`` beside the self-contact detection already) and joins it before the first
        correction: the factorization, most of a correction's time, leaves the chain of
        dependent launches (session 30). Pressed at the substep-start positions instead, two corrections
        per substep threw cloth dropped on a sphere off it (``tests/test_coarse.py``). Three
        levels always take the diagonal at each correction (their inner band is assembled per
        correction anyway; from ``y`` the cycle let that cloth come within 0.9 mm of the
        sphere).

        ``pair_flags`` (the solver's ``coarse_early``): the self-contact stiffness at the
        particles flagged there (the pairs of the previous substep's end) instead of at those
        with pairs in ``sc_data``, so that ``prepare`` need not wait for this substep's
        detection."""
        if not self.prefactor:
            return
        self.restrict(h, self._particles[1], sc_data, RESTRICT_DIAGONAL, pair_flags)
        self.factor()

    def correct(self, h: float, x, snap_out, sc_data, instance_body) -> None:
        """Solve the coarse system of a substep of length ``h`` [s] (with ``prefactor`` its
        diagonal and factor from ``prepare``) for ``self.residual`` (the forces ``-dG/dx`` at
        ``x`` [N], written by the solve kernel's evaluate variant) and add the prolongated
        displacement to ``x`` (free particles) and ``snap_out``, bounded like a sweep's moves by
        ``sc_data`` (the sweeps' self-contact data); ``instance_body``: the control's body mesh
        of each instance (0: none)."""
        m = self.model
        # the right-hand side, and the diagonal at x where ``prepare`` did not form it
        parts = RESTRICT_RHS if self.prefactor else RESTRICT_RHS | RESTRICT_DIAGONAL
        self.restrict(h, x, sc_data, parts)
        self.solve()
        wp.launch(prolong_kernel, dim=m.particle_count,
                  inputs=[self._dx, *self._p, h, *self._particles, m.particle_mass, m.particle_flags,
                          m.particle_instance, m.instance_thickness, m.instance_friction, instance_body,
                          self._contact_margin, sc_data],
                  outputs=[x, snap_out], device=m.device)

    def restrict(self, h: float, x, sc_data, parts: int = 3, pair_flags=None) -> None:
        """The coarse right-hand side ``P^T residual / s`` (``parts`` bit ``RESTRICT_RHS``) and
        diagonal ``(m_c (1/h^2 + alpha/h) + P^T k) / s + K_c,JJ`` (bit ``RESTRICT_DIAGONAL``; ``s``
        the overshoot guard per instance, 1 without ``guard``, module docstring; ``k``: body
        contact penalty at particles of ``x`` pressed onto the body by the solver's contacts,
        self-contact penalty at particles with pairs in ``sc_data``, or flagged in ``pair_flags``
        where given) of a substep of length ``h`` [s]; both in one pass by default."""
        m = self.model
        if pair_flags is None:
            pair_flags = self._no_flags
        _, _, point, normal, _, active = self._particles
        inertia = 1.0 / (h * h) + self._air_damping / h
        if self.restrict_lanes:
            if not wp.get_device(m.device).is_cuda:
                raise ValueError("CoarseLevel.restrict_lanes needs CUDA (lane shuffles; the CPU adds "
                                 "the lanes in a second launch)")
            threads = self.node_count * RESTRICT_LANES
            wp.launch(restrict_lanes_kernel, dim=threads,
                      inputs=[parts, self.residual, *self._r, x, m.particle_instance, point, normal, active,
                              m.instance_thickness, self._k_contact, sc_data, pair_flags, self._mass,
                              self._kdiag, self._node_overshoot, inertia, 1.0 / h, threads],
                      outputs=[self._rhs, self._diag], device=m.device)
            return
        wp.launch(restrict_kernel, dim=self.node_count * RESTRICT_LANES,
                  inputs=[parts, self.residual, *self._r, x, m.particle_instance, point, normal, active,
                          m.instance_thickness, self._k_contact, sc_data, pair_flags],
                  outputs=[self._rhs_part, self._k_part], device=m.device)
        wp.launch(restrict_sum_kernel, dim=self.node_count,
                  inputs=[parts, self._rhs_part, self._k_part, self._mass, self._kdiag, self._node_overshoot,
                          inertia, 1.0 / h],
                  outputs=[self._rhs, self._diag], device=m.device)

    def factor(self) -> None:
        """On the split block path (CUDA, two levels, ``factor_kernel`` set): each instance's
        ``L D L^T`` of its coarse system with the current diagonal, for ``solve``. Elsewhere
        nothing: ``solve`` factors as it solves."""
        if self.factor_kernel is None:
            return
        m = self.model
        wp.launch_tiled(self.factor_kernel, dim=[m.instance_count], block_dim=self.block_threads,
                        inputs=[self._diag, *self._inst, self._order, self._band_k], outputs=[self._band],
                        device=m.device)

    def solve(self) -> None:
        """Every instance's coarse system for the current right-hand side and diagonal: solved
        exactly with two levels (on the split block path with ``factor``'s factor, which must be
        current); with three, ``smoothing`` l1-Jacobi passes, the inner level's
        exact solve of the residual with the Galerkin operator ``P2^T A_c P2`` (its mass and
        contact part added to the inner band here, ``galerkin_band_kernel``), its prolongation,
        and as many passes again (a two-grid cycle, symmetric, so the correction stays a descent
        direction)."""
        m = self.model
        if self.levels == 2:
            self.exact_solve()
            return
        bufs = (self._dx, self._x1)
        nc, d = self.node_count, m.device
        for j in range(2 * self.smoothing):
            if j == self.smoothing:
                wp.launch(level_pass_kernel, dim=nc,
                          inputs=[bufs[j % 2], self._rhs, self._diag, *self._off, self._l1, PASS_RESIDUAL],
                          outputs=[self._res1], device=d)
                wp.launch(restrict_level_kernel, dim=self.exact_node_count,
                          inputs=[self._res1, self._diag, self._kdiag, *self._r2, self._kdiag2],
                          outputs=[self._exact[0], self._exact[1]], device=d)
                wp.launch(galerkin_band_kernel, dim=self._band_a.shape[0],
                          inputs=[self._band_k, self._diag, self._kdiag, *self._galerkin],
                          outputs=[self._band_a], device=d)
                self.exact_solve()
                wp.launch(prolong_level_kernel, dim=nc, inputs=[self._exact[2], *self._p2],
                          outputs=[bufs[j % 2]], device=d)
            # pass j reads bufs[j % 2] and writes bufs[(j + 1) % 2]: the last lands in ``_dx``
            wp.launch(level_pass_kernel, dim=nc,
                      inputs=[bufs[j % 2], self._rhs, self._diag, *self._off, self._l1,
                              PASS_FIRST if j == 0 else PASS_SMOOTH],
                      outputs=[bufs[(j + 1) % 2]], device=d)

    def exact_solve(self) -> None:
        """The exactly solved level's systems (``_exact``: right-hand side, diagonal, solution):
        the block kernel on CUDA where it fits, else one thread per instance."""
        m = self.model
        rhs, diag, dx = self._exact
        if self.substitute_kernel is not None:
            wp.launch_tiled(self.substitute_kernel, dim=[m.instance_count],
                            block_dim=coarse_block.SUBSTITUTE_THREADS,
                            inputs=[rhs, *self._inst, self._order, self._band], outputs=[dx], device=m.device)
        elif self.block_kernel is not None:
            wp.launch_tiled(self.block_kernel, dim=[m.instance_count], block_dim=self.block_threads,
                            inputs=[rhs, diag, *self._inst, self._order, self._band_a],
                            outputs=[dx], device=m.device)
        else:
            wp.launch(band_solve_kernel, dim=m.instance_count,
                      inputs=[rhs, diag, *self._inst, self._order, self._band_a],
                      outputs=[self._band, self._y, dx], device=m.device)


@wp.func
def level_product(i: int, x: wp.array(dtype=wp.vec3), diag: wp.array(dtype=float),
                  offsets: wp.array(dtype=wp.int32), ids: wp.array(dtype=wp.int32),
                  weights: wp.array(dtype=float)) -> wp.vec3:
    """Row ``i`` of ``A_c x``: ``diag`` (mass, stiffness and contact) times ``x_i`` plus the
    stiffness's off-diagonal row (CSR ``offsets, ids, weights``)."""
    s = diag[i] * x[i]
    for k in range(offsets[i], offsets[i + 1]):
        s = s + weights[k] * x[ids[k]]
    return s


# what ``level_pass_kernel`` writes
PASS_FIRST = wp.constant(0)  # an l1-Jacobi pass from x = 0
PASS_SMOOTH = wp.constant(1)  # an l1-Jacobi pass from x
PASS_RESIDUAL = wp.constant(2)  # the residual rhs - A_c x


@wp.kernel
def level_pass_kernel(
    x: wp.array(dtype=wp.vec3),
    rhs: wp.array(dtype=wp.vec3),
    diag: wp.array(dtype=float),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    l1: wp.array(dtype=float),
    mode: int,
    out: wp.array(dtype=wp.vec3),
):
    """Coarse node ``i`` of the coarse system ``A_c x = rhs``: an l1-Jacobi pass ``x + (rhs - A_c
    x) / (diag + l1)`` (``PASS_SMOOTH``; ``l1`` the off-diagonal's absolute row sum), the same
    from ``x = 0`` (``PASS_FIRST``, ``x`` not read), or the residual ``rhs - A_c x``
    (``PASS_RESIDUAL``)."""
    i = wp.tid()
    if mode == PASS_FIRST:
        out[i] = rhs[i] / (diag[i] + l1[i])
    else:
        r = rhs[i] - level_product(i, x, diag, offsets, ids, weights)
        if mode == PASS_RESIDUAL:
            out[i] = r
        else:
            out[i] = x[i] + r / (diag[i] + l1[i])


@wp.kernel
def restrict_level_kernel(
    res: wp.array(dtype=wp.vec3),
    diag: wp.array(dtype=float),
    node_stiffness: wp.array(dtype=float),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    inner_stiffness: wp.array(dtype=float),
    rhs_out: wp.array(dtype=wp.vec3),
    diag_out: wp.array(dtype=float),
):
    """Inner node ``c``: ``rhs = P2^T res`` and the Galerkin diagonal ``K_2,cc + sum_J P2_Jc^2
    d_J``, ``d = diag - node_stiffness`` the coarse diagonal's mass and contact part
    (``offsets, ids, weights``: ``P2^T`` as CSR)."""
    c = wp.tid()
    s = wp.vec3(0.0)
    dc = float(0.0)
    for k in range(offsets[c], offsets[c + 1]):
        j = ids[k]
        w = weights[k]
        s = s + w * res[j]
        dc = dc + w * w * (diag[j] - node_stiffness[j])
    rhs_out[c] = s
    diag_out[c] = inner_stiffness[c] + dc


@wp.kernel
def galerkin_band_kernel(
    band_k: wp.array(dtype=float),
    diag: wp.array(dtype=float),
    node_stiffness: wp.array(dtype=float),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    band_out: wp.array(dtype=float),
):
    """Slot ``s`` of the inner levels' bands: ``K_2``'s value plus ``sum P2_Ja P2_Jb d_J`` over
    the slot's coarse nodes ``J`` (``galerkin_slots``; ``d = diag - node_stiffness``), the
    off-diagonal of ``P2^T diag(d) P2``."""
    s = wp.tid()
    v = band_k[s]
    for k in range(offsets[s], offsets[s + 1]):
        j = ids[k]
        v = v + weights[k] * (diag[j] - node_stiffness[j])
    band_out[s] = v


@wp.kernel
def prolong_level_kernel(
    dx: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    x_inout: wp.array(dtype=wp.vec3),
):
    """``x += P2 dx`` at coarse node ``i`` (``P2`` as CSR)."""
    i = wp.tid()
    s = wp.vec3(0.0)
    for k in range(offsets[i], offsets[i + 1]):
        s = s + weights[k] * dx[ids[k]]
    x_inout[i] = x_inout[i] + s


@wp.func
def clamp_length(v: wp.vec3, cap: float) -> wp.vec3:
    """``v`` shortened to length ``cap`` where longer."""
    vl = wp.length(v)
    if vl > cap:
        return v * (cap / vl)
    return v


# threads that share one coarse node's restriction (``restrict_kernel``): a node gathers 30-60
# particles, which one thread reads one after another
RESTRICT_LANES = wp.constant(8)


# what ``restrict_kernel`` / ``restrict_sum_kernel`` form (bits): the right-hand side, the diagonal
RESTRICT_RHS = wp.constant(1)
RESTRICT_DIAGONAL = wp.constant(2)


@wp.func
def restrict_lane(
    parts: int,
    tid: int,
    c: int,
    r: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    contact_point: wp.array(dtype=wp.vec3),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    instance_thickness: wp.array(dtype=float),
    k_contact: float,
    sc: SelfContactData,
    pair_flags: wp.array(dtype=wp.int32),
):
    """Lane ``tid % RESTRICT_LANES``'s shares of node ``c``'s ``P^T r`` and ``P^T k``
    (``restrict_kernel``). The self-contact stiffness goes to the particles with pairs in
    ``sc``, or where ``pair_flags`` is not empty to those it flags (``CoarseLevel.prepare``'s
    early diagonal: the pairs at the previous substep's end)."""
    s = wp.vec3(0.0)
    kc = float(0.0)
    rhs = (parts & RESTRICT_RHS) != 0
    diagonal = (parts & RESTRICT_DIAGONAL) != 0
    for k in range(offsets[c] + tid % RESTRICT_LANES, offsets[c + 1], RESTRICT_LANES):
        i = ids[k]
        w = weights[k]
        if rhs:
            s = s + w * r[i]
        if diagonal:
            if contact_active[i] != 0:
                th = instance_thickness[particle_instance[i]]
                if wp.dot(contact_normal[i], x[i] - contact_point[i]) < th:
                    kc = kc + w * k_contact
            flagged = False
            if pair_flags.shape[0] > 0:
                flagged = pair_flags[i] != 0
            else:
                flagged = has_pairs(sc, i)
            if flagged:
                kc = kc + w * sc.stiffness
    return s, kc


@wp.func
def node_scale(node_overshoot: wp.array(dtype=wp.vec2), c: int, inv_h: float) -> float:
    """``1/s`` of coarse node ``c``: its instance's coarse system is ``s`` times the one solved,
    ``s = max(1, (1 + k_d/h) r / COARSE_OVERSHOOT)`` with ``node_overshoot[c]`` = (``k_d`` [s],
    ``r / COARSE_OVERSHOOT``) of its instance (module docstring); 1 exactly where the overshoot
    stays within ``COARSE_OVERSHOOT`` (and with ``guard`` off), so those systems are the same
    floats as before session 51."""
    o = node_overshoot[c]
    return 1.0 / wp.max(1.0, (1.0 + o[0] * inv_h) * o[1])


@wp.kernel
def restrict_lanes_kernel(
    parts: int,
    r: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    contact_point: wp.array(dtype=wp.vec3),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    instance_thickness: wp.array(dtype=float),
    k_contact: float,
    sc: SelfContactData,
    pair_flags: wp.array(dtype=wp.int32),
    node_mass: wp.array(dtype=float),
    node_stiffness: wp.array(dtype=float),
    node_overshoot: wp.array(dtype=wp.vec2),
    inertia: float,
    inv_h: float,
    threads: int,
    rhs_out: wp.array(dtype=wp.vec3),
    diag_out: wp.array(dtype=float),
):
    """``restrict_kernel`` and ``restrict_sum_kernel`` in one launch (of ``threads``), on CUDA (``lanes``): a
    node's ``RESTRICT_LANES`` consecutive threads are a segment of a warp, and its first lane
    reads the others' shares by shuffles and adds them in lane order, as the sum kernel does
    (the same floats, one launch fewer on the correction's critical path)."""
    tid = wp.tid()
    c = tid // RESTRICT_LANES
    s, kc = restrict_lane(parts, tid, c, r, offsets, ids, weights, x, particle_instance, contact_point,
                          contact_normal, contact_active, instance_thickness, k_contact, sc, pair_flags)
    mask = lane_mask(tid, threads)
    first = (tid % 32) - tid % RESTRICT_LANES
    total = wp.vec3(0.0)
    k_total = float(0.0)
    for lane in range(RESTRICT_LANES):
        total = total + lane_read_vec3(s, first + lane, mask)
        k_total = k_total + lane_read(kc, first + lane, mask)
    if tid % RESTRICT_LANES == 0:
        inv_s = node_scale(node_overshoot, c, inv_h)
        if (parts & RESTRICT_RHS) != 0:
            rhs_out[c] = total * inv_s
        if (parts & RESTRICT_DIAGONAL) != 0:
            diag_out[c] = node_mass[c] * inertia * inv_s + node_stiffness[c] + k_total * inv_s


@wp.kernel
def restrict_kernel(
    parts: int,
    r: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    particle_instance: wp.array(dtype=wp.int32),
    contact_point: wp.array(dtype=wp.vec3),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    instance_thickness: wp.array(dtype=float),
    k_contact: float,
    sc: SelfContactData,
    pair_flags: wp.array(dtype=wp.int32),
    rhs_part: wp.array(dtype=wp.vec3),
    k_part: wp.array(dtype=float),
):
    """Lane ``l`` of node ``c``'s share of ``rhs = P^T r`` (``parts`` bit ``RESTRICT_RHS``) and of
    ``P^T k`` (bit ``RESTRICT_DIAGONAL``), ``k`` the body contact's penalty at particles of ``x``
    pressed onto the body plus the self-contact penalty at particles with cloth-cloth pairs:
    entries ``l, l + RESTRICT_LANES, ...`` of the node's row (thread ``c * RESTRICT_LANES + l``;
    ``restrict_sum_kernel`` adds the lanes)."""
    tid = wp.tid()
    c = tid // RESTRICT_LANES
    s, kc = restrict_lane(parts, tid, c, r, offsets, ids, weights, x, particle_instance, contact_point,
                          contact_normal, contact_active, instance_thickness, k_contact, sc, pair_flags)
    if (parts & RESTRICT_RHS) != 0:
        rhs_part[tid] = s
    if (parts & RESTRICT_DIAGONAL) != 0:
        k_part[tid] = kc


@wp.kernel
def restrict_sum_kernel(
    parts: int,
    rhs_part: wp.array(dtype=wp.vec3),
    k_part: wp.array(dtype=float),
    node_mass: wp.array(dtype=float),
    node_stiffness: wp.array(dtype=float),
    node_overshoot: wp.array(dtype=wp.vec2),
    inertia: float,
    inv_h: float,
    rhs_out: wp.array(dtype=wp.vec3),
    diag_out: wp.array(dtype=float),
):
    """``rhs = P^T r / s`` and the coarse diagonal ``(m_c (1/h^2 + alpha/h) + P^T k) / s + K_c,JJ``
    of node ``c`` (the ``parts`` of ``restrict_kernel``) from its lanes, summed in lane order (one
    node per thread); ``s`` the overshoot guard (``node_scale``)."""
    c = wp.tid()
    inv_s = node_scale(node_overshoot, c, inv_h)
    if (parts & RESTRICT_RHS) != 0:
        s = wp.vec3(0.0)
        for lane in range(RESTRICT_LANES):
            s = s + rhs_part[c * RESTRICT_LANES + lane]
        rhs_out[c] = s * inv_s
    if (parts & RESTRICT_DIAGONAL) != 0:
        kc = float(0.0)
        for lane in range(RESTRICT_LANES):
            kc = kc + k_part[c * RESTRICT_LANES + lane]
        diag_out[c] = node_mass[c] * inertia * inv_s + node_stiffness[c] + kc * inv_s


@wp.kernel
def prolong_kernel(
    dx: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=float),
    h: float,
    x_prev: wp.array(dtype=wp.vec3),
    y: wp.array(dtype=wp.vec3),
    contact_point: wp.array(dtype=wp.vec3),
    contact_normal: wp.array(dtype=wp.vec3),
    contact_body_velocity: wp.array(dtype=wp.vec3),
    contact_active: wp.array(dtype=wp.int32),
    mass: wp.array(dtype=float),
    flags: wp.array(dtype=wp.int32),
    particle_instance: wp.array(dtype=wp.int32),
    instance_thickness: wp.array(dtype=float),
    instance_friction: wp.array(dtype=float),
    instance_body: wp.array(dtype=wp.uint64),
    contact_margin: float,
    sc: SelfContactData,
    x_inout: wp.array(dtype=wp.vec3),
    snap_out: wp.array(dtype=wp.vec3),
):
    """``x += P dx_c`` for free particles, the result also to ``snap_out``; a particle with
    self-contact pairs moves at most ``SELF_CONTACT_CAP`` times the contact radius; one on the
    body is not moved deeper into it than it is (or than its thickness shell), and the move is
    truncated to the particle's self-contact displacement bound like a sweep's, on the body too
    (``vbd_kernels.bound_step``): the correction carries no layer through another."""
    i = wp.tid()
    xi = x_inout[i]
    if flags[i] != PINNED:
        s = wp.vec3(0.0)
        for k in range(offsets[i], offsets[i + 1]):
            s = s + weights[k] * dx[ids[k]]
        if has_pairs(sc, i):
            # self-contact is not in the coarse system: a particle with cloth-cloth pairs moves at
            # most a fraction of the contact radius, so two capped neighbours across a gap close it
            # by less than the radius the penalty keeps between them
            s = clamp_length(s, SELF_CONTACT_CAP * sc.radius)
        p = load_particle_step(i, x_prev, y, mass, flags, particle_instance, contact_point, contact_normal,
                               contact_body_velocity, contact_active, instance_thickness, instance_friction,
                               sc, x_inout)
        if p.contact_active == 0 and instance_body[particle_instance[i]] != wp.uint64(0):
            # off the body (further than the contact margin as the substep began): the move stays
            # within half the margin's room, so the body contact found at the substep's start
            # still covers the particle
            s = clamp_length(s, 0.5 * wp.max(contact_margin - p.thickness, 0.0))
        x_new = xi + s
        if p.contact_active != 0:
            floor = wp.min(wp.dot(p.contact_normal, xi - p.contact_point), p.thickness)
            depth = wp.dot(p.contact_normal, x_new - p.contact_point)
            if depth < floor:
                x_new = x_new + (floor - depth) * p.contact_normal
        xi = bound_step(p, x_new, h, sc, 0)
        x_inout[i] = xi
    snap_out[i] = xi


@wp.kernel
def band_solve_kernel(
    rhs: wp.array(dtype=wp.vec3),
    diag: wp.array(dtype=float),
    inst_start: wp.array(dtype=wp.int32),
    inst_count: wp.array(dtype=wp.int32),
    inst_width: wp.array(dtype=wp.int32),
    inst_band: wp.array(dtype=wp.int64),
    order: wp.array(dtype=wp.int32),
    band_k: wp.array(dtype=float),
    band: wp.array(dtype=float),
    y: wp.array(dtype=wp.vec3),
    dx_out: wp.array(dtype=wp.vec3),
):
    """Solve one instance's coarse system ``A dx = rhs`` exactly (one thread per instance):
    assemble the lower band of ``A`` (``K_c``'s off-diagonal band, ``diag`` on the diagonal;
    ``restrict_kernel`` puts ``K_c``'s own diagonal there), factor it in place (banded Cholesky,
    ``L[r, t] = L_{r, r-t}``), then forward and back substitution; rows are in the template's
    RCM order (``order``: row -> node)."""
    k = wp.tid()
    start = inst_start[k]
    n = inst_count[k]
    b = inst_width[k]
    w = wp.int64(b + 1)
    base = inst_band[k]
    for r in range(n):
        row = base + wp.int64(r) * w
        band[row] = diag[start + order[start + r]]
        for t in range(1, b + 1):
            band[row + wp.int64(t)] = band_k[row + wp.int64(t)]
    # factor: column j, then the rows i = j + 1 .. j + b below it
    for j in range(n):
        rj = base + wp.int64(j) * w
        s = band[rj]
        for t in range(1, wp.min(b, j) + 1):
            v = band[rj + wp.int64(t)]
            s = s - v * v
        d = wp.sqrt(wp.max(s, 1.0e-30))
        band[rj] = d
        for i in range(j + 1, wp.min(n, j + b + 1)):
            ri = base + wp.int64(i) * w
            ti = i - j
            s = band[ri + wp.int64(ti)]
            # sum over columns c < j inside both rows' bands: c >= i - b
            for c in range(wp.max(0, i - b), j):
                s = s - band[ri + wp.int64(i - c)] * band[rj + wp.int64(j - c)]
            band[ri + wp.int64(ti)] = s / d
    # L y = rhs
    for r in range(n):
        rr = base + wp.int64(r) * w
        u = rhs[start + order[start + r]]
        for t in range(1, wp.min(b, r) + 1):
            u = u - band[rr + wp.int64(t)] * y[start + r - t]
        y[start + r] = u / band[rr]
    # L^T x = y (x kept in y, last row first)
    for q in range(n):
        r = n - 1 - q
        u = y[start + r]
        for t in range(1, wp.min(b, n - 1 - r) + 1):
            u = u - band[base + wp.int64(r + t) * w + wp.int64(t)] * y[start + r + t]
        y[start + r] = u / band[base + wp.int64(r) * w]
        dx_out[start + order[start + r]] = y[start + r]
