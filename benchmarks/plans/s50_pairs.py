"""Session 50 scratch: the self-contact vertex-triangle pairs a saved frame holds within the
contact radius (worst_edges --save ... --keep-prelude), by rest distance and place, and the share
of particles within 3 / 4 / 6 mm of a non-incident triangle.
python benchmarks/plans/s50_pairs.py RUN.npz FRAME [RADIUS]"""
import sys

import numpy as np
from scipy.spatial import cKDTree


def point_triangle(p, a, b, c):
    """Closest points on triangles abc to points p (all (N, 3)), Ericson's regions, vectorised."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    den = np.where(np.abs(va + vb + vc) > 1e-30, va + vb + vc, 1e-30)
    v, w = vb / den, vc / den
    out = a + v[:, None] * ab + w[:, None] * ac
    # edge and vertex regions
    at_a, at_b, at_c = (d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (d6 >= 0) & (d5 <= d6)
    out[at_a], out[at_b], out[at_c] = a[at_a], b[at_b], c[at_c]
    m = (vc <= 0) & (d1 >= 0) & (d3 <= 0) & ~at_a & ~at_b
    t = d1[m] / np.where(d1[m] - d3[m] != 0, d1[m] - d3[m], 1e-30)
    out[m] = a[m] + t[:, None] * ab[m]
    m = (vb <= 0) & (d2 >= 0) & (d6 <= 0) & ~at_a & ~at_c
    t = d2[m] / np.where(d2[m] - d6[m] != 0, d2[m] - d6[m], 1e-30)
    out[m] = a[m] + t[:, None] * ac[m]
    m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0) & ~at_b & ~at_c
    t = (d4 - d3)[m] / np.where(((d4 - d3) + (d5 - d6))[m] != 0, ((d4 - d3) + (d5 - d6))[m], 1e-30)
    out[m] = b[m] + t[:, None] * (c - b)[m]
    return out


d = np.load(sys.argv[1])
f = int(sys.argv[2])
r = float(sys.argv[3]) if len(sys.argv) > 3 else 0.003
x, rest, faces = d["x"][f].astype(float), d["rest"].astype(float), d["faces"]
on = np.flatnonzero(np.abs(rest[:, 0]) < 1e-6)
cy = rest[on[np.argmin(rest[on, 1])], 1]
cent = x[faces].mean(1)
rad = np.linalg.norm(x[faces] - cent[:, None], axis=2).max(1)
tree = cKDTree(x)
pv, pt = [], []
for t, nb in enumerate(tree.query_ball_point(cent, rad + r)):
    nb = np.asarray(nb, int)
    nb = nb[(nb != faces[t, 0]) & (nb != faces[t, 1]) & (nb != faces[t, 2])]
    pv.append(nb)
    pt.append(np.full(len(nb), t))
pv, pt = np.concatenate(pv), np.concatenate(pt)
tri = faces[pt]
q = point_triangle(x[pv], x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]])
dist = np.linalg.norm(x[pv] - q, axis=1)
q0 = point_triangle(rest[pv], rest[tri[:, 0]], rest[tri[:, 1]], rest[tri[:, 2]])
d0 = np.linalg.norm(rest[pv] - q0, axis=1)
rp = np.where(d0 < r, 0.5 * d0, r)
act = dist < rp
print(f"frame {f}: {len(pv)} vertex-triangle pairs within {r * 1000:g} mm + the triangle's size; "
      f"{act.sum()} active (d < contact distance)")
n = (x[pv] - q) / np.maximum(dist, 1e-12)[:, None]
lam = 3.0e4 * (rp - dist)
bins = [0, 1, 2, 3, 4, 5, 6, 8, 10, 20, 50, 1000]
print("active pairs by rest distance [mm]:", np.histogram(d0[act] * 1000, bins)[0])
pen = 1000 * (rp - dist)[act]
print("  their penetration (contact distance - d) mean/max [mm]:",
      pen.mean().round(2) if act.any() else 0, pen.max().round(2) if act.any() else 0)
dy = rest[pv, 1] - cy
ax = np.abs(rest[pv, 0])
BANDS = ((0.06, 0.5), (0.02, 0.06), (0.0, 0.02), (-0.02, 0.0), (-0.05, -0.02), (-0.1, -0.05), (-0.5, -0.1))
for lo, hi in BANDS:
    row = []
    for a0, a1 in ((0, 0.002), (0.002, 0.01), (0.01, 0.03), (0.03, 0.08), (0.08, 1)):
        m = act & (dy >= lo) & (dy < hi) & (ax >= a0) & (ax < a1)
        near = m & (d0 < 0.01)
        row.append(f"{m.sum():5d}/{near.sum():5d}")
    print(f"  y-C in [{lo:+.2f},{hi:+.2f}) active / rest-near(<10mm): " + " ".join(row))
for m_ in (0.003, 0.004, 0.006):
    near = dist < m_
    flagged = np.zeros(len(x), bool)
    flagged[pv[near]] = True
    flagged[tri[near].ravel()] = True
    print(f"particles in a vertex-triangle pair closer than {m_ * 1000:g} mm now: "
          f"{flagged.mean() * 100:.1f} % (pairs {near.sum()}, "
          f"rest distance < 10 mm: {(near & (d0 < 0.01)).sum()})")
