"""Plain-torch reference implementations of every physics loss term (tests, documentation).

Each function is the same energy as its Warp-backed module in ``learn.losses.physics``, written
with dense batched torch ops so that it runs in any dtype (float64 for finite differences and
``gradcheck``) and differentiates with torch's autograd. Positions ``x`` [m] are (B, V, 3); every
function returns the per-sample energy (B,). Slower and hungrier than the Warp terms (it
materialises (B, F, 3, 2) deformation gradients, and the collision search is a dense
``torch.cdist`` per sample), but obviously correct.
"""

from __future__ import annotations

import numpy as np
import torch

from sim.losses.topology import GarmentTopology


def _long(a: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a, dtype=np.int64), device=device)


def _real(a: np.ndarray, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), device=like.device).to(like.dtype)


def membrane_energy(x: torch.Tensor, topology: GarmentTopology, mu: float, lam: float) -> torch.Tensor:
    """StVK membrane energy [J]: ``sum_t n_t A_t (mu |G|_F^2 + lam/2 tr(G)^2)``, ``G = (F^T F - I)/2``,
    ``F = [x1 - x0, x2 - x0] Dm^-1`` (3x2); Lamé ``mu, lam`` [N/m]; ``n_t`` the face's layers."""
    f = _long(topology.faces, x.device)
    x0, x1, x2 = x[:, f[:, 0]], x[:, f[:, 1]], x[:, f[:, 2]]
    ds = torch.stack([x1 - x0, x2 - x0], dim=-1)  # (B, F, 3, 2)
    F = ds @ _real(topology.dm_inv, x)  # (B, F, 3, 2)
    eye = torch.eye(2, dtype=x.dtype, device=x.device)
    G = 0.5 * (F.transpose(-1, -2) @ F - eye)
    tr = G[..., 0, 0] + G[..., 1, 1]
    psi = mu * (G * G).sum(dim=(-1, -2)) + 0.5 * lam * tr * tr
    return (psi * _real(topology.areas * topology.face_layers, x)).sum(dim=-1)


def dihedral_angles(x: torch.Tensor, hinges: torch.Tensor) -> torch.Tensor:
    """Signed dihedral angles [rad] of hinges ``(o0, o1, a, b)`` (``sim.cloth.energies`` layout), (B, H)."""
    xo0, xo1, xa, xb = (x[:, hinges[:, k]] for k in range(4))
    e = xb - xa
    na = torch.linalg.cross(e, xo0 - xa)
    nb = torch.linalg.cross(xa - xb, xo1 - xb)
    na = na / na.norm(dim=-1, keepdim=True)
    nb = nb / nb.norm(dim=-1, keepdim=True)
    en = e / e.norm(dim=-1, keepdim=True)
    return torch.atan2((torch.linalg.cross(na, nb) * en).sum(-1), (na * nb).sum(-1))


def bending_energy(x: torch.Tensor, topology: GarmentTopology, bending: float) -> torch.Tensor:
    """Hinge bending energy [J]: ``sum_h k_b factor_h / 2 (theta_h - theta0_h)^2`` (``k_b`` [N m])."""
    h = _long(topology.hinges, x.device)
    d = dihedral_angles(x, h) - _real(topology.hinge_rest_angles, x)
    k = bending * _real(topology.hinge_factors, x)
    return (0.5 * k * d * d).sum(dim=-1)


def inertia_energy(x: torch.Tensor, x_prev: torch.Tensor, x_prev2: torch.Tensor, topology: GarmentTopology,
                   density: float, dt: float) -> torch.Tensor:
    """Inertia [J]: ``sum_v m_v / (2 dt^2) |x - 2 x_prev + x_prev2|^2``, ``m_v = density * vertex area``."""
    m = density * _real(topology.vertex_areas, x)
    a = x - 2.0 * x_prev + x_prev2
    return (m * (a * a).sum(-1)).sum(-1) / (2.0 * dt * dt)


def gravity_energy(x: torch.Tensor, topology: GarmentTopology, density: float,
                   gravity: tuple[float, float, float] = (0.0, -9.81, 0.0)) -> torch.Tensor:
    """Gravitational potential energy [J]: ``-sum_v m_v g . x_v``."""
    m = density * _real(topology.vertex_areas, x)
    g = torch.as_tensor(gravity, dtype=x.dtype, device=x.device)
    return -(m * (x * g).sum(-1)).sum(-1)


def edge_energy(x: torch.Tensor, topology: GarmentTopology) -> torch.Tensor:
    """GSNet Eq. 6 [m^2]: ``sum_e (|x_a - x_b| - l_e)^2`` over unique edges."""
    e = _long(topology.edges, x.device)
    length = (x[:, e[:, 1]] - x[:, e[:, 0]]).norm(dim=-1)
    d = length - _real(topology.rest_edge_lengths, x)
    return (d * d).sum(-1)


def vertex_normals(x: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Unit area-weighted vertex normals (B, V, 3) (zero for vertices without area)."""
    x0, x1, x2 = x[:, faces[:, 0]], x[:, faces[:, 1]], x[:, faces[:, 2]]
    c = torch.linalg.cross(x1 - x0, x2 - x0)
    acc = torch.zeros_like(x)
    for k in range(3):
        acc = acc.index_add(1, faces[:, k], c)
    return _safe_normalize(acc)


def _safe_normalize(v: torch.Tensor) -> torch.Tensor:
    n = v.norm(dim=-1, keepdim=True)
    ok = n > 1e-20
    return torch.where(ok, v / torch.where(ok, n, torch.ones_like(n)), torch.zeros_like(v))


def gsnet_bending_energy(x: torch.Tensor, topology: GarmentTopology, weight: float = 1.0) -> torch.Tensor:
    """GSNet Eq. 7 [-]: ``weight * sum_v |(L n)_v|^2`` with the uniform Laplacian
    ``(L n)_i = 1/deg(i) sum_{j ~ i} (n_j - n_i)`` of unit vertex normals."""
    f = _long(topology.faces, x.device)
    e = _long(topology.edges, x.device)
    n = vertex_normals(x, f)
    d = n[:, e[:, 1]] - n[:, e[:, 0]]
    w = _real(topology.inv_degree, x)
    lap = torch.zeros_like(n)
    lap = lap.index_add(1, e[:, 0], d * w[e[:, 0], None])
    lap = lap.index_add(1, e[:, 1], -d * w[e[:, 1], None])
    return weight * (lap * lap).sum(dim=(-1, -2))


def body_anchors(body_vertices: torch.Tensor, body_faces: np.ndarray, anchor: str = "vertex"
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """Anchor points and unit outward normals of each body: vertices with area-weighted vertex
    normals (``"vertex"``) or face centroids with face normals (``"face"``); (B, N, 3) each."""
    f = _long(body_faces, body_vertices.device)
    if anchor == "vertex":
        return body_vertices, vertex_normals(body_vertices, f)
    x0, x1, x2 = (body_vertices[:, f[:, k]] for k in range(3))
    return (x0 + x1 + x2) / 3.0, _safe_normalize(torch.linalg.cross(x1 - x0, x2 - x0))


def collision_energy(x: torch.Tensor, body_vertices: torch.Tensor, body_faces: np.ndarray, *,
                     stiffness: float, eps: float, power: float, anchor: str = "vertex") -> torch.Tensor:
    """Collision penalty [J]: ``sum_v k max(eps - (x_v - p_v) . n_v, 0)^power`` with ``p_v, n_v``
    the nearest anchor (dense ``cdist`` search, not differentiated) and its normal."""
    pts, nrm = body_anchors(body_vertices.detach(), body_faces, anchor)
    # one sample at a time: the distance matrix is (V, anchors), not (B, V, anchors)
    idx = torch.stack([torch.cdist(xb, pb).argmin(dim=-1) for xb, pb in zip(x.detach(), pts, strict=True)])
    g = idx[..., None].expand(-1, -1, 3)
    p = torch.gather(pts, 1, g)
    n = torch.gather(nrm, 1, g)
    pen = torch.clamp(eps - ((x - p) * n).sum(-1), min=0.0)
    valid = (n * n).sum(-1) > 0.25
    return (stiffness * torch.where(valid, pen, torch.zeros_like(pen)) ** power).sum(-1)
