"""Geometric and physical metrics of garment meshes.

Accuracy against ground truth (Guo et al. 2024, Sec 4.1):

- :func:`vertex_error` ``Ev``: mean over vertices of the L2 distance ``|v_i - v̂_i|`` [m].
- :func:`chamfer_distance` ``Ecd``: symmetric *squared* Chamfer distance [m²],
  ``mean_a min_b |a - b|² + mean_b min_a |a - b|²``. This is Guo et al.'s Sec 4.1 definition
  word for word: each direction is a *mean* (1/|V| Σ) of *squared* L2 nearest-neighbour
  distances, and the two directions are *summed* (not averaged). Their Table 1 reports it in
  10⁻⁴ m², consistent with squared distances in metres.

Physical plausibility (GSNet Sec 4.3, which uses "the same metrics as the state-of-the-art
approaches", i.e. DeePSD/PBNS: Euclidean error, edge elongation/compression, bending, collision
rate):

- :func:`edge_elongation`: statistics of the edge stretch ratio ``l / l0`` against the rest
  mesh (:class:`EdgeStats`; ``abs_length_mean`` is DeePSD's "edge elongation", mean
  ``|l - l0|`` [m]).
- :func:`bending_angles` / :func:`bending_error`: angle [rad] between the unit normals of the
  two faces of every interior edge, and its mean absolute error against ground truth. GSNet's
  text says "bending angle between vertex normals"; :func:`vertex_normal_angles` gives that
  variant (angle between the area-weighted vertex normals of the two ends of each edge, the
  quantity DeePSD's bending metric, mean ``1 - n_i·n_j``, is built on).
- :func:`collision_rate`: fraction of garment vertices inside the closed body mesh (Warp mesh
  queries, :func:`sim.quality.inside_fraction`).

All functions take torch tensors (cpu or cuda) or numpy arrays, allow leading batch dims
``...`` unless stated, and reduce in float64. Results are float64 tensors on the input's device.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from sim.errors import WrinklesInputError


def as_tensor(x, *, device: torch.device | str | None = None,
              dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """A torch tensor of ``x`` (tensor, numpy array or nested sequence) as ``dtype``.

    Args:
        x: the data; a tensor keeps its device unless ``device`` is given.
        device: target device; None keeps the tensor's (cpu for numpy input).
        dtype: target floating dtype (float64 by default: metrics reduce in double precision).
    """
    if not isinstance(x, torch.Tensor):
        a = np.asarray(x)
        if not (a.flags.writeable and a.flags.c_contiguous):  # torch wants writeable, positive strides
            a = np.array(a, order="C", copy=True)
        x = torch.from_numpy(a)
    return x.to(device=x.device if device is None else device, dtype=dtype)


def _check_points(x: torch.Tensor, what: str) -> None:
    if x.ndim < 2 or x.shape[-1] != 3:
        raise WrinklesInputError(f"{what} must have shape (..., V, 3), got {tuple(x.shape)}")


def vertex_error(pred, target) -> torch.Tensor:
    """``Ev``: mean over vertices of the L2 vertex distance (Guo et al. 2024, Sec 4.1).

    Args:
        pred: predicted positions [m], shape (..., V, 3).
        target: ground-truth positions [m], shape (..., V, 3) (broadcastable), same vertex order.

    Returns:
        Mean distance [m], float64, shape (...).
    """
    p = as_tensor(pred)
    t = as_tensor(target, device=p.device)
    _check_points(p, "pred")
    _check_points(t, "target")
    if p.shape[-2] != t.shape[-2]:
        raise WrinklesInputError(f"pred has {p.shape[-2]} vertices, target {t.shape[-2]}")
    return torch.linalg.vector_norm(p - t, dim=-1).mean(dim=-1)


def _nearest_blocked(a: torch.Tensor, b: torch.Tensor, chunk: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Index of the nearest point of ``b`` for each point of ``a`` and vice versa (brute force).

    ``a`` (Na, 3), ``b`` (Nb, 3) float64. Squared distances come in blocks of at most
    chunk x chunk pairs from the expanded form |a|² + |b|² - 2 a·b about the common centroid
    (float64 keeps its cancellation error ~1e-16 of the squared extent).
    """
    c = 0.5 * (a.mean(dim=0) + b.mean(dim=0))
    a, b = a - c, b - c
    a2, b2 = (a * a).sum(-1), (b * b).sum(-1)
    best_b = torch.full((b.shape[0],), float("inf"), dtype=a.dtype, device=a.device)
    arg_b = torch.zeros(b.shape[0], dtype=torch.long, device=a.device)
    arg_a = torch.zeros(a.shape[0], dtype=torch.long, device=a.device)
    for i in range(0, a.shape[0], chunk):
        ai = a[i:i + chunk]
        best_a = torch.full((ai.shape[0],), float("inf"), dtype=a.dtype, device=a.device)
        for j in range(0, b.shape[0], chunk):
            bj = b[j:j + chunk]
            d = torch.addmm(a2[i:i + chunk, None] + b2[None, j:j + chunk], ai, bj.T, alpha=-2.0)
            dmin, idx = d.min(dim=1)
            better = dmin < best_a
            best_a = torch.where(better, dmin, best_a)
            arg_a[i:i + chunk] = torch.where(better, idx + j, arg_a[i:i + chunk])
            cmin, cidx = d.min(dim=0)
            better = cmin < best_b[j:j + chunk]
            best_b[j:j + chunk] = torch.where(better, cmin, best_b[j:j + chunk])
            arg_b[j:j + chunk] = torch.where(better, cidx + i, arg_b[j:j + chunk])
    return arg_a, arg_b


def _nearest_kdtree(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """As :func:`_nearest_blocked`, by scipy's k-d tree on the cpu (exact, O(N log N))."""
    from scipy.spatial import cKDTree

    an, bn = a.detach().cpu().numpy(), b.detach().cpu().numpy()
    _, ia = cKDTree(bn).query(an, workers=-1)
    _, ib = cKDTree(an).query(bn, workers=-1)
    return torch.from_numpy(ia).to(a.device), torch.from_numpy(ib).to(a.device)


CHAMFER_METHODS = ("auto", "kdtree", "blocked")
"""Nearest-neighbour searches of :func:`chamfer_distance`: ``kdtree`` (scipy, cpu), ``blocked``
(brute force in torch, on the input's device), ``auto`` (kdtree for cpu tensors, else blocked)."""


def chamfer_distance(a, b, *, chunk: int = 4096, method: str = "auto") -> torch.Tensor:
    """``Ecd``: symmetric squared Chamfer distance (Guo et al. 2024, Sec 4.1).

    ``Ecd = 1/|A| Σ_a min_b |a - b|² + 1/|B| Σ_b min_a |a - b|²`` (means of squared
    nearest-neighbour distances, summed over the two directions; see the module docstring).

    Memory stays bounded: the ``blocked`` search forms squared distances in blocks of
    ``chunk x chunk`` point pairs (4096² float64 = 134 MB), so 30k-point meshes never build a
    30k x 30k matrix; on the cpu the ``kdtree`` search is used by default. Either way each
    nearest neighbour's squared distance is then recomputed exactly as ``|a - b|²``.

    Args:
        a: points [m], shape (..., Na, 3).
        b: points [m], shape (..., Nb, 3), batch dims equal to ``a``'s (or broadcastable).
        chunk: block side (points) of the ``blocked`` search.
        method: nearest-neighbour search, one of :data:`CHAMFER_METHODS`.

    Returns:
        Chamfer distance [m²], float64, shape (...).
    """
    if chunk < 1:
        raise ValueError(f"chunk must be >= 1, got {chunk}")
    if method not in CHAMFER_METHODS:
        raise ValueError(f"method must be one of {CHAMFER_METHODS}, got {method!r}")
    A = as_tensor(a)
    B = as_tensor(b, device=A.device)
    _check_points(A, "a")
    _check_points(B, "b")
    if A.shape[-2] == 0 or B.shape[-2] == 0:
        raise WrinklesInputError("chamfer_distance needs at least one point in each set")
    if method == "auto":
        method = "kdtree" if A.device.type == "cpu" else "blocked"
    batch = torch.broadcast_shapes(A.shape[:-2], B.shape[:-2])
    A = A.expand(*batch, *A.shape[-2:]).reshape(-1, *A.shape[-2:])
    B = B.expand(*batch, *B.shape[-2:]).reshape(-1, *B.shape[-2:])
    out = torch.empty(A.shape[0], dtype=torch.float64, device=A.device)
    for k in range(A.shape[0]):
        if method == "kdtree":
            ia, ib = _nearest_kdtree(A[k], B[k])
        else:
            ia, ib = _nearest_blocked(A[k], B[k], chunk)
        da = ((A[k] - B[k][ia]) ** 2).sum(-1).mean()
        db = ((B[k] - A[k][ib]) ** 2).sum(-1).mean()
        out[k] = da + db
    return out.reshape(batch)


def mesh_edges(faces) -> np.ndarray:
    """Undirected edges of a triangle mesh, each once with i < j, shape (E, 2), int32.

    Same order as :func:`sim.quality.unique_edges` (it is that function).
    """
    from sim.quality import unique_edges

    f = np.asarray(faces.cpu() if isinstance(faces, torch.Tensor) else faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise WrinklesInputError(f"faces must have shape (F, 3), got {f.shape}")
    return unique_edges(f)


def _index(idx, device: torch.device) -> torch.Tensor:
    t = idx if isinstance(idx, torch.Tensor) else torch.as_tensor(np.asarray(idx))
    return t.to(device=device, dtype=torch.long)


def edge_lengths(vertices, edges) -> torch.Tensor:
    """Length of every edge.

    Args:
        vertices: positions [m], shape (..., V, 3).
        edges: vertex index pairs, shape (E, 2).

    Returns:
        Lengths [m], float64, shape (..., E).
    """
    x = as_tensor(vertices)
    _check_points(x, "vertices")
    e = _index(edges, x.device)
    return torch.linalg.vector_norm(x[..., e[:, 1], :] - x[..., e[:, 0], :], dim=-1)


@dataclass(frozen=True)
class EdgeStats:
    """Edge stretch statistics against the rest mesh, each float64 of shape (...).

    With the stretch ratio ``r = l / l0`` of each edge:

    Attributes:
        elongation_mean: mean over edges of ``max(r - 1, 0)`` [-].
        compression_mean: mean over edges of ``max(1 - r, 0)`` [-].
        abs_mean: mean over edges of ``|r - 1|`` [-] (= elongation_mean + compression_mean).
        max_abs: max over edges of ``|r - 1|`` [-].
        abs_length_mean: mean over edges of ``|l - l0|`` [m] (DeePSD's "edge elongation" metric,
            which GSNet Sec 4.3 reports).
    """

    elongation_mean: torch.Tensor
    compression_mean: torch.Tensor
    abs_mean: torch.Tensor
    max_abs: torch.Tensor
    abs_length_mean: torch.Tensor


def edge_elongation(vertices, rest_vertices, edges) -> EdgeStats:
    """Edge elongation / compression against the rest shape (GSNet Sec 4.3).

    Args:
        vertices: positions [m], shape (..., V, 3).
        rest_vertices: rest positions [m], shape (V, 3) or broadcastable to ``vertices``.
        edges: vertex index pairs (E, 2), e.g. :func:`mesh_edges` ``(faces)``.

    Returns:
        :class:`EdgeStats`.
    """
    l = edge_lengths(vertices, edges)
    l0 = edge_lengths(as_tensor(rest_vertices, device=l.device), edges)
    if (l0 <= 0).any():
        raise WrinklesInputError("rest mesh has zero-length edges")
    s = l / l0 - 1.0
    return EdgeStats(
        elongation_mean=s.clamp(min=0).mean(-1),
        compression_mean=(-s).clamp(min=0).mean(-1),
        abs_mean=s.abs().mean(-1),
        max_abs=s.abs().amax(-1),
        abs_length_mean=(l - l0).abs().mean(-1),
    )


def _cross_faces(x: torch.Tensor, faces) -> torch.Tensor:
    f = _index(faces, x.device)
    if f.ndim != 2 or f.shape[1] != 3:
        raise WrinklesInputError(f"faces must have shape (F, 3), got {tuple(f.shape)}")
    p0, p1, p2 = x[..., f[:, 0], :], x[..., f[:, 1], :], x[..., f[:, 2], :]
    return torch.linalg.cross(p1 - p0, p2 - p0, dim=-1)


def face_normals(vertices, faces) -> torch.Tensor:
    """Unit normals of triangles (counter-clockwise winding seen from the normal's side).

    Args:
        vertices: positions [m], shape (..., V, 3).
        faces: (F, 3) int.

    Returns:
        Unit normals, float64, shape (..., F, 3) (zero for degenerate triangles).
    """
    x = as_tensor(vertices)
    _check_points(x, "vertices")
    n = _cross_faces(x, faces)
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True).clamp(min=1e-300)


def interior_edges(faces) -> np.ndarray:
    """Pairs of faces that share an edge (the hinges of the bending metric).

    Built once per topology. Boundary edges (one face) have no pair; non-manifold edges (more
    than two faces) are skipped, like ``sim.cloth.topology.build_hinges``.

    Args:
        faces: (F, 3) int.

    Returns:
        Face index pairs (E, 2), int64, ``[f0, f1]`` with f0 < f1, sorted by edge (i < j).
    """
    f = np.asarray(faces.cpu() if isinstance(faces, torch.Tensor) else faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise WrinklesInputError(f"faces must have shape (F, 3), got {f.shape}")
    F = f.shape[0]
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e.sort(axis=1)
    face = np.tile(np.arange(F), 3)
    order = np.lexsort((face, e[:, 1], e[:, 0]))
    e, face = e[order], face[order]
    _, start, count = np.unique(e, axis=0, return_index=True, return_counts=True)
    two = start[count == 2]
    return np.stack([face[two], face[two + 1]], axis=1)


def _angle(n0: torch.Tensor, n1: torch.Tensor) -> torch.Tensor:
    """Angle [rad] in [0, π] between vectors, via atan2(|n0 x n1|, n0·n1) (accurate near 0 and π)."""
    c = torch.linalg.vector_norm(torch.linalg.cross(n0, n1, dim=-1), dim=-1)
    return torch.atan2(c, (n0 * n1).sum(-1))


def bending_angles(vertices, faces, *, pairs=None) -> torch.Tensor:
    """Angle between the unit normals of adjacent faces (GSNet Sec 4.3, bending).

    0 for a flat hinge, θ for a hinge folded by θ out of plane (π - the interior dihedral
    angle). Unsigned, in [0, π].

    Args:
        vertices: positions [m], shape (..., V, 3).
        faces: (F, 3) int.
        pairs: face pairs from :func:`interior_edges` ``(faces)`` (pass it to avoid rebuilding).

    Returns:
        Angles [rad], float64, shape (..., E).
    """
    p = _index(interior_edges(faces) if pairs is None else pairs, as_tensor(vertices).device)
    n = face_normals(vertices, faces)
    return _angle(n[..., p[:, 0], :], n[..., p[:, 1], :])


def bending_error(pred, target, faces, *, pairs=None) -> torch.Tensor:
    """Mean absolute difference of the bending angles of two meshes of one topology.

    Args:
        pred: predicted positions [m], shape (..., V, 3).
        target: ground-truth positions [m], shape (..., V, 3).
        faces: (F, 3) int.
        pairs: face pairs from :func:`interior_edges` (optional, rebuilt when None).

    Returns:
        Mean |angle_pred - angle_target| over interior edges [rad], float64, shape (...).
    """
    p = interior_edges(faces) if pairs is None else pairs
    a = bending_angles(pred, faces, pairs=p)
    b = bending_angles(target, faces, pairs=p).to(a.device)
    return (a - b).abs().mean(-1)


def vertex_normals(vertices, faces) -> torch.Tensor:
    """Unit area-weighted vertex normals (zero where incident faces cancel).

    Args:
        vertices: positions [m], shape (..., V, 3).
        faces: (F, 3) int.

    Returns:
        Unit normals, float64, shape (..., V, 3).
    """
    x = as_tensor(vertices)
    _check_points(x, "vertices")
    c = _cross_faces(x, faces)  # 2 x area x unit normal
    f = _index(faces, x.device)
    n = torch.zeros_like(x)
    for k in range(3):
        n = n.index_add(-2, f[:, k], c)
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True).clamp(min=1e-300)


def vertex_normal_angles(vertices, faces, *, edges=None) -> torch.Tensor:
    """Angle between the vertex normals at the two ends of each edge (GSNet Sec 4.3's wording).

    Args:
        vertices: positions [m], shape (..., V, 3).
        faces: (F, 3) int.
        edges: (E, 2) vertex pairs; None: :func:`mesh_edges` ``(faces)``.

    Returns:
        Angles [rad], float64, shape (..., E).
    """
    n = vertex_normals(vertices, faces)
    e = _index(mesh_edges(faces) if edges is None else edges, n.device)
    return _angle(n[..., e[:, 0], :], n[..., e[:, 1], :])


def collision_rate(vertices, body_vertices, body_faces, *, device: str | None = None) -> np.ndarray:
    """Per frame, the fraction of garment vertices inside the closed body mesh (GSNet Sec 4.3).

    Uses Warp mesh queries (:func:`sim.quality.inside_fraction`: sign of the angle-weighted
    pseudo-normal at the closest body point), so the body must be closed and outward wound.

    Args:
        vertices: garment positions [m], shape (T, V, 3) (or (V, 3): one frame).
        body_vertices: body positions [m], shape (T, Vb, 3) or (Vb, 3) (static body).
        body_faces: (Fb, 3) int, outward wound.
        device: Warp device (None: cuda when present, else cpu).

    Returns:
        Fractions in [0, 1], numpy float64, shape (T,).
    """
    from sim.quality import inside_fraction

    def _np(x):
        return np.asarray(x.detach().cpu() if isinstance(x, torch.Tensor) else x)

    x = _np(vertices).astype(np.float32)
    if x.ndim == 2:
        x = x[None]
    if x.ndim != 3 or x.shape[-1] != 3:
        raise WrinklesInputError(f"vertices must have shape (T, V, 3), got {x.shape}")
    bv = _np(body_vertices).astype(np.float32)
    if bv.ndim not in (2, 3) or bv.shape[-1] != 3 or (bv.ndim == 3 and bv.shape[0] != x.shape[0]):
        raise WrinklesInputError(f"body_vertices must have shape ({x.shape[0]}, Vb, 3) or (Vb, 3), "
                                 f"got {bv.shape}")
    bf = _np(body_faces).astype(np.int32)
    return np.asarray(inside_fraction(x, bv, bf, device=device), dtype=np.float64)
