"""Sewing a pattern onto the rest body with the cloth solver (``sew_pattern``).

1. The flat mesh (``sim.garments.pattern_mesh``) is placed around the body: each panel on its
   cylinder (``Placement``); cylinders are developable, so the placed panels are unstretched
   and serve as the rest shape of this stage. Points that land inside the body are pushed out.
2. *Closing*: the seam vertices are pinned and their pins travel, over ``close_frames`` frames
   (smoothstep), from where they were placed to the mean of their seam group, weighted by
   their panels' ``Placement.hold`` (kept outside the body); the solver drags the rest of each
   panel along, with body contact and self-contact on and no gravity, as a virtual sewing
   machine pulls the seam lines together.
3. The seam groups are merged into one vertex each (the gaps are 0 by then), and the sewn
   garment, its rest shape now the flat pattern (``ClothModelBuilder.add_cloth``'s
   ``rest_corners``), *settles* for ``settle_frames`` frames under gravity on the body, pinned only along
   the edges labelled ``HELD`` (an elastic waistband grips the waist; everything else hangs).
   A garment that comes out of the settle with an edge through one of its own faces settles
   again from the sewn state at ``resettle_substeps``: a crossing at rest fails every sequence
   made with the garment (the self-intersection gate counts it from frame 0).

The merged mesh keeps the pattern's UV seams: each face keeps its panel's flat corners.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from sim.easing import smoothstep
from sim.garments.pattern import Pattern
from sim.garments.pattern_mesh import PatternMesh, mesh_pattern
from sim.profiling import phase

HELD = ("waistband",)
"""Edge labels whose vertices stay where sewing left them while the garment settles."""
PUSH_EPS = 0.002
"""Step [m] of the finite differences that give the body's outward normal from its distance."""


@dataclass(frozen=True)
class SewingConfig:
    """How a pattern is sewn.

    Attributes:
        close_frames: frames (at ``fps``) over which the seams are pulled closed.
        settle_frames: frames the sewn garment hangs under gravity afterwards.
        fps: frame rate of the sewing simulation [1/s].
        substeps, iterations: the solver's per frame (``VBDConfig.stepping``).
        clearance: gap [m] kept between a seam line and the body, on top of the cloth thickness.
        contact_offset: distance [m] the cloth keeps from the body on top of its thickness
            (``BodyContact.offset``).
        resettle_substeps: substeps of a second settle, from the sewn state, of the garments
            whose settle left an edge through a face of their own (at most ``substeps``: none);
            the second is kept unless it crosses itself more. Of the 9 designs x 6
            fabrics sewn coarse on the mean body, 5 cross at 8 substeps: the jersey t-shirt's
            sleeve underarm folds through itself (11 edges; none at 10 or 16), 3 hoodies and the
            jersey shorts; at 16 two still do (the leather hoodie 9 edges, the jersey shorts 6).
    """

    close_frames: int = 30
    settle_frames: int = 20
    fps: float = 30.0
    substeps: int = 8
    iterations: int = 5
    clearance: float = 0.004
    contact_offset: float = 0.003
    resettle_substeps: int = 16


@dataclass(frozen=True)
class SewnPattern:
    """A sewn garment mesh.

    Attributes:
        vertices: rest positions [m] on the body, (G, 3); faces: int32 (F, 3) into them.
        mesh: the unsewn pattern mesh (flat corners, panels, seam pairs; ``mesh.groups`` maps
            its vertices to ``vertices``).
        seam_gap: largest distance [m] between the two sides of a seam when they were merged.
    """

    vertices: np.ndarray
    faces: np.ndarray
    mesh: PatternMesh
    seam_gap: float


def push_outside(collider, x: np.ndarray, distance: float, rounds: int = 3) -> np.ndarray:
    """``x`` (N, 3) [m] with every point nearer than ``distance`` to the body (or inside it)
    moved along the body's outward normal until it is ``distance`` away."""
    x = np.array(x, np.float64)
    for _ in range(rounds):
        d = collider.signed_distance(x)
        near = d < distance
        if not near.any():
            break
        p = x[near]
        grad = np.zeros_like(p)
        for k in range(3):
            e = np.zeros(3)
            e[k] = PUSH_EPS
            grad[:, k] = (collider.signed_distance(p + e) - collider.signed_distance(p - e)) / (2 * PUSH_EPS)
        grad /= np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-9)
        x[near] = p + grad * (distance - d[near])[:, None]
    return x


@dataclass(frozen=True)
class SewingJob:
    """One pattern to sew (``sew_patterns``): its panels placed around the rest body
    ``body_vertices`` [m] (Vb, 3) / ``body_faces``, meshed at edge length ``h`` [m], of
    ``material`` (``Material`` or solver parameters)."""

    pattern: Pattern
    body_vertices: np.ndarray
    body_faces: np.ndarray
    h: float
    material: Any


def _solver(instances: list[dict], *, gravity: bool, cfg: SewingConfig, device: str):
    """A batched cloth model of ``instances`` (``add_cloth`` keyword arguments with ``vertices``,
    ``faces`` and ``material``) and its solver."""
    from sim.cloth import ClothModelBuilder, SolverVBD
    from sim.cloth.config import BodyContact, Stepping, VBDConfig

    builder = ClothModelBuilder(gravity=(0.0, -9.81 if gravity else 0.0, 0.0),
                                contact_offset=cfg.contact_offset)
    for ins in instances:
        builder.add_cloth(**ins)
    model = builder.finalize(device)
    vbd = VBDConfig(stepping=Stepping(substeps=cfg.substeps, iterations=cfg.iterations),
                    body_contact=BodyContact(offset=cfg.contact_offset))
    return model, SolverVBD(model, vbd)


def _run(model, solver, colliders: list, frames: int, fps: float, targets=None) -> list[np.ndarray]:
    """Step ``frames`` frames, instance k on body ``colliders[k]``; ``targets(t)`` (N, 3) gives
    the pins' positions (all instances') at frame t + 1. Returns each instance's positions."""
    from sim.device import warp

    wp = warp()
    control = model.control()
    for k, collider in enumerate(colliders):
        control.set_body(k, collider)
    state = model.state()
    for t in range(frames):
        if targets is not None:
            control.pin_targets.assign(wp.array(targets(t).astype(np.float32), dtype=wp.vec3,
                                                device=model.device))
        solver.step(state, state, control, 1.0 / fps)
    x = state.positions.numpy().astype(np.float64)
    return [x[model.instance_slice(k)] for k in range(len(colliders))]


def sew_pattern(pattern: Pattern, body_vertices: np.ndarray, body_faces: np.ndarray, h: float,
                material, *, config: SewingConfig | None = None, device: str | None = None) -> SewnPattern:
    """Mesh ``pattern`` at edge length ``h`` [m], sew it on the rest body and let it settle.

    Args:
        pattern: the sewing pattern, panels placed around the body.
        body_vertices: the rest body [m], (Vb, 3); body_faces: its triangles.
        h: target edge length [m].
        material: the cloth (``Material`` or solver parameters; its thickness is kept from the body).
        config: sewing settings.
        device: Warp device (None: cuda when present, else cpu).
    """
    job = SewingJob(pattern, body_vertices, body_faces, h, material)
    return sew_patterns([job], config=config, device=device)[0]


def sew_patterns(jobs: list[SewingJob], *, config: SewingConfig | None = None,
                 device: str | None = None) -> list[SewnPattern]:
    """``sew_pattern`` of several patterns at once: each stage one batched cloth model of all of
    them (instances never interact), each on its own body, so a batch of garments costs about
    the solver launches of one."""
    from sim.device import resolve_device

    if not jobs:
        return []
    cfg = config or SewingConfig()
    dev = resolve_device(device)
    colliders = _colliders(jobs, dev)
    with phase("mesh"):
        meshes = [mesh_pattern(j.pattern, j.h) for j in jobs]
    with phase("close"):
        closed = _close(jobs, meshes, colliders, cfg, dev)
    with phase("settle"):
        merged = [mesh.merge(x) for mesh, (x, _) in zip(meshes, closed, strict=True)]
        settled = _settle(jobs, meshes, merged, colliders, cfg, dev)
    return [SewnPattern(vertices=x.astype(np.float32), faces=mesh.sewn_faces(), mesh=mesh, seam_gap=gap)
            for x, mesh, (_, gap) in zip(settled, meshes, closed, strict=True)]


def _colliders(jobs: list[SewingJob], dev: str) -> list:
    """Each job's rest body as a collider, one per distinct body."""
    from sim.cloth import BodyCollider
    from sim.memo import content_key

    made: dict[str, Any] = {}
    out = []
    for j in jobs:
        body = np.ascontiguousarray(j.body_vertices, np.float32)
        faces = np.ascontiguousarray(j.body_faces, np.int32)
        key = content_key(body, faces)
        if key not in made:
            made[key] = BodyCollider(body, faces, device=dev)
            made[key].set_frame(body, body)
        out.append(made[key])
    return out


def _close(jobs: list[SewingJob], meshes: list[PatternMesh], colliders: list, cfg: SewingConfig,
           dev: str) -> list[tuple[np.ndarray, float]]:
    """The closing stage: per job, the positions of its (unsewn) mesh's vertices once the seams
    are pulled together, and the largest seam gap left."""
    from sim.cloth.model import as_cloth_params

    starts, seams, goals, instances = [], [], [], []
    for j, mesh, collider in zip(jobs, meshes, colliders, strict=True):
        keep = float(as_cloth_params(j.material).thickness) + cfg.clearance
        x0 = push_outside(collider, mesh.placed, keep)
        seam = np.zeros(len(x0), bool)
        seam[mesh.pairs.ravel()] = True
        hold = np.array([p.placement.hold for p in j.pattern.panels])[mesh.vertex_panel]
        goal = push_outside(collider, mesh.merge(x0, hold)[mesh.groups], keep)
        starts.append(x0)
        seams.append(seam)
        goals.append(goal)
        instances.append({"vertices": x0, "faces": mesh.triangles, "material": j.material,
                          "rest_vertices": mesh.placed, "pinned": seam})
    model, solver = _solver(instances, gravity=False, cfg=cfg, device=dev)
    x0_all, seam_all, goal_all = (np.concatenate(a) for a in (starts, seams, goals))

    def targets(t: int) -> np.ndarray:
        w = float(smoothstep(np.array((t + 1) / cfg.close_frames)))
        out = x0_all.copy()
        out[seam_all] = (1 - w) * x0_all[seam_all] + w * goal_all[seam_all]
        return out

    xs = _run(model, solver, colliders, cfg.close_frames, cfg.fps, targets)
    return [(x, float(np.linalg.norm(x[mesh.pairs[:, 0]] - x[mesh.pairs[:, 1]], axis=1).max(initial=0.0)))
            for x, mesh in zip(xs, meshes, strict=True)]


def _settle(jobs: list[SewingJob], meshes: list[PatternMesh], merged: list[np.ndarray], colliders: list,
            cfg: SewingConfig, dev: str) -> list[np.ndarray]:
    """Each sewn garment ``merged[k]`` (G, 3) after ``cfg.settle_frames`` frames under gravity
    with the flat pattern as its rest shape, pinned along the ``HELD`` edges; those left with a
    self-crossing edge settled again, together, at ``cfg.resettle_substeps`` (when that is more
    than ``cfg.substeps``), the second settle kept unless it crosses itself more."""
    if cfg.settle_frames == 0:
        return merged
    settled = _settle_batch(jobs, meshes, merged, colliders, cfg, dev)
    if cfg.resettle_substeps <= cfg.substeps:
        return settled
    from sim.quality import crossing_edges

    def crossings(x: np.ndarray, mesh: PatternMesh) -> int:
        return int(crossing_edges(x, mesh.sewn_faces(), device=dev).sum())

    first = [crossings(x, mesh) for x, mesh in zip(settled, meshes, strict=True)]
    again = [k for k, n in enumerate(first) if n]
    if again:
        redo = _settle_batch([jobs[k] for k in again], [meshes[k] for k in again], [merged[k] for k in again],
                             [colliders[k] for k in again], replace(cfg, substeps=cfg.resettle_substeps), dev)
        for k, x in zip(again, redo, strict=True):
            if crossings(x, meshes[k]) <= first[k]:
                settled[k] = x
    return settled


def _settle_batch(jobs: list[SewingJob], meshes: list[PatternMesh], merged: list[np.ndarray], colliders: list,
                  cfg: SewingConfig, dev: str) -> list[np.ndarray]:
    """One batched settle of ``merged`` (``_settle``)."""
    instances = []
    for j, mesh, x in zip(jobs, meshes, merged, strict=True):
        held = np.zeros(len(x), bool)
        for ref in (r for label in HELD for r in j.pattern.labelled(label)):
            held[mesh.groups[mesh.edge_vertices[ref]]] = True
        instances.append({"vertices": x, "faces": mesh.sewn_faces(), "material": j.material,
                          "rest_vertices": x, "pinned": held, "rest_corners": mesh.flat[mesh.triangles],
                          "face_panels": mesh.face_panel})
    model, solver = _solver(instances, gravity=True, cfg=cfg, device=dev)
    return _run(model, solver, colliders, cfg.settle_frames, cfg.fps)
