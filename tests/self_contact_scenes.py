"""Scenes and numpy references for the cloth self-contact tests: exact closest points and
distances in float64, sheets in contact, the stacked-layer drop, the hairpin and the fine denim
sheet (``tests/test_self_contact*.py``, ``tests/test_coarse_correction.py``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import warp as wp

from sim.cloth import ClothMaterialParams, ClothModelBuilder, SolverVBD, VBDConfig, apply_overrides
from sim.cloth.model import mesh_edges
from tests.test_cloth_solver import grid

FINE_SHEET = (21, 41, 0.0055)  # columns, rows, edge [m]: a fine garment's edges


# --- numpy references ----------------------------------------------------------------------------


def closest_point_triangle_np(p, a, b, c, n=200):
    """Brute force: the closest point of a dense barycentric sampling of triangle ``abc`` to ``p``
    and its distance (an upper bound within the grid spacing)."""
    s = np.linspace(0.0, 1.0, n)
    u, v = np.meshgrid(s, s)
    m = u + v <= 1.0
    pts = a + u[m, None] * (b - a) + v[m, None] * (c - a)
    d = np.linalg.norm(pts - p, axis=1)
    k = int(np.argmin(d))
    return pts[k], d[k]


def bary_np(p, a, b, c):
    """Exact closest point's barycentric weights (projection, else the nearest edge) in float64."""
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    q = p - np.dot(p - a, n) * n
    m = np.array([b - a, c - a]).T
    uv, *_ = np.linalg.lstsq(m, q - a, rcond=None)
    if uv[0] >= 0 and uv[1] >= 0 and uv.sum() <= 1:
        return np.array([1 - uv.sum(), uv[0], uv[1]])
    best = None
    for (i, j) in ((0, 1), (1, 2), (2, 0)):
        pts = (a, b, c)
        s = np.clip(np.dot(p - pts[i], pts[j] - pts[i]) / np.dot(pts[j] - pts[i], pts[j] - pts[i]), 0, 1)
        w = np.zeros(3)
        w[i], w[j] = 1 - s, s
        d = np.linalg.norm(p - (pts[i] + s * (pts[j] - pts[i])))
        if best is None or d < best[0]:
            best = (d, w)
    return best[1]


def point_triangle_distance_np(p, a, b, c):
    """Exact distance: the plane projection when it falls inside, else the nearest edge."""
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    q = p - ((p - a) @ n) * n
    inside = all(np.cross(v1 - v0, q - v0) @ n >= 0.0 for v0, v1 in ((a, b), (b, c), (c, a)))
    if inside:
        return float(abs((p - a) @ n))

    def to_segment(s0, s1):
        t = np.clip((p - s0) @ (s1 - s0) / ((s1 - s0) @ (s1 - s0)), 0.0, 1.0)
        return float(np.linalg.norm(p - (s0 + t * (s1 - s0))))

    return min(to_segment(a, b), to_segment(b, c), to_segment(c, a))


def segment_closest_np(p1, q1, p2, q2):
    """Segment-segment distance and the closest points' parameters ``s`` on ``p1 q1``, ``t`` on
    ``p2 q2`` (Ericson, Real-Time Collision Detection, 5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = np.dot(d1, d1), np.dot(d2, d2), np.dot(d2, r)
    c, b = np.dot(d1, r), np.dot(d1, d2)
    denom = a * e - b * b
    s = np.clip((b * f - c * e) / denom, 0.0, 1.0) if denom > 1e-18 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, np.clip(-c / a, 0.0, 1.0)
    elif t > 1.0:
        t, s = 1.0, np.clip((b - c) / a, 0.0, 1.0)
    return np.linalg.norm((p1 + s * d1) - (p2 + t * d2)), s, t


def segment_distance_np(p1, q1, p2, q2):
    """Exact segment-segment distance (``segment_closest_np``)."""
    return segment_closest_np(p1, q1, p2, q2)[0]


def contact_pairs_np(x, faces, reach):
    """Vertex-triangle and edge-edge (no shared vertex) pairs closer than ``reach``."""
    vt = [(i, t) for i in range(len(x)) for t, f in enumerate(faces)
          if i not in f and point_triangle_distance_np(x[i], *x[f]) < reach]
    edges = mesh_edges(faces)
    ee = [(a, b) for a in range(len(edges)) for b in range(a + 1, len(edges))
          if not set(edges[a]) & set(edges[b]) and segment_distance_np(*x[edges[a]], *x[edges[b]]) < reach]
    return vt, [(edges[a], edges[b]) for a, b in ee]


def contact_energy_np(x, faces, pairs, radius, k):
    """Sum over vertex-triangle pairs and unordered edge-edge pairs of ``k/2 (radius - d)^2``
    for ``d < radius``."""
    vt, ee = pairs
    e_total = 0.0
    for i, t in vt:
        f = faces[t]
        w = bary_np(x[i], x[f[0]], x[f[1]], x[f[2]])
        d = np.linalg.norm(x[i] - (w[0] * x[f[0]] + w[1] * x[f[1]] + w[2] * x[f[2]]))
        if d < radius:
            e_total += 0.5 * k * (radius - d) ** 2
    for ea, eb in ee:
        d = segment_distance_np(x[ea[0]], x[ea[1]], x[eb[0]], x[eb[1]])
        if d < radius:
            e_total += 0.5 * k * (radius - d) ** 2
    return e_total


# --- the lists of a SelfContact as sets ----------------------------------------------------------


def stored(sc, owners: int, ids: str, count: str) -> set:
    """The (owner, partner) pairs of one of ``sc``'s lists (``ids`` / ``count``: its arrays)."""
    c = getattr(sc.data, count).numpy()
    table = getattr(sc.data, ids).numpy().reshape(owners, -1)
    return {(k, int(table[k, j])) for k in range(owners) for j in range(c[k])}


def all_lists(sc, m) -> dict:
    """Every list of ``sc`` as a set of (owner, partner) pairs, and each vertex's record count."""
    ne = m.mesh_edge_indices.shape[0]
    return {"vt": stored(sc, m.particle_count, "vt_tri", "vt_count"),
            "tv": stored(sc, m.tri_count, "tv_vertex", "tv_count"),
            "ee": stored(sc, ne, "ee_edge", "ee_count"),
            "records": sc.data.pair_count.numpy().tolist()}


# --- scenes ----------------------------------------------------------------------------------------


def two_layers(n: int = 4, gap: float = 0.002, angle: float = 0.5):
    """A flat square sheet and a smaller, rotated sheet ``gap`` above it (one mesh)."""
    v0, f0 = grid(n, n, 0.04, 0.04, plane="xz")
    v1, f1 = grid(n, n, 0.03, 0.03, plane="xz")
    ca, sa = np.cos(angle), np.sin(angle)
    rot = np.array([[ca, 0, -sa], [0, 1, 0], [sa, 0, ca]], dtype=np.float32)
    v1 = (v1 - v1.mean(axis=0)) @ rot.T + v0.mean(axis=0) + np.array([0.001, gap, 0.002], np.float32)
    return np.concatenate([v0, v1]), np.concatenate([f0, f1 + len(v0)]).astype(np.int32)


def jittered_sheets(nx: int, ny: int, e: float, seed: int):
    """An ``nx`` x ``ny`` sheet of spacing ``e`` in the xz plane and a copy shifted in the plane
    at random heights of 2-8 mm above it (one mesh): positions and faces."""
    v1, f1 = grid(nx, ny, (nx - 1) * e, (ny - 1) * e, plane="xz")
    v2 = v1 + np.array([0.4 * e, 0.0, 0.3 * e], np.float32)
    v2[:, 1] = np.random.default_rng(seed).uniform(0.002, 0.008, len(v2))
    return np.concatenate([v1, v2]).astype(np.float32), np.concatenate([f1, f1 + len(v1)]).astype(np.int32)


def folded_sheet(nx: int, ny: int, e: float, mid: int, gap: float):
    """An ``nx`` x ``ny`` grid of spacing ``e`` in the xz plane (its rest shape ``v``) and the
    same sheet folded flat onto itself at column ``mid``: the columns past it lie ``gap``
    above the ones before it. Returns ``v``, the folded positions, the faces and each vertex's
    column."""
    v, f = grid(nx, ny, (nx - 1) * e, (ny - 1) * e, plane="xz")
    col = np.arange(len(v)) % nx
    folded = v.copy()
    over = col > mid
    folded[over, 0] = (2 * mid - col[over]) * e
    folded[over, 1] = gap
    return v, folded, f, col


def three_pieces(device, motion: str):
    """Two instances of a sheet with a jittered sheet over it (the second overlapping the first
    in space) and a smaller piece of another topology in between, with every vertex at its own
    random velocity (``motion`` "still") or the upper layers sliding at 3 m/s ("sliding"): the
    model and the velocities (numpy)."""
    nx, ny, e = 9, 8, 0.012
    v, f = jittered_sheets(nx, ny, e, seed=1)
    half = len(v) // 2
    b = ClothModelBuilder()
    for offset in ((0.0, 0.0, 0.0), (0.05, 0.003, 0.0)):
        b.add_cloth(v + np.array(offset, np.float32), f, ClothMaterialParams())
    vs, fs = grid(3, 3, 2 * e, 2 * e, plane="xz")
    b.add_cloth(np.concatenate([vs, vs + np.array([0.3 * e, 0.004, 0.2 * e], np.float32)]),
                np.concatenate([fs, fs + len(vs)]).astype(np.int32), ClothMaterialParams())
    m = b.finalize(device)
    rng = np.random.default_rng(2)
    if motion == "still":
        vel = rng.normal(0.0, 1.0, (m.particle_count, 3)).astype(np.float32)
    else:
        vel = np.zeros((m.particle_count, 3), np.float32)
        for start in (half, len(v) + half):
            vel[start:start + half] = (3.0, 0.0, 0.0)
    return m, vel


def stacked_layers(device, self_contact: bool, n: int = 13, frames: int = 12, speed: float = 3.0,
                   carry: float = 0.0, reference: bool = False, solver: Mapping[str, Any] | None = None):
    """A sheet pinned at its corners and a second sheet dropped onto it at ``speed`` (one mesh),
    the whole scene, pins included, carried along x at ``carry`` [m/s] (``reference``: that is
    the instance's reference velocity, else zero), at 5 substeps x 5 sweeps; ``solver``: further
    ``"section.field"`` solver settings (``apply_overrides``; no coarse correction unless they
    name one). Returns the positions per frame with the carrying motion taken out, the faces,
    the vertices per sheet and the grid size."""
    v, f = grid(n, n, 0.5, 0.5, plane="xz")
    top = v + np.array([0.011, 0.03, 0.013], np.float32)
    x = np.concatenate([v, top])
    faces = np.concatenate([f, f + len(v)])
    b = ClothModelBuilder()
    b.add_cloth(x, faces, ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.003),
                pinned=[0, n - 1, n * (n - 1), n * n - 1])
    m = b.finalize(device)
    cfg = apply_overrides(VBDConfig(), {"stepping.substeps": 5, "stepping.iterations": 5,
                                        "self_contact.enabled": self_contact, "coarse.sweeps": (),
                                        **(solver or {})})
    vbd = SolverVBD(m, cfg)
    state = m.state()
    u = np.array([carry, 0.0, 0.0], np.float32)
    vel = np.zeros_like(x) + u
    vel[len(v):, 1] = -speed
    state.velocities.assign(vel)
    control = m.control()
    if reference:
        control.instance_velocity.assign(u[None])
    dt = 1.0 / 30.0
    out = []
    for k in range(frames):
        control.pin_targets.assign(x + u * (k + 1) * dt)
        vbd.step(state, state, control, dt)
        out.append(state.positions.numpy() - u * (k + 1) * dt)
    return np.stack(out), faces, len(v), n


def center_gap(x, nv, n):
    """Height of the top sheet above the bottom one at the centre (same grid index)."""
    c = (n // 2) * n + n // 2
    return x[:, nv + c, 1] - x[:, c, 1]


def hairpin_pass(device, gap: float, speed: float = 1.0, frames: int = 8,
                 solver: Mapping[str, Any] | None = None):
    """One sheet folded at rest into a hairpin whose arms lie ``gap`` apart (a crease at a seam,
    as under a t-shirt's arm or at the crotch of trousers), the lower arm pinned and the upper
    one thrown down onto it at ``speed`` [m/s] (10 substeps x 10 sweeps, no coarse correction;
    ``solver``: further ``"section.field"`` solver settings, ``apply_overrides``). Returns, per
    frame, the mean height [m] of the upper arm's interior (away from the fold and the rims)
    above the lower arm, the largest distance [m] of that interior past the fold line (> 0: the
    arm flipped over the fold, off the lower arm) and the kinetic plus gravitational energy [J]
    of the sheet, with the energy at the throw as the last entry."""
    nx, ny, mid, e = 13, 5, 6, 0.02
    _, folded, f, col = folded_sheet(nx, ny, e, mid, gap)
    row = np.arange(len(folded)) // nx
    over = col > mid
    b = ClothModelBuilder()
    b.add_cloth(folded.astype(np.float32), f, ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.001),
                pinned=np.flatnonzero(col < mid))
    m = b.finalize(device)
    cfg = apply_overrides(VBDConfig(), {"stepping.substeps": 10, "stepping.iterations": 10,
                                        "self_contact.enabled": True, "coarse.sweeps": (), **(solver or {})})
    vbd = SolverVBD(m, cfg)
    state, control = m.state(), m.control()
    vel = np.zeros_like(folded)
    vel[over, 1] = -speed
    state.velocities.assign(vel.astype(np.float32))
    control.pin_targets.assign(folded.astype(np.float32))
    interior = (col >= mid + 2) & (col <= nx - 3) & (row > 0) & (row < ny - 1)
    mass = m.particle_mass.numpy().astype(np.float64)
    g = -float(m.gravity[1])

    def energy(x, v):
        return float(0.5 * (mass[:, None] * v.astype(np.float64) ** 2).sum() + g * (mass * x[:, 1]).sum())

    e0 = energy(folded, vel)
    heights, flipped, energies = [], [], []
    for _ in range(frames):
        vbd.step(state, state, control, 1.0 / 30.0)
        x, v = state.positions.numpy(), state.velocities.numpy()
        assert np.all(np.isfinite(x))
        heights.append(float(x[interior, 1].mean()))
        flipped.append(float(x[interior, 0].max() - mid * e))
        energies.append(energy(x, v))
    return np.array(heights), np.array(flipped), np.array(energies + [e0])


def fine_denim_sheet(device, gravity: float = 9.81):
    """A ``FINE_SHEET`` of denim in the plane z = 0 pinned along its top row, under ``gravity``
    [m/s^2]: the model and its rest positions."""
    from sim.cloth.model import as_cloth_params
    from sim.garments.materials import get_material

    nx, ny, e = FINE_SHEET
    v, f = grid(nx, ny, (nx - 1) * e, (ny - 1) * e)
    b = ClothModelBuilder(gravity=(0.0, -gravity, 0.0))
    b.add_cloth(v, f, as_cloth_params(get_material("denim")), pinned=np.arange(nx))
    return b.finalize(device), v


def detect_at(sc, x: np.ndarray, vel: np.ndarray | None = None, h: float = 1.0 / 300.0, **kw) -> None:
    """``sc.detect`` at positions ``x`` with velocities ``vel`` (None: at rest), numpy in."""
    device = sc.model.device
    v = np.zeros_like(x) if vel is None else vel
    sc.detect(wp.array(np.asarray(x, np.float32), dtype=wp.vec3, device=device),
              wp.array(np.asarray(v, np.float32), dtype=wp.vec3, device=device), h, **kw)
