"""Deform a base mesh so that its surface follows a normal map (Guo et al. 2024, Eq. 10, after DDE).

Guo et al. turn the normal maps of DeepWrinkles and DDE into geometry by deforming the base mesh
v0 to minimise

    E(v) = Σ_v Σ_{p ∈ N(v)} (n_v · (v − p) / ‖v − p‖)²  +  λ_l Σ_v ‖Δv‖²  +  λ_r Σ_v ‖v − v0‖²   (Eq. 10)

with n_v the target unit normal of vertex v (the normal map sampled there) and N(v) its one-ring:
every edge should lie in the target tangent planes, the surface should stay smooth and near v0.

Solution. The energy (Eq. 10, or the variant the defaults choose below) is a sum of squares that
is nonlinear only through ‖v − p‖: it is minimised by Gauss-Newton, a short sequence of sparse
linear least-squares problems, each with the edge lengths and directions frozen at the previous
iterate (the first at the base). The residual r = m · ê of an edge (m a target normal, ê the
unit edge) is linearised as r_k + (m − r_k ê_k) · (e − e_k) / ‖e_k‖: the derivative of 1 / ‖e‖
is kept, so scaling an edge changes nothing, as in E. A step that raises E is halved (up to
``BACKTRACKS`` times). Every problem is solved through its normal equations, a sparse symmetric
positive definite system (sparse LU, SuperLU in symmetric mode); the Laplacian and
regularisation part is built once.

What is solved, and why. Measured as the RMS distance of the vertices to their true positions
(Guo et al.'s E_v averages the distances instead; the base's own in brackets) on: a flat
jittered grid, 10 mm edges, with a Gaussian bump 4 mm high, σ = 30 mm (0.52 mm); a jittered
sleeve, R = 6 cm, ~6.6 mm edges, with ring and oblique folds of 3 mm at 3.5-4.2 cm (1.52 mm);
the same grid folded 90° along a line, with folds across the crease (1.51 mm); and a
5,746-vertex t-shirt (12 mm edges, its rest shape smoothed by ``smooth_base``) with 3 mm folds
of 4-5 cm along its normals (1.53 mm). Normals exact (the wrinkled surface's vertex normals), or
with 3° of per-vertex noise.

- ``normal_term="edge"`` (default): each edge is held against the mean of its two end normals,
  m = (n_a + n_b) / ‖n_a + n_b‖, counted twice, as Eq. 10 counts an edge once from each end. On a
  curved surface the chord from v to a neighbour is not perpendicular to n_v (it is off by half
  the bend along the edge), so Eq. 10's per-vertex term ("vertex") is not zero on the true
  surface and biases its minimiser; the mean normal is perpendicular to the chord to second
  order in the edge length. "vertex" / "edge": sleeve 0.81 / 0.20 mm, crease 0.60 / 0.45 mm,
  t-shirt 0.75 / 0.69 mm (bump 0.14 mm both).
- ``relative=True`` (default): each residual is measured from the base's own, m0 · ê0 with m0 from
  the base's vertex normals, so the base's own normals give back the base exactly, and the
  normal map acts as a change of the base's normals (as a tangent-space map is). Vertex normals
  at a crease are not perpendicular to the crease's edges: from zero, the base's own normals
  move the creased grid up to 2.7 mm and the t-shirt up to 2.9 mm. From zero / relative: crease
  0.87 / 0.45 mm, t-shirt 0.98 / 0.69 mm, sleeve 0.19 / 0.20 mm.
- ``directions="normal"`` (default): every vertex moves along its base vertex normal,
  v = v0 + s_v n0_v. The normal term hardly resists sliding along the surface, which only the
  regulariser holds in the 3D solve ("free"): "free" / "normal", sleeve 0.40 / 0.20 mm, with 3°
  noise 1.28 / 0.39 mm, the bump with 3° noise 1.36 / 0.41 mm, t-shirt 0.75 / 0.69 mm. "normal"
  has V unknowns instead of 3V: ~0.2 s against ~3 s on the t-shirt (two steps, one core).
- ``smooth="displacement"`` (default): the Laplacian term is ‖Δ(v − v0)‖², not Eq. 10's ‖Δv‖².
  ‖Δv‖² is not zero on the base (on a curved part Δv lies along the mean-curvature normal, at a
  boundary it points across the border), so it moves the base by an amount set by λ_l, not by
  the normals: with its own normals at c_l = 10, the sleeve's radius changes by 0.6 mm on
  average, and the t-shirt moves up to 1.8 (c_l = 1) and 4.8 mm (c_l = 10). At c_l = 1 (10),
  "position" / "displacement": t-shirt 0.91 (1.55) / 0.73 (0.97) mm, sleeve 0.22 (0.77) /
  0.23 (0.44) mm.
- ``laplacian="cotangent"`` (default): Δ normalised per row, Δu = u − Σ w_p u_p / Σ w_p with the
  clamped cotangent weights of ``cotangent_stiffness``: zero on displacements linear over a flat
  patch whatever the triangle shapes, which the uniform graph Laplacian (w = 1) is not on an
  irregular mesh. Sleeve at c_l = 1 (10): cotangent 0.23 (0.44) mm, uniform 0.25 (0.55) mm;
  t-shirt equal.
- Eq. 10 exactly as printed ("vertex", "free", "position", relative=False, same weights and
  steps) is worse than the base on all four: bump 1.87, sleeve 3.47, crease 3.73, t-shirt
  5.07 mm.
- Gauss-Newton rather than frozen lengths alone: with 1 / ‖e‖ frozen, the linear problem is
  smaller for shorter edges, so the residual that noisy normals leave shrinks curved parts: the
  sleeve with 3° (6°) noise, measured from zero, c_l = 0: 0.55 (1.57) mm frozen, 0.38 (0.70) mm
  Gauss-Newton. Two steps converge on the test surfaces and the t-shirt (the default; a third
  changes the energy by < 1e-5).

Weights and scale. The normal term is dimensionless per edge; ‖Δd‖² and ‖v − v0‖² carry length².
The weights are set relative to the base's mean edge length h̄: λ_l = laplacian_weight / h̄²,
λ_r = regularization_weight / h̄², so they mean the same on 5-30 mm meshes and the result scales
with the mesh (deform(s v0) = s deform(v0)). On a plane, a height field z then costs about
3 ‖∇z‖² + c_r (z / h̄)² per vertex: the normals fix z up to the regulariser, which screens waves
longer than ℓ = h̄ √(3 / c_r) (17 edges at c_r = 0.01): a wavelength λ keeps 1 / (1 + (λ / 2πℓ)²)
of its amplitude (99 % at 10 edges, half at ~110). The Laplacian term damps a wave of k edges per
wavelength by about c_l (2π / k)² / 48 relative to the normal term (2 % at 6 edges for c_l = 1).
Defaults, measured:

- c_r = 0.01. At c_r = 0.003, 0.01, 0.03: sleeve 0.23, 0.20, 0.21 mm, with 3° noise 0.43, 0.39,
  0.36 mm; bump 0.136, 0.139, 0.156 mm (97, 94, 87 % of its amplitude), with 3° noise 0.44,
  0.41, 0.36 mm; t-shirt 0.71, 0.69, 0.69 mm. 0.03 resists noise better and flattens broad
  shapes more; 0.01 is between.
- c_l = 0.1. At c_l = 0, 0.1, 1, 10: sleeve 0.199, 0.202, 0.23, 0.44 mm (10 removes 18 % of the
  6-edge folds), with 3° noise 0.391, 0.392, 0.40, 0.53 mm; bump with 3° noise 0.405, 0.405,
  0.401, 0.379 mm; t-shirt 0.690, 0.694, 0.73, 0.97 mm. Moving along the normals, the normal term
  integrates the normals and so already smooths per-vertex noise; the Laplacian did not help with
  a 20° seam in the normal map either. The default keeps Eq. 10's term at a weight that costs
  < 2 %.

The normals carry no absolute position, so a bump's mean height comes out at the base's: the
flat bump sits 0.14 mm low, nearly all of its error. Sampled folds come out low: the chord of a
sine is steeper than the mean of its end normals (88 % of the amplitude at 6 vertices per
wavelength on the sleeve, ~58 % at 3-4 on the t-shirt).

Orientation. Target normals are flipped, vertex by vertex, to the side of the base's vertex
normal (right-hand rule on ``faces``): a flipped or inward normal map gives the same result.
Normals are normalised; ones of (near-)zero length are refused. Vertices whose base normal is
zero (faces that cancel) stay at the base in the "normal" directions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.errors import WrinklesInputError
from sim.geometry.strain import check_faces

LAPLACIANS = ("cotangent", "uniform")
"""Discrete Laplacians Δ of the smoothing term (module docstring)."""
SMOOTHED = ("displacement", "position")
"""What the smoothing term acts on: v − v0 (default) or v (Eq. 10 as printed)."""
NORMAL_TERMS = ("edge", "vertex")
"""Normal term: each edge against its ends' mean normal (default), or Eq. 10's per-vertex sum."""
DIRECTIONS = ("normal", "free")
"""How vertices move: along their base vertex normal (default), or freely in 3D."""
MIN_NORMAL_LENGTH = 1e-3
"""Target normals shorter than this have no direction (the average of opposite normals)."""
MIN_EDGE_FRACTION = 1e-3
"""Edge lengths in the linearisation are floored at this fraction of the base's mean edge length,
so that an edge collapsed in an iterate does not give its residual an unbounded weight."""
BACKTRACKS = 4
"""Halvings of a Gauss-Newton step that raises the energy before the step is dropped."""


@dataclass(frozen=True)
class NormalGeometryConfig:
    """Weights and choices of :func:`deform_to_normals` (module docstring: what each one does and
    the measurements behind the defaults). Eq. 10 exactly as printed is ``normal_term="vertex",
    directions="free", smooth="position", relative=False``.

    Attributes:
        laplacian_weight: c_l ≥ 0, dimensionless; λ_l = c_l / h̄².
        regularization_weight: c_r > 0, dimensionless; λ_r = c_r / h̄².
        iterations: Gauss-Newton steps (≥ 1).
        laplacian: "cotangent" or "uniform".
        smooth: "displacement" (‖Δ(v − v0)‖²) or "position" (‖Δv‖²).
        normal_term: "edge" or "vertex".
        directions: "normal" or "free".
        relative: measure each normal residual from the base's own (True), or from zero (Eq. 10).
    """

    laplacian_weight: float = 0.1
    regularization_weight: float = 0.01
    iterations: int = 2
    laplacian: str = "cotangent"
    smooth: str = "displacement"
    normal_term: str = "edge"
    directions: str = "normal"
    relative: bool = True

    def __post_init__(self) -> None:
        for name, positive in (("laplacian_weight", False), ("regularization_weight", True)):
            value = getattr(self, name)
            number = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
            if not number or not np.isfinite(value) or value < 0.0 or (positive and value == 0.0):
                kind = "positive" if positive else "non-negative"
                raise WrinklesInputError(f"{name} must be a finite {kind} number, got {value!r}")
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, (int, np.integer)) \
                or self.iterations < 1:
            raise WrinklesInputError(f"iterations must be an integer >= 1, got {self.iterations!r}")
        if not isinstance(self.relative, (bool, np.bool_)):
            raise WrinklesInputError(f"relative must be True or False, got {self.relative!r}")
        for name, allowed in (("laplacian", LAPLACIANS), ("smooth", SMOOTHED), ("normal_term", NORMAL_TERMS),
                              ("directions", DIRECTIONS)):
            if getattr(self, name) not in allowed:
                raise WrinklesInputError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")


def _fixed_mask(fixed, V: int) -> np.ndarray:
    """Boolean (V,) mask of the vertices held at the base: from indices (K,) or a mask (V,)."""
    if fixed is None:
        return np.zeros(V, bool)
    fx = np.asarray(fixed)
    if fx.dtype == bool:
        if fx.shape != (V,):
            raise WrinklesInputError(f"a boolean fixed mask must have shape ({V},), got {fx.shape}")
        return fx.copy()
    if fx.ndim != 1 or (fx.size and not np.issubdtype(fx.dtype, np.integer)):
        raise WrinklesInputError(f"fixed must be vertex indices (K,) or a boolean mask ({V},), "
                                 f"got {fx.shape}")
    mask = np.zeros(V, bool)
    if fx.size:
        if fx.min() < 0 or fx.max() >= V:
            bad = int(fx.min()) if fx.min() < 0 else int(fx.max())
            raise WrinklesInputError(f"fixed vertex index {bad} is outside [0, {V - 1}]")
        mask[fx] = True
    return mask


def _check_inputs(base: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> tuple:
    """Validated float64 base (V, 3), int64 faces (F, 3) and unit normals (V, 3)."""
    x = np.asarray(base)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0 or not np.issubdtype(x.dtype, np.number):
        raise WrinklesInputError(f"base must be a numeric array of shape (V, 3), got {x.shape}")
    x = x.astype(np.float64)
    if not np.isfinite(x).all():
        raise WrinklesInputError("base has non-finite positions")
    f = check_faces(faces, len(x)).astype(np.int64)
    n = np.asarray(normals)
    if n.shape != x.shape or not np.issubdtype(n.dtype, np.number):
        raise WrinklesInputError(f"normals must have the shape of base {x.shape}, got {n.shape}")
    n = n.astype(np.float64)
    if not np.isfinite(n).all():
        raise WrinklesInputError("normals have non-finite values")
    length = np.linalg.norm(n, axis=1)
    short = np.flatnonzero(length < MIN_NORMAL_LENGTH)
    if short.size:
        raise WrinklesInputError(f"{short.size} normal(s) have (near-)zero length (first: vertex {short[0]})")
    return x, f, n / length[:, None]


def _laplacian(x: np.ndarray, faces: np.ndarray, edges: np.ndarray, kind: str):
    """Row-normalised Laplacian Δ (scipy CSR, V × V): (Δu)_v = u_v − Σ_p w_vp u_p / Σ_p w_vp, with
    w = 1 ("uniform") or the clamped cotangent weights of ``cotangent_stiffness`` ("cotangent");
    a vertex without positive weights gets a zero row."""
    import scipy.sparse as sp

    V = len(x)
    if kind == "cotangent":
        from sim.cloth.coarse.operators import cotangent_stiffness

        k = cotangent_stiffness(x, faces, np.ones(len(faces)), V)
        w = (sp.diags(k.diagonal()) - k).tocsr()
    else:
        a, b = edges[:, 0], edges[:, 1]
        ones = np.ones(2 * len(edges))
        w = sp.csr_matrix((ones, (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(V, V))
    total = np.asarray(w.sum(axis=1)).ravel()
    has = total > 0.0
    inv = np.divide(1.0, total, out=np.zeros(V), where=has)
    return (sp.diags(has.astype(np.float64)) - sp.diags(inv) @ w).tocsr()


def _edge_normals(edges: np.ndarray, normals: np.ndarray, form: str) -> tuple:
    """Residual rows: the normal of every row (R, 3), its edge (R,), its weight (R,) and the
    residual it is measured from (R,), zero here: "vertex", both end normals, weight 1 (Eq. 10);
    "edge", their normalised mean, weight 2."""
    E = len(edges)
    if form == "vertex":
        both = np.concatenate([normals[edges[:, 0]], normals[edges[:, 1]]])
        return both, np.tile(np.arange(E), 2), np.ones(2 * E), np.zeros(2 * E)
    m = normals[edges[:, 0]] + normals[edges[:, 1]]
    length = np.linalg.norm(m, axis=1, keepdims=True)
    # opposite end normals (a fold sharper than the mesh) have no mean: take either end's
    m = np.where(length > MIN_NORMAL_LENGTH, m / np.maximum(length, MIN_NORMAL_LENGTH), normals[edges[:, 0]])
    return m, np.arange(E), np.full(E, 2.0), np.zeros(E)


def _residuals(x: np.ndarray, edges: np.ndarray, rows: tuple, h: float) -> np.ndarray:
    """The residuals m · ê − r0 of the rows at positions x (R,)."""
    m, edge, _, r0 = rows
    e = x[edges[edge, 0]] - x[edges[edge, 1]]
    return (m * e).sum(1) / np.maximum(np.linalg.norm(e, axis=1), MIN_EDGE_FRACTION * h) - r0


def _linearize(x: np.ndarray, x0: np.ndarray, edges: np.ndarray, rows: tuple, h: float) -> tuple:
    """Gauss-Newton model of the rows at x: r ≈ t · (d_a − d_b) + c, d = v − v0 (t (R, 3), c (R,))."""
    m, edge, _, r0 = rows
    a, b = edges[edge, 0], edges[edge, 1]
    ek = x[a] - x[b]
    lk = np.maximum(np.linalg.norm(ek, axis=1), MIN_EDGE_FRACTION * h)
    uk = ek / lk[:, None]
    r = (m * uk).sum(1)
    t = (m - r[:, None] * uk) / lk[:, None]
    return t, r - r0 + (t * (x0[a] - x0[b] - ek)).sum(1)


def _normal_system(edges: np.ndarray, rows: tuple, ta: np.ndarray, tb: np.ndarray, c: np.ndarray, V: int):
    """N (scipy CSR, kV × kV) and g (kV,) with Σ w (ta · u_a − tb · u_b + c)² = uᵀ N u + 2 gᵀ u + const,
    u the k unknowns of every vertex (k = 1 or 3, the columns of ``ta`` and ``tb``)."""
    import scipy.sparse as sp

    _, edge, w, _ = rows
    a, b = edges[edge, 0], edges[edge, 1]
    k = ta.shape[1]
    blocks = [(a, a, ta, ta, 1.0), (b, b, tb, tb, 1.0), (a, b, ta, tb, -1.0), (b, a, tb, ta, -1.0)]
    r, shape = np.arange(k), (len(w), k, k)
    ri = np.concatenate([np.broadcast_to(k * i[:, None, None] + r[:, None], shape) for i, *_ in blocks])
    ci = np.concatenate([np.broadcast_to(k * j[:, None, None] + r[None, :], shape) for _, j, *_ in blocks])
    data = np.concatenate([s * w[:, None, None] * p[:, :, None] * q[:, None, :] for _, _, p, q, s in blocks])
    n = sp.csr_matrix((data.ravel(), (ri.ravel(), ci.ravel())), shape=(k * V, k * V))
    g = np.zeros((V, k))
    for j in range(k):
        g[:, j] = np.bincount(a, w * c * ta[:, j], V) - np.bincount(b, w * c * tb[:, j], V)
    return n, g.ravel()


def _solve(matrix, rhs: np.ndarray, free: np.ndarray) -> np.ndarray:
    """The solution of ``matrix`` u = ``rhs`` with u = 0 where ``free`` is False: sparse LU of the
    free block, symmetric mode (minimum degree on A + Aᵀ, diagonal pivots: the matrix is SPD)."""
    from scipy.sparse.linalg import splu

    u = np.zeros(len(rhs))
    idx = np.flatnonzero(free)
    if idx.size:
        lu = splu(matrix[idx][:, idx].tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
        u[idx] = lu.solve(rhs[idx])
    return u


def _quadratic_part(x0: np.ndarray, lap, n0: np.ndarray, cfg: NormalGeometryConfig, h: float) -> tuple:
    """The constant part of the normal equations, λ_l ΔᵀΔ + λ_r I in the unknowns (s along n0 per
    vertex, or the 3 coordinates), and its right-hand side (−λ_l ΔᵀΔ v0 for ``smooth="position"``)."""
    import scipy.sparse as sp

    V = len(x0)
    ll, lr = cfg.laplacian_weight / h**2, cfg.regularization_weight / h**2
    ltl = (lap.T @ lap).tocoo()
    pull = -ll * (lap.T @ (lap @ x0)) if cfg.smooth == "position" else np.zeros((V, 3))
    if cfg.directions == "free":
        const = sp.kron(ltl, sp.identity(3), format="csr") * ll + sp.identity(3 * V, format="csr") * lr
        return const, pull.ravel()
    # with v − v0 = s n0: (B s)ᵀ (ΔᵀΔ ⊗ I3) (B s) has entries (ΔᵀΔ)_ij n0_i · n0_j
    coupling = (n0[ltl.row] * n0[ltl.col]).sum(1)
    const = sp.csr_matrix((ltl.data * coupling * ll, (ltl.row, ltl.col)), shape=(V, V))
    const = const + sp.diags((n0 * n0).sum(1) * lr)
    return const.tocsr(), (pull * n0).sum(1)


def _energy(x: np.ndarray, x0: np.ndarray, edges: np.ndarray, rows: tuple, lap, cfg, h: float) -> float:
    """The energy being minimised (module docstring) at positions x."""
    y = x - x0 if cfg.smooth == "displacement" else x
    return float((rows[2] * _residuals(x, edges, rows, h) ** 2).sum()
                 + cfg.laplacian_weight / h**2 * ((lap @ y) ** 2).sum()
                 + cfg.regularization_weight / h**2 * ((x - x0) ** 2).sum())


def deform_to_normals(base: np.ndarray, faces: np.ndarray, normals: np.ndarray, *,
                      config: NormalGeometryConfig | None = None,
                      fixed: np.ndarray | None = None) -> np.ndarray:
    """Positions that minimise Guo et al. 2024 Eq. 10 for target vertex normals (module docstring:
    the energy, the solver and the measured defaults).

    Args:
        base: base-mesh positions v0 [m], shape (V, 3).
        faces: (F, 3) int, counter-clockwise seen from the side the normals point to.
        normals: target normals (V, 3), the normal map sampled at the vertices; normalised here,
            and each one's sign is taken from the base (either orientation gives the same result).
        config: weights and choices (``NormalGeometryConfig``; None: its defaults).
        fixed: vertices held at ``base``: indices (K,) or a boolean mask (V,); None: none.

    Returns:
        float64 positions [m], shape (V, 3).

    Raises:
        WrinklesInputError: shapes that do not match, non-finite values, (near-)zero normals, face
            or fixed indices out of range, a bad config, or a base whose edges all have zero length.
    """
    from sim.geometry.frames import vertex_normals
    from sim.quality import unique_edges

    cfg = NormalGeometryConfig() if config is None else config
    x0, f, n = _check_inputs(base, faces, normals)
    V = len(x0)
    free = ~_fixed_mask(fixed, V)
    edges = unique_edges(f).astype(np.int64)
    h = float(np.linalg.norm(x0[edges[:, 0]] - x0[edges[:, 1]], axis=1).mean())
    if not h > 0.0:
        raise WrinklesInputError("base has no edge of non-zero length")
    n0 = vertex_normals(x0, f).astype(np.float64)
    n = n * np.where((n * n0).sum(1) < 0.0, -1.0, 1.0)[:, None]
    lap = _laplacian(x0, f, edges, cfg.laplacian)
    const, pull = _quadratic_part(x0, lap, n0, cfg, h)
    rows = _edge_normals(edges, n, cfg.normal_term)
    if cfg.relative:
        own = _edge_normals(edges, n0, cfg.normal_term)
        rows = (*rows[:3], _residuals(x0, edges, own, h))
    along = cfg.directions == "normal"
    if along:
        free &= np.linalg.norm(n0, axis=1) > 0.5
    unknowns = free if along else np.repeat(free, 3)
    x, energy = x0, _energy(x0, x0, edges, rows, lap, cfg, h)
    for _ in range(cfg.iterations):
        t, c = _linearize(x, x0, edges, rows, h)
        a, b = edges[rows[1], 0], edges[rows[1], 1]
        ta, tb = ((t * n0[a]).sum(1, keepdims=True), (t * n0[b]).sum(1, keepdims=True)) if along else (t, t)
        nt, g = _normal_system(edges, rows, ta, tb, c, V)
        u = _solve(const + nt, pull - g, unknowns)
        step = (u[:, None] * n0 if along else u.reshape(V, 3)) - (x - x0)
        for _ in range(BACKTRACKS + 1):
            e_trial = _energy(x + step, x0, edges, rows, lap, cfg, h)
            if e_trial <= energy:
                x, energy = x + step, e_trial
                break
            step = 0.5 * step
        else:
            break  # no descent along this step: x is (numerically) a minimum
    return x
