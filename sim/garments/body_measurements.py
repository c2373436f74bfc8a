"""Tailor's measurements of a body at rest: girths, lengths, and the landmarks patterns are placed by.

A girth is what a tape measure reads: the perimeter of the convex hull of the body's section by
a plane (the tape bridges hollows), the section cut from the triangles themselves, so it does not
depend on where the vertices happen to lie. Regions come from the skinning weights: a face
belongs to an arm or a leg when the joints of that limb (the shoulder or hip and everything
below it in the kinematic tree) carry most of its vertices' weight. Landmarks follow ISO 8559-1
where the smooth mesh allows (it has no bones to palpate; each field says how it is found).

Everything is in metres, in the rest mesh's own frame (SMPL convention: T-pose, Y up, facing
+Z, the body's left at +x); heights are y coordinates in that frame, not heights above the
floor (``floor_height`` is the soles' level).
"""

from __future__ import annotations

import ast
import inspect
from dataclasses import dataclass, fields
from functools import cache

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from sim.errors import WrinklesInputError

STEP = 0.004
"""Height step of the horizontal scans that find girth extrema and landmarks [m]; an extremum's
girth is off by a second-order amount of it (well under a millimetre)."""
TURN_SLOPE = 1.0
"""Slope of the body's outline (change across / change along the scan) where a corner is taken:
45°, halfway between the torso's side and the arm's underside (armpit) and between the neck's
side and the shoulder's top (side neck point)."""
THIGH_DROP = 0.02
"""Thigh girth is taken this far below the crotch [m], just under the gluteal fold."""
SIDES = ("left", "right")
UP = (0.0, 1.0, 0.0)
JOINTS_READ = ("pelvis", "spine2", "neck", "head") + tuple(
    f"{s}_{j}" for s in SIDES for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle"))
"""SMPL joints the measurements read (SMPL-H and SMPL-X share them)."""
ARM_JOINTS = tuple(range(16, 24))
"""SMPL shoulders, elbows, wrists and hands (even: left, odd: right): a vertex these carry most
of the skinning weight of is an arm's, the rest is the torso's (drafting's region masks)."""


@dataclass(frozen=True)
class TorsoExtent:
    """The torso's horizontal section at one level, arms left out [m]."""

    center: np.ndarray
    """(x, z) centre of the section's bounding box."""
    width: float
    """Side-to-side extent (x)."""
    depth: float
    """Front-to-back extent (z)."""


@dataclass(frozen=True)
class BodyMeasurements:
    """A body's tailor's measurements and landmarks at rest [m] (see the module docstring)."""

    neck_base: float
    """Neck base girth: a closed tape over the cervicale, both side neck points and the jugular
    notch (not planar: the front drops to the notch), bridging hollows horizontally."""
    chest: float
    """Chest girth: fullest horizontal girth from 10 to 2 cm below the armpit, arms left out."""
    waist: float
    """Natural waist girth: narrowest horizontal torso girth between the pelvis joint (hip bone
    level) and the spine2 joint (lowest ribs)."""
    hip: float
    """Hip girth: fullest horizontal girth between the crotch and the waist, both legs in."""
    bicep: float
    """Upper arm girth: fullest girth perpendicular to the upper arm's axis (shoulder to elbow
    joint), from 2 cm past the armpit to 3 cm before the elbow; mean of both arms."""
    elbow: float
    """Elbow girth: perpendicular to the arm at the elbow joint; mean of both arms."""
    wrist: float
    """Wrist girth: narrowest girth perpendicular to the forearm within 5 cm above the wrist
    joint; mean of both arms."""
    thigh: float
    """Thigh girth: one leg's horizontal girth 2 cm below the crotch; mean of both legs."""
    knee: float
    """Knee girth: one leg's horizontal girth at the knee joint; mean of both legs."""
    calf: float
    """Calf girth: one leg's fullest horizontal girth between 5 cm below the knee joint and 5 cm
    above the ankle joint; mean of both legs."""
    ankle: float
    """Ankle girth: one leg's narrowest horizontal girth between 1.5 cm above the ankle joint and
    the calf; mean of both legs."""
    shoulder_width: float
    """Shoulder width: straight distance between the two shoulder points (biacromial breadth),
    not the longer arc over the back."""
    arm_length: float
    """Arm length: shoulder point to the wrist joint along the arm's axis (shoulder to wrist
    joint), straight as the T-pose arm is; mean of both arms."""
    back_length: float
    """Back waist length: a taut tape down the back's centre line from the nape to the waist
    level, bridging the back's hollows."""
    front_length: float
    """Centre front waist length: a taut tape down the front's centre line from the jugular notch
    to the waist level, bridging hollows."""
    inseam: float
    """Inside leg to the ankle: crotch level minus ankle level (vertical; to the floor add
    ``ankle_height - floor_height``)."""
    rise: float
    """Body rise: waist level minus crotch level (vertical)."""
    outseam: float
    """Outside leg to the ankle: waist level minus ankle level (vertical), ``rise + inseam``."""
    neck_to_shoulder: float
    """Shoulder length: straight distance from the side neck point to the shoulder point; mean
    of both sides."""
    neck_base_height: float
    """Height of the side neck points: where the outline seen from the front turns from the
    neck's side to the shoulder's top (45°)."""
    shoulder_height: float
    """Height of the shoulder points (mean of both)."""
    armpit_height: float
    """Height of the armpits: where the outline seen from the front turns from the torso's side
    to the arm's underside (45°, the last turn below the arm); mean of both sides."""
    chest_height: float
    """Height of the chest girth."""
    waist_height: float
    """Height of the natural waist girth."""
    hip_height: float
    """Height of the hip girth."""
    crotch_height: float
    """Lowest point where the body's surface crosses the mid-sagittal plane between the knees and
    the hips."""
    knee_height: float
    """Height of the knee joints (mean of both)."""
    ankle_height: float
    """Height of the ankle joints (mean of both), the level trousers are measured to."""
    floor_height: float
    """Lowest point of the body (the soles)."""
    shoulder_points: np.ndarray
    """(2, 3) left and right shoulder points (acromion): the body's upper surface straight above
    each shoulder joint."""
    side_neck_points: np.ndarray
    """(2, 3) left and right side neck points, at ``neck_base_height``."""
    nape_point: np.ndarray
    """(3,) back neck point (cervicale) on the back's centre line at the side neck points' height
    (the smooth mesh has no vertebra to find)."""
    front_neck_point: np.ndarray
    """(3,) front neck point (jugular notch): the deepest point of the front's centre line between
    the armpits' and the side neck points' height."""
    armpit_points: np.ndarray
    """(2, 3) left and right armpit points, at the turn that sets ``armpit_height``."""
    wrist_x: float
    """|x| of the wrist joints (mean of both): where a long sleeve ends in the T-pose."""
    leg_axis_x: np.ndarray
    """(2,) x of each leg's axis (left, right): the centre of the thigh section's bounding box."""
    chest_extent: TorsoExtent
    """Torso section at the chest height."""
    waist_extent: TorsoExtent
    """Torso section at the waist height."""
    hip_extent: TorsoExtent
    """Section at the hip height (both legs in)."""
    sides: dict
    """Each limb girth (bicep, elbow, wrist, thigh, knee, calf, ankle) and ``arm_length`` per
    side: name -> (left, right)."""

    def to_dict(self) -> dict:
        """Plain JSON-ready values: floats, lists, and dicts for the torso extents."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, TorsoExtent):
                v = {"center": v.center.tolist(), "width": v.width, "depth": v.depth}
            elif isinstance(v, np.ndarray):
                v = v.tolist()
            elif isinstance(v, dict):
                v = {k: list(x) for k, x in v.items()}
            out[f.name] = v
        return out


@cache
def measurement_notes() -> dict[str, str]:
    """How each ``BodyMeasurements`` field is taken: its docstring, by field name."""
    try:
        node = ast.parse(inspect.getsource(BodyMeasurements)).body[0]
    except (OSError, TypeError):  # installed without its sources
        return {}
    notes = {}
    for a, b in zip(node.body, node.body[1:], strict=False):
        if (isinstance(a, ast.AnnAssign) and isinstance(b, ast.Expr)
                and isinstance(b.value, ast.Constant) and isinstance(b.value.value, str)):
            notes[a.target.id] = " ".join(b.value.value.split())
    return notes


# ----------------------------------------------------------------------------- sections


def plane_segments(vertices: np.ndarray, faces: np.ndarray, origin, normal,
                   mask: np.ndarray | None = None) -> np.ndarray:
    """The section of a triangle mesh by a plane, one segment per crossing face.

    A vertex on the plane counts as being on its positive side, so every face that reaches
    both sides gives exactly two edge crossings.

    Args:
        vertices: (V, 3) [m]. faces: (F, 3). origin: a point of the plane. normal: its normal.
        mask: (F,) bool, the faces that count (all when None).

    Returns:
        (K, 2, 3) segment ends [m].
    """
    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    if mask is not None:
        faces = faces[mask]
    d = (np.asarray(vertices, np.float64) - np.asarray(origin, np.float64)) @ n
    neg = d < 0
    fn = neg[faces]
    hit = fn.any(axis=1) & ~fn.all(axis=1)
    return face_crossings(vertices, faces[hit], d)


def face_crossings(vertices: np.ndarray, faces: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(K, 2, 3) where faces that reach both sides of a plane cross it, given the vertices'
    signed distances ``d`` (V,) [m] (d >= 0 counts as the positive side)."""
    neg = d[faces] < 0
    # the vertex alone on its side; the face crosses on its two edges
    k = np.where(neg.sum(axis=1) == 1, np.argmax(neg, axis=1), np.argmin(neg, axis=1))
    rows = np.arange(len(faces))
    i0, i1, i2 = faces[rows, k], faces[rows, (k + 1) % 3], faces[rows, (k + 2) % 3]
    d0 = d[i0]
    p0 = vertices[i0]
    t1 = (d0 / (d0 - d[i1]))[:, None]
    t2 = (d0 / (d0 - d[i2]))[:, None]
    return np.stack([p0 + t1 * (vertices[i1] - p0), p0 + t2 * (vertices[i2] - p0)], axis=1)


class Slicer:
    """Sections of a mesh's faces by planes normal to one axis. Faces are binned by their
    extent along the axis, so a plane looks only at the faces of its bin."""

    BIN = 0.01
    """Bin width along the axis [m]."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, axis) -> None:
        self.vertices, self.faces = vertices, faces
        self.axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
        self.basis = plane_basis(self.axis)
        self.t = vertices @ self.axis
        tf = self.t[faces]
        self.lo, self.hi = tf.min(axis=1), tf.max(axis=1)
        self.t0 = float(self.lo.min()) if len(faces) else 0.0
        b0 = ((self.lo - self.t0) // self.BIN).astype(np.int64)
        n = ((self.hi - self.t0) // self.BIN).astype(np.int64) - b0 + 1
        face = np.repeat(np.arange(len(faces)), n)
        bins = np.repeat(b0, n) + np.arange(len(face)) - np.repeat(np.cumsum(n) - n, n)
        order = np.argsort(bins, kind="stable")
        self.members = face[order]
        self.starts = np.searchsorted(bins[order], np.arange(int(bins.max(initial=0)) + 2))

    def segments(self, t: float) -> np.ndarray:
        """(K, 2, 3) section by the plane at ``t`` [m] along the axis."""
        b = int((t - self.t0) // self.BIN)
        if b < 0 or b + 1 >= len(self.starts):
            return np.zeros((0, 2, 3))
        f = self.members[self.starts[b]:self.starts[b + 1]]
        f = f[(self.lo[f] < t) & (self.hi[f] >= t)]
        return face_crossings(self.vertices, self.faces[f], self.t - t)

    def points(self, t: float) -> np.ndarray:
        """(K, 3) section points by the plane at ``t`` [m] along the axis."""
        return self.segments(t).reshape(-1, 3)

    def girth(self, t: float) -> float:
        """Tape-measure girth [m] at ``t`` along the axis (0.0 where the plane misses)."""
        p = self.points(t)
        return hull_perimeter(p @ self.basis.T) if len(p) else 0.0


def plane_basis(normal) -> np.ndarray:
    """(2, 3) orthonormal in-plane axes of a plane with this normal."""
    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    e = np.eye(3)[int(np.argmin(np.abs(n)))]
    u = np.cross(n, e)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(n, u)])


def hull_perimeter(points_2d: np.ndarray) -> float:
    """Perimeter of the convex hull of 2D points [m] (twice the length of a collinear set)."""
    p = np.asarray(points_2d, np.float64)
    if len(p) < 2:
        return 0.0
    try:
        return float(ConvexHull(p).area)  # a 2D hull's "area" is its perimeter
    except QhullError:
        return 2.0 * float(np.linalg.norm(np.ptp(p, axis=0)))


def cross_section_perimeter(vertices: np.ndarray, faces: np.ndarray, origin, normal,
                            mask: np.ndarray | None = None) -> float:
    """Tape-measure girth of a mesh: perimeter of the convex hull of its section by a plane [m].

    Args:
        vertices: (V, 3) [m]. faces: (F, 3) triangles.
        origin: a point of the plane, (3,). normal: the plane's normal, (3,).
        mask: (F,) bool, the faces that count (all when None).

    Returns:
        the perimeter, 0.0 where the plane misses the (masked) mesh.
    """
    seg = plane_segments(vertices, faces, origin, normal, mask)
    if not len(seg):
        return 0.0
    return hull_perimeter(seg.reshape(-1, 3) @ plane_basis(normal).T)


def hull_2d(points_2d: np.ndarray) -> np.ndarray:
    """Convex hull vertices (K, 2), counter-clockwise."""
    return points_2d[ConvexHull(points_2d).vertices]


def taut_length(along: np.ndarray, out: np.ndarray) -> float:
    """Length of a taut tape laid over a profile: the outer convex chain of the points
    (``along``, ``out``) from the first ``along`` to the last, bulging toward larger ``out`` [m]
    (Andrew's monotone chain)."""
    order = np.argsort(along, kind="stable")
    p = np.stack([along[order], out[order]], axis=1)
    chain: list[np.ndarray] = []
    for q in p:
        while len(chain) >= 2:
            a, b = chain[-2], chain[-1]
            if (b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0]) >= 0:
                chain.pop()  # b lies on or under the chord a-q
            else:
                break
        chain.append(q)
    c = np.asarray(chain)
    return float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum())


# ----------------------------------------------------------------------------- the body


def descendants(parents: np.ndarray, root: int) -> list[int]:
    """``root`` and every joint below it in the kinematic tree (parents[j] < j)."""
    out = [root]
    for j in range(root + 1, len(parents)):
        if parents[j] in out:
            out.append(j)
    return out


@dataclass(frozen=True)
class RestBody:
    """A body at rest with the face regions the measurements read."""

    vertices: np.ndarray  # (V, 3) [m]
    faces: np.ndarray  # (F, 3)
    joints: np.ndarray  # (J, 3) [m]
    joint: dict  # name -> index
    torso: np.ndarray  # (F,) faces of neither arm
    arms: tuple  # (left, right) (F,) faces of each arm
    legs: tuple  # (left, right) (F,) faces on each leg's side (the leg below the crotch)

    @classmethod
    def of(cls, body, betas: np.ndarray | None = None) -> RestBody:
        v = np.asarray(body.rest_mesh(betas), np.float64)
        f = np.asarray(body.faces, np.int64)
        w = np.asarray(body.weights, np.float64)
        parents = np.asarray(body.parents)
        names = {n: i for i, n in enumerate(body.joint_names)}
        missing = [n for n in JOINTS_READ if n not in names]
        if missing:
            raise WrinklesInputError(f"body {body.name!r} has no joint {missing[0]!r}; measuring "
                                     "needs SMPL's joint names", path=body.source or None)

        def region(root: str) -> np.ndarray:
            return w[:, descendants(parents, names[root])].sum(axis=1)[f].mean(axis=1)

        arm_l, arm_r = region("left_shoulder"), region("right_shoulder")
        leg_l, leg_r = region("left_hip"), region("right_hip")
        # left or right leg by the larger weight; faces neither leg moves (the torso) by side
        left = (leg_l > leg_r) | ((leg_l == leg_r) & (v[f, 0].mean(axis=1) >= 0))
        return cls(v, f, np.asarray(body.rest_joints(betas), np.float64), names,
                   (arm_l + arm_r) < 0.5, (arm_l > 0.5, arm_r > 0.5), (left, ~left))

    def j(self, name: str) -> np.ndarray:
        return self.joints[self.joint[name]]

    def slicer(self, mask: np.ndarray, axis=UP) -> Slicer:
        """Sections of the masked faces by planes normal to ``axis`` (horizontal by default)."""
        return Slicer(self.vertices, self.faces[mask], axis)


@dataclass(frozen=True)
class Levels:
    """Horizontal torso sections (arms left out) every ``STEP`` from ``ys[0]`` up."""

    ys: np.ndarray  # (L,) [m]
    hulls: list  # L convex hulls (K, 2) in (x, z), counter-clockwise
    girth: np.ndarray  # (L,) the hulls' perimeters [m]
    midline: np.ndarray  # (L, 2) front and back z where each hull crosses x = 0 [m]

    @classmethod
    def scan(cls, rest: RestBody, lo: float, hi: float) -> Levels:
        ys = np.arange(lo, hi + STEP, STEP)
        sl = rest.slicer(rest.torso)
        hulls = []
        for y in ys:
            p = sl.points(float(y))[:, [0, 2]]
            if len(p) < 3 or np.ptp(p[:, 0]) <= 0 or np.ptp(p[:, 1]) <= 0:
                raise WrinklesInputError(f"cannot measure this body: its torso has no section at "
                                         f"height {y:.3f} m")
            hulls.append(hull_2d(p))
        girth = np.array([np.linalg.norm(h - np.roll(h, 1, axis=0), axis=1).sum() for h in hulls])
        return cls(ys, hulls, girth, np.array([midline_crossings(h) for h in hulls]))

    def index(self, y: float) -> int:
        return int(np.clip(np.rint((y - self.ys[0]) / STEP), 0, len(self.ys) - 1))

    def span(self, lo: float, hi: float) -> np.ndarray:
        """Level indices from ``lo`` to ``hi`` [m]."""
        return np.arange(self.index(lo), self.index(hi) + 1)

    def extent(self, i: int) -> TorsoExtent:
        lo, hi = self.hulls[i].min(axis=0), self.hulls[i].max(axis=0)
        return TorsoExtent(0.5 * (lo + hi), float(hi[0] - lo[0]), float(hi[1] - lo[1]))


def midline_crossings(hull: np.ndarray) -> tuple[float, float]:
    """(front z, back z) [m] where a convex polygon (K, 2) in (x, z) crosses x = 0."""
    a, b = hull, np.roll(hull, -1, axis=0)
    cross = (a[:, 0] < 0) != (b[:, 0] < 0)
    a, b = a[cross], b[cross]
    z = a[:, 1] + (b[:, 1] - a[:, 1]) * (-a[:, 0] / (b[:, 0] - a[:, 0]))
    return float(z.max()), float(z.min())


def midplane_crossings(vertices: np.ndarray, faces: np.ndarray,
                       y_range: tuple[float, float] | None = None) -> np.ndarray:
    """Points (K, 3) where the mesh's edges cross the mid-sagittal plane x = 0, interpolated
    along the edge; with ``y_range`` (lo, hi) only edges whose both ends lie strictly within it."""
    e = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    a, b = vertices[e[:, 0]], vertices[e[:, 1]]
    cross = a[:, 0] * b[:, 0] < 0
    if y_range is not None:
        cross &= (np.minimum(a[:, 1], b[:, 1]) > y_range[0]) & (np.maximum(a[:, 1], b[:, 1]) < y_range[1])
    a, b = a[cross], b[cross]
    t = a[:, 0] / (a[:, 0] - b[:, 0])
    return a + t[:, None] * (b - a)


def crotch_level(rest: RestBody) -> float:
    """Lowest point where the surface crosses x = 0 between the knees and the hips [m]."""
    lo, hi = rest.j("left_knee")[1], rest.j("left_hip")[1] + 0.05
    p = midplane_crossings(rest.vertices, rest.faces, (lo, hi))
    if not len(p):
        raise WrinklesInputError("cannot find the crotch of this body (no surface crosses the "
                                 "mid-plane between the knees and the hips)")
    return float(p[:, 1].min())


def outline_turn(widths: np.ndarray, what: str) -> int:
    """First step along a scan where the outline's width grows by ``TURN_SLOPE`` or more per
    unit scanned (the outline has turned past 45°)."""
    k = np.nonzero(np.diff(widths) / STEP >= TURN_SLOPE)[0]
    if not len(k):
        raise WrinklesInputError(f"cannot find the {what} of this body (its outline never turns)")
    return int(k[0])


def armpit_point(rest: RestBody, side: int) -> np.ndarray:
    """(3,) Where the front-view outline turns from the torso's side to the arm's underside:
    scanning down from the first height whose outline reaches halfway along the upper arm, the
    top of the first step steeper than 45°."""
    s = 1.0 if side == 0 else -1.0
    name = SIDES[side]
    sl = rest.slicer(rest.torso | rest.arms[side])
    ys = np.arange(rest.j("spine2")[1], rest.j(f"{name}_shoulder")[1], STEP)
    outer = []
    for y in ys:
        p = sl.points(float(y))
        outer.append(p[np.argmax(s * p[:, 0])])
    outer = np.asarray(outer)
    w = s * outer[:, 0]
    reach = 0.5 * s * (rest.j(f"{name}_shoulder")[0] + rest.j(f"{name}_elbow")[0])
    arm = np.nonzero(w > reach)[0]
    steep = np.nonzero(np.diff(w[:arm[0] + 1]) / STEP < TURN_SLOPE)[0] if len(arm) else []
    if not len(steep):
        raise WrinklesInputError("cannot find the armpits of this body (its outline never turns "
                                 "from the torso to the arm)")
    return outer[steep[-1] + 1]


def shoulder_point(rest: RestBody, side: int) -> np.ndarray:
    """(3,) The body's upper surface straight above the shoulder joint."""
    j = rest.j(f"{SIDES[side]}_shoulder")
    seg = plane_segments(rest.vertices, rest.faces, j, (1.0, 0.0, 0.0), rest.torso | rest.arms[side])
    z0, z1 = seg[:, 0, 2] - j[2], seg[:, 1, 2] - j[2]
    cross = (z0 < 0) != (z1 < 0)
    t = z0[cross] / (z0[cross] - z1[cross])
    y = seg[cross, 0, 1] + t * (seg[cross, 1, 1] - seg[cross, 0, 1])
    return np.array([j[0], float(y.max()), j[2]])


@dataclass(frozen=True)
class Neck:
    """Neck base landmarks: side neck points (left, right), nape and front neck point [m]."""

    sides: np.ndarray  # (2, 3)
    nape: np.ndarray  # (3,)
    front: np.ndarray  # (3,)
    girth: float


def neck_landmarks(rest: RestBody, lv: Levels, armpit_y: float) -> Neck:
    """Side neck points where the outline turns from the neck's side to the shoulder's top; the
    nape on the back's centre line at their height; the jugular notch, the deepest point of the
    front's centre line below them; and the neck base girth through all four."""
    yn, yh = rest.j("neck")[1], rest.j("head")[1]
    g = lv.girth
    top = lv.span(yn, 0.5 * (yn + yh))
    i_neck = int(top[np.argmin(g[top])])
    down = np.arange(i_neck, lv.index(armpit_y) - 1, -1)
    half = np.array([0.5 * np.ptp(lv.hulls[i][:, 0]) for i in down])
    i_side = int(down[outline_turn(half, "side neck point")])
    h = lv.hulls[i_side]
    y_side = float(lv.ys[i_side])
    sides = np.array([[h[k, 0], y_side, h[k, 1]] for k in (np.argmax(h[:, 0]), np.argmin(h[:, 0]))])
    nape = np.array([0.0, y_side, lv.midline[i_side, 1]])
    below = lv.span(armpit_y, y_side)
    zf = lv.midline[below, 0]
    flat = below[zf <= zf.min() + 0.001]  # a level bottom of the hollow: take its middle
    i_notch = lv.index(float(lv.ys[flat].mean()))
    front = np.array([0.0, float(lv.ys[i_notch]), lv.midline[i_notch, 0]])
    return Neck(sides, nape, front, neck_base_girth(lv, i_side, front[1]))


def polar_hits(poly_xz: np.ndarray, center: np.ndarray, theta: np.ndarray):
    """Ray casts from ``center`` at angles ``theta`` against the closed polygon ``poly_xz``.

    Returns:
        (r, edge, s): distance to the nearest hit, the polygon edge hit and the parameter
        along it (edge k runs from vertex k to k + 1, cyclically).
    """
    d = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    a = poly_xz - center
    e = np.roll(a, -1, axis=0) - a
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (a[None, :, 0] * e[None, :, 1] - a[None, :, 1] * e[None, :, 0]) / den
        s = (a[None, :, 0] * d[:, None, 1] - a[None, :, 1] * d[:, None, 0]) / den
    ok = (s >= -1e-9) & (s <= 1 + 1e-9) & (t > 0)
    tt = np.where(ok, t, np.inf)
    edge = tt.argmin(axis=1)
    rows = np.arange(len(theta))
    return tt[rows, edge], edge, np.clip(s[rows, edge], 0.0, 1.0)


def neck_base_girth(lv: Levels, i_side: int, y_front: float, n: int = 180) -> float:
    """Length of a closed tape around the neck base [m]: level with the side neck points (level
    ``i_side``) at the sides and the back, dropping as sin² of the angle from the side to
    ``y_front`` at the front; at each angle the tape lies on that height's section hull."""
    h = lv.hulls[i_side]
    c = np.array([0.0, 0.5 * (h[:, 1].min() + h[:, 1].max())])
    phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    s = np.sin(phi)
    y = lv.ys[i_side] + (y_front - lv.ys[i_side]) * np.where(s > 0, s * s, 0.0)
    idx = np.array([lv.index(float(v)) for v in y])
    r = np.empty(n)
    for i in np.unique(idx):
        k = idx == i
        r[k] = polar_hits(lv.hulls[i], c, phi[k])[0]
    p = np.stack([c[0] + r * np.cos(phi), lv.ys[idx], c[1] + r * s], axis=1)
    return float(np.linalg.norm(p - np.roll(p, 1, axis=0), axis=1).sum())


def taut_centre_line(lv: Levels, lo: float, hi: float, front: bool) -> float:
    """A taut tape down the centre line (x = 0) between heights ``lo`` and ``hi`` [m], on the
    front or the back."""
    idx = lv.span(lo, hi)
    z = lv.midline[idx, 0 if front else 1]
    return taut_length(lv.ys[idx], z if front else -z)


def extremum(f, lo: float, hi: float, largest: bool) -> tuple[float, float]:
    """(where, value) of the largest or smallest ``f`` on [lo, hi]: a scan every 4 ``STEP``, then
    every ``STEP`` around the best (girths along a limb are smooth at that scale)."""
    pick = np.argmax if largest else np.argmin
    xs = np.arange(lo, max(lo, hi) + 1e-9, 4 * STEP)
    k = int(pick([f(x) for x in xs]))
    xs = np.arange(max(lo, xs[k] - 3 * STEP), max(lo, min(hi, xs[k] + 3 * STEP)) + 1e-9, STEP)
    vals = [f(x) for x in xs]
    k = int(pick(vals))
    return float(xs[k]), float(vals[k])


def arm_measures(rest: RestBody, side: int, armpit: np.ndarray, shoulder: np.ndarray) -> dict:
    """One arm's girths (perpendicular to its bones) and length [m]."""
    name = SIDES[side]
    sh, el, wr = (rest.j(f"{name}_{k}") for k in ("shoulder", "elbow", "wrist"))
    mask = rest.arms[side]  # a plane across the arm also meets the torso and the hips
    upper, fore = rest.slicer(mask, el - sh), rest.slicer(mask, wr - el)
    s0, e0 = float(sh @ upper.axis), float(el @ fore.axis)
    l1, l2 = float(np.linalg.norm(el - sh)), float(np.linalg.norm(wr - el))
    t0 = float((armpit - sh) @ upper.axis) + 0.02
    _, bicep = extremum(lambda t: upper.girth(s0 + t), t0, l1 - 0.03, largest=True)
    _, wrist = extremum(lambda t: fore.girth(e0 + t), l2 - 0.05, l2, largest=False)
    bend = upper.axis + fore.axis
    elbow = cross_section_perimeter(rest.vertices, rest.faces, el, bend, mask)
    reach = (wr - sh) / np.linalg.norm(wr - sh)
    return {"bicep": bicep, "elbow": elbow, "wrist": wrist,
            "arm_length": float((wr - shoulder) @ reach)}


def leg_measures(rest: RestBody, side: int, crotch_y: float) -> dict:
    """One leg's horizontal girths [m] and its axis' x (the thigh section's middle)."""
    name = SIDES[side]
    knee_y, ankle_y = rest.j(f"{name}_knee")[1], rest.j(f"{name}_ankle")[1]
    sl = rest.slicer(rest.legs[side])
    calf_y, calf = extremum(sl.girth, ankle_y + 0.05, knee_y - 0.05, largest=True)
    thigh = sl.points(crotch_y - THIGH_DROP)
    return {"thigh": sl.girth(crotch_y - THIGH_DROP), "knee": sl.girth(knee_y), "calf": calf,
            "ankle": extremum(sl.girth, ankle_y + 0.015, calf_y, largest=False)[1],
            "axis_x": float(0.5 * (thigh[:, 0].min() + thigh[:, 0].max()))}


LIMB_GIRTHS = ("bicep", "elbow", "wrist", "arm_length", "thigh", "knee", "calf", "ankle")
"""Per-side measures: ``BodyMeasurements.sides`` keeps both, the scalar fields their mean."""


def measure_body(body, betas: np.ndarray | None = None) -> BodyMeasurements:
    """A body's tailor's measurements at rest (see ``BodyMeasurements`` for how each is taken).

    Args:
        body: a ``sim.bodies.BodyModel`` (SMPL joint names: the default body, SMPL, SMPL-H, SMPL-X).
        betas: shape coefficients (None: the mean shape).

    Raises:
        WrinklesInputError: a body whose landmarks cannot be found (no SMPL joints, no crotch, no
            armpit or neck turn).
    """
    rest = RestBody.of(body, betas)
    crotch = crotch_level(rest)
    pits = np.array([armpit_point(rest, k) for k in (0, 1)])
    pit_y = float(pits[:, 1].mean())
    lv = Levels.scan(rest, crotch + STEP, 0.5 * (rest.j("neck")[1] + rest.j("head")[1]) + STEP)
    g = lv.girth
    i_chest = (s := lv.span(pit_y - 0.10, pit_y - 0.02))[np.argmax(g[s])]
    i_waist = (s := lv.span(rest.j("pelvis")[1], rest.j("spine2")[1]))[np.argmin(g[s])]
    i_hip = (s := lv.span(crotch + STEP, lv.ys[i_waist]))[np.argmax(g[s])]
    waist_y = float(lv.ys[i_waist])
    neck = neck_landmarks(rest, lv, pit_y)
    shoulders = np.array([shoulder_point(rest, k) for k in (0, 1)])
    arms = [arm_measures(rest, k, pits[k], shoulders[k]) for k in (0, 1)]
    legs = [leg_measures(rest, k, crotch) for k in (0, 1)]
    sides = {k: (float((arms[0] | legs[0])[k]), float((arms[1] | legs[1])[k])) for k in LIMB_GIRTHS}
    mean = {k: 0.5 * (a + b) for k, (a, b) in sides.items()}
    ankle_y = float(0.5 * (rest.j("left_ankle")[1] + rest.j("right_ankle")[1]))
    return BodyMeasurements(
        neck_base=neck.girth, chest=float(g[i_chest]), waist=float(g[i_waist]), hip=float(g[i_hip]),
        bicep=mean["bicep"], elbow=mean["elbow"], wrist=mean["wrist"], thigh=mean["thigh"],
        knee=mean["knee"], calf=mean["calf"], ankle=mean["ankle"],
        shoulder_width=float(np.linalg.norm(shoulders[0] - shoulders[1])),
        arm_length=mean["arm_length"],
        back_length=taut_centre_line(lv, waist_y, float(neck.nape[1]), front=False),
        front_length=taut_centre_line(lv, waist_y, float(neck.front[1]), front=True),
        inseam=crotch - ankle_y, rise=waist_y - crotch, outseam=waist_y - ankle_y,
        neck_to_shoulder=float(np.linalg.norm(neck.sides - shoulders, axis=1).mean()),
        neck_base_height=float(neck.sides[:, 1].mean()), shoulder_height=float(shoulders[:, 1].mean()),
        armpit_height=pit_y, chest_height=float(lv.ys[i_chest]), waist_height=waist_y,
        hip_height=float(lv.ys[i_hip]), crotch_height=crotch,
        knee_height=float(0.5 * (rest.j("left_knee")[1] + rest.j("right_knee")[1])),
        ankle_height=ankle_y, floor_height=float(rest.vertices[:, 1].min()),
        shoulder_points=shoulders, side_neck_points=neck.sides, nape_point=neck.nape,
        front_neck_point=neck.front, armpit_points=pits,
        wrist_x=float(0.5 * (abs(rest.j("left_wrist")[0]) + abs(rest.j("right_wrist")[0]))),
        leg_axis_x=np.array([legs[0]["axis_x"], legs[1]["axis_x"]]),
        chest_extent=lv.extent(i_chest), waist_extent=lv.extent(i_waist), hip_extent=lv.extent(i_hip),
        sides=sides)
