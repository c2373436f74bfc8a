"""The batched-throughput floor (benchmarks/batch_floor.py): its contact-free sweep must do the
job's per-particle physics, or the floor it times says nothing about the job's sweeps."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth import ClothMaterialParams, ClothModelBuilder, SolverVBD, VBDConfig
from tests.test_cloth_solver import grid


def _bent_stretched_sheet(device: str, bending: float = 2e-5, membrane: bool = True):
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
    mu, lam = (400.0, 150.0) if membrane else (0.0, 0.0)
    b.add_cloth(x, f, ClothMaterialParams(density=0.2, mu=mu, lam=lam, bending=bending, damping=3e-3),
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


@pytest.mark.parametrize("sweeps", [1, 3])
def test_a_block_per_garment_takes_the_same_sweeps(device, sweeps):
    """The ``block`` layout (one block per instance, its positions in shared memory, barriers
    between colours) sweeps each instance exactly as the per-colour launches do: on the CPU the
    same order, so the same floats; on CUDA up to the order of same-coloured hinge neighbours'
    live reads. Two instances of different sizes and shapes, so a wrong run or offset shows."""
    from benchmarks.batch_floor import FloorScene

    v, f = grid(9, 9, 0.2, 0.2)
    v2, f2 = grid(7, 11, 0.15, 0.25)
    b = ClothModelBuilder()
    cloth = ClothMaterialParams(density=0.2, mu=400.0, lam=150.0, bending=2e-5, damping=3e-3)
    for rest, faces, stretch in ((v, f, 1.08), (v2, f2, 0.95)):
        x = rest.copy()
        x[:, 0] *= stretch
        x[:, 2] = 0.02 * np.sin(12.0 * rest[:, 1])  # rippled: bent hinges
        b.add_cloth(x, faces, cloth, rest_vertices=rest)
    model = b.finalize(device)
    x0 = model.particle_q.numpy()
    h = 1.0 / 360.0
    plain, block = FloorScene(model, h), FloorScene(model, h)
    for _ in range(sweeps):
        plain.sweep()
    block.block_sweeps(64, sweeps)
    x_plain, x_block = plain.x.numpy(), block.x.numpy()
    moved = np.abs(x_plain - x0).max()
    assert moved > 1e-4
    if device == "cpu":
        np.testing.assert_array_equal(x_block, x_plain)
    else:
        np.testing.assert_allclose(x_block, x_plain, atol=0.01 * moved)


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


def test_the_terms_are_timed_apart_by_leaving_the_others_out(device):
    """``FloorScene.without``: the ``membrane`` sweep of a bent sheet is the whole sweep of the
    same sheet with no bending stiffness; the ``inertia`` sweep leaves every particle at its
    inertial target (the Newton step of ``m/h^2 |x - y|^2`` alone from ``y``); the ``bending``
    sweep moves the sheet off that target, and elsewhere than the membrane does."""
    from benchmarks.batch_floor import FloorScene

    h = 1.0 / 240.0
    moved = {}
    for terms in ("membrane", "bending", "inertia"):
        model, _ = _bent_stretched_sheet(device)
        scene = FloorScene(model, h)
        scene.sweep(None, scene.without(terms))
        moved[terms] = scene.x.numpy()
        y = scene.y.numpy()
    flat, _ = _bent_stretched_sheet(device, bending=0.0)
    reference = FloorScene(flat, h)
    reference.sweep(None)
    np.testing.assert_allclose(moved["membrane"], reference.x.numpy(), rtol=0, atol=1e-7)
    np.testing.assert_array_equal(moved["inertia"], y)
    # the bending sweep is the whole sweep of the sheet with no membrane stiffness
    limp, _ = _bent_stretched_sheet(device, membrane=False)
    reference = FloorScene(limp, h)
    reference.sweep(None)
    np.testing.assert_allclose(moved["bending"], reference.x.numpy(), rtol=0, atol=1e-7)
    assert np.abs(moved["bending"] - y).max() > 1e-6
    assert np.abs(moved["bending"] - moved["membrane"]).max() > 1e-6
    with pytest.raises(ValueError, match="terms 'contact'"):
        reference.without("contact")


@pytest.mark.parametrize("layout", ["threads", "lanes"])
def test_the_fast_math_floor_takes_the_same_step(device, layout):
    """``fast_math``: the floor's kernels built as the job's solve kernel is (CUDA's approximate
    division and square roots) take the same step to within their rounding; the CPU build is
    unaffected, so there the floats are the same."""
    from benchmarks.batch_floor import FloorScene

    h = 1.0 / 240.0
    lanes = None if layout == "threads" else ((32, 4) if device == "cuda" else (1, 1))
    out = []
    for fast in (False, True):
        model, x0 = _bent_stretched_sheet(device)
        scene = FloorScene(model, h, fast_math=fast)
        for _ in range(3):
            scene.sweep(lanes)
        out.append(scene.x.numpy())
    moved = np.abs(out[0] - x0).max()
    assert moved > 1e-4
    if device == "cpu":
        np.testing.assert_array_equal(out[1], out[0])
    else:
        np.testing.assert_allclose(out[1], out[0], atol=1e-3 * moved)


def test_a_job_variant_changes_only_what_it_names(device):
    """"job:KEY=V" layouts time the job's kernel with solver fields changed: the register cap and
    the block layout change how the kernel runs, not the step (the same positions as 'job'; on
    the CPU a block is one thread and no cap applies). Bad variants are refused."""
    from benchmarks.batch_floor import FloorScene, job_overrides, parse_layouts

    assert parse_layouts("job,job:max_registers=0+lanes=2") == ["job", "job:max_registers=0+lanes=2"]
    assert job_overrides("job:lanes=2+particles_per_block=64") == {"lanes": 2, "particles_per_block": 64}
    for bad in ("job:warp_speed=9", "job:lanes=two", "job:lanes"):
        with pytest.raises(ValueError, match="job:KEY=INT"):
            parse_layouts(bad)
    h = 1.0 / 240.0
    model, _ = _bent_stretched_sheet(device)
    scene = FloorScene(model, h)
    for layout in ("job", "job:max_registers=0+lanes=2+particles_per_block=64"):
        for _ in range(2):
            scene.job_sweep(layout)
    solver, _ = scene.job_solver("job:max_registers=0+lanes=2+particles_per_block=64")
    assert solver.config.max_registers == 0 and solver.config.lanes == 2
    a, b = (scene.job_solver(k)[1].positions.numpy() for k in ("job", "job:max_registers=0+lanes=2+"
                                                                       "particles_per_block=64"))
    if device == "cpu":
        np.testing.assert_array_equal(a, b)
    else:  # another lane split sums the same terms in another order
        np.testing.assert_allclose(a, b, atol=1e-6)
