"""A ring of virtual depth cameras around a dressed body: the garment as a 4D scanner sees it.

DeepWrinkles (Lähner et al. 2018, Sec. 3.1) registers a garment template to 4D scans: ~200k-point
surfaces with holes and noise, no correspondence to the template, the garment's boundaries
(hems, cuffs, neckline) marked in a distinguishable colour. ``scan_garment`` makes that input
from a simulated frame: pinhole cameras on horizontal rings around the body's vertical axis cast
one ray per pixel against the garment and the body (``scanner_kernels.first_hits_kernel``); a
pixel keeps the garment's point where the garment is the first surface it meets (the body, or
the garment itself, occludes the rest), unless the surface is seen at a grazing angle
(``ScanConfig.grazing_deg``: structured light returns nothing there) or the pixel drops out at
random (``dropout``). Depth noise is Gaussian along the ray. A point is a boundary point when it
lies within ``boundary_band`` of the garment's open border, as a coloured tape along the hems
would mark it. The points carry no reference to the garment's vertices or faces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sim.device import resolve_device, warp
from sim.errors import WrinklesInputError


@dataclass(frozen=True)
class ScanConfig:
    """The scanner.

    Attributes:
        cameras: cameras per ring, evenly spaced around the vertical (Y) axis.
        heights: each ring's height [m] relative to the body's root joint; its cameras look
            horizontally at the axis at that height.
        radius: distance [m] of the cameras from the vertical axis through the root.
        resolution: pixels (width, height) of each camera.
        fov_deg: vertical field of view [deg].
        noise: standard deviation [m] of the depth noise along each ray.
        dropout: share of pixels that return nothing at random (sensor holes).
        grazing_deg: rays meeting the surface closer than this to tangent [deg] return nothing.
        boundary_band: width [m] of the marked band along the garment's open border.
    """

    cameras: int = 8
    heights: tuple[float, ...] = (-0.45, 0.05, 0.55)
    radius: float = 1.8
    resolution: tuple[int, int] = (240, 320)
    fov_deg: float = 45.0
    noise: float = 0.001
    dropout: float = 0.02
    grazing_deg: float = 10.0
    boundary_band: float = 0.008

    def __post_init__(self):
        w, h = self.resolution
        if self.cameras < 1 or not self.heights or w < 1 or h < 1 or self.radius <= 0:
            raise WrinklesInputError(f"scan config: need cameras >= 1, some heights, a positive radius and "
                                     f"resolution; got {self.cameras}, {self.heights}, {self.radius}, "
                                     f"{self.resolution}")
        if (not 0 < self.fov_deg < 180 or self.noise < 0 or not 0 <= self.dropout < 1
                or self.boundary_band < 0 or not 0 <= self.grazing_deg < 90):
            raise WrinklesInputError("scan config: fov_deg in (0, 180), noise >= 0, dropout in [0, 1), "
                                     "boundary_band >= 0, grazing_deg in [0, 90)")


@dataclass(frozen=True)
class Scan:
    """Points of one scanned frame.

    Attributes:
        points: [m], float32 (N, 3).
        normals: unit surface normals facing the camera that saw each point, float32 (N, 3).
        boundary: the point lies in the marked band along the garment's open border, bool (N,).
        camera: index of the camera that saw each point, int32 (N,).
    """

    points: np.ndarray
    normals: np.ndarray
    boundary: np.ndarray
    camera: np.ndarray


def camera_rays(center: np.ndarray, cfg: ScanConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every camera's pixel rays: origins (N, 3), unit directions (N, 3), camera index (N,), for
    rings around the vertical axis through ``center`` [m] (3,). Pixel (row, col) of a camera
    looks through the centre of that pixel; row 0 is the top."""
    w, h = cfg.resolution
    f = 1.0 / np.tan(np.radians(cfg.fov_deg) / 2.0)
    xs = ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * (w / h)
    ys = 1.0 - (np.arange(h) + 0.5) / h * 2.0
    px, py = np.meshgrid(xs, ys)
    origins, dirs, cams = [], [], []
    for ring, dy in enumerate(cfg.heights):
        for k in range(cfg.cameras):
            a = 2.0 * np.pi * k / cfg.cameras
            fwd = -np.array([np.sin(a), 0.0, np.cos(a)])  # towards the axis
            right = np.array([np.cos(a), 0.0, -np.sin(a)])
            up = np.array([0.0, 1.0, 0.0])
            d = f * fwd + px[..., None] * right + py[..., None] * up
            dirs.append((d / np.linalg.norm(d, axis=-1, keepdims=True)).reshape(-1, 3))
            origins.append(np.broadcast_to(center + [0.0, dy, 0.0] - cfg.radius * fwd, (w * h, 3)))
            cams.append(np.full(w * h, ring * cfg.cameras + k, np.int32))
    return np.concatenate(origins), np.concatenate(dirs), np.concatenate(cams)


def border_distance(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Each vertex's distance [m] to the nearest vertex of the mesh's open border (edges of one
    face), float64 (V,); inf for a closed mesh."""
    from sim.garments.hems import boundary_vertices

    border = boundary_vertices(faces)
    if not len(border):
        return np.full(len(vertices), np.inf)
    return cKDTree(vertices[border]).query(vertices)[0]


def scan_garment(vertices: np.ndarray, faces: np.ndarray, center: np.ndarray, *,
                 body_vertices: np.ndarray | None = None, body_faces: np.ndarray | None = None,
                 config: ScanConfig | None = None, seed: int = 0, device: str | None = None) -> Scan:
    """What the camera ring sees of a garment frame (module docstring).

    Args:
        vertices: the garment [m], (V, 3); faces: (F, 3) int.
        center: the point the rings circle [m], (3,): the body's root joint.
        body_vertices, body_faces: the body [m] (occluder), or None.
        config: the scanner (``ScanConfig()``).
        seed: the noise's and the dropout's random draws.
        device: Warp device of the ray casts.
    """
    cfg = config or ScanConfig()
    wp = warp()
    d = resolve_device(device)
    v = np.ascontiguousarray(vertices, np.float32)
    f = np.ascontiguousarray(faces, np.int32)
    _check_mesh(v, f, "garment")
    origins, dirs, cams = camera_rays(np.asarray(center, np.float64).reshape(3), cfg)
    garment = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device=d),
                      indices=wp.array(f.ravel(), dtype=wp.int32, device=d))
    meshes = [garment]
    if (body_vertices is None) != (body_faces is None):
        raise WrinklesInputError("scan_garment: give the body's vertices and faces together")
    if body_vertices is not None:
        bv = np.ascontiguousarray(body_vertices, np.float32)
        bf = np.ascontiguousarray(body_faces, np.int32)
        _check_mesh(bv, bf, "body")
        meshes.append(wp.Mesh(points=wp.array(bv, dtype=wp.vec3, device=d),
                              indices=wp.array(bf.ravel(), dtype=wp.int32, device=d)))
    n = len(origins)
    t, face = wp.zeros(n, dtype=float, device=d), wp.zeros(n, dtype=int, device=d)
    bary, normal = wp.zeros(n, dtype=wp.vec2, device=d), wp.zeros(n, dtype=wp.vec3, device=d)
    wp.launch(_kernels().first_hits_kernel, dim=n,
              inputs=[garment.id, meshes[-1].id, int(len(meshes) > 1),
                      wp.array(origins.astype(np.float32), dtype=wp.vec3, device=d),
                      wp.array(dirs.astype(np.float32), dtype=wp.vec3, device=d),
                      float(4.0 * cfg.radius)],
              outputs=[t, face, bary, normal], device=d)
    hits = (t.numpy(), face.numpy(), bary.numpy(), normal.numpy())
    return _points(v, f, origins, dirs, cams, hits, cfg, seed)


def _check_mesh(v: np.ndarray, f: np.ndarray, what: str) -> None:
    if (v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0
            or f.min() < 0 or f.max() >= len(v)):
        raise WrinklesInputError(f"scan_garment: {what} vertices {v.shape} and faces {f.shape} "
                                 "do not form a mesh")


def _kernels():
    from sim.scans import scanner_kernels

    return scanner_kernels


def _points(v, f, origins, dirs, cams, hits, cfg: ScanConfig, seed: int) -> Scan:
    """The kept ``hits`` (distance, face, barycentrics, normal per ray) as a ``Scan``: grazing,
    dropped-out and empty pixels removed, depth noise along the ray, the boundary band from the
    hit's barycentric distance."""
    t, face, bary, normal = hits
    rng = np.random.default_rng(seed)
    n = normal.astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    cos = np.abs(np.sum(n * dirs, axis=1))
    keep = (face >= 0) & (cos > np.sin(np.radians(cfg.grazing_deg))) & (rng.random(len(face)) >= cfg.dropout)
    noise = rng.normal(scale=cfg.noise, size=len(face)) if cfg.noise > 0 else np.zeros(len(face))
    k = np.flatnonzero(keep)
    points = origins[k] + (t[k] + noise[k])[:, None] * dirs[k]
    w = np.stack([bary[k, 0], bary[k, 1], 1.0 - bary[k, 0] - bary[k, 1]], axis=1)
    dist = np.sum(border_distance(v.astype(np.float64), f)[f[face[k]]] * w, axis=1)
    facing = np.where(np.sum(n[k] * dirs[k], axis=1)[:, None] > 0, -n[k], n[k])
    return Scan(points=points.astype(np.float32), normals=facing.astype(np.float32),
                boundary=dist <= cfg.boundary_band, camera=cams[k].astype(np.int32))
