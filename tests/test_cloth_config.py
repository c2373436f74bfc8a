"""Solver settings (``sim.cloth.config``): the job's defaults by garment size and device, the
sections' validation, the ``"section.field"`` overrides and the dict round trip."""

from __future__ import annotations

import dataclasses
import json

import pytest

from sim.cloth import (
    BodyContact,
    CoarseConfig,
    KernelLayout,
    SelfContactConfig,
    Stepping,
    VBDConfig,
    apply_overrides,
    job_config,
)
from sim.cloth import config as C
from sim.errors import WrinklesInputError


def job_values(config: VBDConfig) -> tuple:
    """What the job sets by garment size and device."""
    return (config.stepping.substeps, config.stepping.iterations, config.coarse.sweeps, config.coarse.spacing,
            config.coarse.early, config.layout.max_colors, config.layout.fast_math,
            config.self_contact.enabled, config.self_contact.coarse_exclusion)


@pytest.mark.parametrize(("vertices", "cuda", "expected"), [
    (4939, False, (12, 5, (2,), 0, False, 0, True, True, 0.0)),
    (4939, True, (12, 5, (2,), 0, True, 3, True, True, 0.0)),
    (10_000, False, (12, 5, (2,), 0, False, 0, True, True, 0.0)),
    (10_001, False, (14, 8, (2,), 0, False, 0, True, True, 0.006)),
    (19_542, True, (14, 8, (2,), 0, True, 3, True, True, 0.006)),
])
def test_job_config_by_garment_size_and_device(vertices, cuda, expected):
    """12 substeps x 5 sweeps up to 10k vertices, 14 x 8 above with 6 mm of coarse exclusion;
    one coarse correction before sweep 2; on CUDA 3 colours and the early coarse system; fast
    math and self-contact everywhere; everything else at the defaults."""
    config = job_config(vertices, cuda)
    assert job_values(config) == expected
    defaults = VBDConfig()
    assert config.body_contact == defaults.body_contact
    assert config.stepping.air_damping == defaults.stepping.air_damping
    assert dataclasses.replace(config.self_contact, coarse_exclusion=0.0) == defaults.self_contact
    assert dataclasses.replace(config.layout, max_colors=0) == defaults.layout
    assert job_config(4939, False) == defaults  # the defaults: the job's for a coarse garment on the CPU


def test_job_config_arguments_and_overrides():
    """Explicit substeps, sweeps and coarse settings replace the job's; the coarse correction
    needs more than 2 sweeps unless named; ``self_contact`` wins over an override, None leaves
    it to them."""
    config = job_config(19_542, False, substeps=9, iterations=6, coarse_spacing=5)
    assert (config.stepping.substeps, config.stepping.iterations, config.coarse.spacing) == (9, 6, 5)
    assert job_config(3000, False, iterations=2).coarse.sweeps == ()
    assert job_config(3000, False, iterations=3).coarse.sweeps == (2,)
    assert job_config(3000, False, coarse_sweeps=[1, 3]).coarse.sweeps == (1, 3)
    assert not job_config(3000, False, self_contact=False).self_contact.enabled
    off = {"self_contact.enabled": False}
    assert job_config(3000, False, overrides=off).self_contact.enabled
    assert not job_config(3000, False, self_contact=None, overrides=off).self_contact.enabled
    # overrides over the job's values, validated together: 8 sweeps make sweep 6 valid
    config = job_config(3000, True, coarse_sweeps=(6,), overrides={
        "stepping.iterations": 8, "body_contact.stiffness": 2e5, "layout.max_colors": 0,
        "self_contact.radius": 0.0035, "coarse.early": 0})
    assert config.stepping.iterations == 8 and config.coarse.sweeps == (6,)
    assert config.body_contact.stiffness == 2e5 and config.layout.max_colors == 0
    assert config.self_contact.radius == 0.0035 and config.coarse.early is False


@pytest.mark.parametrize(("key", "value", "message"), [
    ("radius", 0.004, "expected section.field"),
    ("self_contact.radiuss", 0.004, "unknown; self_contact has"),
    ("solver.radius", 0.004, "expected section.field"),
    ("stepping.substeps", 2.5, "must be an integer"),
    ("layout.gather", 3.0, "must be a string"),
    ("coarse.early", 2, "must be true or false"),
    ("stepping.substeps", 0, "stepping.substeps must be >= 1"),
    ("self_contact.margin", 0.001, "self_contact.margin must be >= radius"),
])
def test_overrides_refuse_unknown_keys_and_bad_values_in_one_line(key, value, message):
    with pytest.raises(WrinklesInputError, match=message) as err:
        apply_overrides(VBDConfig(), {key: value})
    assert "\n" not in str(err.value)


def test_overrides_take_their_fields_types():
    """A command line gives numbers as floats and a TOML table lists: each is read as its field's
    type."""
    config = apply_overrides(VBDConfig(), {"self_contact.capacity": 8.0, "layout.fast_math": 0,
                                           "coarse.sweeps": [0.0, 3], "layout.gather": "split",
                                           "body_contact.margin": 1})
    assert config.self_contact.capacity == 8 and isinstance(config.self_contact.capacity, int)
    assert config.layout.fast_math is False and config.coarse.sweeps == (0, 3)
    assert config.layout.gather == "split" and config.body_contact.margin == 1.0
    assert apply_overrides(config, {}) == config
    tables = apply_overrides(VBDConfig(), {"self_contact": {"capacity": 8}, "layout.fast_math": False})
    assert tables == VBDConfig(self_contact=SelfContactConfig(capacity=8),
                               layout=KernelLayout(fast_math=False))
    assert set(C.override_keys()) >= {"self_contact.radius", "coarse.sweeps", "layout.max_colors"}


@pytest.mark.parametrize(("make", "message"), [
    (lambda: Stepping(iterations=0), "stepping.iterations must be >= 1"),
    (lambda: Stepping(air_damping=-1.0), "stepping.air_damping"),
    (lambda: BodyContact(margin=0.0), "body_contact.margin must be > 0"),
    (lambda: SelfContactConfig(radius=0.02, margin=0.01), "self_contact.margin"),
    (lambda: SelfContactConfig(weight_floor=1.5), "self_contact.weight_floor"),
    (lambda: SelfContactConfig(heavy_cap=-2), "self_contact.heavy_cap"),
    (lambda: SelfContactConfig(pool=-1), "self_contact.pool"),
    (lambda: SelfContactConfig(broadphase="grid"), "self_contact.broadphase"),
    (lambda: SelfContactConfig(cluster_size=12), "self_contact.cluster_size"),
    (lambda: SelfContactConfig(coarse_exclusion=-0.001), "self_contact.coarse_exclusion"),
    (lambda: CoarseConfig(levels=1), "coarse.levels"),
    (lambda: CoarseConfig(smoothing=0), "coarse.smoothing"),
    (lambda: CoarseConfig(spacing=-1), "coarse.spacing"),
    (lambda: CoarseConfig(sweeps=(1.5,)), "coarse.sweeps"),
    (lambda: KernelLayout(lanes=257), "layout.lanes"),
    (lambda: KernelLayout(lanes=16, particles_per_block=128), "layout.particles_per_block"),
    (lambda: KernelLayout(particles_per_block=0), "layout.particles_per_block"),
    (lambda: KernelLayout(gather="both"), "layout.gather"),
    (lambda: KernelLayout(max_colors=1), "layout.max_colors"),
    (lambda: VBDConfig(coarse=CoarseConfig(sweeps=(5,))), r"coarse.sweeps .* 0..4"),
    (lambda: VBDConfig(coarse=CoarseConfig(sweeps=(1, 1))), "coarse.sweeps"),
    (lambda: VBDConfig(stepping={"substeps": 3}), "stepping must be a Stepping"),
])
def test_each_section_validates_its_fields(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_dict_round_trip():
    """``to_dict`` is JSON-ready and ``from_dict`` inverts it; a missing field takes its default,
    an unknown section or field is refused."""
    config = job_config(19_542, True, overrides={"layout.lanes": 4, "layout.particles_per_block": 32})
    data = json.loads(json.dumps(config.to_dict()))
    assert set(data) == set(C.SECTIONS) and data["coarse"]["sweeps"] == [2]
    assert VBDConfig.from_dict(data) == config
    assert VBDConfig.from_dict({"stepping": {"substeps": 7}}) == VBDConfig(stepping=Stepping(substeps=7))
    with pytest.raises(ValueError, match="unknown section"):
        VBDConfig.from_dict({"contact": {}})
    with pytest.raises(ValueError, match="unknown field"):
        VBDConfig.from_dict({"stepping": {"sweeps": 3}})

