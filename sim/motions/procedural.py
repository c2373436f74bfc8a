"""Procedural motions: shared kinematics helpers and the non-gait library.

Every generator takes a frozen params dataclass and returns a ``Motion`` at ``params.fps``
lasting ``params.duration`` (``round(duration * fps)`` frames), in full motion from its first
frame (t = 0). The way in from the rest T-pose is the motion's *lead-in*: the same motion
evaluated before t = 0 over its ``ramp`` (``round(ramp * fps)`` frames), its amplitudes and
the gaits' speed eased up from zero (:func:`lead_weight`; the jump goes from the T-pose to
standing), so it starts at rest (poses 0) with zero velocity and joins the clip at t = 0
without a velocity jump. It is returned beside the clip as ``extra["lead_in"]`` (a ``Motion``
of the frames before t = 0, ``LEAD_IN``), not in it: a simulation plays it in its prelude after
the garment settles on the rest body (``sim.motions.blend.enter_from_rest``), and every output
starts at t = 0. ``rest_to_apose``, whose content is that transition, has none. ``trans`` is
relative to standing at rest: the feet stay on the rest floor level (sole contact points found
by forward kinematics on a ``MotionSkeleton``: the body's own joints and soles via
``MotionSkeleton.from_body``, or SMPL's approximate skeleton
``sim.motions.retarget.SMPL_REST_JOINTS`` with heel/toe points when no skeleton is given); no
height offset is added; the gaits reach z = 0 at t = 0 (their lead-in walks up from z < 0).
Every generator takes ``skeleton=None``.

Signs of SMPL joint rotations are listed in ``sim.motions.limits``. Angles in params are in
degrees (``*_deg``), times in seconds, lengths in metres.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from sim.easing import smootherstep, smoothstep
from sim.errors import WrinklesInputError
from sim.motions.limits import JOINT_LIMITS
from sim.motions.resample import LEAD_IN
from sim.motions.skeleton import MotionSkeleton, resolve_skeleton
from sim.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from sim.types import NUM_SMPL_JOINTS, SMPL_JOINT_NAMES, Motion

D2R = np.pi / 180.0
GRAVITY = 9.81  # [m/s^2]
JOINT = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
_AX = {"x": 0, "y": 1, "z": 2}

# Segment masses (fraction of body mass) and centre-of-mass positions along the segment
# (fraction from the proximal joint), Winter (2009) "Biomechanics and Motor Control of Human
# Movement", Table 4.1: trunk-head-neck, upper arm, forearm+hand, thigh, leg, foot.
_SEGMENTS = (  # (mass, proximal joint(s), distal joint(s), COM fraction)
    (0.578, ("left_hip", "right_hip"), ("left_shoulder", "right_shoulder"), 0.66),
    (0.028, ("left_shoulder",), ("left_elbow",), 0.436),
    (0.028, ("right_shoulder",), ("right_elbow",), 0.436),
    (0.022, ("left_elbow",), ("left_wrist",), 0.682),
    (0.022, ("right_elbow",), ("right_wrist",), 0.682),
    (0.100, ("left_hip",), ("left_knee",), 0.433),
    (0.100, ("right_hip",), ("right_knee",), 0.433),
    (0.0465, ("left_knee",), ("left_ankle",), 0.433),
    (0.0465, ("right_knee",), ("right_ankle",), 0.433),
    (0.0145, ("left_ankle",), ("left_foot",), 0.5),
    (0.0145, ("right_ankle",), ("right_foot",), 0.5),
)


# --- parameters and registry ----------------------------------------------------------------

@dataclass(frozen=True)
class MotionSpec:
    """A registered procedural motion: its params class, generator and a one-line description."""

    params: type
    generate: Callable[..., Motion]
    description: str


def check_params(p, **rules: tuple[float, float]) -> None:
    """Validate a params dataclass: every float finite, ``duration``/``fps`` positive, and each
    ``name=(low, high)`` rule inclusive. Raises ``WrinklesInputError`` naming the field."""
    where = f"procedural:{type(p).__name__.removesuffix('Params').lower()}"
    for f in fields(p):
        v = getattr(p, f.name)
        if isinstance(v, (int, float)) and not isinstance(v, bool) and not np.isfinite(v):
            raise WrinklesInputError(f"parameter '{f.name}' must be finite, got {v}", path=where)
    rules = {"duration": (1e-6, 1e5), "fps": (1e-3, 1e4), **rules}
    for name, (lo, hi) in rules.items():
        v = getattr(p, name)
        if not (lo <= v <= hi):
            raise WrinklesInputError(f"parameter '{name}' must be in [{lo:g}, {hi:g}], got {v}",
                                     path=where)


def check_choice(p, name: str, allowed: tuple[str, ...]) -> None:
    """Raise ``WrinklesInputError`` unless ``p.<name>`` is one of ``allowed``."""
    v = getattr(p, name)
    if v not in allowed:
        where = f"procedural:{type(p).__name__.removesuffix('Params').lower()}"
        raise WrinklesInputError(f"parameter '{name}' must be one of {', '.join(allowed)}, got "
                                 f"{v!r}", path=where)


# --- small kinematics helpers -----------------------------------------------------------------

def lead_frames(ramp: float, fps: float) -> int:
    """Frames of a lead-in of ``ramp`` seconds at ``fps``: ``round(ramp * fps)``, at least one."""
    return max(1, int(round(ramp * fps)))


def time_axis(duration: float, fps: float, lead: int = 0) -> np.ndarray:
    """Frame times [s]: ``lead`` frames before t = 0 (the lead-in, negative times), then the
    clip's ``round(duration * fps)`` frames (at least one) from t = 0."""
    return np.arange(-lead, max(1, int(round(duration * fps))), dtype=np.float64) / fps


def lead_weight(t: np.ndarray, lead: int, fps: float) -> np.ndarray:
    """The lead-in's ease: smootherstep from 0 at its first frame (t = -lead / fps, the rest
    pose) to 1 at t = 0, 1 from t = 0 on. Zero slope and curvature at both ends: a motion
    ``w(t) g(t)`` leaves rest with zero velocity and meets ``g`` at t = 0 with continuous
    velocity and acceleration (a cubic smoothstep would leave an acceleration jump there)."""
    return smootherstep(1.0 + np.asarray(t, dtype=np.float64) * fps / lead)


class PoseBuilder:
    """Local joint rotations built by composing elementary rotations.

    ``rot(joint, axis, angle)`` pre-multiplies the joint's local rotation by a rotation about
    the parent-frame axis, so ``rot(j, "z", a); rot(j, "x", b)`` gives ``Rx(b) Rz(a)``.

    Args:
        shape: leading batch shape, e.g. ``(T,)``.
    """

    def __init__(self, shape: tuple[int, ...]):
        self.shape = tuple(shape)
        self.L = np.broadcast_to(np.eye(3), self.shape + (NUM_SMPL_JOINTS, 3, 3)).copy()

    def rot(self, joint: str, axis: str, angle) -> PoseBuilder:
        """Rotate ``joint`` by ``angle`` [rad] (broadcast to ``shape``) about ``axis``."""
        aa = np.zeros(self.shape + (3,))
        aa[..., _AX[axis]] = np.broadcast_to(np.asarray(angle, dtype=np.float64), self.shape)
        j = JOINT[joint]
        self.L[..., j, :, :] = axis_angle_to_matrix(aa) @ self.L[..., j, :, :]
        return self

    def side(self, joint: str, axis: str, angle) -> PoseBuilder:
        """Rotate the left and right ``joint`` mirrored: Y and Z angles flip sign on the right."""
        sign = 1.0 if axis == "x" else -1.0
        self.rot("left_" + joint, axis, angle)
        return self.rot("right_" + joint, axis, sign * np.asarray(angle))

    def axis_angle(self) -> np.ndarray:
        """Axis-angle [rad], shape ``shape + (24, 3)``, float64."""
        return matrix_to_axis_angle(self.L)


def arms(pb: PoseBuilder, down, flex=0.0, elbow=0.0) -> PoseBuilder:
    """Both arms: lowered by ``down`` from the T-pose toward the sides, then swung forward by
    ``flex`` (about X), elbows flexed by ``elbow`` [rad] (all broadcast to the batch shape)."""
    pb.side("shoulder", "z", -np.asarray(down))
    pb.rot("left_shoulder", "x", -np.asarray(flex))
    pb.rot("right_shoulder", "x", -np.asarray(flex))
    return pb.side("elbow", "y", -np.asarray(elbow))


def flat_feet_pose(pb: PoseBuilder, knee, dorsi, lean, rise=0.0) -> PoseBuilder:
    """Symmetric legs with flat feet: knee flexion, ankle dorsiflexion and a forward trunk lean
    at the pelvis [rad]; the hips take ``a - k - p`` about X so the feet stay level. ``rise``
    [rad] plantarflexes the ankles on top, uncompensated (heels lift, as at take-off)."""
    knee, dorsi, lean = (np.asarray(v, dtype=np.float64) for v in (knee, dorsi, lean))
    pb.rot("pelvis", "x", lean)
    pb.side("hip", "x", dorsi - knee - lean)
    pb.side("knee", "x", knee)
    pb.side("ankle", "x", np.asarray(rise) - dorsi)
    return pb


def contact_heights(G: np.ndarray, P: np.ndarray,
                    skeleton: MotionSkeleton | None = None) -> np.ndarray:
    """Height [m] of the skeleton's foot contact points, shape (..., N); for the default
    skeleton N = 4: left heel, left toe, right heel, right toe."""
    return resolve_skeleton(skeleton).contact_heights(G, P)


def ground_trans_y(poses: np.ndarray, skeleton: MotionSkeleton | None = None) -> np.ndarray:
    """Vertical root translation [m] putting the lowest foot contact point on the rest floor.

    Args:
        poses: axis-angle [rad], shape (..., 24, 3).
        skeleton: the skeleton (None: the default).

    Returns:
        shape (...,): 0 for the rest pose.
    """
    sk = resolve_skeleton(skeleton)
    G, P = sk.forward_kinematics(poses)
    return sk.rest_floor - sk.contact_heights(G, P).min(axis=-1)


def feet_fixed_trans(poses: np.ndarray, skeleton: MotionSkeleton | None = None) -> np.ndarray:
    """Root translation [m] keeping the ankles' midpoint over its rest spot (x, z) and the
    lowest foot contact on the floor (y), shape (..., 3)."""
    sk = resolve_skeleton(skeleton)
    G, P = sk.forward_kinematics(poses)
    la, ra = JOINT["left_ankle"], JOINT["right_ankle"]
    mid = 0.5 * (P[..., la, :] + P[..., ra, :])
    rest_mid = 0.5 * (sk.rest_joints[la] + sk.rest_joints[ra])
    out = rest_mid - mid
    out[..., 1] = sk.rest_floor - sk.contact_heights(G, P).min(axis=-1)
    return out


def center_of_mass(P: np.ndarray) -> np.ndarray:
    """Whole-body centre of mass [m] from joint positions (..., 24, 3) (Winter's segments)."""
    com = np.zeros(P.shape[:-2] + (3,))
    for mass, prox, dist, frac in _SEGMENTS:
        a = np.mean([P[..., JOINT[n], :] for n in prox], axis=0)
        b = np.mean([P[..., JOINT[n], :] for n in dist], axis=0)
        com += mass * (a + frac * (b - a))
    return com


_LEAN_GRID = np.linspace(-10.0, 80.0, 46) * D2R


def balance_lean(knee: np.ndarray, dorsi: np.ndarray, *, down=0.0, flex=0.0, elbow=0.0,
                 arms_level: bool = False, skeleton: MotionSkeleton | None = None) -> np.ndarray:
    """Trunk lean [rad] at the pelvis that keeps the centre of mass over the feet.

    The target is the rest pose's horizontal distance from the ankles to the centre of mass
    (quiet stance); the lean is searched on a 2-degree grid and interpolated linearly.

    Args:
        knee, dorsi: knee flexion and ankle dorsiflexion [rad], shape (T,).
        down, flex, elbow: arm pose as in :func:`arms` (scalars or (T,)).
        arms_level: add the lean to ``flex`` so the arms keep their angle to the vertical.
        skeleton: the skeleton (None: the default).

    Returns:
        lean [rad], shape (T,).
    """
    knee = np.asarray(knee, dtype=np.float64)
    T, n = knee.shape[0], _LEAN_GRID.shape[0]
    lean = np.broadcast_to(_LEAN_GRID, (T, n))
    bshape = (T, n)

    def col(v):
        return np.broadcast_to(np.asarray(v, dtype=np.float64).reshape(-1, 1)
                               if np.ndim(v) else np.asarray(v), bshape)

    pb = flat_feet_pose(PoseBuilder(bshape), col(knee), col(dorsi), lean)
    arms(pb, col(down), col(flex) + (lean if arms_level else 0.0), col(elbow))
    sk = resolve_skeleton(skeleton)
    _, P = sk.forward_kinematics(pb.axis_angle())
    ankles = 0.5 * (P[..., JOINT["left_ankle"], 2] + P[..., JOINT["right_ankle"], 2])
    f = center_of_mass(P)[..., 2] - ankles
    P0 = sk.rest_joints
    target = center_of_mass(P0)[2] - 0.5 * (P0[JOINT["left_ankle"], 2] + P0[JOINT["right_ankle"], 2])
    out = np.empty(T)
    for t in range(T):  # f rises with the lean: interpolate where it crosses the target
        out[t] = np.interp(target, np.maximum.accumulate(f[t]), _LEAN_GRID)
    return out


def make_motion(name: str, params, poses: np.ndarray, trans: np.ndarray, *, lead: int = 0,
                **extra) -> Motion:
    """Wrap arrays into a ``Motion`` (float32) with ``source='procedural:<name>'``.

    The first ``lead`` frames (times before t = 0, :func:`time_axis`) become the lead-in,
    ``extra[LEAD_IN]``; the clip is the rest. Per-frame arrays in ``extra`` are split the same way.
    """
    poses, trans = poses.astype(np.float32), trans.astype(np.float32)
    per_frame = {k for k, v in extra.items()
                 if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == poses.shape[0]}
    clip = {k: (v[lead:] if k in per_frame else v) for k, v in extra.items()}
    source = f"procedural:{name}"
    if lead:
        clip[LEAD_IN] = Motion(poses=poses[:lead], trans=trans[:lead], fps=float(params.fps),
                               name=f"{name} lead-in", source=source,
                               extra={k: extra[k][:lead] for k in per_frame})
    return Motion(poses=poses[lead:], trans=trans[lead:], fps=float(params.fps), name=name, source=source,
                  extra={"params": {f.name: getattr(params, f.name) for f in fields(params)}, **clip})


# --- library ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class RestToAPoseParams:
    """Attributes: duration [s]; fps [1/s]; angle_deg: arm lowering from the T-pose [deg];
    start: time the arms start moving [s]; transition: time to reach the A-pose [s]."""

    duration: float = 2.0
    fps: float = 30.0
    angle_deg: float = 45.0
    start: float = 0.0
    transition: float = 1.0

    def __post_init__(self) -> None:
        check_params(self, angle_deg=(-30.0, 85.0), start=(0.0, 1e5), transition=(1e-3, 1e5))


def rest_to_apose(p: RestToAPoseParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """T-pose -> A-pose (arms lowered by ``angle_deg``, collars following by 15 %), then hold."""
    t = time_axis(p.duration, p.fps)
    w = smoothstep((t - p.start) / p.transition)
    a = p.angle_deg * D2R * w
    pb = PoseBuilder(t.shape)
    pb.side("collar", "z", -0.15 * a)
    pb.side("shoulder", "z", -0.85 * a)
    return make_motion("rest_to_apose", p, pb.axis_angle(), np.zeros((t.size, 3)))


@dataclass(frozen=True)
class ArmRaiseParams:
    """Attributes: duration [s]; fps [1/s]; style: ``side`` (abduction, frontal plane) or
    ``front`` (flexion, sagittal plane); elevation_deg: top arm elevation from hanging [deg];
    period: one raise-and-lower [s]; arms: ``both``, ``left`` or ``right``; ramp: lead-in
    before t = 0 in which the arms come down from the T-pose to the sides [s] (played in a
    simulation's prelude, not part of duration)."""

    duration: float = 5.0
    fps: float = 30.0
    style: str = "side"
    elevation_deg: float = 160.0
    period: float = 2.0
    arms: str = "both"
    ramp: float = 1.0

    def __post_init__(self) -> None:
        check_params(self, elevation_deg=(15.0, 175.0), period=(0.2, 1e5), ramp=(1e-3, 1e5))
        check_choice(self, "style", ("side", "front"))
        check_choice(self, "arms", ("both", "left", "right"))


def arm_raise(p: ArmRaiseParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """Arms raised and lowered (side or front) from hanging at the sides at t = 0 (the lead-in
    brings them down from the T-pose)."""
    n = lead_frames(p.ramp, p.fps)
    t = time_axis(p.duration, p.fps, n)
    hang = 75.0 * D2R  # arm at the side: 15 deg from vertical (SMPL's arm clears the hip)
    down = hang * lead_weight(t, n, p.fps)
    cyc = 0.5 * (1.0 - np.cos(2.0 * np.pi * np.maximum(t, 0.0) / p.period))
    E = p.elevation_deg * D2R  # top angle between the arm and straight down
    if p.style == "side":
        lift = (E - (np.pi / 2 - hang)) * cyc  # abduction beyond the hanging position
    else:  # flexion phi of the hanging arm (15 deg out): cos E = cos(15 deg) cos(phi)
        lift = np.arccos(np.clip(np.cos(E) / np.sin(hang), -1.0, 1.0)) * cyc
    pb = PoseBuilder(t.shape)
    sides = ("left", "right") if p.arms == "both" else (p.arms,)
    for s in sides:
        sg = 1.0 if s == "left" else -1.0
        if p.style == "side":
            elev = -down + lift  # about Z from the T-pose; above horizontal past 90 deg
            pb.rot(f"{s}_collar", "z", sg * 0.25 * np.maximum(elev, 0.0))
            pb.rot(f"{s}_shoulder", "z", sg * (elev - 0.25 * np.maximum(elev, 0.0)))
        else:
            pb.rot(f"{s}_shoulder", "z", -sg * down)
            pb.rot(f"{s}_shoulder", "x", -lift)
            pb.rot(f"{s}_collar", "z", sg * 0.15 * np.maximum(lift - np.pi / 2, 0.0))
    for s in {"left", "right"} - set(sides):  # the other arm just hangs
        pb.rot(f"{s}_shoulder", "z", -(1.0 if s == "left" else -1.0) * down)
    return make_motion("arm_raise", p, pb.axis_angle(), np.zeros((t.size, 3)), lead=n)


@dataclass(frozen=True)
class TorsoTwistParams:
    """Attributes: duration [s]; fps [1/s]; amplitude_deg: thorax yaw relative to the pelvis
    [deg]; period: one left-right twist [s]; arm_angle_deg: arms lowered from the T-pose [deg];
    ramp: lead-in before t = 0 in which the arms come down and the twist grows to its full
    amplitude [s] (played in a simulation's prelude, not part of duration)."""

    duration: float = 4.0
    fps: float = 30.0
    amplitude_deg: float = 35.0
    period: float = 2.0
    arm_angle_deg: float = 45.0
    ramp: float = 1.0

    def __post_init__(self) -> None:
        check_params(self, amplitude_deg=(0.0, 45.0), period=(0.2, 1e5),
                     arm_angle_deg=(0.0, 80.0), ramp=(1e-3, 1e5))


def torso_twist(p: TorsoTwistParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """Trunk rotation about the vertical axis, shared by the three spine joints, head
    partly counter-rotating, arms in an A-pose; at t = 0 the trunk passes the middle turning
    left at full amplitude (the lead-in grows the twist and lowers the arms)."""
    n = lead_frames(p.ramp, p.fps)
    t = time_axis(p.duration, p.fps, n)
    w = lead_weight(t, n, p.fps)
    yaw = p.amplitude_deg * D2R * np.sin(2.0 * np.pi * t / p.period) * w
    pb = PoseBuilder(t.shape)
    for j in ("spine1", "spine2", "spine3"):
        pb.rot(j, "y", yaw / 3.0)
    pb.rot("neck", "y", -0.3 * yaw)
    pb.side("shoulder", "z", -p.arm_angle_deg * D2R * w)
    return make_motion("torso_twist", p, pb.axis_angle(), np.zeros((t.size, 3)), lead=n)


@dataclass(frozen=True)
class SquatParams:
    """Attributes: duration [s]; fps [1/s]; depth_deg: knee flexion at the bottom [deg];
    period: one down-and-up [s], from standing at t = 0; ramp: lead-in before t = 0 in which
    the arms come forward from the T-pose [s] (played in a simulation's prelude, not part of duration)."""

    duration: float = 6.0
    fps: float = 30.0
    depth_deg: float = 100.0
    period: float = 2.5
    ramp: float = 1.0

    def __post_init__(self) -> None:
        check_params(self, depth_deg=(0.0, 130.0), period=(0.3, 1e5), ramp=(1e-3, 1e5))


def squat(p: SquatParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """Bodyweight squat with arms held forward: knee flexion, ankle dorsiflexion (0.3 x knee,
    at most 35 deg), feet flat; the trunk lean is solved per frame so the centre of mass
    stays over the feet (:func:`balance_lean`), the pelvis moving back and down. The first
    squat starts at t = 0 from standing with the arms forward."""
    n = lead_frames(p.ramp, p.fps)
    t = time_axis(p.duration, p.fps, n)
    w = lead_weight(t, n, p.fps)
    cyc = 0.5 * (1.0 - np.cos(2.0 * np.pi * np.maximum(t, 0.0) / p.period))
    knee = p.depth_deg * D2R * cyc
    dorsi = np.minimum(0.3 * knee, 35.0 * D2R)
    down, flex = 90.0 * D2R * w, 90.0 * D2R * w
    lean = balance_lean(knee, dorsi, down=down, flex=flex, arms_level=True, skeleton=skeleton)
    pb = flat_feet_pose(PoseBuilder(t.shape), knee, dorsi, lean)
    arms(pb, down, flex + lean)
    pb.rot("neck", "x", -0.5 * lean)
    poses = pb.axis_angle()
    return make_motion("squat", p, poses, feet_fixed_trans(poses, skeleton), lead=n)


@dataclass(frozen=True)
class JumpParams:
    """Attributes: duration [s], about 2.5 s shows the whole jump from standing at t = 0 to
    standing again; fps [1/s]; height: rise of the root during flight [m]; depth_deg: knee
    flexion at the bottom of the countermovement [deg]; ramp: lead-in before t = 0 from the
    T-pose to standing with the arms down [s] (played in a simulation's prelude, not part of duration)."""

    duration: float = 3.0
    fps: float = 30.0
    height: float = 0.3
    depth_deg: float = 80.0
    ramp: float = 0.6

    def __post_init__(self) -> None:
        check_params(self, height=(0.0, 1.2), depth_deg=(10.0, 120.0), ramp=(1e-3, 1e5))


def _jump_keys(p: JumpParams) -> dict[str, np.ndarray]:
    """Key poses as (knee, dorsi, rise, down, flex, elbow) [rad] (see :func:`flat_feet_pose`,
    :func:`arms`)."""
    k = p.depth_deg * D2R
    return {
        "tpose": np.zeros(6),
        "stand": np.array([0.0, 0.0, 0.0, 75.0, 0.0, 10.0]) * D2R,
        "crouch": np.array([k, min(0.35 * k, 30 * D2R), 0.0, 75 * D2R, -50 * D2R, 20 * D2R]),
        "takeoff": np.array([0.0, 0.0, 30.0, 75.0, 150.0, 10.0]) * D2R,  # on the toes
        "land": np.array([0.6 * k, min(0.25 * k, 25 * D2R), 0.0, 75 * D2R, 45 * D2R, 20 * D2R]),
    }


def _jump_pose(vals: np.ndarray, skeleton: MotionSkeleton | None = None) -> np.ndarray:
    """(T, 6) key values -> axis-angle poses (T, 24, 3) with a balancing lean."""
    knee, dorsi, rise, down, flex, elbow = vals.T
    lean = balance_lean(knee, dorsi, down=down, flex=flex, elbow=elbow, skeleton=skeleton)
    pb = flat_feet_pose(PoseBuilder(knee.shape), knee, dorsi, lean, rise)
    arms(pb, down, flex, elbow)
    pb.rot("neck", "x", -0.5 * lean)
    return pb.axis_angle()


def jump(p: JumpParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """Countermovement vertical jump: stand, crouch (arms back), push off (arms up, ankles
    plantarflexed), ballistic flight where the root follows ``y0 + v0 t - g t^2 / 2`` exactly
    with ``v0 = sqrt(2 g height)``, landing with knee flexion, recovery to standing. The clip
    starts standing with the arms down (the lead-in comes from the T-pose); ``takeoff_time`` is
    in clip time."""
    key = _jump_keys(p)
    n = lead_frames(p.ramp, p.fps)
    t = time_axis(p.duration, p.fps, n)
    v0 = np.sqrt(2.0 * GRAVITY * p.height)
    t_flight = 2.0 * v0 / GRAVITY
    # push-off time from the root rise between crouch and take-off: mean speed v0 / 2
    y_c, y_to = (float(ground_trans_y(_jump_pose(key[k][None], skeleton), skeleton)[0])
                 for k in ("crouch", "takeoff"))
    t_push = float(np.clip(2.0 * (y_to - y_c) / max(v0, 1e-3), 0.15, 0.5))
    phases = [("tpose", "stand", n / p.fps, "smooth"), ("stand", "stand", 0.2, "smooth"),
              ("stand", "crouch", 0.45, "smooth"), ("crouch", "takeoff", t_push, "accel"),
              ("takeoff", "takeoff", t_flight, "flight"), ("takeoff", "land", 0.3, "decel"),
              ("land", "stand", 0.6, "smooth")]
    vals = np.tile(key["stand"], (t.size, 1))
    flight = np.zeros(t.size, dtype=bool)
    t0 = -n / p.fps
    t_takeoff = 0.0
    for a, b, dt, kind in phases:
        sel = (t >= t0) & (t < t0 + dt)
        s = (t[sel] - t0) / dt
        s = {"smooth": smoothstep(s), "accel": s * s, "decel": 1.0 - (1.0 - s) ** 2,
             "flight": s}[kind]
        vals[sel] = key[a] + s[:, None] * (key[b] - key[a])
        if kind == "flight":
            flight[sel] = True
            t_takeoff = t0
        t0 += dt
    vals[t >= t0] = key["stand"]
    poses = _jump_pose(vals, skeleton)
    trans = feet_fixed_trans(poses, skeleton)
    if flight.any():
        tau = t[flight] - t_takeoff
        trans[flight, 1] = y_to + v0 * tau - 0.5 * GRAVITY * tau**2
    return make_motion("jump", p, poses, trans, lead=n, takeoff_time=t_takeoff, flight_time=t_flight)


@dataclass(frozen=True)
class RandomParams:
    """Attributes: duration [s]; fps [1/s]; seed: random seed (same seed, same motion);
    amplitude: fraction of each joint's range used, in (0, 1]; frequency: highest frequency of
    the joint signals [Hz]; ramp: lead-in before t = 0 easing the motion in from the rest
    pose [s] (played in a simulation's prelude, not part of duration)."""

    duration: float = 5.0
    fps: float = 30.0
    seed: int = 0
    amplitude: float = 0.5
    frequency: float = 0.5
    ramp: float = 1.0

    def __post_init__(self) -> None:
        check_params(self, amplitude=(0.0, 1.0), frequency=(1e-3, 10.0), ramp=(1e-3, 1e5))
        if int(self.seed) != self.seed:
            raise WrinklesInputError(f"parameter 'seed' must be an integer, got {self.seed}",
                                     path="procedural:random")


def random_motion(p: RandomParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """Smooth random motion inside the joint-limit table (``sim.motions.limits``).

    Each axis-angle component is ``w(t) * amplitude * (c + h * tanh(g(t)))`` with ``c, h`` the
    centre and half-width of its range, ``g`` a sum of 6 random sinusoids below ``frequency``
    (unit variance) and ``w`` the lead-in's ease from the rest pose (1 from t = 0). Since the
    rest pose (0) lies in every range and ``amplitude <= 1``, every frame stays inside the limits.
    """
    n = lead_frames(p.ramp, p.fps)
    t = time_axis(p.duration, p.fps, n)
    rng = np.random.default_rng(int(p.seed))
    K = 6
    freq = rng.uniform(0.1, 1.0, size=(K, NUM_SMPL_JOINTS, 3)) * p.frequency
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(K, NUM_SMPL_JOINTS, 3))
    g = np.sqrt(2.0 / K) * np.sin(2.0 * np.pi * freq[None] * t[:, None, None, None]
                                  + phase[None]).sum(axis=1)
    lo, hi = JOINT_LIMITS[..., 0], JOINT_LIMITS[..., 1]
    c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
    w = lead_weight(t, n, p.fps)[:, None, None]
    poses = w * p.amplitude * (c + h * np.tanh(g))
    trans = np.zeros((t.size, 3))
    trans[:, 1] = ground_trans_y(poses, skeleton)
    return make_motion("random", p, poses, trans, lead=n)


@dataclass(frozen=True)
class IdleParams:
    """Attributes: duration [s]; fps [1/s]; sway_deg: side-to-side weight shift at the pelvis
    [deg]; breathing: breaths per second [Hz]; ramp: lead-in before t = 0 from the T-pose to
    arms down, swaying and breathing at full amplitude [s] (played in a simulation's prelude,
    not part of duration)."""

    duration: float = 5.0
    fps: float = 30.0
    sway_deg: float = 2.0
    breathing: float = 0.25
    ramp: float = 1.0

    def __post_init__(self) -> None:
        check_params(self, sway_deg=(0.0, 10.0), breathing=(0.0, 2.0), ramp=(1e-3, 1e5))


def idle(p: IdleParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """Standing idle: arms at the sides, breathing (spine), weight shift (pelvis roll
    compensated at the hips, feet fixed) and slow head turns."""
    n = lead_frames(p.ramp, p.fps)
    t = time_axis(p.duration, p.fps, n)
    w = lead_weight(t, n, p.fps)
    sway = p.sway_deg * D2R * np.sin(2.0 * np.pi * 0.2 * t) * w
    breath = 1.5 * D2R * np.sin(2.0 * np.pi * p.breathing * t) * w
    pb = PoseBuilder(t.shape)
    pb.rot("pelvis", "z", sway)
    pb.rot("left_hip", "z", -sway).rot("right_hip", "z", -sway)
    pb.rot("spine2", "x", -breath).rot("spine3", "x", -breath)
    pb.rot("spine1", "z", -0.5 * sway)
    pb.rot("neck", "y", 10.0 * D2R * np.sin(2.0 * np.pi * 0.1 * t) * w)
    arms(pb, 75.0 * D2R * w, 0.0, 10.0 * D2R * w)
    poses = pb.axis_angle()
    return make_motion("idle", p, poses, feet_fixed_trans(poses, skeleton), lead=n)


@dataclass(frozen=True)
class WaveParams:
    """Attributes: duration [s]; fps [1/s]; frequency: waves per second [Hz]; amplitude_deg:
    forearm swing either side [deg]; ramp: lead-in before t = 0 in which the hand is raised
    and the wave grows to its full amplitude [s] (played in a simulation's prelude, not part of duration)."""

    duration: float = 4.0
    fps: float = 30.0
    frequency: float = 1.5
    amplitude_deg: float = 25.0
    ramp: float = 1.0

    def __post_init__(self) -> None:
        check_params(self, frequency=(0.0, 5.0), amplitude_deg=(0.0, 60.0), ramp=(1e-3, 1e5))


def wave(p: WaveParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """Right hand raised beside the head (upper arm 10 deg above horizontal, rotated so the
    forearm points up) waving at the elbow, at full amplitude from t = 0; the left arm hangs."""
    n = lead_frames(p.ramp, p.fps)
    t = time_axis(p.duration, p.fps, n)
    w = lead_weight(t, n, p.fps)
    osc = p.amplitude_deg * D2R * np.sin(2.0 * np.pi * p.frequency * t)
    pb = PoseBuilder(t.shape)
    pb.rot("right_shoulder", "x", -90.0 * D2R * w)   # external rotation: flexion plane upward
    pb.rot("right_shoulder", "z", -10.0 * D2R * w)   # right arm slightly above horizontal
    pb.rot("right_elbow", "y", (100.0 * D2R - osc) * w)
    pb.rot("left_shoulder", "z", -75.0 * D2R * w)
    return make_motion("wave", p, pb.axis_angle(), np.zeros((t.size, 3)), lead=n)
