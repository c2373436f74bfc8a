"""Self-contact data and settings (sim.cloth.self_contact.data, SelfContact, the solver's
self-contact options): the solve's view carries every field it names, the disabled data is
complete, and wrong settings are refused when they are made."""

from __future__ import annotations

import inspect
import re

import pytest
import warp as wp

from sim.cloth import ClothMaterialParams, ClothModelBuilder, SelfContactConfig, SolverVBD, VBDConfig
from sim.cloth.self_contact import (
    SelfContact,
    SelfContactData,
    SolveContactArrays,
    contact_view,
    disabled_data,
)
from sim.cloth.self_contact.data import solve_contact_arrays, solve_contact_key
from tests.test_cloth_solver import grid

CONTACT = dict(radius=0.003, margin=0.004, stiffness=1e4, friction=0.0, speed_factor=2.5, capacity=4)


def small_model(device: str = "cpu"):
    """A 3 x 3 grid: 9 vertices, 8 triangles, 16 edges."""
    v, f = grid(3, 3, 0.1, 0.1, plane="xz")
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams())
    return b.finalize(device)


def test_the_solve_view_sets_every_field_it_carries():
    """``contact_view`` (a Warp function, written out) sets every field of
    ``SolveContactArrays`` on the ``SelfContactData`` it builds, and each is a field of it."""
    source = inspect.getsource(contact_view.func)
    assigned = set(re.findall(r"^\s*sc\.(\w+) = ", source, re.MULTILINE))
    assert assigned == set(SolveContactArrays.vars)
    assert assigned <= set(SelfContactData.vars)


def test_the_solve_arrays_point_at_the_data_and_their_key_follows_them():
    """``solve_contact_arrays`` gives the spans of the data's own arrays; its key changes when
    an array is replaced (the solver then rebuilds the spans)."""
    sc = SelfContact(small_model(), **CONTACT)
    a = solve_contact_arrays(sc.data)
    assert a.pair_verts.ptr == sc.data.pair_verts.ptr and a.pair_verts.n == sc.data.pair_verts.shape[0]
    assert a.radius == pytest.approx(0.003) and a.enabled == 1
    key = solve_contact_key(sc.data)
    assert solve_contact_key(sc.data) == key
    kept = sc.data.pair_ref  # the old array stays alive: a new one gets a new address
    sc.data.pair_ref = wp.zeros_like(kept)
    assert solve_contact_key(sc.data) != key


def test_disabled_data_is_off_with_every_array_set():
    sc = disabled_data("cpu")
    assert sc.enabled == 0
    for name, var in SelfContactData.vars.items():
        value = getattr(sc, name)
        if hasattr(value, "shape"):
            assert value.shape == (1,), name
            assert value.dtype == var.type.dtype, name
        else:
            assert value == 0, name


@pytest.mark.parametrize("bad,match", [
    ({"broadphase": "grid"}, "broadphase"), ({"weight_floor": 1.5}, "weight_floor"),
    ({"heavy_cap": -1}, "heavy_cap"), ({"coarse_exclusion": -0.001}, "coarse_exclusion"),
    ({"broadphase": "clusters", "cluster_split": -1}, "cluster_split"),
    ({"broadphase": "clusters", "cluster_size": 12}, "size")])
def test_self_contact_settings_are_checked(bad, match):
    with pytest.raises(ValueError, match=match):
        SelfContact(small_model(), **CONTACT, **bad)


def test_an_automatic_split_halves_one_garments_cluster_query():
    sc = SelfContact(small_model(), **CONTACT, broadphase="clusters", cluster_split=0)
    assert sc.broadphase.split == 2
    assert SelfContact(small_model(), **CONTACT).clusters is None


def test_solver_self_contact_options_are_checked():
    for bad, match in (({"radius": 0.02, "margin": 0.01}, "self_contact.margin"),
                       ({"broadphase": "grid"}, "self_contact.broadphase"),
                       ({"cluster_size": 0}, "self_contact.cluster_size"),
                       ({"weight_floor": -0.1}, "self_contact.weight_floor"),
                       ({"weight_floor": 1.5}, "self_contact.weight_floor"),
                       ({"coarse_exclusion": -0.001}, "self_contact.coarse_exclusion")):
        with pytest.raises(ValueError, match=match):
            SelfContactConfig(**bad)


def test_the_automatic_broadphase_is_the_clusters_on_cuda_for_small_models():
    """``"auto"``: the clusters on CUDA for a model of at most ``CLUSTER_PRIMITIVES`` vertices,
    triangles and edges, the trees on the CPU and for larger models."""
    from sim.cloth import solver_vbd

    solver = SolverVBD(small_model(), VBDConfig())  # self-contact on, broadphase "auto"
    assert solver.broadphase(cuda=True) == "clusters" and solver.broadphase(cuda=False) == "bvh"
    assert solver.self_contact.clusters is None
    primitives = 9 + 8 + 16  # the 3 x 3 grid's vertices, triangles and edges
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(solver_vbd, "CLUSTER_PRIMITIVES", primitives - 1)
        assert solver.broadphase(cuda=True) == "bvh"
        mp.setattr(solver_vbd, "CLUSTER_PRIMITIVES", primitives)
        assert solver.broadphase(cuda=True) == "clusters"
