"""Skirts and trousers drafted from body measurements (sim.garments.drafting.bottoms, .trousers):
outlines, girths against the body's plus ease, seam lengths, placement, and sewing on the body."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.garments.drafting.bottoms import (
    PanelRow,
    SkirtDesign,
    bottom_ease,
    draft_skirt,
    girth_at,
    placement_rows,
    waist_shaping,
)
from sim.garments.drafting.trousers import PantsDesign, draft_pants
from sim.garments.flat_mesh import first_crossing
from sim.garments.pattern import Placement
from sim.garments.pattern_mesh import mesh_pattern

GIRTH_TOL = 0.005
"""Drafted girths equal the body's plus ease within 5 mm (the issue's fit tolerance)."""


@pytest.fixture(scope="module")
def parts():
    from sim.bodies import load_body
    from sim.garments.designs import BodyParts

    return BodyParts.of(load_body())


def skirt(parts, **kw):
    return draft_skirt(parts.measurements, parts.vertices, parts.torso_mask, parts.joints, SkirtDesign(**kw))


def pants(parts, **kw):
    return draft_pants(parts.measurements, parts.vertices, parts.torso_mask, parts.joints, PantsDesign(**kw))


DESIGNS = [("skirt", {}), ("skirt", {"flare": 0.6, "length": 0.75, "fit": "loose"}),
           ("skirt", {"flare": 1.0, "fit": "tight"}), ("pants", {}), ("pants", {"length": 0.2}),
           ("pants", {"fit": "loose", "flare": 0.4, "waist_drop": 0.08})]


def drafted(parts, kind, kw):
    return skirt(parts, **kw) if kind == "skirt" else pants(parts, **kw)


def width_at(panel, y: float) -> float:
    """The panel's extent along x where the horizontal line at panel height ``y`` crosses its
    outline [m] (taken a nanometre lower, so that a corner on the line counts once)."""
    y = y - 1e-9
    p = panel.outline(64)
    q = np.roll(p, -1, axis=0)
    hit = (p[:, 1] - y) * (q[:, 1] - y) < 0
    t = (y - p[hit, 1]) / (q[hit, 1] - p[hit, 1])
    x = p[hit, 0] + t * (q[hit, 0] - p[hit, 0])
    assert len(x) == 2, f"{panel.name}: the line y = {y} crosses the outline {len(x)} times"
    return float(x.max() - x.min())


def waist_length(pattern, panels) -> float:
    return sum(pattern.panel(n).edge_length(i) for n, i in pattern.labelled("waist") if n in panels)


@pytest.mark.parametrize(("kind", "kw"), DESIGNS)
def test_outlines_close_counter_clockwise_without_crossing_and_mesh(parts, kind, kw):
    pat = drafted(parts, kind, kw)
    for p in pat.panels:
        last = p.edge_curve(len(p.edges) - 1, 8)
        np.testing.assert_allclose(last[-1], p.corners[0], atol=1e-12)
        assert p.area() > 0
        assert first_crossing(p.outline(32)) is None, p.name
    m = mesh_pattern(pat, 0.02)
    assert len(m.triangles) > 0 and len(np.unique(m.vertex_panel)) == len(pat.panels)


@pytest.mark.parametrize(("kind", "kw"), DESIGNS)
def test_every_seam_joins_edges_of_equal_length(parts, kind, kw):
    pat = drafted(parts, kind, kw)
    for s in pat.seams:
        la, lb = pat.panel(s.a[0]).edge_length(s.a[1]), pat.panel(s.b[0]).edge_length(s.b[1])
        np.testing.assert_allclose(la, lb, atol=1e-4, err_msg=str(s))
    labels = {pat.panel(n).edges[i].label for s in pat.seams for n, i in (s.a, s.b)}
    assert {"waist", "side"} <= labels
    # openings: the hem(s) and the waistband's top edge, which sewing holds
    free = {pat.panel(n).edges[i].label for n, i in pat.free_edges()}
    assert free == {"hem", "waistband"}


@pytest.mark.parametrize("fit", ["tight", "regular", "loose"])
def test_skirt_girths_are_the_body_plus_ease(parts, fit):
    m = parts.measurements
    d = SkirtDesign(fit=fit)
    pat = skirt(parts, fit=fit)
    hem_y = m.waist_height - d.length
    hip = sum(width_at(pat.panel(n), m.hip_height - hem_y) for n in ("front", "back"))
    np.testing.assert_allclose(hip, m.hip + bottom_ease("hip", fit), atol=GIRTH_TOL)
    waist = m.waist + bottom_ease("waist", fit)
    # darts closed: the waist edges between the darts, and the band sewn to them
    np.testing.assert_allclose(waist_length(pat, ("front", "back")), waist, atol=GIRTH_TOL)
    np.testing.assert_allclose(waist_length(pat, ("band_front", "band_back")), waist, atol=GIRTH_TOL)
    assert len(pat.darts) == 4
    # the back darts are wider and longer than the front ones
    front = pat.panel("front")
    back = pat.panel("back")
    df = min(front.corners[[i for i, e in enumerate(front.edges) if e.label == "dart"]][:, 1])
    db = min(back.corners[[i for i, e in enumerate(back.edges) if e.label == "dart"]][:, 1])
    assert db < df


@pytest.mark.parametrize("flare", [0.5, 1.0])
def test_flared_skirts_keep_the_waist_and_clear_the_hips(parts, flare):
    m = parts.measurements
    d = SkirtDesign(flare=flare, length=0.7)
    pat = skirt(parts, flare=flare, length=0.7)
    waist = m.waist + bottom_ease("waist", "regular")
    np.testing.assert_allclose(waist_length(pat, ("front", "back")), waist, atol=GIRTH_TOL)
    hem_y = m.waist_height - d.length
    hip = sum(width_at(pat.panel(n), m.hip_height - hem_y) for n in ("front", "back"))
    assert hip >= m.hip + bottom_ease("hip", "regular") - 1e-9
    # darts shrink with flare and vanish at 1; the hem widens
    assert len(pat.darts) == (0 if flare == 1.0 else 4)
    hem = sum(pat.panel(n).edge_length(0) for n in ("front", "back"))
    assert hem > hip + 0.1 * flare
    # the hem meets the side seams at right angles (it hangs level), and at flare 1 the waist too
    front = pat.panel("front")
    for i in (0, 2) if flare == 1.0 else (0,):  # the hem's end, the waist's side end (edge 2's end)
        side = front.edge_curve(1 if i == 0 else 2, 64)
        curve = front.edge_curve(0, 64) if i == 0 else front.edge_curve(3, 64)
        a = side[1] - side[0] if i == 0 else side[-1] - side[-2]
        b = curve[-1] - curve[-2] if i == 0 else curve[1] - curve[0]
        cos = abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b)
        assert cos < 0.08, (i, cos)


@pytest.mark.parametrize("fit", ["tight", "regular", "loose"])
def test_trouser_girths_are_the_body_plus_ease(parts, fit):
    m = parts.measurements
    d = PantsDesign(fit=fit, waist_drop=0.0)
    pat = pants(parts, fit=fit, waist_drop=0.0)
    legs = ("front_l", "front_r", "back_l", "back_r")
    crotch = m.crotch_height - bottom_ease("crotch", fit)
    hem_y = crotch - d.length * (m.crotch_height - m.ankle_height)
    hip = sum(width_at(pat.panel(n), m.hip_height - hem_y) for n in legs)
    np.testing.assert_allclose(hip, m.hip + bottom_ease("hip", fit), atol=GIRTH_TOL)
    waist = m.waist + bottom_ease("waist", fit)
    np.testing.assert_allclose(waist_length(pat, legs), waist, atol=GIRTH_TOL)
    np.testing.assert_allclose(waist_length(pat, ("band_front", "band_back")), waist, atol=GIRTH_TOL)
    # crotch extensions beyond the centre line: hip/16 in front, hip/10 at the back
    hip_g = m.hip + bottom_ease("hip", fit)
    front, back = pat.panel("front_l"), pat.panel("back_r")
    extension = []
    for p in (front, back):
        curve = [i for i, e in enumerate(p.edges) if e.kind == "cubic" and e.label == "crotch"][0]
        extension.append(p.corners[curve, 0] - p.corners[curve + 1, 0])  # centre at the hip to the fork
    np.testing.assert_allclose(extension, [hip_g / 16, hip_g / 10], atol=1e-9)
    # the centre back rises above the side seam's waist point
    top = [back.corners[:, 1].max(), front.corners[:, 1].max()]
    assert top[0] - top[1] > 0.02


def test_trouser_legs_are_mirror_images_and_the_back_seat_is_longer(parts):
    pat = pants(parts)
    fl, fr = pat.panel("front_l"), pat.panel("front_r")
    np.testing.assert_allclose(np.sort(fl.corners[:, 0]), np.sort(-fr.corners[:, 0]), atol=1e-12)
    crotch = [sum(p.edge_length(i) for i, e in enumerate(p.edges) if e.label == "crotch")
              for p in (fl, pat.panel("back_l"))]
    assert crotch[1] > crotch[0] + 0.03


def test_shorts_hem_lies_between_crotch_and_knee_and_trousers_above_the_ankle(parts):
    m = parts.measurements
    for kw, lo, hi in (({"length": 0.2}, m.knee_height, m.crotch_height),
                       ({}, m.ankle_height + 0.01, m.knee_height)):
        pat = pants(parts, **kw)
        p = pat.panel("front_l")
        hem = p.placement.place(p.corners[:2])[:, 1]
        assert np.all((hem > lo) & (hem < hi)), (kw, hem)


def test_waist_shaping_shares_the_difference_and_keeps_the_side_seams_equal():
    s = waist_shaping((0.26, 0.27), 0.2, (0.3, 0.5), (0.01, 0.02))
    total = 0.26 + 0.27 - 0.4
    np.testing.assert_allclose(sum(s.darts) + sum(s.centre) + 2 * s.side, total, atol=1e-12)
    np.testing.assert_allclose(s.waist[0] + s.waist[1], 0.4, atol=1e-12)
    np.testing.assert_allclose(s.darts, [0.3 * total / 2, 0.5 * total / 2], atol=1e-12)
    flat = waist_shaping((0.2, 0.2), 0.22, (0.3, 0.5))  # a waist wider than the hips: no darts
    assert flat.darts == (0.0, 0.0) and flat.side < 0


def test_girth_between_waist_and_hip_is_linear_in_height(parts):
    m = parts.measurements
    mid = 0.5 * (m.waist_height + m.hip_height)
    np.testing.assert_allclose(girth_at(m, mid), 0.5 * (m.waist + m.hip), atol=1e-12)
    assert girth_at(m, m.waist_height + 0.1) == pytest.approx(m.waist)
    assert girth_at(m, m.hip_height - 0.1) == pytest.approx(m.hip)


def test_row_placement_is_each_rows_at_its_height_and_keeps_the_span_share_between():
    low = Placement((0.0, 0.0, 0.2), curvature=5.0)
    high = Placement((0.0, 0.5, 0.1), curvature=10.0, origin=(0.0, 0.3))
    rows = placement_rows([PanelRow(0.0, low, -0.2, 0.2), PanelRow(0.3, high, -0.1, 0.1)])
    pts = np.array([[0.15, -0.1], [0.15, 0.0], [0.05, 0.3], [0.05, 0.4]])
    np.testing.assert_allclose(rows.place(pts[:2]), low.place(pts[:2]), atol=1e-12)
    np.testing.assert_allclose(rows.place(pts[2:]), high.place(pts[2:]), atol=1e-12)
    # halfway up, the span's right end is at x = 0.15: the rows' right ends, blended
    mid = rows.place(np.array([[0.15, 0.15]]))[0]
    ends = 0.5 * (low.place(np.array([[0.2, 0.0]]))[0] + high.place(np.array([[0.1, 0.3]]))[0])
    np.testing.assert_allclose(mid, ends, atol=1e-12)
    # a curved row (a flared skirt's waist) is placed level: its ends at the row's height
    curved = placement_rows([PanelRow(0.0, low, 0.0, 0.2), PanelRow(0.3, high, 0.0, 0.1, rise=0.04)])
    ends = curved.place(np.array([[0.1, 0.34], [-0.1, 0.34], [0.0, 0.3], [0.1, 0.35]]))
    np.testing.assert_allclose(ends, high.place(np.array([[0.1, 0.3], [-0.1, 0.3], [0.0, 0.3], [0.1, 0.31]])),
                               atol=1e-12)


def test_row_placement_ends_a_curved_side_where_the_rows_place_their_sides():
    low = Placement((0.0, 0.0, 0.2), curvature=5.0)
    high = Placement((0.0, 0.5, 0.1), curvature=10.0, origin=(0.0, 0.3))
    rows = [PanelRow(0.0, low, 0.0, 0.2), PanelRow(0.3, high, 0.0, 0.1)]
    bulge = lambda y: 0.2 - 0.1 * (y / 0.3) ** 0.5  # noqa: E731  (a convex hip curve)
    side = tuple((y, bulge(y)) for y in np.linspace(0.0, 0.3, 301))
    curved = placement_rows(rows, side)
    for y in (0.05, 0.15, 0.25):
        t = y / 0.3
        ends = (1 - t) * low.place(np.array([[0.2, 0.0]]))[0] + t * high.place(np.array([[0.1, 0.3]]))[0]
        np.testing.assert_allclose(curved.place(np.array([[bulge(y), y]]))[0], ends, atol=1e-6)
        # the linear blend of the spans wraps the bulging side past the rows' sides
        assert np.linalg.norm(placement_rows(rows).place(np.array([[bulge(y), y]]))[0] - ends) > 0.005


def test_skirt_panels_side_seams_are_placed_together(parts):
    """Front and back meet at the side seam when placed: no overlap to cross when sewn."""
    m = mesh_pattern(skirt(parts), 0.02)
    a, b = m.pairs.T
    pa, pb = m.vertex_panel[a], m.vertex_panel[b]
    front_back = (pa <= 1) & (pb <= 1) & (pa != pb)
    assert front_back.sum() > 20
    gap = np.linalg.norm(m.placed[a[front_back]] - m.placed[b[front_back]], axis=1)
    assert gap.max() < 1e-4  # the side sampled at 33 points: 13 um between them


def test_placed_panels_stay_near_their_flat_lengths_and_legs_apart(parts):
    # measured on the default body: straight skirt median 0.03 %, p90 3.4 % (the hip curve's
    # width placed between the rows' sides); trousers (the leg cone's shear, the blend under the
    # seat) median 1.2 %, p90 5.5 %
    for pat, p90 in ((skirt(parts), 0.04), (pants(parts), 0.07)):
        m = mesh_pattern(pat, 0.02)
        e = np.concatenate([m.triangles[:, [0, 1]], m.triangles[:, [1, 2]]])
        ratio = (np.linalg.norm(np.diff(m.placed[e], axis=1)[:, 0], axis=1)
                 / np.linalg.norm(np.diff(m.flat[e], axis=1)[:, 0], axis=1))
        assert np.median(np.abs(ratio - 1)) < 0.015, pat.name
        assert np.percentile(np.abs(ratio - 1), 90) < p90, pat.name
    # below the crotch each leg's panels stay on their own side of the body's mid-plane
    m = mesh_pattern(pat, 0.02)
    names = [p.name for p in pat.panels]
    low = m.placed[:, 1] < parts.measurements.crotch_height - 0.05
    for k, name in enumerate(names[:4]):
        x = m.placed[(m.vertex_panel == k) & low, 0]
        assert np.all(x * (1.0 if name.endswith("_l") else -1.0) > 0), name


def test_designs_out_of_range_and_too_short_skirts_are_refused(parts):
    with pytest.raises(WrinklesInputError, match="fit"):
        SkirtDesign(fit="baggy")
    with pytest.raises(WrinklesInputError, match="flare"):
        SkirtDesign(flare=1.5)
    with pytest.raises(WrinklesInputError, match="length"):
        PantsDesign(length=1.3)
    m = dataclasses.replace(parts.measurements, hip_height=parts.measurements.waist_height - 0.3)
    with pytest.raises(WrinklesInputError, match="above the hips"):
        draft_skirt(m, parts.vertices, parts.torso_mask, parts.joints, SkirtDesign(length=0.3))


@pytest.mark.parametrize("shape", ["height=0.6,weight=0.8", "height=0.3,weight=0.2"])
def test_drafts_fit_other_body_shapes(shape):
    from sim.bodies import load_body
    from sim.bodies.default import parse_shape
    from sim.garments.designs import BodyParts

    p = BodyParts.of(load_body(), parse_shape(shape))
    m = p.measurements
    pat = pants(p)
    np.testing.assert_allclose(waist_length(pat, ("band_front", "band_back")),
                               girth_at(m, m.waist_height - 0.02) + bottom_ease("waist", "regular"),
                               atol=GIRTH_TOL)
    d = SkirtDesign()
    pat = skirt(p)
    hip = sum(width_at(pat.panel(n), m.hip_height - (m.waist_height - d.length)) for n in ("front", "back"))
    np.testing.assert_allclose(hip, max(m.hip, m.waist) + bottom_ease("hip", "regular"), atol=GIRTH_TOL)


def sewn_checks(pattern, parts, sewn):
    from sim.quality import inside_fraction

    assert sewn.seam_gap <= 1e-3
    f = sewn.faces
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    undirected, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    assert counts.max() == 2  # manifold: every edge in one or two faces
    # consistently oriented: no directed edge twice (two faces sharing an edge run it oppositely)
    assert len(np.unique(directed, axis=0)) == len(directed)
    # one piece
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(sewn.vertices)
    graph = coo_matrix((np.ones(len(undirected)), (undirected[:, 0], undirected[:, 1])), shape=(n, n))
    assert connected_components(graph, directed=False)[0] == 1
    assert inside_fraction(sewn.vertices[None], parts.vertices, parts.faces, device="cpu")[0] == 0.0


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["skirt", "pants"])
def test_sewing_on_the_default_body_closes_every_seam_into_one_manifold_garment(parts, kind):
    from sim.garments.materials import get_material
    from sim.garments.sewing import sew_pattern

    pat = drafted(parts, kind, {})
    sewn = sew_pattern(pat, parts.vertices, parts.faces, 0.02, get_material("cotton"), device="cpu")
    sewn_checks(pat, parts, sewn)
    # the waistband's top, held where sewing left it, is about as long as drafted: not stretched
    # out around the seams, not slack
    from scipy.spatial import ConvexHull

    top = np.concatenate([sewn.mesh.groups[sewn.mesh.edge_vertices[r]] for r in pat.labelled("waistband")])
    girth = ConvexHull(sewn.vertices[top][:, [0, 2]].astype(np.float64)).area
    band = sum(pat.panel(n).edge_length(i) for n, i in pat.labelled("waistband"))
    np.testing.assert_allclose(girth, band, rtol=0.05)


@pytest.mark.slow
def test_patterns_sewn_in_one_batch_are_those_sewn_one_by_one(parts):
    """sew_patterns puts every pattern of a batch in one cloth model (instances never interact),
    each on its own body: the garments are the ones sewn alone, to the bit."""
    from sim.bodies import load_body
    from sim.garments.designs import BodyParts
    from sim.garments.materials import get_material
    from sim.garments.sewing import SewingConfig, SewingJob, sew_pattern, sew_patterns

    body = load_body()
    betas = np.zeros(body.num_betas, np.float32)
    betas[0] = 1.5
    wide = BodyParts.of(body, betas)
    cfg = SewingConfig(close_frames=6, settle_frames=4)
    jobs = [SewingJob(drafted(parts, "skirt", {}), parts.vertices, parts.faces, 0.05, get_material("cotton")),
            SewingJob(drafted(wide, "pants", {}), wide.vertices, wide.faces, 0.06, get_material("denim")),
            SewingJob(drafted(parts, "pants", {}), parts.vertices, parts.faces, 0.05, get_material("silk"))]
    batch = sew_patterns(jobs, config=cfg, device="cpu")
    for job, got in zip(jobs, batch, strict=True):
        alone = sew_pattern(job.pattern, job.body_vertices, job.body_faces, job.h, job.material, config=cfg,
                            device="cpu")
        np.testing.assert_array_equal(got.vertices, alone.vertices)
        np.testing.assert_array_equal(got.faces, alone.faces)
        assert got.seam_gap == alone.seam_gap
    assert len(batch[1].vertices) != len(batch[2].vertices)  # another body, another garment
