"""Hems: the bands of extra fabric layers along a garment's openings, and what the cloth model
makes of a face's layers (mass, membrane, bending)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.bodies import load_body
from sim.bodies.default import parse_shape
from sim.cloth import ClothModelBuilder
from sim.cloth.model import ClothMaterialParams, build_hinges, hinge_faces
from sim.errors import WrinklesInputError
from sim.garments import TEMPLATES, make_garment
from sim.garments.hems import HEM_LAYERS, HEM_WIDTH, boundary_vertices, distance_to_boundary, hem_face_layers
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
    from tests.test_cloth_solver import uv_sphere

    v, f = uv_sphere((0.0, 0.0, 0.0), 0.2)
    assert np.isinf(distance_to_boundary(v, f)).all()
    np.testing.assert_array_equal(hem_face_layers(v, f, 0.05, 2.0), 1.0)


def test_grid_hem_is_the_band_along_the_border():
    """A 2 cm hem on a 1 cm grid: the faces whose corners average under 2 cm from the border."""
    v, f = grid(31, 41, 0.3, 0.4)
    layers = hem_face_layers(v, f, 0.02, 2.5)
    assert set(np.unique(layers)) == {1.0, 2.5}
    c = v[f].mean(axis=1)
    x, y = c[:, 0], -c[:, 1]
    from_side = np.minimum.reduce([x, 0.3 - x, y, 0.4 - y])
    # every face within a centimetre of the border is hem, none beyond 2 cm (+ a third of a row:
    # the rule takes the mean of the corners' distances, below the centroid's at a corner)
    assert (layers[from_side < 0.01] == 2.5).all()
    assert (layers[from_side > 0.0234] == 1.0).all()
    assert 0.3 * 0.4 - (0.3 - 0.04) * (0.4 - 0.04) < 1.2 * (layers > 1).sum() * 0.5 * 0.01 ** 2
    assert np.array_equal(hem_face_layers(v, f, 0.0, 2.5), np.ones(len(f), np.float32))


@pytest.fixture(scope="module")
def body():
    return load_body()


@pytest.mark.parametrize("shape", ["", "height=0.7,weight=0.9"])
@pytest.mark.parametrize("category", ["t_shirt", "trousers", "dress"])
def test_template_hems_line_every_opening(body, category, shape):
    g = make_garment(category, body, parse_shape(shape))
    layers = g.face_layers
    assert layers.dtype == np.float32 and set(np.unique(layers)) == {1.0, HEM_LAYERS}
    edges, uses = unique_edges(g.faces, counts=True)
    border = edges[uses == 1]
    # every face with an edge on an opening is hem
    on_border = np.zeros(len(g.rest_vertices), bool)
    on_border[border.ravel()] = True
    touching = on_border[g.faces].sum(axis=1) >= 2
    assert (layers[touching] == HEM_LAYERS).all()
    # the band's area is the openings' length times the width, to within the row rounding
    tri = g.rest_vertices[g.faces].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    length = np.linalg.norm(g.rest_vertices[border[:, 0]] - g.rest_vertices[border[:, 1]], axis=1).sum()
    ratio = area[layers > 1].sum() / (length * HEM_WIDTH)
    assert 0.6 < ratio < 1.4, ratio
    # no hem face far from an opening along the cloth
    d = distance_to_boundary(g.rest_vertices, g.faces)
    assert d[g.faces[layers > 1]].mean(axis=1).max() < HEM_WIDTH


@pytest.mark.parametrize("category", ["straight_skirt", "t_shirt"])
def test_a_mesh_coarser_than_the_hem_keeps_one_row_of_it(body, category):
    """At 7 cm edges no face's corners average under 2 cm from an opening; the faces with an edge
    on one are hem all the same, and nothing else is."""
    g = make_garment(category, body, resolution=0.07)
    edges, uses = unique_edges(g.faces, counts=True)
    n = len(g.rest_vertices)
    border = set((edges[uses == 1].astype(np.int64) @ np.array([n, 1])).tolist())
    sides = np.sort(np.stack([g.faces[:, [0, 1]], g.faces[:, [1, 2]], g.faces[:, [2, 0]]], axis=1), axis=2)
    on_opening = np.array([any(int(a) * n + int(b) in border for a, b in t) for t in sides])
    np.testing.assert_array_equal(g.face_layers > 1, on_opening)
    assert on_opening.sum() > 20


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
    assert set(np.unique(wide.face_layers)) == {1.0, 2.0}
    assert (wide.face_layers > 1).sum() > 1.5 * (narrow.face_layers > 1).sum()
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
