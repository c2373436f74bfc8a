"""The sequence driver: ``simulate`` one job or ``simulate_batch`` several in one batched cloth
model, frame by frame, screening every frame and judging every sequence.

Per frame the host copies two body frames device-to-device into each collider and the
reference velocity into the control, launches the step (replayed from a CUDA graph on CUDA,
plain launches on the CPU) and reads the positions back for the screening and the output.
Nothing runs on the host per substep.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.types import Garment
from sim.geometry.points import frame_centroids
from sim.profiling import PHASES, phase
from sim.quality import SimulationError
from sim.simulate.config import SimulationConfig
from sim.simulate.jobs import SimulationJob, Track
from sim.simulate.prelude import prepare_track
from sim.simulate.results import SimulationResult, finish_track
from sim.simulate.screening import BatchScreen, FrameChecker, phase_label
from sim.types import Motion

ProgressFn = Callable[[int, int], None]


def body_mean_velocities(vertices: np.ndarray, steps: int, fps: float) -> np.ndarray:
    """The mean velocity [m/s] of a body's vertices over each solver step, shape (steps, 3):
    step ``t`` moves the body from frame ``min(t, L - 1)`` to ``min(t + 1, L - 1)`` of its ``L``
    frames ``vertices`` (L, B, 3) [m] (a shorter sequence holds its last frame). The body
    moves linearly within a step, so this is the velocity of its centroid over the step."""
    c = frame_centroids(vertices)
    t = np.arange(steps)
    last = len(c) - 1
    return ((c[np.minimum(t + 1, last)] - c[np.minimum(t, last)]) * fps).astype(np.float32)


def reference_velocities(tracks: list[Track], steps: int, fps: float) -> np.ndarray:
    """Each instance's reference velocity per step (self-contact searches in its frame): the mean
    velocity of its body (``body_mean_velocities``), float32 (steps, I, 3) [m/s]."""
    means: dict[tuple, np.ndarray] = {}
    reference = np.zeros((steps, len(tracks), 3), np.float32)
    for k, tr in enumerate(tracks):
        if tr.body_key not in means:
            means[tr.body_key] = body_mean_velocities(tr.frames.vertices, steps, fps)
        reference[:, k] = means[tr.body_key]
    return reference


def _build_model(tracks: list[Track], vbd, device: str):
    """The batched cloth model of the tracks' garments, placed on their bodies, and the binding of
    each garment's pinned vertices to its body's surface."""
    from sim.cloth import ClothModelBuilder
    from sim.cloth.topology import mesh_topologies
    from sim.dressing import bind_to_surface, place_garment

    builder = ClothModelBuilder(max_colors=vbd.layout.max_colors, contact_offset=vbd.body_contact.offset)
    with phase("topology"):  # the new garments' colourings side by side (sim.cloth.topology)
        topologies = mesh_topologies([(tr.job.garment.num_vertices, tr.job.garment.faces) for tr in tracks],
                                     vbd.layout.max_colors)
    bindings = []
    for tr, topology in zip(tracks, topologies, strict=True):
        g = tr.job.garment
        x0 = place_garment(g.rest_vertices, tr.placement)
        builder.add_cloth(x0, g.faces, g.material, pinned=tr.pinned, rest_vertices=g.rest_vertices,
                          face_layers=g.face_layers, rest_corners=g.flat_corners(), face_panels=g.panel_ids,
                          topology=topology)
        try:
            bindings.append(bind_to_surface(x0, tr.frames.vertices[0], tr.job.body.faces, vertices=tr.pinned,
                                            device=device))
        except ValueError as e:
            raise WrinklesInputError(f"{tr.job.label}: {e}") from None
    return builder.finalize(device), bindings


def _attach_bodies(model, control, tracks: list[Track], bindings: list, device: str):
    """One body collider per shared body (``Track.body_key``) with its frames on the device, set
    as each instance's body, and each instance's attachment pins. Returns ``(colliders, pins)``,
    colliders keyed by body: ``(collider, frames (T, V_body) Warp vec3, T)``."""
    from sim.cloth import BodyCollider
    from sim.device import warp
    from sim.dressing import AttachmentPins

    wp = warp()
    colliders: dict[tuple, tuple[Any, Any, int]] = {}
    pins = []
    for k, (tr, binding) in enumerate(zip(tracks, bindings, strict=True)):
        tr.span = model.instance_slice(k)
        key = tr.body_key
        if key not in colliders:
            c = BodyCollider(tr.frames.vertices[0], tr.job.body.faces, device=device)
            seq = wp.array(np.ascontiguousarray(tr.frames.vertices), dtype=wp.vec3, device=device)
            colliders[key] = (c, seq, tr.length)
        tr.collider, tr.body_points, _ = colliders[key]
        control.set_body(k, tr.collider)
        pins.append(AttachmentPins(binding, tr.span.start, tr.collider.points_end, device=device))
    return colliders, pins


def freeze_instance(model, state, control, span: slice, x: np.ndarray) -> None:
    """Stop one instance of a batched model where it is: its positions become ``x[span]`` (the
    rest of ``x`` is the live state), its particles pinned to them with zero velocity; its
    attachment particles keep following the body (their pins are rewritten every step), which
    nothing reads. Only array contents change, so a captured CUDA graph stays valid."""
    from sim.cloth.vbd_kernels import PINNED

    state.positions.assign(x)
    for a in (state.velocities, state.accelerations):
        z = a.numpy().copy()
        z[span] = 0.0
        a.assign(z)
    flags = model.particle_flags.numpy().copy()
    flags[span] = PINNED
    model.particle_flags.assign(flags)
    targets = control.pin_targets.numpy().copy()
    targets[span] = x[span]
    control.pin_targets.assign(targets)


class _Batch:
    """The tracks of one ``simulate_batch`` call in one cloth model on ``device``, stepped frame by
    frame (``run``)."""

    def __init__(self, tracks: list[Track], cfg: SimulationConfig, vbd, device: str):
        from sim.cloth import SolverVBD
        from sim.device import warp

        self.wp = warp()
        self.tracks, self.cfg, self.device = tracks, cfg, device
        with phase("cloth"):
            self.model, bindings = _build_model(tracks, vbd, device)
        self.control = self.model.control()
        with phase("bodies"):
            self.colliders, self.pins = _attach_bodies(self.model, self.control, tracks, bindings, device)
        with phase("solver"):
            self.solver = SolverVBD(self.model, vbd)
        self.state = self.model.state()
        self.dt = 1.0 / cfg.fps
        with phase("screen"):
            self.checkers = [FrameChecker(tr.job.garment, cfg) for tr in tracks]
            self.screen = BatchScreen(self.model, self.checkers, cfg)
        self.graph = None
        self.use_graph = self.wp.get_device(device).is_cuda
        self.total = max(tr.length for tr in tracks) - 1
        reference = reference_velocities(tracks, max(self.total, 1), cfg.fps)
        self.reference = self.wp.array(reference, dtype=self.wp.vec3, device=device)

    def _step(self) -> None:
        for p in self.pins:
            p.launch(self.control.pin_targets)
        self.solver.step(self.state, self.state, self.control, self.dt)

    def advance(self, t: int) -> float:
        """Solver step ``t``: the bodies move from frame ``t`` to ``t + 1`` (a shorter sequence
        holds its last). Returns its wall time [ms], launch to device synchronisation."""
        wp = self.wp
        for c, seq, length in self.colliders.values():
            c.set_frame(seq[min(t, length - 1)], seq[min(t + 1, length - 1)])
        wp.copy(self.control.instance_velocity, self.reference[t])
        if self.use_graph and self.graph is None:
            try:
                with wp.ScopedCapture(device=self.device) as cap:
                    self._step()
                self.graph = cap.graph
            except Exception:  # capture unsupported here (driver, mempool): plain launches
                self.use_graph = False
        t_start = time.perf_counter()
        if self.graph is not None:
            wp.capture_launch(self.graph)
        else:
            self._step()
        wp.synchronize_device(self.device)
        return 1000.0 * (time.perf_counter() - t_start)

    def check(self, frame: int, x: np.ndarray, x_prev: np.ndarray, failures: str,
              errors: dict[int, SimulationError]) -> None:
        """Screen timeline ``frame`` (positions ``x``, the frame before ``x_prev``); an instance that
        fails raises (``failures="raise"``) or is frozen at ``x_prev`` with its error in ``errors``."""
        tracks = self.tracks
        roots = np.stack([tr.frames.joints[min(frame, tr.length - 1), 0] for tr in tracks])
        flagged = self.screen(self.state.positions, roots)
        for k, (tr, check) in enumerate(zip(tracks, self.checkers, strict=True)):
            if frame >= tr.length or not flagged[k] or k in errors:
                continue
            label = phase_label(tr, frame, tr.n_settle + tr.n_blend, len(tracks) > 1)
            try:
                check(x[tr.span], x_prev[tr.span], roots[k], frame - tr.first_out, label)
            except SimulationError as e:
                if failures == "raise":
                    raise
                errors[k] = e
                x[tr.span] = x_prev[tr.span]
                freeze_instance(self.model, self.state, self.control, tr.span, x)

    def run(self, progress: ProgressFn | None,
            failures: str) -> tuple[np.ndarray, dict[int, SimulationError]]:
        """Every solver step of the batch, each frame screened and written to the tracks'
        outputs. Returns the wall time [ms] of each step and the errors of the frozen instances."""
        tracks = self.tracks
        x_prev = self.state.positions.numpy().copy()  # on CPU .numpy() is a view of the live buffer
        step_ms = np.zeros(self.total)
        errors: dict[int, SimulationError] = {}  # failures="return": frozen instances
        for t in range(self.total):
            self.screen.remember(self.state.positions)
            step_ms[t] = self.advance(t)
            if self.cfg.settle_relax and t + 1 <= tracks[0].n_settle:
                self.state.velocities.zero_()
            frame = t + 1
            x = self.state.positions.numpy().copy()
            self.check(frame, x, x_prev, failures, errors)
            for k, tr in enumerate(tracks):
                if frame < tr.length and frame >= tr.first_out and k not in errors:
                    tr.out[frame - tr.first_out] = x[tr.span]
            x_prev = x
            if progress is not None:
                progress(t + 1, self.total)
            if len(errors) == len(tracks):
                break
        return step_ms, errors


def simulate(garment: Garment, body, motion: Motion, *, betas: np.ndarray | None = None,
             config: SimulationConfig | None = None, solver=None, seed: int = 0,
             progress: ProgressFn | None = None, garment_betas: np.ndarray | None = None) -> SimulationResult:
    """Dress ``garment`` on ``body``, play ``motion``, and judge the result.

    Args:
        garment: the garment at rest around the body's rest mesh (shape ``garment_betas``).
        body: a ``sim.bodies.BodyModel``.
        motion: the motion.
        betas: body shape (B,); None: the motion's own, else the mean shape.
        config: settings (default ``SimulationConfig()``).
        solver: a ``VBDConfig`` used instead of ``config.vbd_config()``.
        seed: recorded in the provenance (the simulation itself is deterministic).
        progress: ``progress(frames_done, frames_total)`` over solver frames.
        garment_betas: the shape (B,) the garment was built on; None: ``betas``. When it
            differs, the body morphs from it to ``betas`` during the settle
            (``SimulationJob.garment_betas``).

    Returns:
        The sequence (vertices (T, V, 3) [m], T = the motion's frames, or prelude + motion
        with ``keep_prelude``) and its quality report.

    Raises:
        SimulationError: NaN or explosion; names the output frame (negative inside a dropped
            prelude) and the cause.
        WrinklesInputError: bad config.
    """
    job = SimulationJob(garment, body, motion, betas, garment_betas=garment_betas)
    return simulate_batch([job], config=config, solver=solver, seed=seed, progress=progress)[0]


def simulate_batch(jobs: Sequence[SimulationJob], *, config: SimulationConfig | None = None, solver=None,
                   seed: int = 0, progress: ProgressFn | None = None,
                   failures: str = "raise") -> list[SimulationResult | SimulationError]:
    """Simulate several sequences in one batched cloth model (see ``simulate``).

    Sequences may differ in garment, body, shape and motion length; a shorter one holds its
    body's last frame until the longest ends (its output stops at its own end). Jobs with the
    same body model, motion object and betas (and garment betas) share one body collider.

    Args:
        failures: "raise": the first sequence that blows up raises. "return": a sequence that
            blows up is frozen at its last good frame (its particles pinned in place, but for
            attachments, which keep following the body; instances of a batch never interact)
            and its slot of the result holds the ``SimulationError``; the others run on
            unchanged, so one bad sequence costs a batch nothing.

    Raises:
        SimulationError: with ``failures="raise"``, the first sequence that blows up, named in
            the cause.
    """
    if failures not in ("raise", "return"):
        raise ValueError(f"simulate_batch: failures must be 'raise' or 'return', got {failures!r}")
    from sim.device import resolve_device, warp

    if not jobs:
        raise ValueError("simulate_batch: no jobs")
    wp = warp()
    cfg = config or SimulationConfig()
    device = resolve_device(cfg.device)
    vbd = solver if solver is not None else cfg.vbd_config(max(j.garment.num_vertices for j in jobs),
                                                           cuda=wp.get_device(device).is_cuda)
    skinned: dict = {}
    with phase("prelude"):
        tracks = [prepare_track(j, cfg, device, skinned) for j in jobs]
    with phase("model"):
        batch = _Batch(tracks, cfg, vbd, device)
    with phase("steps"):
        step_ms, errors = batch.run(progress, failures)
        # the solver's launch-to-synchronisation time; the rest of "steps" is the host's per frame
        PHASES.add("solver", float(step_ms.sum()) / 1000.0, len(step_ms))
    graph = batch.graph is not None
    with phase("results"):
        return [errors[k] if k in errors else finish_track(tr, cfg, vbd, device, seed, graph, step_ms)
                for k, tr in enumerate(tracks)]
