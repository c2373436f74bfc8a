"""How far a pair of pants' crotch point hangs below the body's crotch, frame by frame (session 47).

Reads the per-motion file that ``benchmarks.worst_edges --save PATH`` writes (``PATH_run.npz``:
the garment's rest mesh and positions per frame, the body's positions and faces). The crotch
point C is the pattern's inseam point: the lowest rest vertex in the mid-sagittal plane x = 0
(the pants template's bridge F -> C -> B lies in that plane, ``sim.garments.templates``). Per
frame it reports how far C lies below the lowest point where the body's surface crosses the plane
x = 0 within ``--window`` (z) of C and no lower than 1 cm below C (the body's crotch above C), and
C's distance to the nearest body vertex. At rest C hangs the bridge's depth (about 3 cm) below the
crotch; where it hangs far lower, the legs' inner walls are pulled into a web between the thighs.

    python -m benchmarks.worst_edges --device cuda --garment trousers --vertices 20000 --motion run \\
        --save /tmp/tr.npz
    python -m benchmarks.crotch_gap /tmp/tr_run.npz --tag _fine_run

Writes ``benchmarks/results/crotch_gap<tag>.json`` (``--tag``; nothing without it).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from sim.garments.templates import midplane_crossings

BELOW = (0.01, 0.03, 0.05, 0.08)
"""Depths below the body's crotch [m] at which ``thigh_gap`` measures the room between the thighs."""

MID_PLANE = 1e-6
"""Rest vertices with |x| below this [m] lie in the mid-sagittal plane (the bridge is built at x = 0)."""


def crotch_point(rest: np.ndarray) -> int:
    """Index of the lowest rest vertex in the plane x = 0 (the inseam point C of the pants template)."""
    on = np.flatnonzero(np.abs(rest[:, 0]) < MID_PLANE)
    if on.size == 0:
        raise ValueError("no garment vertex lies in the mid-plane x = 0 (not a pants template)")
    return int(on[np.argmin(rest[on, 1])])


def thigh_gap(body: np.ndarray, faces: np.ndarray, y, z: float):
    """Room between the thighs [m] along the line (y, z) parallel to x: the distance between the
    nearest points where that line crosses the body's surface on either side of the plane x = 0
    (inf where it misses a side); ``y`` a height or an array of them (one triangle setup for
    all). Crossings are found in the (y, z) projection of every triangle.
    It assumes the plane x = 0 runs between the thighs (the body not turned or swayed far from it)
    and cannot go negative: thighs pressed into each other read as the width of their overlap."""
    t = body[faces]  # (F, 3, 3)
    a, b, c = t[:, 0, 1:], t[:, 1, 1:], t[:, 2, 1:]
    d = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(d) > 1e-14
    ds = np.where(ok, d, 1.0)
    gaps = []
    for yk in np.atleast_1d(y):
        u = ((b[:, 0] - yk) * (c[:, 1] - z) - (c[:, 0] - yk) * (b[:, 1] - z)) / ds
        v = ((c[:, 0] - yk) * (a[:, 1] - z) - (a[:, 0] - yk) * (c[:, 1] - z)) / ds
        w = 1.0 - u - v
        hit = ok & (u >= 0) & (v >= 0) & (w >= 0)
        xs = (u[:, None] * t[:, 0, :1] + v[:, None] * t[:, 1, :1] + w[:, None] * t[:, 2, :1])[hit, 0]
        pos, neg = xs[xs > 0], xs[xs < 0]
        gaps.append(float(pos.min() - neg.max()) if len(pos) and len(neg) else float("inf"))
    return gaps[0] if np.ndim(y) == 0 else np.asarray(gaps)


def crotch_gap(x: np.ndarray, rest: np.ndarray, body: np.ndarray, body_faces: np.ndarray,
               window: float = 0.02) -> dict:
    """Per frame: C's drop below the body's crotch [mm] (NaN where no body crossing lies within
    ``window`` in z of C and above C - 1 cm), C's distance to the nearest body vertex [mm] and the
    room between the thighs ``BELOW`` the body's crotch at C's z (``thigh_gap``) [mm].

    Args:
        x: garment positions (T, V, 3); rest: (V, 3); body: body positions (T, B, 3); body_faces (F, 3).
    """
    c = crotch_point(rest)
    drop, dist, gaps = [], [], []
    for f in range(len(x)):
        p = midplane_crossings(body[f], body_faces)
        cy, cz = float(x[f, c, 1]), float(x[f, c, 2])
        above = p[(np.abs(p[:, 2] - cz) < window) & (p[:, 1] > cy - 0.01)]
        crotch = float(above[:, 1].min()) if len(above) else float("nan")
        drop.append((crotch - cy) * 1000.0)
        dist.append(float(np.linalg.norm(body[f] - x[f, c], axis=1).min()) * 1000.0)
        gaps.append(thigh_gap(body[f], body_faces, crotch - np.asarray(BELOW), cz) * 1000.0)
    d = np.asarray(drop)
    g = np.asarray(gaps).reshape(-1, len(BELOW))
    return {"crotch_vertex": c, "rest_position": rest[c].tolist(), "drop_mm": d.round(1).tolist(),
            "nearest_body_mm": np.round(dist, 1).tolist(), "thigh_gap_below_m": list(BELOW),
            "thigh_gap_mm": g.round(1).tolist(),
            "least_thigh_gap_mm": [round(float(col[np.isfinite(col)].min()), 1) if np.isfinite(col).any()
                                   else float("nan") for col in g.T],
            "first_frame_drop_mm": float(d[0]), "max_drop_mm": float(np.nanmax(d)) if np.isfinite(d).any()
            else float("nan")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("npz", help="a file of `worst_edges --save` (PATH_run.npz)")
    ap.add_argument("--window", type=float, default=0.02,
                    help="z distance [m] from C within which the body's crotch is sought (default: 0.02)")
    ap.add_argument("--every", type=int, default=4, help="print every N-th frame (default: 4)")
    ap.add_argument("--tag", default="", help="write benchmarks/results/crotch_gap<TAG>.json")
    args = ap.parse_args(argv)
    try:
        d = np.load(args.npz)
        x, rest, body, bf = d["x"], d["rest"], d["body"], d["body_faces"]
        r = crotch_gap(x.astype(np.float32), rest, body.astype(np.float32), bf, args.window)
    except (OSError, KeyError, ValueError) as e:
        print(f"crotch_gap: {args.npz}: {e}", file=sys.stderr)
        return 2
    for f in range(0, len(r["drop_mm"]), max(args.every, 1)):
        gap = " / ".join(f"{v:.0f}" for v in r["thigh_gap_mm"][f])
        print(f"frame {f}: C {r['drop_mm'][f]:.0f} mm below the body's crotch, "
              f"{r['nearest_body_mm'][f]:.0f} mm from the nearest body vertex; thighs {gap} mm apart "
              f"{' / '.join(f'{b * 100:g}' for b in BELOW)} cm below the crotch")
    print(f"C's largest drop {r['max_drop_mm']:.0f} mm; the thighs' least gaps "
          f"{' / '.join(f'{v:.0f}' for v in r['least_thigh_gap_mm'])} mm")
    if args.tag:
        from benchmarks.common import write_result
        write_result(f"crotch_gap{args.tag}", {"file": args.npz, "window": args.window, **r})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
