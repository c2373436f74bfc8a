"""Where a t-shirt run's edge strain sits: its most stretched edges, with place and shape.

One run of the benchmark t-shirt (``bench_tshirt.build_garment``) on the default body at the
job defaults (``SimulationConfig``; ``--solver`` adds ``VBDConfig`` fields), then per mesh edge
the largest strain ``l / l0 - 1`` over the motion's frames. Written: the run's maximum and mean
strain, how many edges exceed 0.2 and the 0.35 gate, and the worst edges with their frame, rest
length, triangles per end vertex, panel and rest position. The max-strain gate is set by a few
edges; this shows whether they sit at a feature of the pattern (session 26: the neckline's
square corners) or spread over the garment.

    python -m benchmarks.worst_edges --device cuda --vertices 20000 --motion run --tag _19k_run
    python -m benchmarks.worst_edges --device cpu --vertices 1000 --seconds 0.5 --param neck_fillet=0
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from benchmarks.common import machine, write_result


def main() -> None:
    from benchmarks.bench_tshirt import build_garment
    from sim.bodies.default import load_default_body
    from sim.device import resolve_device
    from sim.garments import make_garment
    from sim.motions import load_motion
    from sim.quality import edge_strain, unique_edges
    from sim.simulate import SimulationConfig, SimulationJob, simulate_batch

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--vertices", type=int, default=5000, help="t-shirt size (default: %(default)s)")
    ap.add_argument("--motion", default="walk")
    ap.add_argument("--seconds", type=float, default=2.0, help="motion length [s]")
    ap.add_argument("--solver", default="{}", help="JSON dict of extra VBDConfig fields")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="a t-shirt template parameter, e.g. neck_fillet=0 (repeatable)")
    ap.add_argument("--worst", type=int, default=15, help="edges to list (default: %(default)s)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()
    params = {}
    for item in args.param:
        name, _, value = item.partition("=")
        try:
            params[name] = float(value)
        except ValueError:
            raise SystemExit(f"--param: expected NAME=NUMBER, got {item!r}") from None
    device = resolve_device(args.device)
    body = load_default_body()
    _, edge = build_garment(body, args.vertices)
    g = make_garment("t_shirt", body, None, resolution=edge, **params)
    motion = load_motion(args.motion, fps=30.0, duration=args.seconds)
    cfg = SimulationConfig(device=device, solver=json.loads(args.solver))
    t0 = time.perf_counter()
    r = simulate_batch([SimulationJob(g, body, motion, None)], config=cfg, failures="raise")[0]
    wall = time.perf_counter() - t0
    # the quality gates' own strain (l / l0 - 1 per edge and frame), so the worst edge is the gate's
    rest = g.rest_vertices
    e = unique_edges(g.faces)
    strain = edge_strain(r.sequence.vertices, rest, g.faces, device=device)
    worst = strain.max(axis=0)
    tris = np.bincount(g.faces.ravel(), minlength=len(rest))
    panel = np.full(len(rest), -1)
    panel[g.faces.ravel()] = np.repeat(g.panel_ids, 3)
    rows = []
    for k in np.argsort(-worst)[: args.worst]:
        a, b = (int(i) for i in e[k])
        rows.append({"edge": [a, b], "strain": float(worst[k]), "frame": int(strain[:, k].argmax()),
                     "rest_length_mm": float(1000.0 * np.linalg.norm(rest[a] - rest[b])),
                     "triangles": [int(tris[a]), int(tris[b])], "panel": g.panel_names[panel[a]],
                     "rest_position": np.round(rest[a], 4).tolist()})
    write_result(f"worst_edges_{device.split(':')[0]}{args.tag}", {
        "machine": machine(device), "vertices": len(rest), "motion": args.motion, "seconds": args.seconds,
        "solver": json.loads(args.solver), "params": params, "wall_s": wall,
        "ms_per_frame": float(np.mean(r.step_ms)), "failed_gates": list(r.failed_gates),
        "max_strain": float(worst.max()), "mean_strain": float(np.abs(strain).mean()),
        "edges_over_0.2": int((worst > 0.2).sum()), "edges_over_0.35": int((worst > 0.35).sum()),
        "worst": rows,
    })


if __name__ == "__main__":
    main()
