"""Walking and running from normative sagittal joint-angle curves.

Normative data (degrees, flexion / dorsiflexion positive, over one gait cycle from the right
heel strike, 0-100 %) are stored as key points of the published mean curves and
interpolated with a periodic cubic Hermite spline:

- walking: after Perry & Burnfield (2010), *Gait Analysis: Normal and Pathological
  Function*, 2nd ed., chapters on hip, knee and ankle, and Winter (1991), *The Biomechanics
  and Motor Control of Human Gait*, 2nd ed. (natural cadence): hip 30 deg at initial contact,
  peak extension -10 deg near 50 %, peak flexion ~35 deg in late swing; knee ~18 deg loading
  response, ~40 deg at toe-off (62 %), peak ~60 deg at ~72 %; ankle -6 deg plantarflexion after
  contact, +10 deg dorsiflexion in terminal stance, -16 deg after push-off.
- running: after Novacheck (1998), "The biomechanics of running", *Gait & Posture* 7:77-95
  (running at about 3.2 m/s): toe-off at ~39 %, knee ~40 deg at mid-stance and ~95 deg in
  swing, ankle ~20 deg dorsiflexion at mid-stance, ~-24 deg after toe-off.

The key points are read off the published mean curves to about +-3 deg; they reproduce the
curves' shape and extremes, not the original tabulated values.

Hip angles in these sources are thigh-to-pelvis with the pelvis tilted forward
(``pelvic_tilt``, ~10 deg walking, ~15 deg running); SMPL's rest pelvis is upright, so the
tilt is subtracted to keep the thigh's angle to the vertical right.

Cadence: walking stride length ``L = 1.41 (v / 1.3)^0.5`` m, the square-root growth of stride
with speed (cf. Grieve 1968, "Gait patterns and the speed of walking"), giving 110 steps/min at
1.3 m/s; running stride frequency ``f = 1.25 + 0.04 v`` Hz (runners speed up mostly by longer
strides; Cavanagh & Kram 1989, ~1.35-1.45 Hz at 3-5 m/s). Where a body's legs would need a hip
extension past the joint-limit table (30 deg, ``sim.motions.limits``) to reach that stride, the
cadence rises instead (:func:`limited_cadence`): on the default body the run takes 1.62
strides/s (194 steps/min) at 29 deg of hip extension, where 1.39 strides/s would need 35 deg; a
short body (betas[0] = -2) takes 2.09, where 1.39 would need 49 deg. A stride given explicitly is
kept.

Stride calibration: the normative curves belong to one stride length; at another speed /
stride the hip curve is scaled about its mean so that the stance foot, carried back by the
leg, moves at the root's speed (:func:`stride_calibration`) and does not slide.

Vertical motion: walking takes the root height from forward kinematics (the lowest heel/toe
contact stays on the floor, which yields the ~3-4 cm double-bump oscillation of the pelvis);
running uses the spring-mass model: during stance ``y = y_td - (v0 / w) sin(w tau)`` with
``w = pi / t_stance``, during flight the ballistic ``y = y_td + v0 tau - g tau^2 / 2`` with
``v0 = g t_flight / 2``, so the root leaves and meets the ground with the same speed. The
normative leg curves flex less in stance than that spring compresses, so the root is never
below the height where the lowest foot contact touches the floor: the stance foot does not
sink (the flight phase, where the feet are above the floor, stays ballistic).
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass

import numpy as np

from sim.motions.limits import JOINT_LIMITS
from sim.motions.procedural import (
    D2R,
    GRAVITY,
    JOINT,
    PoseBuilder,
    check_params,
    ground_trans_y,
    lead_frames,
    lead_weight,
    make_motion,
    time_axis,
)
from sim.motions.skeleton import MotionSkeleton, resolve_skeleton
from sim.types import Motion

# (percent of the gait cycle, degrees); periodic, the value at 100 % is the one at 0 %.
WALK_HIP = ((0, 30), (10, 28), (30, 10), (52, -10), (62, 2), (75, 24), (87, 34), (95, 31))
WALK_KNEE = ((0, 5), (15, 18), (28, 10), (40, 4), (50, 10), (62, 40), (72, 60), (82, 45),
             (92, 12), (97, 4))
WALK_ANKLE = ((0, 0), (7, -6), (15, -1), (30, 5), (45, 10), (52, 7), (62, -16), (68, -12),
              (78, -1), (90, 1))
WALK_TOE_OFF = 0.62

RUN_HIP = ((0, 35), (12, 27), (28, 5), (42, -12), (55, 0), (70, 30), (85, 45), (94, 40))
RUN_KNEE = ((0, 18), (14, 40), (28, 25), (39, 15), (48, 35), (60, 75), (70, 95), (80, 80),
            (90, 40), (96, 22))
# the 14 % key is 19.5 deg: the interpolated curve overshoots its key (to 19.64 deg), and a key of
# 20 would pass the joint-limit table's 20 deg of dorsiflexion (20.12)
RUN_ANKLE = ((0, 5), (14, 19.5), (28, 10), (39, -20), (46, -24), (56, -8), (70, 5), (85, 10),
             (94, 7))
RUN_TOE_OFF = 0.39


def periodic_curve(keys: tuple[tuple[float, float], ...], phase: np.ndarray) -> np.ndarray:
    """Periodic cubic Hermite interpolation of (percent, value) key points.

    Tangents are central differences over the neighbouring keys (non-uniform
    Catmull-Rom), so the curve is C1 and passes through every key.

    Args:
        keys: (percent in [0, 100), value) pairs, increasing percent.
        phase: cycle phase, any real (wrapped into [0, 1)), shape (...,).

    Returns:
        values, shape (...,).
    """
    x = np.array([k[0] for k in keys], dtype=np.float64) / 100.0
    y = np.array([k[1] for k in keys], dtype=np.float64)
    n = x.size
    xe = np.concatenate([x[-1:] - 1.0, x, x[:1] + 1.0, x[1:2] + 1.0])
    ye = np.concatenate([y[-1:], y, y[:1], y[1:2]])
    m = (ye[2:] - ye[:-2]) / (xe[2:] - xe[:-2])  # tangents at keys 0..n (n = wrap of 0)
    u = np.mod(np.asarray(phase, dtype=np.float64), 1.0)
    i = np.clip(np.searchsorted(x, u, side="right") - 1, 0, n - 1)
    x0, x1 = xe[i + 1], xe[i + 2]
    y0, y1 = ye[i + 1], ye[i + 2]
    h = x1 - x0
    s = (u - x0) / h
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * y0 + h10 * h * m[i] + h01 * y1 + h11 * h * m[i + 1]


def walk_stride_length(speed: float) -> float:
    """Walking stride length [m] (two steps) at ``speed`` [m/s] (module docstring)."""
    return 1.41 * np.sqrt(max(speed, 1e-6) / 1.3)


def run_stride_frequency(speed: float) -> float:
    """Running stride frequency [Hz] at ``speed`` [m/s] (module docstring)."""
    return 1.25 + 0.04 * speed


@dataclass(frozen=True)
class _GaitStyle:
    hip: tuple
    knee: tuple
    ankle: tuple
    toe_off: float
    pelvic_tilt: float  # [deg]
    lean: float  # trunk lean [deg]
    pelvis_yaw: float  # [deg]
    pelvis_roll: float  # [deg]
    arm_down: float  # [deg]
    arm_gain: float  # shoulder flexion per degree of opposite hip flexion
    elbow: float  # [deg]


_WALK = _GaitStyle(WALK_HIP, WALK_KNEE, WALK_ANKLE, WALK_TOE_OFF, 10.0, 2.0, 4.0, 4.0, 64.0,
                   0.6, 20.0)
_RUN = _GaitStyle(RUN_HIP, RUN_KNEE, RUN_ANKLE, RUN_TOE_OFF, 15.0, 6.0, 5.0, 5.0, 60.0,
                  0.8, 55.0)


def _warp(phase: np.ndarray, duty: float, toe_off: float) -> np.ndarray:
    """Map stride phase to the normative curve's phase so stance lasts ``duty`` of the stride."""
    u = np.mod(phase, 1.0)
    return np.where(u < duty, u * toe_off / duty,
                    toe_off + (u - duty) * (1.0 - toe_off) / (1.0 - duty))


def gait_pose(style: _GaitStyle, phase: np.ndarray, *, duty: float | None = None,
              arm_swing: float = 1.0, hip_scale: float = 1.0) -> np.ndarray:
    """Full-body gait pose at stride phase(s) (0 = right heel strike).

    Args:
        style: walking or running constants.
        phase: stride phase of the right leg, shape (T,).
        duty: stance fraction of the stride (None: the data's own toe-off).
        arm_swing: scale of the arm swing.
        hip_scale: scale of the hip flexion curve about its mean (stride calibration).

    Returns:
        axis-angle [rad], shape (T, 24, 3).
    """
    phase = np.asarray(phase, dtype=np.float64)
    d = style.toe_off if duty is None else duty
    pb = PoseBuilder(phase.shape)
    hips = {}
    lean = style.lean * D2R
    yaw = style.pelvis_yaw * D2R * np.cos(2 * np.pi * phase)  # right hip forward at 0
    roll = -style.pelvis_roll * D2R * np.sin(2 * np.pi * phase)  # swing side drops
    pb.rot("pelvis", "y", yaw).rot("pelvis", "x", lean).rot("pelvis", "z", roll)
    mean_hip = float(np.mean(periodic_curve(style.hip, np.linspace(0, 1, 64, endpoint=False))))
    for side, off in (("right", 0.0), ("left", 0.5)):
        u = _warp(phase + off, d, style.toe_off)
        hips[side] = mean_hip + hip_scale * (periodic_curve(style.hip, u) - mean_hip)
        pb.rot(f"{side}_hip", "z", -roll)
        pb.rot(f"{side}_hip", "x", -(hips[side] - style.pelvic_tilt) * D2R - lean)
        pb.rot(f"{side}_knee", "x", periodic_curve(style.knee, u) * D2R)
        pb.rot(f"{side}_ankle", "x", -periodic_curve(style.ankle, u) * D2R)
    for j in ("spine1", "spine2", "spine3"):
        pb.rot(j, "y", -0.5 * yaw)  # thorax counter-rotates against the pelvis
    pb.rot("neck", "y", 0.5 * yaw).rot("neck", "x", -lean)
    for side, other in (("left", "right"), ("right", "left")):
        flex = arm_swing * style.arm_gain * (hips[other] - mean_hip) * D2R
        sg = 1.0 if side == "left" else -1.0
        pb.rot(f"{side}_shoulder", "z", -sg * style.arm_down * D2R)
        pb.rot(f"{side}_shoulder", "x", -flex)
        pb.rot(f"{side}_elbow", "y", -sg * (style.elbow * D2R + 0.3 * np.maximum(flex, 0.0)))
    return pb.axis_angle()


def _stance_speed(style: _GaitStyle, duty: float, f: float, hip_scale: float,
                  skeleton: MotionSkeleton | None = None) -> float:
    """Backward speed [m/s] of the right ankle relative to the pelvis in mid-stance (the speed
    the leg can carry the body at, without foot sliding), stride frequency ``f`` [Hz]."""
    ph = np.linspace(0.15 * duty, 0.75 * duty, 16)
    _, P = resolve_skeleton(skeleton).forward_kinematics(
        gait_pose(style, ph, duty=duty, hip_scale=hip_scale))
    z = P[:, 8, 2]  # right ankle
    return float(-(z[-1] - z[0]) / (ph[-1] - ph[0]) * f)


HIP_SCALE_RANGE = (0.2, 2.0)
"""The hip-curve scales ``stride_calibration`` chooses from. A run slower than ~1 m/s (the
running cadence stays above 1.25 strides/s, so its strides are short) needs a swing below half
the curves': with a floor of 0.5 the stance foot slides forward at ~0.5 m/s at a 0.5 m/s jog.
At 0.2 the stance foot still moves backwards (the knee's flexion alone moves it forwards:
the stance speed is ~(1.74 s - 0.12) m per stride, s the scale), and every run down to the
slowest ``RunParams`` allows (0.5 m/s) is within the range."""


def stride_calibration(style: _GaitStyle, duty: float, f: float, speed: float,
                       skeleton: MotionSkeleton | None = None) -> float:
    """Hip-curve scale so the stance foot does not slide at ``speed`` [m/s]: the normative
    curves are for one stride length; longer strides need a larger hip excursion (and the
    reverse). Three fixed-point steps ``s <- s * speed / v(s)``, clipped to ``HIP_SCALE_RANGE``."""
    s = 1.0
    lo, hi = HIP_SCALE_RANGE
    for _ in range(3):
        v = _stance_speed(style, duty, f, s, skeleton)
        if v <= 1e-6:
            break
        s = float(np.clip(s * speed / v, lo, hi))
    return s


HIP_EXTENSION_MARGIN = 1.0 * D2R
"""How far [rad] below the joint-limit table's hip extension (``sim.motions.limits``, 30 deg)
the automatic cadence keeps a gait's peak hip extension (``limited_cadence``)."""

MAX_STRIDE_FREQUENCY = {"walk": 1.75, "run": 2.5}
"""The quickest cadence [strides/s] ``limited_cadence`` raises a gait to: race walkers take about
3.5 steps/s, sprinters about 5 (Weyand et al. 2000, "Faster top running speeds are achieved with
greater ground forces not more rapid leg movements"). A body that would need more (a short body
at a sprint) keeps this cadence and a hip swing past the joint-limit table: an absurd step rate
is the worse error. (Past a swing of 2, where ``stride_calibration`` clips, the stance foot
slides: a short body at 10 m/s.)"""


def hip_extension_limit() -> float:
    """The joint-limit table's hip extension [rad] (the smaller of the two hips')."""
    return float(min(JOINT_LIMITS[JOINT["left_hip"], 0, 1], JOINT_LIMITS[JOINT["right_hip"], 0, 1]))


def peak_hip_extension(style: _GaitStyle, duty: float, hip_scale: float) -> float:
    """Largest hip extension [rad] (the hips' axis-angle X component, extension positive) over a
    stride of the gait at ``hip_scale``, either hip."""
    poses = gait_pose(style, np.linspace(0.0, 1.0, 400, endpoint=False), duty=duty, hip_scale=hip_scale)
    return float(poses[:, [JOINT["left_hip"], JOINT["right_hip"]], 0].max())


@functools.lru_cache(maxsize=64)
def hip_scale_cap(style: _GaitStyle, duty: float) -> float:
    """The largest hip-curve scale whose peak extension stays ``HIP_EXTENSION_MARGIN`` inside the
    joint-limit table (bisection; the extension grows with the scale)."""
    target = hip_extension_limit() - HIP_EXTENSION_MARGIN
    lo, hi = 0.5, HIP_SCALE_RANGE[1]
    if peak_hip_extension(style, duty, hi) <= target:
        return hi  # stride_calibration clips its scale there too (HIP_SCALE_RANGE)
    if peak_hip_extension(style, duty, lo) > target:
        raise RuntimeError(f"gait curves: the hip extension passes the joint limits even at scale {lo} "
                           f"(duty {duty}); the curve tables and the limit table disagree")
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if peak_hip_extension(style, duty, mid) <= target else (lo, mid)
    return lo


def limited_cadence(style: _GaitStyle, duty: float, f: float, speed: float,
                    skeleton: MotionSkeleton | None = None,
                    f_max: float = float("inf")) -> tuple[float, float]:
    """Stride frequency [Hz] and hip-curve scale of a gait at ``speed`` [m/s] whose stance foot
    does not slide and whose hips stay inside the joint limits.

    At the automatic cadence ``f`` a short-legged body needs a larger hip excursion for the
    same speed (``stride_calibration``): the run at 3.5 m/s reached 35 deg of hip extension on the
    default body and 49 deg on a short one (betas[0] = -2), past the 30 deg of the joint-limit
    table and far past the 10-20 deg runners use. Where the calibrated scale would pass
    ``hip_scale_cap``, the cadence rises instead, as shorter runners' does: the scale is held at
    the cap and the frequency is the one at which the stance foot, swept at that scale, moves at
    ``speed`` (the stance speed is proportional to the frequency), so the foot still does not
    slide. The cadence rises to ``f_max`` [Hz] at most (``MAX_STRIDE_FREQUENCY``); a gait that
    would need more takes ``f_max`` and the swing that frequency needs, past the cap."""
    k = stride_calibration(style, duty, f, speed, skeleton)
    cap = hip_scale_cap(style, duty)
    if k <= cap:
        return f, k
    per_hz = _stance_speed(style, duty, 1.0, cap, skeleton)
    if per_hz <= 1e-6:
        raise RuntimeError(f"gait: the stance foot does not move at hip scale {cap} (duty {duty})")
    f_limited = speed / per_hz
    if f_limited <= f_max:
        return f_limited, cap
    f_top = max(f, f_max)
    return f_top, stride_calibration(style, duty, f_top, speed, skeleton)


def gait_record() -> dict:
    """What shapes the procedural walks and runs beyond their parameters, for a dataset's record
    of its simulator defaults (``sim.simulate.simulator_defaults``): the cadence rule, its
    margin, ceiling and hip limit, and a digest of the gait curves, so that a dataset is not
    continued with other motions."""
    curves = repr((_WALK, _RUN, WALK_HIP, RUN_HIP)).encode()
    return {"cadence": "hip-limited", "hip_extension_margin_rad": HIP_EXTENSION_MARGIN,
            "hip_extension_limit_rad": hip_extension_limit(),
            "max_stride_frequency": dict(MAX_STRIDE_FREQUENCY), "hip_scale_range": list(HIP_SCALE_RANGE),
            "curves_sha1": hashlib.sha1(curves).hexdigest()}


def ramped_phase(w: np.ndarray, rate: float, fps: float, lead: int) -> np.ndarray:
    """Integral of ``rate * w(t)`` over frames at ``fps``, 0 at frame ``lead`` (t = 0).

    Each step advances by ``rate * w / fps`` at the step's first frame, so from t = 0 (w = 1)
    the value is exactly ``rate * t``, and in the lead-in before it (``w`` easing up from 0)
    the speed rises smoothly to ``rate``.

    Args:
        w: the lead-in's ease per frame (``procedural.lead_weight``), 1 from frame ``lead``.
        rate: the value's rate at full motion (stride frequency [1/s], speed [m/s]).
        fps: frame rate [1/s].
        lead: frames of the lead-in.
    """
    out = np.empty(w.size)
    out[lead:] = rate * np.arange(w.size - lead) / fps
    out[:lead] = -rate * np.cumsum(w[:lead][::-1])[::-1] / fps
    return out


@dataclass(frozen=True)
class WalkParams:
    """Attributes: duration [s]; fps [1/s]; speed: forward speed along +Z [m/s]; stride: stride
    length (two steps) [m], 0 for the speed-dependent default (whose cadence rises where the
    body's hips would pass their joint limits: ``limited_cadence``); a stride given is kept at
    whatever hip swing it takes, inside the limits or not; arm_swing: arm swing scale (0
    keeps the arms still); ramp: lead-in before t = 0 from the rest T-pose up to full speed and
    pose [s] (played in a simulation's prelude, not part of duration)."""

    duration: float = 4.0
    fps: float = 30.0
    speed: float = 1.3
    stride: float = 0.0
    arm_swing: float = 1.0
    ramp: float = 1.0

    def __post_init__(self) -> None:
        check_params(self, speed=(0.0, 3.0), stride=(0.0, 3.0), arm_swing=(0.0, 3.0),
                     ramp=(1e-3, 1e5))


def walk(p: WalkParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """Straight walk along +Z from normative gait curves (see the module docstring), at full
    speed from t = 0, where the right heel strikes at z = 0 (the lead-in walks up to it)."""
    n = lead_frames(p.ramp, p.fps)
    t = time_axis(p.duration, p.fps, n)
    w = lead_weight(t, n, p.fps)
    stride = p.stride if p.stride > 0 else walk_stride_length(p.speed)
    f = f_auto = p.speed / stride
    if p.speed <= 0:
        k = 1.0
    elif p.stride > 0:  # the stride asked for, at whatever hip swing it takes
        k = stride_calibration(_WALK, WALK_TOE_OFF, f, p.speed, skeleton)
    else:
        f, k = limited_cadence(_WALK, WALK_TOE_OFF, f, p.speed, skeleton, MAX_STRIDE_FREQUENCY["walk"])
        stride = p.speed / f
    phase = ramped_phase(w, f, p.fps, n)
    poses = w[:, None, None] * gait_pose(_WALK, phase, arm_swing=p.arm_swing, hip_scale=k)
    trans = np.zeros((t.size, 3))
    trans[:, 2] = ramped_phase(w, p.speed, p.fps, n)
    trans[:, 1] = ground_trans_y(poses, skeleton)
    return make_motion("walk", p, poses, trans, lead=n, phase=phase.astype(np.float32),
                       stride_frequency=f, stride_length=stride, toe_off=WALK_TOE_OFF,
                       hip_scale=k, cadence_raised=f / f_auto if f_auto > 0 else 1.0)


@dataclass(frozen=True)
class RunParams:
    """Attributes: duration [s]; fps [1/s]; speed: forward speed along +Z [m/s]; stride: stride
    length [m], 0 for the speed-dependent default (whose cadence rises where the body's hips
    would pass their joint limits: ``limited_cadence``); a stride given is kept at whatever hip
    swing it takes, inside the limits or not; duty: stance fraction of the stride (< 0.5
    gives a flight phase); arm_swing: arm swing scale; ramp: lead-in before t = 0 from the rest
    T-pose up to full speed and pose [s] (played in a simulation's prelude, not part of duration)."""

    duration: float = 4.0
    fps: float = 30.0
    speed: float = 3.5
    stride: float = 0.0
    duty: float = 0.35
    arm_swing: float = 1.0
    ramp: float = 1.0

    def __post_init__(self) -> None:
        check_params(self, speed=(0.5, 10.0), stride=(0.0, 6.0), duty=(0.2, 0.49),
                     arm_swing=(0.0, 3.0), ramp=(1e-3, 1e5))


def spring_mass_height(step_time: np.ndarray, t_stance: float, t_flight: float) -> np.ndarray:
    """Root height [m] relative to touchdown over a running step (module docstring).

    Args:
        step_time: time since the last touchdown [s], shape (...,), in [0, t_stance + t_flight).
        t_stance, t_flight: contact and flight times of one step [s].
    """
    v0 = 0.5 * GRAVITY * t_flight
    omega = np.pi / t_stance
    tau = np.asarray(step_time, dtype=np.float64)
    stance = -(v0 / omega) * np.sin(omega * np.minimum(tau, t_stance))
    tf = np.maximum(tau - t_stance, 0.0)
    return np.where(tau < t_stance, stance, v0 * tf - 0.5 * GRAVITY * tf**2)


def run(p: RunParams, skeleton: MotionSkeleton | None = None) -> Motion:
    """Straight run along +Z: normative running curves time-warped to ``duty``, spring-mass
    vertical motion with a ballistic flight phase, forward trunk lean, bent-elbow arm swing; at
    full speed from t = 0, where the right foot touches down at z = 0."""
    n = lead_frames(p.ramp, p.fps)
    t = time_axis(p.duration, p.fps, n)
    w = lead_weight(t, n, p.fps)
    f = f_auto = p.speed / p.stride if p.stride > 0 else run_stride_frequency(p.speed)
    if p.stride > 0:  # the stride asked for, at whatever hip swing it takes
        k = stride_calibration(_RUN, p.duty, f, p.speed, skeleton)
    else:
        f, k = limited_cadence(_RUN, p.duty, f, p.speed, skeleton, MAX_STRIDE_FREQUENCY["run"])
    phase = ramped_phase(w, f, p.fps, n)
    poses = w[:, None, None] * gait_pose(_RUN, phase, duty=p.duty, arm_swing=p.arm_swing,
                                         hip_scale=k)
    t_stance, t_flight = p.duty / f, (0.5 - p.duty) / f
    y_td = float(ground_trans_y(gait_pose(_RUN, np.zeros(1), duty=p.duty, hip_scale=k),
                                skeleton)[0])
    step_time = np.mod(phase, 0.5) / f
    y_run = y_td + spring_mass_height(step_time, t_stance, t_flight)
    trans = np.zeros((t.size, 3))
    trans[:, 2] = ramped_phase(w, p.speed, p.fps, n)
    ground = ground_trans_y(poses, skeleton)
    # the spring-mass stance dips deeper than the normative leg curves flex (2-4 cm): raise it
    # wherever it would push the stance foot into the floor (flight stays ballistic)
    trans[:, 1] = np.maximum((1.0 - w) * ground + w * y_run, ground)
    return make_motion("run", p, poses, trans, lead=n, phase=phase.astype(np.float32),
                       stride_frequency=f, stride_length=p.speed / f, duty=p.duty,
                       t_stance=t_stance, t_flight=t_flight, hip_scale=k, cadence_raised=f / f_auto)
