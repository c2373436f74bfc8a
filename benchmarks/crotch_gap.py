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

MID_PLANE = 1e-6
"""Rest vertices with |x| below this [m] lie in the mid-sagittal plane (the bridge is built at x = 0)."""


def crotch_point(rest: np.ndarray) -> int:
    """Index of the lowest rest vertex in the plane x = 0 (the inseam point C of the pants template)."""
    on = np.flatnonzero(np.abs(rest[:, 0]) < MID_PLANE)
    if on.size == 0:
        raise ValueError("no garment vertex lies in the mid-plane x = 0 (not a pants template)")
    return int(on[np.argmin(rest[on, 1])])


def crotch_gap(x: np.ndarray, rest: np.ndarray, body: np.ndarray, body_faces: np.ndarray,
               window: float = 0.02) -> dict:
    """Per frame: C's drop below the body's crotch [mm] (NaN where no body crossing lies within
    ``window`` in z of C and above C - 1 cm) and C's distance to the nearest body vertex [mm].

    Args:
        x: garment positions (T, V, 3); rest: (V, 3); body: body positions (T, B, 3); body_faces (F, 3).
    """
    c = crotch_point(rest)
    drop, dist = [], []
    for f in range(len(x)):
        p = midplane_crossings(body[f], body_faces)
        cy, cz = float(x[f, c, 1]), float(x[f, c, 2])
        above = p[(np.abs(p[:, 2] - cz) < window) & (p[:, 1] > cy - 0.01)]
        drop.append(float(above[:, 1].min() - cy) * 1000.0 if len(above) else float("nan"))
        dist.append(float(np.linalg.norm(body[f] - x[f, c], axis=1).min()) * 1000.0)
    d = np.asarray(drop)
    return {"crotch_vertex": c, "rest_position": rest[c].tolist(), "drop_mm": d.round(1).tolist(),
            "nearest_body_mm": np.round(dist, 1).tolist(),
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
        print(f"frame {f}: C {r['drop_mm'][f]:.0f} mm below the body's crotch, "
              f"{r['nearest_body_mm'][f]:.0f} mm from the nearest body vertex")
    if args.tag:
        from benchmarks.common import write_result
        write_result(f"crotch_gap{args.tag}", {"file": args.npz, "window": args.window, **r})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
