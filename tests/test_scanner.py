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
    """A sheet turned 80 degrees from facing the camera meets its rays at 78.7-81.0 degrees from
    its normal: with the 10-degree cut-off only those under 80 degrees come back."""
    v, f = sheet()
    a = np.radians(80.0)
    tilted = v.copy()
    tilted[:, 0], tilted[:, 2] = v[:, 0] * np.cos(a), -v[:, 0] * np.sin(a)
    normal = np.array([np.sin(a), 0.0, np.cos(a)])
    camera = np.array([0.0, 0.0, 1.5])

    def angles(scan):
        ray = scan.points - camera
        cos = np.abs(ray @ normal) / np.linalg.norm(ray, axis=1)
        return np.degrees(np.arccos(cos))

    grazing_off = ScanConfig(**{**ONE.__dict__, "grazing_deg": 0.0})
    every = scan_garment(tilted, f, np.zeros(3), config=grazing_off, device="cpu")
    cut = scan_garment(tilted, f, np.zeros(3), config=ONE, device="cpu")
    assert angles(every).max() > 80.5 and 0 < len(cut.points) < len(every.points)
    assert angles(cut).max() < 80.0 + 1e-3


def test_a_hit_carries_warps_barycentrics_of_corners_0_and_1():
    from sim.device import warp
    from sim.scans import scanner_kernels as K

    wp = warp()
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], np.float32)
    mesh = wp.Mesh(points=wp.array(tri, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(np.arange(3, dtype=np.int32), dtype=wp.int32, device="cpu"))
    target = np.array([0.2, 0.5, 0.0])
    out = [wp.zeros(1, dtype=float), wp.zeros(1, dtype=int), wp.zeros(1, dtype=wp.vec2),
           wp.zeros(1, dtype=wp.vec3)]
    wp.launch(K.first_hits_kernel, dim=1, device="cpu",
              inputs=[mesh.id, mesh.id, 0, wp.array([target + [0, 0, 1]], dtype=wp.vec3, device="cpu"),
                      wp.array([[0.0, 0.0, -1.0]], dtype=wp.vec3, device="cpu"), 5.0], outputs=out)
    u, v = out[2].numpy()[0]
    np.testing.assert_allclose(u * tri[0] + v * tri[1] + (1 - u - v) * tri[2], target, atol=1e-6)
    assert out[0].numpy()[0] == pytest.approx(1.0)


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
