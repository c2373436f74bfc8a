"""The sweep's population (benchmarks/sweep_tshirt.py): the verdict of a setting rests on it."""

import numpy as np
import pytest

from benchmarks.sweep_tshirt import parse_setting, population_motions


def test_the_population_starts_with_the_benchmark_motions_and_varies_the_rest_within_its_ranges():
    pop = population_motions(10, 0.5, seed=3)
    labels = [label for label, _ in pop]
    assert labels[:2] == ["walk", "run"]
    assert [label.split()[0] for label in labels] == ["walk", "run"] * 5
    assert len(set(labels)) == 10
    for label, m in pop:
        assert m.fps == 30.0 and m.num_frames == 15
        fields = dict(f.split("=") for f in label.split()[1:])
        if fields:
            lo, hi = (1.0, 1.8) if label.startswith("walk") else (2.8, 4.5)
            assert lo <= float(fields["speed"]) <= hi and 0.7 <= float(fields["arm_swing"]) <= 1.4
    # the root travels at the drawn speed: a faster run covers more ground in the same time
    runs = [(float(dict(f.split("=") for f in label.split()[1:])["speed"]), m) for label, m in pop[2:]
            if label.startswith("run")]
    runs.sort(key=lambda t: t[0])
    dist = [float(np.linalg.norm(m.trans[-1] - m.trans[0])) for _, m in runs]
    assert dist[-1] > dist[0]
    # seeded: the same seed draws the same population, another seed another one
    assert [label for label, _ in population_motions(10, 0.5, seed=3)] == labels
    assert [label for label, _ in population_motions(10, 0.5, seed=4)] != labels


def test_a_setting_is_read_or_refused():
    p = parse_setting("10x5i2m6c8r0.9")
    assert (p["substeps"], p["iterations"], p["interval"]) == (10, 5, 2)
    assert p["solver"] == {"self_contact_interval": 2, "self_contact_margin": 0.006,
                           "self_contact_capacity": 8, "chebyshev_rho": 0.9}
    # a field the setting leaves out is not set: --solver's value holds (session 32: "14x5" set
    # the interval to 1 over --solver '{"self_contact_interval": 2}')
    p = parse_setting("14x5")
    assert p["solver"] == {} and p["interval"] is None
    with pytest.raises(SystemExit, match="cannot read"):
        parse_setting("10by5")



def test_benchmark_motions_are_built_on_the_bodys_skeleton_as_the_cli_builds_them():
    """Session 48: the benchmarks play the motion `wrinkles simulate` makes for the body (its own
    skeleton and soles), not the one built on SMPL's approximate skeleton (longer strides)."""
    from benchmarks.bench_tshirt import benchmark_motion
    from sim.bodies.default import load_default_body
    from sim.motions import MotionSkeleton, load_motion

    body = load_default_body()
    cli = load_motion("run", fps=30.0, duration=0.5, skeleton=MotionSkeleton.from_body(body), speed=3.0)
    ours = benchmark_motion("run", body, 0.5, speed=3.0)
    np.testing.assert_array_equal(ours.poses, cli.poses)
    np.testing.assert_array_equal(ours.trans, cli.trans)
    old = benchmark_motion("run", body, 0.5, "default", speed=3.0)
    # SMPL's legs need more hip swing per stride at the same speed: a larger swing at the same
    # cadence, or (session 52, where the swing is capped at the hips' joint limits) quicker steps
    def sweep_rate(m):
        return m.extra["hip_scale"] * m.extra["stride_frequency"]

    assert sweep_rate(old) > 1.03 * sweep_rate(ours)
    pop = population_motions(4, 0.5, seed=3, body=body)
    np.testing.assert_array_equal(pop[1][1].poses, benchmark_motion("run", body, 0.5).poses)
