"""``SolverVBD``: Vertex Block Descent cloth solver (Chen et al. 2024).

``step(state_in, state_out, control, dt)`` advances every instance of the model by ``dt``
[s] in ``substeps`` implicit-Euler substeps, each solved by ``iterations`` Gauss-Seidel sweeps
over the vertex colouring. Per substep:

1. bodies move to the substep's end (linear in time between the step's two body frames) and
   their BVHs are refit; on CUDA on a side stream, beside 2 and 4 (``sim.device.SideStreams``),
   and from the second substep on beside the previous substep's detection and sweeps, once its
   body contact has read them (session 41);
2. ``forward_kernel``: inertial target and initial guess; pinned particles placed;
   ``previous_deformation_kernel``: substep-start strains and hinge angles (damping reference);
   on CUDA on a side stream beside 3 and 4, which read only the substep's start ``x_prev`` (set
   by the previous substep's velocity kernel; the first substep's forward step sets it, before);
3. ``body_contact_kernel``: one contact plane per particle against its instance's body,
   found from the particle's substep-start position (outside the body) against the body's
   substep-end placement; on CUDA on the same side stream after 1, beside 4;
4. with ``self_contact``: refit the cloth BVHs (rebuild them in the step's first substep),
   find vertex-triangle and edge-edge pairs and per-vertex displacement bounds
   (``sim.cloth.self_contact``; its three tree-and-query chains on three streams on CUDA),
   with speeds measured relative to each instance's ``control.instance_velocity``;
5. ``iterations`` x colours launches of the solve kernel (``solve_color_kernel(particles,
   lanes)``), each iteration followed by ``chebyshev_kernel`` when ``chebyshev_rho`` > 0;
   neighbours of a vertex's own colour (a hinge's opposite vertex, self-contact partners) are
   read from the sweep-start snapshot, so the step does not depend on the order of the GPU's
   threads; with ``coarse_sweeps``, a coarse-level correction before the sweeps named there
   (with ``coarse_prefactor`` its diagonal and factor are made from the substep-start state
   beside the first sweeps, on CUDA on a side stream: ``CoarseLevel.prepare``; with
   ``coarse_early`` already beside 4, after 2 and 3, from the previous substep's pairs);
6. ``velocity_kernel`` (and ``x_prev`` for the next substep; with ``coarse_early`` the flags of
   the particles with pairs, for the next substep's 5).

Substep safety: contact is found against the body where it will be at the end of each
substep, and the sign test classifies a particle the body has overtaken correctly as long as
the body moves less than half its local thickness per substep (5 m/s at 30 fps with 10
substeps: 1.7 cm). The contact energy is a half-space penalty, so the particle is pushed back
out however far its initial guess went.

No host synchronisation, numpy or allocation inside ``step``: all buffers are allocated in
the constructor; the step can be captured in a CUDA graph once bodies and pins are uploaded.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim.cloth import vbd_kernels as K
from sim.cloth.clusters import CLUSTER_SIZES
from sim.cloth.model import ClothModel
from sim.cloth.self_contact import SelfContact, disabled_data, solve_contact_arrays, solve_contact_key
from sim.cloth.spans import fill_spans
from sim.cloth.state import ClothControl, ClothState
from sim.device import SideStreams, warp

# the largest model (vertices + triangles + edges) that the "auto" broadphase searches with
# clusters on CUDA (``SolverVBD.broadphase``): up to four 5k t-shirts or one 30k garment
CLUSTER_PRIMITIVES = 131072


@dataclass(frozen=True)
class VBDConfig:
    """Solver settings.

    Attributes:
        substeps: implicit-Euler substeps per ``step``.
        iterations: Gauss-Seidel sweeps (over all colours) per substep.
        contact_stiffness: body contact penalty stiffness [N/m].
        contact_margin: distance [m] within which body contacts are detected; must exceed the
            cloth thickness plus the relative cloth/body motion of one substep. 15 mm (was 50 mm
            until session 11; 15 mm covers 4.5 m/s of relative motion at 10 substeps of a 30 fps
            frame): the closest-point query's cost grows with it, 5 % of the t-shirt frame.
        friction_epsilon: tangential speed [m/s] below which friction is smoothed (static).
        membrane: "corotated" (default; co-rotated linear FEM: resists compression, so cloth
            buckles into wrinkles instead of shrinking in plane) or "stvk" (Saint
            Venant-Kirchhoff: its stress vanishes as a triangle collapses, so squeezed cloth
            shrinks to under half its rest length).
        lanes: GPU threads that share one particle's solve (tiled launch; 1 on CPU). 0 (default):
            chosen by the model's size (``auto_lanes``): 16 lanes x 8 particles per block while
            the largest colour has fewer than ``AUTO_LANES_PARTICLES`` particles (one garment: the
            launches are latency-bound, and more lanes shorten each particle's serial gather),
            4 x 32 from there on (batches: the GPU is full, and 16 lanes of which ~4 idle on a
            vertex's ~12 elements cost throughput; 64 t-shirts: 344 against 248 garment-frames/s,
            session 12).
        particles_per_block: particles solved by one GPU thread block (``particles x lanes``
            threads; 1 on CPU); with ``lanes`` 0 it is chosen with them.
        gather: how a solve thread gathers its share of a particle's triangles, hinges and
            self-contact records (``vbd_kernels.vertex_share_force_hessian``): "fused" (item ``r``
            of every kind loaded together: one chain of dependent loads; single garments,
            latency-bound), "split" (one kind after the other, only the items a lane has:
            batches, throughput-bound), "auto" (default: fused from ``vbd_kernels.FUSED_LANES`` lanes per
            particle, so with the 16-lane layout of single garments, split with the 4-lane
            layout of batches and on the CPU).
        max_registers: CUDA registers per thread of the solve kernel (``__maxnreg__``; the compiler
            spills what does not fit), 0: the compiler's choice, -1 (default): auto,
            ``AUTO_BATCH_MAX_REGISTERS`` with the automatic batch layout (4 lanes x 32) and the
            compiler's choice otherwise. A cap trades spills for resident warps.
        fast_math: compile the CUDA solve kernel with fast math (approximate division, square
            root and transcendentals, denormals flushed); the CPU is unaffected.
        chebyshev_rho: estimated spectral radius rho of the sweeps for Chebyshev acceleration
            (Chen et al. 2024, Sec. 3.8: ``omega_1 = 1, omega_2 = 2 / (2 - rho^2), omega_k = 4 /
            (4 - rho^2 omega_{k-1})``); 0 turns it off. It converges further per sweep, but
            overshoots where the sweeps are far from linear (contact).
        air_damping: mass-proportional Rayleigh damping alpha [1/s] (force ``-alpha m v``): the
            linear drag of still air that lets garments come to rest; the material's damping
            [s] acts on strain and bending rates only and leaves rigid motion undamped.
        self_contact: cloth-cloth collision (vertex-triangle and edge-edge) on/off.
        self_contact_radius: distance [m] kept between cloth surfaces.
        self_contact_margin: smallest query radius [m] of the pair detection and of the
            intersection-free displacement bounds; a vertex moves at most ``relaxation x`` its
            distance to the nearest non-incident primitive (capped at the query radius) per
            substep. 4 mm (10 mm until session 9, 5 mm until session 11): pairs beyond the 3 mm
            contact radius plus the substep's motion never act, and storing them costs solve
            time (1.5x the step at batch 64 for 10 mm); faster pairs are covered by the
            relative-speed term (``self_contact_relative_lists``).
        self_contact_stiffness: penalty stiffness [N/m] of a cloth-cloth pair. 3e4 (was 1e4
            until session 10): at 1e4 body contact (1e5) squeezes sleeve layers through each
            other. Repeated t-shirt runs at 20x10: walk 5/8 and run 8/8 pass the gates at 3e4,
            2/5 and 0/5 at 1e4 (GPU runs were not bit-reproducible then: a single pass proved little).
        self_contact_friction: cloth-cloth Coulomb friction coefficient.
        self_contact_relaxation: gamma of the bounds (< 0.5 keeps the guarantee).
        self_contact_speed_factor: query radius at least this times |v| h, so fast cloth with
            space around it is not slowed by the bounds.
        self_contact_capacity: pairs stored per vertex, triangle and edge.
        self_contact_bounds: per-vertex displacement bounds that make the cloth provably
            intersection-free (tested: stacked layers at 3 m/s), measured from the body surface
            a particle touches, elsewhere in the instance's frame
            (``ClothControl.instance_velocity``). Off by default: in the world frame (until
            session 12) they held back a walking body's sleeves until edges tore; in the body's
            frame the t-shirt passed 5 of 6 runs (session 13; one run stretched an edge to
            0.367 > 0.35), no better than without them; off, contact is penalty only.
        self_contact_rest_exclusion: vertex-triangle and edge-edge pairs closer than this [m]
            in the rest shape are surface neighbours left to the elastic forces (0: only incident
            pairs). Pairs of one piece closer than ``self_contact_radius`` at rest (panels meeting
            at a seam, a crease folded at rest) are in contact at half their rest distance, so
            they exert nothing at rest and cannot pass through each other (until session 18 they
            were excluded: a folded crease passed through itself). Everything else, a ring or two
            away included, is in contact at the full radius once a fold brings it together (an
            exclusion of 2.5 edge lengths let sleeves crumple through themselves: hundreds of
            crossings on the t-shirt walk).
        self_contact_ring_exclusion: leave out the pairs whose primitives an edge joins (a
            triangle with a corner next to the vertex; edges with neighbouring ends) unless they
            are closer than ``self_contact_radius`` at rest (``SelfContact``'s ``ring_exclusion``).
            Off by default (session 50). On 19k-vertex garments (5.5 mm edges) those surface
            neighbours, ~4.8 mm apart, come within the 4 mm query margin wherever the cloth moves
            or gathers, so a third of the particles hold pairs and the coarse correction is
            capped there: a flat fine sheet hanging in denim bounces by 1-2 cm with self-contact
            on and hangs still with it off or with this exclusion; the fine shorts sink 12 mm in
            a 1 s settle against 3 mm without self-contact. On (H100), every coarse template's walk
            crossed itself (3-42 crossings, none at the default), the 5k t-shirt's walk and run
            too (35 / 64) at 4.29 / 4.45 ms per frame, and the fine shorts' crotch still sank
            (46 mm in the settle): the pairs an edge apart keep tight folds of coarse meshes
            from passing through themselves.
        self_contact_coarse_exclusion: self-contact pairs of one piece closer than this [m] at
            rest leave the coarse correction alone (``SelfContact``'s ``coarse_exclusion``): they
            stay in contact, but no longer cap their particles' prolongated moves nor add the
            self-contact stiffness to the coarse diagonal. 0 (default): every stored pair holds
            the correction back. The job sets 6 mm for fine garments
            (``sim.simulate.FINE_COARSE_EXCLUSION``, session 50): at 5.5 mm edges the neighbours
            an edge or two apart, 4-6 mm at rest, come within the 4 mm query margin as soon as
            the cloth moves, nearly every particle had pairs, and the correction, which carries
            a load across the garment, was left out of most of it: a flat fine sheet hanging in
            denim bounced by 1-2 cm (tests/test_self_contact.py), the fine shorts sank 12 mm in
            their settle and their crotch 10 cm in the blend. It also frees the pairs that rest
            close across a gap (the pants' inner walls, 3 mm apart): the fine shorts' and
            trousers' walks did not cross, but on coarse garments (14-20 mm edges), where those
            are the only pairs it frees, the coarse trousers' walk crossed itself (H100, 8
            crossings), so the job leaves coarse garments at 0.
        self_contact_side_memory: keep the side each self-contact pair was found on across
            detections and push pairs that crossed back (``sim.cloth.self_contact``). Off by
            default: it clears the t-shirt run's persistent sleeve crossing but makes the walk
            fail more often (session 10, docs/BENCHMARKS.md).
        self_contact_relative_lists: store a self-contact pair for the solve only within the query
            radius of its own relative speed, ``max(margin, speed_factor |v_a - v_b| h)``; the
            query itself (and the bounds' ``d_min``) still covers each primitive's absolute
            speed. Off: every pair within the query radius is stored, and on the t-shirt run
            88 % of the edges' lists filled with surface neighbours riding on the limb with them
            (session 11).
        self_contact_pool: gather records per vertex, on average over the model, of the solve's
            self-contact pairs (each pair's vertices, role and side in one record, written once
            per detection): a vertex whose records do not fit is gathered from the pair lists,
            with the same forces but a chain of dependent loads per pair (session 12: the lists
            made a solve launch 24 us against 10 us without self-contact). 0: always the lists.
        self_contact_heavy_cap: vertices per colour launch that get a whole thread block each when
            they have more gather records than the solve has lanes per particle (so would take
            more than one round of them): a dense fold gives a few vertices 50-160 records
            (session 13, the t-shirt run: mean 2-6), and the slowest vertex sets every launch's
            length. A colour with more such vertices than this solves them in the lanes layout
            (the cap fixes the launch size, as a CUDA graph needs). 0: off; -1 (default):
            ``AUTO_HEAVY_CAP`` per instance in the 16-lane layout on CUDA, otherwise off (the
            batched 4-lane layout fills the GPU: a long vertex no longer idles it).
        self_contact_weight_floor: smallest weight of a vertex in a self-contact pair that the
            pair's Hessian block takes (``self_contact.pair_force_hessian``; 0: the exact
            ``w^2``). 0.5 (session 17): with the exact Hessian a vertex with a small weight in a
            pair (an edge end far from the closest point) moves ``1/w`` times the penetration in
            its own Newton step; a hairpin thrown onto itself at 1.1 m/s left the contact with
            10x its energy, flipped over its fold and fell past itself. The forces, so the
            converged state, are the same; steps are at most twice a pair's penetration.
        self_contact_rebuild: rebuild the cloth BVHs at the first detection of every step and
            refit them at the others. Refitting a tree built for the rest shape keeps its
            topology while the garment deforms, and queries on the loosened boxes cost 1.5-2x.
        self_contact_ee_interior: store an edge-edge pair only where its closest points lie
            inside both edges (``SelfContact``'s ``ee_interior``): at an edge's end the vertex-
            triangle pairs of that end vertex hold the same contact, and the edge pair counted
            it twice. On the folded t-shirt run ~80 % of the stored edge pairs were of that kind
            (session 21). H100, 16x10: population 37/48 against 38/48, 1-4 % faster; off by
            default (docs/BENCHMARKS.md, session 21).
        self_contact_lookahead: form each substep's pair lists from candidate pairs found a substep
            ahead (``SelfContact.query_candidates``, ``remeasure``): at a step's first substep a
            query for it and the next, its boxes swept over the substep's motion and the margin
            widened by ``self_contact_lookahead_margin``, and at substep ``s`` (0 < s <
            substeps - 1) the same query for ``s + 1`` on a side stream beside the sweeps (CUDA).
            Each substep then re-measures only its candidates at its own start positions and
            velocities, with the detection's own tests and radii: no tree refit or traversal on
            the critical path, and no lists from stale positions (the pipeline's). Needs
            ``self_contact_interval`` 1, no bounds and no pipeline. Not yet measured on a GPU
            (docs/BENCHMARKS.md, session 36), so off by default.
        self_contact_lookahead_margin: widening [m] of the candidate queries' margin (2 mm: on
            a CPU t-shirt run the remeasured lists then missed 0.12 % of a detection's pairs,
            none within the contact radius; 1 mm missed 0.43 %).
        self_contact_pipeline: detect the pairs of substep ``s + 1`` during substep ``s``, on a
            side stream beside the sweeps (CUDA), from the positions and velocities ``s`` starts
            with and a query that covers two substeps of motion (``2 h``); only the first substep
            of a step waits for its own detection. Detection then leaves the critical path of a
            single garment, whose solve launches are latency-bound and leave the GPU room. Needs
            ``self_contact_interval`` 1, no bounds and no side memory (they hold for the substep
            detected from). Two sets of pair lists alternate (``SelfContact(slots=2)``); each
            pair's side is re-measured as its substep starts (``SelfContact.refresh_sides``). On
            the CPU the same detections run in order. H100, t-shirt 16x10: walk 9.15 against 11.30
            ms, run 9.74 against 10.90 ms, but the population passed 32/48 against 38/48 (more
            crossings), so it is off by default (docs/BENCHMARKS.md, session 21).
        max_colors: colours of the model's vertex colouring (``ClothModelBuilder(max_colors=...)``,
            which ``sim.simulate`` builds from this field; the solver itself runs any colouring):
            0 (default) a proper colouring (the t-shirt: 4); 3 leaves ~2 % of the t-shirt's edges
            same-coloured, coupled by a Jacobi step, for one launch fewer per sweep (the job
            default on CUDA, ``sim.simulate.CUDA_COLORS``).
        strain_limit: largest edge stretch ``l / l0 - 1`` [-] the substep ends with (0: off):
            after the sweeps, ``strain_limit_passes`` Jacobi passes shorten every edge stretched
            further (``vbd_kernels.strain_limit_kernel``; Provot 1995). Truncated Gauss-Seidel
            sweeps move a stiff sheet's support forces ~1 ring per sweep, so where the body
            drags cloth (straps carrying a running shirt) edges stretch far more than the
            material would; the passes move that stretch on to slack edges at a fraction of a
            sweep's cost, and the velocity update carries the shortening (as position-based
            dynamics does).
        strain_limit_passes: Jacobi passes of the strain limit per substep.
        coarse_sweeps: sweep indices (0 .. iterations - 1) before which a coarse-level correction
            runs (``sim.cloth.coarse``; empty, the default: none). A correction evaluates the
            residual at every particle (one sweep's gather), restricts it to about one node
            per 15 vertices, solves that level's linear system exactly and adds the
            prolongated displacement: the long reach the sweeps lack (~1 ring each).
        coarse_spacing: seed spacing of the coarse level's aggregates [edges]; 0: per garment,
            4, or with ``coarse_levels`` 2 the least from 4 that gives at most 256 coarse nodes
            (``coarse.auto_aggregate``: the t-shirt's 5k vertices take 4, a 20k-vertex garment 8).
        coarse_levels: 2 solves the coarse level exactly (one CUDA block per garment where its
            band fits in shared memory); 3 adds an inner level of at most 256 nodes on the coarse
            level's aggregate graph and solves the coarse level by a two-grid cycle around the
            inner one's exact solve (``coarse.coarse_template``); 0, the default: 3 for a garment
            whose coarse level has more than 256 nodes (a 20k-vertex t-shirt has 808 at spacing
            4), else 2.
        coarse_smoothing: l1-Jacobi passes on the coarse level before and after the inner solve
            (three levels only).
        coarse_prefactor: with two coarse levels, form each substep's coarse diagonal (its body
            contact stiffness at particles pressed at the inertial targets ``y``) and, on CUDA,
            factor each instance's coarse system at the substep start, beside the first sweeps on
            a side stream; a correction then only substitutes (``CoarseLevel.prepare``). Off
            (default here; ``SimulationConfig`` turns it on since session 34): the diagonal at
            each correction's positions, factored and solved there.
            H100, 5k t-shirt (docs/BENCHMARKS.md, session 30): 9.25 -> 8.30 ms per frame, 137
            of 144 sequences pass against 133, but the single run's worst strain is 0.356 (gate
            0.35) against 0.278, and a 164-vertex skirt dressed at 3 x 3 keeps 2 vertices inside
            the body, so it was not then the job default. At 15 substeps (session 33) it passes both
            singles and 137 of 144 sequences at 7.67 / 7.65 ms against the default's 8.00 / 8.01
            (both before the raw loads and fast math). With them (session 34), at 14 substeps:
            6.25 / 6.24 ms against 7.05 / 7.06, both singles pass (run 0.250), 133 of 144
            sequences against 134; the skirt passes at 5 x 5.
        coarse_early: with ``coarse_prefactor``, prepare the coarse system at the substep start
            beside the self-contact detection instead of after it, beside the first sweeps:
            the self-contact stiffness of its diagonal then goes to the particles that had pairs
            at the previous substep's end (the velocity kernel flags them) instead of those with
            pairs now (none in a solver's first substep). Needs ``coarse_prefactor`` and two
            coarse levels (else nothing changes). Off (default here; ``SimulationConfig`` turns
            it on for CUDA since session 42, where the factor was on the critical path: doubling
            it added its whole 63 us per substep to the 5k t-shirt's frame).
        coarse_guard: the coarse system's overshoot guard (``coarse`` module docstring): its
            membrane proxy stiffened per garment just enough that a correction overshoots the
            sweeps' Hessian, which holds the strain-rate damping (``1 + k_d/h`` times the elastic
            one), by at most ``coarse.COARSE_OVERSHOOT`` (1.8). On by default since session 51
            (``SimulationConfig`` turns it off, ``sim.simulate.JOB_COARSE_GUARD``: it raised the
            fine walks' strain on the CPU); off, a correction overshoots by up to ``1 + k_d/h``
            times 1.3 where stiffness outweighs inertia, and beyond 2 it amplifies error instead
            of removing it (a denim sheet at rest with aggregates 2-3 edges apart crumpled by
            itself).
        self_contact_broadphase: how the self-contact detection finds its candidates: ``"bvh"``
            (three trees, refitted every detection and rebuilt every step), ``"clusters"`` (no
            trees: the primitives in fixed clusters of ``self_contact_cluster_size``, culled
            cluster by cluster, ``sim.cloth.clusters``) or ``"auto"`` (default: the clusters on
            CUDA, the trees on the CPU and with the lookahead; ``SolverVBD.broadphase``). The same
            pairs either way; on CUDA the clusters take the trees' chains of dependent loads off
            every substep's critical path.
        self_contact_cluster_size: primitives per cluster of the ``"clusters"`` broadphase.
        self_contact_cluster_split: threads per primitive of the cluster query (0: automatic,
            ``SelfContact``'s ``cluster_split``).
        self_contact_interval: detect self-contact pairs every this many substeps (1: every
            substep). The query radius grows with the motion it must cover (``speed_factor x |v|
            x h x interval``); contact forces, signs and friction are still evaluated every
            iteration from the current positions.
    """

    substeps: int = 10
    iterations: int = 10
    contact_stiffness: float = 1.0e5
    contact_margin: float = 0.015
    friction_epsilon: float = 1.0e-2
    air_damping: float = 0.5
    lanes: int = 0
    particles_per_block: int = 8
    gather: str = "auto"
    max_registers: int = -1
    fast_math: bool = False
    chebyshev_rho: float = 0.0
    membrane: str = "corotated"
    self_contact: bool = False
    self_contact_radius: float = 0.003
    self_contact_margin: float = 0.004
    self_contact_stiffness: float = 3.0e4
    self_contact_friction: float = 0.2
    self_contact_relaxation: float = 0.45
    self_contact_speed_factor: float = 2.5
    self_contact_capacity: int = 16
    self_contact_rest_exclusion: float = 0.0
    self_contact_ring_exclusion: bool = False
    self_contact_coarse_exclusion: float = 0.0
    self_contact_bounds: bool = False
    self_contact_interval: int = 1
    self_contact_rebuild: bool = True
    self_contact_side_memory: bool = False
    self_contact_relative_lists: bool = True
    self_contact_pool: int = 16
    self_contact_heavy_cap: int = -1
    self_contact_weight_floor: float = 0.5
    self_contact_ee_interior: bool = False
    self_contact_pipeline: bool = False
    self_contact_lookahead: bool = False
    self_contact_lookahead_margin: float = 0.002
    self_contact_broadphase: str = "auto"
    self_contact_cluster_size: int = 32
    self_contact_cluster_split: int = 0
    max_colors: int = 0
    strain_limit: float = 0.0
    strain_limit_passes: int = 4
    coarse_sweeps: tuple[int, ...] = ()
    coarse_spacing: int = 3
    coarse_levels: int = 0
    coarse_smoothing: int = 2
    coarse_prefactor: bool = False
    coarse_early: bool = False
    coarse_guard: bool = True

    def __post_init__(self):
        if self.self_contact_heavy_cap < -1:
            raise ValueError(f"VBDConfig.self_contact_heavy_cap must be >= -1 (-1: auto), got "
                             f"{self.self_contact_heavy_cap}")
        if self.self_contact_pool < 0:
            raise ValueError(f"VBDConfig.self_contact_pool must be >= 0, got {self.self_contact_pool}")
        if self.max_colors < 0 or self.max_colors == 1:
            raise ValueError(f"VBDConfig.max_colors must be 0 (proper colouring) or >= 2, got "
                             f"{self.max_colors}")
        if self.strain_limit < 0.0:
            raise ValueError(f"VBDConfig.strain_limit must be >= 0 (0: off), got {self.strain_limit}")
        for name in ("substeps", "iterations", "self_contact_interval", "strain_limit_passes"):
            if getattr(self, name) < 1:
                raise ValueError(f"VBDConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.self_contact_bounds and self.self_contact_interval != 1:
            raise ValueError("VBDConfig.self_contact_interval must be 1 with self_contact_bounds (the bounds "
                             f"hold for one substep), got {self.self_contact_interval}")
        if self.self_contact_pipeline and (self.self_contact_interval != 1 or self.self_contact_bounds
                                           or self.self_contact_side_memory):
            raise ValueError("VBDConfig.self_contact_pipeline needs self_contact_interval 1, "
                             "self_contact_bounds off and self_contact_side_memory off")
        if self.self_contact_lookahead and (self.self_contact_interval != 1 or self.self_contact_bounds
                                            or self.self_contact_pipeline):
            raise ValueError("VBDConfig.self_contact_lookahead needs self_contact_interval 1, "
                             "self_contact_bounds off and self_contact_pipeline off")
        if self.self_contact_lookahead_margin < 0.0:
            raise ValueError("VBDConfig.self_contact_lookahead_margin must be >= 0, got "
                             f"{self.self_contact_lookahead_margin}")
        if self.self_contact_broadphase not in ("auto", "bvh", "clusters"):
            raise ValueError("VBDConfig.self_contact_broadphase must be 'auto', 'bvh' or 'clusters', got "
                             f"{self.self_contact_broadphase!r}")
        if self.self_contact_broadphase == "clusters" and self.self_contact_lookahead:
            raise ValueError("VBDConfig.self_contact_lookahead needs self_contact_broadphase 'bvh' (its "
                             "swept candidate queries run on the trees)")
        if self.self_contact_cluster_size not in CLUSTER_SIZES:
            raise ValueError("VBDConfig.self_contact_cluster_size must be a multiple of 8 in [8, 64], got "
                             f"{self.self_contact_cluster_size}")
        if self.gather not in ("auto", "fused", "split"):
            raise ValueError(f"VBDConfig.gather must be 'auto', 'fused' or 'split', got {self.gather!r}")
        if self.membrane not in ("stvk", "corotated"):
            raise ValueError(f"VBDConfig.membrane must be 'stvk' or 'corotated', got {self.membrane!r}")
        if self.max_registers not in (-1, 0) and not 24 <= self.max_registers <= 255:
            raise ValueError("VBDConfig.max_registers must be -1 (auto), 0 (compiler's choice) or in "
                             f"24..255, got {self.max_registers}")
        if self.lanes < 0 or self.lanes > 256:
            raise ValueError(f"VBDConfig.lanes must be in 0..256 (0: auto), got {self.lanes}")
        if self.particles_per_block < 1 or self.lanes * self.particles_per_block > 1024:
            raise ValueError("VBDConfig.particles_per_block must be >= 1 with lanes x particles_per_block "
                             f"<= 1024, got {self.particles_per_block} x {self.lanes}")
        for name in ("contact_stiffness", "contact_margin", "friction_epsilon", "self_contact_radius",
                     "self_contact_margin", "self_contact_stiffness", "self_contact_speed_factor",
                     "self_contact_capacity"):
            if getattr(self, name) <= 0.0:
                raise ValueError(f"VBDConfig.{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 <= self.self_contact_weight_floor <= 1.0:
            raise ValueError("VBDConfig.self_contact_weight_floor must be in [0, 1], got "
                             f"{self.self_contact_weight_floor}")
        if not 0.0 < self.self_contact_relaxation < 0.5:
            raise ValueError("VBDConfig.self_contact_relaxation must be in (0, 0.5), got "
                             f"{self.self_contact_relaxation}")
        object.__setattr__(self, "coarse_sweeps", tuple(int(k) for k in self.coarse_sweeps))
        if any(not 0 <= k < self.iterations for k in self.coarse_sweeps) or \
                len(set(self.coarse_sweeps)) != len(self.coarse_sweeps):
            raise ValueError("VBDConfig.coarse_sweeps must hold distinct sweep indices in 0.."
                             f"{self.iterations - 1}, got {self.coarse_sweeps} (or none: coarse_sweeps = [])")
        if self.coarse_spacing < 0:
            raise ValueError("VBDConfig.coarse_spacing must be >= 1 (0: automatic), got "
                             f"{self.coarse_spacing}")
        if self.coarse_levels not in (0, 2, 3):
            raise ValueError("VBDConfig.coarse_levels must be 2, 3 or 0 (automatic), got "
                             f"{self.coarse_levels}")
        if self.coarse_smoothing < 1:
            raise ValueError(f"VBDConfig.coarse_smoothing must be >= 1, got {self.coarse_smoothing}")
        if self.coarse_sweeps and self.chebyshev_rho > 0.0:
            raise ValueError("VBDConfig.coarse_sweeps and chebyshev_rho cannot be combined")
        if not 0.0 <= self.chebyshev_rho < 1.0:
            raise ValueError(f"VBDConfig.chebyshev_rho must be in [0, 1), got {self.chebyshev_rho}")
        if self.air_damping < 0.0:
            raise ValueError(f"VBDConfig.air_damping must be >= 0 1/s, got {self.air_damping}")
        if self.self_contact_friction < 0.0:
            raise ValueError(f"VBDConfig.self_contact_friction must be >= 0, got "
                             f"{self.self_contact_friction}")
        if self.self_contact_coarse_exclusion < 0.0:
            raise ValueError(f"VBDConfig.self_contact_coarse_exclusion must be >= 0, got "
                             f"{self.self_contact_coarse_exclusion}")
        if self.self_contact_rest_exclusion < 0.0:
            raise ValueError(f"VBDConfig.self_contact_rest_exclusion must be >= 0, got "
                             f"{self.self_contact_rest_exclusion}")
        if self.self_contact_margin < self.self_contact_radius:
            raise ValueError("VBDConfig.self_contact_margin must be >= self_contact_radius")


AUTO_LANES_PARTICLES = 16384
# register cap of the solve in the automatic batch layout (VBDConfig.max_registers -1). The
# uncapped 4-lane split kernel takes 146 registers (3 blocks of 128 threads per SM); t-shirt
# 16x10, walk, H100, session 19: 256 t-shirts 608.3 garment-frames/s uncapped, 632.9 at 128
# (80 spilled bytes), 589.4 at 96 (208); one t-shirt (16-lane fused layout, 209 registers)
# 10.18 ms/frame uncapped, 11.56 at 128, so single garments stay uncapped.
AUTO_BATCH_MAX_REGISTERS = 128
# heavy blocks per colour launch and instance (auto): every launch carries the cap's blocks, and
# those without a vertex still cost their place in the grid. t-shirt 20x10, H100, session 15
# (4 colours), walk/run ms per frame: cap 0 17.6/18.0, 64 16.3/16.4, 96 16.3/16.4,
# 128 16.4/16.5, 160 16.3/16.4, 256 16.7/16.8, 512 17.3/17.5
AUTO_HEAVY_CAP = 96


def auto_lanes(largest_color: int) -> tuple[int, int]:
    """(lanes, particles per block) of the solve for ``VBDConfig.lanes`` 0, by the particle count
    of the model's largest colour: 16 x 8 below ``AUTO_LANES_PARTICLES`` (latency-bound
    launches: a 5k t-shirt's colours hold ~1000 particles), 4 x 32 from there on (the GPU is
    full: 16k particles x 16 lanes is about two waves of an H100's resident threads).
    Measured on the t-shirt (session 12, H100, 20x10, walk): batch 1 runs fastest at 16
    lanes; batch 64 gives 248 garment-frames/s at 16 lanes, 314 at 8, 344 at 4 and 2, 320 at 1."""
    return (4, 32) if largest_color >= AUTO_LANES_PARTICLES else (16, 8)


def solve_layout(config: VBDConfig, largest_color: int) -> tuple[int, int, int]:
    """(lanes, particles per block, register cap) of the CUDA solve for ``config`` and the
    particle count of the model's largest colour: ``auto_lanes`` where ``config.lanes`` is 0,
    and with ``max_registers`` -1 the cap ``AUTO_BATCH_MAX_REGISTERS`` where that picks the
    batch layout (fewer than ``vbd_kernels.FUSED_LANES`` lanes), else none (0)."""
    lanes, particles = config.lanes, config.particles_per_block
    regs = max(config.max_registers, 0)
    if lanes == 0:
        lanes, particles = auto_lanes(largest_color)
        if config.max_registers == -1 and lanes < K.FUSED_LANES:
            regs = AUTO_BATCH_MAX_REGISTERS
    return lanes, particles, regs


def chebyshev_omegas(rho: float, iterations: int) -> list[float]:
    """Chebyshev weights ``omega_1 .. omega_iterations`` for spectral radius ``rho`` (empty for
    ``rho = 0``: no acceleration)."""
    if rho <= 0.0:
        return []
    out = [1.0]
    for k in range(2, iterations + 1):
        out.append(2.0 / (2.0 - rho * rho) if k == 2 else 4.0 / (4.0 - rho * rho * out[-1]))
    return out


class SolverVBD:
    """Vertex Block Descent for a (batched) ``ClothModel``.

    Args:
        model: the cloth model.
        config: solver settings.
    """

    def __init__(self, model: ClothModel, config: VBDConfig | None = None):
        wp = warp()
        self.model = model
        self.config = config or VBDConfig()
        d = model.device
        n = model.particle_count
        self._x_prev = wp.zeros(n, dtype=wp.vec3, device=d)
        self._y = wp.zeros(n, dtype=wp.vec3, device=d)
        self._x_step_start = wp.zeros(n, dtype=wp.vec3, device=d)
        self._contact_point = wp.zeros(n, dtype=wp.vec3, device=d)
        self._contact_normal = wp.zeros(n, dtype=wp.vec3, device=d)
        self._contact_body_velocity = wp.zeros(n, dtype=wp.vec3, device=d)
        self._contact_active = wp.zeros(n, dtype=wp.int32, device=d)
        self._gravity = wp.vec3(*model.gravity)
        # lanes per particle and particles per block of the solve (Warp runs tiles with one
        # thread per block on the CPU)
        cuda = wp.get_device(d).is_cuda
        offsets = model.color_offsets
        lanes, particles, regs = solve_layout(
            self.config, max((b - a for a, b in zip(offsets[:-1], offsets[1:], strict=True)), default=0))
        self._lanes = lanes if cuda else 1
        self._particles = particles if cuda else 1
        fused = {"auto": None, "fused": True, "split": False}[self.config.gather]
        self._max_registers = regs if cuda else 0
        self._solve = K.solve_color_kernel(self._particles, self._lanes, fused, self._max_registers,
                                           fast_math=self.config.fast_math)
        # side stream 0: the bodies' placement and contact; 1: the forward step (after the first
        # substep's) and the previous deformation; ``_placing``: the next substep's placement (``step``)
        self._side = SideStreams(d, 2)
        self._placing = SideStreams(d, 1)
        self._pipe = SideStreams(d, 1)
        self._coarse_side = SideStreams(d, 1)
        self._membrane = {"stvk": 0, "corotated": 1}[self.config.membrane]
        # the solve's fused gather reads entry 0 of the per-hinge arrays for vertices without
        # hinges: a model without any gets one-entry placeholders
        self._hinges = [model.edge_indices, model.edge_rest_angle, model.edge_stiffness, model.edge_damping]
        self._vertex_hinges = [model.vertex_edge_offsets, model.vertex_edge_ids, model.vertex_edge_local]
        if model.edge_count == 0:
            self._hinges = [wp.zeros(1, dtype=a.dtype, device=d) for a in self._hinges]
            self._vertex_hinges[1:] = [wp.zeros(1, dtype=wp.int32, device=d)] * 2
        self._tri_strain_prev = wp.zeros(model.tri_count, dtype=wp.vec3, device=d)
        self._edge_angle_prev = wp.zeros(max(model.edge_count, 1), dtype=float, device=d)
        cfg = self.config
        self._omegas = chebyshev_omegas(cfg.chebyshev_rho, cfg.iterations)
        if self._omegas:
            self._cheb_prev1 = wp.zeros(n, dtype=wp.vec3, device=d)
            self._cheb_prev2 = wp.zeros(n, dtype=wp.vec3, device=d)
        if cfg.self_contact:
            self.self_contact = SelfContact(
                model, radius=cfg.self_contact_radius, margin=cfg.self_contact_margin,
                stiffness=cfg.self_contact_stiffness, friction=cfg.self_contact_friction,
                relaxation=cfg.self_contact_relaxation, speed_factor=cfg.self_contact_speed_factor,
                capacity=cfg.self_contact_capacity, rest_exclusion=cfg.self_contact_rest_exclusion,
                ring_exclusion=cfg.self_contact_ring_exclusion,
                coarse_exclusion=cfg.self_contact_coarse_exclusion,
                bounds=cfg.self_contact_bounds, side_memory=cfg.self_contact_side_memory,
                relative_lists=cfg.self_contact_relative_lists, pool=cfg.self_contact_pool,
                heavy_cap=self.heavy_cap(cuda), heavy_threshold=self._lanes,
                weight_floor=cfg.self_contact_weight_floor, ee_interior=cfg.self_contact_ee_interior,
                slots=2 if cfg.self_contact_pipeline else 1,
                lookahead=cfg.self_contact_lookahead_margin if cfg.self_contact_lookahead else None,
                broadphase=self.broadphase(cuda), cluster_size=cfg.self_contact_cluster_size,
                cluster_split=cfg.self_contact_cluster_split if not cfg.self_contact_side_memory else 1)
            self._sc_data = self.self_contact.data
        else:
            self.self_contact = None
            self._sc_data = disabled_data(d)
        # the positions at the start of each sweep, for same-colour neighbours (hinge opposites,
        # contact partners); the sweeps alternate between the two (``sweep``)
        self._snapshots = (wp.zeros(n, dtype=wp.vec3, device=d), wp.zeros(n, dtype=wp.vec3, device=d))
        self._solve_arrays_cache: dict = {}
        self._limit_buffer = wp.zeros(n, dtype=wp.vec3, device=d) if cfg.strain_limit > 0.0 else None
        self.coarse = None
        if cfg.coarse_sweeps:
            from sim.cloth.coarse import CoarseLevel

            particles = (self._x_prev, self._y, self._contact_point, self._contact_normal,
                         self._contact_body_velocity, self._contact_active)
            self.coarse = CoarseLevel(model, particles, cfg.contact_stiffness, cfg.contact_margin,
                                      cfg.air_damping, cfg.coarse_spacing, cfg.coarse_levels,
                                      cfg.coarse_smoothing, cfg.coarse_prefactor, cfg.coarse_guard)
            self._evaluate = K.solve_color_kernel(self._particles, self._lanes, fused, self._max_registers,
                                                  evaluate=True, fast_math=cfg.fast_math)
        # ``coarse_early``: the particles with pairs at the previous substep's end (the velocity
        # kernel writes them; empty: not written)
        self._early = self.coarse is not None and self.coarse.prefactor and cfg.coarse_early
        self._pair_flags = wp.zeros(n if self._early and cfg.self_contact else 0, dtype=wp.int32, device=d)

    def broadphase(self, cuda: bool) -> str:
        """The self-contact broadphase: ``VBDConfig.self_contact_broadphase``, where ``"auto"`` is
        the clusters on CUDA for a model of at most ``CLUSTER_PRIMITIVES`` vertices, triangles
        and edges (session 40, H100: one 5k t-shirt 4.54 / 4.55 against 5.33 / 5.44 ms per frame,
        populations passing as often), and the trees for larger models (64 / 256 t-shirts: 1,236
        / 1,327 garment-frames/s with clusters against 1,378 / 1,493 with trees: a full GPU pays
        for the clusters' extra candidates, not for the trees' latency), on the CPU (1k t-shirt
        112 against 151 ms: one thread walks every marked cluster in turn) and wherever the
        lookahead needs them."""
        cfg = self.config
        if cfg.self_contact_broadphase != "auto":
            return cfg.self_contact_broadphase
        m = self.model
        primitives = m.particle_count + m.tri_count + m.mesh_edge_indices.shape[0]
        small = primitives <= CLUSTER_PRIMITIVES
        return "clusters" if cuda and small and not cfg.self_contact_lookahead else "bvh"

    def heavy_cap(self, cuda: bool) -> int:
        """Heavy-vertex blocks per colour launch (``VBDConfig.self_contact_heavy_cap``; -1: auto,
        ``AUTO_HEAVY_CAP`` per instance in the 16-lane layout on CUDA, else 0)."""
        cap = self.config.self_contact_heavy_cap
        if cap >= 0:
            return cap
        return AUTO_HEAVY_CAP * self.model.instance_count if cuda and self._lanes >= 8 else 0

    def _solve_arrays(self, sc_data) -> K.SolveArrays:
        """The solve kernel's ``SolveArrays`` with ``sc_data``'s self-contact part (cached per
        ``sc_data`` while its scalars and array addresses stay the same)."""
        key = solve_contact_key(sc_data)
        cached = self._solve_arrays_cache.get(id(sc_data))
        if cached is not None and cached[0] is sc_data and cached[1] == key:
            return cached[2]
        m = self.model
        a = K.SolveArrays()
        arrays = [m.color_vertices, self._x_prev, self._y, m.particle_mass, m.particle_flags,
                  m.particle_instance, m.tri_indices, m.tri_dm_inv, m.tri_area, m.tri_mu, m.tri_lam,
                  m.tri_damping, self._tri_strain_prev, *self._hinges, self._edge_angle_prev,
                  m.vertex_tri_offsets, m.vertex_tri_ids, m.vertex_tri_local, *self._vertex_hinges,
                  self._contact_point, self._contact_normal, self._contact_body_velocity,
                  self._contact_active, m.instance_thickness, m.instance_friction]
        fill_spans(a, dict(zip(K.SOLVE_ARRAYS, arrays, strict=True)))
        a.contact = solve_contact_arrays(sc_data)
        # the cache holds sc_data itself: its arrays stay alive as long as the spans are used
        self._solve_arrays_cache[id(sc_data)] = (sc_data, key, a)
        return a

    def sweep(self, x, sc_data, eps_u: float, h: float, parity: int = 0, evaluate: bool = False) -> None:
        """One Gauss-Seidel sweep: the solve kernel over every colour, updating ``x`` in place
        against the substep's current buffers (``sc_data``: the self-contact data to use). Sweep
        ``k`` of a substep has ``parity`` ``k % 2``: the neighbours of a particle's own colour
        (hinge opposites, contact partners) are read from snapshot ``parity``, which must hold
        ``x``, and every solved particle writes its new position to snapshot ``1 - parity``.
        ``evaluate``: write the residual forces at ``x`` to the coarse level's residual buffer
        instead (``x`` stays)."""
        wp = warp()
        m = self.model
        cfg = self.config
        arrays = self._solve_arrays(sc_data)
        if evaluate:  # no particle moves: one launch over all colours, no heavy blocks
            kernel, snap_out, heavy = self._evaluate, self.coarse.residual, 0
            spans = [(0, m.particle_count)]
        else:
            kernel, snap_out = self._solve, self._snapshots[1 - parity]
            heavy = sc_data.heavy_cap if sc_data.enabled else 0
            spans = [(m.color_offsets[c], m.color_offsets[c + 1]) for c in range(m.color_count)]
        for c, (start, end) in enumerate(spans):
            light = -(-(end - start) // self._particles)
            wp.launch_tiled(
                kernel, dim=[light + min(heavy, end - start)],
                block_dim=self._particles * self._lanes,
                inputs=[end - start, c, light, self._membrane, start, cfg.contact_stiffness, eps_u, h,
                        cfg.air_damping, arrays, self._snapshots[parity]],
                outputs=[x, snap_out], device=m.device)

    def limit_strain(self, x) -> None:
        """``strain_limit_passes`` Jacobi passes of the strain limit on ``x`` (in place; the
        passes alternate between ``x`` and a buffer, an odd count ends with a copy)."""
        wp = warp()
        m = self.model
        buffers = (x, self._limit_buffer)
        for p in range(self.config.strain_limit_passes):
            wp.launch(K.strain_limit_kernel, dim=m.particle_count,
                      inputs=[self.config.strain_limit, buffers[p % 2], m.particle_rest, m.particle_mass,
                              m.particle_flags, m.mesh_edge_indices, m.vertex_mesh_edge_offsets,
                              m.vertex_mesh_edge_ids, m.vertex_mesh_edge_local, self._contact_normal,
                              self._contact_active],
                      outputs=[buffers[(p + 1) % 2]], device=m.device)
        if self.config.strain_limit_passes % 2:
            wp.copy(x, self._limit_buffer)

    def _forward(self, x, v, state_out: ClothState, control: ClothControl, h: float, alpha: float,
                 remember: int) -> None:
        m = self.model
        warp().launch(K.forward_kernel, dim=m.particle_count,
                      inputs=[x, v, state_out.accelerations, m.particle_flags, self._x_step_start,
                              control.pin_targets, self._gravity, h, alpha, remember],
                      outputs=[self._x_prev, self._y, x, self._snapshots[0]], device=m.device)

    def step(self, state_in: ClothState, state_out: ClothState, control: ClothControl, dt: float) -> None:
        """Advance by ``dt`` [s]; ``state_out`` may be ``state_in``.

        Pinned particles move linearly from their ``state_in`` positions to
        ``control.pin_targets``; bodies from ``points_start`` to ``points_end``.
        """
        wp = warp()
        m = self.model
        cfg = self.config
        d = m.device
        n = m.particle_count
        x = state_out.positions
        v = state_out.velocities
        if state_out is not state_in:
            wp.copy(x, state_in.positions)
            wp.copy(v, state_in.velocities)
            wp.copy(state_out.accelerations, state_in.accelerations)
        h = dt / cfg.substeps
        eps_u = cfg.friction_epsilon * h
        pipe = self.self_contact is not None and cfg.self_contact_pipeline
        for s in range(cfg.substeps):
            alpha = (s + 1) / cfg.substeps
            if control.bodies and s == 0:
                # the bodies moved (and their trees refitted) on a side stream (CUDA), beside the
                # forward step: only the body contact below reads them (session 31: ~60 us of
                # small launches per substep off the critical path); the later substeps' moves
                # run beside the sweeps before them (below)
                with self._side.on(0):
                    for body in control.bodies:
                        body.place(alpha, dt)
            if s == 0:
                # x_prev: the step's start (later substeps have it from the velocity kernel)
                self._forward(x, v, state_out, control, h, alpha, 1)
            with self._side.on(1):
                # only the sweeps read them: the forward step (after the first substep's) and the
                # previous deformation beside the self-contact detection and the body contact,
                # which read only x_prev and v (session 41)
                if s > 0:
                    self._forward(x, v, state_out, control, h, alpha, 0)
                wp.launch(K.previous_deformation_kernel, dim=m.tri_count + m.edge_count,
                          inputs=[self._x_prev, m.tri_indices, m.tri_dm_inv, m.edge_indices, m.tri_count],
                          outputs=[self._tri_strain_prev, self._edge_angle_prev], device=d)
            if control.bodies:
                # on the same side stream, after the bodies' placement and beside the self-contact
                # detection: both only read x_prev
                with self._side.on(0):
                    self._placing.join()
                    wp.launch(K.body_contact_kernel, dim=n,
                              inputs=[self._x_prev, m.particle_instance, control.instance_body,
                                      cfg.contact_margin],
                              outputs=[self._contact_point, self._contact_normal, self._contact_body_velocity,
                                       self._contact_active], device=d)
                    if s + 1 < cfg.substeps:
                        # the next substep's placement, once this contact has read the bodies, on a
                        # stream of its own beside this substep's detection and sweeps (nothing
                        # else reads the bodies' meshes), joined before the next contact (session
                        # 41); on the CPU in this order, so the same floats
                        with self._placing.on(0):
                            for body in control.bodies:
                                body.place((s + 2) / cfg.substeps, dt)
            else:
                self._contact_active.zero_()
            if self._early:
                # the coarse diagonal and factor beside the detection (``coarse_early``): from the
                # inertial targets and the body contacts (side streams 1 and 0) and the previous
                # substep's pairs, so only the sweeps wait for the detection (session 42)
                with self._coarse_side.on(0):
                    self._side.wait_here()
                    # (without self-contact the flags are empty: the disabled lists flag nothing)
                    self.coarse.prepare(h, self._sc_data, self._pair_flags)
            sc_data = self._sc_data
            if self.self_contact is not None and cfg.self_contact_lookahead:
                # the trees are rebuilt once per step, by the first query beside the sweeps
                # rather than the step's first query, which is on the critical path
                rebuild = cfg.self_contact_rebuild and s == (1 if cfg.substeps > 2 else 0)
                if s == 0:
                    # the step's first candidates, for this substep and the next
                    self.self_contact.query_candidates(self._x_prev, v, h, rebuild=rebuild,
                                                       reference=control.instance_velocity)
                self.self_contact.remeasure(self._x_prev, v, h)
                if 0 < s < cfg.substeps - 1:
                    # the next substep's candidates beside this substep's sweeps, from its start;
                    # joined before x_prev and v change
                    with self._pipe.on(0):
                        self.self_contact.query_candidates(self._x_prev, v, h, rebuild=rebuild)
            elif (self.self_contact is not None and s % cfg.self_contact_interval == 0
                  and (s == 0 or not pipe)):
                # pairs found now serve the next ``interval`` substeps: the query covers that motion
                self.self_contact.detect(self._x_prev, v, h * cfg.self_contact_interval,
                                         rebuild=cfg.self_contact_rebuild and s == 0,
                                         reference=control.instance_velocity)
            if pipe:
                sc_data = self.self_contact.datas[s % 2]
                if s > 0:
                    # lists found from the previous substep's start: sides as this substep starts
                    self.self_contact.refresh_sides(self._x_prev, slot=s % 2)
                if s + 1 < cfg.substeps:
                    # the next substep's pairs, beside this substep's sweeps: from this substep's
                    # start, over the motion of both substeps; joined before x_prev and v change
                    with self._pipe.on(0):
                        self.self_contact.detect(self._x_prev, v, 2.0 * h,
                                                 reference=control.instance_velocity, slot=(s + 1) % 2)
            self._side.join()
            if self.coarse is not None and self.coarse.prefactor and not self._early:
                # the coarse diagonal and factor from the substep start, beside the first sweeps
                with self._coarse_side.on(0):
                    self.coarse.prepare(h, sc_data)
            if self._omegas:
                wp.copy(self._cheb_prev1, x)
            for it in range(cfg.iterations):
                if it in cfg.coarse_sweeps:
                    # the residual at x (snapshot it % 2 holds x), its coarse-level correction
                    self.sweep(x, sc_data, eps_u, h, it % 2, evaluate=True)
                    self._coarse_side.join()
                    self.coarse.correct(h, x, self._snapshots[it % 2], sc_data, control.instance_body)
                self.sweep(x, sc_data, eps_u, h, it % 2)
                if self._omegas:
                    wp.launch(K.chebyshev_kernel, dim=n,
                              inputs=[self._omegas[it], m.particle_flags],
                              outputs=[x, self._cheb_prev1, self._cheb_prev2, self._snapshots[(it + 1) % 2]],
                              device=d)
            if self._limit_buffer is not None:
                self.limit_strain(x)
            self._pipe.join()
            wp.launch(K.velocity_kernel, dim=n, inputs=[x, self._x_prev, 1.0 / h, sc_data],
                      outputs=[v, state_out.accelerations, self._pair_flags], device=d)
