"""Cloth self-contact (sim.cloth.self_contact) in whole scenes: a dropped layer held by the
penalty, instances that never collide, a hairpin thrown onto itself, parts close at rest, and a
fine sheet whose surface neighbours leave the coarse correction alone. The pair maths, the
detection and the data are tested in ``test_self_contact_pairs.py``,
``test_self_contact_detection.py`` and ``test_self_contact_data.py``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim.cloth import (
    ClothMaterialParams,
    ClothModelBuilder,
    CoarseConfig,
    SelfContactConfig,
    SolverVBD,
    Stepping,
    VBDConfig,
)
from sim.cloth.config import FINE_COARSE_EXCLUSION, job_config
from sim.cloth.self_contact import RADIUS_CODES
from tests.self_contact_scenes import (
    FINE_SHEET,
    center_gap,
    fine_denim_sheet,
    folded_sheet,
    hairpin_pass,
    point_triangle_distance_np,
    segment_distance_np,
    stacked_layers,
)
from tests.test_cloth_solver import grid, simulate


@pytest.mark.parametrize("solver", [{}, {"self_contact.broadphase": "clusters"}])
def test_penalty_self_contact_holds_a_gently_dropped_layer(device, solver):
    """The penalty stops a layer dropped at 1 m/s onto a pinned one (the rims, where the loose
    layer folds over the pinned one's edge, may cross: no guarantee), with the pairs found
    through trees or through clusters; without self-contact the same drop goes straight
    through."""
    x, faces, nv, n = stacked_layers(device, True, speed=1.0, frames=20, solver=solver)
    gap = center_gap(x, nv, n)
    assert np.all(np.isfinite(x))
    assert np.all(gap > 0.0) and gap[-1] < 0.03
    assert gap[-1] > 0.5 * VBDConfig().self_contact.radius
    x_off, *_ = stacked_layers(device, False, speed=1.0, frames=20)
    assert center_gap(x_off, nv, n).min() < -0.02


def test_instances_do_not_collide_with_each_other(device):
    """Two overlapping sheets as separate instances of one model fall through each other
    exactly as alone: self-contact only acts within an instance."""
    v, f = grid(7, 7, 0.3, 0.3, plane="xz")
    cfg = VBDConfig(stepping=Stepping(substeps=3, iterations=3))  # self-contact on

    def run(parts):
        b = ClothModelBuilder()
        for vv in parts:
            b.add_cloth(vv, f, ClothMaterialParams())
        m = b.finalize(device)
        return simulate(m, SolverVBD(m, cfg), m.control(), 5, 1.0 / 30.0)

    lower = v
    upper = v + np.array([0.01, 0.005, 0.02], np.float32)
    both = run([lower, upper])
    np.testing.assert_allclose(both[:, :len(v)], run([lower]), atol=1e-6)
    np.testing.assert_allclose(both[:, len(v):], run([upper]), atol=1e-6)


@pytest.mark.parametrize("speed", [1.1, 2.0])
def test_a_hairpin_whose_arms_start_apart_lands_on_itself(device, speed):
    """A sheet folded at rest into a hairpin with its arms 10 mm apart, the upper arm thrown
    onto the pinned lower one: it lands and stays above it, without flipping over the fold, and
    the contact creates no energy: the sheet starts at its rest shape (no elastic energy) out of
    contact and its pins hold still, so its kinetic plus gravitational energy can only fall."""
    h, flipped, energy = hairpin_pass(device, gap=0.01, speed=speed)
    assert np.all(h > 0.0), h
    assert np.all(flipped < 0.0), flipped
    e0 = energy[-1]
    assert np.all(energy[:-1] <= e0 + 0.02 * abs(e0)), (energy[:-1], e0)


def test_the_exact_contact_hessian_lets_a_thrown_hairpin_gain_energy(device):
    """Why the contact Hessian has a weight floor (``SelfContactConfig.weight_floor``):
    with the exact ``w^2 k`` (floor 0) the hairpin above, thrown at 1.1 m/s, gains energy in its
    first contact (a rim vertex with a small weight in its pairs takes their whole penetration as
    its own step). This keeps the energy check above a test that can fail."""
    _, _, energy = hairpin_pass(device, gap=0.01, speed=1.1, frames=2,
                                solver={"self_contact.weight_floor": 0.0})
    assert energy[:-1].max() > energy[-1] + 1e-3  # more than a millijoule made


@pytest.mark.parametrize("gap", [0.001, 0.0004])
def test_parts_of_one_piece_close_at_rest_do_not_pass_through_each_other(device, gap):
    """A crease folded at rest with its arms closer than the 3 mm contact radius (as at a
    t-shirt's underarm seam or the crotch of trousers), the upper arm thrown down at 1 m/s: it
    stays above the lower one. Such pairs are in contact at half their rest distance."""
    h, flipped, energy = hairpin_pass(device, gap=gap)
    assert np.all(h > 0.0), h
    assert np.all(flipped < 0.0), flipped
    assert np.all(energy[:-1] <= energy[-1] + 0.02 * abs(energy[-1])), energy


def _coded_records(sc) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gather records of ``sc`` (``SelfContactData``) in use: indices, roles, vertices."""
    first, count = sc.pair_first.numpy(), sc.pair_count.numpy()
    recs = np.concatenate([np.arange(a, a + c) for a, c in zip(first, count, strict=True) if c > 0] or
                          [np.zeros(0, int)])
    return recs, sc.pair_role.numpy(), sc.pair_verts.numpy()


def test_pairs_close_at_rest_get_half_their_rest_distance_and_push_nothing_at_rest(device):
    """The folded sheet at rest (arms 1 mm apart): detection stores its facing pairs with a
    radius code (bits 8-15 of the records' role) whose radius is at most half, and at least
    0.49x, the pair's rest distance; a sweep of the sheet at rest moves nothing (no contact
    force at rest). Arms 10 mm apart: no pair within reach, no code."""
    radius = 0.003
    for gap, expect_codes in ((0.001, True), (0.01, False)):
        _, folded, f, _ = folded_sheet(13, 5, 0.02, 6, gap)
        params = ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.001)
        b = ClothModelBuilder()
        b.add_cloth(folded.astype(np.float32), f, params)
        m = b.finalize(device)
        cfg = VBDConfig(stepping=Stepping(substeps=1, iterations=2),
                        self_contact=SelfContactConfig(radius=radius), coarse=CoarseConfig(sweeps=()))
        solver = SolverVBD(m, cfg)
        state = m.state()
        solver.self_contact.detect(state.positions, state.velocities, 1.0 / 300.0)
        recs, role, verts = _coded_records(solver.self_contact.data)
        codes = (role[recs] >> 8) & 255
        assert (codes > 0).any() == expect_codes
        if not expect_codes:
            continue
        x = folded.astype(np.float64)
        for r in recs[codes > 0]:  # every coded record's radius against its rest distance
            q, kind = verts[r], role[r] & 15
            d = (point_triangle_distance_np(*x[q]) if kind < 4 else segment_distance_np(*x[q]))
            pr = radius * (1.0 - ((role[r] >> 8) & 255) / RADIUS_CODES)
            assert 0.49 * d - 1e-9 <= pr <= 0.5 * d + 1e-9, (d, pr)
        # at rest the solve exerts no contact force: gravity off, no velocity, nothing moves
        b2 = ClothModelBuilder(gravity=(0.0, 0.0, 0.0))
        b2.add_cloth(folded.astype(np.float32), f, params)
        m2 = b2.finalize(device)
        s2 = SolverVBD(m2, dataclasses.replace(cfg, stepping=dataclasses.replace(cfg.stepping, iterations=4)))
        st = m2.state()
        s2.step(st, st, m2.control(), 1.0 / 120.0)
        assert s2.self_contact.data.pair_count.numpy().sum() > 0
        np.testing.assert_allclose(st.positions.numpy(), folded, atol=1e-7)


def _hanging_fine_sheet(device, frames: int, **changes):
    """A 21 x 41 sheet of 5.5 mm edges (a fine garment's) in denim hanging from its pinned top row
    for ``frames`` frames at the job's solver settings for a fine garment on the CPU
    (``job_config``: the coarse correction, ``FINE_COARSE_EXCLUSION``), ``changes`` to its
    self-contact section on top: the bottom row's mean height per frame [m] and the share of
    particles with stored vertex-triangle pairs at the end."""
    m, v = fine_denim_sheet(device)
    nx = FINE_SHEET[0]
    cfg = job_config(20_000, cuda=False)
    cfg = dataclasses.replace(cfg, self_contact=dataclasses.replace(cfg.self_contact, **changes))
    solver = SolverVBD(m, cfg)
    state, control = m.state(), m.control()
    control.pin_targets.assign(v)
    bottom = []
    for _ in range(frames):
        solver.step(state, state, control, 1.0 / 30.0)
        bottom.append(float(state.positions.numpy()[-nx:, 1].mean()))
    share = float((solver.self_contact.data.vt_count.numpy() > 0).mean()) if cfg.self_contact.enabled else 0.0
    return np.array(bottom), share


@pytest.mark.slow
def test_neighbours_near_at_rest_leave_the_coarse_correction_of_a_fine_sheet_alone(device):
    """A flat sheet is never in contact with itself, and on a fine mesh it hangs with self-contact
    on as with it off (22 cm long, its bottom steady 0.1 mm below its rest height from the 6th
    frame). Its neighbours an edge or two apart (3.9-5.5 mm on the 5.5 mm grid) come within the
    4 mm query margin as it moves: nearly every particle holds pairs. Those pairs stay in
    contact but, closer than ``self_contact.coarse_exclusion`` (6 mm for fine garments) at rest,
    leave the coarse correction alone (``has_pairs``); with an exclusion of 0 (the coarse
    garments' value) the correction is capped nearly everywhere and the sheet bounces by
    centimetres."""
    off, _ = _hanging_fine_sheet(device, 12, enabled=False)
    np.testing.assert_allclose(off[5:], -0.2201, atol=2e-4)
    default, share = _hanging_fine_sheet(device, 12)
    assert share > 0.9 and FINE_COARSE_EXCLUSION == 0.006
    np.testing.assert_allclose(default, off, atol=1e-4)
    held, held_share = _hanging_fine_sheet(device, 12, coarse_exclusion=0.0)
    assert held_share > 0.9
    assert np.abs(held - off).max() > 0.005, held - off


def test_a_fold_close_in_the_rest_shape_but_far_along_the_pattern_keeps_the_full_radius(device):
    """The folded sheet (arms 1 mm apart) as a sewn garment's rest shape, its flat pattern the
    unfolded sheet: its facing pairs are 2 to 12 columns apart along the cloth, so detection
    stores them with the full radius (no radius code), where the same fold without a pattern
    codes them (``test_pairs_close_at_rest_get_half_their_rest_distance_...``)."""
    flat, folded, f, _ = folded_sheet(13, 5, 0.02, 6, 0.001)
    params = ClothMaterialParams(mu=300.0, lam=100.0, thickness=0.001)
    cfg = VBDConfig(stepping=Stepping(substeps=1, iterations=2),
                    self_contact=SelfContactConfig(radius=0.003), coarse=CoarseConfig(sweeps=()))
    codes = {}
    for pattern in (False, True):
        b = ClothModelBuilder()
        corners = flat[f][:, :, [2, 0]] if pattern else None  # counter-clockwise
        b.add_cloth(folded.astype(np.float32), f, params, rest_corners=corners,
                    face_panels=np.zeros(len(f), np.int64) if pattern else None)
        m = b.finalize(device)
        solver = SolverVBD(m, cfg)
        state = m.state()
        solver.self_contact.detect(state.positions, state.velocities, 1.0 / 300.0)
        recs, role, _ = _coded_records(solver.self_contact.data)
        assert len(recs) > 0
        codes[pattern] = (role[recs] >> 8) & 255
    assert (codes[False] > 0).any() and not (codes[True] > 0).any(), codes
