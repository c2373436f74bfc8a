"""Issue 3: which solver settings pass the quality gates, and at what cost per frame.

The ~5k-vertex t-shirt of ``bench_tshirt`` on the default body, body and self contact on,
the full pipeline (settle, blend, motion; CUDA graph per frame), for several
substeps x iterations x self-contact detection intervals, on walk and run. Per setting:
ms per 30 fps frame of the motion and the gates' verdict; then the cheapest setting that passes
every gate on every motion is run batched (garment-frames per second).

One trajectory is one sample of a chaotic system: a setting that passes walk and run may fail
the same motions a little faster, and changes far below the gates' resolution move crossings in
and out (session 17). ``--population N`` therefore also runs, per setting, N sequences in one
batched model (``population_motions``: the benchmark's walk and run, then walks and runs of
other speeds and arm swings, seeded) and records how many pass every gate; a setting passes
only when all of them and the single walk and run do.

Every setting runs with the job default's coarse-level correction before sweep 2
(``SimulationConfig.coarse_sweeps``); ``--solver '{"coarse_sweeps": []}'`` runs without.

    python -m benchmarks.sweep_tshirt --device cuda --batch 1,16,64,256
    python -m benchmarks.sweep_tshirt --device cuda --settings 15x10,10x10 --population 16
    python -m benchmarks.sweep_tshirt --device cpu --vertices 1000 --seconds 0.5 --settings 4x4,2x4
"""

from __future__ import annotations

import argparse
import json
import re

import numpy as np

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
    order; a field left out is --solver's or the solver's default: without ``i`` the interval
    is None here)."""
    m = SETTING.match(s)
    if m is None:
        raise SystemExit(f"--settings: cannot read {s!r} "
                         "(SUBSTEPSxITERATIONS[iINTERVAL][mMILLIMETRES][cCAPACITY][rRHO])")
    out = {"substeps": int(m[1]), "iterations": int(m[2]), "interval": int(m[3]) if m[3] else None,
           "solver": {}}
    if m[3]:  # without ``i``, the interval of --solver (or the solver's default) holds
        out["solver"]["self_contact_interval"] = int(m[3])
    if m[4]:
        out["solver"]["self_contact_margin"] = float(m[4]) / 1000.0
    if m[5]:
        out["solver"]["self_contact_capacity"] = int(m[5])
    if m[6]:
        out["solver"]["chebyshev_rho"] = float(m[6])
    return out


def population_motions(n: int, seconds: float, seed: int = 0, body=None, skeleton: str = "body") -> list:
    """``n`` motions of ``seconds`` at 30 fps: the benchmark's walk and run (default parameters)
    first, then walks and runs alternating with speeds drawn uniformly from 1.0-1.8 m/s (walk)
    and 2.8-4.5 m/s (run), arm swing from 0.7-1.4 (``seed``: the draw); built on ``body``'s own
    skeleton (None: the default body) or, with ``skeleton="default"``, on SMPL's approximate one
    (``bench_tshirt.benchmark_motion``)."""
    from benchmarks.bench_tshirt import benchmark_motion
    from sim.bodies.default import load_default_body

    body = load_default_body() if body is None else body
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        name = ("walk", "run")[k % 2]
        params = {}
        if k >= 2:
            lo, hi = (1.0, 1.8) if name == "walk" else (2.8, 4.5)
            params = {"speed": round(float(rng.uniform(lo, hi)), 3),
                      "arm_swing": round(float(rng.uniform(0.7, 1.4)), 3)}
        m = benchmark_motion(name, body, seconds, skeleton, **params)
        out.append((name + "".join(f" {k}={v}" for k, v in params.items()), m))
    return out


def run_population(garment, body, motions: list, cfg) -> dict:
    """The ``population_motions`` in one batched model (a sequence that blows up is frozen and
    counted as failing): how many pass every gate, and which gates the others failed."""
    import time

    from sim.quality import SimulationError
    from sim.simulate import SimulationJob, simulate_batch

    jobs = [SimulationJob(garment, body, m, None, name=label) for label, m in motions]
    t0 = time.perf_counter()
    results = simulate_batch(jobs, config=cfg, failures="return")
    members = []
    for (label, _), r in zip(motions, results, strict=True):
        if isinstance(r, SimulationError):
            members.append({"motion": label, "passed": False, "error": str(r)})
        else:
            q = r.quality
            members.append({"motion": label, "passed": bool(r.passed), "failed_gates": list(r.failed_gates),
                            "max_edge_strain": q.max_edge_strain,
                            "inside_fraction_max": float(np.max(q.inside_fraction)),
                            "self_intersections_max": int(np.max(q.self_intersections))})
    return {"size": len(members), "passing": sum(m["passed"] for m in members),
            "wall_s": time.perf_counter() - t0, "members": members}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    ap.add_argument("--settings", default=DEFAULT_SETTINGS,
                    help="comma list of SUBSTEPSxITERATIONS[iINTERVAL] (default: %(default)s)")
    ap.add_argument("--solver", default="{}", help="JSON dict of VBDConfig fields shared by every setting")
    ap.add_argument("--population", type=int, default=0,
                    help="also run N walks and runs of varied speed per setting in one batch; a setting "
                    "passes only when all N do (default: %(default)s, off)")
    ap.add_argument("--population-seed", type=int, default=0, help="seed of the population's speeds")
    add_batch_arguments(ap)
    ap.add_argument("--tag", default="")
    args = ap.parse_args()

    from sim.cloth import VBDConfig
    from sim.simulate import SimulationConfig

    device, body, garment, edge, motions = load_scene(args)
    rows = []
    shared = json.loads(args.solver)
    population = (population_motions(args.population, args.seconds, args.population_seed, body,
                                    args.motion_skeleton)
                  if args.population > 0 else [])
    for s in args.settings.split(","):
        p = parse_setting(s)
        p["solver"] = {**shared, **p["solver"]}
        p["interval"] = int(p["solver"].get("self_contact_interval", VBDConfig.self_contact_interval))
        cfg = SimulationConfig(fps=30.0, substeps=p["substeps"], iterations=p["iterations"],
                               self_contact=True, solver=p["solver"], device=device)
        row = {"setting": s, **p, "motions": {}}
        for name, motion in motions.items():
            out, _ = run_ours(garment, body, motion, cfg)
            row["motions"][name] = out
        row["passes"] = all("error" not in o and not o["failed_gates"] for o in row["motions"].values())
        row["ms_per_frame_worst"] = max(o.get("ms_per_frame", float("inf")) for o in row["motions"].values())
        if population:
            row["population"] = run_population(garment, body, population, cfg)
            row["passes"] = row["passes"] and row["population"]["passing"] == row["population"]["size"]
        rows.append(row)
        print(s, "passes" if row["passes"] else "FAILS",
              {n: (round(o["ms_per_frame"], 2) if "ms_per_frame" in o else o["error"],
                   o.get("failed_gates")) for n, o in row["motions"].items()},
              "" if not population else
              f"population {row['population']['passing']}/{row['population']['size']} pass "
              f"{[m['motion'] for m in row['population']['members'] if not m['passed']]}", flush=True)
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
        "population": [label for label, _ in population],
        "settings": rows,
        "cheapest_passing": None if best is None else best["setting"],
        "batched": batch,
    })


if __name__ == "__main__":
    main()
