"""``CoarseLevel``: the coarse level of every instance of a ``ClothModel`` on its device, built
from the templates' operators (``operators``) and driving the kernels (module docstring of
``sim.cloth.coarse``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import warp as wp

from sim.cloth.coarse import block
from sim.cloth.coarse.band_kernels import band_solve_kernel
from sim.cloth.coarse.cycle_kernels import (
    PASS_FIRST,
    PASS_RESIDUAL,
    PASS_SMOOTH,
    galerkin_band_kernel,
    level_pass_kernel,
    prolong_level_kernel,
    restrict_level_kernel,
)
from sim.cloth.coarse.operators import CoarseTemplate, galerkin_slots, instance_templates
from sim.cloth.coarse.transfer_kernels import (
    RESTRICT_DIAGONAL,
    RESTRICT_LANES,
    RESTRICT_RHS,
    prolong_kernel,
    restrict_kernel,
    restrict_lanes_kernel,
    restrict_sum_kernel,
)
from sim.cloth.vbd_kernels import PINNED


class DeviceCsr(NamedTuple):
    """A scipy CSR matrix on the device, unpacked into a kernel's ``offsets, ids, weights``."""

    offsets: Any  # wp.array int32 (rows + 1,)
    ids: Any  # wp.array int32 (nnz,)
    weights: Any  # wp.array float32 (nnz,)


def device_array(a: np.ndarray, dtype, device) -> Any:
    return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)


def device_csr(m, device) -> DeviceCsr:
    """The scipy CSR matrix ``m`` on ``device`` (float32 weights)."""
    return DeviceCsr(device_array(m.indptr.astype(np.int32), wp.int32, device),
                     device_array(m.indices.astype(np.int32), wp.int32, device),
                     device_array(m.data.astype(np.float32), float, device))


@dataclass
class BandSystems:
    """Each instance's exactly solved system as a lower band in its template's RCM order: the
    banded Cholesky's (and the block kernels') inputs on the device."""

    # per instance: node start (int32), node count (int32), band width (int32), band offset (int64)
    inst: tuple
    order: Any  # int32 (nodes,): band row -> node, per instance
    stiffness: Any  # float (band floats,): the stiffness's band; the solves put the diagonal in
    values: Any  # the band the solves read: ``stiffness``, or three levels' Galerkin band
    factor: Any  # float (band floats,): the block factor, or the serial solve's working band
    forward: Any  # vec3 (nodes,): the serial solve's forward substitution
    counts: np.ndarray  # (instances,) nodes
    widths: np.ndarray  # (instances,) band widths


def band_systems(exact: list[CoarseTemplate], galerkin: bool, device) -> BandSystems:
    """The ``BandSystems`` of the instances' exactly solved templates ``exact``; ``galerkin``
    (three levels): ``values`` is its own array, assembled at each correction."""
    widths = np.array([e.band.shape[1] - 1 for e in exact], dtype=np.int64)
    counts = np.array([len(e.mass) for e in exact], dtype=np.int64)
    band_off = np.concatenate([[0], np.cumsum(counts * (widths + 1))])
    node_off = np.concatenate([[0], np.cumsum(counts)])
    inst = (device_array(node_off[:-1].astype(np.int32), wp.int32, device),
            device_array(counts.astype(np.int32), wp.int32, device),
            device_array(widths.astype(np.int32), wp.int32, device),
            device_array(band_off[:-1].astype(np.int64), wp.int64, device))
    order = device_array(np.concatenate([e.order for e in exact]).astype(np.int32), wp.int32, device)
    bands = np.concatenate([e.band.ravel() for e in exact])
    stiffness = device_array(bands.astype(np.float32), float, device)
    values = wp.zeros_like(stiffness) if galerkin else stiffness
    factor = wp.zeros(int(band_off[-1]), dtype=float, device=device)
    forward = wp.zeros(int(node_off[-1]), dtype=wp.vec3, device=device)
    return BandSystems(inst, order, stiffness, values, factor, forward, counts, widths)


@dataclass
class TwoGrid:
    """Three levels' cycle on the device: the inner prolongation ``P2`` and its transpose, the
    coarse stiffness's off-diagonal and l1 row sums (the l1-Jacobi smoother), the cycle's
    buffers, the inner level's Galerkin stiffness diagonal and band slots (``galerkin_slots``)
    and its system's right-hand side, diagonal and solution."""

    p2: DeviceCsr
    r2: DeviceCsr
    off: DeviceCsr
    l1: Any
    x1: Any
    residual: Any
    inner_stiffness: Any
    galerkin: DeviceCsr
    exact: tuple


def two_grid(blocks: list[CoarseTemplate], kc, device) -> tuple[TwoGrid, list[CoarseTemplate]]:
    """The ``TwoGrid`` of the instances' templates ``blocks`` (block-diagonal stiffness ``kc``) and
    the templates solved exactly: each inner level, and a template without one itself (identity
    prolongation, whose exact solve the smoothing passes leave exact)."""
    import scipy.sparse as sp

    own = {id(b): CoarseTemplate(sp.identity(len(b.mass), format="csr"), b.stiffness, b.mass, b.order, b.band)
           for b in blocks if b.inner is None}
    exact = [b.inner if b.inner is not None else own[id(b)] for b in blocks]
    p2 = sp.block_diag([e.prolongation for e in exact], format="csr")
    off = (kc - sp.diags(kc.diagonal())).tocsr()
    off.eliminate_zeros()
    nc = kc.shape[0]
    kc2 = sp.block_diag([e.stiffness for e in exact], format="csr")
    nc2 = kc2.shape[0]
    cycle = TwoGrid(
        device_csr(p2, device), device_csr(p2.T.tocsr(), device), device_csr(off, device),
        # l1-Jacobi: the diagonal plus the off-diagonal's absolute row sum
        device_array(np.asarray(abs(off).sum(axis=1)).ravel().astype(np.float32), float, device),
        wp.zeros(nc, dtype=wp.vec3, device=device), wp.zeros(nc, dtype=wp.vec3, device=device),
        device_array(kc2.diagonal().astype(np.float32), float, device),
        device_csr(galerkin_slots(exact), device),
        (wp.zeros(nc2, dtype=wp.vec3, device=device), wp.zeros(nc2, dtype=float, device=device),
         wp.zeros(nc2, dtype=wp.vec3, device=device)))
    return cycle, exact


def model_templates(model, spacing: int, levels: int) -> list[CoarseTemplate]:
    """Each instance's ``CoarseTemplate`` of ``model`` (``operators.instance_templates``): the
    membrane proxy's modulus is each triangle's ``lambda + 2 mu`` [N/m]."""
    rest = model.particle_rest.numpy().astype(np.float64)
    mass = model.particle_mass.numpy().astype(np.float64)
    pinned = model.particle_flags.numpy() == PINNED
    modulus = model.tri_lam.numpy().astype(np.float64) + 2.0 * model.tri_mu.numpy().astype(np.float64)
    return instance_templates(rest, np.asarray(model.faces), mass, pinned, modulus,
                              np.asarray(model.instance_starts), spacing, levels)


def check_settings(spacing: int, levels: int, smoothing: int) -> None:
    if spacing < 0:
        raise ValueError(f"CoarseLevel: spacing must be >= 1 (0: automatic), got {spacing}")
    if levels not in (0, 2, 3):
        raise ValueError(f"CoarseLevel: levels must be 2, 3 or 0 (automatic), got {levels}")
    if smoothing < 1:
        raise ValueError(f"CoarseLevel: smoothing must be >= 1, got {smoothing}")


class CoarseLevel:
    """The coarse level of every instance of a ``ClothModel`` on its device (``sim.cloth.coarse``).

    Args:
        model: the cloth model.
        targets: the solver's inertial targets ``y`` (vec3 per particle), read by ``prepare``.
        contact_point, contact_normal, contact_active: the solver's body contact planes of the
            substep (point, normal, active flag per particle), read at each correction.
        k_contact: the body contact's penalty stiffness [N/m].
        contact_margin: the body contact's detection margin [m].
        air_damping: the solver's air damping [1/s].
        spacing: seed spacing of the aggregates [edges]; 3 gives about 15 vertices per coarse
            node on a near-uniform mesh; 0: per template, the least from ``AUTO_MIN_SPACING``
            that gives at most ``AUTO_MAX_NODES`` nodes (``auto_aggregate``) with ``levels`` 2,
            else ``AUTO_MIN_SPACING``.
        levels: 2, 3 or 0 (automatic; ``coarse_template``).
        smoothing: l1-Jacobi passes before and after the inner solve (three levels).

    Attributes:
        residual: the forces ``-dG/dx`` [N] per particle that a correction restricts (the solve
            kernel's evaluate variant writes them).
        prefactor: True with two levels: ``prepare`` forms the diagonal and factors the system at
            the substep start, and a correction only substitutes; three levels form the diagonal
            at each correction (their inner band is assembled per correction anyway).
    """

    def __init__(self, model, targets, contact_point, contact_normal, contact_active, *, k_contact: float,
                 contact_margin: float, air_damping: float, spacing: int = 0, levels: int = 0,
                 smoothing: int = 2):
        check_settings(spacing, levels, smoothing)
        self.model = model
        self._targets = targets
        self._contact = (contact_point, contact_normal, contact_active)
        self._k_contact = float(k_contact)
        self._contact_margin = float(contact_margin)
        self._air_damping = float(air_damping)
        self.smoothing = int(smoothing)
        blocks = model_templates(model, spacing, levels)
        self.templates = list({id(b): b for b in blocks}.values())
        # three levels where any template has an inner level
        self.levels = 3 if any(b.inner is not None for b in blocks) else 2
        self.prefactor = self.levels == 2
        self._build_transfer(blocks)
        self._build_solve(blocks)
        self._build_block_kernels()

    def _build_transfer(self, blocks: list[CoarseTemplate]) -> None:
        """The prolongation and restriction, the coarse nodes' mass and stiffness diagonal, and the
        coarse system's right-hand side, diagonal and solution."""
        import scipy.sparse as sp

        d = self.model.device
        p = sp.block_diag([b.prolongation for b in blocks], format="csr")
        self.prolongation = p
        self._kc = sp.block_diag([b.stiffness for b in blocks], format="csr")
        mc = np.concatenate([b.mass for b in blocks])
        nc = self.node_count = len(mc)
        self._p, self._r = device_csr(p, d), device_csr(p.T.tocsr(), d)
        self.node_mass = device_array(mc.astype(np.float32), float, d)
        self.node_stiffness = device_array(self._kc.diagonal().astype(np.float32), float, d)
        self.rhs = wp.zeros(nc, dtype=wp.vec3, device=d)
        self.diag = wp.zeros(nc, dtype=float, device=d)
        self.dx = wp.zeros(nc, dtype=wp.vec3, device=d)
        self._rhs_part = wp.zeros(nc * RESTRICT_LANES, dtype=wp.vec3, device=d)
        self._k_part = wp.zeros(nc * RESTRICT_LANES, dtype=float, device=d)
        self._no_flags = wp.zeros(0, dtype=wp.int32, device=d)  # ``restrict``: the pairs of ``sc_data``
        self.residual = wp.zeros(self.model.particle_count, dtype=wp.vec3, device=d)
        # CUDA: a node's lanes summed by shuffles in the restriction's own launch
        # (``restrict_lanes_kernel``); the CPU adds them in a second launch
        self.restrict_lanes = wp.get_device(d).is_cuda

    def _build_solve(self, blocks: list[CoarseTemplate]) -> None:
        """The exactly solved level's systems (``_exact``: right-hand side, diagonal, solution) and
        bands; with three levels the two-grid cycle around them."""
        d = self.model.device
        if self.levels == 3:
            self._cycle, exact = two_grid(blocks, self._kc, d)
            self._exact = self._cycle.exact
        else:
            self._cycle, exact = None, blocks
            self._exact = (self.rhs, self.diag, self.dx)
        self.exact_node_count = len(self._exact[0])
        self.bands = band_systems(exact, self.levels == 3, d)

    def _build_block_kernels(self) -> None:
        """CUDA: a thread block per instance (``block``) where the largest instance's band fits in
        one block's shared memory: two levels split the factor (``prepare``) from the
        substitutions (each correction), three solve whole at each correction."""
        self.solve_kernel = self.factor_kernel = self.substitute_kernel = None
        self.block_threads = block.threads(int(self.bands.widths.max()))
        device = wp.get_device(self.model.device)
        if not device.is_cuda:
            return
        need = max(block.shared_floats(int(c), int(b)) for c, b in
                   zip(self.bands.counts, self.bands.widths, strict=True))
        if 4 * block.padded(need) > device.max_shared_memory_per_block - 1024:
            return
        if self.prefactor:
            self.factor_kernel = block.block_kernel(need, "factor")
            self.substitute_kernel = block.block_kernel(need, "substitute")
        else:
            self.solve_kernel = block.block_kernel(need, "solve")

    def prepare(self, h: float, sc_data, pair_flags=None) -> None:
        """With two levels (``prefactor``): what every correction of a substep of length ``h``
        [s] shares, made from the substep's start: the coarse diagonal with the body contacts
        pressed at the inertial targets ``y`` (where the cloth goes if nothing holds it; the
        solver's substep-start contact planes) and ``sc_data``'s pairs (``restrict``), and on the
        block path each instance's factor (``factor``). It reads nothing a sweep writes, so the
        solver runs it beside the first sweeps (on a side stream on CUDA, or beside the
        self-contact detection with ``CoarseConfig.early``) and joins it before the first
        correction: the factorization, most of a correction's time, leaves the chain of dependent
        launches. Pressed at the substep-start positions instead, two corrections per substep throw
        cloth dropped on a sphere off it (docs/DECISIONS.md; the sphere test of
        ``tests/test_coarse_correction.py``). Three levels take the diagonal at each correction:
        from ``y`` their cycle lets that cloth come within 0.9 mm of the sphere.

        ``pair_flags`` (``CoarseConfig.early``): the self-contact stiffness at the particles
        flagged there (the pairs of the previous substep's end) instead of at those with pairs in
        ``sc_data``, so that ``prepare`` need not wait for this substep's detection."""
        if not self.prefactor:
            return
        self.restrict(h, self._targets, sc_data, RESTRICT_DIAGONAL, pair_flags)
        self.factor()

    def correct(self, h: float, x, snap_out, sc_data, instance_body) -> None:
        """Solve the coarse system of a substep of length ``h`` [s] (with ``prefactor`` its
        diagonal and factor from ``prepare``) for ``residual`` and add the prolongated
        displacement to ``x`` (free particles) and ``snap_out``, limited near ``sc_data``'s pairs
        (the sweeps' self-contact data) and the body (``transfer_kernels.prolong_kernel``);
        ``instance_body``: the control's body mesh of each instance (0: none)."""
        m = self.model
        parts = RESTRICT_RHS if self.prefactor else RESTRICT_RHS | RESTRICT_DIAGONAL
        self.restrict(h, x, sc_data, parts)
        self.solve()
        point, normal, active = self._contact
        wp.launch(prolong_kernel, dim=m.particle_count,
                  inputs=[self.dx, *self._p, point, normal, active, m.particle_flags, m.particle_instance,
                          m.instance_thickness, instance_body, self._contact_margin, sc_data],
                  outputs=[x, snap_out], device=m.device)

    def restrict(self, h: float, x, sc_data, parts: int = 3, pair_flags=None) -> None:
        """The coarse right-hand side ``P^T residual`` (``parts`` bit ``RESTRICT_RHS``) and
        diagonal ``m_c (1/h^2 + alpha/h) + K_c,JJ + P^T k`` (bit ``RESTRICT_DIAGONAL``; ``k``: body
        contact penalty at particles of ``x`` pressed onto the body by the solver's contacts,
        self-contact penalty at particles with pairs in ``sc_data``, or flagged in ``pair_flags``
        where given) of a substep of length ``h`` [s]; both in one pass by default."""
        m = self.model
        if pair_flags is None:
            pair_flags = self._no_flags
        point, normal, active = self._contact
        inertia = 1.0 / (h * h) + self._air_damping / h
        gather = [parts, self.residual, *self._r, x, m.particle_instance, point, normal, active,
                  m.instance_thickness, self._k_contact, sc_data, pair_flags]
        if self.restrict_lanes:
            if not wp.get_device(m.device).is_cuda:
                raise ValueError("CoarseLevel.restrict_lanes needs CUDA (lane shuffles; the CPU adds "
                                 "the lanes in a second launch)")
            threads = self.node_count * RESTRICT_LANES
            wp.launch(restrict_lanes_kernel, dim=threads,
                      inputs=[*gather, self.node_mass, self.node_stiffness, inertia, threads],
                      outputs=[self.rhs, self.diag], device=m.device)
            return
        wp.launch(restrict_kernel, dim=self.node_count * RESTRICT_LANES, inputs=gather,
                  outputs=[self._rhs_part, self._k_part], device=m.device)
        wp.launch(restrict_sum_kernel, dim=self.node_count,
                  inputs=[parts, self._rhs_part, self._k_part, self.node_mass, self.node_stiffness, inertia],
                  outputs=[self.rhs, self.diag], device=m.device)

    def factor(self) -> None:
        """On the split block path (CUDA, two levels, ``factor_kernel`` set): each instance's
        ``L D L^T`` of its coarse system with the current diagonal, for ``solve``. Elsewhere
        nothing: ``solve`` factors as it solves."""
        if self.factor_kernel is None:
            return
        m, b = self.model, self.bands
        wp.launch_tiled(self.factor_kernel, dim=[m.instance_count], block_dim=self.block_threads,
                        inputs=[self.diag, *b.inst, b.order, b.stiffness], outputs=[b.factor],
                        device=m.device)

    def solve(self) -> None:
        """Every instance's coarse system for the current right-hand side and diagonal: solved
        exactly with two levels (on the split block path with ``factor``'s factor, which must be
        current); with three, ``smoothing`` l1-Jacobi passes, the inner level's exact solve of the
        residual with the Galerkin operator ``P2^T A_c P2`` (its mass and contact part added to
        the inner band here, ``galerkin_band_kernel``), its prolongation, and as many passes again
        (a two-grid cycle, symmetric, so the correction stays a descent direction)."""
        if self.levels == 2:
            self.exact_solve()
            return
        cy, d, nc = self._cycle, self.model.device, self.node_count
        bufs = (self.dx, cy.x1)
        for j in range(2 * self.smoothing):
            if j == self.smoothing:
                self._inner_correction(bufs[j % 2])
            # pass j reads bufs[j % 2] and writes bufs[(j + 1) % 2]: the last lands in ``dx``
            wp.launch(level_pass_kernel, dim=nc,
                      inputs=[bufs[j % 2], self.rhs, self.diag, *cy.off, cy.l1,
                              PASS_FIRST if j == 0 else PASS_SMOOTH],
                      outputs=[bufs[(j + 1) % 2]], device=d)

    def _inner_correction(self, x_inout) -> None:
        """The cycle's coarse-grid step on the iterate ``x_inout``: its residual restricted to the
        inner level, the inner system (Galerkin diagonal and band) solved exactly, and the
        solution prolongated onto ``x_inout``."""
        cy, d, nc, b = self._cycle, self.model.device, self.node_count, self.bands
        wp.launch(level_pass_kernel, dim=nc,
                  inputs=[x_inout, self.rhs, self.diag, *cy.off, cy.l1, PASS_RESIDUAL],
                  outputs=[cy.residual], device=d)
        wp.launch(restrict_level_kernel, dim=self.exact_node_count,
                  inputs=[cy.residual, self.diag, self.node_stiffness, *cy.r2, cy.inner_stiffness],
                  outputs=[cy.exact[0], cy.exact[1]], device=d)
        wp.launch(galerkin_band_kernel, dim=b.values.shape[0],
                  inputs=[b.stiffness, self.diag, self.node_stiffness, *cy.galerkin],
                  outputs=[b.values], device=d)
        self.exact_solve()
        wp.launch(prolong_level_kernel, dim=nc, inputs=[cy.exact[2], *cy.p2], outputs=[x_inout], device=d)

    def exact_solve(self) -> None:
        """The exactly solved level's systems (``_exact``: right-hand side, diagonal, solution):
        the block kernels on CUDA where they fit, else one thread per instance."""
        m, b = self.model, self.bands
        rhs, diag, dx = self._exact
        if self.substitute_kernel is not None:
            wp.launch_tiled(self.substitute_kernel, dim=[m.instance_count],
                            block_dim=block.SUBSTITUTE_THREADS, inputs=[rhs, *b.inst, b.order, b.factor],
                            outputs=[dx], device=m.device)
        elif self.solve_kernel is not None:
            wp.launch_tiled(self.solve_kernel, dim=[m.instance_count], block_dim=self.block_threads,
                            inputs=[rhs, diag, *b.inst, b.order, b.values], outputs=[dx], device=m.device)
        else:
            wp.launch(band_solve_kernel, dim=m.instance_count,
                      inputs=[rhs, diag, *b.inst, b.order, b.values],
                      outputs=[b.factor, b.forward, dx], device=m.device)
