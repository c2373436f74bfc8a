"""BVH motion files: parser and retargeting onto SMPL's 24 joints.

Parsing follows the Biovision format: a ``HIERARCHY`` of ``ROOT`` / ``JOINT`` / ``End Site``
blocks with ``OFFSET`` and ``CHANNELS``, then ``MOTION``, ``Frames: N``, ``Frame Time: dt`` and
one line of numbers per frame. Rotation channels are Euler angles [deg] applied in the listed
order (``Zrotation Xrotation Yrotation`` -> ``R = Rz Rx Ry``, column vectors, intrinsic);
position channels, on the root or on every joint, give the joint's local translation and
replace its ``OFFSET`` for that frame. The world is taken as Y up.

Retargeting (see ``sim.motions.retarget``) maps SMPL joints to BVH joints by name (default
maps for CMU-style and Mixamo-style skeletons, picked automatically, namespaces such as
``mixamorig:`` ignored, case-insensitive), copies global rotations through a rest alignment
and converts them to SMPL's local rotations. Assumption about the rest pose: the BVH's zero
pose is a standing pose, facing +Z, left side at +X. What it stands for (``rest``, see
``sim.motions.retarget``):

- ``"auto"`` (default): SMPL's T-pose with the file's limbs. SMPL's thighs, shins, upper arms
  and forearms are turned by the smallest rotation onto the file's rest bone directions, so
  they point where the file's point (at rest an A-pose file lowers the body's arms, CMU's
  spreads its legs by 20 degrees, slightly bent arms stay bent); the hands continue their
  forearms; the torso, neck, head, collars and feet are SMPL's rest (upright, head level,
  feet flat) whatever the directions between the file's joints there.
- ``"tpose"``: the file's rest is SMPL's T-pose as it is (no alignment).
- ``"file"``: every bone's rest direction is aligned with SMPL's, torso, neck, head and hands
  included; this follows the file's joint placement literally and tilts the head where it
  differs from the body's (a CMU skeleton's head 50 degrees back on ``SMPL_REST_JOINTS``, 15
  on the default body).

Units: ``scale="auto"`` measures the rest skeleton's height ``h`` (in file units): metres when
``h <= 3``, centimetres when ``100 <= h <= 300``, millimetres when ``1000 <= h <= 3000``,
otherwise the skeleton is scaled to 1.7 m tall (CMU's inch-like units, for instance). Root
translation: the BVH floor is y = 0; ``trans`` is the root position minus its rest height above
the rest skeleton's lowest point, so ``trans = 0`` stands like SMPL's rest body.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError
from sim.motions.retarget import (
    BONE_CHILD,
    rest_alignment,
    retarget_global_rotations,
)
from sim.rotations import axis_angle_to_matrix
from sim.types import SMPL_JOINT_NAMES, Motion

#: ``load_bvh``'s ``rest`` choices (see the module docstring).
REST_MODES = ("auto", "tpose", "file")

_CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_AXIS = {"X": 0, "Y": 1, "Z": 2}

#: SMPL joint -> BVH joint candidates (first present and unused wins), CMU-style names.
CMU_MAP: dict[str, tuple[str, ...]] = {
    "pelvis": ("Hips",), "left_hip": ("LeftUpLeg",), "right_hip": ("RightUpLeg",),
    "spine1": ("LowerBack", "Spine"), "left_knee": ("LeftLeg",), "right_knee": ("RightLeg",),
    "spine2": ("Spine",), "left_ankle": ("LeftFoot",), "right_ankle": ("RightFoot",),
    "spine3": ("Spine1",), "left_foot": ("LeftToeBase",), "right_foot": ("RightToeBase",),
    "neck": ("Neck",), "left_collar": ("LeftShoulder",), "right_collar": ("RightShoulder",),
    "head": ("Head",), "left_shoulder": ("LeftArm",), "right_shoulder": ("RightArm",),
    "left_elbow": ("LeftForeArm",), "right_elbow": ("RightForeArm",),
    "left_wrist": ("LeftHand",), "right_wrist": ("RightHand",),
    "left_hand": ("LeftFingerBase", "LeftHandMiddle1"),
    "right_hand": ("RightFingerBase", "RightHandMiddle1"),
}
#: Mixamo-style names (after dropping the ``mixamorig:`` namespace).
MIXAMO_MAP: dict[str, tuple[str, ...]] = {
    **CMU_MAP,
    "spine1": ("Spine",), "spine2": ("Spine1",), "spine3": ("Spine2",),
    "left_hand": ("LeftHandMiddle1",), "right_hand": ("RightHandMiddle1",),
}
JOINT_MAPS = {"cmu": CMU_MAP, "mixamo": MIXAMO_MAP}


@dataclass
class BvhJoint:
    """One BVH joint: name, parent index, rest offset (file units), channels."""

    name: str
    parent: int
    offset: np.ndarray
    channels: list[str] = field(default_factory=list)
    channel_start: int = 0
    end_sites: list[np.ndarray] = field(default_factory=list)
    children: list[int] = field(default_factory=list)


@dataclass
class BvhData:
    """A parsed BVH file.

    Attributes:
        joints: joints in file order (parents before children).
        frames: channel values, shape (T, C), float64 (degrees and file units).
        frame_time: seconds per frame [s].
        path: the file.
    """

    joints: list[BvhJoint]
    frames: np.ndarray
    frame_time: float
    path: str

    @property
    def fps(self) -> float:
        """Frames per second [1/s]; snapped to the nearest integer when within 0.02 % (frame
        times are often printed with 6 decimals: 0.008333 s -> 120.005 -> 120)."""
        f = 1.0 / self.frame_time
        r = round(f)
        return float(r) if r > 0 and abs(f - r) <= 2e-4 * f else f

    def index(self) -> dict[str, int]:
        return {j.name: i for i, j in enumerate(self.joints)}

    def rest_positions(self) -> np.ndarray:
        """Rest (zero-channel) joint positions in file units, shape (S, 3)."""
        P = np.zeros((len(self.joints), 3))
        for i, j in enumerate(self.joints):
            P[i] = j.offset if j.parent < 0 else P[j.parent] + j.offset
        return P

    def rest_height(self) -> float:
        """Vertical extent of the rest skeleton incl. end sites, file units."""
        P = self.rest_positions()
        ys = list(P[:, 1]) + [P[i, 1] + e[1] for i, j in enumerate(self.joints)
                              for e in j.end_sites]
        return float(max(ys) - min(ys))

    def rest_floor(self) -> float:
        """Lowest y of the rest skeleton (joints and end sites), file units."""
        P = self.rest_positions()
        ys = list(P[:, 1]) + [P[i, 1] + e[1] for i, j in enumerate(self.joints)
                              for e in j.end_sites]
        return float(min(ys))

    def global_transforms(self) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations (T, S, 3, 3) and positions (T, S, 3) [file units] of every joint."""
        T, S = self.frames.shape[0], len(self.joints)
        G = np.empty((T, S, 3, 3))
        P = np.empty((T, S, 3))
        for i, j in enumerate(self.joints):
            vals = self.frames[:, j.channel_start:j.channel_start + len(j.channels)]
            R = np.broadcast_to(np.eye(3), (T, 3, 3)).copy()
            local_t = np.broadcast_to(j.offset, (T, 3)).copy()
            if any(c.endswith("position") for c in j.channels):
                local_t[:] = 0.0  # position channels replace the offset
            for k, ch in enumerate(j.channels):
                ax = _AXIS[ch[0]]
                if ch.endswith("rotation"):
                    aa = np.zeros((T, 3))
                    aa[:, ax] = np.deg2rad(vals[:, k])
                    R = R @ axis_angle_to_matrix(aa)
                else:
                    local_t[:, ax] = vals[:, k]
            if j.parent < 0:
                G[:, i] = R
                P[:, i] = local_t
            else:
                G[:, i] = G[:, j.parent] @ R
                P[:, i] = P[:, j.parent] + np.einsum("tab,tb->ta", G[:, j.parent], local_t)
        return G, P


def _err(path: str, line: int | None, msg: str) -> WrinklesInputError:
    return WrinklesInputError(f"line {line}: {msg}" if line else msg, path=path)


def _floats(path: str, line: int, tokens: list[str], what: str) -> np.ndarray:
    try:
        v = np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise _err(path, line, f"{what}: '{bad}' is not a number") from None
    if not np.all(np.isfinite(v)):
        raise _err(path, line, f"{what}: NaN or inf value")
    return v


def _is_float(t: str) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False


def parse_bvh(path: str | os.PathLike) -> BvhData:
    """Parse a BVH file.

    Raises:
        WrinklesInputError: naming the file and line, for a bad hierarchy, a missing MOTION
            section, a wrong number of values on a frame line, non-numeric values or a
            ``Frames:`` count that does not match the frame lines.
    """
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            lines = f.read().splitlines()
    except OSError as e:
        raise WrinklesInputError(f"cannot read ({e.strerror or e})", path=path) from None
    toks: list[tuple[int, list[str]]] = [(n + 1, ln.split()) for n, ln in enumerate(lines)]
    toks = [(n, t) for n, t in toks if t]
    if not toks or toks[0][1][0].upper() != "HIERARCHY":
        raise _err(path, toks[0][0] if toks else None, "expected 'HIERARCHY' at the start")
    hierarchy = _Hierarchy(path)
    i = 1
    while i < len(toks):
        closed = hierarchy.read(*toks[i])
        i += 1
        if closed:
            break
    else:
        raise _err(path, toks[-1][0], "hierarchy not closed (missing '}') and no MOTION section")
    if not hierarchy.joints:
        raise _err(path, None, "no ROOT joint in the hierarchy")
    frames, frame_time = _parse_motion(path, toks, i, hierarchy.n_channels)
    return BvhData(joints=hierarchy.joints, frames=frames, frame_time=frame_time, path=path)


@dataclass
class _Hierarchy:
    """The HIERARCHY section read line by line: joints in file order, the open blocks."""

    path: str
    joints: list[BvhJoint] = field(default_factory=list)
    stack: list[int] = field(default_factory=list)  # open joint indices; -2 marks an End Site block
    pending: BvhJoint | None = None  # declared, its '{' not yet read
    end_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    n_channels: int = 0

    def read(self, line: int, t: list[str]) -> bool:
        """Take one line's tokens; True once the ROOT's block is closed."""
        key = t[0]
        if key in ("ROOT", "JOINT", "End"):
            self._declare(line, t)
        elif key == "{":
            self._open(line)
        elif key == "}":
            return self._close(line)
        elif key == "OFFSET":
            self._offset(line, t)
        elif key == "CHANNELS":
            self._channels(line, t)
        elif key == "MOTION":
            raise _err(self.path, line, "MOTION before the hierarchy is closed (missing '}')")
        else:
            raise _err(self.path, line, f"unexpected '{key}' in the hierarchy")
        return False

    def _declare(self, line: int, t: list[str]) -> None:
        key, stack = t[0], self.stack
        if key == "End":
            if not stack or stack[-1] == -2:
                raise _err(self.path, line, "'End Site' outside a joint")
            self.pending = BvhJoint(name="", parent=-2, offset=np.zeros(3))
            return
        if (key == "ROOT") != (not stack) or (key == "ROOT" and self.joints):
            raise _err(self.path, line, f"'{key}' not allowed here (one ROOT, JOINTs inside it)")
        if stack and stack[-1] == -2:
            raise _err(self.path, line, "'JOINT' inside an End Site")
        if len(t) < 2:
            raise _err(self.path, line, f"'{key}' without a name")
        self.pending = BvhJoint(name=" ".join(t[1:]), parent=stack[-1] if stack else -1,
                                offset=np.zeros(3))

    def _open(self, line: int) -> None:
        pending = self.pending
        if pending is None:
            raise _err(self.path, line, "'{' without a ROOT, JOINT or End Site before it")
        if pending.parent == -2:
            self.stack.append(-2)
            self.end_offset = np.zeros(3)
        else:
            self.joints.append(pending)
            idx = len(self.joints) - 1
            if pending.parent >= 0:
                self.joints[pending.parent].children.append(idx)
            self.stack.append(idx)
        self.pending = None

    def _close(self, line: int) -> bool:
        if not self.stack:
            raise _err(self.path, line, "unbalanced '}'")
        top = self.stack.pop()
        if top == -2:
            self.joints[self.stack[-1]].end_sites.append(self.end_offset)
        return not self.stack

    def _offset(self, line: int, t: list[str]) -> None:
        if len(t) != 4:
            raise _err(self.path, line, f"OFFSET needs 3 numbers, got {len(t) - 1}")
        off = _floats(self.path, line, t[1:], "OFFSET")
        if self.stack and self.stack[-1] == -2:
            self.end_offset = off
        elif self.stack:
            self.joints[self.stack[-1]].offset = off
        else:
            raise _err(self.path, line, "OFFSET outside a joint")

    def _channels(self, line: int, t: list[str]) -> None:
        if not self.stack or self.stack[-1] == -2:
            raise _err(self.path, line, "CHANNELS outside a joint")
        if len(t) < 2 or not t[1].isdigit():
            raise _err(self.path, line, "CHANNELS needs a count")
        n = int(t[1])
        chans = t[2:]
        if len(chans) != n:
            raise _err(self.path, line, f"CHANNELS says {n} channels, lists {len(chans)}")
        for c in chans:
            if c not in _CHANNELS:
                raise _err(self.path, line, f"unknown channel '{c}' (allowed: {', '.join(_CHANNELS)})")
        jt = self.joints[self.stack[-1]]
        jt.channels = chans
        jt.channel_start = self.n_channels
        self.n_channels += n


def _parse_motion(path: str, toks: list[tuple[int, list[str]]], i: int,
                  n_channels: int) -> tuple[np.ndarray, float]:
    """The MOTION section from token line ``i`` on: (frames (T, n_channels), frame time [s])."""
    if i >= len(toks) or toks[i][1][0].upper() != "MOTION":
        raise _err(path, toks[i][0] if i < len(toks) else None, "missing 'MOTION' section")
    i += 1
    if i >= len(toks) or toks[i][1][0] != "Frames:" or len(toks[i][1]) != 2 \
            or not toks[i][1][1].isdigit():
        raise _err(path, toks[i][0] if i < len(toks) else toks[-1][0],
                   "expected 'Frames: <count>' after MOTION")
    n_frames = int(toks[i][1][1])
    i += 1
    if i >= len(toks) or toks[i][1][:2] != ["Frame", "Time:"] or len(toks[i][1]) != 3:
        raise _err(path, toks[i][0] if i < len(toks) else toks[-1][0],
                   "expected 'Frame Time: <seconds>'")
    frame_time = float(_floats(path, toks[i][0], toks[i][1][2:], "Frame Time")[0])
    if frame_time <= 0:
        raise _err(path, toks[i][0], f"Frame Time must be positive, got {frame_time}")
    i += 1
    rows = toks[i:]
    if n_frames == 0:
        raise _err(path, toks[i - 2][0], "the motion has zero frames")
    if len(rows) != n_frames:
        raise _err(path, rows[-1][0] if rows else toks[-1][0],
                   f"'Frames: {n_frames}' but {len(rows)} frame lines follow")
    frames = np.empty((n_frames, n_channels))
    for k, (line, t) in enumerate(rows):
        if len(t) != n_channels:
            raise _err(path, line, f"frame {k} has {len(t)} values, the hierarchy has "
                                   f"{n_channels} channels")
        frames[k] = _floats(path, line, t, f"frame {k}")
    return frames, frame_time


def _short(name: str) -> str:
    return name.rsplit(":", 1)[-1].lower()


def detect_joint_map(bvh: BvhData) -> str:
    """``"mixamo"`` when the skeleton has Mixamo's three spine joints or namespace, else ``"cmu"``."""
    names = {_short(j.name) for j in bvh.joints}
    if any(j.name.lower().startswith("mixamorig") for j in bvh.joints) or "spine2" in names:
        return "mixamo"
    return "cmu"


def resolve_joint_map(bvh: BvhData, joint_map: str | dict[str, str | tuple[str, ...]] = "auto"
                      ) -> tuple[dict[int, int], str]:
    """SMPL joint index -> BVH joint index.

    Args:
        bvh: parsed file.
        joint_map: ``"auto"``, ``"cmu"``, ``"mixamo"``, or a dict SMPL joint name -> BVH joint
            name (or candidate names).

    Returns:
        ``(mapping, map_name)``.
    """
    if isinstance(joint_map, str):
        key = detect_joint_map(bvh) if joint_map == "auto" else joint_map
        if key not in JOINT_MAPS:
            raise WrinklesInputError(f"unknown joint_map {joint_map!r}; use 'auto', "
                                     f"{', '.join(map(repr, JOINT_MAPS))} or a dict", path=bvh.path)
        table, label = JOINT_MAPS[key], key
    else:
        unknown = sorted(set(joint_map) - set(SMPL_JOINT_NAMES))
        if unknown:
            raise WrinklesInputError(f"joint_map names unknown SMPL joints {unknown}; SMPL joints: "
                                     f"{', '.join(SMPL_JOINT_NAMES)}", path=bvh.path)
        table = {k: ((v,) if isinstance(v, str) else tuple(v)) for k, v in joint_map.items()}
        label = "custom"
    by_name: dict[str, int] = {}
    for i, j in enumerate(bvh.joints):
        by_name.setdefault(j.name.lower(), i)
        by_name.setdefault(_short(j.name), i)
    mapping: dict[int, int] = {}
    used: set[int] = set()
    for s, smpl_name in enumerate(SMPL_JOINT_NAMES):
        for cand in table.get(smpl_name, ()):
            b = by_name.get(cand.lower(), by_name.get(_short(cand)))
            if b is not None and b not in used:
                mapping[s] = b
                used.add(b)
                break
    if 0 not in mapping:
        raise WrinklesInputError(
            f"no root joint for SMPL 'pelvis' ({'/'.join(table.get('pelvis', ()))}) among the BVH "
            f"joints: {', '.join(j.name for j in bvh.joints[:12])}", path=bvh.path)
    return mapping, label


def _src_bone_dirs(bvh: BvhData, mapping: dict[int, int]) -> dict[int, np.ndarray]:
    """Rest direction of the BVH bone driven by each mapped SMPL joint."""
    P = bvh.rest_positions()
    dirs: dict[int, np.ndarray] = {}
    for s, b in mapping.items():
        c = BONE_CHILD[s]
        if c >= 0 and c in mapping:
            d = P[mapping[c]] - P[b]
        elif bvh.joints[b].children:
            d = bvh.joints[bvh.joints[b].children[0]].offset
        elif bvh.joints[b].end_sites:
            d = bvh.joints[b].end_sites[0]
        else:
            continue
        if np.linalg.norm(d) > 1e-9:
            dirs[s] = np.asarray(d, dtype=np.float64)
    return dirs


def _rest_joints(rest_joints, path: str) -> np.ndarray:
    """``rest_joints`` as a finite (24, 3) float64 array, or a one-line error."""
    try:
        J = np.asarray(rest_joints, dtype=np.float64)
    except (TypeError, ValueError):
        J = np.zeros(0)
    if J.shape != (len(SMPL_JOINT_NAMES), 3) or not np.all(np.isfinite(J)):
        raise WrinklesInputError("rest_joints must be SMPL's 24 joint positions [m], a finite (24, 3) "
                                 f"array; got shape {J.shape}", path=path)
    return J


def bvh_scale(bvh: BvhData, scale: float | str = "auto") -> float:
    """Metres per file unit (see the module docstring for ``"auto"``)."""
    if not isinstance(scale, str):
        if not (np.isfinite(scale) and scale > 0):
            raise WrinklesInputError(f"scale must be positive, got {scale}", path=bvh.path)
        return float(scale)
    if scale != "auto":
        raise WrinklesInputError(f"scale must be a number or 'auto', got {scale!r}", path=bvh.path)
    h = bvh.rest_height()
    if h <= 0:
        raise WrinklesInputError("the rest skeleton has zero height; pass scale", path=bvh.path)
    if h <= 3.0:
        return 1.0
    if 100.0 <= h <= 300.0:
        return 0.01
    if 1000.0 <= h <= 3000.0:
        return 0.001
    return 1.7 / h


def load_bvh(path: str | os.PathLike, *, joint_map: str | dict = "auto",
             scale: float | str = "auto", rest: str = "auto",
             rest_joints: np.ndarray | None = None, name: str | None = None) -> Motion:
    """Load a BVH file and retarget it onto SMPL's 24 joints.

    Args:
        path: the ``.bvh`` file.
        joint_map: ``"auto"`` / ``"cmu"`` / ``"mixamo"`` or a dict SMPL name -> BVH name.
        scale: metres per file unit, or ``"auto"``.
        rest: what the file's rest pose stands for (see the module docstring): ``"auto"``
            aligns the limbs with SMPL's T-pose and keeps SMPL's torso, head, hands and feet;
            ``"tpose"`` takes it as SMPL's T-pose unchanged; ``"file"`` aligns every bone.
        rest_joints: SMPL rest joints [m] (24, 3) of the body the motion will pose, for the
            alignment; default the approximate ``SMPL_REST_JOINTS``.
        name: label; default the file's stem.

    Returns:
        ``Motion`` at the file's frame rate: poses (T, 24, 3) [rad], trans (T, 3) [m];
        ``extra`` has ``joint_map`` (name of the map used), ``mapped`` (SMPL -> BVH names),
        ``scale`` and ``rest``.
    """
    path = os.fspath(path)
    if rest not in REST_MODES:
        raise WrinklesInputError(f"rest must be one of {', '.join(REST_MODES)}, got {rest!r}", path=path)
    if rest_joints is not None:
        rest_joints = _rest_joints(rest_joints, path)
    bvh = parse_bvh(path)
    mapping, label = resolve_joint_map(bvh, joint_map)
    s = bvh_scale(bvh, scale)
    G, P = bvh.global_transforms()
    align = None if rest == "tpose" else rest_alignment(
        _src_bone_dirs(bvh, mapping), rest_joints, limbs_only=rest == "auto")
    poses = retarget_global_rotations(G, mapping, align)
    root = mapping[0]
    rest_pos = bvh.rest_positions()
    stand = rest_pos[root, 1] - bvh.rest_floor()  # root height above the rest skeleton's floor
    trans = P[:, root] * s
    trans[:, 1] -= stand * s
    extra = {"joint_map": label, "scale": s, "rest": rest,
             "mapped": {SMPL_JOINT_NAMES[k]: bvh.joints[v].name for k, v in mapping.items()}}
    return Motion(poses=poses.astype(np.float32), trans=trans.astype(np.float32), fps=bvh.fps,
                  name=name or Path(path).stem, source=path, extra=extra)
