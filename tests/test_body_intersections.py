"""The body's parts moved out of each other (sim/bodies/intersections.py): parts and their closed
solids, the separation against a numpy reference (closest points, winding numbers), two boxes
pushed into each other, and the default body's rest pose left as it is."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim.bodies.intersections import (
    PART_JOINTS,
    BodyParts,
    PartSeparator,
    body_parts,
    joint_parts,
    parts_of,
)

# ------------------------------------------------------------------------ numpy references


def closest_points(p: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Closest point of each triangle (K, 3, 3) to the point p (3,), (K, 3) (Ericson 2005,
    Real-Time Collision Detection, 5.1.5), by the Voronoi region of p."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp, cp = p - b, p - c
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        out = a + ab * (vb * denom)[:, None] + ac * (vc * denom)[:, None]  # face interior
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        t_ab, t_ac = d1 / (d1 - d3), d2 / (d2 - d6)
    regions = [  # later entries win, so vertex regions come last
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * t_bc[:, None]),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[:, None]),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[:, None]),
        ((d6 >= 0) & (d5 <= d6), c), ((d3 >= 0) & (d4 <= d3), b), ((d1 <= 0) & (d2 <= 0), a),
    ]
    for mask, q in regions:
        out = np.where(mask[:, None], q, out)
    return out


def winding_number(p: np.ndarray, tris: np.ndarray) -> float:
    """Winding number of a closed triangle mesh around p: the sum of its triangles' solid angles
    over 4 pi (Van Oosterom and Strackee 1983)."""
    a, b, c = (tris[:, k] - p for k in range(3))
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = la * lb * lc + (a * b).sum(1) * lc + (b * c).sum(1) * la + (c * a).sum(1) * lb
    return float(2.0 * np.arctan2(num, den).sum() / (4.0 * np.pi))


def reference_stage(x: np.ndarray, parts: BodyParts, pairs, clearance: float, max_depth: float) -> np.ndarray:
    """One stage of ``PartSeparator.separate`` in numpy: each mover vertex inside its obstacle's
    solid or nearer its skin than ``clearance`` goes to ``clearance`` off the closest skin point,
    unless that point is on a cap; every pair reads the same positions."""
    pts = parts.cap_points(x).astype(np.float64)
    out = np.array(x, np.float64)
    for mover, obstacle in pairs:
        k = parts.index(obstacle)
        tris = pts[parts.solids[k]]
        for i in parts.movers(mover, obstacle):
            c = closest_points(pts[i], tris)
            d = np.linalg.norm(pts[i] - c, axis=1)
            f = int(np.argmin(d))
            if d[f] > max_depth or f >= parts.skin_faces[k]:
                continue
            sign = -1.0 if winding_number(pts[i], tris) > 0.5 else 1.0
            if sign * d[f] < clearance:
                out[i] += c[f] + clearance * sign * (pts[i] - c[f]) / d[f] - pts[i]
    return out


def reference_separate(x, parts, pairs, *, rounds: int, clearance: float, max_depth: float) -> np.ndarray:
    for _ in range(rounds):
        x = reference_stage(x, parts, pairs, clearance, max_depth)
        x = reference_stage(x, parts, [(b, a) for a, b in pairs], clearance, max_depth)
    return x


# ------------------------------------------------------------------------------- meshes


def box(lo, hi, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed box from ``lo`` to ``hi`` [m], each face an n x n grid of quads, outward-wound."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    verts, faces, index = [], [], {}

    def vid(p):
        key = tuple(np.round(p, 9))
        if key not in index:
            index[key] = len(verts)
            verts.append(p)
        return index[key]

    s = np.linspace(0.0, 1.0, n + 1)
    for axis in range(3):
        for side in (0, 1):
            u, v = (axis + 1) % 3, (axis + 2) % 3
            grid = np.empty((n + 1, n + 1), int)
            for i, a in enumerate(s):
                for j, b in enumerate(s):
                    p = lo.copy()
                    p[axis] = (lo if side == 0 else hi)[axis]
                    p[u] = lo[u] + a * (hi[u] - lo[u])
                    p[v] = lo[v] + b * (hi[v] - lo[v])
                    grid[i, j] = vid(p)
            for i in range(n):
                for j in range(n):
                    q = (grid[i, j], grid[i + 1, j], grid[i + 1, j + 1], grid[i, j + 1])
                    tri = [(q[0], q[1], q[2]), (q[0], q[2], q[3])]
                    faces += tri if side == 1 else [t[::-1] for t in tri]
    return np.asarray(verts, np.float32), np.asarray(faces, np.int32)


def two_part_body(va, fa, vb, fb) -> tuple[np.ndarray, BodyParts]:
    """Two closed meshes as the parts ``a`` and ``b`` of one body (no caps)."""
    x = np.concatenate([va, vb]).astype(np.float32)
    parts = BodyParts(names=("a", "b"),
                      vertex_part=np.repeat(np.int32([0, 1]), [len(va), len(vb)]),
                      solids=(fa.astype(np.int32), (fb + len(va)).astype(np.int32)),
                      skin_faces=(len(fa), len(fb)), loop_vertices=np.zeros(0, np.int32),
                      loop_starts=np.zeros(1, np.int32))
    return x, parts


def bent_tube(angle: float, n_around: int = 12, n_along: int = 13, radius: float = 0.05,
              half: float = 0.3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A closed tube along x from -half to +half, its x > 0 half turned by ``angle`` [rad] about
    the z axis through the origin (a joint bent as a knee bends): (rest vertices, posed
    vertices, faces)."""
    xs = np.linspace(-half, half, n_along)
    t = 2.0 * np.pi * np.arange(n_around) / n_around
    ring = np.stack([np.zeros_like(t), radius * np.cos(t), radius * np.sin(t)], 1)
    v = np.concatenate([ring + [x, 0.0, 0.0] for x in xs] + [[[-half, 0, 0], [half, 0, 0]]])
    f = []
    for i in range(n_along - 1):
        for j in range(n_around):
            a, b = i * n_around + j, i * n_around + (j + 1) % n_around
            f += [(a, b + n_around, b), (a, a + n_around, b + n_around)]
    end0, end1 = len(v) - 2, len(v) - 1
    last = (n_along - 1) * n_around
    for j in range(n_around):
        f += [(end0, j, (j + 1) % n_around), (end1, last + (j + 1) % n_around, last + j)]
    f = np.asarray(f, np.int32)[:, ::-1]  # outward
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    posed = np.where(v[:, :1] > 1e-9, v @ rot.T, v)
    # off the grid by up to 1 mm: no point is equally near two faces of the other part
    posed += np.random.default_rng(3).uniform(-1e-3, 1e-3, posed.shape)
    return v.astype(np.float32), posed.astype(np.float32), f


def signed_volume(points: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (points[faces[:, k]].astype(np.float64) for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def directed_edges_closed(faces: np.ndarray) -> bool:
    """Every directed edge's reverse is in the mesh exactly once, and no directed edge twice."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    fwd = e[:, 0] * (1 << 32) + e[:, 1]
    rev = e[:, 1] * (1 << 32) + e[:, 0]
    return len(np.unique(fwd)) == len(fwd) and bool(np.all(np.isin(rev, fwd)))


# -------------------------------------------------------------------------------- tests


def test_joints_not_named_take_their_ancestors_part():
    names = ("pelvis", "left_hip", "spine1", "jaw", "left_shoulder", "left_elbow", "left_index1",
             "left_index2", "right_knee")
    parents = np.array([-1, 0, 0, 2, 2, 4, 5, 6, 0])
    got = [list(PART_JOINTS)[k] for k in joint_parts(names, parents)]
    assert got == ["torso", "left_thigh", "torso", "torso", "left_upper_arm", "left_forearm",
                   "left_forearm", "left_forearm", "right_shin"]


def test_default_body_parts_close_into_solids_that_add_up_to_the_body():
    from sim.bodies import load_body

    body = load_body()
    parts = parts_of(body)
    rest = parts.cap_points(body.rest_mesh())
    volumes = []
    for name, solid, skin in zip(parts.names, parts.solids, parts.skin_faces, strict=True):
        assert skin > 0 and len(solid) > skin, name  # every part has skin and at least one cap
        assert directed_edges_closed(solid), name
        volumes.append(signed_volume(rest, solid))
    assert min(volumes) > 0.0  # outward-oriented
    # a cap between two parts is the other part's cap reversed: the solids tile the body
    np.testing.assert_allclose(sum(volumes), signed_volume(rest, body.faces), rtol=1e-3)
    assert np.bincount(parts.vertex_part, minlength=len(PART_JOINTS)).min() > 100


def test_default_body_at_rest_is_left_as_it_is():
    from sim.bodies import load_body

    body = load_body()
    rest = body.rest_mesh()[None]
    sep = PartSeparator(parts_of(body), device="cpu")
    np.testing.assert_array_equal(sep.penetration(rest), 0.0)
    np.testing.assert_array_equal(sep.separate(rest), rest)


@pytest.mark.parametrize("clearance", [0.0, 0.004])
def test_bent_tube_separation_matches_the_numpy_reference(clearance, device):
    rest, posed, faces = bent_tube(np.radians(150.0))
    weights = np.stack([rest[:, 0] <= 1e-9, rest[:, 0] > 1e-9], 1).astype(np.float32)
    parts = body_parts(faces, weights, ("pelvis", "left_hip"), np.array([-1, 0]))
    assert parts.num_caps == 2
    pairs = (("left_thigh", "torso"),)
    sep = PartSeparator(parts, pairs, device=device, clearance=clearance)
    got = sep.separate(posed[None], rounds=2)[0]
    want = reference_separate(posed, parts, pairs, rounds=2, clearance=clearance, max_depth=sep.max_depth)
    assert np.abs(want - posed).max() > 0.02  # the bend sinks the thigh centimetres deep
    np.testing.assert_allclose(got, want, atol=2e-6)


def test_frames_separated_side_by_side_match_each_frame_alone(device, monkeypatch):
    """A motion's frames are separated chunk by chunk in one set of solids (three per chunk
    here, the last chunk padded): each frame comes out as the numpy reference separates it
    alone. The bends are those where every axis ray the inside test casts is unambiguous: at
    120 degrees the thigh's cap folds and a torso vertex 15 mm inside the thigh is called
    outside or inside depending on the frames' placement (round-off)."""
    import sim.bodies.intersections as intersections

    monkeypatch.setitem(intersections.FRAME_CHUNK, "cuda" if device.startswith("cuda") else "cpu", 3)
    angles = (135.0, 140.0, 145.0, 150.0, 160.0)
    poses = [bent_tube(np.radians(a)) for a in angles]
    rest, _, faces = poses[0]
    weights = np.stack([rest[:, 0] <= 1e-9, rest[:, 0] > 1e-9], 1).astype(np.float32)
    parts = body_parts(faces, weights, ("pelvis", "left_hip"), np.array([-1, 0]))
    pairs = (("left_thigh", "torso"),)
    sep = PartSeparator(parts, pairs, device=device, clearance=0.004)
    frames = np.stack([p[1] for p in poses])
    got = sep.separate(frames, rounds=2)
    for t in range(len(angles)):
        want = reference_separate(frames[t], parts, pairs, rounds=2, clearance=0.004, max_depth=sep.max_depth)
        np.testing.assert_allclose(got[t], want, atol=5e-6, err_msg=f"{angles[t]} degrees")
    depth = sep.penetration(frames)
    assert depth.shape == (len(angles), 1, 2) and (depth[:, 0, 0] > 0.01).all()  # deeper the more it bends
    assert np.all(np.diff(depth[:, 0, 0]) > 0)
    assert sep.penetration(got).max() < 0.1 * depth.min()  # two rounds leave a fraction of a millimetre


def test_boxes_pushed_into_each_other_come_apart_and_the_rest_stays(device):
    va, fa = box([-0.2, -0.2, -0.2], [0.0, 0.2, 0.2], 6)
    vb, fb = box([-0.03, -0.1, -0.1], [0.17, 0.1, 0.1], 6)  # 3 cm into a
    x, parts = two_part_body(va, fa, vb, fb)
    sep = PartSeparator(parts, (("b", "a"),), device=device, clearance=0.004)
    np.testing.assert_allclose(sep.penetration(x[None])[0, 0], [0.03, 0.03], atol=1e-6)
    y = sep.separate(x[None])[0]
    np.testing.assert_array_equal(sep.penetration(y[None]), 0.0)
    ya, yb = y[: len(va)], y[len(va):]
    assert max(winding_number(p, ya[fa]) for p in yb) < 0.5  # no vertex of one inside the other
    assert max(winding_number(p, yb[fb]) for p in ya) < 0.5
    far = (x[:, 0] > 0.03) | (x[:, 0] < -0.06)  # 3 cm and more from the overlap
    np.testing.assert_array_equal(y[far], x[far])
    moved = np.abs(y - x).max(axis=1) > 0
    # b yields: its vertices inside a or within 4 mm of its side (its face and the ring next to
    # it, 3.3 mm out) go 4 mm off a's side; a stays
    np.testing.assert_array_equal(moved, np.r_[np.zeros(len(va), bool), vb[:, 0] < 0.004])
    np.testing.assert_allclose(yb[moved[len(va):], 0], 0.004, atol=1e-6)
    none = x[None][:0]  # no frames: nothing to do
    assert sep.separate(none).shape == (0, len(x), 3) and sep.penetration(none).shape == (0, 1, 2)


def caught_curtain(separate: bool, overlap: float = 0.03, frames: int = 20):
    """A cotton curtain hanging in the 3 cm gap between a torso (a box, its side at x = 0) and an
    arm (a box) that moves into the torso by ``overlap`` [m] over 10 frames, simulated with the
    cloth solver against the body as it is or with its parts separated. Returns the curtain's
    positions (frames, N, 3), its edge strain (frames, E) and the arm's vertices (T, V_arm, 3)."""
    from sim.cloth import BodyCollider, ClothModelBuilder, SolverVBD
    from sim.cloth.model import as_cloth_params
    from sim.garments.materials import get_material
    from sim.quality import edge_strain
    from tests.test_cloth_solver import grid, plain_config

    va, fa = box([-0.3, -0.3, -0.15], [0.0, 0.3, 0.15], 6)
    vb, fb = box([0.03, -0.25, -0.1], [0.23, 0.25, 0.1], 6)
    x0, parts = two_part_body(va, fa, vb, fb)
    body = np.repeat(x0[None], frames + 1, axis=0)
    body[:, len(va):, 0] -= (np.minimum(np.arange(frames + 1) / 10.0, 1.0) * (0.03 + overlap))[:, None]
    if separate:
        body = PartSeparator(parts, (("b", "a"),), device="cpu", clearance=0.004).separate(body)
    v, f = grid(9, 9, 0.2, 0.2)  # 20 cm square in the plane x = 15 mm, its top row pinned above the arm
    v = np.stack([np.full(len(v), 0.015), v[:, 1] + 0.29, v[:, 0] - 0.1], axis=1).astype(np.float32)
    b = ClothModelBuilder()
    b.add_cloth(v, f, as_cloth_params(get_material("cotton")), pinned=np.arange(9))
    model = b.finalize("cpu")
    collider = BodyCollider(body[0], np.concatenate([fa, fb + len(va)]), device="cpu")
    control = model.control()
    control.set_body(0, collider)
    solver, state, out = SolverVBD(model, plain_config(10, 5)), model.state(), []
    for k in range(frames):
        collider.set_frame(body[k], body[k + 1])
        solver.step(state, state, control, 1.0 / 30.0)
        out.append(state.positions.numpy().copy())
    out = np.stack(out)
    return out, edge_strain(out, v, f, device="cpu"), body[:, len(va):]


def test_cloth_caught_between_parts_that_pass_through_each_other_keeps_its_length_when_they_are_separated():
    from sim.quality import QualityGates

    gate = QualityGates().max_edge_strain
    x, strain, _ = caught_curtain(separate=False)
    # the arm sinks 3 cm into the torso and drags the curtain in with it: overstretched
    assert np.abs(strain).max() > gate
    assert x[-1, :, 0].min() < -0.02
    x, strain, arm = caught_curtain(separate=True)
    assert np.all(np.isfinite(x))
    assert np.abs(strain).max() < 0.1 * gate
    # the arm's face stops 4 mm off the torso's side, and the curtain lies between them (the
    # penalty contact lets it a fraction of a millimetre into the torso)
    np.testing.assert_allclose(arm[-1, :, 0].min(), 0.004, atol=1e-6)
    assert x[-1, :, 0].min() > -0.001


def test_the_simulation_separates_its_body_when_its_config_says_so(monkeypatch):
    """``prepare_track`` hands the skinned body to ``separate_body_frames`` with
    ``separate_body_parts`` on (the default) and uses what it returns; off, the body is as
    skinned. The dataset record names the separation's settings."""
    from types import SimpleNamespace

    import sim.bodies.intersections as intersections
    from sim.bodies import load_body
    from sim.motions import load_motion
    from sim.simulate import SimulationConfig, simulator_defaults
    from sim.simulate.jobs import SimulationJob
    from sim.simulate.prelude import prepare_track

    calls = []

    def marked(frames, parts, *, device):
        calls.append(parts)
        return dataclasses.replace(frames, vertices=frames.vertices + np.float32(1.0))

    monkeypatch.setattr(intersections, "separate_body_frames", marked)
    body = load_body()
    garment = SimpleNamespace(rest_vertices=body.rest_mesh()[:4], attachments={}, num_vertices=4)
    job = SimulationJob(garment, body, load_motion("walk", duration=0.2))
    fast = dict(settle_seconds=0.1, blend_seconds=0.1, device="cpu")
    on = prepare_track(job, SimulationConfig(**fast), "cpu", {})
    off = prepare_track(job, SimulationConfig(**fast, separate_body_parts=False), "cpu", {})
    assert len(calls) == 1 and calls[0].names == tuple(PART_JOINTS)
    np.testing.assert_allclose(on.frames.vertices, off.frames.vertices + 1.0, atol=1e-5)
    cfg = SimulationConfig(separate_body_parts=False)
    assert SimulationConfig.from_dict(cfg.to_dict()) == cfg
    record = simulator_defaults()["body_separation"]
    assert record["on"] is True and ["left_thigh", "torso"] in record["separations"]
    assert record["clearance_m"] == intersections.CLEARANCE and record["rounds"] == intersections.ROUNDS
