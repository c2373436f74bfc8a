"""Issue 3: which solver settings pass the quality gates, and at what cost per frame.

The ~5k-vertex t-shirt of ``bench_tshirt`` on the default body, body and self contact on,
the full pipeline (settle, blend, motion; CUDA graph per frame), for several
substeps x iterations x self-contact detection intervals, on walk and run. Per setting:
ms per 30 fps frame of the motion and the gates' verdict; then the cheapest setting that passes
every gate on every motion is run batched (garment-frames per second).

    python -m benchmarks.sweep_tshirt --device cuda --batch 1,16,64,256
    python -m benchmarks.sweep_tshirt --device cpu --vertices 1000 --seconds 0.5 --settings 4x4,2x4
"""

from __future__ import annotations

import argparse
import json
import re

from benchmarks.bench_tshirt import (
    add_batch_arguments,
    add_scene_arguments,
    load_scene,
    run_batches,
    run_ours,
)
from benchmarks.common import machine, write_result

DEFAULT_SETTINGS = "10x10,10x5,5x10,5x5,10x10i2,5x5i2,4x4,3x5"


SETTING = re.compile(r"^(\d+)x(\d+)(?:i(\d+))?(?:m([\d.]+))?(?:c(\d+))?(?:r([\d.]+))?$")


def parse_setting(s: str) -> dict:
    """``"10x5i2m6c8r0.9"`` -> substeps 10, iterations 5, self-contact detection every 2
    substeps, smallest self-contact query radius 6 mm, 8 pairs stored per vertex / triangle /
    edge, Chebyshev acceleration with rho 0.9 (``i``, ``m``, ``c``, ``r`` optional, in this
    order: the solver's defaults)."""
    m = SETTING.match(s)
    if m is None:
        raise SystemExit(f"--settings: cannot read {s!r} "
                         "(SUBSTEPSxITERATIONS[iINTERVAL][mMILLIMETRES][cCAPACITY][rRHO])")
    out = {"substeps": int(m[1]), "iterations": int(m[2]), "interval": int(m[3] or 1)}
    out["solver"] = {"self_contact_interval": out["interval"]}
    if m[4]:
        out["solver"]["self_contact_margin"] = float(m[4]) / 1000.0
    if m[5]:
        out["solver"]["self_contact_capacity"] = int(m[5])
    if m[6]:
        out["solver"]["chebyshev_rho"] = float(m[6])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    ap.add_argument("--settings", default=DEFAULT_SETTINGS,
                    help="comma list of SUBSTEPSxITERATIONS[iINTERVAL] (default: %(default)s)")
    ap.add_argument("--solver", default="{}", help="JSON dict of VBDConfig fields shared by every setting")
    add_batch_arguments(ap)
    ap.add_argument("--tag", default="")
    args = ap.parse_args()

    from sim.simulate import SimulationConfig

    device, body, garment, edge, motions = load_scene(args)
    rows = []
    shared = json.loads(args.solver)
    for s in args.settings.split(","):
        p = parse_setting(s)
        p["solver"] = {**shared, **p["solver"]}
        cfg = SimulationConfig(fps=30.0, substeps=p["substeps"], iterations=p["iterations"],
                               self_contact=True, solver=p["solver"], device=device)
        row = {"setting": s, **p, "motions": {}}
        for name, motion in motions.items():
            out, _ = run_ours(garment, body, motion, cfg)
            row["motions"][name] = out
        row["passes"] = all("error" not in o and not o["failed_gates"] for o in row["motions"].values())
        row["ms_per_frame_worst"] = max(o.get("ms_per_frame", float("inf")) for o in row["motions"].values())
        rows.append(row)
        print(s, "passes" if row["passes"] else "FAILS",
              {n: (round(o["ms_per_frame"], 2) if "ms_per_frame" in o else o["error"],
                   o.get("failed_gates")) for n, o in row["motions"].items()}, flush=True)
    passing = [r for r in rows if r["passes"]]
    best = min(passing, key=lambda r: r["ms_per_frame_worst"]) if passing else None
    batch = {}
    if best is not None and args.batch:  # the cheapest passing setting, batched
        cfg = SimulationConfig(fps=30.0, substeps=best["substeps"], iterations=best["iterations"],
                               self_contact=True, solver=best["solver"], device=device)
        batch = run_batches(garment, body, next(iter(motions.values())), cfg, args)
    write_result(f"tshirt_sweep_{device.split(':')[0]}{args.tag}", {
        "machine": machine(device),
        "sizes": {"garment_vertices": garment.num_vertices, "garment_faces": garment.num_faces,
                  "edge_m": edge, "fps": 30.0, "seconds": args.seconds, "motions": list(motions)},
        "settings": rows,
        "cheapest_passing": None if best is None else best["setting"],
        "batched": batch,
    })


if __name__ == "__main__":
    main()
