"""The batched-throughput floor (benchmarks/batch_floor.py): its contact-free sweep must do the
job's per-particle physics, or the floor it times says nothing about the job's sweeps."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth import ClothMaterialParams, ClothModelBuilder, SolverVBD, VBDConfig
from tests.test_cloth_solver import grid


def _bent_stretched_sheet(device: str, bending: float = 2e-5):
    """A flat 9 x 9 sheet of 20 cm, stretched 8 % along x and rolled onto a cylinder of 30 cm
    radius about the x axis (its hinges bent 38 degrees in all), at rest (zero velocity):
    membrane, its damping, bending and inertia all act on the first step."""
    v, f = grid(9, 9, 0.2, 0.2)
    rest = v.copy()
    x = v.copy()
    x[:, 0] *= 1.08
    r = 0.3
    theta = -v[:, 1] / r  # arc length along the roll = the rest length: only x is stretched
    x[:, 1], x[:, 2] = -r * np.sin(theta), r * (1.0 - np.cos(theta))
    b = ClothModelBuilder()
    b.add_cloth(x, f, ClothMaterialParams(density=0.2, mu=400.0, lam=150.0, bending=bending, damping=3e-3),
                rest_vertices=rest)
    return b.finalize(device), x


@pytest.mark.parametrize("layout", ["threads", "lanes"])
@pytest.mark.parametrize("sweeps", [1, 4])
@pytest.mark.parametrize("bending, rtol", [(0.0, 1e-4), (2e-5, 1e-2)])
def test_the_floor_sweep_takes_the_solvers_contact_free_step(device, layout, sweeps, bending, rtol):
    """With contact, self-contact, air damping and the coarse correction off, one substep of
    ``SolverVBD`` is the floor kernel's sweeps from the same first guess: the same positions to
    round-off without bending; with it, up to the solver reading a hinge's same-coloured
    opposite vertex from the sweep's snapshot where the floor reads it live (a Jacobi against a
    Gauss-Seidel coupling: 0.4 % of the move at this stiffness, 3 % at ten times it). Both
    layouts: one thread per particle, and blocks of particles x lanes (4 lanes on CUDA; a CPU
    block is one thread)."""
    from benchmarks.batch_floor import FloorScene

    wp = pytest.importorskip("warp")
    h = 1.0 / 240.0
    model, x0 = _bent_stretched_sheet(device, bending)
    solver = SolverVBD(model, VBDConfig(substeps=1, iterations=sweeps, air_damping=0.0))
    state = model.state()
    solver.step(state, state, model.control(), h)
    x_solver = state.positions.numpy()

    scene = FloorScene(model, h)
    lanes = None if layout == "threads" else ((32, 4) if device == "cuda" else (1, 1))
    for _ in range(sweeps):
        scene.sweep(lanes)
    wp.synchronize_device(device)
    x_floor = scene.x.numpy()

    moved = np.abs(x_solver - x0).max()
    assert moved > 1e-4  # the stretched, bent sheet moves: the comparison below means something
    np.testing.assert_allclose(x_floor, x_solver, atol=rtol * moved)
    # the floor is not the inertial target alone: without the elastic terms the sheet would
    # only fall by h^2 g, far from where both solvers put it
    y = x0 + h * h * np.asarray(model.gravity, np.float32)
    assert np.abs(x_floor - y).max() > 0.5 * moved


@pytest.mark.parametrize("sweeps", [1, 4])
def test_the_job_layout_times_the_solvers_own_sweeps(device, sweeps):
    """``FloorScene.job_sweep`` runs the job's solve kernel on the substep its one set-up step
    left: k more sweeps land exactly where a step of 1 + k sweeps does (the snapshots
    alternating as the step's), so the ``job`` layout times the job's own contact-free sweeps."""
    from benchmarks.batch_floor import FloorScene

    h = 1.0 / 240.0
    model, x0 = _bent_stretched_sheet(device)
    solver = SolverVBD(model, VBDConfig(substeps=1, iterations=1 + sweeps, air_damping=0.0))
    state = model.state()
    solver.step(state, state, model.control(), h)

    scene = FloorScene(model, h)
    for _ in range(sweeps):
        scene.job_sweep()
    x_job = scene.job_solver()[1].positions.numpy()
    assert np.abs(x_job - x0).max() > 1e-4
    if device == "cpu":
        np.testing.assert_array_equal(x_job, state.positions.numpy())
    else:  # the job's CUDA settings (fast math) against the bare config's
        np.testing.assert_allclose(x_job, state.positions.numpy(), atol=1e-6)


def test_the_floor_reads_each_array_once_per_sweep():
    """``sweep_bytes``: every input array's bytes once, plus the positions written back."""
    from benchmarks.batch_floor import FloorScene

    model, _ = _bent_stretched_sheet("cpu")
    scene = FloorScene(model, 1.0 / 360.0)
    n, t, e = model.particle_count, model.tri_count, model.edge_count
    adj_t, adj_e = 3 * t, 4 * e
    expected = (n * 4  # colour lists
                + 3 * n * 12 + n * 4  # x read and written, y, mass
                + t * (12 + 16 + 4 * 4 + 12)  # indices, Dm^-1, area / mu / lam / damping, strain_prev
                + e * (16 + 4 * 4)  # indices, rest angle, stiffness, damping, angle_prev
                + 2 * (n + 1) * 4 + 2 * adj_t * 4 + 2 * adj_e * 4)  # the two CSR adjacencies
    assert scene.sweep_bytes() == expected
    # copies of one mesh share the topology: the colour lists, indices and adjacencies once
    b = ClothModelBuilder()
    v, f = grid(9, 9, 0.2, 0.2)
    for _ in range(3):
        b.add_cloth(v, f, ClothMaterialParams())
    three = FloorScene(b.finalize("cpu"), 1.0 / 360.0)
    topology = n * 4 + t * 12 + e * 16 + 2 * (n + 1) * 4 + 2 * adj_t * 4 + 2 * adj_e * 4
    offsets_once = 2 * 2 * 4  # the two CSR offset arrays have 3n + 1 entries, not 3 (n + 1)
    assert three.sweep_bytes() == 3 * expected - offsets_once
    assert three.sweep_bytes_shared() == 3 * (expected - topology) + (3 * topology - offsets_once) // 3
