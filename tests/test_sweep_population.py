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
    with pytest.raises(SystemExit, match="cannot read"):
        parse_setting("10by5")


def test_worst_edges_measures_each_edge_stretch_against_its_rest_length():
    """``benchmarks.worst_edges.edge_strain_history``: a sheet stretched 10 % along x and then
    squeezed 20 % along y gives its x edges strain 0.1 then 0, its y edges 0 then -0.2, and its
    diagonals the analytic value; every mesh edge appears once."""
    from benchmarks.worst_edges import edge_strain_history
    from tests.test_cloth_solver import grid

    v, f = grid(4, 3, 0.3, 0.2)
    v = v.astype(np.float64)
    frames = np.stack([v * [1.1, 1.0, 1.0], v * [1.0, 0.8, 1.0]])
    e, strain = edge_strain_history(frames, v, f)
    assert len(e) == len({tuple(sorted(t)) for t in f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).tolist()})
    d = v[e[:, 1]] - v[e[:, 0]]
    expect = [np.linalg.norm(d * s, axis=1) / np.linalg.norm(d, axis=1) - 1.0
              for s in ([1.1, 1, 1], [1, 0.8, 1])]
    np.testing.assert_allclose(strain, np.stack(expect), atol=1e-12)
    along_x = np.abs(d[:, 1]) < 1e-9
    np.testing.assert_allclose(strain[0, along_x], 0.1, atol=1e-12)
    np.testing.assert_allclose(strain[1, ~along_x & (np.abs(d[:, 0]) < 1e-9)], -0.2, atol=1e-12)
