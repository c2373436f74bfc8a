"""Smooth skinning decomposition with rigid bones (SSDR), numpy + scipy.

Fits a *virtual skeleton* to a garment's mesh sequence: ``J`` rigid bones with per-frame
transforms and sparse, convex per-vertex weights such that linear blend skinning of the rest
mesh reproduces the frames (Le & Deng 2012, "Smooth Skinning Decomposition with Rigid Bones",
ACM TOG 31(6)). Guo et al. 2024 (Sec. 3.3, Eq. 8) rig each garment's base mesh this way with
``k = 64`` bones; a CVAE then predicts the bone transforms from body pose and shape.

Model (Le & Deng 2012), for frame ``t`` and vertex ``v``::

    x_tv ~= sum_j w_vj (R_tj r_v + T_tj),   w_vj >= 0,  sum_j w_vj = 1,  |{j: w_vj > 0}| <= K

Algorithm (equation numbers of the paper are not cited: its text is not in shared/papers):

1. Initialisation, rigid-motion clustering as in the paper: k-means on vertex trajectories
   into ``J / 4`` clusters (k-means++ seeding from ``seed``), then the bone count is doubled
   repeatedly by seeding new bones (Kabsch on a rest-space neighbourhood) at the worst-fitted
   vertex of the clusters with the largest error; after each growth, rounds of re-assignment
   (each vertex to the bone that moves it with the smallest rigid error) and Kabsch re-fits.
   A final local search moves the least useful bone to the worst-fitted vertex while that
   lowers the rigid error (fixes clusters that straddle two rigid parts).
2. Alternate block-coordinate updates:

   a. weights: per vertex, the ``P <= 2K`` bones with the smallest rigid fitting error are the
      candidates (the paper takes the ``K`` best; a larger pool recovers small influences);
      the convex (non-negative, sum-to-one) least squares with at most ``K`` non-zeros is
      solved *exactly* by enumerating the supports of size <= K (equality-constrained KKT solve
      on each, best feasible one kept), vectorised over vertices. The normal equations are
      formed from per-bone-pair sums over frames, so the cost is one ``(V, 3T) x (3T, 4J)``
      product. The previous weights are kept where they are better, so this step never
      increases the error.
   b. bone transforms: for each bone in turn, weighted Procrustes on the residual with the
      other bones' contributions removed (the paper's rigid bone update); the exact minimiser
      for that bone, so this step never increases the error either.

   Bones influencing fewer than ``min_bone_vertices`` vertices are re-seeded at the vertex
   with the largest error during the first half of the iterations; that step alone may raise
   the error slightly.

Internally positions are centred per frame (rest: by its mean; frame ``t``: by its mean),
which is exact for convex weights and keeps the normal equations well conditioned.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sim.errors import WrinklesInputError
from sim.geometry.points import frame_centroids

# Largest K handled by exact support enumeration (2^8 - 1 = 255 small solves per vertex).
MAX_INFLUENCES = 8
# Relative ridge added to each vertex's Gram matrix: keeps KKT systems solvable when two
# candidate bones move identically (their columns coincide); 1e-10 of the mean diagonal changes
# the optimum far below float32 resolution.
_RIDGE = 1e-10
# Weights below this are treated as zero when counting a bone's vertices.
_WEIGHT_EPS = 1e-6


@dataclass(frozen=True)
class SSDRResult:
    """A fitted virtual skeleton (Le & Deng 2012).

    Attributes:
        weight_idx: bone index of each influence, int32 (V, K); unused slots have weight 0.
        weight_val: weights, float32 (V, K); non-negative, rows sum to 1, sorted descending.
        rotations: bone rotations (proper, orthonormal) per frame, float32 (T, J, 3, 3).
        translations: bone translations [m] per frame, float32 (T, J, 3); a rest vertex ``r``
            moves with bone ``j`` to ``rotations[t, j] @ r + translations[t, j]``.
        rest: rest positions [m], float32 (V, 3).
        rmse_per_iteration: RMS vertex error [m] after initialisation (index 0, rigid one-hot
            weights) and after each iteration.
        rmse: final RMS vertex error [m], ``sqrt(mean_tv |x_tv - y_tv|^2)``.
    """

    weight_idx: np.ndarray
    weight_val: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray
    rest: np.ndarray
    rmse_per_iteration: list[float]
    rmse: float

    @property
    def num_bones(self) -> int:
        return int(self.rotations.shape[1])

    def dense_weights(self) -> np.ndarray:
        """Weights as a dense float32 (V, J) matrix."""
        v = self.weight_idx.shape[0]
        out = np.zeros((v, self.num_bones), np.float32)
        np.add.at(out, (np.arange(v)[:, None], self.weight_idx), self.weight_val)
        return out


# ----------------------------------------------------------------------------- helpers


def _proper_rotation(h: np.ndarray) -> np.ndarray:
    """Rotation maximising tr(R H) for covariance H = sum p q^T, shape (..., 3, 3) (Kabsch)."""
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)))
    d = np.where(d == 0, 1.0, d)
    vt = vt.copy()
    vt[..., 2, :] *= d[..., None]
    return np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)


def _weighted_procrustes(
    rest: np.ndarray, w: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """argmin_{R,t} sum_i |q_ti - w_i (R_t r_i + t_t)|^2 for every frame (Le & Deng 2012).

    Args:
        rest: (n, 3) rest positions.
        w: (n,) weights of this bone.
        q: (n, T, 3) residual targets (frames minus the other bones' contributions).

    Returns:
        (R (T, 3, 3), t (T, 3)), or None when the bone has no weight.
    """
    w2 = float(np.dot(w, w))
    if w2 <= 1e-12:
        return None
    p_star = (w * w) @ rest / w2  # (3,)
    q_star = np.einsum("i,itc->tc", w, q) / w2  # (T, 3)
    p_bar = w[:, None] * (rest - p_star)  # (n, 3)
    q_bar = q - w[:, None, None] * q_star[None]  # (n, T, 3)
    n, t = q.shape[:2]
    h = (p_bar.T @ q_bar.reshape(n, 3 * t)).reshape(3, t, 3).transpose(1, 0, 2)  # (T, 3, 3)
    rot = _proper_rotation(h)
    return rot, q_star - rot @ p_star


def _lbs_columns(rest: np.ndarray, idx: np.ndarray, val: np.ndarray, rot: np.ndarray, tr: np.ndarray):
    """LBS of all frames as (V, 3T): sparse (V, 4J) [w r, w] times dense (4J, 3T) [R^T; t]."""
    from scipy.sparse import csr_matrix

    v, k = idx.shape
    t, j = rot.shape[:2]
    hom = np.concatenate([rest, np.ones((v, 1))], axis=1)  # (V, 4)
    data = (val[:, :, None] * hom[:, None, :]).reshape(-1)
    cols = (idx[:, :, None] * 4 + np.arange(4)).reshape(-1)
    rows = np.repeat(np.arange(v), 4 * k)
    m = csr_matrix((data, (rows, cols)), shape=(v, 4 * j))
    a = np.concatenate([np.swapaxes(rot, -1, -2), tr[:, :, None, :]], axis=2)  # (T, J, 4, 3)
    a = a.transpose(1, 2, 0, 3).reshape(4 * j, 3 * t)
    return np.asarray(m @ a)


class _Problem:
    """Centred data and the per-iteration statistics of the weight step."""

    def __init__(self, rest: np.ndarray, frames: np.ndarray):
        self.t, self.v = frames.shape[:2]
        self.rest_center = rest.mean(axis=0)
        self.frame_center = frame_centroids(frames)  # (T, 3)
        self.rest = rest.astype(np.float64) - self.rest_center
        # (V, 3T), row v = trajectory of vertex v, float64 for the normal equations.
        self.x = (
            (frames.astype(np.float64) - self.frame_center[:, None])
            .transpose(1, 0, 2)
            .reshape(self.v, 3 * self.t)
        )
        self.xx = np.einsum("ij,ij->i", self.x, self.x)  # (V,)

    def rmse(self, y: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((self.x - y).reshape(self.v, self.t, 3) ** 2, axis=2))))

    def bone_targets(self, rot: np.ndarray, tr: np.ndarray, verts: np.ndarray) -> np.ndarray:
        """Positions of ``verts`` moved rigidly by one bone, (n, 3T)."""
        p = np.einsum("tab,nb->nta", rot, self.rest[verts]) + tr[None]
        return p.reshape(len(verts), 3 * self.t)

    def fit_stats(self, rot: np.ndarray, tr: np.ndarray):
        """Per-vertex, per-bone terms of |sum_k w_k (R_k r + t_k) - x|^2 summed over frames.

        Returns:
            c (V, J) = sum_t x_tv . (R_tj r_v + t_tj); gram(idx) -> (V, K, K) Gram matrices;
            err (V, J) = rigid fitting error of each bone alone.
        """
        t, j = rot.shape[:2]
        r = self.rest
        # [R | t] laid out so that x (V, 3T) @ m gives sum_t x_t^T R_tj (V, J, 3) and sum_t x_t.t_tj.
        m = np.concatenate([rot, tr[..., None]], axis=3)  # (T, J, 3, 4)
        m = m.transpose(0, 2, 1, 3).reshape(3 * t, 4 * j)
        xm = (self.x @ m).reshape(self.v, j, 4)
        c = np.einsum("vjb,vb->vj", xm[..., :3], r) + xm[..., 3]
        c_rr = np.einsum("tjab,tkac->jkbc", rot, rot)  # sum_t R_j^T R_k, (J, J, 3, 3)
        c_rt = np.einsum("tjab,tka->jkb", rot, tr)  # sum_t R_j^T t_k, (J, J, 3)
        c_tt = np.einsum("tja,tka->jk", tr, tr)  # (J, J)

        def gram(idx: np.ndarray) -> np.ndarray:
            a, b = idx[:, :, None], idx[:, None, :]
            g = np.einsum("vb,vklbc,vc->vkl", r, c_rr[a, b], r)
            g += np.einsum("vb,vklb->vkl", r, c_rt[a, b] + c_rt[b, a])
            return g + c_tt[a, b]

        diag_rr = np.einsum("jjbc->jbc", c_rr)
        diag = np.einsum("vb,jbc,vc->vj", r, diag_rr, r) + 2 * r @ np.einsum("jjb->jb", c_rt).T
        diag += np.diag(c_tt)[None]
        err = np.maximum(diag - 2 * c + self.xx[:, None], 0.0)
        return c, gram, err


def _convex_lsq(
    g: np.ndarray, c: np.ndarray, xx: np.ndarray, *, max_support: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """min_w w^T G w - 2 c^T w + xx  s.t.  w >= 0, sum w = 1, |supp w| <= S, exactly, per row.

    Enumerates supports; on each, solves the KKT system [2G 1; 1^T 0][w; l] = [2c; 1]
    (the weight problem of Le & Deng 2012 with the affinity constraint). The global optimum of this convex QP
    is the best feasible support solution.

    Args:
        g: (V, P, P) Gram matrices; c: (V, P); xx: (V,) constant term.
        max_support: at most this many non-zeros S (default P); supports of size <= S are
            enumerated, so the sparse problem is solved exactly too.

    Returns:
        (w (V, P), objective (V,)).
    """
    v, k = c.shape
    max_support = k if max_support is None else min(max_support, k)
    ridge = _RIDGE * np.maximum(np.einsum("vkk->v", g) / k, 1e-30)
    best_w = np.zeros((v, k))
    best_f = np.full(v, np.inf)
    for size in range(1, max_support + 1):
        for sub in itertools.combinations(range(k), size):
            s = list(sub)
            if size == 1:
                ws = np.ones((v, 1))
            else:
                kkt = np.zeros((v, size + 1, size + 1))
                kkt[:, :size, :size] = 2 * g[:, s][:, :, s]
                kkt[:, :size, :size] += 2 * ridge[:, None, None] * np.eye(size)
                kkt[:, :size, size] = 1.0
                kkt[:, size, :size] = 1.0
                rhs = np.concatenate([2 * c[:, s], np.ones((v, 1))], axis=1)
                ws = np.linalg.solve(kkt, rhs[..., None])[..., 0][:, :size]
            feasible = np.all(ws >= -1e-12, axis=1) & np.all(np.isfinite(ws), axis=1)
            ws = np.clip(ws, 0.0, None)
            ws /= np.maximum(ws.sum(axis=1, keepdims=True), 1e-300)
            f = np.einsum("vk,vkl,vl->v", ws, g[:, s][:, :, s], ws) - 2 * np.einsum("vk,vk->v", ws, c[:, s])
            better = feasible & (f < best_f)
            best_f = np.where(better, f, best_f)
            full = np.zeros((v, k))
            full[:, s] = ws
            best_w = np.where(better[:, None], full, best_w)
    return best_w, best_f + xx


# ----------------------------------------------------------------------------- steps


def _kmeans(feat: np.ndarray, k: int, rng: np.random.Generator, iterations: int = 20) -> np.ndarray:
    """Lloyd's k-means with k-means++ seeding; returns labels (n,)."""
    n = feat.shape[0]
    sq = np.einsum("ij,ij->i", feat, feat)
    centers = [int(rng.integers(n))]
    d2 = np.maximum(sq - 2 * feat @ feat[centers[0]] + sq[centers[0]], 0)
    for _ in range(1, k):
        total = d2.sum()
        nxt = int(rng.choice(n, p=d2 / total)) if total > 0 else int(rng.integers(n))
        centers.append(nxt)
        d2 = np.minimum(d2, np.maximum(sq - 2 * feat @ feat[nxt] + sq[nxt], 0))
    cen = feat[centers].copy()
    labels = np.zeros(n, np.int64)
    for it in range(iterations):
        dist = sq[:, None] - 2 * feat @ cen.T + np.einsum("ij,ij->i", cen, cen)[None]
        new = np.argmin(dist, axis=1)
        if it > 0 and np.array_equal(new, labels):
            break
        labels = new
        counts = np.bincount(labels, minlength=k)
        sums = np.zeros_like(cen)
        np.add.at(sums, labels, feat)
        nonempty = counts > 0
        cen[nonempty] = sums[nonempty] / counts[nonempty, None]
    return labels


def _fit_clusters(prob: _Problem, labels: np.ndarray, rot: np.ndarray, tr: np.ndarray) -> None:
    """Kabsch transforms of every non-empty cluster, in place."""
    for b in np.unique(labels):
        members = np.flatnonzero(labels == b)
        fit = _weighted_procrustes(
            prob.rest[members], np.ones(members.size), prob.x[members].reshape(-1, prob.t, 3)
        )
        rot[:, b], tr[:, b] = fit


def _init_clusters(prob, tree, num_bones, rng, rounds, seed_size):
    """Rigid-motion clustering of vertices into ``num_bones`` bones (Le & Deng 2012).

    Starts from k-means on trajectories with ``num_bones / 4`` clusters (k-means++ seeding by
    ``rng``), then repeatedly adds bones seeded at the worst-fitted vertex of the clusters with
    the largest error (at most doubling the count), each time followed by ``rounds`` of
    re-assignment to the bone with the smallest rigid error and Kabsch re-fits; then
    ``_swap_bones``.
    """
    v, t = prob.v, prob.t
    rot = np.tile(np.eye(3), (t, num_bones, 1, 1))
    tr = np.zeros((t, num_bones, 3))
    sub = np.unique(np.linspace(0, t - 1, min(t, 64)).round().astype(int))
    feat = np.concatenate([prob.rest, prob.x.reshape(v, t, 3)[:, sub].reshape(v, -1)], axis=1)
    nb = max(1, num_bones // 4)
    labels = _kmeans(feat, nb, rng)
    _fit_clusters(prob, labels, rot, tr)
    while True:
        for _ in range(max(rounds, 1)):
            _, _, err = prob.fit_stats(rot[:, :nb], tr[:, :nb])
            counts = np.bincount(labels, minlength=nb)
            _reseed(prob, tree, rot, tr, counts, err[np.arange(v), labels], 1, seed_size)
            _, _, err = prob.fit_stats(rot[:, :nb], tr[:, :nb])
            labels = np.argmin(err, axis=1)
            _fit_clusters(prob, labels, rot, tr)
        if nb == num_bones:
            return _swap_bones(prob, tree, labels, rot, tr, seed_size, max_swaps=max(4, num_bones // 2))
        _, _, err = prob.fit_stats(rot[:, :nb], tr[:, :nb])
        vert_err = err[np.arange(v), labels]
        cluster_err = np.bincount(labels, weights=vert_err, minlength=nb)
        add = min(nb, num_bones - nb)
        for b in np.argsort(-cluster_err, kind="stable")[:add]:
            members = np.flatnonzero(labels == b)
            center = int(members[np.argmax(vert_err[members])])
            _, near = tree.query(prob.rest[center], k=min(seed_size, v))
            near = np.atleast_1d(near)
            near = near[labels[near] == b] if np.count_nonzero(labels[near] == b) >= 3 else near
            fit = _weighted_procrustes(prob.rest[near], np.ones(near.size), prob.x[near].reshape(-1, t, 3))
            rot[:, nb], tr[:, nb] = fit
            nb += 1


def _swap_bones(prob, tree, labels, rot, tr, seed_size, *, max_swaps):
    """Local search on the clustering: move the least useful bone to the worst-fitted vertex.

    The bone whose removal raises the rigid error least is re-seeded on the neighbourhood of the
    vertex with the largest error, followed by one re-assignment and Kabsch re-fit; kept only
    when the total rigid error drops (fixes clusters that straddle two rigid parts).
    """
    v = prob.v
    rows = np.arange(v)
    _, _, err = prob.fit_stats(rot, tr)
    total = err[rows, labels].sum()
    for _ in range(max_swaps):
        part = np.partition(err, 1, axis=1) if err.shape[1] > 1 else np.concatenate([err, err], 1)
        removal = np.bincount(labels, weights=part[:, 1] - part[:, 0], minlength=err.shape[1])
        weak = int(np.argmin(removal))
        vert_err = err[rows, labels]
        center = int(np.argmax(vert_err))
        _, near = tree.query(prob.rest[center], k=min(seed_size, v))
        near = np.atleast_1d(near)
        fit = _weighted_procrustes(prob.rest[near], np.ones(near.size), prob.x[near].reshape(-1, prob.t, 3))
        rot_new, tr_new = rot.copy(), tr.copy()
        rot_new[:, weak], tr_new[:, weak] = fit
        _, _, err_new = prob.fit_stats(rot_new, tr_new)
        lab_new = np.argmin(err_new, axis=1)
        _fit_clusters(prob, lab_new, rot_new, tr_new)
        _, _, err_new = prob.fit_stats(rot_new, tr_new)
        lab_new = np.argmin(err_new, axis=1)
        total_new = err_new[rows, lab_new].sum()
        if not total_new < total:
            break
        labels, rot, tr, err, total = lab_new, rot_new, tr_new, err_new, total_new
    return labels, rot, tr


def _seed_bone(prob: _Problem, tree: cKDTree, center: int, size: int):
    """Rigid (Kabsch) transforms of the ``size`` rest-space neighbours of vertex ``center``."""
    _, nb = tree.query(prob.rest[center], k=min(size, prob.v))
    nb = np.atleast_1d(nb)
    q = prob.x[nb].reshape(len(nb), prob.t, 3)
    return _weighted_procrustes(prob.rest[nb], np.ones(len(nb)), q)


def _reseed(prob, tree, rot, tr, counts, vert_err, min_vertices, seed_size) -> np.ndarray:
    """Re-seed bones influencing fewer than ``min_vertices`` vertices (Le & Deng 2012)."""
    dead = np.flatnonzero(counts < min_vertices)
    if dead.size == 0:
        return dead
    err = vert_err.astype(np.float64).copy()
    for j in dead:
        center = int(np.argmax(err))
        fit = _seed_bone(prob, tree, center, seed_size)
        if fit is not None:
            rot[:, j], tr[:, j] = fit
        _, nb = tree.query(prob.rest[center], k=min(seed_size, prob.v))
        err[np.atleast_1d(nb)] = -np.inf  # next dead bone seeds elsewhere
    return dead


def _pool_size(k: int, num_bones: int) -> int:
    """Candidate bones per vertex: up to 2K, at most 256 supports of size <= K to enumerate."""
    p = k
    while p < min(2 * k, num_bones) and sum(math.comb(p + 1, s) for s in range(1, k + 1)) <= 256:
        p += 1
    return p


def _update_weights(prob, rot, tr, idx_old, val_old, k):
    """Weight step (Le & Deng 2012); never worse than the previous weights."""
    c, gram, err = prob.fit_stats(rot, tr)
    pool = _pool_size(k, err.shape[1])
    cand = np.argsort(err, axis=1, kind="stable")[:, :pool]
    rows = np.arange(prob.v)[:, None]
    w_pool, f_new = _convex_lsq(gram(cand), c[rows, cand], prob.xx, max_support=k)
    top = np.argsort(-w_pool, axis=1, kind="stable")[:, :k]
    cand, w_new = np.take_along_axis(cand, top, 1), np.take_along_axis(w_pool, top, 1)
    g_old = gram(idx_old)
    f_old = (
        np.einsum("vk,vkl,vl->v", val_old, g_old, val_old)
        - 2 * np.einsum("vk,vk->v", val_old, c[rows, idx_old])
        + prob.xx
    )
    keep_old = f_old <= f_new
    idx = np.where(keep_old[:, None], idx_old, cand)
    val = np.where(keep_old[:, None], val_old, w_new)
    order = np.argsort(-val, axis=1, kind="stable")
    return np.take_along_axis(idx, order, 1), np.take_along_axis(val, order, 1), err


def _update_bones(prob, rot, tr, idx, val, y):
    """Bone step (Le & Deng 2012): per bone, weighted Procrustes on the residual.

    Updates ``rot``, ``tr`` and the reconstruction ``y`` (V, 3T) in place.
    """
    j_count = rot.shape[1]
    flat_idx = idx.reshape(-1)
    flat_val = val.reshape(-1)
    use = flat_val > 0
    verts_all = np.repeat(np.arange(prob.v), idx.shape[1])[use]
    bones_all, w_all = flat_idx[use], flat_val[use]
    order = np.argsort(bones_all, kind="stable")
    bounds = np.searchsorted(bones_all[order], np.arange(j_count + 1))
    for j in range(j_count):
        sel = order[bounds[j] : bounds[j + 1]]
        if sel.size == 0:
            continue
        verts, w = verts_all[sel], w_all[sel]
        old = prob.bone_targets(rot[:, j], tr[:, j], verts)
        q = prob.x[verts] - y[verts] + w[:, None] * old
        fit = _weighted_procrustes(prob.rest[verts], w, q.reshape(len(verts), prob.t, 3))
        if fit is None:
            continue
        rot[:, j], tr[:, j] = fit
        y[verts] += w[:, None] * (prob.bone_targets(rot[:, j], tr[:, j], verts) - old)


# ----------------------------------------------------------------------------- public API


def _validate(rest, frames, num_bones, max_influences, iterations) -> tuple[np.ndarray, np.ndarray]:
    rest = np.asarray(rest)
    frames = np.asarray(frames)
    if rest.ndim != 2 or rest.shape[1] != 3:
        raise WrinklesInputError(f"SSDR rest positions must have shape (V, 3), got {rest.shape}")
    if frames.ndim != 3 or frames.shape[1:] != rest.shape:
        raise WrinklesInputError(
            f"SSDR frames must have shape (T, {rest.shape[0]}, 3) to match the rest mesh, got {frames.shape}"
        )
    if frames.shape[0] < 1:
        raise WrinklesInputError("SSDR needs at least one frame")
    if not (np.all(np.isfinite(rest)) and np.all(np.isfinite(frames))):
        raise WrinklesInputError("SSDR input positions contain NaN or infinite values")
    if not 1 <= num_bones <= rest.shape[0]:
        raise WrinklesInputError(f"SSDR num_bones must be in [1, V={rest.shape[0]}], got {num_bones}")
    if not 1 <= max_influences <= min(MAX_INFLUENCES, num_bones):
        raise WrinklesInputError(
            f"SSDR max_influences must be in [1, min({MAX_INFLUENCES}, num_bones={num_bones})], "
            f"got {max_influences}"
        )
    if iterations < 0:
        raise WrinklesInputError(f"SSDR iterations must be >= 0, got {iterations}")
    return rest, frames


def fit_ssdr(
    rest: np.ndarray,
    frames: np.ndarray,
    *,
    num_bones: int = 64,
    max_influences: int = 4,
    iterations: int = 20,
    seed: int = 0,
    init_rounds: int = 5,
    min_bone_vertices: int = 4,
    progress: Callable[[int, float], None] | None = None,
) -> SSDRResult:
    """Fit rigid bones and sparse convex skinning weights to a mesh sequence (Le & Deng 2012).

    Args:
        rest: rest positions [m], shape (V, 3).
        frames: deformed positions [m], shape (T, V, 3), same vertex order as ``rest``.
        num_bones: number of bones J (Guo et al. 2024 use 64).
        max_influences: at most K non-zero weights per vertex, 1 <= K <= min(8, J).
        iterations: alternations of weight and bone updates.
        seed: seed of the k-means++ initialisation; same seed, same result.
        init_rounds: rounds of re-assignment and Kabsch re-fit after each growth of the bone count.
        min_bone_vertices: bones influencing fewer vertices are re-seeded (first half of the
            iterations); also the size of a re-seeded bone's neighbourhood is ``4x`` this.
        progress: called as ``progress(iteration, rmse)`` after initialisation (0) and after
            each iteration (1..iterations).

    Returns:
        SSDRResult with weights, per-frame bone transforms and the error history.

    Raises:
        WrinklesInputError: bad shapes, non-finite positions, or out-of-range counts.
    """
    rest, frames = _validate(rest, frames, num_bones, max_influences, iterations)
    prob = _Problem(rest, frames)
    v, j, k = prob.v, num_bones, max_influences
    rng = np.random.default_rng(seed)
    tree = cKDTree(prob.rest)
    seed_size = max(4 * min_bone_vertices, 8)

    # --- initialisation: rigid-motion clustering grown by splitting (Le & Deng 2012)
    labels, rot, tr = _init_clusters(prob, tree, j, rng, init_rounds, seed_size)
    # Final transforms of the rigid clustering, one-hot weights.
    idx, val = _one_hot_weights(labels, v, k, j)
    y = _lbs_columns(prob.rest, idx, val, rot, tr)
    history = [prob.rmse(y)]
    if progress is not None:
        progress(0, history[-1])

    for it in range(1, iterations + 1):
        idx, val, _ = _update_weights(prob, rot, tr, idx, val, k)
        if it <= iterations // 2:
            counts = np.bincount(idx[val > _WEIGHT_EPS], minlength=j)
            y = _lbs_columns(prob.rest, idx, val, rot, tr)
            vert_err = np.sum((prob.x - y) ** 2, axis=1)
            dead = _reseed(prob, tree, rot, tr, counts, vert_err, min_bone_vertices, seed_size)
            if dead.size:
                idx, val, _ = _update_weights(prob, rot, tr, idx, val, k)
        y = _lbs_columns(prob.rest, idx, val, rot, tr)
        _update_bones(prob, rot, tr, idx, val, y)
        y = _lbs_columns(prob.rest, idx, val, rot, tr)  # fresh, no drift from in-place updates
        history.append(prob.rmse(y))
        if progress is not None:
            progress(it, history[-1])

    return _world_result(prob, rest, idx, val, rot, tr, history)


def _one_hot_weights(labels: np.ndarray, v: int, k: int, j: int) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex fully on its cluster's bone: indices (V, K) and weights (V, K)."""
    idx = np.zeros((v, k), np.int64)
    idx[:, 0] = labels
    if k > 1:  # distinct (zero-weight) fillers keep supports well defined
        idx[:, 1:] = (labels[:, None] + np.arange(1, k)) % j
    val = np.zeros((v, k))
    val[:, 0] = 1.0
    return idx, val


def _world_result(prob: _Problem, rest: np.ndarray, idx: np.ndarray, val: np.ndarray, rot: np.ndarray,
                  tr: np.ndarray, history: list) -> SSDRResult:
    """The fit in world coordinates, negligible weights dropped and the rest renormalised."""
    # Undo the centring: x = x' + c_t, r = r' + c_r  =>  T = T' + c_t - R c_r.
    tr_world = tr + prob.frame_center[:, None, :] - np.einsum("tjab,b->tja", rot, prob.rest_center)
    val = np.where(val > _WEIGHT_EPS * 1e-3, val, 0.0)
    val /= val.sum(axis=1, keepdims=True)
    return SSDRResult(
        weight_idx=idx.astype(np.int32),
        weight_val=val.astype(np.float32),
        rotations=rot.astype(np.float32),
        translations=tr_world.astype(np.float32),
        rest=np.asarray(rest, np.float32).copy(),
        rmse_per_iteration=[float(h) for h in history],
        rmse=float(history[-1]),
    )


def ssdr_reconstruct(
    result: SSDRResult,
    *,
    rotations: np.ndarray | None = None,
    translations: np.ndarray | None = None,
) -> np.ndarray:
    """Linear blend skinning of ``result.rest`` with the fitted weights (Guo et al. 2024, Eq. 8).

    Args:
        result: a fitted skeleton.
        rotations: bone rotations, shape (T, J, 3, 3); default: the fitted ones.
        translations: bone translations [m], shape (T, J, 3); default: the fitted ones.

    Returns:
        Skinned positions [m], float32 (T, V, 3).
    """
    rot = result.rotations if rotations is None else np.asarray(rotations)
    tr = result.translations if translations is None else np.asarray(translations)
    j = result.num_bones
    if rot.ndim != 4 or rot.shape[1:] != (j, 3, 3):
        raise WrinklesInputError(f"rotations must have shape (T, {j}, 3, 3), got {rot.shape}")
    if tr.shape != (rot.shape[0], j, 3):
        raise WrinklesInputError(f"translations must have shape ({rot.shape[0]}, {j}, 3), got {tr.shape}")
    t, v = rot.shape[0], result.rest.shape[0]
    y = _lbs_columns(
        result.rest.astype(np.float64),
        result.weight_idx,
        result.weight_val.astype(np.float64),
        rot.astype(np.float64),
        tr.astype(np.float64),
    )
    return y.reshape(v, t, 3).transpose(1, 0, 2).astype(np.float32)


def fit_bone_transforms(
    rest: np.ndarray,
    weight_idx: np.ndarray,
    weight_val: np.ndarray,
    frames: np.ndarray,
    *,
    iterations: int = 3,
    chunk: int = 256,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame bone transforms of a fixed skeleton's weights (the SSDR bone step alone).

    Used to label every frame of a dataset with the virtual skeleton's transforms after the
    weights were fitted on a subset (Guo et al. 2024, Sec. 3.3: the CVAE's targets).
    Initialisation: each bone's rigid (Kabsch) fit to the vertices it dominates; then
    ``iterations`` rounds of per-bone weighted Procrustes on the residual (Le & Deng 2012).

    Args:
        rest: rest positions [m], (V, 3).
        weight_idx, weight_val: sparse weights (V, K) (``SSDRResult``).
        frames: positions [m], (T, V, 3).
        iterations: bone-update rounds.
        chunk: frames solved together (memory: V x 3 chunk float64).

    Returns:
        (rotations (T, J, 3, 3), translations (T, J, 3)), float32, J = weight_idx.max() + 1.
    """
    rest = np.asarray(rest, np.float64)
    frames = np.asarray(frames)
    idx = np.asarray(weight_idx, np.int64)
    val = np.asarray(weight_val, np.float64)
    if frames.ndim != 3 or frames.shape[1:] != rest.shape or idx.shape != val.shape or len(idx) != len(rest):
        raise WrinklesInputError(f"fit_bone_transforms: rest {rest.shape}, weights {idx.shape}/{val.shape} "
                                 "and "
                                 f"frames {frames.shape} do not fit together")
    j = int(idx.max()) + 1
    dominant = idx[np.arange(len(idx)), np.argmax(val, axis=1)]
    rots, trs = [], []
    for s in range(0, len(frames), chunk):
        prob = _Problem(rest, frames[s:s + chunk])
        t = prob.t
        rot = np.tile(np.eye(3), (t, j, 1, 1))
        tr = np.zeros((t, j, 3))
        xs = prob.x.reshape(prob.v, t, 3)
        for b in range(j):
            verts = np.flatnonzero(dominant == b)
            if verts.size == 0:
                verts = np.flatnonzero((idx == b).any(axis=1) & (val > 0).any(axis=1))
            if verts.size == 0:
                continue
            fit = _weighted_procrustes(prob.rest[verts], np.ones(len(verts)), xs[verts])
            if fit is not None:
                rot[:, b], tr[:, b] = fit
        y = _lbs_columns(prob.rest, idx, val, rot, tr)
        for _ in range(iterations):
            _update_bones(prob, rot, tr, idx, val, y)
            y = _lbs_columns(prob.rest, idx, val, rot, tr)
        rots.append(rot)
        trs.append(tr + prob.frame_center[:, None, :] - np.einsum("tjab,b->tja", rot, prob.rest_center))
    return np.concatenate(rots).astype(np.float32), np.concatenate(trs).astype(np.float32)
