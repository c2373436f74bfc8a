"""Where a linear-blend-skinned body passes through itself, and the body moved out of itself.

Linear blend skinning folds the skin through itself at deep flexion: the upper arm into the
chest when the arms come forward or down, the thigh into the belly at the groin, the calf into
the thigh behind a bent knee. Cloth caught there is pushed by one part's surface into the other
and overstretched. HOOD and ContourCraft (Grigorev et al. 2023, 2024) keep it out of the motion
and the contact: they turn the arms out by 20 degrees at the shoulders (SNUG's
``separate_arms``) and leave the hands out of the body contact. Here the body itself is
corrected, frame by frame, before the simulation (the solver's kernels are untouched), and the
motion is kept:

- parts (``body_parts``): every vertex belongs to the part of the joint that skins it most
  (``PART_JOINTS``: the torso, upper arms, forearms with the hands, thighs, shins with the
  feet); a part's faces, closed by a fan over each of its boundary loops (a cap), are its solid.
- separation (``PartSeparator.separate``): per frame, a vertex of a yielding part inside the
  other part's solid (``SEPARATIONS``) or nearer its skin than ``CLEARANCE`` goes ``CLEARANCE``
  off the closest point of that skin, then the other part's vertices likewise off the moved
  part, for ``ROUNDS`` rounds, so the collider the cloth meets has no overlapping parts and room
  for cloth between them. A vertex whose closest point is on a cap is in the joint where the
  parts meet, and stays.

The posed default body's parts sink into each other only in deep flexion
(``PartSeparator.penetration`` over the procedural motions with their lead-ins, every second
frame): not at all over ``walk``, 2.8 mm (upper arms into the torso) over ``arm_raise``, and over
``squat`` 16 mm (upper arms into the chest, 95 of 120 frames), 27 mm (thighs into the belly, 41
of 120) and 12 mm (calves into the thighs, 23 of 120).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.geometry.points import coordinate_bounds
from sim.types import BodyFrames

PART_JOINTS: dict[str, tuple[str, ...]] = {
    "torso": ("pelvis", "spine1", "spine2", "spine3", "neck", "head", "left_collar", "right_collar"),
    "left_upper_arm": ("left_shoulder",),
    "right_upper_arm": ("right_shoulder",),
    "left_forearm": ("left_elbow", "left_wrist", "left_hand"),
    "right_forearm": ("right_elbow", "right_wrist", "right_hand"),
    "left_thigh": ("left_hip",),
    "right_thigh": ("right_hip",),
    "left_shin": ("left_knee", "left_ankle", "left_foot"),
    "right_shin": ("right_knee", "right_ankle", "right_foot"),
}
"""The body's parts by SMPL joint name; a joint not named here (SMPL-H / SMPL-X fingers, jaw,
eyes) belongs to the part of its nearest named ancestor."""


SEPARATIONS: tuple[tuple[str, str], ...] = (
    *((f"{side}_upper_arm", "torso") for side in ("left", "right")),
    *((f"{side}_forearm", "torso") for side in ("left", "right")),
    *((f"{side}_forearm", f"{side}_upper_arm") for side in ("left", "right")),
    *((f"{side}_thigh", "torso") for side in ("left", "right")),
    *((f"{side}_shin", f"{side}_thigh") for side in ("left", "right")),
    ("left_thigh", "right_thigh"),
    ("left_shin", "right_shin"),
)
"""Pairs of parts that may pass through each other, ``(mover, obstacle)``: the mover yields
(``PartSeparator.separate``): a limb to the trunk, the distal segment to the proximal one (the
forearm to the upper arm at the elbow, the calf to the thigh at the knee)."""

ROUNDS = 3
"""Rounds of ``PartSeparator.separate``. Over the default body's ``squat`` (every second frame,
``PartSeparator.penetration`` both ways) one round leaves thighs up to 22 mm in the belly in 22
of 120 frames (the belly, pushed out of the thighs in the second stage, has moved over them), two
leave 1.4 mm in 2 frames, three none; a round after the first visits only the frames the one
before it moved."""

MAX_DEPTH = 0.05
"""Deepest penetration [m] that is corrected: a vertex farther than this from the other part's
surface is left. The query's cost grows with the radius (at 0.1 m the default body's ``squat``
takes 2.4 times as long on the CPU); its deepest over the procedural motions is 27 mm (thighs
into the belly in ``squat``)."""

CLEARANCE = 0.004
"""Distance [m] kept between a separated vertex and the other part's skin: room for two layers
of cloth caught between the parts (the solver's cloth self-contact keeps layers 3 mm apart,
``SelfContactConfig.radius``, plus the fabrics' thickness, 0.1-0.8 mm). The coarse shorts over the
default body's ``squat`` (CPU): 78 and 159 edge-frames over the strain gate in two runs with it,
183 with the parts touching, 304 without the separation."""

FRAME_CHUNK = {"cpu": 4, "cuda": 64}
"""Frames placed side by side in one set of solids (``PartSeparator``), by device kind: each stage
places, refits and queries them with one launch each rather than one per frame (on the GPU a
population's separation took 144 of its 204 s, 40,230 refits at 3 ms, one per frame, stage and
solid). On the CPU the work is the same either way (the default body's 120-frame squat: 2.4 s at
1 to 4 frames, 4.1 s at 64, where every refit covers all 64)."""

TOLERANCE = 1e-6
"""A vertex nearer its target than this [m] stays (round-off of the closest-point query)."""


@dataclass(frozen=True, eq=False)
class BodyParts:
    """A body mesh cut into parts, each closed into a solid.

    Attributes:
        names: part names (``PART_JOINTS`` order).
        vertex_part: part index of every body vertex, int32 (V,).
        solids: per part, its closed triangles, int32 (F_p + C_p, 3), indexing the solids'
            points: the V body vertices, then one centre per cap (``cap_points``); its skin
            faces first, its caps' fans after them.
        skin_faces: per part, how many of its solid's triangles are body faces.
        loop_vertices: the boundary loops' vertices, cap after cap, int32.
        loop_starts: where cap c's loop begins in ``loop_vertices``, int32 (C + 1,).
    """

    names: tuple[str, ...]
    vertex_part: np.ndarray
    solids: tuple[np.ndarray, ...]
    skin_faces: tuple[int, ...]
    loop_vertices: np.ndarray
    loop_starts: np.ndarray

    @property
    def num_vertices(self) -> int:
        return int(self.vertex_part.shape[0])

    @property
    def num_caps(self) -> int:
        return int(self.loop_starts.shape[0] - 1)

    def index(self, name: str) -> int:
        """Index of part ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown body part {name!r}; parts: {', '.join(self.names)}") from None

    def vertices_of(self, name: str) -> np.ndarray:
        """The body vertices of part ``name``, int32."""
        return np.flatnonzero(self.vertex_part == self.index(name)).astype(np.int32)

    def movers(self, mover: str, obstacle: str) -> np.ndarray:
        """The vertices of part ``mover`` that can lie inside ``obstacle``'s solid: all but the
        corners of its faces (where the parts meet, on both surfaces), int32."""
        own = self.vertices_of(mover)
        return own[~np.isin(own, self.solids[self.index(obstacle)])].astype(np.int32)

    def cap_points(self, vertices: np.ndarray) -> np.ndarray:
        """The solids' points of one pose: ``vertices`` (V, 3) [m], then each cap's centre (the
        mean of its loop), float32 (V + C, 3)."""
        v = np.asarray(vertices, np.float64)
        if self.num_caps == 0:
            return v.astype(np.float32)
        sums = np.add.reduceat(v[self.loop_vertices], self.loop_starts[:-1], axis=0)
        centres = sums / np.diff(self.loop_starts)[:, None]
        return np.concatenate([v, centres]).astype(np.float32)


def joint_parts(joint_names, parents) -> np.ndarray:
    """Part index (``PART_JOINTS`` order) of every joint, int32 (J,): its own where
    ``PART_JOINTS`` names it, else its nearest named ancestor's, else the torso's."""
    names = list(PART_JOINTS)
    own = {j: names.index(p) for p, joints in PART_JOINTS.items() for j in joints}
    out = np.zeros(len(joint_names), np.int32)
    for j, n in enumerate(joint_names):  # parents come first
        parent = int(parents[j])
        out[j] = own.get(n, out[parent] if parent >= 0 else 0)
    return out


def _face_parts(faces: np.ndarray, vertex_part: np.ndarray) -> np.ndarray:
    """Each face's part: the part of two or three of its vertices, else its first vertex's."""
    a, b, c = (vertex_part[faces[:, k]] for k in range(3))
    return np.where((b == c) & (a != b), b, a)


def _caps(part_faces: np.ndarray, num_vertices: int) -> list[np.ndarray]:
    """The boundary loops of a set of faces: its directed edges whose reverse is not in the set,
    grouped into connected chains; per loop its boundary edges (L, 2), in the faces' order."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = np.concatenate([part_faces[:, [0, 1]], part_faces[:, [1, 2]], part_faces[:, [2, 0]]]).astype(np.int64)
    key = e[:, 0] * num_vertices + e[:, 1]
    border = e[~np.isin(e[:, 1] * num_vertices + e[:, 0], key)]
    if len(border) == 0:
        return []
    n = num_vertices
    graph = coo_matrix((np.ones(len(border)), (border[:, 0], border[:, 1])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    loop = comp[border[:, 0]]
    return [border[loop == k] for k in np.unique(loop)]


def body_parts(faces: np.ndarray, weights: np.ndarray, joint_names, parents) -> BodyParts:
    """Cut a body mesh into ``PART_JOINTS``' parts by its skinning weights and close each.

    Args:
        faces: body triangles, outward-wound, int (F, 3).
        weights: skinning weights (V, J).
        joint_names: J joint names; parents: parent joint index (J,), -1 for the root.

    Returns:
        The parts and their solids: each cap is a fan from its loop's centre over the loop's
        edges, wound like the faces, so every solid is closed and outward-oriented.
    """
    faces = np.asarray(faces, np.int64)
    V = int(np.asarray(weights).shape[0])
    vertex_part = joint_parts(tuple(joint_names), parents)[np.argmax(weights, axis=1)]
    face_part = _face_parts(faces, vertex_part)
    solids, skins, loops = [], [], []
    for p in range(len(PART_JOINTS)):
        skin = faces[face_part == p]
        fans = []
        for border in _caps(skin, V):
            centre = V + len(loops)
            loops.append(np.unique(border))
            fans.append(np.column_stack([border[:, 1], border[:, 0], np.full(len(border), centre)]))
        solids.append(np.concatenate([skin, *fans]).astype(np.int32) if fans else skin.astype(np.int32))
        skins.append(len(skin))
    sizes = np.array([len(loop) for loop in loops], np.int64)
    return BodyParts(names=tuple(PART_JOINTS), vertex_part=vertex_part.astype(np.int32), solids=tuple(solids),
                     skin_faces=tuple(skins),
                     loop_vertices=(np.concatenate(loops) if loops else np.zeros(0)).astype(np.int32),
                     loop_starts=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32))


def separation_record() -> dict:
    """The separation's settings, for the simulator's record (``sim.simulate.simulator_defaults``:
    a dataset is not continued under other ones)."""
    return {"parts": {k: list(v) for k, v in PART_JOINTS.items()},
            "separations": [list(pair) for pair in SEPARATIONS], "rounds": ROUNDS,
            "max_depth_m": MAX_DEPTH, "clearance_m": CLEARANCE}


@functools.lru_cache(maxsize=8)
def parts_of(body) -> BodyParts:
    """``body_parts`` of a ``sim.bodies.BodyModel`` (cached per model object)."""
    return body_parts(body.faces, body.weights, body.joint_names, body.parents)


@dataclass(frozen=True)
class _Stage:
    """One stage's work: a task per (vertex, pair), sorted by vertex; the pairs' obstacles; the
    moving vertices and where each one's tasks begin."""

    movers: Any  # int32 (K,): the vertex of each task
    pair: Any  # int32 (K,): the task's pair, indexing ``obstacles`` / ``skin_faces``
    obstacles: tuple[str, ...]  # each pair's other part
    skin_faces: Any  # int32 (P,): the obstacles' skin triangles (a frame's first ones)
    solid_faces: Any  # int32 (P,): the obstacles' triangles per frame
    vertices: Any  # int32 (U,): the moving vertices
    starts: Any  # int32 (U + 1,): vertex u's tasks are starts[u] .. starts[u + 1]
    columns: np.ndarray  # int (K,): each task's separation (``PartSeparator.separations`` index)


class _Space:
    """``frames`` poses of the body's solids side by side: frame t's points (the body's vertices,
    then the cap centres) translated into its own cell of an n x n x n grid, cells ``spacing``
    apart, one Warp mesh per solid over every frame, so a stage places, refits and queries all
    frames with one launch each. The inside test of ``skin_point`` casts axis-aligned rays from
    the point through the whole mesh; the cells (i, j, (i + j) mod n) share no two indices with
    each other, so no ray from one frame's cell meets another frame's solids."""

    def __init__(self, wp, parts: BodyParts, frames: int, spacing: float, lo: np.ndarray, device: str):
        self.frames, self.stride = frames, parts.num_vertices + parts.num_caps
        n = int(np.ceil(np.sqrt(frames) - 1e-9))
        i, j = np.arange(frames) % n, np.arange(frames) // n
        cells = np.stack([i, j, (i + j) % n], axis=1).astype(np.float64)
        self.offsets = wp.array((cells * spacing - lo).astype(np.float32), dtype=wp.vec3, device=device)
        self.points = wp.zeros(frames * self.stride, dtype=wp.vec3, device=device)
        self.wp, self.parts, self.device, self.meshes, self._ids = wp, parts, device, {}, {}

    def refit(self, name: str) -> None:
        """Fit solid ``name``'s tree to the points; the first time, build it on them (a tree
        built on the placed frames keeps each frame's triangles in their own subtrees)."""
        mesh = self.meshes.get(name)
        if mesh is not None:
            mesh.refit()
            return
        shift = (np.arange(self.frames, dtype=np.int64) * self.stride)[:, None, None]
        tiled = (self.parts.solids[self.parts.index(name)][None].astype(np.int64) + shift).reshape(-1)
        self.meshes[name] = self.wp.Mesh(points=self.points, indices=self.wp.array(
            tiled.astype(np.int32), dtype=self.wp.int32, device=self.device))

    def ids(self, obstacles: tuple[str, ...]):
        """Mesh ids of ``obstacles`` (built by ``refit``), uint64 (P,), made once per tuple."""
        if obstacles not in self._ids:
            self._ids[obstacles] = self.wp.array([self.meshes[o].id for o in obstacles], dtype=self.wp.uint64,
                                                 device=self.device)
        return self._ids[obstacles]


class PartSeparator:
    """``BodyParts``' solids on a Warp device, placed ``FRAME_CHUNK`` frames at a time side by
    side (``_Space``): how deep parts lie in each other (``penetration``) and the body with its
    parts moved out of each other (``separate``).

    Args:
        parts: the body's parts.
        separations: ``(mover, obstacle)`` pairs of part names (``SEPARATIONS``).
        device: Warp device.
        max_depth: deepest penetration [m] that is seen and corrected.
        clearance: distance [m] kept between a separated vertex and the other part's skin.
    """

    def __init__(self, parts: BodyParts, separations: tuple[tuple[str, str], ...] = SEPARATIONS, *,
                 device: str, max_depth: float = MAX_DEPTH, clearance: float = CLEARANCE):
        from sim.device import warp

        wp = warp()
        self.wp, self.parts, self.device = wp, parts, device
        self.separations = tuple((str(a), str(b)) for a, b in separations)
        self.max_depth, self.clearance = float(max_depth), float(clearance)
        self.loop_vertices = wp.array(parts.loop_vertices, dtype=wp.int32, device=device)
        self.loop_starts = wp.array(parts.loop_starts, dtype=wp.int32, device=device)
        self.solid_names = tuple(n for n in dict.fromkeys(n for pair in self.separations for n in pair)
                                 if len(parts.solids[parts.index(n)]))
        self.stages = tuple(s for s in (self._stage_tasks(False), self._stage_tasks(True)) if s is not None)

    def _stage_tasks(self, reverse: bool) -> _Stage | None:
        """The tasks of a stage: each separation's mover vertices against its obstacle's solid,
        or with ``reverse`` the obstacle's vertices against the mover's (None: no task)."""
        wp, d = self.wp, self.device
        movers, pair, columns, obstacles = [], [], [], []
        for k, (a, b) in enumerate(self.separations):
            mover, obstacle = (b, a) if reverse else (a, b)
            v = self.parts.movers(mover, obstacle)
            if obstacle in self.solid_names and len(v):
                movers.append(v)
                pair.append(np.full(len(v), len(obstacles), np.int32))
                columns.append(np.full(len(v), k))
                obstacles.append(obstacle)
        if not movers:
            return None
        v, j, c = np.concatenate(movers), np.concatenate(pair), np.concatenate(columns)
        order = np.lexsort((j, v))  # by vertex, then in the separations' order
        v, j, c = v[order], j[order], c[order]
        first = np.flatnonzero(np.r_[True, v[1:] != v[:-1]])
        skin = [self.parts.skin_faces[self.parts.index(o)] for o in obstacles]
        solid = [len(self.parts.solids[self.parts.index(o)]) for o in obstacles]
        return _Stage(movers=wp.array(v, dtype=wp.int32, device=d),
                      pair=wp.array(j, dtype=wp.int32, device=d),
                      obstacles=tuple(obstacles), skin_faces=wp.array(skin, dtype=wp.int32, device=d),
                      solid_faces=wp.array(solid, dtype=wp.int32, device=d),
                      vertices=wp.array(v[first], dtype=wp.int32, device=d),
                      starts=wp.array(np.r_[first, len(v)], dtype=wp.int32, device=d), columns=c)

    def _space(self, vertices: np.ndarray) -> _Space:
        """The side-by-side solids for chunks of ``vertices`` (T, V, 3): cells as far apart as
        the frames' largest extent plus twice ``max_depth`` and 10 cm."""
        lo, hi = coordinate_bounds(vertices)
        spacing = float((hi - lo).max()) + 2.0 * self.max_depth + 0.1
        frames = min(len(vertices), FRAME_CHUNK["cuda" if str(self.device).startswith("cuda") else "cpu"])
        return _Space(self.wp, self.parts, frames, spacing, lo, self.device)

    def _place(self, space: _Space, x, stage: _Stage) -> None:
        """Put the chunk ``x`` (Warp (frames, V) vec3) into ``space``'s points and refit the
        solids ``stage`` queries."""
        from sim.bodies import intersection_kernels as K

        self.wp.launch(K.frame_points_kernel, dim=(space.frames, space.stride),
                       inputs=[x, self.loop_vertices, self.loop_starts, space.offsets],
                       outputs=[space.points],
                       device=self.device)
        for name in dict.fromkeys(stage.obstacles):
            space.refit(name)

    def _chunks(self, vertices: np.ndarray, space: _Space):
        """``(start, count, x)`` per chunk of ``vertices``: x the chunk on the device, (frames, V)
        vec3, a short last chunk padded with copies of its last frame."""
        for a in range(0, len(vertices), space.frames):
            chunk = vertices[a:a + space.frames]
            pad = space.frames - len(chunk)
            if pad:
                chunk = np.concatenate([chunk, np.repeat(chunk[-1:], pad, axis=0)])
            yield a, space.frames - pad, self.wp.array(chunk, dtype=self.wp.vec3, device=self.device)

    def penetration(self, vertices: np.ndarray) -> np.ndarray:
        """How deep the parts lie in each other: per frame and separation, the deepest vertex
        [m] of the mover in the obstacle's solid and of the obstacle in the mover's, float32
        (T, S, 2) (``separations`` order; 0 where none is inside)."""
        from sim.bodies import intersection_kernels as K

        wp, d = self.wp, self.device
        v = np.ascontiguousarray(vertices, np.float32)
        out = np.zeros((v.shape[0], len(self.separations), 2), np.float32)
        if not len(v):
            return out
        space = self._space(v)
        active = wp.ones(space.frames, dtype=wp.int32, device=d)
        for a, n, x in self._chunks(v, space):
            for side, st in enumerate(self.stages):
                self._place(space, x, st)
                depth = wp.zeros((space.frames, st.movers.shape[0]), dtype=float, device=d)
                wp.launch(K.penetration_kernel, dim=depth.shape,
                          inputs=[space.ids(st.obstacles), st.skin_faces, st.solid_faces, st.movers, st.pair,
                                  space.points, space.stride, active, self.max_depth],
                          outputs=[depth], device=d)
                deepest = np.zeros((space.frames, len(self.separations)), np.float32)
                np.maximum.at(deepest.T, st.columns, depth.numpy().T)
                out[a:a + n, :, side] = deepest[:n]
        return out

    def separate(self, vertices: np.ndarray, *, rounds: int = ROUNDS) -> np.ndarray:
        """The body's frames with its parts moved out of each other.

        A round has two stages: every mover's vertices inside its obstacle's solid (or nearer
        its skin than ``clearance``) go to ``clearance`` off that solid's skin, then every
        obstacle's vertices still inside its (moved) mover's solid go off the mover's skin
        (where the mover's triangles are larger than the obstacle's, the obstacle bulges through
        them). Within a stage every separation reads the same positions. A round after the
        first visits only the frames the one before it moved.

        Args:
            vertices: posed body [m], (T, V, 3).
            rounds: rounds of the two stages.

        Returns:
            float32 (T, V, 3); vertices inside no other part are unchanged.
        """
        v = np.ascontiguousarray(vertices, np.float32)
        out = np.empty_like(v)
        if not len(v):
            return out
        space = self._space(v)
        for a, n, x in self._chunks(v, space):
            self._separate_chunk(space, x, n, rounds)
            out[a:a + n] = x.numpy()[:n]
        return out

    def _separate_chunk(self, space: _Space, x, count: int, rounds: int) -> None:
        """``separate`` of the first ``count`` frames of the chunk ``x``, in place."""
        from sim.bodies import intersection_kernels as K

        wp, d = self.wp, self.device
        active = wp.array((np.arange(space.frames) < count).astype(np.int32), dtype=wp.int32, device=d)
        for _ in range(rounds):
            moved = wp.zeros(space.frames, dtype=wp.int32, device=d)
            for st in self.stages:  # each stage's start is copied to the solids before it moves
                self._place(space, x, st)
                delta = wp.zeros((space.frames, st.movers.shape[0]), dtype=wp.vec3, device=d)
                wp.launch(K.displacement_kernel, dim=delta.shape,
                          inputs=[space.ids(st.obstacles), st.skin_faces, st.solid_faces, st.movers, st.pair,
                                  space.points, space.stride, active, self.max_depth, self.clearance,
                                  TOLERANCE],
                          outputs=[delta], device=d)
                wp.launch(K.apply_displacements_kernel, dim=(space.frames, st.vertices.shape[0]),
                          inputs=[st.vertices, st.starts, delta], outputs=[x, moved], device=d)
            active = moved
            if not moved.numpy().any():
                break


def separate_body_frames(frames: BodyFrames, parts: BodyParts, *, device: str) -> BodyFrames:
    """``frames`` with the body's parts moved out of each other (``PartSeparator.separate``);
    joints and transforms are kept."""
    sep = PartSeparator(parts, device=device)
    return BodyFrames(vertices=sep.separate(frames.vertices), joints=frames.joints,
                      transforms=frames.transforms, faces=frames.faces)
