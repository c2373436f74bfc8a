"""Every garment template through the walk and the run at the job default and at solver variants:
ms per frame, max edge strain, worst inside fraction, crossings and the gates, side by side.

The t-shirt populations (``sweep_tshirt``) decide the defaults; this checks that a default chosen
on the t-shirt does not fail the other templates (session 42: ``coarse_early`` against the
coarse system prepared after the detection).

    python -m benchmarks.garment_gates --device cuda --variants '[{}, {"coarse_early": false}]'
    python -m benchmarks.garment_gates --device cuda --garments tank_top,dress --param armhole_depth=0.06
"""

from __future__ import annotations

import argparse
import json

from benchmarks.bench_tshirt import add_skeleton_argument, build_garment, quality_dict, run_ours
from benchmarks.common import machine, write_result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--garments", default="all", help="template names, comma-separated (default: all)")
    ap.add_argument("--vertices", type=int, default=0,
                    help="about this many vertices per garment (default 0: each template's coarse size)")
    ap.add_argument("--motions", default="walk,run")
    ap.add_argument("--seconds", type=float, default=2.0, help="motion length [s] (default: %(default)s)")
    ap.add_argument("--variants", default="[{}]",
                    help="JSON list of solver overrides (VBDConfig fields) run per garment and motion; "
                    "{} is the job default (default: %(default)s)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="a template parameter for every garment run (each must have it; repeatable; "
                    "default: the templates' own)")
    add_skeleton_argument(ap)
    ap.add_argument("--tag", default="")
    args = ap.parse_args()
    from benchmarks.bench_tshirt import _numbers, benchmark_motion
    from sim.bodies.default import load_default_body
    from sim.device import resolve_device
    from sim.errors import WrinklesInputError
    from sim.garments.templates import TEMPLATES, make_params
    from sim.simulate import SimulationConfig

    names = list(TEMPLATES) if args.garments == "all" else args.garments.split(",")
    unknown = [n for n in names if n not in TEMPLATES]
    if unknown:
        raise SystemExit(f"garment_gates: unknown template(s) {unknown}; expected {sorted(TEMPLATES)}")
    params = _numbers(args.param, "--param", lambda out: [make_params(n, **out) for n in names])
    try:
        variants = json.loads(args.variants)
        assert isinstance(variants, list) and all(isinstance(v, dict) for v in variants)
    except (ValueError, AssertionError):
        raise SystemExit(f"garment_gates: --variants must be a JSON list of objects, got "
                         f"{args.variants!r}") from None
    device = resolve_device(args.device)
    body = load_default_body()
    motions = {n: benchmark_motion(n, body, args.seconds, args.motion_skeleton)
               for n in args.motions.split(",")}
    figures: dict = {}

    def write() -> None:  # after every garment: a run cut short by a time limit keeps what it measured
        write_result(f"garment_gates_{device.split(':')[0]}{args.tag}", {
            "machine": machine(device),
            "sizes": {"seconds": args.seconds, "vertices": args.vertices or "template coarse",
                      "motion_skeleton": args.motion_skeleton},
            "variants": variants, "params": params, "figures": figures,
            "complete": len(figures) == len(names)})

    for name in names:
        garment, _ = build_garment(body, args.vertices or TEMPLATES[name].vertices[0], category=name,
                                   **params)
        figures[name] = {"vertices": garment.num_vertices, "runs": {}}
        for motion_name, motion in motions.items():
            for k, solver in enumerate(variants):
                try:
                    cfg = SimulationConfig(fps=30.0, self_contact=True, solver=solver, device=device)
                except WrinklesInputError as e:
                    raise SystemExit(f"garment_gates: variant {solver}: {e}") from None
                out, r = run_ours(garment, body, motion, cfg)
                row = {"solver": solver, "ms_per_frame": out.get("ms_per_frame"), "error": out.get("error"),
                       "failed_gates": out.get("failed_gates"),
                       "quality": quality_dict(r.quality) if r is not None else None}
                figures[name]["runs"][f"{motion_name}/{k}"] = row
                q = row["quality"] or {}
                ms = row["ms_per_frame"] or float("nan")
                strain = q.get("max_edge_strain", float("nan"))
                verdict = row["failed_gates"] or row["error"] or "pass"
                print(f"{name:15s} {garment.num_vertices:6d} {motion_name:5s} variant {k} {ms:7.2f} ms  "
                      f"strain {strain:.3f}  crossings {q.get('self_intersections_max')}  {verdict}",
                      flush=True)
        write()


if __name__ == "__main__":
    main()
