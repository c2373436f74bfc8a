"""Per-step cloth data: ``ClothState`` (positions, velocities), ``ClothControl`` (inputs of a
step: pin targets, body meshes) and ``BodyCollider`` (one moving body mesh as a ``wp.Mesh``).

A body moves linearly from ``points_start`` to ``points_end`` over one ``Solver.step``; the
solver places it at each substep's end and refits its BVH (substep-safe contact, see
``sim.cloth.solver_vbd``). Uploading a new frame (``set_frame``) happens outside ``step``, so
the step itself can be captured in a CUDA graph.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from sim.device import warp

if TYPE_CHECKING:  # pragma: no cover
    from sim.cloth.model import ClothModel


class ClothState:
    """Per-particle ``wp.array(dtype=vec3)`` (N,): positions [m], velocities [m/s], and the
    last substep's accelerations [m/s^2] (the VBD solver's initial guess uses them; a new
    state starts with gravity, i.e. "falling")."""

    def __init__(self, positions: Any, velocities: Any, accelerations: Any):
        self.positions = positions
        self.velocities = velocities
        self.accelerations = accelerations

    @classmethod
    def from_model(cls, model: ClothModel) -> ClothState:
        w = warp()
        acc = np.tile(np.asarray(model.gravity, dtype=np.float32), (model.particle_count, 1))
        return cls(w.clone(model.particle_q), w.zeros_like(model.particle_q),
                   w.array(acc, dtype=w.vec3, device=model.device))

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) as float32 (N, 3) host arrays."""
        return self.positions.numpy(), self.velocities.numpy()


@wp.kernel
def _lerp_body_kernel(
    start: wp.array(dtype=wp.vec3),
    end: wp.array(dtype=wp.vec3),
    alpha: float,
    inv_dt: float,
    points_out: wp.array(dtype=wp.vec3),
    velocities_out: wp.array(dtype=wp.vec3),
):
    """Body vertex at fraction ``alpha`` of the step; constant velocity over the step."""
    i = wp.tid()
    a = start[i]
    b = end[i]
    points_out[i] = a + alpha * (b - a)
    velocities_out[i] = (b - a) * inv_dt


@wp.kernel
def _signed_distance_kernel(
    mesh: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    max_dist: float,
    dist_out: wp.array(dtype=float),
):
    i = wp.tid()
    q = wp.mesh_query_point_sign_normal(mesh, x[i], max_dist)
    if q.result:
        p = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        dist_out[i] = q.sign * wp.length(x[i] - p)
    else:
        dist_out[i] = max_dist


class BodyCollider:
    """A (closed, outward-oriented) body mesh that moves over a step.

    Args:
        points: body vertex positions [m], (B, 3), at the start of the first step.
        faces: int (G, 3), outward-facing (counter-clockwise seen from outside).
        device: Warp device.
    """

    def __init__(self, points: np.ndarray, faces: np.ndarray, *, device: str):
        w = warp()
        p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        f = np.asarray(faces, dtype=np.int32).reshape(-1, 3)
        if len(f) == 0 or f.min() < 0 or f.max() >= len(p):
            raise ValueError(f"body mesh: faces must index 0..{len(p) - 1} (got {len(f)} faces)")
        self.device = device
        self.points_start = w.array(p, dtype=w.vec3, device=device)
        self.points_end = w.array(p, dtype=w.vec3, device=device)
        self.points = w.array(p, dtype=w.vec3, device=device)
        self.velocities = w.zeros_like(self.points)
        self.indices = w.array(f.reshape(-1), dtype=w.int32, device=device)
        # a top-down SAH tree (built on the host, refit on the device each substep): its
        # closest-point queries run 25-30 % faster on an H100 than the default CUDA LBVH's (the
        # body's upper half at walk and run frames, docs/BENCHMARKS.md)
        self.mesh = w.Mesh(points=self.points, indices=self.indices, velocities=self.velocities,
                           bvh_constructor="sah")

    @property
    def id(self) -> int:
        return int(self.mesh.id)

    def set_frame(self, start: np.ndarray | Any, end: np.ndarray | Any) -> None:
        """Body positions [m] at the start and end of the next step ((B, 3) numpy or Warp)."""
        for dst, src in ((self.points_start, start), (self.points_end, end)):
            if isinstance(src, np.ndarray):
                dst.assign(np.asarray(src, dtype=np.float32).reshape(-1, 3))
            else:
                warp().copy(dst, src)

    def place(self, alpha: float, dt: float) -> None:
        """Move the mesh to fraction ``alpha`` of a step of length ``dt`` [s] and refit its BVH."""
        w = warp()
        w.launch(_lerp_body_kernel, dim=self.points.shape[0],
                 inputs=[self.points_start, self.points_end, float(alpha), 1.0 / dt],
                 outputs=[self.points, self.velocities], device=self.device)
        self.mesh.refit()

    def signed_distance(self, x: np.ndarray | Any, *, max_dist: float = 1.0) -> np.ndarray:
        """Signed distance [m] of points to the mesh at its current placement (< 0 inside).

        Points farther than ``max_dist`` report ``max_dist``.
        """
        w = warp()
        xa = x if not isinstance(x, np.ndarray) else w.array(x.astype(np.float32), dtype=w.vec3,
                                                               device=self.device)
        out = w.zeros(xa.shape[0], dtype=float, device=self.device)
        w.launch(_signed_distance_kernel, dim=xa.shape[0], inputs=[self.mesh.id, xa, float(max_dist)],
                 outputs=[out], device=self.device)
        return out.numpy()


class ClothControl:
    """Inputs of one step.

    Attributes:
        pin_targets: positions [m] pinned particles reach at the end of the step, vec3 (N,);
            entries of free particles are ignored.
        bodies: colliders in use; ``instance_body`` (uint64 (I,)) holds the mesh id each
            instance collides with (0: none). Several instances may share one body.
        instance_velocity: reference velocity [m/s] of each instance over the step, vec3 (I,):
            self-contact detection measures speeds relative to it, so a garment carried along
            by its body (a run covers 3.5 m/s) is searched as if it stood still, as Galilean
            invariance allows (cloth-cloth contact depends on relative motion only). Its only
            effect is on the cost of the search. Zeros (the default): absolute speeds.
            ``sim.simulate`` sets it per step to the mean velocity of the instance's body.
    """

    def __init__(self, pin_targets: Any, instance_count: int, device: str):
        w = warp()
        self.pin_targets = pin_targets
        self.device = device
        self.bodies: list[BodyCollider] = []
        self._instance_body = np.zeros(instance_count, dtype=np.uint64)
        self.instance_body = w.array(self._instance_body, dtype=w.uint64, device=device)
        self.instance_velocity = w.zeros(instance_count, dtype=w.vec3, device=device)

    @classmethod
    def from_model(cls, model: ClothModel) -> ClothControl:
        return cls(warp().clone(model.particle_q), model.instance_count, model.device)

    def set_body(self, instance: int, body: BodyCollider | None) -> None:
        """Let ``instance`` collide with ``body`` (None: no body). Host upload; not per step."""
        if body is not None and body not in self.bodies:
            self.bodies.append(body)
        self._instance_body[instance] = 0 if body is None else body.id
        self.instance_body.assign(self._instance_body)
        used = set(int(i) for i in self._instance_body)
        self.bodies = [b for b in self.bodies if b.id in used]
