"""Hems: the bands of extra fabric layers along a garment's openings, and what the cloth model
makes of a face's layers (mass, membrane, bending)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.bodies import load_body
from sim.bodies.default import parse_shape
from sim.cloth import ClothModelBuilder
from sim.cloth.model import ClothMaterialParams, hinge_faces
from sim.cloth.topology import build_hinges
from sim.errors import WrinklesInputError
from sim.garments import TEMPLATES, make_garment
from sim.garments.hems import (
    HEM_LAYERS,
    HEM_WIDTH,
    band_fraction,
    boundary_vertices,
    distance_to_boundary,
    hem_face_layers,
)
from sim.garments.templates import make_params, template_parameters
from sim.garments.types import Garment
from sim.quality import unique_edges
from tests.test_cloth_solver import grid


def test_distance_to_boundary_on_a_grid_is_the_distance_to_the_nearest_side():
    """On a regular grid a path along the grid lines reaches the nearest side straight, so the
    graph distance is exactly min(x, w - x, y, h - y)."""
    w, h = 0.3, 0.5
    v, f = grid(7, 11, w, h)
    d = distance_to_boundary(v, f)
    x, y = v[:, 0], -v[:, 1]
    np.testing.assert_allclose(d, np.minimum.reduce([x, w - x, y, h - y]), atol=1e-6)
    assert set(boundary_vertices(f)) == set(np.flatnonzero(d < 1e-9))


def test_a_closed_mesh_has_no_hem():
    from sim.geometry.primitives import uv_sphere

    v, f = uv_sphere(0.2)
    assert np.isinf(distance_to_boundary(v, f)).all()
    np.testing.assert_array_equal(hem_face_layers(v, f, 0.05, 2.0), 1.0)


def areas_of(v, f) -> np.ndarray:
    tri = np.asarray(v, np.float64)[f]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def hem_area(v, f, layers, hem_layers) -> float:
    """The area the band covers: each face's area times its share of the band."""
    return float((areas_of(v, f) * (layers - 1.0) / (hem_layers - 1.0)).sum())


def test_band_fraction_is_the_area_share_below_the_level():
    """``band_fraction`` against a Monte Carlo estimate on random triangles with random corner
    values (one, two or three corners below the level, ties included), and its limits."""
    rng = np.random.default_rng(0)
    d = rng.uniform(0.0, 0.04, (60, 3))
    d[:5, 1] = d[:5, 0]  # ties
    d[5:10] = 0.01  # flat below
    d[10:15] = 0.03  # flat above
    got = band_fraction(d, 0.02)
    b = rng.dirichlet(np.ones(3), 200_000)  # uniform points of a triangle, barycentric
    mc = ((b @ d.T) < 0.02).mean(axis=0)
    np.testing.assert_allclose(got, mc, atol=0.005)
    assert (got[5:10] == 1.0).all() and (got[10:15] == 0.0).all()


def test_grid_hem_is_the_band_along_the_border():
    """A 2.5 cm hem on a 1 cm grid: faces inside the band have every layer, faces beyond it one, the
    faces the band's edge crosses (between the 2 and 3 cm rows) some between, and the band covers
    the frame's area 2.5 cm wide (the distance is exact on a grid and linear over a face but near
    the frame's corners)."""
    v, f = grid(31, 41, 0.3, 0.4)
    w = 0.025
    layers = hem_face_layers(v, f, w, 2.5)
    d = distance_to_boundary(v, f)[f]
    assert (layers[d.max(axis=1) <= w] == 2.5).all()
    assert (layers[d.min(axis=1) >= w] == 1.0).all()
    crossing = (d.min(axis=1) < w) & (d.max(axis=1) > w)
    assert crossing.sum() > 100 and ((layers[crossing] > 1.0) & (layers[crossing] < 2.5)).all()
    frame = 0.3 * 0.4 - (0.3 - 2 * w) * (0.4 - 2 * w)
    assert abs(hem_area(v, f, layers, 2.5) / frame - 1.0) < 0.02
    np.testing.assert_array_equal(hem_face_layers(v, f, 0.0, 2.5), np.ones(len(f), np.float32))


@pytest.fixture(scope="module")
def body():
    return load_body()


@pytest.mark.parametrize("shape", ["", "height=0.7,weight=0.9"])
@pytest.mark.parametrize("category", ["t_shirt", "trousers", "dress"])
def test_template_hems_line_every_opening(body, category, shape):
    g = make_garment(category, body, parse_shape(shape))
    layers = g.face_layers
    assert layers.dtype == np.float32 and layers.min() == 1.0 and layers.max() == HEM_LAYERS
    edges, uses = unique_edges(g.faces, counts=True)
    border = edges[uses == 1]
    # every face at an opening is hem, at the default resolution nearly all of it (a face's third
    # vertex can lie just beyond the width along the cloth)
    on_border = np.zeros(len(g.rest_vertices), bool)
    on_border[border.ravel()] = True
    touching = on_border[g.faces].sum(axis=1) >= 2
    assert (layers[touching] > 0.9 * HEM_LAYERS).all()
    # the band covers the openings' length times the width (the distance along mesh edges is a
    # little longer than the straight one, so the band a little narrower)
    length = np.linalg.norm(g.rest_vertices[border[:, 0]] - g.rest_vertices[border[:, 1]], axis=1).sum()
    ratio = hem_area(g.rest_vertices, g.faces, layers, HEM_LAYERS) / (length * HEM_WIDTH)
    assert 0.88 < ratio < 1.08, ratio
    # no hem beyond the width along the cloth
    d = distance_to_boundary(g.rest_vertices, g.faces)
    assert (layers[d[g.faces].min(axis=1) >= HEM_WIDTH] == 1.0).all()


DRESS_HEM = pytest.mark.xfail(reason="the sewn dress's hem mass varies with the resolution beyond the bound "
                                     "(1.11 at 7 cm)", strict=False)


@pytest.mark.parametrize("category", ["straight_skirt", pytest.param("t_shirt", marks=pytest.mark.slow),
                                      pytest.param("dress", marks=[pytest.mark.slow, DRESS_HEM])])
def test_hem_mass_does_not_depend_on_the_resolution(body, category):
    """At 7 cm edges (coarser than the hem: every face on an opening partly hem), 2.5 cm and 1.4 cm
    the band covers the openings' length times the width to within 10 % (faces all hem or none
    by the mean of their corners' distances would give 0.89-1.45 times it, 1.37-1.72 at 7 cm)."""
    for res in (0.07, 0.025, 0.014):
        g = make_garment(category, body, resolution=res)
        edges, uses = unique_edges(g.faces, counts=True)
        n = len(g.rest_vertices)
        border = set((edges[uses == 1].astype(np.int64) @ np.array([n, 1])).tolist())
        fs = g.faces
        sides = np.sort(np.stack([fs[:, [0, 1]], fs[:, [1, 2]], fs[:, [2, 0]]], axis=1), axis=2)
        on_opening = np.array([any(int(a) * n + int(b) in border for a, b in t) for t in sides])
        assert (g.face_layers[on_opening] > 1.0).all()
        ends = g.rest_vertices[edges[uses == 1]]
        length = np.linalg.norm(ends[:, 0] - ends[:, 1], axis=1).sum()
        ratio = hem_area(g.rest_vertices, g.faces, g.face_layers, HEM_LAYERS) / (length * HEM_WIDTH)
        assert 0.9 < ratio < 1.1, (res, ratio)


def test_hem_parameters_are_template_parameters(body):
    names = [n for n, *_ in template_parameters("straight_skirt")]
    assert names[-2:] == ["hem_width", "hem_layers"]
    make_params("t_shirt", hem_width=0.03, hem_layers=2.0)  # accepted by every template
    with pytest.raises(WrinklesInputError, match="hem_layers"):
        make_params("shorts", hem_layers=0.5)
    with pytest.raises(WrinklesInputError, match="hem_width"):
        make_params("t_shirt", hem_width=0.5)
    plain = make_garment("straight_skirt", body, hem_width=0.0)
    assert (plain.face_layers == 1.0).all()
    wide = make_garment("straight_skirt", body, hem_width=0.04, hem_layers=2.0)
    narrow = make_garment("straight_skirt", body, hem_layers=2.0)
    assert wide.face_layers.min() == 1.0 and wide.face_layers.max() == 2.0
    wide_area = hem_area(wide.rest_vertices, wide.faces, wide.face_layers, 2.0)
    assert 1.8 < wide_area / hem_area(narrow.rest_vertices, narrow.faces, narrow.face_layers, 2.0) < 2.1
    # the mesh itself does not change
    np.testing.assert_array_equal(plain.faces, wide.faces)
    assert all(c in TEMPLATES for c in ("straight_skirt", "t_shirt", "shorts"))


def test_garment_refuses_bad_face_layers():
    v, f = grid(3, 3, 0.1, 0.1)
    uv = v[:, :2] * 5 + 0.5
    from sim.garments.materials import get_material

    g = Garment(v, f, uv, f, get_material("cotton"))
    assert g.face_layers.shape == (len(f),) and (g.face_layers == 1).all()
    for bad in (np.full(len(f), 0.5), np.ones(len(f) + 1), np.full(len(f), np.nan)):
        with pytest.raises(WrinklesInputError, match="face_layers"):
            Garment(v, f, uv, f, get_material("cotton"), face_layers=bad)


def test_layers_scale_mass_membrane_and_bending():
    v, f = grid(5, 6, 0.2, 0.25)
    mat = ClothMaterialParams(density=0.2, mu=15.0, lam=10.0, bending=1e-5)
    rng = np.random.default_rng(3)
    layers = rng.choice([1.0, 2.0, 3.0], size=len(f))

    def model(face_layers):
        b = ClothModelBuilder()
        b.add_cloth(v, f, mat, face_layers=face_layers)
        return b.finalize("cpu")

    one, many = model(None), model(layers)
    tri = v[f].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    # lumped mass: a third of each face's layered mass at each corner
    expect = np.zeros(len(v))
    np.add.at(expect, f.ravel(), np.repeat(mat.density * area * layers / 3.0, 3))
    np.testing.assert_allclose(many.particle_mass.numpy(), expect, rtol=1e-5)
    total = mat.density * (area * layers).sum()
    np.testing.assert_allclose(many.particle_mass.numpy().sum(), total, rtol=1e-5)
    np.testing.assert_allclose(many.tri_mu.numpy(), mat.mu * layers, rtol=1e-6)
    np.testing.assert_allclose(many.tri_lam.numpy(), mat.lam * layers, rtol=1e-6)
    # a hinge: the mean of its two faces' layers
    hinges = build_hinges(f)
    t_a, t_b = hinge_faces(f, hinges)
    ratio = many.edge_stiffness.numpy() / one.edge_stiffness.numpy()
    np.testing.assert_allclose(ratio, 0.5 * (layers[t_a] + layers[t_b]), rtol=1e-5)
    b = ClothModelBuilder()
    with pytest.raises(ValueError, match="face_layers"):
        b.add_cloth(v, f, mat, face_layers=np.full(len(f), 0.9))
    with pytest.raises(ValueError, match="face_layers"):
        b.add_cloth(v, f, mat, face_layers=np.ones(3))


def test_hinge_faces_hold_the_hinge_edge():
    v, f = grid(4, 4, 0.1, 0.1)
    hinges = build_hinges(f)
    t_a, t_b = hinge_faces(f, hinges)
    for (o0, o1, a, b), fa, fb in zip(hinges, f[t_a], f[t_b], strict=True):
        assert {a, b, o0} == set(fa) and {a, b, o1} == set(fb)


def test_hinge_faces_match_a_directed_edge_table_on_a_garment():
    g = make_garment("t_shirt", load_body(), None, resolution="coarse")
    f = g.faces.astype(np.int64)
    table = {(int(a), int(b)): t for t, row in enumerate(f)
             for a, b in zip(row, np.roll(row, -1), strict=True)}
    hinges = build_hinges(g.faces)
    t_a, t_b = hinge_faces(g.faces, hinges)
    np.testing.assert_array_equal(t_a, [table[(a, b)] for a, b in hinges[:, 2:]])
    np.testing.assert_array_equal(t_b, [table[(b, a)] for a, b in hinges[:, 2:]])
    with pytest.raises(KeyError, match="no triangle"):
        hinge_faces(g.faces, np.array([[0, 1, 0, int(f.max()) + 5]]))
