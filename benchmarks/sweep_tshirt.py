"""Which solver settings pass the quality gates, and at what cost per frame: the 5k t-shirt of
``bench_tshirt`` at several substeps x sweeps, each on the single walk and run (timed) and, with
``--population N``, on N sequences in one batched model: the benchmark's walk and run, then walks
and runs of other speeds and arm swings drawn from ``--population-seed``. A setting passes when
the single walk and run and every member of its population pass every gate.

One trajectory is one sample of a chaotic system: a change far below the gates' resolution moves
a crossing in or out of a single run, so the population's pass count is the verdict on a setting
(48 sequences resolve it to about +-3).

    python -m benchmarks.sweep_tshirt --device cuda --seconds 2 --settings 12x5 --population 48 \
        --population-seed 0
    python -m benchmarks.sweep_tshirt --device cpu --vertices 1000 --seconds 0.5 --settings 4x4,2x4
"""

from __future__ import annotations

import argparse
import json
import re
import time

import numpy as np

from benchmarks.common import add_results_argument, machine, write_result
from benchmarks.scene import (
    FPS,
    add_batch_arguments,
    add_scene_arguments,
    benchmark_motion,
    load_scene,
    option_error,
    run_batches,
    run_ours,
    scene_sizes,
)

SETTING = re.compile(r"^(\d+)x(\d+)$")
WALK_SPEEDS = (1.0, 1.8)  # [m/s], drawn uniformly
RUN_SPEEDS = (2.8, 4.5)  # [m/s]
ARM_SWINGS = (0.7, 1.4)  # [-], the procedural gait's arm swing scale


def parse_setting(s: str) -> tuple[int, int]:
    """``"12x5"`` -> (12 substeps, 5 sweeps per substep); else exit 2 with a one-line error."""
    m = SETTING.match(s)
    if m is None:
        option_error("--settings", ValueError(f"cannot read {s!r} (SUBSTEPSxITERATIONS, e.g. 12x5)"))
    return int(m[1]), int(m[2])


def population_motions(n: int, seconds: float, seed: int, body) -> list:
    """``n`` (label, motion) pairs of ``seconds`` at 30 fps on ``body``'s skeleton: the benchmark's
    walk and run first, then walks and runs in turn at speeds drawn from ``WALK_SPEEDS`` /
    ``RUN_SPEEDS`` and arm swings from ``ARM_SWINGS``."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        name = ("walk", "run")[k % 2]
        params = {}
        if k >= 2:
            lo, hi = WALK_SPEEDS if name == "walk" else RUN_SPEEDS
            params = {"speed": round(float(rng.uniform(lo, hi)), 3),
                      "arm_swing": round(float(rng.uniform(*ARM_SWINGS)), 3)}
        label = name + "".join(f" {k}={v}" for k, v in params.items())
        out.append((label, benchmark_motion(name, body, seconds, **params)))
    return out


def run_population(garment, body, motions: list, cfg) -> dict:
    """The ``population_motions`` in one batched model (a sequence that stops is frozen and counts
    as failing): how many pass every gate, and what the others failed."""
    from sim.quality import SimulationError
    from sim.simulate import SimulationJob, simulate_batch

    jobs = [SimulationJob(garment, body, m, None, name=label) for label, m in motions]
    t0 = time.perf_counter()
    results = simulate_batch(jobs, config=cfg, failures="return")
    members = []
    for (label, _), r in zip(motions, results, strict=True):
        if isinstance(r, SimulationError):
            members.append({"motion": label, "passed": False, "error": str(r)})
            continue
        q = r.quality
        members.append({"motion": label, "passed": bool(r.passed), "failed_gates": list(r.failed_gates),
                        "max_edge_strain": q.max_edge_strain,
                        "inside_fraction_max": float(np.max(q.inside_fraction)),
                        "self_intersections_max": int(np.max(q.self_intersections))})
    return {"size": len(members), "passing": sum(m["passed"] for m in members),
            "wall_s": time.perf_counter() - t0, "members": members}


def run_setting(setting: str, scene: tuple, population: list, args: argparse.Namespace) -> dict:
    """The singles (and the population) of one ``SUBSTEPSxITERATIONS`` setting."""
    from sim.simulate import SimulationConfig

    device, body, garment, _, motions = scene
    substeps, iterations = parse_setting(setting)
    cfg = SimulationConfig(fps=FPS, substeps=substeps, iterations=iterations, self_contact=True,
                           solver=json.loads(args.solver), device=device)
    row = {"setting": setting, "substeps": substeps, "iterations": iterations, "motions": {}}
    for name, motion in motions.items():
        row["motions"][name], _ = run_ours(garment, body, motion, cfg)
    row["passes"] = all("error" not in o and not o["failed_gates"] for o in row["motions"].values())
    row["ms_per_frame_worst"] = max(o.get("ms_per_frame", float("inf")) for o in row["motions"].values())
    if population:
        row["population"] = run_population(garment, body, population, cfg)
        row["passes"] = row["passes"] and row["population"]["passing"] == row["population"]["size"]
    return row


def report(row: dict) -> None:
    """One line per setting: its verdict, the singles' ms and failed gates, the population."""
    singles = {n: (round(o["ms_per_frame"], 2) if "ms_per_frame" in o else o["error"], o.get("failed_gates"))
               for n, o in row["motions"].items()}
    pop = row.get("population")
    tail = "" if pop is None else (f"population {pop['passing']}/{pop['size']} pass, failing: "
                                   f"{[m['motion'] for m in pop['members'] if not m['passed']]}")
    print(row["setting"], "passes" if row["passes"] else "FAILS", singles, tail, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    ap.add_argument("--settings", default="12x5",
                    help="comma list of SUBSTEPSxITERATIONS (default: %(default)s)")
    ap.add_argument("--solver", default="{}", help='JSON dict of solver settings shared by every setting, '
                    '"section.field": value (SimulationConfig.solver)')
    ap.add_argument("--population", type=int, default=0,
                    help="also run N walks and runs of varied speed per setting in one batch "
                    "(default: 0, none)")
    ap.add_argument("--population-seed", type=int, default=0,
                    help="seed of the population's speeds and arm swings")
    add_batch_arguments(ap)
    ap.add_argument("--tag", default="", help="suffix of the result file's name")
    add_results_argument(ap)
    args = ap.parse_args()
    settings = args.settings.split(",")
    for s in settings:
        parse_setting(s)
    scene = load_scene(args)
    device, body, garment, edge, motions = scene
    population = (population_motions(args.population, args.seconds, args.population_seed, body)
                  if args.population > 0 else [])
    rows = []
    for s in settings:
        rows.append(run_setting(s, scene, population, args))
        report(rows[-1])
    passing = [r for r in rows if r["passes"]]
    best = min(passing, key=lambda r: r["ms_per_frame_worst"]) if passing else None
    batch = {}
    if best is not None and args.batch:  # the cheapest passing setting, batched
        from sim.simulate import SimulationConfig

        cfg = SimulationConfig(fps=FPS, substeps=best["substeps"], iterations=best["iterations"],
                               self_contact=True, solver=json.loads(args.solver), device=device)
        batch = run_batches(garment, body, next(iter(motions.values())), cfg, args)
    write_result(f"tshirt_sweep_{device.split(':')[0]}{args.tag}", {
        "machine": machine(device), "sizes": scene_sizes(garment, body, edge, args),
        "population": [label for label, _ in population], "population_seed": args.population_seed,
        "settings": rows, "cheapest_passing": None if best is None else best["setting"], "batched": batch,
    }, args.results)


if __name__ == "__main__":
    main()
