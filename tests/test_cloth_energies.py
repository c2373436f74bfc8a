"""Cloth energies (``sim.cloth.energies``) against float64 numpy references and finite
differences: the co-rotated membrane and the hinge bending the solver integrates, the StVK
membrane energy of the losses."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from sim.cloth.energies import (
    bending_damped_vertex_force_hessian,
    corotated_damped_vertex_force_hessian,
    corotated_energy,
    green_strain,
)
from sim.cloth.model import dihedral_angles, triangle_rest_data
from sim.device import warp
from sim.losses.loss_kernels import bending_energy_kernel, membrane_energy_kernel

REST = np.array([[0, 0, 0], [0.1, 0, 0], [0.03, 0.08, 0]], dtype=np.float64)
MU, LAM = 300.0, 120.0


@wp.kernel
def corotated_vertex_derivatives_kernel(
    x: wp.array(dtype=wp.vec3),
    dm_inv: wp.mat22,
    area: float,
    mu: float,
    lam: float,
    force_out: wp.array(dtype=wp.vec3),
    hessian_out: wp.array(dtype=wp.mat33),
    energy_out: wp.array(dtype=float),
):
    """Co-rotated membrane force and Hessian block of one triangle ``x[0..2]`` per vertex
    (no damping: the substep-start strain is the current one), and its energy."""
    k = wp.tid()
    s = green_strain(x[0], x[1], x[2], dm_inv)
    f, h = corotated_damped_vertex_force_hessian(x[0], x[1], x[2], dm_inv, area, mu, lam, s, 0.0, k)
    force_out[k] = f
    hessian_out[k] = h
    energy_out[k] = corotated_energy(x[0], x[1], x[2], dm_inv, area, mu, lam)


@wp.kernel
def bending_vertex_derivatives_kernel(
    x: wp.array(dtype=wp.vec3),
    rest_angle: float,
    k_edge: float,
    force_out: wp.array(dtype=wp.vec3),
    hessian_out: wp.array(dtype=wp.mat33),
):
    """Force and Gauss-Newton Hessian of one hinge ``x[0..3] = (o0, o1, a, b)`` per vertex (no
    damping)."""
    k = wp.tid()
    f, h = bending_damped_vertex_force_hessian(x[0], x[1], x[2], x[3], rest_angle, k_edge, 0.0, 0.0, k)
    force_out[k] = f
    hessian_out[k] = h


def stvk_energy_np(x: np.ndarray, dm_inv: np.ndarray, area: float, mu: float, lam: float) -> float:
    ds = np.stack([x[1] - x[0], x[2] - x[0]], axis=1)
    F = ds @ dm_inv
    E = 0.5 * (F.T @ F - np.eye(2))
    return area * (mu * np.sum(E * E) + 0.5 * lam * np.trace(E) ** 2)


def corotated_energy_np(x: np.ndarray, dm_inv: np.ndarray, area: float, mu: float, lam: float) -> float:
    """A (mu |F - R|^2 + lam/2 (tr S - 2)^2) with F = R S from an SVD (float64 reference)."""
    F = np.stack([x[1] - x[0], x[2] - x[0]], axis=1) @ dm_inv
    u, sv, vt = np.linalg.svd(F, full_matrices=False)
    R = u @ vt
    return area * (mu * np.sum((F - R) ** 2) + 0.5 * lam * (sv.sum() - 2.0) ** 2)


def bending_energy_np(x: np.ndarray, rest_angle: float, k: float) -> float:
    th = dihedral_angles(x, np.array([[0, 1, 2, 3]]))[0]
    d = (th - rest_angle + np.pi) % (2 * np.pi) - np.pi  # the short way round
    return 0.5 * k * d**2


def fd_gradient_hessian(energy, x: np.ndarray, vertex: int, h: float = 1e-5):
    """Central differences of ``energy`` in float64: gradient (3,), Hessian block (3, 3)."""
    grad = np.zeros(3)
    hess = np.zeros((3, 3))

    def e_at(da, db):
        y = x.copy()
        y[vertex] += da + db
        return energy(y)

    eye = np.eye(3) * h
    for a in range(3):
        grad[a] = (e_at(eye[a], 0) - e_at(-eye[a], 0)) / (2 * h)
        for b in range(3):
            hess[a, b] = (e_at(eye[a], eye[b]) - e_at(eye[a], -eye[b]) - e_at(-eye[a], eye[b])
                          + e_at(-eye[a], -eye[b])) / (4 * h * h)
    return grad, hess


def test_stvk_energy_matches_numpy(device):
    """The StVK energy of a stretched, rotated triangle (the losses' membrane term) is the
    numpy reference's."""
    dm_inv, area = triangle_rest_data(REST, np.array([[0, 1, 2]]))
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    jitter = np.array([[0, 0, 0], [0, 0.004, 0.003], [0.002, 0, -0.004]])
    x = (REST @ np.diag([1.12, 1.08, 1.0]) + jitter) @ q.T
    e_out = wp.zeros((1, 1), dtype=float, device=device)
    wp.launch(membrane_energy_kernel, dim=(1, 1),
              inputs=[wp.array(x[None].astype(np.float32), dtype=wp.vec3, device=device),
                      wp.array([[0, 1, 2]], dtype=wp.vec3i, device=device),
                      wp.array(dm_inv.astype(np.float32), dtype=wp.mat22, device=device),
                      wp.array(area.astype(np.float32), dtype=float, device=device), MU, LAM],
              outputs=[e_out], device=device)
    np.testing.assert_allclose(e_out.numpy()[0, 0], stvk_energy_np(x, dm_inv[0], area[0], MU, LAM), rtol=1e-4)


@pytest.mark.parametrize("scale", [(1.12, 1.08), (0.7, 0.85), (1.1, 0.8)])
def test_corotated_membrane_force_matches_finite_differences(device, scale):
    """Stretched, compressed and mixed: the force is the exact gradient; the Hessian block is
    the documented positive semi-definite approximation and agrees with the exact one in the
    triangle's plane."""
    dm_inv, area = triangle_rest_data(REST, np.array([[0, 1, 2]]))
    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    x = (REST @ np.diag([scale[0], scale[1], 1.0])) @ q.T
    out = [wp.zeros(3, dtype=t, device=device) for t in (wp.vec3, wp.mat33, float)]
    wp.launch(corotated_vertex_derivatives_kernel, dim=3,
              inputs=[wp.array(x.astype(np.float32), dtype=wp.vec3, device=device),
                      wp.mat22(*dm_inv[0].astype(np.float32).ravel()), float(area[0]), MU, LAM],
              outputs=out, device=device)
    forces, hessians, energies_k = (o.numpy() for o in out)

    def energy(y):
        return corotated_energy_np(y, dm_inv[0], area[0], MU, LAM)

    np.testing.assert_allclose(energies_k[0], energy(x), rtol=1e-3, atol=1e-9)
    for k in range(3):
        grad, _ = fd_gradient_hessian(energy, x, k)
        np.testing.assert_allclose(forces[k], -grad, rtol=2e-3, atol=2e-3 * np.abs(grad).max() + 1e-9)
        h = hessians[k].astype(np.float64)
        np.testing.assert_allclose(h, h.T, atol=1e-6 * np.abs(h).max())
        assert np.linalg.eigvalsh(h).min() > -1e-6 * np.abs(h).max()


def test_bending_force_and_hessian_match_finite_differences(device):
    # hinge (o0, o1, a, b): triangles (a, b, o0) and (b, a, o1), folded out of plane
    x = np.array([[0.05, 0.09, 0.02], [0.06, -0.08, 0.03], [0.0, 0.0, 0.0], [0.1, 0.01, 0.0]])
    theta = dihedral_angles(x, np.array([[0, 1, 2, 3]]))[0]
    assert abs(theta) > 0.2
    k = 2e-3
    f_out = wp.zeros(4, dtype=wp.vec3, device=device)
    h_out = wp.zeros(4, dtype=wp.mat33, device=device)
    x32 = wp.array(x.astype(np.float32), dtype=wp.vec3, device=device)
    # gradient away from the rest angle
    rest_angle = theta - 0.3
    wp.launch(bending_vertex_derivatives_kernel, dim=4, inputs=[x32, float(rest_angle), k],
              outputs=[f_out, h_out], device=device)
    for v in range(4):
        grad, _ = fd_gradient_hessian(lambda y: bending_energy_np(y, rest_angle, k), x, v)
        np.testing.assert_allclose(f_out.numpy()[v], -grad, rtol=1e-3, atol=1e-3 * np.abs(grad).max())
    np.testing.assert_allclose(f_out.numpy().sum(axis=0), 0.0, atol=1e-6)  # translation invariance
    # the Gauss-Newton Hessian is exact at the rest angle
    wp.launch(bending_vertex_derivatives_kernel, dim=4, inputs=[x32, float(theta), k],
              outputs=[f_out, h_out], device=device)
    for v in range(4):
        _, hess = fd_gradient_hessian(lambda y: bending_energy_np(y, theta, k), x, v, h=1e-4)
        np.testing.assert_allclose(h_out.numpy()[v], hess, rtol=2e-3, atol=2e-3 * np.abs(hess).max())


def hinge_folded(phi: float) -> np.ndarray:
    """A hinge (o0, o1, a, b) along x whose wing o1 is turned by ``phi`` [rad] about the hinge
    from flat (0) towards folded onto wing o0 (pi)."""
    return np.array([[0.05, 0.08, 0.0], [0.06, -0.08 * np.cos(phi), 0.08 * np.sin(phi)],
                     [0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])


def test_a_hinge_folded_at_rest_resists_folding_past_flat_the_short_way(device):
    """A crease folded at rest (170 degrees, a seam or a hairpin) folded 20 degrees further, so
    past flat, where the signed dihedral angle jumps from +pi to -pi: the bending energy is that
    of a 20-degree bend, not of a 340-degree one, and the force turns the wing back the short
    way, not on round through the other wing. Forces match finite differences of the wrapped
    energy."""
    w = warp()
    hinge = np.array([[0, 1, 2, 3]])
    rest = dihedral_angles(hinge_folded(np.radians(170.0)), hinge)[0]
    x = hinge_folded(np.radians(190.0))
    theta = dihedral_angles(x, hinge)[0]
    assert abs(abs(rest) - np.radians(170.0)) < 1e-6 and np.sign(theta) != np.sign(rest)  # wrapped
    k = 2e-3
    e_out = w.zeros((1, 1), dtype=float, device=device)
    w.launch(bending_energy_kernel, dim=(1, 1),
             inputs=[w.array(x[None].astype(np.float32), dtype=w.vec3, device=device),
                     w.array(hinge, dtype=w.vec4i, device=device),
                     w.array([rest], dtype=float, device=device),
                     w.array([k], dtype=float, device=device)],
             outputs=[e_out], device=device)
    np.testing.assert_allclose(e_out.numpy()[0, 0], 0.5 * k * np.radians(20.0) ** 2, rtol=1e-4)
    f_out = w.zeros(4, dtype=w.vec3, device=device)
    h_out = w.zeros(4, dtype=w.mat33, device=device)
    w.launch(bending_vertex_derivatives_kernel, dim=4,
             inputs=[w.array(x.astype(np.float32), dtype=w.vec3, device=device), float(rest), k],
             outputs=[f_out, h_out], device=device)
    for v in range(4):
        grad, _ = fd_gradient_hessian(lambda y: bending_energy_np(y, rest, k), x, v)
        np.testing.assert_allclose(f_out.numpy()[v], -grad, rtol=1e-3, atol=1e-3 * np.abs(grad).max())
    # the wing o1 is pushed back towards 170 degrees: along d x1 / d phi with phi decreasing
    back = -(hinge_folded(np.radians(190.0) + 1e-6)[1] - x[1])
    assert np.dot(f_out.numpy()[1], back) > 0.0
