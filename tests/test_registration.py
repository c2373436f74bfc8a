"""Template registration (``sim.scans.registration``, DeepWrinkles Sec. 3.1): the grid
deformation, Eq. 2's border pairs, the Gauss-Newton system against finite differences, and
registering a tube to scans of known deformations of it, with and without the border term."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.scans.registration import (
    RegistrationConfig,
    _deform,
    _grid,
    _solve_spd,
    _system,
    boundary_pairs,
    register,
)
from sim.scans.scanner import ScanConfig, scan_garment


def tube(radius: float = 0.15, height: float = 0.4, around: int = 48, rows: int = 21):
    """An open cylinder around the Y axis from y = 0.8 to 0.8 + height, outward faces."""
    a = np.linspace(0, 2 * np.pi, around, endpoint=False)
    y = np.linspace(0.8, 0.8 + height, rows)
    v = np.stack([np.tile(radius * np.cos(a), rows), np.repeat(y, around),
                  np.tile(radius * np.sin(a), rows)], axis=1)
    i = (np.arange(rows - 1)[:, None] * around + np.arange(around)[None]).ravel()
    j = (i // around) * around + (i + 1) % around
    f = np.concatenate([np.stack([i, i + around, j], 1), np.stack([j, i + around, j + around], 1)])
    return v.astype(np.float32), f.astype(np.int32)


def test_the_identity_grid_keeps_the_template_and_weights_sum_to_one():
    v, _ = tube()
    grid = _grid(v.astype(np.float64) * 1000, 40.0)
    np.testing.assert_allclose(grid.weights.sum(axis=1), 1.0)
    ident = np.tile(np.r_[np.eye(3).ravel(), 0, 0, 0], (len(grid.nodes), 1))
    np.testing.assert_allclose(_deform(grid, v * 1000.0, ident), v * 1000.0, atol=1e-9)
    corners = np.einsum("vk,vkc->vc", grid.weights, grid.nodes[grid.vertex_nodes])
    np.testing.assert_allclose(corners, v * 1000.0, atol=1e-6)  # trilinear weights reproduce the point
    # every node carrying the same rigid motion x -> R x + c moves the template rigidly
    rot = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))
    c = np.array([10.0, -20.0, 5.0])
    rigid = np.concatenate([np.tile(rot.ravel(), (len(grid.nodes), 1)),
                            grid.nodes @ rot.T + c - grid.nodes], axis=1)
    np.testing.assert_allclose(_deform(grid, v * 1000.0, rigid), v * 1000.0 @ rot.T + c, atol=1e-8)


def test_the_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    x = rng.random((40, 3)) * 100.0
    grid = _grid(x, 40.0)
    p = np.tile(np.r_[np.eye(3).ravel(), 0, 0, 0], (len(grid.nodes), 1))
    p = p + rng.normal(scale=0.05, size=p.shape)
    n = rng.normal(size=(20, 3))
    bound = (np.array([1, 5]), rng.random((2, 3)) * 100.0)
    weights = (500.0, 50.0, 10.0)
    d = rng.normal(size=p.shape)
    eps = 1e-6
    pairs = rng.choice(40, size=(30, 2), replace=True)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    edges = (pairs, np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1) * 0.9, 2.0)
    for normals, e in ((None, None), (n / np.linalg.norm(n, axis=1, keepdims=True), None),  # point, plane
                       (None, edges)):  # and the edge-length term
        data = (np.arange(0, 40, 2), rng.random((20, 3)) * 100.0, normals)
        _, jac = _system(grid, x, p, data, bound, weights, 0.1, e)
        rp, _ = _system(grid, x, p + eps * d, data, bound, weights, 0.1, e)
        rm, _ = _system(grid, x, p - eps * d, data, bound, weights, 0.1, e)
        np.testing.assert_allclose(jac @ d.ravel(), (rp - rm) / (2 * eps), rtol=1e-5, atol=1e-5)


def test_eq2_gives_each_template_border_point_the_farthest_scan_point_it_owns():
    template = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    scan = np.array([[0.1, 0, 0], [0.4, 0, 0], [0.9, 0, 0], [0.2, 0.1, 0]])
    t, s = boundary_pairs(template, scan)
    assert dict(zip(t.tolist(), s.tolist(), strict=True)) == {0: 1, 1: 2}  # vertex 2 owns none


SCAN = ScanConfig(cameras=6, heights=(-0.15, 0.25), radius=1.4, resolution=(96, 128), fov_deg=40.0,
                  noise=0.0005, dropout=0.02, boundary_band=0.006)


def bent(v: np.ndarray, curvature: float = 0.6) -> np.ndarray:
    """The tube's axis bent into an arc (curvature [1/m]) in the XY plane, each cross-section
    turned with it, and the whole moved 1 cm sideways: nearly isometric, as cloth deforms
    (the inner side shortens by radius x curvature, 9 %) [m]."""
    h = v[:, 1].astype(np.float64) - 0.8
    a = curvature * h
    out = np.empty(v.shape)
    out[:, 0] = (1.0 - np.cos(a)) / curvature + v[:, 0] * np.cos(a) + 0.01
    out[:, 1] = 0.8 + np.sin(a) / curvature - v[:, 0] * np.sin(a)
    out[:, 2] = v[:, 2]
    return out.astype(np.float32)


@pytest.mark.slow
def test_registration_follows_a_smooth_deformation_of_the_template():
    v, f = tube()
    truth = bent(v)
    scan = scan_garment(truth, f, np.array([0.0, 1.0, 0.0]), config=SCAN, device="cpu", seed=1)
    reg = register(v, f, scan)
    before = np.linalg.norm(v - truth, axis=1)
    after = np.linalg.norm(reg.vertices - truth, axis=1)
    assert before.mean() > 0.025
    assert after.mean() < 0.25 * before.mean() and np.percentile(after, 95) < 0.012
    assert reg.data_rms[-1] < 0.5 * reg.data_rms[0]


@pytest.mark.slow
def test_the_border_term_brings_the_hem_to_the_scans_marked_hem():
    """The scanned tube's lower hem hangs 4 cm lower (the bottom stretched): nearest points alone
    leave the template's hem where the side wall already fits; Eq. 2's pairs pull it down."""
    v, f = tube()
    y = (v[:, 1] - 0.8) / 0.4
    truth = v.copy()
    truth[:, 1] -= 0.04 * (1.0 - y) ** 2
    scan = scan_garment(truth, f, np.array([0.0, 1.0, 0.0]), config=SCAN, device="cpu", seed=2)
    hem = np.flatnonzero(v[:, 1] < 0.8 + 1e-6)
    err = {}
    for use in (False, True):
        reg = register(v, f, scan, config=RegistrationConfig(use_boundary=use))
        err[use] = float(np.linalg.norm(reg.vertices[hem] - truth[hem], axis=1).mean())
    assert err[True] < 0.2 * err[False]


def test_bad_input_is_refused():
    v, f = tube()
    scan = scan_garment(v, f, np.array([0.0, 1.0, 0.0]), config=SCAN, device="cpu")
    with pytest.raises(WrinklesInputError, match="do not form a mesh"):
        register(v, f + len(v), scan)


@pytest.mark.slow
def test_the_edge_term_keeps_the_templates_lengths():
    """Weak grid rigidity lets the template stretch between nodes; the edge-length term holds the
    cloth's own lengths (the tube bent and scanned)."""
    v, f = tube()
    truth = bent(v)
    scan = scan_garment(truth, f, np.array([0.0, 1.0, 0.0]), config=SCAN, device="cpu", seed=1)
    from sim.quality import unique_edges

    e = unique_edges(f)
    l0 = np.linalg.norm(truth[e[:, 0]] - truth[e[:, 1]], axis=1)  # the bent tube's own lengths
    strain = []
    for edge in (0.0, 1.0):
        reg = register(v, f, scan, config=RegistrationConfig(cell=0.06, rigid=0.05, smooth=0.05, edge=edge))
        x = reg.vertices
        strain.append(np.abs(np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1) / l0 - 1).mean())
    assert strain[1] < 0.7 * strain[0], strain  # measured: 0.091 -> 0.057


def test_the_dense_solve_matches_the_sparse_one():
    """The normal equations of a registration step solved by SuperLU on the host and by a dense
    Cholesky factor (torch; on a CUDA device in use) give the same step."""
    import scipy.sparse as sp

    rng = np.random.default_rng(3)
    x = rng.random((60, 3)) * 100.0
    grid = _grid(x, 40.0)
    p = np.tile(np.r_[np.eye(3).ravel(), 0, 0, 0], (len(grid.nodes), 1))
    p = p + rng.normal(scale=0.05, size=p.shape)
    data = (np.arange(0, 60, 2), rng.random((30, 3)) * 100.0, None)
    res, jac = _system(grid, x, p, data, (np.zeros(0, np.int64), np.zeros((0, 3))), (5.0, 5.0, 1.0), 1.0)
    lhs = (jac.T @ jac + 1e-6 * sp.identity(p.size)).tocsc()
    rhs = -(jac.T @ res)
    sparse = _solve_spd(lhs, rhs)
    np.testing.assert_allclose(lhs @ sparse, rhs, atol=1e-6 * np.abs(rhs).max())
    np.testing.assert_allclose(_solve_spd(lhs, rhs, "cpu"), sparse, rtol=1e-6, atol=1e-9)
