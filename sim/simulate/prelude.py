"""The prelude of a run: the garment placed on the body at rest, the settle (with the body's
morph from the garment's shape to the job's) and the way into the motion (``prepare_track``):
the motion's own lead-in (procedural motions) or a blend from rest into its first frame
(``sim.motions.blend.enter_from_rest``).

Reference-shape dressing: a garment built on one shape (``SimulationJob.garment_betas``, e.g.
the mean shape) worn by a body of another (``betas``) keeps its topology; the body morphs from
the garment's rest mesh to the target rest mesh over the first ``MORPH_FRACTION`` of the settle
(smoothstep) and holds the target shape for the rest of it (``morph_settle``). Blend shapes are
linear in the betas and the settle is in rest pose, so the interpolated frames are exactly the
rest meshes of the interpolated shapes. This gives the per-garment models of Guo et al. 2024
(Sec. 3.3) one garment mesh over many body shapes.
"""

from __future__ import annotations

import numpy as np

from sim.easing import smoothstep
from sim.errors import WrinklesInputError
from sim.profiling import phase
from sim.simulate.config import SimulationConfig
from sim.simulate.jobs import SimulationJob, Track, resolve_betas, shared_body_key
from sim.types import BodyFrames

MORPH_FRACTION = 0.6
"""Share of the settle frames over which the body morphs from the garment's shape to the job's;
the cloth comes to rest on the target shape during the remainder."""


def morph_frames(n_settle: int, *, fraction: float = MORPH_FRACTION) -> int:
    """Frames over which the body morphs in a settle of ``n_settle`` frames (>= 1)."""
    return max(1, int(round(fraction * n_settle)))


def morph_settle(frames_ref: BodyFrames, frames_target: BodyFrames, n_settle: int, *,
                 fraction: float = MORPH_FRACTION) -> BodyFrames:
    """Morph a body from a reference shape to the target shape over the settle.

    Timeline frame t <= ``n_settle`` is ``(1 - w) ref[t] + w target[t]`` with
    ``w = smoothstep(t / m)``, ``m = morph_frames(n_settle)``: frame 0 is the reference body,
    frames m.. the target; frames after the settle are the target's unchanged. Exact for rest
    pose (blend shapes and the joint regressor are linear in the betas).

    Args:
        frames_ref: the body with the garment's shape, at least ``n_settle + 1`` frames, in
            rest pose over them; vertices (T_ref, V, 3) [m].
        frames_target: the body with the job's shape over the whole timeline (T, V, 3) [m].
        n_settle: settle frames (timeline frames 0..n_settle are at rest), >= 1.
        fraction: share of the settle spent morphing.

    Returns:
        BodyFrames like ``frames_target`` (float32) with the settle frames morphed; joint
        transforms keep the target's rotations (identity at rest) and interpolate translations.
    """
    n = int(n_settle)
    if n < 1:
        raise ValueError(f"morph_settle: n_settle must be >= 1, got {n_settle}")
    if frames_ref.num_frames < n + 1 or frames_target.num_frames < n + 1:
        raise ValueError(f"morph_settle: need {n + 1} frames, got {frames_ref.num_frames} (reference) and "
                         f"{frames_target.num_frames} (target)")
    if frames_ref.vertices.shape[1:] != frames_target.vertices.shape[1:]:
        raise ValueError("morph_settle: reference and target bodies differ in vertex count")
    w = smoothstep(np.arange(n + 1) / morph_frames(n, fraction=fraction))

    def lerp(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        ww = w.reshape(-1, *([1] * (a.ndim - 1)))
        return ((1.0 - ww) * a.astype(np.float64) + ww * b.astype(np.float64)).astype(np.float32)

    s = slice(0, n + 1)
    vertices = np.array(frames_target.vertices, np.float32, copy=True)
    joints = np.array(frames_target.joints, np.float32, copy=True)
    transforms = np.array(frames_target.transforms, np.float32, copy=True)
    vertices[s] = lerp(frames_ref.vertices[s], frames_target.vertices[s])
    joints[s] = lerp(frames_ref.joints[s], frames_target.joints[s])
    transforms[s, :, :3, 3] = lerp(frames_ref.transforms[s, :, :3, 3], frames_target.transforms[s, :, :3, 3])
    return BodyFrames(vertices=vertices, joints=joints, transforms=transforms, faces=frames_target.faces)


def prepare_track(job: SimulationJob, cfg: SimulationConfig, device: str, cache: dict) -> Track:
    """The timeline of ``job`` (its motion at ``cfg.fps`` after the settle and the way in from
    rest: the motion's lead-in, else a blend of ``cfg.blend_seconds``), its body
    posed over it (shared through ``cache`` by jobs of equal ``shared_body_key``: grounded, morphed from
    the garment's shape, its parts moved out of each other with ``cfg.separate_body_parts``), the
    garment's placement and pinned vertices, and its output buffer.

    Raises:
        WrinklesInputError: a garment of another shape with a settle too short to morph in.
    """
    from sim.bodies.intersections import parts_of, separate_body_frames
    from sim.bodies.placement import floor_offset, translate_frames
    from sim.dressing import attachment_vertices, place_garment
    from sim.motions.blend import enter_from_rest
    from sim.motions.resample import resample_motion

    motion = job.motion
    if abs(float(motion.fps) - float(cfg.fps)) > 1e-9:
        motion = resample_motion(motion, cfg.fps)
    betas = resolve_betas(job.body, motion, job.betas)
    timeline, n_prelude = enter_from_rest(motion, cfg.blend_seconds, hold=cfg.settle_seconds)
    n_settle = cfg.settle_frames
    gbetas = None
    if job.garment_betas is not None:
        gbetas = job.body.full_betas(job.garment_betas)
        if np.array_equal(gbetas, betas):
            gbetas = None
        elif n_settle < 2:
            raise WrinklesInputError(f"{job.label}: the garment was built on another body shape; the body "
                                     f"morphs to this one during the settle, which needs >= 2 frames "
                                     f"(settle_seconds {cfg.settle_seconds:g} s at {cfg.fps:g} fps)")
    key = shared_body_key(job, betas, gbetas)
    if key not in cache:  # garments sharing a body, shape and motion share its skinning
        frames = job.body.pose(betas, timeline.poses, timeline.trans, device=device)
        dy = floor_offset(frames, frame=n_prelude) if cfg.ground else 0.0  # on the target shape
        if gbetas is not None:  # the garment's shape at frame 0, morphing to the target's
            ref = job.body.pose(gbetas, timeline.poses[:n_settle + 1], timeline.trans[:n_settle + 1],
                                device=device)
            frames = morph_settle(ref, frames, n_settle)
        if cfg.separate_body_parts:  # the collider the cloth meets has no overlapping parts
            with phase("body separation"):
                frames = separate_body_frames(frames, parts_of(job.body), device=device)
        if dy:
            frames = translate_frames(frames, np.array([0.0, dy, 0.0]))
        cache[key] = (frames, dy)
    frames, dy = cache[key]
    # timeline frame 0 is the rest pose at the root translation the way in starts from (pose() of
    # zero rotations is rest_mesh + trans), so the garment built on the rest mesh moves by the same;
    # with a garment shape, frame 0 is that shape's rest mesh (morph_settle)
    placement = timeline.trans[0].astype(np.float64) + np.array([0.0, dy, 0.0])
    x0 = place_garment(job.garment.rest_vertices, placement)
    pinned = attachment_vertices(job.garment.attachments, cfg.pinned)
    tr = Track(job=job, motion=motion, timeline=timeline, frames=frames, betas=betas, n_settle=n_settle,
               n_blend=n_prelude - n_settle, first_out=0 if cfg.keep_prelude else n_prelude,
               placement=placement, ground_dy=float(dy), pinned=pinned, body_key=key, garment_betas=gbetas)
    tr.out = np.empty((tr.length - tr.first_out, job.garment.num_vertices, 3), np.float32)
    if tr.first_out == 0:
        tr.out[0] = x0
    return tr
