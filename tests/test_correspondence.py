"""Pattern correspondence between two meshings of one sewing pattern
(``sim.garments.correspondence``): each panel found by name whatever its place in the packed
UVs, every source vertex landing on the same piece of cloth of the target."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.garments.correspondence import layout_locations, panel_offsets, pattern_locations
from sim.garments.materials import get_material
from sim.garments.types import Garment

PANELS = {"front": (0.5, 0.6), "sleeve": (0.3, 0.2)}
"""Panel sizes [m] (width, height)."""
PLACE = {"front": np.array([0.0, 0.0, 0.1]), "sleeve": np.array([0.6, 0.3, -0.2])}
"""Where each panel lies in 3D (flat, in a plane z = const, panel-local x, y)."""


def flat_garment(n: int, packing: dict[str, tuple[float, float]], scale: float = 2.0) -> Garment:
    """Both panels meshed as n x n vertex grids; 3D rest = panel-local flat + PLACE; UVs the flat
    coordinates packed at ``packing`` offsets [m] and divided by ``scale`` (the uv_scale)."""
    vs, fs, uvs, pids = [], [], [], []
    base = 0
    for pid, (name, (w, h)) in enumerate(PANELS.items()):
        x, y = np.meshgrid(np.linspace(0, w, n), np.linspace(0, h, n))
        local = np.stack([x.ravel(), y.ravel()], axis=1)
        vs.append(np.concatenate([local, np.zeros((n * n, 1))], axis=1) + PLACE[name])
        uvs.append((local + packing[name]) / scale)
        i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None]).ravel()
        f = np.concatenate([np.stack([i, i + 1, i + n + 1], 1), np.stack([i, i + n + 1, i + n], 1)])
        fs.append(f + base)
        pids.append(np.full(len(f), pid))
        base += n * n
    faces = np.concatenate(fs)
    return Garment(np.concatenate(vs), faces, np.concatenate(uvs), faces, get_material("cotton"),
                   panel_ids=np.concatenate(pids), panel_names=tuple(PANELS), uv_scale=scale)


def test_every_vertex_lands_on_the_same_cloth_of_the_other_meshing():
    coarse = flat_garment(7, {"front": (0.05, 0.05), "sleeve": (0.6, 0.05)})
    fine = flat_garment(23, {"front": (0.4, 0.3), "sleeve": (0.02, 0.02)}, scale=1.5)
    off = panel_offsets(coarse, fine)
    np.testing.assert_allclose(off["front"], [0.35, 0.25], atol=1e-6)
    np.testing.assert_allclose(off["sleeve"], [-0.58, -0.03], atol=1e-6)
    loc = pattern_locations(coarse, fine)
    assert loc.inside.all()
    np.testing.assert_allclose(loc.barycentric.sum(axis=1), 1.0)
    np.testing.assert_allclose(loc.evaluate(fine.faces, fine.rest_vertices), coarse.rest_vertices, atol=1e-6)
    # many frames at once: a rigid motion of the target carries the points along
    frames = np.stack([fine.rest_vertices + [0.0, 0.1 * t, 0.0] for t in range(3)])
    moved = loc.evaluate(fine.faces, frames)
    np.testing.assert_allclose(moved[2], coarse.rest_vertices + [0.0, 0.2, 0.0], atol=1e-6)
    # the reverse way: fine vertices on the coarse mesh, still the same cloth
    back = pattern_locations(fine, coarse)
    np.testing.assert_allclose(back.evaluate(coarse.faces, coarse.rest_vertices), fine.rest_vertices,
                               atol=1e-6)


def test_a_panel_the_target_lacks_is_refused():
    g = flat_garment(5, {"front": (0.05, 0.05), "sleeve": (0.6, 0.05)})
    other = Garment(g.rest_vertices, g.faces, g.uvs, g.uv_faces, g.material, panel_ids=g.panel_ids,
                    panel_names=("front", "cuff"), uv_scale=g.uv_scale)
    with pytest.raises(WrinklesInputError, match="no panel 'sleeve'"):
        pattern_locations(g, other)


def test_a_point_outside_the_targets_outline_goes_to_the_nearest_border_triangle():
    """Two opposite corners of the source's front 2 mm out along the diagonal (its centroid
    stays): they lie outside the target and land on its corners; every other vertex inside."""
    g = flat_garment(9, {"front": (0.05, 0.05), "sleeve": (0.6, 0.05)})
    fine = flat_garment(17, {"front": (0.3, 0.3), "sleeve": (0.02, 0.02)})
    uvs = np.array(g.uvs, dtype=np.float64)
    front = np.unique(g.uv_faces[g.panel_ids == 0])
    top, bottom = front[np.argmax(uvs[front].sum(axis=1))], front[np.argmin(uvs[front].sum(axis=1))]
    step = 0.002 / np.sqrt(2.0) / g.uv_scale
    uvs[top] += step
    uvs[bottom] -= step
    grown = Garment(g.rest_vertices, g.faces, uvs, g.uv_faces, g.material, panel_ids=g.panel_ids,
                    panel_names=g.panel_names, uv_scale=g.uv_scale)
    loc = pattern_locations(grown, fine)
    outside = np.flatnonzero(~loc.inside)
    assert sorted(outside.tolist()) == sorted([int(top), int(bottom)])
    assert np.all(loc.barycentric >= 0)
    np.testing.assert_allclose(loc.barycentric.sum(axis=1), 1.0)
    at = loc.evaluate(fine.faces, fine.rest_vertices)
    np.testing.assert_allclose(at, g.rest_vertices, atol=1e-6)  # the overhanging corners on the target's


def test_layout_locations_match_pattern_locations_without_panel_names():
    """Two meshings packed alike, the target's UVs 1 % larger: the UV layouts alone place every
    source vertex where the named panels do."""
    packing = {"front": (0.05, 0.05), "sleeve": (0.6, 0.05)}
    coarse = flat_garment(7, packing)
    fine = flat_garment(23, {k: (x * 1.01, y * 1.01) for k, (x, y) in packing.items()}, scale=2.0 / 1.01)
    loc = layout_locations(coarse.faces, coarse.uvs, coarse.uv_faces, fine.uvs, fine.uv_faces)
    assert loc.inside.all()
    np.testing.assert_allclose(loc.evaluate(fine.faces, fine.rest_vertices), coarse.rest_vertices, atol=1e-5)


def test_layout_locations_on_a_sewn_tshirt_agree_with_the_pattern():
    """A real t-shirt's coarse and fine meshings (curved outlines, seams): the located points on
    the fine rest surface within a millimetre of the named-panel locations."""
    from sim.bodies import load_body
    from sim.garments import make_garment

    body = load_body()
    coarse = make_garment("t_shirt", body, resolution=0.06)
    fine = make_garment("t_shirt", body, resolution=0.03)
    loc = layout_locations(coarse.faces, coarse.uvs, coarse.uv_faces, fine.uvs, fine.uv_faces)
    ref = pattern_locations(coarse, fine)
    at = [x.evaluate(fine.faces, fine.rest_vertices) for x in (loc, ref)]
    d = np.linalg.norm(at[0] - at[1], axis=1)
    assert d.max() < 1e-3, d.max()
    assert loc.inside.mean() > 0.9


def test_layouts_of_different_patterns_are_refused():
    g = flat_garment(5, {"front": (0.05, 0.05), "sleeve": (0.6, 0.05)})
    one = g.uv_faces[g.panel_ids == 0]
    with pytest.raises(WrinklesInputError, match="not the same pattern"):
        layout_locations(g.faces, g.uvs, g.uv_faces, g.uvs, one)
