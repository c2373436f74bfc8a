"""Garment templates, pattern UVs, clearance from the body, import and repair."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sim.bodies import load_body
from sim.bodies.default import parse_shape
from sim.errors import WrinklesInputError
from sim.garments import TEMPLATES, load_garment, make_garment
from sim.garments.panels import stitch

SHAPES = {"mean": "", "tall_heavy": "height=0.7,weight=0.9", "short_slim": "height=0.1,weight=0.1"}


@pytest.fixture(scope="module")
def body():
    return load_body()


@pytest.fixture(scope="module")
def garments(body):
    return {(c, s): make_garment(c, body, parse_shape(spec)) for c in TEMPLATES for s, spec in SHAPES.items()}


def _edges(faces):
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0, return_counts=True)


def _signed_distance(body_v, body_f, points):
    """Signed distance of points to the closed body mesh (negative inside) via Warp."""
    from sim.device import warp

    wp = warp()

    @wp.kernel
    def query(mesh: wp.uint64, pts: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
        i = wp.tid()
        q = wp.mesh_query_point_sign_normal(mesh, pts[i], 10.0)
        p = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        out[i] = q.sign * wp.length(pts[i] - p)

    mesh = wp.Mesh(points=wp.array(body_v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(np.asarray(body_f, np.int32).reshape(-1), dtype=int, device="cpu"))
    pts = wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu")
    out = wp.zeros(len(points), dtype=float, device="cpu")
    wp.launch(query, dim=len(points), inputs=[mesh.id, pts, out], device="cpu")
    return out.numpy()


@pytest.mark.parametrize("shape", list(SHAPES))
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
    assert np.percentile(e, 95) / np.percentile(e, 5) < 2.5
    assert abs(e.mean() / 0.025 - 1.0) < 0.25
    assert 500 < g.num_vertices < 5000


def _side(a, b, p):
    return (b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0])


@pytest.mark.parametrize("category", list(TEMPLATES))
def test_uvs_valid_non_overlapping_low_distortion(garments, category):
    g = garments[(category, "mean")]
    assert g.uvs.min() >= 0.0 and g.uvs.max() <= 1.0
    t3 = g.rest_vertices[g.faces].astype(np.float64)
    t2 = g.uvs[g.uv_faces].astype(np.float64)
    a3 = 0.5 * np.linalg.norm(np.cross(t3[:, 1] - t3[:, 0], t3[:, 2] - t3[:, 0]), axis=1)
    d1, d2 = t2[:, 1] - t2[:, 0], t2[:, 2] - t2[:, 0]
    a2 = 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    assert np.all(np.sign(a2) == np.sign(a2[0])) and np.all(np.abs(a2) > 0)  # no flips
    for pid in np.unique(g.panel_ids):
        ratio = a3[g.panel_ids == pid] / np.abs(a2[g.panel_ids == pid])
        assert np.percentile(ratio, 95) / np.percentile(ratio, 5) < 1.6  # area distortion
    # rasterise at 256²: no texel centre is covered by two triangles
    res = 256
    cover = np.zeros((res, res), np.int32)
    for tri in t2 * res:
        lo = np.floor(tri.min(0)).astype(int)
        hi = np.ceil(tri.max(0)).astype(int)
        xs, ys = np.meshgrid(np.arange(lo[0], hi[0]) + 0.5, np.arange(lo[1], hi[1]) + 0.5)
        p = np.stack([xs.ravel(), ys.ravel()], 1)
        s = np.stack([_side(tri[k], tri[(k + 1) % 3], p) for k in range(3)])
        inside = np.all(s > 0, axis=0) | np.all(s < 0, axis=0)
        q = p[inside].astype(int)
        np.add.at(cover, (q[:, 1], q[:, 0]), 1)
    assert cover.max() == 1


@pytest.mark.parametrize("shape", list(SHAPES))
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


@pytest.mark.parametrize("category", list(TEMPLATES))
def test_deterministic(body, category):
    a = make_garment(category, body, parse_shape("weight=0.7"), resolution=0.04)
    b = make_garment(category, body, parse_shape("weight=0.7"), resolution=0.04)
    np.testing.assert_array_equal(a.rest_vertices, b.rest_vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.uvs, b.uvs)


@pytest.mark.parametrize("category", ["flared_skirt", "trousers", "long_sleeve"])
def test_fine_resolution_vertex_count(body, category):
    g = make_garment(category, body, resolution="fine")
    assert 10_000 < g.num_vertices < 30_000


def test_params_and_errors(body):
    g = make_garment("straight_skirt", body, length=0.4, material="denim")
    assert g.material.name == "denim"
    assert np.ptp(g.rest_vertices[:, 1]) == pytest.approx(0.4, abs=0.02)
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
    short = make_garment("dress", body, length=0.6)
    assert short.num_vertices < make_garment("dress", body).num_vertices


def test_stitch_orientation():
    f = stitch(3, np.array([0, 0.5, 1]), 4, np.array([0, 1 / 3, 2 / 3, 1]))
    assert len(f) == 5
    _, counts = _edges(f)
    assert counts.max() <= 2


# ------------------------------------------------------------------------- import

def _seamed_square(tmp_path, name="sq.obj", extra=None):
    """A 4x4-quad grid whose UVs are split along the middle column (a seam)."""
    n = 5
    xs, ys = np.meshgrid(np.linspace(0, 0.4, n), np.linspace(0, 0.4, n))
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], 1)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            f += [(a, a + 1, a + n + 1), (a, a + n + 1, a + n)]
    f = np.array(f)
    # duplicate the vertices of column 2 for faces right of it (a UV seam)
    uv = v[:, :2] / 0.4
    right = np.arange(len(f)) % ((n - 1) * 2) >= 4
    dup = np.arange(n) * n + 2
    new = {int(d): len(v) + k for k, d in enumerate(dup)}
    v2 = np.concatenate([v, v[dup]])
    uv2 = np.concatenate([uv * [0.45, 1], uv[dup] * [0.45, 1] + [0.1, 0]])
    uv2[:n * n][np.arange(n * n) % n > 2] += [0.1, 0]
    f2 = f.copy()
    for k in np.where(right)[0]:
        f2[k] = [new.get(int(x), int(x)) for x in f[k]]
    if extra is not None:
        v2, f2, uv2 = extra(v2, f2, uv2)
    m = trimesh.Trimesh(v2, f2, visual=trimesh.visual.TextureVisuals(uv=uv2), process=False)
    path = tmp_path / name
    m.export(path)
    return path, v, f


def test_import_round_trip_keeps_seams(tmp_path):
    path, v, f = _seamed_square(tmp_path)
    g = load_garment(path)
    assert g.num_vertices == len(v) and g.num_faces == len(f)
    assert len(g.uvs) == len(v) + 5  # seam kept in UV space
    np.testing.assert_allclose(np.sort(g.rest_vertices, axis=0), np.sort(v, axis=0), atol=1e-6)
    assert g.name == "sq"


def test_import_drops_tiny_component(tmp_path):
    def add_speck(v, f, uv):
        s = np.array([[2, 2, 2], [2.001, 2, 2], [2, 2.001, 2]])
        return np.concatenate([v, s]), np.concatenate([f, [[len(v), len(v) + 1, len(v) + 2]]]), \
            np.concatenate([uv, np.zeros((3, 2))])
    path, v, f = _seamed_square(tmp_path, extra=add_speck)
    g = load_garment(path)
    assert g.num_faces == len(f) and g.num_vertices == len(v)


def test_import_refusals(tmp_path):
    def fan(v, f, uv):  # three faces on one edge
        k = len(v)
        return np.concatenate([v, [[0.05, 0.05, 0.1]]]), np.concatenate([f, [[0, 6, k]]]), \
            np.concatenate([uv, [[0.5, 0.5]]])
    path, _, _ = _seamed_square(tmp_path, "fan.obj", extra=fan)
    with pytest.raises(WrinklesInputError, match=r"fan\.obj.*non-manifold"):
        load_garment(path)
    nouv = tmp_path / "nouv.obj"
    trimesh.creation.icosphere(1).export(nouv)
    with pytest.raises(WrinklesInputError, match=r"nouv\.obj.*no UVs"):
        load_garment(nouv)
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n")
    with pytest.raises(WrinklesInputError, match=r"bad\.ply"):
        load_garment(bad)
    with pytest.raises(WrinklesInputError, match="no such file"):
        load_garment(tmp_path / "missing.obj")
