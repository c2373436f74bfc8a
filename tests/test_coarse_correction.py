"""The coarse-level correction inside the VBD solver (``sim.cloth.coarse``,
``CoarseConfig``): further per sweep, cloth kept on the body, layers kept apart."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth import SolverVBD
from sim.cloth.config import CoarseConfig, SelfContactConfig
from sim.device import warp
from sim.quality import self_intersections
from tests.test_cloth_solver import drop_on_sphere, one_step_from, plain_config, simulate
from tests.test_coarse import strip


@pytest.mark.parametrize("levels", [2, 3])
def test_coarse_correction_converges_far_further_per_sweep(device, levels):
    """One stiff implicit step of the long strip: 20 sweeps with a coarse correction before every
    second sweep end an order of magnitude closer to the converged step than 20 plain sweeps;
    pins stay put; a single correction before the first sweep already helps. The same with three
    levels (the coarse system solved by the two-grid cycle, not exactly)."""
    m, v = strip(device)

    def step(iterations: int, sweeps=()) -> np.ndarray:
        coarse = CoarseConfig(sweeps=sweeps, spacing=3, levels=levels)
        solver = SolverVBD(m, plain_config(1, iterations, air_damping=0.0, coarse=coarse))
        assert solver.coarse is None or solver.coarse.levels == levels
        return simulate(m, solver, m.control(), 1, 1.0 / 30.0)[-1]

    ref = step(200, tuple(range(1, 200, 2)))
    plain = np.abs(step(20) - ref).max()
    coarse = step(20, tuple(range(1, 20, 2)))
    assert plain > 5e-3  # far from converged: the comparison means something
    assert np.abs(coarse - ref).max() < 0.1 * plain
    assert np.abs(step(20, (0,)) - ref).max() < 0.2 * plain
    np.testing.assert_array_equal(coarse[:11], v[:11])
    # the converged step is the same with and without corrections (they change the path only)
    np.testing.assert_allclose(step(3000), ref, atol=0.15 * plain)


@pytest.mark.parametrize("levels", [2, 3])
def test_coarse_correction_keeps_cloth_on_a_sphere_outside(device, levels):
    """The contact penalty is part of the coarse system: corrections do not pull cloth resting on
    a sphere into it, and a correction moves no cloth on the body deeper into it than it is or
    than its 5 mm thickness: the cloth stays more than half its thickness out, and on the sphere's
    top. Two levels take the contact stiffness at the inertial targets with the factor from the
    substep start (the system of both corrections of a substep); three levels take it at each
    correction, their inner level through its Galerkin product."""
    m, _, control, body, _ = drop_on_sphere(device)
    coarse = CoarseConfig(sweeps=(0, 2), spacing=3, levels=levels)
    solver = SolverVBD(m, plain_config(5, 5, coarse=coarse))
    assert solver.coarse.levels == levels and solver.coarse.prefactor == (levels == 2)
    x = simulate(m, solver, control, 30, 1.0 / 30.0)
    assert np.isfinite(x).all()
    assert min(body.signed_distance(frame).min() for frame in x) > 0.0025
    top = np.abs(x[-1, :, 0]) + np.abs(x[-1, :, 2]) < 0.05
    assert top.any()  # the cloth is still on the sphere's top (a cloth thrown off it fails here)
    assert np.all(x[-1, top, 1] > 0.19)
    assert np.all(x[-1, top, 1] < 0.215)


def assert_layers_kept_apart(x, faces, nv, n, device, landed: float) -> None:
    """The stacked layers' run ``x``: finite, never crossing, the top sheet always above the
    bottom one at the centre and at most ``landed`` [m] above it at the end."""
    from tests.self_contact_scenes import center_gap

    assert np.all(np.isfinite(x))
    np.testing.assert_array_equal(self_intersections(x, faces, device=device), 0)
    gap = center_gap(x, nv, n)
    assert np.all(gap > 0.0)
    assert gap[-1] < landed


@pytest.mark.parametrize("sweeps", [(0, 2, 4), (0, 1, 2, 3, 4)])
def test_coarse_corrections_carry_no_layer_through_another(device, sweeps):
    """A sheet dropped at 1 m/s onto a pinned one (``self_contact_scenes.stacked_layers``) with
    corrections before the sweeps, aggregates 3 edges apart. The self-contact penalty is part of
    the coarse system at particles with pairs (the residual holds the contact forces), and the
    prolongated moves are capped near pairs: the sheets never cross and the top one lands on the
    other."""
    from tests.self_contact_scenes import stacked_layers

    x, faces, nv, n = stacked_layers(device, True, speed=1.0, frames=20,
                                     solver={"coarse.sweeps": sweeps, "coarse.spacing": 3})
    assert_layers_kept_apart(x, faces, nv, n, device, landed=0.03)


def test_early_diagonal_takes_the_previous_substeps_pairs(device):
    """``CoarseConfig.early``: the velocity kernel flags the particles with pairs at a substep's
    end, and the next substep's ``prepare`` (beside the detection) gives exactly those the
    self-contact stiffness: the step's diagonal is ``prepare``'s from the flags it found, the
    flags give the same diagonal as the pair lists they came from, bit for bit, and without them
    the diagonal is smaller by ``P^T`` of the stiffness at exactly the flagged particles. Off, no
    flags are written."""
    from tests.test_cloth_solver import draped_layers_in_contact

    wp = warp()
    m, *start = draped_layers_in_contact(device)
    h = 1.0 / 120.0
    solver = SolverVBD(m, plain_config(1, 4, self_contact=SelfContactConfig(),
                                       coarse=CoarseConfig(sweeps=(1,), early=True)))
    s = m.state()
    s.positions.assign(start[0])
    s.velocities.assign(start[1])
    control = m.control()
    solver.step(s, s, control, h)
    sc = solver.self_contact.data
    counts = sc.vt_count.numpy() + sc.tv_total.numpy() + sc.ee_total.numpy()
    flags = solver._pair_flags.numpy()
    assert flags.shape == (m.particle_count,) and set(np.unique(flags)) == {0, 1}
    np.testing.assert_array_equal(flags, (counts > 0).astype(np.int32))
    # the next step's diagonal is made from the flags it starts with, whatever its own pairs:
    # flag every other particle instead, step, and form the diagonal from those by hand
    planted = np.zeros_like(flags)
    planted[::2] = 1
    solver._pair_flags.assign(planted)
    solver.step(s, s, control, h)
    level = solver.coarse
    stepped = level.diag.numpy().copy()
    level.prepare(h, sc, wp.array(planted, dtype=wp.int32, device=device))
    np.testing.assert_array_equal(level.diag.numpy(), stepped)
    diags = {}
    flags = solver._pair_flags.numpy()  # the second step's pairs
    assert flags.any()
    for name, pair_flags in (("lists", None), ("flags", solver._pair_flags),
                             ("none", wp.zeros_like(solver._pair_flags))):
        level.prepare(h, sc, pair_flags)
        diags[name] = level.diag.numpy().copy()
    np.testing.assert_array_equal(diags["flags"], diags["lists"])
    assert np.abs(stepped - diags["flags"]).max() > 0.0  # the planted flags are not the pairs
    added = level.prolongation.T @ (flags * sc.stiffness)
    assert added.max() > 0.0
    np.testing.assert_allclose(diags["lists"] - diags["none"], added, rtol=1e-4, atol=1e-6 * added.max())
    _, plain = one_step_from(m, start, coarse=CoarseConfig(sweeps=(1,)))
    assert plain._pair_flags.shape[0] == 0
