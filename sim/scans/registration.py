"""Non-rigid registration of a garment template to a scan (DeepWrinkles, Lähner et al. 2018,
Sec. 3.1, Eq. 1-2).

The template deforms by a grid (Sumner et al. 2007's embedded deformation on the corners of a
regular lattice): each node j of the cells holding template vertices carries an affine map
(A_j, t_j), and a vertex moves to ``Σ_j w_j (A_j (x - g_j) + g_j + t_j)`` with its cell's
trilinear weights. Iterated closest points with Gauss-Newton steps minimise Eq. 1,

    E_reg = E_data + ω_r E_rigid + ω_s E_smooth + ω_b E_bound,

E_data pulling each template vertex to its nearest scan point (pairs farther than
``max_distance`` dropped, and those whose normals' lines are more than 60 degrees apart: either
orientation, since a scan normal faces its camera and an inner layer seen through an opening
faces inwards), E_rigid keeping every A_j
a rotation (Σ of (a_k·a_l)² and (a_k·a_k - 1)² over its columns), E_smooth making neighbouring
nodes agree on where they carry each other, and E_bound pulling the template's border vertices
to the scan's marked border points chosen by Eq. 2: each scan border point is given to its
nearest template border vertex, and each template border vertex takes the farthest of the points
it was given (none: no pair), so the pairs spread along the whole border, folds included.
Lengths are in millimetres inside the solve, where the paper's weights (ω_r = ω_s = 500,
ω_b = 10) apply; the stiffness starts ``anneal`` times higher and halves each round.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from sim.errors import WrinklesInputError
from sim.garments.hems import boundary_vertices
from sim.geometry.frames import vertex_normals

MM = 1000.0
"""Millimetres per metre (the solve's length unit)."""


@dataclass(frozen=True)
class RegistrationConfig:
    """Settings of ``register``.

    Attributes:
        cell: grid spacing [m] of the deformation nodes.
        rigid, smooth, boundary: ω_r, ω_s, ω_b of Eq. 1 (lengths in mm).
        rounds: closest-point rounds; each re-pairs and takes ``steps`` Gauss-Newton steps
            (a tube bent 3 cm, scanned: 6 x 1 left 4.6 mm mean vertex error, 8 x 1 4.9 mm,
            8 x 2 4.9 mm at twice the time).
        steps: Gauss-Newton steps per round.
        anneal: the stiffness (ω_r, ω_s) of the first round over the last's; halves per round
            down to 1.
        max_distance: farthest data pair kept [m].
        edge: ω_e of a term that keeps the template's edge lengths, Σ_e (|x_a - x_b| - l_e)² over
            its mesh edges with l_e the starting template's (mm); 0: off (the paper's Eq. 1). The
            grid's rigidity acts on its nodes, so a weakly regularised template can stretch between
            them; this term holds the cloth's own lengths.
        use_boundary: include E_bound.
        point_to_plane: E_data measures each pair along the scan point's normal (the scan's
            point spacing does not bias it), plus ``point_weight`` times the full distance.
        point_weight: weight of the point-to-point part with ``point_to_plane``.
    """

    cell: float = 0.04
    rigid: float = 500.0
    smooth: float = 500.0
    boundary: float = 10.0
    rounds: int = 6
    steps: int = 1
    anneal: float = 16.0
    max_distance: float = 0.05
    edge: float = 0.0
    use_boundary: bool = True
    point_to_plane: bool = True
    point_weight: float = 0.1


@dataclass(frozen=True)
class _Grid:
    nodes: np.ndarray  # (J, 3) [mm]
    vertex_nodes: np.ndarray  # (V, 8) node index per cell corner
    weights: np.ndarray  # (V, 8) trilinear weights
    edges: np.ndarray  # (E, 2) neighbouring nodes along the axes


def _grid(x: np.ndarray, cell: float) -> _Grid:
    """The lattice nodes of the cells holding the points x [mm] (V, 3)."""
    lo = x.min(axis=0) - 1e-6
    rel = (x - lo) / cell
    base = np.floor(rel).astype(np.int64)
    frac = rel - base
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    keys = base[:, None, :] + corners[None]  # (V, 8, 3)
    dims = keys.reshape(-1, 3).max(axis=0) + 2
    flat = (keys[..., 0] * dims[1] + keys[..., 1]) * dims[2] + keys[..., 2]
    used, inverse = np.unique(flat.ravel(), return_inverse=True)
    w = np.prod(np.where(corners[None] == 1, frac[:, None, :], 1.0 - frac[:, None, :]), axis=2)
    ijk = np.stack([used // (dims[1] * dims[2]), (used // dims[2]) % dims[1], used % dims[2]], axis=1)
    index = {int(k): n for n, k in enumerate(used)}
    edges = []
    for axis, step in ((0, dims[1] * dims[2]), (1, dims[2]), (2, 1)):
        nb = used + step
        has = np.isin(nb, used) & (ijk[:, axis] + 1 < dims[axis])
        edges += [(n, index[int(k)]) for n, k in zip(np.flatnonzero(has), nb[has], strict=True)]
    return _Grid(nodes=ijk * cell + lo, vertex_nodes=inverse.reshape(-1, 8), weights=w,
                 edges=np.array(edges, np.int64).reshape(-1, 2))


def _deform(grid: _Grid, x: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Template vertices x [mm] (V, 3) under node params (J, 12) = (A row-major, t)."""
    a = params[:, :9].reshape(-1, 3, 3)[grid.vertex_nodes]  # (V, 8, 3, 3)
    g = grid.nodes[grid.vertex_nodes]
    moved = np.einsum("vkrc,vkc->vkr", a, x[:, None] - g) + g + params[grid.vertex_nodes, 9:]
    return np.einsum("vk,vkr->vr", grid.weights, moved)


def _linear_rows(point_nodes, point_weights, offsets, rows0):
    """COO entries of residuals Σ_k w_k (A_k d_k + t_k) per point and coordinate: rows rows0 +
    3 p + r; A_k[r, c] takes w_k d_k[c], t_k[r] takes w_k."""
    p, k = point_nodes.shape
    r = np.arange(3)
    rows = rows0 + 3 * np.arange(p)[:, None, None, None] + r[None, None, :, None]  # (p, k, 3, 1)
    a_cols = 12 * point_nodes[:, :, None, None] + 3 * r[None, None, :, None] + np.arange(3)[None, None, None]
    a_vals = point_weights[:, :, None, None] * offsets[:, :, None, :]  # (p, k, 1->3, 3)
    a_vals = np.broadcast_to(a_vals, (p, k, 3, 3))
    t_rows = np.broadcast_to(rows, (p, k, 3, 1))[..., 0]
    t_cols = 12 * point_nodes[:, :, None] + 9 + r[None, None, :]
    t_vals = np.broadcast_to(point_weights[:, :, None], (p, k, 3))
    return (np.concatenate([np.broadcast_to(rows, (p, k, 3, 3)).ravel(), t_rows.ravel()]),
            np.concatenate([a_cols.ravel(), t_cols.ravel()]),
            np.concatenate([a_vals.ravel(), t_vals.ravel()]))


def _rigid_rows(params: np.ndarray, rows0: int):
    """Residuals and COO Jacobian of Rot(A_j) per node: 6 rows a node."""
    a = params[:, :9].reshape(-1, 3, 3)
    cols = [a[:, :, 0], a[:, :, 1], a[:, :, 2]]
    pairs = [(0, 1), (0, 2), (1, 2), (0, 0), (1, 1), (2, 2)]
    res, rows, cc, vals = [], [], [], []
    n = len(a)
    for q, (k, l) in enumerate(pairs):
        dot = np.sum(cols[k] * cols[l], axis=1)
        res.append(dot - (1.0 if k == l else 0.0))
        row = rows0 + 6 * np.arange(n) + q
        for r in range(3):  # d(a_k·a_l)/dA[r, k] = a_l[r], /dA[r, l] = a_k[r] (twice when k == l)
            for col, other in ((k, cols[l]), (l, cols[k])):
                rows.append(row)
                cc.append(12 * np.arange(n) + 3 * r + col)
                vals.append(other[:, r])
    return (np.stack(res, axis=1).ravel(), np.concatenate(rows), np.concatenate(cc), np.concatenate(vals))


def boundary_pairs(template_border: np.ndarray, scan_border: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2: pairs (template border index, scan border index): each scan border point goes to its
    nearest template border point t, and t takes the farthest of the points it got."""
    if not len(template_border) or not len(scan_border):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    dist, owner = cKDTree(template_border).query(scan_border)
    order = np.lexsort((-dist, owner))  # by owner, the farthest first
    first = np.flatnonzero(np.r_[True, owner[order][1:] != owner[order][:-1]])
    return owner[order][first], order[first]


@dataclass(frozen=True)
class Registration:
    """A registered template.

    Attributes:
        vertices: the template's vertices on the scan [m], float32 (V, 3).
        data_rms: per round, the RMS distance [m] of the kept data pairs before its steps.
        pairs: data pairs kept in the last round.
        boundary_pairs: border pairs (Eq. 2) in the last round.
    """

    vertices: np.ndarray
    data_rms: tuple[float, ...]
    pairs: int
    boundary_pairs: int


def _system(grid: _Grid, x, params, data, bound, weights, point_weight: float = 1.0, edges=None):
    """Residuals and sparse Jacobian of Eq. 1 at ``params``: data (vertex index, target [mm],
    target normal or None: point-to-point only), bound (vertex index, target [mm]), weights
    (ω_r, ω_s, ω_b); with normals the data term is point-to-plane plus ``point_weight`` times
    point-to-point; ``edges`` (vertex pairs (E, 2), lengths [mm] (E,), ω_e) adds the edge-length
    term."""
    w_r, w_s, w_b = weights
    cur = _deform(grid, x, params)
    blocks, res, row = [], [], 0
    (d_idx, d_target, d_normal), (b_idx, b_target) = data, bound
    for idx, target, w, normal in ((d_idx, d_target, point_weight if d_normal is not None else 1.0, d_normal),
                                   (b_idx, b_target, w_b, None)):
        if not len(idx):
            continue
        nodes = grid.vertex_nodes[idx]
        r, c, v = _linear_rows(nodes, grid.weights[idx], x[idx][:, None] - grid.nodes[nodes], 0)
        blocks.append((row + r, c, np.sqrt(w) * v))
        res.append(np.sqrt(w) * (cur[idx] - target).ravel())
        row += 3 * len(idx)
        if normal is not None:  # point-to-plane: the same entries, each coordinate's row times n_r
            point, coord = r // 3, r % 3
            blocks.append((row + point, c, v * normal[point, coord]))
            res.append(np.sum((cur[idx] - target) * normal, axis=1))
            row += len(idx)
    if len(grid.edges):
        e = np.concatenate([grid.edges, grid.edges[:, ::-1]])
        j, k = e[:, 0], e[:, 1]
        a = params[:, :9].reshape(-1, 3, 3)
        off = grid.nodes[k] - grid.nodes[j]
        r_s = (np.einsum("erc,ec->er", a[j], off) + grid.nodes[j] + params[j, 9:]
               - grid.nodes[k] - params[k, 9:])
        nodes = np.stack([j, k], axis=1)
        r, c, v = _linear_rows(nodes, np.broadcast_to([1.0, -1.0], nodes.shape).copy(),
                               np.stack([off, np.zeros_like(off)], axis=1), row)
        blocks.append((r, c, np.sqrt(w_s) * v))
        res.append(np.sqrt(w_s) * r_s.ravel())
        row += 3 * len(e)
    if edges is not None:
        e_idx, e_len, w_e = edges
        d = cur[e_idx[:, 0]] - cur[e_idx[:, 1]]
        length = np.linalg.norm(d, axis=1)
        u = d / np.maximum(length, 1e-9)[:, None]
        nodes = np.concatenate([grid.vertex_nodes[e_idx[:, 0]], grid.vertex_nodes[e_idx[:, 1]]], axis=1)
        wts = np.concatenate([grid.weights[e_idx[:, 0]], -grid.weights[e_idx[:, 1]]], axis=1)
        offs = np.concatenate([x[e_idx[:, 0]][:, None] - grid.nodes[grid.vertex_nodes[e_idx[:, 0]]],
                               x[e_idx[:, 1]][:, None] - grid.nodes[grid.vertex_nodes[e_idx[:, 1]]]], axis=1)
        r, c, v = _linear_rows(nodes, wts, offs, 0)  # d(x_a - x_b), 3 rows an edge, along u
        point, coord = r // 3, r % 3
        blocks.append((row + point, c, np.sqrt(w_e) * v * u[point, coord]))
        res.append(np.sqrt(w_e) * (length - e_len))
        row += len(e_idx)
    r_r, r, c, v = _rigid_rows(params, row)
    blocks.append((r, c, np.sqrt(w_r) * v))
    res.append(np.sqrt(w_r) * r_r)
    row += len(r_r)
    rows, cols, vals = (np.concatenate([b[i] for b in blocks]) for i in range(3))
    jac = sp.csr_matrix((vals, (rows, cols)), shape=(row, params.size))
    return np.concatenate(res), jac


def _solve_spd(lhs, rhs: np.ndarray, device: str | None = None) -> np.ndarray:
    """Solve the Gauss-Newton normal equations (symmetric positive definite). On the host: SuperLU
    in symmetric mode on the minimum-degree ordering of A + Aᵀ, no pivoting off the diagonal (a
    5,304-unknown t-shirt system: 0.18 s against 0.52 s for the general LU with COLAMD; 0.89 s
    with the edge term's denser 2.9M non-zeros). With ``device`` a torch device ("cuda:0"; "cpu"
    works too, slower): a dense float64 Cholesky factor there (the matrix goes over as its
    non-zeros)."""
    if device is None:
        lu = splu(lhs, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        return lu.solve(rhs)
    import torch

    coo = lhs.tocoo()
    dev = torch.device(device)
    rows, cols = (torch.from_numpy(i.astype(np.int64)).to(dev) for i in (coo.row, coo.col))
    a = torch.zeros(coo.shape, dtype=torch.float64, device=dev)
    a.index_put_((rows, cols), torch.from_numpy(coo.data.astype(np.float64)).to(dev), accumulate=True)
    factor = torch.linalg.cholesky(a)
    b = torch.from_numpy(np.ascontiguousarray(rhs, np.float64)).to(dev)[:, None]
    return torch.cholesky_solve(b, factor)[:, 0].cpu().numpy()


def register(template: np.ndarray, faces: np.ndarray, scan, *, config: RegistrationConfig | None = None,
             solve_device: str | None = None) -> Registration:
    """Register ``template`` [m] (V, 3) (already near the scan, e.g. skinned to its pose), faces
    (F, 3), to ``scan`` (``sim.scans.scanner.Scan``: points, normals, border marks); the normal
    equations are solved on the host, or densely on ``solve_device`` (a CUDA torch device)."""
    cfg = config or RegistrationConfig()
    x = np.asarray(template, np.float64) * MM
    f = np.asarray(faces, np.int64)
    if (x.ndim != 2 or x.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0
            or f.min() < 0 or f.max() >= len(x)):
        raise WrinklesInputError(f"register: template {x.shape} and faces {f.shape} do not form a mesh")
    n = len(scan.points)
    if n == 0 or len(scan.normals) != n or len(scan.boundary) != n:
        raise WrinklesInputError(f"register: the scan needs points with one normal and one border mark "
                                 f"each; got {n}, {len(scan.normals)}, {len(scan.boundary)}")
    if cfg.cell <= 0 or cfg.max_distance <= 0:
        raise WrinklesInputError(f"register: cell {cfg.cell} m and max_distance {cfg.max_distance} m "
                                 "must be > 0")
    grid = _grid(x, cfg.cell * MM)
    params = np.tile(np.r_[np.eye(3).ravel(), 0.0, 0.0, 0.0], (len(grid.nodes), 1))
    pts = np.asarray(scan.points, np.float64) * MM
    tree = cKDTree(pts)
    border = boundary_vertices(f) if cfg.use_boundary else np.zeros(0, np.int64)
    scan_border = pts[np.asarray(scan.boundary, bool)]
    edges = None
    if cfg.edge > 0:
        from sim.quality import unique_edges

        e_idx = np.asarray(unique_edges(f), np.int64)
        edges = (e_idx, np.linalg.norm(x[e_idx[:, 0]] - x[e_idx[:, 1]], axis=1), cfg.edge)
    rms, kept, nb = [], 0, 0
    for rnd in range(cfg.rounds):
        stiff = max(cfg.anneal / 2.0 ** rnd, 1.0)
        cur = _deform(grid, x, params)
        dist, idx = tree.query(cur)
        agree = np.abs(np.sum(vertex_normals(cur, f, device="cpu") * scan.normals[idx], axis=1)) > 0.5
        keep = np.flatnonzero((dist < cfg.max_distance * MM) & agree)
        rms.append(float(np.sqrt(np.mean(dist[keep] ** 2))) / MM if len(keep) else float("nan"))
        t_idx, s_idx = boundary_pairs(cur[border], scan_border)
        normals = np.asarray(scan.normals, np.float64)[idx[keep]] if cfg.point_to_plane else None
        data, bound = (keep, pts[idx[keep]], normals), (border[t_idx], scan_border[s_idx])
        kept, nb = len(keep), len(t_idx)
        for _ in range(cfg.steps):
            res, jac = _system(grid, x, params, data, bound,
                               (cfg.rigid * stiff, cfg.smooth * stiff, cfg.boundary), cfg.point_weight, edges)
            lhs = (jac.T @ jac + 1e-6 * sp.identity(params.size)).tocsc()
            params = params + _solve_spd(lhs, -(jac.T @ res), solve_device).reshape(params.shape)
    return Registration(vertices=(_deform(grid, x, params) / MM).astype(np.float32), data_rms=tuple(rms),
                        pairs=kept, boundary_pairs=nb)
