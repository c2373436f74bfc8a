"""``SolverVBD``: Vertex Block Descent cloth solver (Chen et al. 2024).

``step(state_in, state_out, control, dt)`` advances every instance of the model by ``dt``
[s] in ``substeps`` implicit-Euler substeps, each solved by ``iterations`` Gauss-Seidel sweeps
over the vertex colouring. Per substep:

1. ``_begin_substep``: the bodies move to the substep's end (linear in time between the step's
   two body frames) and their BVHs are refit; ``forward_kernel`` sets the inertial target and
   the initial guess (pinned particles placed); ``previous_deformation_kernel`` the
   substep-start strains and hinge angles (the damping reference); ``body_contact_kernel`` one
   contact plane per particle against its instance's body, found from the particle's
   substep-start position against the body's substep-end placement. On CUDA these run on side
   streams (``sim.device.SideStreams``) beside the detection, and the next substep's body
   placement beside this substep's detection and sweeps.
2. ``_detect``: with self-contact, the vertex-triangle and edge-edge pairs at the substep start
   (``sim.cloth.self_contact``; the cloth BVHs are rebuilt at a step's first detection and
   refit at the others), with speeds relative to each instance's
   ``control.instance_velocity``; with the coarse correction its system is prepared from the
   substep start beside the first sweeps (``CoarseConfig.early``: already beside the
   detection, from the previous substep's pairs).
3. ``_sweeps``: ``iterations`` x colours launches of the solve kernel
   (``sim.cloth.solve_kernel``); neighbours of a vertex's own colour are read from the
   sweep-start snapshot, so the step does not depend on the order of the GPU's threads; a
   coarse-level correction before the sweeps ``CoarseConfig.sweeps`` names.
4. ``_end_substep``: ``velocity_kernel`` (and ``x_prev`` for the next substep; with
   ``CoarseConfig.early`` the flags of the particles with pairs).

Substep safety: contact is found against the body where it will be at the end of each
substep, and the sign test classifies a particle the body has overtaken correctly as long as
the body moves less than half its local thickness per substep (5 m/s at 30 fps with 10
substeps: 1.7 cm). The contact energy is a half-space penalty, so the particle is pushed back
out however far its initial guess went.

No host synchronisation, numpy or allocation inside ``step``: all buffers are allocated in
the constructor; the step can be captured in a CUDA graph once bodies and pins are uploaded.
"""

from __future__ import annotations

from sim.cloth import solve_kernel as S
from sim.cloth import vbd_kernels as K
from sim.cloth.config import KernelLayout, VBDConfig
from sim.cloth.model import ClothModel
from sim.cloth.self_contact import SelfContact, disabled_data, solve_contact_arrays, solve_contact_key
from sim.cloth.spans import fill_spans
from sim.cloth.state import ClothControl, ClothState
from sim.device import SideStreams, warp

CLUSTER_PRIMITIVES = 131072
"""The largest model (vertices + triangles + edges) that the ``"auto"`` broadphase searches with
clusters on CUDA (``SolverVBD.broadphase``): up to four 5k t-shirts or one 30k garment."""
AUTO_LANES_PARTICLES = 16384
"""Particles of the largest colour from which ``auto_lanes`` picks the batch layout."""
AUTO_BATCH_MAX_REGISTERS = 128
"""Register cap of the solve in the automatic batch layout (``KernelLayout.max_registers`` -1):
the uncapped 4-lane split kernel takes 146 registers (3 blocks of 128 threads per SM); H100,
t-shirt 16 x 10 walk: 256 t-shirts 632.9 garment-frames/s at 128 (80 spilled bytes) against
608.3 uncapped and 589.4 at 96; one t-shirt (16-lane fused layout, 209 registers) 10.18 ms per
frame uncapped against 11.56 at 128, so single garments stay uncapped."""
AUTO_HEAVY_CAP = 96
"""Heavy blocks per colour launch and instance (``SelfContactConfig.heavy_cap`` -1): every launch
carries the cap's blocks, and those without a vertex still cost their place in the grid. H100,
t-shirt 20 x 10 (4 colours), walk / run ms per frame: cap 0 17.6 / 18.0, 64 16.3 / 16.4, 96
16.3 / 16.4, 128 16.4 / 16.5, 256 16.7 / 16.8, 512 17.3 / 17.5."""


def auto_lanes(largest_color: int) -> tuple[int, int]:
    """(lanes, particles per block) of the solve for ``KernelLayout.lanes`` 0, by the particle
    count of the model's largest colour: 16 x 8 below ``AUTO_LANES_PARTICLES`` (latency-bound
    launches: a 5k t-shirt's colours hold ~1000 particles, and more lanes shorten each
    particle's serial gather), 4 x 32 from there on (the GPU is full: 16k particles x 16 lanes is
    about two waves of an H100's resident threads). H100, t-shirt 20 x 10, walk: batch 1 runs
    fastest at 16 lanes; batch 64 gives 248 garment-frames/s at 16 lanes, 314 at 8, 344 at 4
    and 2, 320 at 1."""
    return (4, 32) if largest_color >= AUTO_LANES_PARTICLES else (16, 8)


def solve_layout(layout: KernelLayout, largest_color: int) -> tuple[int, int, int]:
    """(lanes, particles per block, register cap) of the CUDA solve for ``layout`` and the
    particle count of the model's largest colour: ``auto_lanes`` where ``layout.lanes`` is 0,
    and with ``max_registers`` -1 the cap ``AUTO_BATCH_MAX_REGISTERS`` where that picks the
    batch layout (fewer than ``solve_kernel.FUSED_LANES`` lanes), else none (0)."""
    lanes, particles = layout.lanes, layout.particles_per_block
    regs = max(layout.max_registers, 0)
    if lanes == 0:
        lanes, particles = auto_lanes(largest_color)
        if layout.max_registers == -1 and lanes < S.FUSED_LANES:
            regs = AUTO_BATCH_MAX_REGISTERS
    return lanes, particles, regs


class SolverVBD:
    """Vertex Block Descent for a (batched) ``ClothModel``.

    Args:
        model: the cloth model.
        config: solver settings (None: the defaults, ``VBDConfig()``).
    """

    def __init__(self, model: ClothModel, config: VBDConfig | None = None):
        wp = warp()
        self.model = model
        self.config = config or VBDConfig()
        self._cuda = wp.get_device(model.device).is_cuda
        self._allocate()
        self._build_solve()
        # side stream 0: the bodies' placement and contact; 1: the forward step (after the first
        # substep's) and the previous deformation; ``_placing``: the next substep's placement
        self._side = SideStreams(model.device, 2)
        self._placing = SideStreams(model.device, 1)
        self._coarse_side = SideStreams(model.device, 1)
        self._build_self_contact()
        self._build_coarse()

    def _allocate(self) -> None:
        """The per-particle buffers of a substep and the model arrays the solve reads."""
        wp = warp()
        m = self.model
        d, n = m.device, m.particle_count
        self._x_prev, self._y, self._x_step_start = (wp.zeros(n, dtype=wp.vec3, device=d) for _ in range(3))
        self._contact_point, self._contact_normal, self._contact_body_velocity = (
            wp.zeros(n, dtype=wp.vec3, device=d) for _ in range(3))
        self._contact_active = wp.zeros(n, dtype=wp.int32, device=d)
        self._gravity = wp.vec3(*m.gravity)
        # the solve's fused gather reads entry 0 of the per-hinge arrays for vertices without
        # hinges: a model without any gets one-entry placeholders
        self._hinges = [m.edge_indices, m.edge_rest_angle, m.edge_stiffness, m.edge_damping]
        self._vertex_hinges = [m.vertex_edge_offsets, m.vertex_edge_ids, m.vertex_edge_local]
        if m.edge_count == 0:
            self._hinges = [wp.zeros(1, dtype=a.dtype, device=d) for a in self._hinges]
            self._vertex_hinges[1:] = [wp.zeros(1, dtype=wp.int32, device=d)] * 2
        self._tri_strain_prev = wp.zeros(m.tri_count, dtype=wp.vec3, device=d)
        self._edge_angle_prev = wp.zeros(max(m.edge_count, 1), dtype=float, device=d)
        # the positions at the start of each sweep, for same-colour neighbours (hinge opposites,
        # contact partners); the sweeps alternate between the two (``sweep``)
        self._snapshots = (wp.zeros(n, dtype=wp.vec3, device=d), wp.zeros(n, dtype=wp.vec3, device=d))
        self._solve_arrays_cache: dict = {}

    def _build_solve(self) -> None:
        """The solve kernel for the model's size and the layout (one thread per particle on the
        CPU, where Warp runs a tile block as one thread)."""
        layout = self.config.layout
        offsets = self.model.color_offsets
        largest = max((b - a for a, b in zip(offsets[:-1], offsets[1:], strict=True)), default=0)
        lanes, particles, regs = solve_layout(layout, largest)
        self._lanes = lanes if self._cuda else 1
        self._particles = particles if self._cuda else 1
        self._max_registers = regs if self._cuda else 0
        self._fused = {"auto": None, "fused": True, "split": False}[layout.gather]
        self._solve = S.solve_color_kernel(self._particles, self._lanes, self._fused, self._max_registers,
                                           fast_math=layout.fast_math)

    def _build_self_contact(self) -> None:
        """The self-contact detection and its data (disabled data without self-contact)."""
        sc = self.config.self_contact
        self.self_contact = None
        if not sc.enabled:
            self._sc_data = disabled_data(self.model.device)
            return
        self.self_contact = SelfContact(
            self.model, radius=sc.radius, margin=sc.margin, stiffness=sc.stiffness, friction=sc.friction,
            speed_factor=sc.speed_factor, capacity=sc.capacity, coarse_exclusion=sc.coarse_exclusion,
            pool=sc.pool, heavy_cap=self.heavy_cap(self._cuda), heavy_threshold=self._lanes,
            weight_floor=sc.weight_floor, broadphase=self.broadphase(self._cuda),
            cluster_size=sc.cluster_size, cluster_split=sc.cluster_split)
        self._sc_data = self.self_contact.data

    def _build_coarse(self) -> None:
        """The coarse level and the solve's evaluate variant, where ``CoarseConfig.sweeps`` names
        sweeps; ``_pair_flags``: the particles with pairs at the previous substep's end, for
        ``CoarseConfig.early`` (the velocity kernel writes them; empty: not written)."""
        wp = warp()
        cfg = self.config
        m = self.model
        self.coarse = None
        if cfg.coarse.sweeps:
            from sim.cloth.coarse import CoarseLevel

            c, contact = cfg.coarse, cfg.body_contact
            self.coarse = CoarseLevel(
                m, self._y, self._contact_point, self._contact_normal, self._contact_active,
                k_contact=contact.stiffness, contact_margin=contact.margin,
                air_damping=cfg.stepping.air_damping, spacing=c.spacing, levels=c.levels,
                smoothing=c.smoothing)
            self._evaluate = S.solve_color_kernel(self._particles, self._lanes, self._fused,
                                                  self._max_registers, evaluate=True,
                                                  fast_math=cfg.layout.fast_math)
        self._early = self.coarse is not None and self.coarse.prefactor and cfg.coarse.early
        flags = m.particle_count if self._early and self.self_contact is not None else 0
        self._pair_flags = wp.zeros(flags, dtype=wp.int32, device=m.device)

    def broadphase(self, cuda: bool) -> str:
        """The self-contact broadphase: ``SelfContactConfig.broadphase``, where ``"auto"`` is the
        clusters on CUDA for a model of at most ``CLUSTER_PRIMITIVES`` vertices, triangles and
        edges (H100, one 5k t-shirt: 4.54 / 4.55 against 5.33 / 5.44 ms per walk / run frame,
        populations passing as often) and the trees for larger models (64 / 256 t-shirts: 1,378
        / 1,493 garment-frames/s with trees against 1,236 / 1,327 with clusters: a full GPU pays
        for the clusters' extra candidates, not for the trees' latency) and on the CPU (1k
        t-shirt 112 against 151 ms: one thread walks every marked cluster in turn)."""
        choice = self.config.self_contact.broadphase
        if choice != "auto":
            return choice
        m = self.model
        primitives = m.particle_count + m.tri_count + m.mesh_edge_indices.shape[0]
        return "clusters" if cuda and primitives <= CLUSTER_PRIMITIVES else "bvh"

    def heavy_cap(self, cuda: bool) -> int:
        """Heavy-vertex blocks per colour launch (``SelfContactConfig.heavy_cap``; -1:
        ``AUTO_HEAVY_CAP`` per instance in the 16-lane layout on CUDA, else 0: the batched
        4-lane layout fills the GPU, so a long vertex does not idle it)."""
        cap = self.config.self_contact.heavy_cap
        if cap >= 0:
            return cap
        return AUTO_HEAVY_CAP * self.model.instance_count if cuda and self._lanes >= 8 else 0

    def _solve_arrays(self, sc_data) -> S.SolveArrays:
        """The solve kernel's ``SolveArrays`` with ``sc_data``'s self-contact part (cached per
        ``sc_data`` while its scalars and array addresses stay the same)."""
        key = solve_contact_key(sc_data)
        cached = self._solve_arrays_cache.get(id(sc_data))
        if cached is not None and cached[0] is sc_data and cached[1] == key:
            return cached[2]
        m = self.model
        a = S.SolveArrays()
        arrays = [m.color_vertices, self._x_prev, self._y, m.particle_mass, m.particle_flags,
                  m.particle_instance, m.tri_indices, m.tri_dm_inv, m.tri_area, m.tri_mu, m.tri_lam,
                  m.tri_damping, self._tri_strain_prev, *self._hinges, self._edge_angle_prev,
                  m.vertex_tri_offsets, m.vertex_tri_ids, m.vertex_tri_local, *self._vertex_hinges,
                  self._contact_point, self._contact_normal, self._contact_body_velocity,
                  self._contact_active, m.instance_thickness, m.instance_friction]
        fill_spans(a, dict(zip(S.SOLVE_ARRAYS, arrays, strict=True)))
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
                inputs=[end - start, c, light, start, cfg.body_contact.stiffness, eps_u, h,
                        cfg.stepping.air_damping, arrays, self._snapshots[parity]],
                outputs=[x, snap_out], device=m.device)

    def step(self, state_in: ClothState, state_out: ClothState, control: ClothControl, dt: float) -> None:
        """Advance by ``dt`` [s]; ``state_out`` may be ``state_in``.

        Pinned particles move linearly from their ``state_in`` positions to
        ``control.pin_targets``; bodies from ``points_start`` to ``points_end``.
        """
        wp = warp()
        if state_out is not state_in:
            wp.copy(state_out.positions, state_in.positions)
            wp.copy(state_out.velocities, state_in.velocities)
            wp.copy(state_out.accelerations, state_in.accelerations)
        substeps = self.config.stepping.substeps
        h = dt / substeps
        for s in range(substeps):
            self._begin_substep(s, state_out, control, h, dt)
            self._detect(s, state_out.velocities, h, control)
            self._sweeps(state_out.positions, h, control)
            self._end_substep(state_out, h)

    def _forward(self, state: ClothState, control: ClothControl, h: float, alpha: float,
                 remember: int) -> None:
        m = self.model
        warp().launch(K.forward_kernel, dim=m.particle_count,
                      inputs=[state.positions, state.velocities, state.accelerations, m.particle_flags,
                              control.pin_targets, self._gravity, h, alpha, remember],
                      outputs=[self._x_step_start, self._x_prev, self._y, state.positions,
                               self._snapshots[0]], device=m.device)

    def _begin_substep(self, s: int, state: ClothState, control: ClothControl, h: float, dt: float) -> None:
        """Substep ``s``'s inertial targets and initial guess, its damping reference and its body
        contacts (item 1 of the module docstring)."""
        wp = warp()
        m = self.model
        substeps = self.config.stepping.substeps
        alpha = (s + 1) / substeps
        if control.bodies and s == 0:
            # the bodies move on a side stream (CUDA) beside the forward step: only the body
            # contact reads them; the later substeps' moves run beside the sweeps before them
            with self._side.on(0):
                for body in control.bodies:
                    body.place(alpha, dt)
        if s == 0:
            # x_prev: the step's start (later substeps have it from the velocity kernel)
            self._forward(state, control, h, alpha, 1)
        with self._side.on(1):
            # only the sweeps read these: the forward step (after the first substep's) and the
            # previous deformation run beside the detection and the body contact, which read
            # only x_prev and v
            if s > 0:
                self._forward(state, control, h, alpha, 0)
            wp.launch(K.previous_deformation_kernel, dim=m.tri_count + m.edge_count,
                      inputs=[self._x_prev, m.tri_indices, m.tri_dm_inv, m.edge_indices, m.tri_count],
                      outputs=[self._tri_strain_prev, self._edge_angle_prev], device=m.device)
        if control.bodies:
            self._body_contact(s, control, dt)
        else:
            self._contact_active.zero_()
        if self._early:
            # the coarse diagonal and factor beside the detection: from the inertial targets and
            # the body contacts (side streams 1 and 0) and the previous substep's pairs, so only
            # the sweeps wait for the detection (without self-contact the flags are empty: the
            # disabled lists flag nothing)
            with self._coarse_side.on(0):
                self._side.wait_here()
                self.coarse.prepare(h, self._sc_data, self._pair_flags)

    def _body_contact(self, s: int, control: ClothControl, dt: float) -> None:
        """Substep ``s``'s body contacts, on the bodies' side stream after their placement and
        beside the self-contact detection (both only read x_prev); then the next substep's
        placement, on a stream of its own beside this substep's detection and sweeps (nothing
        else reads the bodies' meshes), joined before the next contact. On the CPU in this order."""
        m = self.model
        cfg = self.config
        with self._side.on(0):
            self._placing.join()
            warp().launch(K.body_contact_kernel, dim=m.particle_count,
                          inputs=[self._x_prev, m.particle_instance, control.instance_body,
                                  cfg.body_contact.margin],
                          outputs=[self._contact_point, self._contact_normal, self._contact_body_velocity,
                                   self._contact_active], device=m.device)
            if s + 1 < cfg.stepping.substeps:
                with self._placing.on(0):
                    for body in control.bodies:
                        body.place((s + 2) / cfg.stepping.substeps, dt)

    def _detect(self, s: int, v, h: float, control: ClothControl) -> None:
        """Substep ``s``'s self-contact pairs (the BVHs rebuilt at the step's first substep,
        refit at the others); the side streams joined; the coarse system prepared beside the
        first sweeps where it was not beside the detection."""
        if self.self_contact is not None:
            self.self_contact.detect(self._x_prev, v, h, rebuild=s == 0, reference=control.instance_velocity)
        self._side.join()
        if self.coarse is not None and self.coarse.prefactor and not self._early:
            with self._coarse_side.on(0):
                self.coarse.prepare(h, self._sc_data)

    def _sweeps(self, x, h: float, control: ClothControl) -> None:
        """The substep's sweeps, each named in ``CoarseConfig.sweeps`` after a coarse-level
        correction: the residual at ``x`` (snapshot ``it % 2`` holds ``x``), then its correction."""
        cfg = self.config
        eps_u = cfg.body_contact.friction_epsilon * h
        sc_data = self._sc_data
        for it in range(cfg.stepping.iterations):
            if it in cfg.coarse.sweeps:
                self.sweep(x, sc_data, eps_u, h, it % 2, evaluate=True)
                self._coarse_side.join()
                self.coarse.correct(h, x, self._snapshots[it % 2], sc_data, control.instance_body)
            self.sweep(x, sc_data, eps_u, h, it % 2)

    def _end_substep(self, state: ClothState, h: float) -> None:
        m = self.model
        warp().launch(K.velocity_kernel, dim=m.particle_count,
                      inputs=[state.positions, 1.0 / h, self._sc_data],
                      outputs=[self._x_prev, state.velocities, state.accelerations, self._pair_flags],
                      device=m.device)
