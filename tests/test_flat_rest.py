"""Cloth whose rest shape is its flat sewing pattern (ClothModelBuilder.add_cloth rest_corners)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth.model import (
    ClothMaterialParams,
    ClothModelBuilder,
    flat_rest_data,
    hinge_rest_angles,
    triangle_rest_data,
)


def grid(n: int, size: float) -> tuple[np.ndarray, np.ndarray]:
    """An n x n grid of squares split in two, in the xy plane, counter-clockwise."""
    u = np.linspace(0.0, size, n + 1)
    xy = np.stack(np.meshgrid(u, u, indexing="xy"), axis=-1).reshape(-1, 2)
    f = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            f += [(a, a + 1, a + n + 2), (a, a + n + 2, a + n + 1)]
    return xy, np.array(f, np.int32)


def test_flat_rest_data_has_the_metric_and_areas_of_the_same_triangles_in_3d():
    rng = np.random.default_rng(0)
    xy, faces = grid(4, 0.1)
    xy = xy + rng.normal(0.0, 0.004, xy.shape)
    # the same triangles rotated into 3D: the rest metric cannot change
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    x3 = np.c_[xy, np.zeros(len(xy))] @ rot.T
    d_flat, a_flat = flat_rest_data(xy[faces])
    d_3d, a_3d = triangle_rest_data(x3, faces)
    np.testing.assert_allclose(a_flat, a_3d, rtol=1e-10)
    # Dm^-1 Dm^-T is invariant to the triangle's in-plane frame
    np.testing.assert_allclose(d_flat @ d_flat.transpose(0, 2, 1), d_3d @ d_3d.transpose(0, 2, 1), rtol=1e-8)
    with pytest.raises(ValueError, match="counter-clockwise"):
        flat_rest_data(xy[faces][:, ::-1])


def test_hinges_inside_a_panel_rest_flat_and_across_a_seam_keep_their_angle():
    # two squares folded 90 degrees along x = 0.1: left panel in the xy plane, right one going up z
    xy, faces = grid(2, 0.1)
    x3 = np.c_[xy, np.zeros(len(xy))]
    folded = x3.copy()
    right = xy[:, 0] > 0.05 + 1e-9
    folded[right, 0] = 0.05
    folded[right, 2] = xy[right, 0] - 0.05
    panels = (xy[faces].mean(axis=1)[:, 0] > 0.05).astype(np.int64)
    b = ClothModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_cloth(folded, faces, ClothMaterialParams(), rest_corners=xy[faces], face_panels=panels)
    ins = b._instances[0]
    angles = hinge_rest_angles(ins)
    def face_of(o, a, b):
        return np.flatnonzero((faces == o).any(1) & (faces == a).any(1) & (faces == b).any(1))[0]

    t_a = np.array([face_of(h[0], h[2], h[3]) for h in ins.hinges])
    t_b = np.array([face_of(h[1], h[2], h[3]) for h in ins.hinges])
    seam = panels[t_a] != panels[t_b]
    assert seam.any() and (~seam).any()
    np.testing.assert_allclose(np.abs(angles[seam]), np.pi / 2, atol=1e-9)
    np.testing.assert_array_equal(angles[~seam], 0.0)


def test_a_sheet_stretched_beyond_its_pattern_pulls_back_to_it():
    """Membrane physics: rest_vertices 10 % larger than the flat pattern, no gravity; the sheet
    contracts to the pattern's size (the rest shape is the pattern, not rest_vertices)."""
    from sim.cloth import SolverVBD

    xy, faces = grid(6, 0.3)
    big = np.c_[xy * 1.1, np.zeros(len(xy))]
    b = ClothModelBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_cloth(big, faces, ClothMaterialParams(mu=500.0, lam=200.0), rest_corners=xy[faces])
    model = b.finalize("cpu")
    solver, state, control = SolverVBD(model), model.state(), model.control()
    for _ in range(60):
        solver.step(state, state, control, 1.0 / 30.0)
    x = state.positions.numpy()
    edges = faces[:, [0, 1]]
    ratio = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1) / np.linalg.norm(
        xy[edges[:, 0]] - xy[edges[:, 1]], axis=1)
    assert abs(float(np.median(ratio)) - 1.0) < 0.01  # started at 1.10
