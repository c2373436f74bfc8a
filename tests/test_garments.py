"""Garment templates: clean meshes, resolution, pattern UVs, clearance from the body, attachments.

Import is tested in test_garment_import.py, the UV functions in test_garment_uvs.py.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest
import trimesh

from sim.bodies import load_body
from sim.bodies.default import parse_shape
from sim.errors import WrinklesInputError
from sim.garments import TEMPLATES, make_garment
from sim.garments.panels import corner_angles, stitch
from sim.garments.parameters import parameter_specs
from sim.garments.templates import resolve_resolution
from sim.garments.tops import ARMHOLE_FILLET_ANGLE, armhole_inset, fillet_inset
from sim.garments.uv import UV_MARGIN, uv_stats

SHAPES = {"mean": "", "tall_heavy": "height=0.7,weight=0.9", "short_slim": "height=0.1,weight=0.1"}
# the coarse checks on the other bodies build 16 more garments: the slow tier runs them
SHAPE_PARAMS = ["mean", *(pytest.param(s, marks=pytest.mark.slow) for s in SHAPES if s != "mean")]


@pytest.fixture(scope="module")
def body():
    return load_body()


class _Built(dict):
    """Garments built on first use, keyed (category, shape)."""

    def __init__(self, build):
        super().__init__()
        self._build = build

    def __missing__(self, key):
        self[key] = self._build(*key)
        return self[key]


@pytest.fixture(scope="module")
def garments(body):
    """Coarse garments, built once per (category, shape) on first use."""
    return _Built(lambda category, shape: make_garment(category, body, parse_shape(SHAPES[shape])))


@pytest.fixture(scope="module")
def fine(body):
    """Fine-resolution garments, built once per (category, shape) on first use."""
    cache = {}

    def get(category: str, shape: str = "mean"):
        if (category, shape) not in cache:
            cache[(category, shape)] = make_garment(category, body, parse_shape(SHAPES[shape]),
                                                    resolution="fine")
        return cache[(category, shape)]
    return get


def _edge_lengths(g) -> np.ndarray:
    """Length [m] of every edge of a garment (``sim.quality.unique_edges``)."""
    from sim.quality import unique_edges

    e = unique_edges(g.faces)
    return np.linalg.norm(g.rest_vertices[e[:, 0]] - g.rest_vertices[e[:, 1]], axis=1)


def _edges(faces):
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0, return_counts=True)


def _signed_distance(body_v, body_f, points):
    """Distance of points to the closed body mesh [m], negative inside, via Warp.

    The sign comes from the generalised winding number: the pseudo-normal sign is unreliable
    on the mid-plane between touching thighs (the crotch bridge of pants lies there).
    """
    from sim.device import warp

    wp = warp()

    @wp.kernel
    def query(mesh: wp.uint64, pts: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
        i = wp.tid()
        q = wp.mesh_query_point_sign_winding_number(mesh, pts[i], 10.0, 2.0, 0.5)
        p = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        out[i] = q.sign * wp.length(pts[i] - p)

    mesh = wp.Mesh(points=wp.array(body_v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(np.asarray(body_f, np.int32).reshape(-1), dtype=int, device="cpu"),
                   support_winding_number=True)
    pts = wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu")
    out = wp.zeros(len(points), dtype=float, device="cpu")
    wp.launch(query, dim=len(points), inputs=[mesh.id, pts, out], device="cpu")
    return out.numpy()


@pytest.mark.parametrize("category", list(TEMPLATES))
def test_rows_interleave_into_near_equilateral_triangles(garments, category):
    """Odd inner rows are staggered half a spacing: most triangles are near equilateral (a split-
    quad strip has a longest/shortest edge ratio of ~1.5 in every triangle). Rows that change
    length (a flare, a crotch loop) drift in phase on their own and stay near 1.25."""
    g = garments[(category, "mean")]
    x, f = g.rest_vertices, g.faces
    e = np.stack([np.linalg.norm(x[f[:, (i + 1) % 3]] - x[f[:, i]], axis=1) for i in range(3)], axis=1)
    aspect = np.median(e.max(1) / e.min(1))
    assert aspect < (1.3 if category in ("flared_skirt", "shorts") else 1.2), aspect


def test_stagger_puts_mid_points_on_the_curve():
    from sim.garments.panels import stagger

    t = np.linspace(0.0, 2 * np.pi, 25)  # a closed circle of radius 0.1 m, 24 segments
    ring = np.stack([0.1 * np.cos(t), 0.1 * np.sin(t), np.zeros_like(t)], axis=1)
    ring[-1] = ring[0]
    out = stagger(ring)
    assert out.shape == (26, 3)
    np.testing.assert_array_equal(out[[0, -1]], ring[[0, -1]])
    r = np.linalg.norm(out[1:-1, :2], axis=1)
    assert np.abs(r - 0.1).max() < 2e-5  # the chord mid-point would sit 0.86 mm inside
    ang = np.unwrap(np.arctan2(out[1:-1, 1], out[1:-1, 0]))
    np.testing.assert_allclose(ang, (np.arange(24) + 0.5) * 2 * np.pi / 24, atol=1e-6)
    line = np.stack([np.linspace(0, 1, 5), np.zeros(5), np.zeros(5)], axis=1)  # open: exact on a line
    np.testing.assert_allclose(stagger(line)[:, 0], [0.0, 0.125, 0.375, 0.625, 0.875, 1.0], atol=1e-12)


@pytest.mark.parametrize("shape", SHAPE_PARAMS)
@pytest.mark.parametrize("category", list(TEMPLATES))
def test_template_is_clean_manifold(garments, category, shape):
    g = garments[(category, shape)]
    m = trimesh.Trimesh(g.rest_vertices, g.faces, process=False)
    _, counts = _edges(g.faces)
    assert counts.max() <= 2 and counts.min() >= 1
    assert m.is_winding_consistent
    assert len(m.split(only_watertight=False)) == 1
    assert m.area_faces.min() > 1e-6
    e = m.edges_unique_length
    assert np.percentile(e, 95) / np.percentile(e, 5) < 1.8  # near-uniform edges
    assert abs(e.mean() / TEMPLATES[category].coarse - 1.0) < 0.15
    assert corner_angles(g.rest_vertices, g.faces).min() > 10.0  # no slivers
    assert 1900 < g.num_vertices < 4000  # "coarse": ~3k on the mean body, 2-4k on others
    if shape == "mean":  # the count `wrinkles garments` lists
        assert g.num_vertices == pytest.approx(TEMPLATES[category].vertices[0], rel=0.01)


def raster_cover(tris: np.ndarray, res: int) -> np.ndarray:
    """How many triangles cover each texel centre of a res x res image, shape (res, res).

    Args:
        tris: UV triangles in [0, 1]², shape (F, 3, 2). Strict inside test: a texel centre on
            an edge shared by two triangles counts for neither, so only real overlap gives 2.
    """
    t = tris * res
    lo = np.floor(t.min(1)).astype(int)
    size = np.ceil(t.max(1)).astype(int) - lo
    k = int(size.max())
    oy, ox = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    cover = np.zeros((res, res), np.int32)
    for c in range(0, len(t), 4096):
        tc, lc = t[c:c + 4096], lo[c:c + 4096]
        px = lc[:, None, 0] + ox.ravel()[None] + 0.5  # (f, k*k) texel centres
        py = lc[:, None, 1] + oy.ravel()[None] + 0.5
        side = []
        for e in range(3):
            a, b = tc[:, e], tc[:, (e + 1) % 3]
            side.append((b[:, None, 0] - a[:, None, 0]) * (py - a[:, None, 1])
                        - (b[:, None, 1] - a[:, None, 1]) * (px - a[:, None, 0]))
        side = np.stack(side)
        inside = np.all(side > 0, axis=0) | np.all(side < 0, axis=0)
        inside &= (px < res) & (py < res)
        np.add.at(cover, (py[inside].astype(int), px[inside].astype(int)), 1)
    return cover


# Bounds for the sewing-pattern UVs (measured on the 3 test bodies, coarse: conformal mean
# <= 1.04, p95 <= 1.10, max <= 1.6; area p5 >= 0.92, p95 <= 1.08; >= 124 texels/m at 256²),
# with headroom. Texel density: at 512² a texel must be <= 4.5 mm of cloth, so a 1 cm wrinkle
# gets >= 2 texels per period (Nyquist); a coarse mesh's mean edge must span >= 2 texels at
# 256² (each coarse vertex gets its own texels in the smallest UV image we use).
UV_ANGLE_MEAN, UV_ANGLE_P95, UV_ANGLE_MAX = 1.06, 1.15, 2.0
UV_AREA_P5, UV_AREA_P95 = 0.9, 1.1
TEXEL_512_MAX = 0.0045
COARSE_EDGE_TEXELS_256 = 2.0


@pytest.mark.parametrize("shape", SHAPE_PARAMS)
@pytest.mark.parametrize("category", list(TEMPLATES))
def test_uv_distortion_and_texel_density(garments, category, shape):
    g = garments[(category, shape)]
    s = uv_stats(g.rest_vertices, g.faces, g.uvs, g.uv_faces)
    assert s.flipped == 0
    assert s.angle_mean <= UV_ANGLE_MEAN and s.angle_p95 <= UV_ANGLE_P95 and s.angle_max <= UV_ANGLE_MAX, s
    assert UV_AREA_P5 <= s.area_p5 and s.area_p95 <= UV_AREA_P95, s
    assert 1.0 / (2 * s.texels_per_metre_256) <= TEXEL_512_MAX, s
    assert s.mean_edge_texels_256 >= COARSE_EDGE_TEXELS_256, s
    # every panel on its own: one scale for all (equal texel density), none distorted alone
    for pid in np.unique(g.panel_ids):
        m = g.panel_ids == pid
        sp = uv_stats(g.rest_vertices, g.faces[m], g.uvs, g.uv_faces[m])
        assert sp.angle_p95 <= UV_ANGLE_P95, (g.panel_names[pid], sp)
        assert abs(sp.texels_per_metre_256 / s.texels_per_metre_256 - 1) < 0.05, g.panel_names[pid]


@pytest.mark.parametrize("category", list(TEMPLATES))
def test_uv_charts_inside_unit_square_and_apart(garments, category):
    g = garments[(category, "mean")]
    assert g.uvs.min() >= UV_MARGIN - 1e-6 and g.uvs.max() <= 1 - UV_MARGIN + 1e-6
    # UV vertices belong to one panel each (seams split them)
    owner = np.full(len(g.uvs), -1)
    for pid in range(len(g.panel_names)):
        owner[g.uv_faces[g.panel_ids == pid]] = pid
    assert np.all(owner >= 0)
    for pid in range(len(g.panel_names)):
        assert not np.isin(g.uv_faces[g.panel_ids != pid], np.flatnonzero(owner == pid)).any()
    # panels' boxes are >= the margin (5 px at 256²) apart: bilinear lookups and mip levels up
    # to 4 px never mix two panels
    boxes = [(g.uvs[owner == p].min(0), g.uvs[owner == p].max(0)) for p in range(len(g.panel_names))]
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            gap = np.maximum(boxes[j][0] - boxes[i][1], boxes[i][0] - boxes[j][1]).max()
            assert gap >= UV_MARGIN - 1e-6, (g.panel_names[i], g.panel_names[j], gap)
    # no overlap anywhere: rasterised at 512², no texel centre is inside two triangles
    cover = raster_cover(g.uvs[g.uv_faces].astype(np.float64), 512)
    assert cover.max() == 1
    assert 0.3 < (cover > 0).mean() < 0.75  # packing leaves a usable share of the image


@pytest.mark.parametrize("shape", SHAPE_PARAMS)
def test_no_self_intersection_at_rest(garments, shape):
    from sim.quality import crossing_edges

    for category in TEMPLATES:
        g = garments[(category, shape)]
        assert not crossing_edges(g.rest_vertices, g.faces, device="cpu").any(), category


@pytest.mark.slow
@pytest.mark.parametrize("category", ["t_shirt", "long_sleeve"])
def test_sleeve_stays_clear_of_the_back_panel_without_untangling(body, category):
    """A shape and resolution where a sleeve's first rows would cross the back panel under the
    arm (17 edge-face crossings) if the left sleeve took each row point's x from the mirrored
    armhole loop: the raw build, before ``untangle``, has no crossing and is the garment."""
    from sim.garments.measure import BodyMeasure
    from sim.garments.panels import sew
    from sim.garments.templates import make_params
    from sim.quality import crossing_edges

    betas = body.full_betas(np.array([0.12573022, -0.13210486, 0.64042264, 0.10490011], np.float32))
    g = make_garment(category, body, betas, resolution=0.0125)
    raw = sew(TEMPLATES[category].build(BodyMeasure.of(body, betas), make_params(category), 0.0125,
                                g.material.thickness))
    assert not crossing_edges(raw.vertices, raw.faces, device="cpu").any()
    np.testing.assert_array_equal(raw.vertices.astype(np.float32), g.rest_vertices)


@pytest.mark.slow
@pytest.mark.parametrize("category", ["t_shirt", "long_sleeve"])
def test_a_sleeve_vertex_through_the_back_panel_is_untangled(body, category):
    """``untangle``, the rest shape's safety net: a sleeve vertex pushed 1 cm through the back
    panel (past the back vertex nearest to it) is smoothed back. No edge crosses a face after,
    only sleeve vertices move, and the result lies within an edge length of the clean shape."""
    from sim.garments.templates import untangle
    from sim.quality import crossing_edges

    h = 0.0125
    g = make_garment(category, body, None, resolution=h)
    v = g.rest_vertices.astype(np.float64)
    names = np.array(g.panel_names)[g.panel_ids]
    sleeve_v = np.unique(g.faces[np.char.find(names.astype(str), "sleeve") >= 0].ravel())
    back_v = np.unique(g.faces[names == "back"].ravel())
    only_sleeve = np.setdiff1d(sleeve_v, back_v)
    d = np.linalg.norm(v[only_sleeve][:, None] - v[back_v][None], axis=2)
    i, j = np.unravel_index(d.argmin(), d.shape)
    a, b = only_sleeve[i], back_v[j]
    tangled = v.copy()
    tangled[a] = v[b] + 0.01 * (v[b] - v[a]) / np.linalg.norm(v[b] - v[a])
    assert crossing_edges(tangled, g.faces, device="cpu").sum() > 0
    out = untangle(tangled, g.faces, g.panel_ids, list(g.panel_names))
    assert not crossing_edges(out, g.faces, device="cpu").any()
    moved = np.linalg.norm(out - tangled, axis=1) > 1e-9
    assert moved.any() and np.isin(np.flatnonzero(moved), only_sleeve).all()
    assert np.linalg.norm(out - v, axis=1).max() < h
    # a clean mesh passes through unchanged
    assert untangle(g.rest_vertices, g.faces, g.panel_ids, list(g.panel_names)) is g.rest_vertices


@pytest.mark.slow
@pytest.mark.parametrize("category", list(TEMPLATES))
def test_fine_template_has_no_long_edges_or_slivers(fine, category):
    """At the fine resolution (~20k vertices) no edge is longer than 2.7 median edges and no
    corner is under 12°: a sleeve's first row that jumps 4 row spacings off the armhole makes
    edges 4.4 medians long (where a batched run's cloth crosses itself), hip rings centred on
    their hull's vertex mean make 7° corners on the shorts."""
    g = fine(category)
    length = _edge_lengths(g)
    assert length.max() < 2.7 * np.median(length), (category, length.max() / np.median(length))
    assert corner_angles(g.rest_vertices, g.faces).min() > 12.0


@pytest.mark.slow
@pytest.mark.parametrize("shape", list(SHAPES))
def test_fine_sleeves_follow_the_armhole(fine, shape):
    """Each sleeve row stays within reach of the one before, on both sides: at the fine
    resolution no sleeve edge is longer than 2.6 median edges for any body shape (the left
    sleeve, built from the mirrored loop, had edges 3.1 medians long on the tall body)."""
    from sim.quality import unique_edges

    for category in ("t_shirt", "long_sleeve"):
        g = fine(category, shape)
        e = unique_edges(g.faces)
        length = _edge_lengths(g)
        for side in ("left_sleeve", "right_sleeve"):
            on = np.zeros(g.num_vertices, bool)
            on[g.faces[g.panel_ids == g.panel_names.index(side)].ravel()] = True
            worst = length[on[e[:, 0]] & on[e[:, 1]]].max() / np.median(length)
            assert worst < 2.6, (category, shape, side, worst)


@pytest.mark.parametrize("shape", SHAPE_PARAMS)
def test_outside_body_at_rest(body, garments, shape):
    betas = parse_shape(SHAPES[shape])
    bv = body.rest_mesh(betas)
    for category in TEMPLATES:
        g = garments[(category, shape)]
        sd = _signed_distance(bv, body.faces, g.rest_vertices)
        assert sd.min() >= g.material.thickness, (category, float(sd.min()))


@pytest.mark.parametrize("category", list(TEMPLATES))
def test_attachments_on_the_right_boundary(body, garments, category):
    g = garments[(category, "mean")]
    assert set(TEMPLATES[category].attachments) <= set(g.attachments)
    edges, counts = _edges(g.faces)
    boundary = np.unique(edges[counts == 1])
    v = g.rest_vertices
    hem = g.attachments["hem"]
    assert hem.size > 10 and np.isin(hem, boundary).all()
    if "waistband" in g.attachments:  # bottoms: waistband at the top, nothing else open
        wb = g.attachments["waistband"]
        assert wb.size > 10 and np.isin(wb, boundary).all() and not np.isin(hem, wb).any()
        np.testing.assert_allclose(v[wb, 1], v[:, 1].max(), atol=1e-5)
        assert np.isin(boundary, np.concatenate([wb, hem])).all()  # one hem loop per leg
    if "shoulders" in g.attachments:  # tops: a line across each strap, on top of the shoulder
        sh = g.attachments["shoulders"]
        j = body.rest_joints(None)
        assert (v[sh, 0] > 0).sum() >= 3 and (v[sh, 0] < 0).sum() >= 3
        assert np.all(v[sh, 1] > j[16, 1]) and np.all(np.abs(v[sh, 0]) < abs(j[16, 0]))
        # each line ends on the neckline and, without sleeves, on the open armhole
        assert np.isin(sh, boundary).sum() == (2 if "cuffs" in g.attachments else 4)
        assert v[sh, 1].mean() > np.percentile(v[:, 1], 97)  # near the top of the garment
    if "cuffs" in g.attachments:  # sleeves: an open ring at the end of each arm
        cuffs = g.attachments["cuffs"]
        assert np.isin(cuffs, boundary).all()
        x = v[cuffs, 0]
        j = body.rest_joints(None)
        assert (x > j[16, 0]).sum() > 10 and (x < j[17, 0]).sum() > 10
        assert np.all(np.abs(x) > abs(j[16, 0]))


def test_trousers_split_into_two_legs(garments):
    g = garments[("trousers", "mean")]
    assert g.panel_names == ("front", "back", "left_leg", "right_leg")
    hem = g.attachments["hem"]
    x = g.rest_vertices[hem, 0]
    assert (x > 0).sum() > 10 and (x < 0).sum() > 10  # a hem loop around each leg
    # the legs never cross the mid-sagittal plane below the crotch bridge
    legs = np.unique(g.faces[g.panel_ids >= 2])
    v = g.rest_vertices
    below = v[legs, 1] < v[g.attachments["waistband"], 1].min() - 0.45
    assert np.all(np.abs(v[legs][below, 0]) > 0.001)


def _leg_vertices(g):
    """Which panels each vertex of a pants garment belongs to (V, panels) and which are the legs'."""
    names = list(g.panel_names)
    panels_of = np.zeros((len(g.rest_vertices), len(names)), bool)
    for k in range(len(names)):
        panels_of[np.unique(g.faces[g.panel_ids == k]), k] = True
    return panels_of, panels_of[:, [names.index("left_leg"), names.index("right_leg")]].any(axis=1)


@pytest.mark.parametrize("shape", SHAPE_PARAMS)
@pytest.mark.parametrize("category", ["shorts", "trousers"])
def test_legs_leave_the_mid_plane_below_the_bridge(garments, category, shape):
    """The two legs' inner rows do not lie on the mid-sagittal plane, where the other leg's lie:
    off the seams, no leg vertex is within a quarter of ``leg_gap`` of it (rows left on the plane
    by the blend from the crotch bridge, at x = 0, would put faces of one leg on the other's:
    54 of the shorts' vertices and 21 of the trousers', and the shorts cross themselves within
    four frames of the settle on the default body; one vertex is allowed, the back end of the
    bridge's row)."""
    from sim.garments.pants import PantsParams

    g = garments[(category, shape)]
    panels_of, leg = _leg_vertices(g)
    seam = panels_of.sum(axis=1) > 1
    mid = leg & ~seam & (np.abs(g.rest_vertices[:, 0]) < 0.25 * PantsParams().leg_gap)
    assert mid.sum() <= 1, np.round(g.rest_vertices[mid], 4)


@pytest.mark.parametrize("gap", [0.003, 0.01])
def test_leg_gap_is_the_least_distance_between_the_legs_inner_walls(body, gap):
    """``leg_gap``: off the seams, the shorts' leg vertices lie at least half the gap from the
    mid-sagittal plane (all but 3 % exactly; the rows' resampling leaves a few up to 0.8 mm
    nearer), and the inner walls between the thighs lie at exactly that distance (the cut is
    where the legs' ease would have crossed the plane): the walls face each other ``leg_gap``
    apart. The legs' rows start at the bridge (x = 0), so the seam is excluded."""
    g = make_garment("shorts", body, leg_gap=gap)
    panels_of, leg = _leg_vertices(g)
    off_seam = leg & (panels_of.sum(axis=1) == 1)
    ax = np.abs(g.rest_vertices[off_seam, 0])
    assert ax.min() >= 0.5 * gap - 8e-4
    assert (ax >= 0.5 * gap - 1e-6).mean() > 0.97
    on_wall = np.abs(ax - 0.5 * gap) < 1e-6
    assert on_wall.sum() >= 20, on_wall.sum()  # a wall of vertices, both legs
    walls = g.rest_vertices[off_seam][on_wall]
    assert (walls[:, 0] > 0).any() and (walls[:, 0] < 0).any()


@pytest.mark.parametrize("category", list(TEMPLATES))
def test_deterministic(body, category):
    a = make_garment(category, body, parse_shape("weight=0.7"), resolution=0.04)
    b = make_garment(category, body, parse_shape("weight=0.7"), resolution=0.04)
    np.testing.assert_array_equal(a.rest_vertices, b.rest_vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.uvs, b.uvs)


@pytest.mark.slow
@pytest.mark.parametrize("category", ["t_shirt", "dress"])
def test_fine_resolution_vertex_count(fine, category):
    g = fine(category)
    assert 15_000 < g.num_vertices < 30_000
    assert g.num_vertices == pytest.approx(TEMPLATES[category].vertices[1], rel=0.01)
    s = uv_stats(g.rest_vertices, g.faces, g.uvs, g.uv_faces)
    assert s.angle_p95 <= UV_ANGLE_P95 and s.flipped == 0
    assert s.mean_edge_texels_256 * 2 >= 2.0  # a fine edge spans >= 2 texels at 512²
    e = np.linalg.norm(np.diff(g.rest_vertices[g.faces[:, [0, 1, 2, 0]]], axis=1), axis=2)
    assert abs(e.mean() / resolve_resolution("fine", category) - 1.0) < 0.15


def _boundary_cloth_angle(g, panels: tuple[str, ...], exclude: tuple[str, ...] = ()) -> float:
    """Largest angle of cloth [deg] around a boundary vertex of ``panels`` that is on none of
    ``exclude`` (the sum of its triangles' corner angles there; 180° on a straight edge)."""
    total = np.bincount(g.faces.ravel(), weights=corner_angles(g.rest_vertices, g.faces).ravel(),
                        minlength=g.num_vertices)
    e, count = _edges(g.faces)
    keep = np.zeros(g.num_vertices, bool)
    keep[e[count == 1].ravel()] = True

    def on(names: tuple[str, ...]) -> np.ndarray:
        mask = np.zeros(g.num_vertices, bool)
        for name in names:
            mask[g.faces[g.panel_ids == g.panel_names.index(name)].ravel()] = True
        return mask

    keep &= on(panels) & ~on(exclude)
    return float(total[keep].max())


def _strap_corner_angle(g) -> float:
    """Largest angle of cloth around a strap's boundary vertex: 270° at a square neckline corner."""
    return _boundary_cloth_angle(g, ("left_strap", "right_strap"))


@pytest.mark.slow
@pytest.mark.parametrize("category", ["tank_top", "t_shirt"])
@pytest.mark.parametrize("shape", ["mean", "short_slim"])
def test_neckline_corners_are_rounded(body, category, shape):
    """Where a strap meets a neckline the cloth has no re-entrant corner: with the default
    ``neck_fillet`` no strap boundary vertex has more than 235° of cloth around it (a straight
    edge has 180°); with ``neck_fillet=0`` the square corner has about 270°. The mesh stays
    manifold with its vertex count within 1 %."""
    betas = parse_shape(SHAPES[shape])
    rounded = make_garment(category, body, betas, resolution=0.01)
    square = make_garment(category, body, betas, resolution=0.01, neck_fillet=0.0)
    assert _strap_corner_angle(rounded) < 235.0
    assert _strap_corner_angle(square) > 260.0
    e, count = _edges(rounded.faces)
    assert count.max() == 2
    assert rounded.num_vertices == pytest.approx(square.num_vertices, rel=0.01)


def _armhole_corner_angle(g) -> float:
    """Largest angle of cloth around a bib's boundary vertex below the straps (where a bib's side
    meets the tube's top row): about 270° at a square armhole corner."""
    return _boundary_cloth_angle(g, ("front_bib", "back_bib"), exclude=("left_strap", "right_strap"))


@pytest.mark.slow
@pytest.mark.parametrize("shape", ["mean", "short_slim"])
def test_armhole_fillet_rounds_the_armholes_bottom_corners(body, shape):
    """``armhole_fillet``: the bibs' sides curve into the tube's top row along an arc
    that leaves the side tangentially and meets the row at 45° (``armhole_inset``), so no bib
    boundary vertex below the straps has more than 235° of cloth around it where the square
    corner (``armhole_fillet=0``) has about 270°. The bibs' bottom rows reach out by the arc's
    reach, capped where it would leave the armhole's bottom less than two edges before the tube's
    side (the slim body) and by 3/4 of the lower rise; the mesh stays manifold, without slivers,
    its vertex count within 2 %, and the straps are untouched."""
    betas = parse_shape(SHAPES[shape])
    h, radius = 0.01, 0.06
    square = make_garment("tank_top", body, betas, resolution=h, armhole_fillet=0.0)
    rounded = make_garment("tank_top", body, betas, resolution=h, armhole_fillet=radius)
    assert _armhole_corner_angle(square) > 260.0
    assert _armhole_corner_angle(rounded) < 235.0
    e, count = _edges(rounded.faces)
    assert count.max() == 2
    assert corner_angles(rounded.rest_vertices, rounded.faces).min() > 15.0
    assert rounded.num_vertices == pytest.approx(square.num_vertices, rel=0.02)
    def panel(g, name: str) -> np.ndarray:
        return g.rest_vertices[np.unique(g.faces[g.panel_ids == g.panel_names.index(name)])]

    for name in ("left_strap", "right_strap"):
        np.testing.assert_array_equal(panel(rounded, name), panel(square, name))

    def bib_half_width(g) -> float:
        return float(np.abs(panel(g, "front_bib")[:, 0]).max())

    front = panel(square, "front")
    side = float(np.abs(front[front[:, 1] > front[:, 1].max() - 1e-4, 0]).max())  # the tube's top row
    x_out = bib_half_width(square)
    reach = min(float(armhole_inset(0.0, radius)), side - x_out - 2 * h)
    assert reach > 0.008
    assert bib_half_width(rounded) - x_out == pytest.approx(reach, abs=0.003)
    capped = make_garment("tank_top", body, betas, resolution=h, armhole_fillet=0.1, front_rise=0.03)
    cap = 0.75 * 0.03 / np.sin(ARMHOLE_FILLET_ANGLE)
    assert bib_half_width(capped) - x_out == pytest.approx(min(float(armhole_inset(0.0, cap)), reach),
                                                            abs=0.003)


def test_armhole_inset_is_an_arc_tangent_to_the_side_meeting_the_row_at_its_angle():
    """``armhole_inset``: the bib's side at (x - inset(dy), dy) lies on the circle of ``radius``
    about (x + radius, radius sin(angle)) from the row (dy = 0, inset radius (1 - cos(angle))) up
    to the tangent point (dy = radius sin(angle), inset 0), meeting the row at ``angle`` from the
    horizontal; above it the straight side; the inset falls monotonically."""
    r, a = 0.06, ARMHOLE_FILLET_ANGLE
    top = r * np.sin(a)
    dy = np.linspace(0.0, top, 201)
    w = armhole_inset(dy, r)
    np.testing.assert_allclose((r - w) ** 2 + (top - dy) ** 2, r * r, rtol=1e-12)
    assert w[0] == pytest.approx(r * (1.0 - np.cos(a))) and w[-1] == pytest.approx(0.0, abs=1e-15)
    assert np.all(np.diff(w) <= 0.0)
    np.testing.assert_array_equal(armhole_inset(np.array([top + 1e-4, 0.2]), r), 0.0)
    # slope at the row: d(inset)/d(dy) = -1/tan(angle); at the tangent point vertical (slope 0)
    eps = 1e-7
    assert (armhole_inset(0.0, r) - armhole_inset(eps, r)) / eps == pytest.approx(1.0 / np.tan(a), rel=1e-4)
    assert abs(armhole_inset(top - 1e-6, r)) < 1e-9


def test_fillet_inset_is_a_quarter_circle_tangent_at_both_ends():
    """``fillet_inset``: the strap's inner edge at (x_in - inset(s), s) lies on the circle of
    radius r about (x_in - r, r), from the neckline (s = 0, inset r) to the straight edge (s = r,
    inset 0); beyond r it is the straight edge; the inset falls monotonically."""
    r = 0.02
    s = np.linspace(0.0, r, 201)
    d = fillet_inset(s, r)
    np.testing.assert_allclose((r - d) ** 2 + (s - r) ** 2, r * r, rtol=1e-12)
    assert d[0] == pytest.approx(r) and d[-1] == pytest.approx(0.0, abs=1e-15)
    assert np.all(np.diff(d) <= 0.0)
    np.testing.assert_array_equal(fillet_inset(np.array([0.021, 0.1]), r), 0.0)
    # tangent to the strap's edge at s = r (slope -> 0) and to the neckline at s = 0 (slope -> -inf)
    assert abs(fillet_inset(r - 1e-6, r)) < 1e-9
    assert (fillet_inset(0.0, r) - fillet_inset(1e-6, r)) / 1e-6 > 20.0


def test_length_and_material_parameters(body):
    g = make_garment("straight_skirt", body, length=0.4, material="denim")
    assert g.material.name == "denim"
    assert np.ptp(g.rest_vertices[:, 1]) == pytest.approx(0.4, abs=0.02)
    short = make_garment("dress", body, length=0.6, resolution=0.04)
    assert short.num_vertices < make_garment("dress", body, resolution=0.04).num_vertices


def test_parameter_errors(body):
    with pytest.raises(WrinklesInputError, match="unknown garment category"):
        make_garment("cape", body)
    with pytest.raises(WrinklesInputError, match="unknown parameter"):
        make_garment("straight_skirt", body, lenght=0.4)
    with pytest.raises(WrinklesInputError, match="resolution"):
        make_garment("straight_skirt", body, resolution="ultra")
    with pytest.raises(WrinklesInputError, match="no leg"):
        make_garment("trousers", body, length=0.3)
    with pytest.raises(WrinklesInputError, match="sleeve_length"):
        make_garment("t_shirt", body, sleeve_length=0.01)
    with pytest.raises(WrinklesInputError, match=r"ease = -0.01 is outside its range \[0, 0.15\]"):
        make_garment("t_shirt", body, ease=-0.01)
    with pytest.raises(WrinklesInputError, match="length = 3 is outside"):
        make_garment("dress", body, length=3.0)
    with pytest.raises(WrinklesInputError, match="must be a number"):
        make_garment("shorts", body, ease=float("nan"))
    # every parameter of every template has a unit, a range and a description, and the
    # template's default lies inside the range
    for cat, t in TEMPLATES.items():
        specs = parameter_specs(t.params)
        for f in fields(t.params):
            spec = specs[f.name]
            assert spec.unit in ("m", "-") and spec.description, (cat, f.name)
            assert spec.low <= t.defaults.get(f.name, f.default) <= spec.high, (cat, f.name)


def test_stitch_orientation():
    a = np.array([[0, 0, 0], [0.5, 0, 0], [1, 0, 0]], float)
    b = np.array([[0, -0.4, 0], [1 / 3, -0.4, 0], [2 / 3, -0.4, 0], [1, -0.4, 0]])
    f = stitch(a, b)
    assert len(f) == 5
    _, counts = _edges(f)
    assert counts.max() <= 2
    p = np.concatenate([a, b])
    n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    assert np.all(n[:, 2] > 0)  # one orientation
    assert corner_angles(p, f).min() > 30  # shortest diagonals: no slivers
