"""Coarse-level correction of the VBD sweeps (smoothed aggregation, two or three levels).

A Gauss-Seidel sweep moves a stiff membrane's force about one ring of edges, so within a substep
the sweeps cannot carry a running sleeve's pull across the 20-30 rings of a shoulder strap. This
package adds the missing long reach: between sweeps, the residual of the substep's incremental
potential is restricted to a coarse level of about one node per 15-25 vertices, a linear coarse
system is solved, and its solution is prolongated back as a displacement of every free particle.

Setup (numpy/scipy, once per distinct garment template, shared by its instances; ``aggregation``,
``operators``):

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
- **coarse system** ``A_c = (1/h^2 + alpha/h) M_c + K_c + C_c`` with ``K_c = P^T K P``
  (Galerkin, sparse), ``M_c = P^T m`` (lumped) and ``C_c = P^T c``, ``c`` the body contact's
  penalty stiffness at particles pressed onto the body plus the self-contact penalty stiffness
  at particles with cloth-cloth pairs (``has_pairs``: not those only in pairs closer than
  ``coarse_exclusion`` at rest), pressed at the substep's inertial targets
  (``CoarseLevel.prepare``). The residual holds both contacts' forces; without their stiffness in
  ``A_c`` the correction answers them with the membrane alone: the 5k t-shirt's CPU run explodes
  at frame 16 without the body contact's, and stacked layers go metres apart in 4 frames without
  the self-contact's (docs/DECISIONS.md). Contact pins cloth as firmly as a pin does, so the
  coarse level must know where it holds. The sparsity pattern of ``K_c`` is fixed, so its rows
  are put in reverse Cuthill-McKee order once (the 5k t-shirt's 202 nodes at spacing 4: band 37)
  and the system is factored as a band.

Per substep (``CoarseLevel``): with two levels, ``prepare`` forms the diagonal from the
substep-start contacts and the inertial targets and factors each instance's system beside the
first sweeps (on CUDA a thread block per instance, ``block``). Per correction: the solve
kernel's evaluate variant writes the residual ``r = -dG/dx`` at ``x`` (inertia, membrane,
bending, damping, body and self-contact); ``transfer_kernels.restrict_kernel`` forms ``P^T r``;
the system is solved (CUDA: the block's substitutions with the prepared factor; CPU: one thread
per instance, ``band_kernels.band_solve_kernel``, banded Cholesky); ``prolong_kernel`` adds ``P
dx_c`` to ``x`` and to the next sweep's snapshot, limited where a move could cross something,
since the coarse system is linear and blind to geometry.

Three levels (``levels``; automatic where a garment's coarse level has more than
``AUTO_MAX_NODES`` nodes, whose band would not fit a CUDA block): an inner level aggregates the
coarse level's own graph (``aggregate_graph``), and ``CoarseLevel.solve`` runs a symmetric
two-grid cycle on the coarse system (``cycle_kernels``): l1-Jacobi passes, the inner level's
exact solve of the restricted residual with the Galerkin operator ``P2^T A_c P2`` (its mass and
contact part added to the inner band at each correction), the prolongation and as many passes
again; the diagonal is formed at each correction.
"""

from sim.cloth.coarse.aggregation import (
    AUTO_MAX_NODES,
    AUTO_MIN_SPACING,
    aggregate,
    aggregate_graph,
    auto_aggregate,
    mesh_edge_graph,
)
from sim.cloth.coarse.band_kernels import band_solve_kernel
from sim.cloth.coarse.level import CoarseLevel
from sim.cloth.coarse.operators import (
    CoarseTemplate,
    coarse_template,
    cotangent_stiffness,
    galerkin_level,
    galerkin_slots,
)
from sim.cloth.coarse.transfer_kernels import (
    RESTRICT_DIAGONAL,
    RESTRICT_LANES,
    RESTRICT_RHS,
    SELF_CONTACT_CAP,
)

__all__ = [
    "AUTO_MAX_NODES", "AUTO_MIN_SPACING", "RESTRICT_DIAGONAL", "RESTRICT_LANES", "RESTRICT_RHS",
    "SELF_CONTACT_CAP", "CoarseLevel", "CoarseTemplate", "aggregate", "aggregate_graph", "auto_aggregate",
    "band_solve_kernel", "coarse_template", "cotangent_stiffness", "galerkin_level", "galerkin_slots",
    "mesh_edge_graph",
]

