"""Easing curves: the cubic ``smoothstep`` and the quintic ``smootherstep``."""

from __future__ import annotations

import numpy as np
import pytest

from sim.easing import smootherstep, smoothstep


@pytest.mark.parametrize("curve, poly", [
    (smoothstep, lambda t: 3 * t**2 - 2 * t**3),
    (smootherstep, lambda t: 6 * t**5 - 15 * t**4 + 10 * t**3),
])
def test_curves_are_their_polynomials_clamped_outside(curve, poly):
    t = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(curve(t), poly(t), atol=1e-15)
    np.testing.assert_array_equal(curve(np.array([-0.5, 0.0, 0.5, 1.0, 1.5])), [0.0, 0.0, 0.5, 1.0, 1.0])


def test_slopes_vanish_at_the_ends_and_the_quintic_acceleration_too():
    eps = 1e-4
    for curve in (smoothstep, smootherstep):
        assert abs(float(curve(eps)) / eps) < 1e-3  # zero slope at 0
        assert abs((1.0 - float(curve(1.0 - eps))) / eps) < 1e-3  # and at 1
    # second difference at the ends: the cubic's acceleration is 6, the quintic's 0
    accel = [(float(c(2 * eps)) - 2 * float(c(eps)) + float(c(0.0))) / eps**2
             for c in (smoothstep, smootherstep)]
    assert accel[0] == pytest.approx(6.0, rel=1e-3) and abs(accel[1]) < 1e-2


def test_smoothstep_computes_in_float64_and_smootherstep_in_the_input_dtype():
    t = np.array([0.25, 0.75], np.float32)
    assert smoothstep(t).dtype == np.float64
    assert smootherstep(t).dtype == np.float32
