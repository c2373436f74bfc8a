"""Set-in sleeves of the tops: a shirt's cap over the upper arm plus its ease, for every fit and
body shape (a flat cap makes a sleeve that stands out as in the T-pose it is sewn in, and folds
into the armpit when the arm comes down), and bodices that reach over the shoulders."""

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
def test_sleeve_cap_stands_11_to_17_cm_over_a_sleeve_as_wide_as_the_arm_plus_ease(body, shape, fit):
    betas = parse_shape(shape)
    m = BodyParts.of(body, betas).measurements
    pattern = make_pattern("t_shirt", body, betas, fit=fit)
    sleeve = pattern.panel("sleeve_l")
    cuff_l, cuff_r, under_r, crown, under_l = sleeve.corners
    assert 0.11 <= crown[1] - under_r[1] <= 0.17
    np.testing.assert_allclose(under_r[0] - under_l[0], m.bicep + ease("bicep", fit), atol=1e-9)
    assert under_r[1] == under_l[1] and crown[0] == 0.0


def box_body(depth: float = 0.2, height: float = 0.3, width: float = 0.4):
    import trimesh

    box = trimesh.creation.box(extents=(width, height, depth))
    box.apply_translation((0.0, height / 2, 0.0))
    for _ in range(5):  # edges of ~1 cm, as the body's
        box = box.subdivide()
    return np.asarray(box.vertices), np.asarray(box.faces)


@pytest.mark.parametrize("top_y", [0.3, 0.25])
@pytest.mark.parametrize("front", [True, False])
def test_shoulder_tape_is_the_tape_over_a_box_top_to_its_middle(top_y, front):
    """A box torso 0.2 m deep: from chest level (0.1 m) the tape runs up the front (back) to the
    seam's height, then half the depth across the top to the seam: 0.1 m beyond the rise, short
    by at most an edge length (the tape cuts the top corner between its last crossings)."""
    from sim.garments.drafting.body_frame import ShoulderTape

    v, f = box_body()
    extra = ShoulderTape(v, f, np.ones(len(v), bool), 0.1).over(0.1, top_y, front)
    assert 0.1 - 0.0125 <= extra <= 0.1 + 1e-9  # short by at most an edge (1.25 cm)


def test_shoulder_tape_is_nothing_beside_the_body():
    from sim.garments.drafting.body_frame import ShoulderTape

    v, f = box_body()
    assert ShoulderTape(v, f, np.ones(len(v), bool), 0.1).over(0.3, 0.3, True) == 0.0


def test_bodices_reach_over_the_shoulders_of_the_body():
    """The front and back panels stand taller than the body's rise from the hem to the side neck
    point by the mean of their over-shoulder lengths, 2-8 cm on the default body."""
    from sim.garments.drafting.body_frame import ShoulderTape

    body = load_body()
    parts = BodyParts.of(body)
    m = parts.measurements
    pattern = make_pattern("t_shirt", body)
    front, back = pattern.panel("front"), pattern.panel("back")
    top = m.neck_base_height + 0.005
    hps = m.neck_base / (2 * np.pi) + 0.01  # the design's neck_width
    tape = ShoulderTape(parts.vertices, parts.faces, parts.torso_mask, m.chest_height)
    extra = np.mean([tape.over(hps, top, s) for s in (True, False)])
    assert 0.02 < extra < 0.08
    hem_y = m.waist_height - 0.22  # the t-shirt's hem_drop
    for panel, depth in ((front, 0.08), (back, 0.02)):  # the design's neck depths
        rise = panel.corners[:, 1].max() - panel.corners[:, 1].min()
        assert rise == pytest.approx(top + extra - hem_y, abs=1e-9)
        centre = panel.corners[panel.corners[:, 0] == 0.0]  # the neckline's centre goes over no shoulder
        assert centre[:, 1].max() == pytest.approx(top - hem_y - depth, abs=1e-9)
