"""Set-in sleeves of the tops: a cap as high as a tee's over the upper arm plus its ease, for
every fit and body shape (a flat cap makes a sleeve that stands out as in the T-pose it is sewn
in, and folds into the armpit when the arm comes down)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.bodies import load_body
from sim.bodies.default import parse_shape
from sim.garments.designs import BodyParts, make_pattern
from sim.garments.drafting.tops import ease


@pytest.fixture(scope="module")
def body():
    return load_body()


@pytest.mark.parametrize("shape", ["", "height=0.6,weight=0.8", "height=0.3,weight=0.2"])
@pytest.mark.parametrize("fit", ["tight", "regular", "loose"])
def test_sleeve_cap_stands_6_to_9_cm_over_a_sleeve_as_wide_as_the_arm_plus_ease(body, shape, fit):
    betas = parse_shape(shape)
    m = BodyParts.of(body, betas).measurements
    pattern = make_pattern("t_shirt", body, betas, fit=fit)
    sleeve = pattern.panel("sleeve_l")
    cuff_l, cuff_r, under_r, crown, under_l = sleeve.corners
    assert 0.06 <= crown[1] - under_r[1] <= 0.09
    np.testing.assert_allclose(under_r[0] - under_l[0], m.bicep + ease("bicep", fit), atol=1e-9)
    assert under_r[1] == under_l[1] and crown[0] == 0.0
