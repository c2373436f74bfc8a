"""The phase recorder (``sim.profiling``): nested phases under their paths, times that add up,
and nothing recorded while it is off."""

from __future__ import annotations

import time

import pytest

from sim.profiling import PHASES, phase


@pytest.fixture
def phases():
    PHASES.start()
    yield PHASES
    PHASES.stop()


def test_nested_phases_add_up_to_their_parent(phases):
    with phase("job"):
        for _ in range(2):
            with phase("simulate"):
                time.sleep(0.02)
                with phase("prelude"):
                    time.sleep(0.01)
        with phase("write"):
            time.sleep(0.01)
    r = phases.report()
    assert list(r) == ["job", "job/simulate", "job/simulate/prelude", "job/write"]
    assert r["job/simulate"]["calls"] == 2 and r["job/simulate/prelude"]["calls"] == 2
    assert r["job/simulate/prelude"]["s"] >= 0.02
    sim, prelude = r["job/simulate"], r["job/simulate/prelude"]
    assert sim["self_s"] == pytest.approx(sim["s"] - prelude["s"])
    children = r["job/simulate"]["s"] + r["job/write"]["s"]
    assert r["job"]["self_s"] == pytest.approx(r["job"]["s"] - children)
    assert sum(p["self_s"] for p in r.values()) == pytest.approx(r["job"]["s"])


def test_a_phase_that_raises_is_recorded_and_unwinds(phases):
    with pytest.raises(ValueError):
        with phase("outer"):
            with phase("inner"):
                raise ValueError("boom")
    with phase("after"):
        pass
    assert list(phases.report()) == ["outer", "outer/inner", "after"]


def test_an_added_measurement_is_a_nested_phase_taken_from_its_parent(phases):
    with phase("steps"):
        time.sleep(0.03)
        phases.add("solver", 0.02, calls=5)
    r = phases.report()
    assert list(r) == ["steps", "steps/solver"]
    assert r["steps/solver"] == {"s": 0.02, "self_s": 0.02, "calls": 5}
    assert r["steps"]["self_s"] == pytest.approx(r["steps"]["s"] - 0.02)


def test_nothing_is_recorded_while_off():
    PHASES.start()
    PHASES.stop()
    with phase("ignored"):
        pass
    PHASES.add("ignored too", 1.0)
    assert PHASES.report() == {}
