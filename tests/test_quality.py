"""Quality-gate kernels on exact cases: strain of a scaled mesh, points in a sphere,
crossing vs separated sheets, explosion detection."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sim.quality import (
    QualityGates,
    SimulationError,
    check_frame,
    edge_strain,
    evaluate_sequence,
    inside_fraction,
    mesh_edges,
    push_outside,
    self_intersections,
    unique_edges,
)


def grid(n: int = 6, size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex square sheet in the XZ plane, (V, 3) and (F, 3)."""
    u = np.linspace(0, size, n)
    X, Z = np.meshgrid(u, u, indexing="ij")
    v = np.stack([X.ravel(), np.zeros(n * n), Z.ravel()], axis=1).astype(np.float32)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            f += [[a, b, c], [a, c, d]]
    return v, np.array(f, np.int32)


def test_unique_edges_counts():
    v, f = grid(4)
    # n x n grid with diagonals: 2 n (n-1) axis edges + (n-1)^2 diagonals
    assert unique_edges(f).shape[0] == 2 * 4 * 3 + 9


def test_unique_edges_match_a_row_unique_with_their_face_counts():
    rng = np.random.default_rng(3)
    f = rng.integers(0, 400, size=(900, 3))
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    ref, ref_counts = np.unique(e, axis=0, return_counts=True)
    got, counts = unique_edges(f, counts=True)
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(counts, ref_counts)
    np.testing.assert_array_equal(unique_edges(f), ref)
    assert unique_edges(np.zeros((0, 3), np.int64)).shape == (0, 2)


def test_edge_strain_of_scaled_mesh_is_exact(device):
    v, f = grid(5)
    seq = np.stack([v, v * 1.1, v * 0.8])
    s = edge_strain(seq, v, f, device=device)
    np.testing.assert_allclose(s[0], 0.0, atol=1e-6)
    np.testing.assert_allclose(s[1], 0.1, atol=1e-5)
    np.testing.assert_allclose(s[2], -0.2, atol=1e-5)


def test_edge_strain_of_an_anisotropic_stretch_matches_each_edge(device):
    """``edge_strain`` (the strain the max-strain gate reads): a sheet stretched 10 % along x and
    then squeezed 20 % along y gives its x edges strain 0.1 then 0, its y edges 0 then -0.2, and
    its diagonals the analytic value; every mesh edge appears once."""
    from tests.test_cloth_solver import grid as sheet

    v, f = sheet(4, 3, 0.3, 0.2)
    v = v.astype(np.float64)
    frames = np.stack([v * [1.1, 1.0, 1.0], v * [1.0, 0.8, 1.0]])
    e, strain = unique_edges(f), edge_strain(frames, v, f, device=device)
    assert len(e) == len({tuple(sorted(t)) for t in f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).tolist()})
    d = v[e[:, 1]] - v[e[:, 0]]
    expect = [np.linalg.norm(d * s, axis=1) / np.linalg.norm(d, axis=1) - 1.0
              for s in ([1.1, 1, 1], [1, 0.8, 1])]
    np.testing.assert_allclose(strain, np.stack(expect), atol=1e-6)
    along_x = np.abs(d[:, 1]) < 1e-9
    np.testing.assert_allclose(strain[0, along_x], 0.1, atol=1e-6)
    np.testing.assert_allclose(strain[1, ~along_x & (np.abs(d[:, 0]) < 1e-9)], -0.2, atol=1e-6)


def test_inside_fraction_sphere(device):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.5, 1.5, size=(2000, 3)).astype(np.float32)
    r = np.linalg.norm(pts, axis=1)
    keep = np.abs(r - 1.0) > 0.03  # away from the tessellated surface
    pts = pts[keep]
    expect = float((np.linalg.norm(pts, axis=1) < 1.0).mean())
    got = inside_fraction(pts[None], sphere.vertices, sphere.faces, device=device)
    np.testing.assert_allclose(got[0], expect, atol=1e-9)
    # the body moves away in frame 1: nothing inside
    moved = np.stack([sphere.vertices, sphere.vertices + [10.0, 0, 0]])
    got2 = inside_fraction(np.stack([pts, pts]), moved, sphere.faces, device=device)
    assert got2[0] == pytest.approx(expect) and got2[1] == 0.0


def test_push_outside_moves_exactly_the_inside_points_to_the_surface(device):
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = rng.uniform(0.3, 1.5, size=(500, 1))
    pts = (d * r).astype(np.float32)
    body = np.stack([sphere.vertices, sphere.vertices + [0.0, 0.2, 0.0]])  # moves up in frame 1
    seq = np.stack([pts, pts + [0.0, 0.2, 0.0]]).astype(np.float32)
    out = push_outside(seq, body, sphere.faces, clearance=0.01, device=device)
    for t in range(2):
        c = np.asarray(body[t][0] - sphere.vertices[0])  # the sphere's centre
        rad_in, rad_out = np.linalg.norm(seq[t] - c, axis=1), np.linalg.norm(out[t] - c, axis=1)
        far = rad_in > 1.02  # outside the clearance: untouched
        np.testing.assert_array_equal(out[t][far], seq[t][far])
        # inside points end on the tessellated sphere + 1 cm (facets sit up to 1.2 mm inside r = 1)
        near = rad_in < 0.99
        assert np.all((rad_out[near] > 0.997) & (rad_out[near] < 1.011))
        # ... outward along their own direction (the closest point of a convex body)
        cos = np.einsum("ij,ij->i", (out[t] - c)[near], (seq[t] - c)[near]) / (rad_out[near] * rad_in[near])
        assert cos.min() > 0.99
    assert inside_fraction(out, body, sphere.faces, device=device).max() == 0.0


def test_self_intersections_detects_crossing_sheets(device):
    v, f = grid(6)
    # two parallel sheets 1 cm apart: no crossing
    v2 = v + [0.0, 0.01, 0.0]
    V = np.concatenate([v, v2])
    F = np.concatenate([f, f + len(v)])
    assert self_intersections(V[None], F, device=device)[0] == 0
    # the second sheet stood up through the middle of the first: crossings
    v3 = v[:, [0, 2, 1]] + [0.0, -0.5, 0.0]  # XY plane sheet, spans y in [-0.5, 0.5]
    v3[:, 2] += 0.5 + 1e-3
    V2 = np.concatenate([v, v3])
    n = self_intersections(V2[None], F, device=device)[0]
    assert n >= 2
    # edge_mask: the crossings of the standing sheet's edges and of the lying sheet's add up
    standing = unique_edges(F)[:, 0] >= len(v)
    part = [self_intersections(V2[None], F, device=device, edge_mask=m)[0] for m in (standing, ~standing)]
    assert part[0] > 0 and part[1] > 0 and part[0] + part[1] == n


def test_self_intersections_zero_for_flat_and_folded_sheet(device):
    v, f = grid(8)
    folded = v.copy()
    # fold along x = 0.5 without crossing: the far half lifted into a tent
    m = folded[:, 0] > 0.5
    folded[m, 1] = (folded[m, 0] - 0.5) * 0.8
    assert self_intersections(np.stack([v, folded]), f, device=device).tolist() == [0, 0]


def test_evaluate_sequence_and_gates():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    v, f = grid(6, size=1.0)
    v = v + [-0.5, 0.3, -0.5]  # sheet above the sphere
    seq = np.stack([v, v * [1.0, 1.0, 1.0], v + [0, -0.3, 0]])  # last frame: cuts the sphere
    rep = evaluate_sequence(seq, v, f, sphere.vertices, sphere.faces, device="cpu")
    assert rep.finite
    assert rep.inside_fraction[0] == 0.0 and rep.inside_fraction[2] > 0.0
    fails = rep.failures(QualityGates(max_inside_fraction=0.0))
    assert any("frame 2" in s for s in fails)
    assert rep.failures(QualityGates(max_inside_fraction=1.0)) == []
    d = rep.to_json()
    assert d["max_inside_fraction"] == pytest.approx(rep.inside_fraction.max())


def test_check_frame_names_frame_and_cause():
    p = np.zeros((10, 3))
    check_frame(p, 0)
    p[3, 1] = np.nan
    with pytest.raises(SimulationError, match="frame 7.*NaN"):
        check_frame(p, 7)
    p[3, 1] = 1e6
    with pytest.raises(SimulationError, match="frame 2.*explosion"):
        check_frame(p, 2)


def test_the_strain_gate_reads_compression_as_stretch(device):
    """The max-strain gate takes ``|l / l0 - 1|``: a sheet whose x edges stretch 10 % in frame 0
    and whose z edges are crumpled to 55 % in frame 1 reads 0.45 (the crumpling, not the stretch's
    0.1), fails the 0.35 gate with that figure, and keeps stretch and compression apart."""
    v, f = grid(5)
    frames = np.stack([v * [1.1, 1.0, 1.0], v * [1.0, 1.0, 0.55]]).astype(np.float32)
    rep = evaluate_sequence(frames, v, f, device=device)
    assert rep.max_edge_strain == pytest.approx(0.45, abs=1e-5)
    assert rep.max_stretch == pytest.approx(0.1, abs=1e-5)
    assert rep.max_compression == pytest.approx(0.45, abs=1e-5)
    failures = rep.failures(QualityGates())
    assert len(failures) == 1 and "0.450" in failures[0]
    strain = edge_strain(frames, v, f, device=device)
    np.testing.assert_allclose(np.abs(strain).max(axis=1), [0.1, 0.45], atol=1e-5)
    z_edges = np.abs(np.diff(v[unique_edges(f)][:, :, 0], axis=1))[:, 0] < 1e-6
    np.testing.assert_allclose(strain[1, z_edges], -0.45, atol=1e-5)
    assert (np.abs(strain[1]) > QualityGates().max_edge_strain).sum() == z_edges.sum()


def test_body_crossings_summary_names_joints_frames_and_heights():
    """``sim.quality.summarize_self_crossings``: edges crossing at rest (the default mesh's toes)
    are not counted; the others are counted per frame and grouped by the joint that skins their
    first vertex most, with the frames they cross in and their rest-pose height range."""
    from sim.quality import summarize_self_crossings as summarize

    rest = np.array([[0, 0.0, 0], [0, -0.65, 0], [0, -0.66, 0], [0, -0.35, 0], [0, -1.19, 0]], np.float32)
    edges = np.array([[1, 2], [3, 0], [4, 0]])
    weights = np.zeros((5, 3))
    weights[[1, 2], 1] = 1.0  # the knee
    weights[[0, 3], 2] = 1.0  # the hip
    weights[4, 0] = 1.0       # the foot
    hit = np.zeros((4, 3), bool)
    hit[:, 2] = True          # the foot's edge crosses in every frame, as at rest
    hit[1, 0] = hit[2, 0] = True
    hit[2, 1] = True
    out = summarize(hit, np.array([False, False, True]), edges, rest, weights, ("foot", "knee", "hip"))
    assert out["per_frame"] == [0, 1, 2, 0]
    assert out["frames_with_crossings"] == 2 and out["max_edges"] == 2
    assert set(out["by_joint"]) == {"knee", "hip"}
    assert out["by_joint"]["knee"] == {"frames": [1, 2], "most_edges": 1, "rest_y_m": [-0.655, -0.655]}
    assert out["by_joint"]["hip"]["frames"] == [2] and out["by_joint"]["hip"]["rest_y_m"] == [-0.175, -0.175]
    # only the edges near a garment (here: the hip's): the knee's crossings are not counted
    near = summarize(hit, np.array([False, False, True]), edges, rest, weights, ("foot", "knee", "hip"),
                     edge_mask=np.array([False, True, True]))
    assert near["per_frame"] == [0, 0, 1, 0] and set(near["by_joint"]) == {"hip"}
    empty = summarize(hit[:0], np.array([False, False, True]), edges, rest, weights, ("foot", "knee", "hip"))
    assert empty["per_frame"] == [] and empty["frames_with_crossings"] == 0 and empty["by_joint"] == {}


def test_a_failure_in_the_prelude_is_named_as_such():
    """Frames before the motion's first output frame (the settle, the blend from rest) are
    negative; the message says where that is rather than "frame -5"."""
    from sim.quality import SimulationError

    assert str(SimulationError(3, "x")) == "simulation failed at frame 3: x"
    assert str(SimulationError(0, "x")) == "simulation failed at frame 0: x"
    assert str(SimulationError(-5, "while settling: x")) == (
        "simulation failed 5 frames before the motion's first frame: while settling: x")
    assert str(SimulationError(-1, "x")) == "simulation failed 1 frame before the motion's first frame: x"
    assert SimulationError(-5, "x").frame == -5


def test_sequences_longer_than_a_chunk_give_each_frames_own_result(device):
    """Frames move to the device in blocks (``FRAME_CHUNK``): every frame of a longer sequence
    gets what it gets alone, across the block boundary too."""
    from sim.quality import FRAME_CHUNK

    rng = np.random.default_rng(0)
    v, f = grid(7)
    T = FRAME_CHUNK + 3
    seq = (v + 0.2 * rng.normal(size=(T,) + v.shape)).astype(np.float32)
    per_frame = [int(self_intersections(seq[t:t + 1], f, device=device)[0]) for t in range(T)]
    np.testing.assert_array_equal(self_intersections(seq, f, device=device), per_frame)
    assert sum(per_frame) > 0
    sphere = trimesh.creation.icosphere(2, radius=0.5)
    body = (np.asarray(sphere.vertices)[None] * (1.0 + 0.02 * np.arange(T))[:, None, None]).astype(np.float32)
    pts = (0.5 * rng.normal(size=(T, 40, 3))).astype(np.float32)
    alone = [inside_fraction(pts[t:t + 1], body[t], sphere.faces, device=device)[0] for t in range(T)]
    np.testing.assert_array_equal(inside_fraction(pts, body, sphere.faces, device=device), alone)
    assert 0.0 < np.mean(alone) < 1.0


def test_mesh_edges_are_unique_edges_made_once_per_mesh_content():
    _, f = grid(7)
    e = mesh_edges(f)
    np.testing.assert_array_equal(e, unique_edges(f))
    assert not e.flags.writeable  # shared by every caller
    assert mesh_edges(f.copy()) is e  # equal content, the same array
    other = mesh_edges(f[:-2])
    assert other is not e and len(other) < len(e)
