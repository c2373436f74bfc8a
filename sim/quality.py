"""Quality gates for simulated garment sequences.

Computed for every simulated sequence and stored with it: edge strain (max, mean), the fraction
of garment vertices inside the body, self-intersections, and non-finite values. ``check_frame``
is the in-simulation guard: it stops a run with a ``SimulationError`` naming the frame and the
cause (NaN, explosion).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sim.device import resolve_device, warp
from sim.memo import LRU, content_key, read_only


class SimulationError(RuntimeError):
    """A simulation blew up; the message names the frame and the cause."""

    def __init__(self, frame: int, cause: str):
        self.frame = int(frame)
        self.cause = cause
        # a negative frame is in the prelude (the settle and the blend from rest), before the
        # motion's first output frame
        where = (f"at frame {self.frame}" if self.frame >= 0 else
                 f"{-self.frame} frame{'s' if self.frame < -1 else ''} before the motion's first frame")
        super().__init__(f"simulation failed {where}: {cause}")


@dataclass(frozen=True)
class QualityGates:
    """Thresholds a sequence must meet.

    Attributes:
        max_edge_strain: largest |l/l0 - 1| allowed on any edge in any frame [-]. Compression
            counts like stretch: cloth is nearly inextensible in both directions, and it
            buckles out of plane instead of shortening. An edge at less than 65 % of its rest
            length means a fold narrower than the mesh can hold, so the triangles crumpled
            (StVK-style collapse) instead of wrinkling. The report keeps ``max_stretch`` and
            ``max_compression`` apart, so it shows which one failed.
        max_inside_fraction: largest fraction of garment vertices inside the body in any frame.
        max_self_intersections: largest number of edge-face crossings in any frame.
    """

    max_edge_strain: float = 0.35
    max_inside_fraction: float = 0.01
    max_self_intersections: int = 0


@dataclass(frozen=True)
class QualityReport:
    """Quality statistics of a garment sequence (T frames).

    Attributes:
        max_edge_strain: max over edges and frames of |l/l0 - 1|.
        mean_edge_strain: mean over edges and frames of |l/l0 - 1|.
        max_stretch / max_compression: max of (l/l0 - 1) and of (1 - l/l0).
        inside_fraction: per frame, fraction of garment vertices inside the body, shape (T,).
        self_intersections: per frame, number of edge-face crossings, shape (T,).
        finite: every position finite.
    """

    max_edge_strain: float
    mean_edge_strain: float
    max_stretch: float
    max_compression: float
    inside_fraction: np.ndarray
    self_intersections: np.ndarray
    finite: bool

    def failures(self, gates: QualityGates) -> list[str]:
        """Human-readable reasons this sequence fails ``gates`` (empty when it passes)."""
        out = []
        if not self.finite:
            out.append("non-finite vertex positions")
        if self.max_edge_strain > gates.max_edge_strain:
            out.append(f"max edge strain {self.max_edge_strain:.3f} > {gates.max_edge_strain}")
        worst = float(self.inside_fraction.max()) if self.inside_fraction.size else 0.0
        if worst > gates.max_inside_fraction:
            f = int(np.argmax(self.inside_fraction))
            out.append(f"{100 * worst:.2f}% of vertices inside the body at frame {f} "
                       f"(gate {100 * gates.max_inside_fraction:.2f}%)")
        si = int(self.self_intersections.max()) if self.self_intersections.size else 0
        if si > gates.max_self_intersections:
            f = int(np.argmax(self.self_intersections))
            out.append(f"{si} self-intersection crossings at frame {f} "
                       f"(gate {gates.max_self_intersections})")
        return out

    def to_json(self) -> dict:
        """JSON-ready summary (per-frame arrays as lists)."""
        d = asdict(self)
        d["inside_fraction"] = [float(v) for v in self.inside_fraction]
        d["self_intersections"] = [int(v) for v in self.self_intersections]
        inside, si = self.inside_fraction, self.self_intersections
        d["max_inside_fraction"] = float(inside.max()) if inside.size else 0.0
        d["max_self_intersections"] = int(si.max()) if si.size else 0
        return d


def unique_edges(faces: np.ndarray, *, counts: bool = False):
    """Undirected edges of a triangle mesh, shape (E, 2), int32, each once (i < j); with
    ``counts``, also how many faces use each edge, int (E,) (1 on an open border)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e.sort(axis=1)
    # one int64 key per edge sorts as the (i, j) rows do, and a 1-D unique is ~10x a row unique
    n = int(e.max(initial=-1)) + 1
    keys = np.unique(e[:, 0] * n + e[:, 1], return_counts=counts)
    uniq, uses = keys if counts else (keys, None)
    out = np.stack([uniq // max(n, 1), uniq % max(n, 1)], axis=1).astype(np.int32).reshape(-1, 2)
    return (out, uses) if counts else out


_EDGES = LRU(16)


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """``unique_edges(faces)``, made once per mesh (read-only, shared): a batch evaluates every
    sequence of a garment mesh on the same edges, and a 36k-face mesh's edges take ~10 ms."""
    f = np.asarray(faces)
    return _EDGES.get_or_make(content_key(f), lambda: read_only(unique_edges(f)))


def edge_strain(vertices: np.ndarray, rest_vertices: np.ndarray, faces: np.ndarray, *,
                device: str | None = None, rest_lengths: np.ndarray | None = None) -> np.ndarray:
    """Engineering strain l/l0 - 1 of every edge in every frame.

    Args:
        vertices: positions [m], shape (T, V, 3).
        rest_vertices: rest positions [m], shape (V, 3).
        faces: (F, 3) int.
        rest_lengths: the edges' rest lengths l0 [m] (E,), in :func:`unique_edges` order, where
            the rest shape is not ``rest_vertices`` (a sewn garment's flat pattern:
            ``Garment.rest_edge_lengths``).

    Returns:
        (T, E) float32, edges as in :func:`unique_edges`.
    """
    wp = warp()
    from sim import quality_kernels as K

    d = resolve_device(device)
    edges = mesh_edges(faces)
    rest = (np.linalg.norm(rest_vertices[edges[:, 1]] - rest_vertices[edges[:, 0]], axis=1)
            if rest_lengths is None else np.asarray(rest_lengths, np.float64))
    x = wp.array(np.ascontiguousarray(vertices, np.float32), dtype=wp.vec3, device=d)
    out = wp.empty((vertices.shape[0], edges.shape[0]), dtype=float, device=d)
    wp.launch(K.edge_strain_kernel, dim=out.shape,
              inputs=[x, wp.array(edges, dtype=int, device=d),
                      wp.array(np.maximum(rest, 1e-12).astype(np.float32), dtype=float, device=d)],
              outputs=[out], device=d)
    return out.numpy()


def _body_meshes(body_vertices: np.ndarray, body_faces: np.ndarray, T: int, device: str):
    """``(t, wp.Mesh)`` for each of ``T`` frames of a body (T, Vb, 3) or static body (Vb, 3): one
    mesh, refit per frame to the frame copied on the device (``_frames_on``'s blocks)."""
    wp = warp()
    bv = np.asarray(body_vertices)
    if bv.ndim == 3 and bv.shape[0] != T:
        raise ValueError(f"{T} garment frames but {bv.shape[0]} body frames")
    pts = wp.array(np.ascontiguousarray(bv if bv.ndim == 2 else bv[0], np.float32), dtype=wp.vec3,
                   device=device)
    mesh = wp.Mesh(points=pts, indices=wp.array(np.asarray(body_faces, np.int32).ravel(), dtype=wp.int32,
                                                device=device))
    if bv.ndim == 2:
        for t in range(T):
            yield t, mesh
        return
    for t, (_, x, _) in enumerate(_frames_on(bv, device)):
        if t > 0:
            wp.copy(pts, x)
            mesh.refit()
        yield t, mesh


def inside_fraction(points: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray, *,
                    device: str | None = None, max_dist: float = 10.0) -> np.ndarray:
    """Per frame, the fraction of ``points`` inside the closed body mesh.

    Args:
        points: garment positions [m], shape (T, V, 3).
        body_vertices: body positions [m], shape (T, Vb, 3) (or (Vb, 3) for a static body).
        body_faces: (Fb, 3) int, outward wound.

    Returns:
        (T,) float.
    """
    wp = warp()
    from sim import quality_kernels as K

    d = resolve_device(device)
    T, V = points.shape[:2]
    inside = wp.empty((min(T, FRAME_CHUNK), V), dtype=int, device=d)
    out = np.empty(T)
    meshes = _body_meshes(body_vertices, body_faces, T, d)
    for (t, mesh), (k, x, last) in zip(meshes, _frames_on(points, d), strict=True):
        wp.launch(K.inside_mesh_kernel, dim=V, inputs=[mesh.id, x, float(max_dist)], outputs=[inside[k]],
                  device=d)
        if last:
            out[t - k:t + 1] = inside.numpy()[:k + 1].mean(axis=1)
    return out


FRAME_CHUNK = 64
"""Frames a quality test moves to and from the device at once (``_frames_on``): one copy
each way per block instead of a synchronising read per frame."""


def _frames_on(points: np.ndarray, device: str):
    """Each frame of ``points`` (T, V, 3) on ``device``, moved there ``FRAME_CHUNK`` frames at a
    time: ``(k, x, last)``, x the frame (Warp vec3 (V,)), k its place in its block, ``last``
    whether it ends the block (a caller reads a block's results back then)."""
    wp = warp()
    for s in range(0, points.shape[0], FRAME_CHUNK):
        block = np.ascontiguousarray(points[s:s + FRAME_CHUNK], np.float32)
        block = wp.array(block, dtype=wp.vec3, device=device)
        for k in range(block.shape[0]):
            yield k, block[k], k == block.shape[0] - 1


def push_outside(points: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray, *,
                 clearance: float = 0.002, device: str | None = None, max_dist: float = 1.0) -> np.ndarray:
    """Move garment points out of the body: a point inside the closed body mesh, or within
    ``clearance`` of it, goes to its closest body point plus ``clearance`` along the face normal
    (the collision post-process of learned garment models, e.g. TailorNet, SNUG).

    Args:
        points: garment positions [m], shape (T, V, 3).
        body_vertices: body positions [m], shape (T, Vb, 3) (or (Vb, 3) for a static body).
        body_faces: (Fb, 3) int, outward wound.
        clearance: distance [m] kept from the skin.
        max_dist: points farther than this [m] from the body are left alone.

    Returns:
        The corrected positions, float32 (T, V, 3) (a new array).
    """
    wp = warp()
    from sim import quality_kernels as K

    d = resolve_device(device)
    points = np.asarray(points, np.float32)
    y = wp.empty(points.shape[1], dtype=wp.vec3, device=d)
    out = np.empty_like(points)
    for t, mesh in _body_meshes(body_vertices, body_faces, points.shape[0], d):
        x = wp.array(np.ascontiguousarray(points[t]), dtype=wp.vec3, device=d)
        wp.launch(K.push_outside_kernel, dim=points.shape[1],
                  inputs=[mesh.id, x, float(max_dist), float(clearance)], outputs=[y], device=d)
        out[t] = y.numpy()
    return out


def _edge_crossings(vertices: np.ndarray, faces: np.ndarray, device: str | None):
    """Per frame of ``vertices`` (T, V, 3), the crossings of each edge of :func:`unique_edges`
    ``(faces)`` through non-adjacent faces, int (E,): one BVH, refit per frame."""
    wp = warp()
    from sim import quality_kernels as K

    d = resolve_device(device)
    faces = np.asarray(faces, np.int32)
    edges = mesh_edges(faces)
    edges_d = wp.array(edges, dtype=int, device=d)
    faces_d = wp.array(faces, dtype=int, device=d)
    T = vertices.shape[0]
    pts = wp.array(np.ascontiguousarray(vertices[0], np.float32), dtype=wp.vec3, device=d)
    mesh = wp.Mesh(points=pts, indices=wp.array(faces.ravel(), dtype=wp.int32, device=d))
    per_edge = wp.empty((min(T, FRAME_CHUNK), edges.shape[0]), dtype=int, device=d)
    for t, (k, x, last) in enumerate(_frames_on(vertices, d)):
        if t > 0:
            wp.copy(pts, x)
            mesh.refit()
        wp.launch(K.self_intersection_kernel, dim=edges.shape[0],
                  inputs=[mesh.id, pts, edges_d, faces_d], outputs=[per_edge[k]], device=d)
        if last:
            yield from per_edge.numpy()[:k + 1].copy()  # rows the next block cannot overwrite


def self_intersections(vertices: np.ndarray, faces: np.ndarray, *, device: str | None = None,
                       edge_mask: np.ndarray | None = None) -> np.ndarray:
    """Per frame, the number of edge-face crossings between non-adjacent elements.

    Args:
        vertices: positions [m], shape (T, V, 3).
        faces: (F, 3) int.
        edge_mask: count only the crossings of these edges, bool (E,) over
            :func:`unique_edges` ``(faces)``; None: every edge.

    Returns:
        (T,) int.
    """
    keep = slice(None) if edge_mask is None else edge_mask
    return np.array([int(hits[keep].sum()) for hits in _edge_crossings(vertices, faces, device)], np.int64)


def crossing_edges(vertices: np.ndarray, faces: np.ndarray, *, device: str | None = None) -> np.ndarray:
    """Which edges of one mesh cross a non-adjacent face of it.

    Args:
        vertices: (V, 3) [m]; faces: (F, 3) int.

    Returns:
        bool (E,) over :func:`unique_edges` ``(faces)``.
    """
    return next(_edge_crossings(np.asarray(vertices)[None], faces, device)) > 0


def summarize_self_crossings(hits, rest_hit: np.ndarray, edges: np.ndarray, rest: np.ndarray,
                             weights: np.ndarray, joint_names: tuple[str, ...],
                             edge_mask: np.ndarray | None = None) -> dict:
    """Where a body's crossing edges are: ``hits`` yields one bool (E,) per frame (a (T, E) array
    or a generator: memory does not grow with the frame count; the default body's 40k edges over
    thousands of frames would be hundreds of MB). Counts per frame the edges that do not cross at
    rest (``rest_hit``, (E,)) and are in ``edge_mask`` (None: all), and per skinning joint (the
    joint with the largest weight at the edge's first vertex) the frames with such edges, the most
    of them in one frame and their rest-pose height range [m]."""
    keep = ~np.asarray(rest_hit, bool)
    if edge_mask is not None:
        keep &= np.asarray(edge_mask, bool)
    owner = np.argmax(weights[edges[:, 0]], axis=1)
    per_frame, per_joint, ever = [], [], np.zeros(len(edges), bool)
    for hit in hits:
        new = np.asarray(hit, bool) & keep
        per_frame.append(int(new.sum()))
        per_joint.append(np.bincount(owner[new], minlength=len(joint_names)))
        ever |= new
    per_frame = np.asarray(per_frame, np.int64)
    by_joint = {}
    if len(per_frame):
        counts = np.stack(per_joint)  # (T, J)
        for j in np.flatnonzero(counts.sum(axis=0)):
            cols = np.flatnonzero(ever & (owner == j))
            y = 0.5 * (rest[edges[cols, 0], 1] + rest[edges[cols, 1], 1])
            by_joint[joint_names[j]] = {"frames": np.flatnonzero(counts[:, j]).tolist(),
                                        "most_edges": int(counts[:, j].max()),
                                        "rest_y_m": [round(float(y.min()), 3), round(float(y.max()), 3)]}
    return {"frames_with_crossings": int((per_frame > 0).sum()),
            "max_edges": int(per_frame.max()) if len(per_frame) else 0,
            "per_frame": per_frame.tolist(), "by_joint": by_joint,
            "rest_pose_crossing_edges": int(np.asarray(rest_hit, bool).sum())}


def body_self_crossings(vertices: np.ndarray, faces: np.ndarray, rest_vertices: np.ndarray,
                        weights: np.ndarray, joint_names, *, edge_mask: np.ndarray | None = None,
                        device: str | None = None, progress=None) -> dict:
    """Where a skinned body passes through itself over a motion.

    Linear blend skinning without pose correctives folds the skin through itself at deep joint
    flexion: the calf into the thigh behind a bent knee, the thigh into the belly at the groin,
    the upper arm into the chest. Cloth caught there has no place outside the body, so a garment
    may fail its gates there for the body's sake. Counts the body's edges that cross one of its own
    faces in each frame, beyond those that cross in the rest pose (the default mesh has 50 at the
    toes), grouped by the joint that skins them most (:func:`summarize_self_crossings`, frame by
    frame).

    Args:
        vertices: posed body [m], (T, V, 3); faces: (F, 3); rest_vertices: the shaped rest pose
            (V, 3); weights: skinning weights (V, J); joint_names: J names.
        edge_mask: count only these edges, bool (E,) over :func:`unique_edges` ``(faces)`` (e.g.
            those near a garment, :func:`body_edges_near`); None: every edge.
        progress: optional callable ``progress(frames_done, frames_total)``.

    Returns:
        dict: ``frames_with_crossings``, ``max_edges``, ``per_frame`` (T,), ``by_joint`` (name ->
        frames, most_edges, rest_y_m) and ``rest_pose_crossing_edges``.
    """
    vertices = np.asarray(vertices, np.float32)
    faces = np.asarray(faces, np.int32)
    rest = np.asarray(rest_vertices, np.float32)
    rest_hit = next(_edge_crossings(rest[None], faces, device)) > 0

    def hits():
        if vertices.shape[0] == 0:
            return
        for t, h in enumerate(_edge_crossings(vertices, faces, device)):
            yield h > 0
            if progress is not None:
                progress(t + 1, vertices.shape[0])

    return summarize_self_crossings(hits(), rest_hit, unique_edges(faces), rest, np.asarray(weights),
                                    tuple(joint_names), edge_mask)


GARMENT_REACH = 0.05
"""How near a garment's rest surface a body self-crossing must lie to be named for it [m]
(``wrinkles simulate`` when the gates fail, a dataset's rejection records)."""


def body_edges_near(body_rest: np.ndarray, body_faces: np.ndarray, garment_rest: np.ndarray,
                    garment_faces: np.ndarray, reach: float, *, device: str | None = None) -> np.ndarray:
    """The body's edges (:func:`unique_edges` order) whose midpoints lie within ``reach`` [m] of a
    garment's surface, both in the rest pose: the body edges whose self-crossings can catch that
    garment (``body_self_crossings(edge_mask=...)``), bool (E,)."""
    from sim.cloth.state import BodyCollider

    rest = np.asarray(body_rest, np.float32)
    e = unique_edges(body_faces)
    d = BodyCollider(garment_rest, garment_faces, device=resolve_device(device)).signed_distance(
        0.5 * (rest[e[:, 0]] + rest[e[:, 1]]), max_dist=2.0 * reach)
    return np.abs(d) < reach


def garment_body_crossings(body, betas: np.ndarray | None, garment, body_vertices: np.ndarray, *,
                           device: str | None = None, progress=None) -> dict:
    """:func:`body_self_crossings` of a body model (``sim.bodies.BodyModel``) of shape ``betas``
    posed at ``body_vertices`` (T, V, 3), counting only the edges within ``GARMENT_REACH`` of
    ``garment``'s rest surface; with ``frames`` (T) and ``frames_by_joint`` (name -> frame count)
    added, the short form the quality reports keep (``wrinkles simulate``, dataset rejections)."""
    rest = body.rest_mesh(betas)
    near = body_edges_near(rest, body.faces, garment.rest_vertices, garment.faces, GARMENT_REACH,
                           device=device)
    c = body_self_crossings(body_vertices, body.faces, rest, body.weights, body.joint_names,
                            edge_mask=near, device=device, progress=progress)
    return {**c, "frames": len(c["per_frame"]),
            "frames_by_joint": {k: len(v["frames"]) for k, v in c["by_joint"].items()}}


def short_crossings(c: dict) -> dict:
    """The part of :func:`garment_body_crossings` a quality report keeps."""
    return {k: c[k] for k in ("frames_with_crossings", "frames", "max_edges", "frames_by_joint")}


def evaluate_sequence(vertices: np.ndarray, rest_vertices: np.ndarray, faces: np.ndarray,
                      body_vertices: np.ndarray | None = None, body_faces: np.ndarray | None = None,
                      *, device: str | None = None, rest_lengths: np.ndarray | None = None) -> QualityReport:
    """All quality statistics of a garment sequence.

    Args:
        vertices: garment positions [m], shape (T, V, 3).
        rest_vertices: garment rest positions [m], shape (V, 3).
        faces: garment triangles (F, 3).
        body_vertices: body positions [m], (T, Vb, 3) or (Vb, 3); None skips the inside test.
        body_faces: body triangles (Fb, 3).
        rest_lengths: edge rest lengths [m] where they are not ``rest_vertices``' (``edge_strain``).
    """
    vertices = np.asarray(vertices, np.float32)
    T = vertices.shape[0]
    finite = bool(np.all(np.isfinite(vertices)))
    if not finite:
        nan = np.full(T, np.nan)
        return QualityReport(float("inf"), float("inf"), float("inf"), float("inf"), nan,
                             np.full(T, -1), False)
    s = edge_strain(vertices, rest_vertices, faces, device=device, rest_lengths=rest_lengths)
    inside = (inside_fraction(vertices, body_vertices, body_faces, device=device)
              if body_vertices is not None else np.zeros(T))
    si = self_intersections(vertices, faces, device=device)
    a = np.abs(s)
    return QualityReport(
        max_edge_strain=float(a.max()), mean_edge_strain=float(a.mean()),
        max_stretch=float(max(s.max(), 0.0)), max_compression=float(max(-s.min(), 0.0)),
        inside_fraction=inside, self_intersections=si, finite=True)


def check_frame(positions: np.ndarray, frame: int, *, rest_edge_length: float | None = None,
                bound: float = 100.0) -> None:
    """Stop a run that has blown up.

    Args:
        positions: (V, 3) [m] of one frame.
        frame: frame index (for the message).
        rest_edge_length: typical rest edge length [m]; with it, any vertex farther than 1000
            edge lengths from the mean position also counts as an explosion.
        bound: |coordinate| above this [m] is an explosion.

    Raises:
        SimulationError: naming the frame and the cause.
    """
    p = np.asarray(positions)
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        first = int(np.argmax(bad))
        raise SimulationError(frame, f"{int(bad.sum())} vertices became NaN/inf (first: vertex {first})")
    far = np.abs(p).max(axis=1) > bound
    if far.any():
        raise SimulationError(frame, f"explosion: vertex {int(np.argmax(far))} left the {bound:g} m box")
    if rest_edge_length is not None:
        spread = np.linalg.norm(p - p.mean(axis=0), axis=1).max()
        if spread > 1000.0 * rest_edge_length:
            raise SimulationError(frame, f"explosion: garment spread {spread:.1f} m")
