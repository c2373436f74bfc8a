"""The virtual depth-camera ring (``sim.scans.scanner``): points on the surface, what the body
and the garment itself hide, depth noise, dropout, grazing rays and the marked border band,
each against geometry whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.geometry.primitives import uv_sphere
from sim.scans.scanner import ScanConfig, scan_garment

ONE = ScanConfig(cameras=1, heights=(0.0,), radius=1.5, resolution=(80, 80), fov_deg=30.0, noise=0.0,
                 dropout=0.0)
"""One camera at +Z (1.5 m from the origin) looking down -Z."""


def sheet(n: int = 41, size: float = 0.4, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A square n x n vertex sheet in the plane z, centred on the Z axis, facing +Z."""
    u = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(u, u)
    v = np.stack([x.ravel(), y.ravel(), np.full(n * n, z)], axis=1).astype(np.float32)
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None]
    i = i.ravel()
    f = np.concatenate([np.stack([i, i + 1, i + n + 1], 1), np.stack([i, i + n + 1, i + n], 1)])
    return v, f.astype(np.int32)


def test_points_lie_on_the_visible_side_of_the_surface():
    v, f = uv_sphere(0.3, 24, 36)
    s = scan_garment(v, f, np.zeros(3), config=ONE, device="cpu")
    assert len(s.points) > 500
    r = np.linalg.norm(s.points, axis=1)
    assert np.all(r <= 0.3 + 1e-5) and np.all(r > 0.3 * np.cos(np.pi / 24) - 1e-5)  # on the facets
    assert s.points[:, 2].min() > -0.02  # the back of the sphere is hidden by its front
    np.testing.assert_allclose(np.sum(s.normals * s.points / r[:, None], axis=1), 1.0, atol=0.02)
    assert np.all(s.camera == 0)


def test_the_body_hides_what_lies_behind_it():
    v, f = sheet(11, 0.2, z=-0.4)
    body_v, body_f = uv_sphere(0.25, 16, 24)
    alone = scan_garment(v, f, np.zeros(3), config=ONE, device="cpu")
    body = {"body_vertices": body_v, "body_faces": body_f}
    behind = scan_garment(v, f, np.zeros(3), **body, config=ONE, device="cpu")
    assert len(alone.points) > 50 and len(behind.points) == 0
    front_v, _ = sheet(11, 0.2, z=0.4)  # in front of the body: seen all the same
    front = scan_garment(front_v, f, np.zeros(3), **body, config=ONE, device="cpu")
    np.testing.assert_array_equal(front.points, scan_garment(front_v, f, np.zeros(3), config=ONE,
                                                             device="cpu").points)


def test_depth_noise_is_gaussian_along_the_ray_and_dropout_drops_its_share():
    v, f = sheet()
    cfg = ScanConfig(**{**ONE.__dict__, "noise": 0.002, "dropout": 0.25})
    clean = scan_garment(v, f, np.zeros(3), config=ONE, device="cpu")
    noisy = scan_garment(v, f, np.zeros(3), config=cfg, device="cpu", seed=4)
    z = noisy.points[:, 2]  # rays within 8 degrees of the normal: z error ~ noise
    assert abs(float(z.mean())) < 3 * 0.002 / np.sqrt(len(z))
    assert 0.9 * 0.002 < float(z.std()) < 1.03 * 0.002
    kept = len(noisy.points) / len(clean.points)
    assert abs(kept - 0.75) < 4 * np.sqrt(0.25 * 0.75 / len(clean.points))
    again = scan_garment(v, f, np.zeros(3), config=cfg, device="cpu", seed=4)
    np.testing.assert_array_equal(again.points, noisy.points)  # the seed decides every draw


def test_grazing_rays_return_nothing():
    v, f = sheet()
    edge_on = v[:, [2, 1, 0]]  # the sheet in the plane x = 0, containing the camera's axis
    assert len(scan_garment(edge_on, f, np.zeros(3), config=ONE, device="cpu").points) == 0
    tilted = v.copy()  # turned 75 degrees from facing the camera: 15 from tangent, still seen
    a = np.radians(75.0)
    tilted[:, 0], tilted[:, 2] = v[:, 0] * np.cos(a), -v[:, 0] * np.sin(a)
    assert len(scan_garment(tilted, f, np.zeros(3), config=ONE, device="cpu").points) > 0


def test_the_marked_band_follows_the_open_border():
    v, f = sheet(81, 0.4)
    cfg = ScanConfig(**{**ONE.__dict__, "boundary_band": 0.02, "resolution": (120, 120)})
    s = scan_garment(v, f, np.zeros(3), config=cfg, device="cpu")
    to_border = 0.2 - np.abs(s.points[:, :2]).max(axis=1)  # distance to the square's edge
    spacing = 0.4 / 80
    sure = np.abs(to_border - 0.02) > spacing  # away from the band's edge by a grid spacing
    np.testing.assert_array_equal(s.boundary[sure], to_border[sure] <= 0.02)
    assert s.boundary.any() and not s.boundary.all()


def test_a_closed_garment_has_no_band_and_bad_input_is_refused():
    v, f = uv_sphere(0.3, 12, 16)
    assert not scan_garment(v, f, np.zeros(3), config=ONE, device="cpu").boundary.any()
    with pytest.raises(WrinklesInputError, match="do not form a mesh"):
        scan_garment(v, f + len(v), np.zeros(3), config=ONE, device="cpu")
    with pytest.raises(WrinklesInputError, match="scan config"):
        ScanConfig(cameras=0)
