"""The batched cloth model's arrays from per-mesh parts (``sim.cloth.model.mesh_parts``): the
same as computing them over the whole stacked batch, whether the parts were cached or not."""

from __future__ import annotations

import numpy as np
import pytest

from sim.bodies import load_body
from sim.cloth import ClothModelBuilder
from sim.cloth import model as M
from sim.garments import make_garment
from sim.garments.materials import get_material


def stacked_adjacency(model) -> dict[str, np.ndarray]:
    """The adjacency computed over the whole batch at once (the reference)."""
    faces, hinges, colors = model.faces, model.hinges, model.colors
    n = model.particle_count
    vt = M._csr(n, faces.reshape(-1),
                [np.repeat(np.arange(len(faces)), 3), np.tile(np.arange(3), len(faces))])
    ve = M._csr(n, hinges.reshape(-1).astype(np.int64),
                [np.repeat(np.arange(len(hinges)), 4), np.tile(np.arange(4), len(hinges))])
    me = M.mesh_edges(faces)
    vme = M._csr(n, me.reshape(-1).astype(np.int64),
                 [np.repeat(np.arange(len(me)), 2), np.tile(np.arange(2), len(me))])
    out = {"mesh_edge_indices": me}
    for name, csr, local in (("vertex_tri", vt, M.local_packed(colors, faces, vt)),
                             ("vertex_edge", ve, M.local_packed(colors, hinges.reshape(-1, 4), ve)),
                             ("vertex_mesh_edge", vme, vme[2])):
        out.update({f"{name}_offsets": csr[0], f"{name}_ids": csr[1], f"{name}_local": local})
    return out


@pytest.fixture(scope="module")
def garments():
    body = load_body()
    return (make_garment("t_shirt", body, None, resolution="coarse"),
            make_garment("straight_skirt", body, None, resolution="coarse"))


def build(garments, device="cpu"):
    b = ClothModelBuilder(max_colors=3)
    shirt, skirt = garments
    for g, material, shift in ((shirt, "cotton", 0.0), (skirt, "jersey_knit", 0.1),
                               (shirt, "jersey_knit", 0.2)):
        b.add_cloth(g.rest_vertices + shift, g.faces, get_material(material), rest_vertices=g.rest_vertices,
                    face_layers=g.face_layers, rest_corners=g.flat_corners(), face_panels=g.panel_ids)
    return b.finalize(device)


def test_a_batch_of_repeated_meshes_matches_the_whole_batch_computation(garments):
    M._MESH_PARTS.clear()
    cold = build(garments)
    assert len(M._MESH_PARTS) == 2  # the t-shirt's parts serve its two instances
    shared = next(iter(M._MESH_PARTS.values()))
    with pytest.raises(ValueError, match="read-only"):
        shared["area"][0] = 1.0  # shared by every model of the mesh: nobody writes into it
    want = stacked_adjacency(cold)
    for name, ref in want.items():
        np.testing.assert_array_equal(getattr(cold, name).numpy().reshape(ref.shape), ref, err_msg=name)
    warm = build(garments)
    for name in ("particle_mass", "particle_flat", "particle_panel", "tri_dm_inv", "tri_area",
                 "edge_rest_angle", "edge_stiffness", "vertex_tri_local", "vertex_edge_ids",
                 "mesh_edge_instance", "tri_instance"):
        np.testing.assert_array_equal(getattr(warm, name).numpy(), getattr(cold, name).numpy(), err_msg=name)
    # the instances of one mesh differ by their material only
    s = cold.instance_starts
    mass = cold.particle_mass.numpy()
    ratio = get_material("jersey_knit").density / get_material("cotton").density
    np.testing.assert_allclose(mass[s[2]:s[3]], ratio * mass[s[0]:s[1]], rtol=1e-6)
    # the stiffness is hinge_factors at each instance's bending
    from sim.cloth.topology import build_hinges

    shirt = garments[0]
    hinges = build_hinges(shirt.faces)
    _, areas = M.flat_rest_data(shirt.flat_corners())
    layers = np.ones(len(areas)) if shirt.face_layers is None else np.asarray(shirt.face_layers, np.float64)
    k = cold.edge_stiffness.numpy()
    for first, material in ((0, "cotton"), (len(k) - len(hinges), "jersey_knit")):
        want = M.hinge_factors(shirt.rest_vertices, shirt.faces, hinges, areas, layers,
                               M.as_cloth_params(get_material(material)).bending).astype(np.float32)
        np.testing.assert_array_equal(k[first:first + len(hinges)], want)
