"""A pattern's flat mesh, its seams and sewing it around a body (pattern_mesh, sewing, designs)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.garments.designs import garment_of
from sim.garments.materials import get_material
from sim.garments.pattern import Edge, Panel, Pattern, Placement, Seam
from sim.garments.pattern_mesh import join_groups, mesh_pattern
from sim.garments.sewing import SewingConfig, sew_pattern
from sim.geometry.primitives import uv_sphere

R_BODY = 0.12
"""Radius [m] of the cylinder the test tube is sewn around."""


def tube_pattern(width: float = 0.42, height: float = 0.3, flare: float = 0.0) -> Pattern:
    """Front and back rectangles (the front's top edge an arc) joined by two side seams into a
    tube around the y axis; each placed on a half cylinder that does not reach the sides."""
    w, h = 0.5 * width, height
    r = R_BODY + 0.05
    panels = []
    for name, sign in (("front", 1.0), ("back", -1.0)):
        corners = np.array([[-w - flare, 0.0], [w + flare, 0.0], [w, h], [-w, h]])
        top = Edge("arc", ((0.6, 0, 0),), "neckline") if name == "front" else Edge(label="neckline")
        edges = (Edge(label="hem"), Edge(label="side"), top, Edge(label="side"))
        placement = Placement(anchor=(0.0, -0.5 * h, sign * r), u_dir=(sign, 0.0, 0.0), curvature=1.0 / r)
        panels.append(Panel(name, corners, edges, placement))
    seams = (Seam(("front", 1), ("back", 3)), Seam(("front", 3), ("back", 1)))
    return Pattern("tube", tuple(panels), seams)


def cylinder_body(radius: float = R_BODY, height: float = 0.6, n: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder around the y axis (outward faces), centred at the origin."""
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([radius * np.cos(a), np.zeros(n), radius * np.sin(a)], axis=1)
    v = np.concatenate([ring + [0, -0.5 * height, 0], ring + [0, 0.5 * height, 0],
                        [[0, -0.5 * height, 0], [0, 0.5 * height, 0]]])
    f = []
    for i in range(n):
        j = (i + 1) % n
        f += [(i, n + j, j), (i, n + i, n + j), (2 * n, i, j), (2 * n + 1, n + j, n + i)]
    return v.astype(np.float32), np.array(f, np.int32)


def test_seams_match_vertex_for_vertex_at_equal_arc_length_fractions():
    pat = tube_pattern(flare=0.03)
    m = mesh_pattern(pat, 0.02)
    for s in pat.seams:
        a, b = m.edge_vertices[s.a], m.edge_vertices[s.b]
        assert len(a) == len(b) >= 2
        for idx in (a, b):
            p = m.flat[idx]
            s_along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
            np.testing.assert_allclose(s_along / s_along[-1], np.linspace(0, 1, len(idx)), atol=1e-9)
    # the two sides of each seam pair start against end (both panels seen from outside)
    pairs = {tuple(p) for p in m.pairs.tolist()}
    a, b = m.edge_vertices[("front", 1)], m.edge_vertices[("back", 3)]
    assert (a[0], b[-1]) in pairs and (a[-1], b[0]) in pairs
    assert m.group_count == len(m.flat) - len(m.pairs)  # every pair joins two vertices once


def test_join_groups_are_connected_components_numbered_by_first_vertex():
    g = join_groups(7, np.array([[5, 1], [3, 5], [6, 4]]))
    np.testing.assert_array_equal(g, [0, 1, 2, 1, 3, 1, 3])


@pytest.fixture(scope="module")
def sewn_tube():
    body_v, body_f = cylinder_body()
    pat = tube_pattern()
    cfg = SewingConfig(close_frames=20, settle_frames=5)
    sewn = sew_pattern(pat, body_v, body_f, 0.02, get_material("cotton"), config=cfg, device="cpu")
    return pat, body_v, sewn


def test_sewing_closes_the_seams_around_the_body_into_one_manifold_tube(sewn_tube):
    pat, body_v, sewn = sewn_tube
    assert sewn.seam_gap <= 1e-3
    f = sewn.faces
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 2
    # a tube: two boundary loops (hem and neckline), Euler characteristic 0
    assert len(sewn.vertices) - len(counts) + len(f) == 0
    # outside the body everywhere, and around it: every direction of the xz plane is covered
    r = np.hypot(sewn.vertices[:, 0], sewn.vertices[:, 2])
    assert r.min() > R_BODY
    ang = np.arctan2(sewn.vertices[:, 2], sewn.vertices[:, 0])
    assert np.histogram(ang, bins=24, range=(-np.pi, np.pi))[0].min() > 0
    # oriented outward: face normals point away from the axis
    tri = sewn.vertices[f].astype(np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    radial = tri.mean(axis=1) * np.array([1.0, 0.0, 1.0])
    assert np.mean(np.sum(n * radial, axis=1) > 0) > 0.99


def test_the_garment_uvs_are_the_flat_pattern_without_distortion(sewn_tube):
    pat, _, sewn = sewn_tube
    g = garment_of(pat, sewn, get_material("cotton"), category="tube", name="tube")
    corners = g.flat_corners()
    flat = sewn.mesh.flat[sewn.mesh.triangles]
    # every face's UV triangle is its pattern triangle, moved (no rotation, no scaling)
    shift = corners - flat
    np.testing.assert_allclose(shift - shift[:, :1], 0.0, atol=2e-6)
    assert g.uvs.min() >= 0.0 and g.uvs.max() <= 1.0
    assert set(g.attachments) == {"hem", "neckline"}
    assert g.panel_names == ("front", "back")


def test_sewing_is_deterministic():
    body_v, body_f = uv_sphere(0.1)
    pat = tube_pattern(width=0.4, height=0.12)
    cfg = SewingConfig(close_frames=6, settle_frames=2)
    runs = [sew_pattern(pat, body_v, body_f, 0.03, get_material("cotton"), config=cfg, device="cpu")
            for _ in range(2)]
    np.testing.assert_array_equal(runs[0].vertices, runs[1].vertices)


def test_rest_edge_lengths_are_the_patterns_for_a_sewn_garment_and_the_meshs_otherwise(sewn_tube):
    import dataclasses

    from sim.quality import unique_edges

    pat, _, sewn = sewn_tube
    g = garment_of(pat, sewn, get_material("cotton"), category="tube", name="tube")
    lengths = g.rest_edge_lengths()
    edges = unique_edges(g.faces)
    flat = sewn.mesh.flat
    # an edge inside a panel: its length in the flat pattern, whatever the sewn shape
    tri = sewn.mesh.triangles[0]
    a, b = sorted(g.faces[0][:2])
    k = np.flatnonzero((edges[:, 0] == a) & (edges[:, 1] == b))[0]
    assert lengths[k] == pytest.approx(np.linalg.norm(flat[tri[1]] - flat[tri[0]]), rel=1e-5)
    plain = dataclasses.replace(g, uv_scale=None)
    sewn_lengths = np.linalg.norm(np.diff(g.rest_vertices[edges], axis=1)[:, 0], axis=1)
    np.testing.assert_allclose(plain.rest_edge_lengths(), sewn_lengths, rtol=1e-6)
    # made once per mesh content, read-only: a copy of the garment in another material shares them
    other = dataclasses.replace(g, material=get_material("jersey_knit"))
    assert other.rest_edge_lengths() is lengths and not lengths.flags.writeable
    doubled = dataclasses.replace(g, uv_scale=2.0 * g.uv_scale)
    assert doubled.rest_edge_lengths()[k] == pytest.approx(2 * lengths[k])


@pytest.mark.slow
def test_a_settle_that_leaves_self_crossings_is_redone_at_more_substeps(monkeypatch):
    """The coarse jersey t-shirt's sleeve underarm folds through itself in the 8-substep settle
    (every sequence made with it would fail the self-intersection gate from frame 0); that
    garment alone settles again at ``resettle_substeps`` and comes out with no crossing edge,
    and the cotton one, clean at 8, keeps its first settle."""
    from sim.bodies import load_body
    from sim.garments import sewing
    from sim.garments.designs import BodyParts, design_params, designs, edge_length
    from sim.garments.sewing import SewingJob, sew_patterns
    from sim.quality import crossing_edges

    settles = []
    original = sewing._settle_batch

    def recorded(jobs, meshes, merged, colliders, cfg, dev):
        out = original(jobs, meshes, merged, colliders, cfg, dev)
        crossing = [int(crossing_edges(x, m.sewn_faces(), device=dev).sum())
                    for x, m in zip(out, meshes, strict=True)]
        settles.append((cfg.substeps, [j.material.name for j in jobs], crossing, out))
        return out

    monkeypatch.setattr(sewing, "_settle_batch", recorded)
    body = load_body()
    rest = np.ascontiguousarray(body.rest_mesh(None), np.float32)
    pattern = designs()["t_shirt"].draft(BodyParts.of(body, None), design_params("t_shirt"))
    h = edge_length("coarse", "t_shirt")
    jobs = [SewingJob(pattern, rest, np.asarray(body.faces), h, get_material(m))
            for m in ("jersey_knit", "cotton")]
    sewn = sew_patterns(jobs, config=SewingConfig(), device="cpu")
    (first_sub, first_mats, first_cross, first_out), (again_sub, again_mats, again_cross, _) = settles
    assert (first_sub, first_mats) == (8, ["jersey_knit", "cotton"])
    assert first_cross[0] > 0 and first_cross[1] == 0  # jersey crosses at 8 substeps, cotton does not
    assert (again_sub, again_mats, again_cross) == (16, ["jersey_knit"], [0])
    assert [int(crossing_edges(s.vertices, s.faces, device="cpu").sum()) for s in sewn] == [0, 0]
    np.testing.assert_array_equal(sewn[1].vertices, first_out[1].astype(np.float32))
