"""Dressing and the sequence driver (sim/dressing.py, sim/simulate/) and ``wrinkles simulate``,
on tiny CPU configurations: coarse garments (5 cm edges, a few hundred vertices), fractions of a
second of motion, few substeps."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from pipelines.cli import main
from sim.cloth import VBDConfig
from sim.errors import WrinklesInputError
from sim.quality import SimulationError
from sim.simulate import SimulationConfig, SimulationJob, simulate, simulate_batch, simulator_defaults

RES = 0.05  # template edge length [m]: ~300 (skirt) to ~450 (t-shirt) vertices
# The CLI writes USD: usd-core (pxr) is a project dependency, absent only on a bare GPU machine.
needs_usd = pytest.mark.skipif(importlib.util.find_spec("pxr") is None, reason="usd-core (pxr) not installed")
FAST = dict(fps=30.0, substeps=4, iterations=4, settle_seconds=0.6, blend_seconds=0.2, device="cpu",
            solver={"body_contact.offset": 0.002})
"""Few substeps and sweeps: 2 mm of contact offset keep the coarse sewn skirt's settle outside
the belly (2.3 % of its vertices inside at 0)."""


@pytest.fixture(scope="module")
def body():
    from sim.bodies import load_body

    return load_body()


@pytest.fixture(scope="module")
def skirt(body):
    from sim.garments import make_garment

    return make_garment("straight_skirt", body, resolution=RES)


def walk(body, duration: float):
    from sim.motions import MotionSkeleton, load_motion

    return load_motion("walk", fps=30, duration=duration, skeleton=MotionSkeleton.from_body(body, None),
                       ramp=0.2)


@pytest.fixture(scope="module")
def prelude_run(body, skirt):
    """The skirt on a 0.3 s walk with the settle/blend prelude kept."""
    cfg = SimulationConfig(**FAST, keep_prelude=True)
    return simulate(skirt, body, walk(body, 0.3), config=cfg), cfg


@pytest.fixture(scope="module")
def plain_run(body, skirt):
    return simulate(skirt, body, walk(body, 0.3), config=SimulationConfig(**FAST))


# ------------------------------------------------------------------------------- config


def test_config_round_trips_and_refuses_unknown_keys():
    from sim.quality import QualityGates

    cfg = SimulationConfig(fps=24.0, substeps=7, pinned=("waistband", "shoulders"),
                           solver={"body_contact.margin": 0.03}, gates=QualityGates(max_edge_strain=0.5))
    d = json.loads(json.dumps(cfg.to_dict()))
    assert SimulationConfig.from_dict(d) == cfg
    assert cfg.vbd_config().body_contact.margin == 0.03 and cfg.vbd_config().stepping.substeps == 7
    with pytest.raises(WrinklesInputError, match="substep"):
        SimulationConfig.from_dict({**d, "substep": 3})
    with pytest.raises(WrinklesInputError, match="max_strain"):
        SimulationConfig.from_dict({**d, "gates": {"max_strain": 1.0}})
    with pytest.raises(WrinklesInputError, match="warp_speed"):
        SimulationConfig(solver={"warp_speed": 9.0})
    with pytest.raises(WrinklesInputError, match="substeps"):
        SimulationConfig(substeps=-1)
    with pytest.raises(WrinklesInputError, match="blend_seconds"):
        SimulationConfig(blend_seconds=-1.0)
    assert SimulationConfig(fps=30, settle_seconds=0.5, blend_seconds=1.0).solver_steps(60) == 15 + 30 + 59


SIZES = (1000, 10_000, 10_001, 19_542)  # garment vertices either side of FINE_GARMENT_VERTICES


def test_config_defaults_scale_substeps_and_sweeps_with_the_garment_size():
    """12 substeps x 5 sweeps up to 10k garment vertices, 14 x 8 above, with a coarse correction
    before sweep 2 either way; a number in the config wins; automatic survives the round trip."""
    vbd = SimulationConfig().vbd_config(4939)
    assert (vbd.stepping.substeps, vbd.stepping.iterations, vbd.coarse.sweeps, vbd.coarse.spacing) == (
        12, 5, (2,), 0)
    assert [SimulationConfig().vbd_config(n).stepping.substeps for n in SIZES] == [12, 12, 14, 14]
    assert SimulationConfig(substeps=9).vbd_config(19_542).stepping.substeps == 9
    assert SimulationConfig().substeps_for(30_000) == 14 and SimulationConfig.from_dict(
        SimulationConfig().to_dict()).substeps == 0
    assert [SimulationConfig().vbd_config(n).stepping.iterations for n in SIZES] == [5, 5, 8, 8]
    assert SimulationConfig().vbd_config(19_542).coarse.sweeps == (2,)
    assert SimulationConfig(iterations=6).vbd_config(19_542).stepping.iterations == 6
    assert SimulationConfig(iterations=6).iterations_for(1000) == 6
    assert SimulationConfig.from_dict(SimulationConfig().to_dict()).iterations == 0
    # a retry keeps the automatic sweeps
    import dataclasses
    first_retry = SimulationConfig(retry_factors=[5 / 3]).retry_substeps(19_542)[0]
    retry = dataclasses.replace(SimulationConfig(), substeps=first_retry)
    fine = retry.vbd_config(19_542).stepping
    assert (fine.substeps, fine.iterations) == (23, 8)
    assert simulator_defaults()["iterations"] == {"default": 5, "fine": 8}
    with pytest.raises(WrinklesInputError, match="iterations must be an integer >= 0"):
        SimulationConfig(iterations=-1)


def test_config_coarse_exclusion_on_fine_garments():
    """Self-contact pairs near at rest leave the coarse correction alone on fine garments only; a
    solver override wins; a dataset records the exclusion and that the coarse system has no
    overshoot guard."""
    exclusion = [SimulationConfig().vbd_config(n).self_contact.coarse_exclusion for n in SIZES]
    assert exclusion == [0.0, 0.0, 0.006, 0.006]
    assert SimulationConfig(solver={"self_contact.coarse_exclusion": 0.0}).vbd_config(
        19_542).self_contact.coarse_exclusion == 0.0
    assert simulator_defaults()["coarse_exclusion"] == {"default": 0.0, "fine": 0.006}
    assert simulator_defaults()["coarse_guard"] is False


def test_config_retry_ladder():
    """Automatic retries: two rungs up to 10k garment vertices, none above; a list wins,
    [] means none; automatic survives the round trip; factors must increase above 1."""
    assert [SimulationConfig().retry_substeps(n) for n in SIZES] == [(20, 24), (20, 24), (), ()]
    assert SimulationConfig(retry_factors=[2.0]).retry_substeps(19_542) == (28,)
    assert SimulationConfig(retry_factors=[]).retry_substeps(19_542) == ()
    assert SimulationConfig(substeps=10).retry_substeps(1000) == (17, 20)
    three = SimulationConfig(substeps=10, retry_factors=[5 / 3, 2.0, 3.0])
    assert three.retry_substeps(19_542) == (17, 20, 30)
    assert SimulationConfig.from_dict(SimulationConfig().to_dict()).retry_factors is None
    assert SimulationConfig.from_dict(SimulationConfig(retry_factors=[1.5]).to_dict()).retry_factors == (1.5,)
    assert simulator_defaults()["retry_factors"] == {"default": [5.0 / 3.0, 2.0],
                                                     "fine": []}
    with pytest.raises(WrinklesInputError, match="retry_factors"):
        SimulationConfig(retry_factors=[2.0, 1.5])


def test_simulator_defaults_record_the_templates_and_the_device_kind():
    """A dataset records every template's default parameters, and the colouring and early coarse
    system only on CUDA (the CPU uses neither); the rest of the record is the same on both."""
    templates = simulator_defaults()["templates"]
    assert templates["tank_top"]["strap_width"] == 0.06 and templates["t_shirt"]["strap_width"] == 0.0
    assert templates["hoodie"]["hood"] == "yes" and templates["t_shirt"]["fit"] == "regular"
    assert templates["t_shirt"]["sleeve_length"] == 0.2 and len(templates) == 9
    on_cuda = simulator_defaults(cuda=True)
    assert on_cuda["max_colors"] == 3 and "max_colors" not in simulator_defaults()
    assert on_cuda["coarse_early"] is True and "coarse_early" not in simulator_defaults()
    cuda_only = ("max_colors", "coarse_early")
    assert {k: v for k, v in on_cuda.items() if k not in cuda_only} == simulator_defaults()


def test_config_cuda_settings_and_their_overrides():
    """The job's solver settings: on the CPU a coarse garment runs at a bare VBDConfig's (fast
    math on, a proper colouring, in order); on CUDA 3 colours and the early coarse system; the
    solver dict wins over each."""
    vbd = SimulationConfig().vbd_config(4939)
    assert vbd == VBDConfig()
    cuda = SimulationConfig().vbd_config(4939, cuda=True)
    assert vbd.layout.fast_math
    assert not SimulationConfig(solver={"layout.fast_math": False}).vbd_config().layout.fast_math
    assert vbd.layout.max_colors == 0 and cuda.layout.max_colors == 3
    proper = SimulationConfig(solver={"layout.max_colors": 0}).vbd_config(4939, cuda=True)
    assert proper.layout.max_colors == 0
    assert SimulationConfig(solver={"layout.max_colors": 5}).vbd_config(4939).layout.max_colors == 5
    assert cuda.coarse.early and not vbd.coarse.early
    assert not SimulationConfig(solver={"coarse.early": False}).vbd_config(4939, cuda=True).coarse.early


def test_cli_solver_params_reach_the_config_as_section_fields():
    """``--solver-param section.field=VALUE`` items go to ``SimulationConfig.solver`` by their
    keys, and from there over the job's settings."""
    from pipelines.simulate_cmd import parse_solver_params

    params = parse_solver_params(["body_contact.stiffness=2e5", " self_contact.radius = 0.004"])
    assert params == {"body_contact.stiffness": 2e5, "self_contact.radius": 0.004}
    vbd = SimulationConfig(solver=params).vbd_config()
    assert vbd.body_contact.stiffness == 2e5 and vbd.self_contact.radius == 0.004


def test_config_coarse_sweeps():
    """Explicit coarse sweeps round-trip and reach the solver; the solver dict overrides them;
    automatic: before sweep 2 where there is one; a sweep out of range says what to change."""
    cfg = SimulationConfig(iterations=4, coarse_sweeps=[1, 3], coarse_spacing=3)
    d = json.loads(json.dumps(cfg.to_dict()))
    assert d["coarse_sweeps"] == [1, 3] and SimulationConfig.from_dict(d) == cfg
    assert cfg.vbd_config().coarse.sweeps == (1, 3)
    assert SimulationConfig(solver={"coarse.sweeps": ()}).vbd_config().coarse.sweeps == ()
    # two sweeps leave no sweep 2 to correct before, so none
    assert SimulationConfig(iterations=2).vbd_config().coarse.sweeps == ()
    assert SimulationConfig(iterations=3).vbd_config().coarse.sweeps == (2,)
    assert SimulationConfig.from_dict(SimulationConfig().to_dict()).coarse_sweeps is None
    with pytest.raises(WrinklesInputError, match=r"coarse.sweeps .* 0\.\.1 .*or none: \[\]"):
        SimulationConfig(iterations=2, coarse_sweeps=[2])
    with pytest.raises(WrinklesInputError, match="coarse_sweeps must be a list"):
        SimulationConfig(coarse_sweeps=2)


def test_surface_binding_kernel_matches_numpy_and_round_trips(body, skirt, device):
    from sim.device import warp
    from sim.dressing import AttachmentPins, bind_to_surface
    from sim.simulate import resolve_betas

    wp = warp()
    rest = body.rest_mesh(resolve_betas(body, walk(body, 0.1), None))
    x = np.asarray(skirt.rest_vertices)
    bnd = bind_to_surface(x, rest, body.faces, vertices=skirt.attachments["waistband"], device=device)
    # at the pose it was bound in, the binding gives the points back
    np.testing.assert_allclose(bnd.targets(rest), x[bnd.vertices], atol=1e-5)
    # on a posed body the Warp kernel and the numpy reference agree
    posed = body.pose(None, np.full((1, 24, 3), 0.2, np.float32), device=device).vertices[0]
    pts = wp.array(posed, dtype=wp.vec3, device=device)
    targets = wp.zeros(len(x), dtype=wp.vec3, device=device)
    AttachmentPins(bnd, 0, pts, device=device).launch(targets)
    np.testing.assert_allclose(targets.numpy()[bnd.vertices], bnd.targets(posed), atol=1e-5)
    # the clearance to the skin is kept: same distance to the bound triangle's plane
    assert np.all(np.abs(bnd.offset[:, 2]) < 0.05)


# ------------------------------------------------------------------------------- dressing


def test_dressing_starts_collision_free_at_rest(prelude_run):
    res, cfg = prelude_run
    seq = res.sequence
    p = seq.provenance["frames"]
    first = p["settle"] + p["blend"]
    assert seq.num_frames == first + 9 and p["first_output_timeline_frame"] == 0
    q = res.quality
    rest = p["settle"]  # the last settle frame, the lead-in's first: still the rest pose
    assert q.self_intersections[rest] == 0
    assert q.inside_fraction[: rest + 1].max() == 0.0
    # carried into the walk (its lead-in from rest to 1.3 m/s takes 0.2 s here): at the clip's
    # first frame at most a few of the skirt's ~320 vertices touch through the skin at 4 substeps
    assert q.inside_fraction[first] <= 0.02
    # settled: the garment barely moves over the last settle frame (a free fall from rest
    # would move it g dt^2 / 2 = 5.4 mm in one frame; the first settle frame moves it 5.5 mm on
    # average, 15 mm at most). A hem vertex touching the leg may still jitter by a few mm at
    # this 5 cm resolution, so the mean and the 99th percentile are judged, not the maximum.
    v = seq.vertices
    step = np.linalg.norm(v[p["settle"]] - v[p["settle"] - 1], axis=1)
    first = np.linalg.norm(v[1] - v[0], axis=1)
    assert step.mean() < 0.05 * first.mean() and step.mean() < 5e-4, (step.mean(), first.mean())
    assert np.percentile(step, 99) < 2.5e-3, np.percentile(step, 99)
    # the body does not move while the garment settles
    np.testing.assert_array_equal(seq.body.vertices[0], seq.body.vertices[p["settle"]])


def test_the_hems_reach_the_cloth_model(body, skirt, monkeypatch):
    """The model simulate builds carries the garment's layers: its total mass is the density
    times the area weighted by the layers (the hems' extra fabric), not the plain area."""
    from sim.cloth import ClothModelBuilder

    built = []
    finalize = ClothModelBuilder.finalize

    def keep(self, device=None):
        built.append(finalize(self, device))
        return built[-1]

    monkeypatch.setattr(ClothModelBuilder, "finalize", keep)
    cfg = SimulationConfig(**{**FAST, "settle_seconds": 0.1, "blend_seconds": 0.0})
    simulate(skirt, body, walk(body, 0.1), config=cfg)
    flat = skirt.flat_corners()  # the sewn skirt's rest shape is its pattern
    e1, e2 = flat[:, 1] - flat[:, 0], flat[:, 2] - flat[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    mass = built[0].particle_mass.numpy().sum()
    assert (skirt.face_layers > 1).sum() > 0
    np.testing.assert_allclose(mass, skirt.material.density * (area * skirt.face_layers).sum(), rtol=1e-5)
    assert mass > 1.05 * skirt.material.density * area.sum()


def test_pinned_waistband_follows_the_body(prelude_run, body, skirt):
    from sim.dressing import bind_to_surface

    res, _ = prelude_run
    seq = res.sequence
    band = skirt.attachments["waistband"]
    assert seq.provenance["garment"]["pinned_sets"] == ["waistband"]
    # the skirt's hems reach the simulation (the waistband and the hem at the knees)
    assert seq.provenance["garment"]["hem_faces"] == int((skirt.face_layers > 1).sum()) > 0
    bnd = bind_to_surface(seq.vertices[0], seq.body.vertices[0], body.faces, vertices=band, device="cpu")
    for t in range(seq.num_frames):
        np.testing.assert_allclose(seq.vertices[t, band], bnd.targets(seq.body.vertices[t]), atol=2e-5)
    # the walk moves the body, and the waistband with it
    assert np.linalg.norm(seq.vertices[-1, band] - seq.vertices[0, band], axis=1).min() > 0.01


def test_prelude_dropped_by_default_same_seed_same_result(prelude_run, plain_run, body, skirt):
    kept, _ = prelude_run
    seq = plain_run.sequence
    first = seq.provenance["frames"]["settle"] + seq.provenance["frames"]["blend"]
    assert seq.num_frames == 9 and seq.motion.num_frames == 9 and seq.body.num_frames == 9
    np.testing.assert_array_equal(seq.vertices, kept.sequence.vertices[first:])
    np.testing.assert_array_equal(seq.body.vertices, kept.sequence.body.vertices[first:])
    assert plain_run.quality.inside_fraction[0] == kept.quality.inside_fraction[first]
    # the body stands on the floor at the motion's first frame
    assert abs(float(seq.body.vertices[0, :, 1].min())) < 1e-5
    again = simulate(skirt, body, walk(body, 0.3), config=SimulationConfig(**FAST))
    np.testing.assert_array_equal(again.sequence.vertices, seq.vertices)
    assert again.sequence.provenance["config"] == seq.provenance["config"]


def test_the_output_starts_at_the_clip_in_full_motion(prelude_run, plain_run, body):
    """The walk's lead-in (from the T-pose up to speed) plays in the prelude after the settle; the
    output is the clip alone, walking at its speed from its first frame."""
    motion = walk(body, 0.3)
    lead = motion.extra["lead_in"]
    seq = plain_run.sequence
    p = seq.provenance["frames"]
    assert p["entry"] == "lead_in" and p["blend"] == lead.num_frames == 6
    assert seq.num_frames == motion.num_frames == 9 and p["output"] == 9
    np.testing.assert_array_equal(seq.motion.poses, motion.poses)
    # the body's root moves at the walk's 1.3 m/s from output frame 0 on, and no output frame is
    # the T-pose (the arms hang at ~64 deg from it while walking)
    vz = np.diff(seq.body.joints[:, 0, 2].astype(np.float64)) * 30.0
    np.testing.assert_allclose(vz, 1.3, rtol=1e-3)
    assert np.degrees(np.linalg.norm(seq.motion.poses[:, 1:], axis=-1)).max(axis=1).min() > 50.0
    # the prelude kept: rest through the settle, then the lead-in, then the clip (the same body)
    kept = prelude_run[0].sequence
    n = p["settle"]
    np.testing.assert_array_equal(kept.motion.poses[: n + 1], 0.0)
    np.testing.assert_array_equal(kept.motion.poses[n: n + 6], lead.poses)
    np.testing.assert_array_equal(kept.motion.poses[n + 6:], motion.poses)
    np.testing.assert_array_equal(kept.body.vertices[n + 6:], seq.body.vertices)
    assert (kept.motion.trans[0, 2] < -0.1) and kept.motion.trans[n + 6, 2] == 0.0  # walks up to z = 0


@pytest.mark.slow
def test_batched_sequences_match_separate_runs(body, skirt, plain_run):
    from sim.garments import make_garment

    top = make_garment("tank_top", body, resolution=RES)
    cfg = SimulationConfig(**FAST)
    short = walk(body, 0.2)
    jobs = [SimulationJob(skirt, body, walk(body, 0.3)), SimulationJob(top, body, short)]
    both = simulate_batch(jobs, config=cfg)
    assert [r.sequence.num_frames for r in both] == [9, 6]
    np.testing.assert_array_equal(both[0].sequence.vertices, plain_run.sequence.vertices)
    alone = simulate(top, body, short, config=cfg)
    np.testing.assert_array_equal(both[1].sequence.vertices, alone.sequence.vertices)


def test_driver_on_each_device(body, skirt, device):
    """On CUDA one frame's step is captured in a CUDA graph and replayed."""
    res = simulate(skirt, body, walk(body, 0.2), config=SimulationConfig(**{**FAST, "device": device}))
    assert res.sequence.provenance["cuda_graph"] == (device == "cuda")
    assert res.sequence.provenance["device"].startswith(device)
    assert res.quality.finite and res.quality.inside_fraction[0] <= 0.02  # walking from frame 0


# ------------------------------------------------------------------------------- failures


class _NaNAtStep:
    """A SolverVBD whose ``n``-th step leaves a NaN in particle ``particle``."""

    def __init__(self, n: int, particle: int = 3):
        from sim.cloth import SolverVBD

        outer = self

        class Solver(SolverVBD):
            calls = 0

            def step(self, state_in, state_out, control, dt):
                super().step(state_in, state_out, control, dt)
                Solver.calls += 1
                outer.record.append((state_out.positions.numpy().copy(), state_out.velocities.numpy().copy()))
                if Solver.calls == outer.n:
                    x = state_out.positions.numpy()
                    x[outer.particle] = np.nan
                    state_out.positions.assign(x)

        self.n = n
        self.particle = particle
        self.record = []  # (positions, velocities) after every step
        self.cls = Solver


def test_nan_stops_the_run_naming_the_frame(body, skirt, monkeypatch):
    import sim.cloth

    # prelude: 3 settle frames and the walk's 6 lead-in frames (its 0.2 s ramp; the 0.1 s blend is
    # for motions without a lead-in)
    cfg = SimulationConfig(**{**FAST, "settle_seconds": 0.1, "blend_seconds": 0.1})
    motion = walk(body, 0.3)
    assert cfg.settle_frames + cfg.entry_frames(motion) == 9
    monkeypatch.setattr(sim.cloth, "SolverVBD", _NaNAtStep(11).cls)
    with pytest.raises(SimulationError) as e:
        simulate(skirt, body, motion, config=cfg)
    assert e.value.frame == 2  # timeline frame 11 = output frame 11 - 9
    assert "NaN" in e.value.cause and "frame 2" in str(e.value)


@pytest.mark.slow
def test_a_failed_sequence_is_frozen_and_the_batch_runs_on(body, skirt, plain_run, monkeypatch):
    """failures="return": the sequence that blows up gets its SimulationError in its slot; the
    other sequence of the batch is bit-identical to its run alone."""
    import sim.cloth
    from sim.garments import make_garment

    top = make_garment("tank_top", body, resolution=RES)
    cfg = SimulationConfig(**FAST)
    prelude = cfg.settle_frames + cfg.entry_frames(walk(body, 0.3))
    # step 15 of the timeline breaks particle 3 of the tank top (the batch's second instance)
    broken = _NaNAtStep(15, particle=skirt.num_vertices + 3)
    monkeypatch.setattr(sim.cloth, "SolverVBD", broken.cls)
    jobs = [SimulationJob(skirt, body, walk(body, 0.3)),
            SimulationJob(top, body, walk(body, 0.3), name="tee")]
    res = simulate_batch(jobs, config=cfg, failures="return")
    assert isinstance(res[1], SimulationError) and res[1].frame == 15 - prelude
    assert "tee" in res[1].cause and "NaN" in res[1].cause
    np.testing.assert_array_equal(res[0].sequence.vertices, plain_run.sequence.vertices)
    assert res[0].quality.finite
    # the tank top (no pinned set) stays at its last good frame, step 14, with zero velocity
    tee = slice(skirt.num_vertices, skirt.num_vertices + top.num_vertices)
    assert len(broken.record) > 16
    last_good = broken.record[13][0][tee]
    for x, v in broken.record[15:]:
        np.testing.assert_array_equal(x[tee], last_good)
        assert not v[tee].any()
    with pytest.raises(SimulationError):  # the default still stops at the first failure
        monkeypatch.setattr(sim.cloth, "SolverVBD", _NaNAtStep(15, particle=skirt.num_vertices + 3).cls)
        simulate_batch(jobs, config=cfg)
    with pytest.raises(ValueError, match="failures"):
        simulate_batch(jobs, config=cfg, failures="ignore")


def test_explosion_in_the_prelude_is_named(body, skirt):
    cfg = SimulationConfig(**FAST, max_speed=1e-4)  # any motion at all "explodes"
    with pytest.raises(SimulationError) as e:
        simulate(skirt, body, walk(body, 0.3), config=cfg)
    assert e.value.frame < 0 and "while settling" in e.value.cause and "m/s" in e.value.cause


# ------------------------------------------------------------------------------- CLI

CLI_FAST = ["--resolution", str(RES), "--duration", "0.2", "--settle", "0.4", "--blend", "0.1",
            "--substeps", "4", "--iterations", "4", "--param", "ramp=0.2", "--device", "cpu", "--quiet"]


def test_simulate_help_explains_itself(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    out = capsys.readouterr().out
    for flag in ("--garment", "--garment-param", "--material", "--motion", "--shape", "--out", "--preview",
                 "--self-collision", "--allow-failed-gates", "--seed", "examples:", "quality.json"):
        assert flag in out


@pytest.mark.slow
@needs_usd
def test_cli_writes_body_and_garment_with_uvs_and_quality(tmp_path):
    from usd_io import read_stage, validate_stage

    out = tmp_path / "tee_walk.usda"
    rc = main(["simulate", "--garment", "tshirt", "--motion", "walk", "--material", "cotton",
               "--shape", "height=0.6", "--out", str(out), "--allow-failed-gates", "--no-retry", *CLI_FAST])
    assert rc == 0
    st = read_stage(out)
    assert st.fps == 30 and st.body.points.shape[0] == 6
    g = st.garments["t_shirt"]
    assert g.points.shape[0] == 6 and g.uvs is not None and g.uv_faces is not None
    assert g.uv_faces.shape == g.faces.shape and g.uvs.min() >= 0.0 and g.uvs.max() <= 1.0
    # the hems' layers, per face, as the template made them (primvars:fabricLayers)
    assert g.face_layers is not None and g.face_layers.shape == (len(g.faces),)
    assert g.face_layers.min() == 1.0 and 1.0 < g.face_layers.max() <= 3.0
    md = st.metadata
    # output frame 0 is the walk at full speed after its 0.2 s lead-in: a few vertices touch through
    assert len(md["quality"]["inside_fraction"]) == 6 and md["quality"]["inside_fraction"][0] < 0.05
    assert md["quality"]["self_intersections"][0] == 0
    assert set(md["gates"]) == {"max_edge_strain", "max_inside_fraction", "max_self_intersections"}
    assert md["config"]["substeps"] == 4 and md["seed"] == 0
    assert md["resolved"] == {"substeps": 4, "iterations": 4}  # what ran (0 in a config: automatic)
    side = json.loads((tmp_path / "tee_walk.quality.json").read_text())
    assert side["quality"] == md["quality"] and side["config"] == md["config"]
    assert validate_stage(out) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tee_walk.quality.json", "tee_walk.usda"]


@needs_usd
def test_cli_failed_gates_exit_1_nothing_written(tmp_path, capsys):
    out = tmp_path / "s.usda"
    rc = main(["simulate", "--garment", "skirt", "--out", str(out), "--gate", "max_edge_strain=1e-9",
               "--preview", str(tmp_path / "s.gif"), "--no-retry", *CLI_FAST])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and len(err.splitlines()) == 1, err
    assert "max edge strain" in err and "--allow-failed-gates" in err and "after" not in err
    assert "more --substeps than 4 or --iterations than 4" in err  # what to try, from this run's settings
    assert "passes through itself" not in err  # the walk's body never does
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@needs_usd
@pytest.mark.xfail(reason="the body's parts are separated, so the run no longer folds the knee pits through "
                          "themselves, and the sewn trousers start 18.7 % inside the body at 4 substeps",
                   strict=False)
def test_cli_failed_gates_name_where_the_body_passes_through_itself(tmp_path, capsys):
    """A run whose gates fail is checked for the body passing through itself near the garment:
    the run folds the default body's knee pits through themselves, inside the trousers' legs, so
    the trousers' one-line error names the knees, and with --allow-failed-gates the report keeps
    the frames by joint; the t-shirt, far from the knees, gets no such note, nor does a walk (no
    crossings at all)."""
    fast = [a for a in CLI_FAST if a not in ("--duration", "0.2")]

    def fails(garment: str, *extra: str) -> str:
        # 1 s of running after the lead-in: at 4 substeps the unpinned t-shirt starts to slide off a
        # body at 3.5 m/s and would pass the 3 m explosion distance 1.4 s in
        rc = main(["simulate", "--garment", garment, "--motion", "run", "--duration", "1.0", "--gate",
                   "max_edge_strain=1e-9", "--no-retry", *fast, "--out", str(tmp_path / "s.usda"), *extra])
        assert rc == (0 if extra else 1)
        return capsys.readouterr().err.strip()

    err = fails("trousers")
    assert len(err.splitlines()) == 1 and "the body passes through itself in" in err and "knee" in err, err
    assert not (tmp_path / "s.usda").exists()
    fails("trousers", "--allow-failed-gates")
    c = json.loads((tmp_path / "s.quality.json").read_text())["body_self_crossings"]
    assert c["frames_with_crossings"] > 0 and {"left_knee", "right_knee"} & set(c["frames_by_joint"])
    err = fails("tshirt")
    assert "max edge strain" in err and "passes through itself" not in err, err


def _simulate_calls(monkeypatch, passes_from: int) -> list[int]:
    """Record the substeps of every ``sim.simulate.simulate`` call; runs below ``passes_from``
    substeps are made to fail the strain gate and runs from it on to pass every gate, so the
    retry ladder is tested apart from what the real cloth does at each count."""
    import dataclasses

    import sim.simulate as sm

    real, calls = sm.simulate, []

    def recorded(*a, config, **kw):
        calls.append(config.substeps)
        r = real(*a, config=config, **kw)
        failed = () if config.substeps >= passes_from else ("max edge strain 0.500 > 0.35",)
        return dataclasses.replace(r, failed_gates=failed)

    monkeypatch.setattr(sm, "simulate", recorded)
    return calls


@pytest.mark.slow
@needs_usd
def test_cli_retries_a_failing_sequence_at_more_substeps(tmp_path, capsys, monkeypatch):
    """A sequence that fails its gates is simulated again at 5/3 and then 2 times the substeps
    (4 -> 7 -> 8); the first run that passes is written, with its substeps in the config and the
    runs before it in the report. One that fails at every count is one line naming them."""
    calls = _simulate_calls(monkeypatch, passes_from=7)
    out = tmp_path / "s.usda"
    rc = main(["simulate", "--garment", "skirt", "--out", str(out), *CLI_FAST])
    assert rc == 0 and calls == [4, 7]
    side = json.loads((tmp_path / "s.quality.json").read_text())
    assert side["config"]["substeps"] == 7 and side["passed"]
    assert side["attempts"] == [{"substeps": 4, "failed_gates": ["max edge strain 0.500 > 0.35"]}]
    out2 = tmp_path / "t.usda"
    calls = _simulate_calls(monkeypatch, passes_from=100)  # fails at every count
    rc = main(["simulate", "--garment", "skirt", "--out", str(out2), *CLI_FAST])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and calls == [4, 7, 8] and len(err.splitlines()) == 1, err
    assert "max edge strain 0.500" in err and "(at 4, 7, 8 substeps)" in err
    assert "more --substeps than 8" in err and not out2.exists()


@pytest.mark.slow
@needs_usd
def test_cli_writes_the_last_finished_run_when_the_retries_stop(tmp_path, monkeypatch):
    """With --allow-failed-gates, a run that fails its gates is written when both retries stop
    (NaN): the report names it and the stopped runs. --no-retry records no retry factors."""
    import sim.simulate as sm
    from sim.quality import SimulationError

    calls = _simulate_calls(monkeypatch, passes_from=100)
    failing = sm.simulate

    def stops_when_retried(*a, config, **kw):
        r = failing(*a, config=config, **kw)
        if config.substeps > 4:
            raise SimulationError(5, "explosion: test")
        return r

    monkeypatch.setattr(sm, "simulate", stops_when_retried)
    out = tmp_path / "s.usda"
    rc = main(["simulate", "--garment", "skirt", "--out", str(out), "--allow-failed-gates", *CLI_FAST])
    side = json.loads((tmp_path / "s.quality.json").read_text())
    assert rc == 0 and calls == [4, 7, 8] and out.exists()
    assert side["config"]["substeps"] == 4 and not side["passed"]
    assert side["failed_gates"] == ["max edge strain 0.500 > 0.35"]
    assert side["attempts"] == [{"substeps": 7, "error": "simulation failed at frame 5: explosion: test"},
                                {"substeps": 8, "error": "simulation failed at frame 5: explosion: test"}]
    assert side["config"]["retry_factors"] is None  # automatic: two rungs for this small skirt
    calls[:] = []
    rc = main(["simulate", "--garment", "skirt", "--out", str(out), "--allow-failed-gates", "--no-retry",
               *CLI_FAST])
    side = json.loads((tmp_path / "s.quality.json").read_text())
    assert rc == 0 and calls == [4] and side["config"]["retry_factors"] == [] and side["attempts"] == []


@pytest.mark.slow
@needs_usd
def test_cli_explosion_is_one_line_nothing_written(tmp_path, capsys, monkeypatch):
    import sim.cloth

    # prelude: 12 settle frames and the walk's 6 lead-in frames (its 0.2 s ramp): step 21 is output frame 3
    monkeypatch.setattr(sim.cloth, "SolverVBD", _NaNAtStep(21).cls)
    rc = main(["simulate", "--garment", "skirt", "--out", str(tmp_path / "s.usda"), "--no-retry", *CLI_FAST])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and err == ("wrinkles simulate: simulation failed at frame 3: 1 vertices became NaN/inf "
                               "(first: vertex 3)")
    assert list(tmp_path.iterdir()) == []
    # with retries (the default) the run at 7 substeps follows; the NaN came at the 21st step of
    # all solvers, so it passes and is written, the stopped run named in the report
    monkeypatch.setattr(sim.cloth, "SolverVBD", _NaNAtStep(21).cls)
    lax = ["--gate", "max_edge_strain=10", "--gate", "max_inside_fraction=1", "--gate",
           "max_self_intersections=100000"]
    rc = main(["simulate", "--garment", "skirt", "--out", str(tmp_path / "s.usda"), *lax, *CLI_FAST])
    side = json.loads((tmp_path / "s.quality.json").read_text())
    assert rc == 0 and side["config"]["substeps"] == 7
    assert side["attempts"] == [{"substeps": 4, "error": "simulation failed at frame 3: 1 vertices became "
                                 "NaN/inf (first: vertex 3)"}]


@pytest.mark.parametrize("case", ["unknown_garment", "unknown_material", "unknown_garment_param",
                                  "bad_garment_param", "bad_suffix", "missing_garment_file", "bad_resolution",
                                  "bad_material_param", "params_for_file", "bad_coarse_sweeps",
                                  "late_coarse_sweep", "unsectioned_solver_param", "text_material_param",
                                  "unknown_pin", "pin_the_garment_lacks", "huge_beta", "into_a_new_folder"])
def test_cli_bad_input_is_one_line_exit_2_no_output(tmp_path, capsys, case):
    out = tmp_path / "o.usda"
    args = ["simulate", "--out", str(out), *CLI_FAST]
    if case == "unknown_garment":
        args += ["--garment", "poncho"]
        needles = ("poncho", "t_shirt")
    elif case == "unknown_material":
        args += ["--material", "kevlar"]
        needles = ("kevlar", "cotton")
    elif case == "unknown_garment_param":
        args += ["--garment-param", "wings=2"]
        needles = ("wings", "sleeve_length")
    elif case == "bad_garment_param":
        args += ["--garment-param", "hem_drop=long"]
        needles = ("hem_drop", "number")
    elif case == "bad_suffix":
        args[args.index("--out") + 1] = str(tmp_path / "o.abc")
        needles = ("o.abc", "--out")
    elif case == "missing_garment_file":
        args += ["--garment", str(tmp_path / "nope.obj")]
        needles = ("nope.obj", "no such file")
    elif case == "bad_resolution":
        args += ["--resolution", "medium"]
        needles = ("medium", "coarse")
    elif case == "bad_material_param":
        args += ["--material-param", "stiffness=3"]
        needles = ("stiffness", "youngs_modulus")
    elif case == "bad_coarse_sweeps":
        args += ["--coarse-sweeps", "two"]
        needles = ("--coarse-sweeps", "'none'")
    elif case == "late_coarse_sweep":
        args += ["--iterations", "3", "--coarse-sweeps", "1,3"]
        needles = ("coarse.sweeps", "0..2")
    elif case == "unsectioned_solver_param":  # solver settings are section.field
        args += ["--solver-param", "contact_stiffness=2e5"]
        needles = ("contact_stiffness", "section.field", "body_contact")
    elif case == "text_material_param":
        args += ["--material-param", "name=3"]
        needles = ("--material-param name", "density [kg/m²]")
    elif case == "unknown_pin":
        args += ["--garment", "skirt", "--pin", "waistband,bogus"]
        needles = ("--pin bogus", "hem, waistband")
    elif case == "pin_the_garment_lacks":  # a top has no waistband: said, not ignored
        args += ["--garment", "tshirt", "--pin", "waistband"]
        needles = ("--pin waistband", "t_shirt", "shoulders")
    elif case == "huge_beta":  # outside the accepted range of a beta
        args += ["--shape", "50,0"]
        needles = ("--shape", "beta 0 = 50", "[-5, 5]")
    elif case == "into_a_new_folder":  # the folder --out names is not left behind either
        args[args.index("--out") + 1] = str(tmp_path / "new" / "deeper" / "o.usda")
        args += ["--material", "kevlar"]
        needles = ("kevlar",)
    else:
        args += ["--garment", str(tmp_path / "nope.obj"), "--garment-param", "length=0.5"]
        needles = ("--garment-param",)
    if case in ("missing_garment_file", "params_for_file"):  # a file has no --resolution (an error too)
        k = args.index("--resolution")
        del args[k:k + 2]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    assert list(tmp_path.iterdir()) == []


def test_the_reference_velocity_of_a_step_is_its_body_centroid_velocity():
    """``body_mean_velocities``: a body translating at 2 m/s while its arm swings (zero mean)
    has reference velocity 2 m/s at every step of its motion; a sequence shorter than the batch
    holds its last frame, so its later steps stand still."""
    from sim.simulate import body_mean_velocities

    fps, frames = 30.0, 5
    t = np.arange(frames)[:, None, None] / fps
    rest = np.array([[0.0, 1.0, 0.0], [0.2, 1.2, 0.0], [-0.2, 1.2, 0.0], [0.0, 0.0, 0.1]])
    swing = np.sin(7.0 * t) * np.array([[0, 0, 0], [0, 0, 0.1], [0, 0, -0.1], [0, 0, 0]])  # mean 0
    verts = (rest + swing + t * np.array([0.0, 0.0, 2.0])).astype(np.float32)
    ref = body_mean_velocities(verts, frames + 2, fps)
    assert ref.shape == (frames + 2, 3)
    np.testing.assert_allclose(ref[:frames - 1], np.tile([0.0, 0.0, 2.0], (frames - 1, 1)), atol=1e-4)
    np.testing.assert_array_equal(ref[frames - 1:], 0.0)
