"""The 5k t-shirt on the default body, walk and run, body and self-contact on: milliseconds per
30 fps frame and the quality gates; optionally Newton's ``SolverVBD`` on the same scene in the
same process (``--newton``); optionally garment-frames per second of N t-shirts in one model
(``--batch``).

    python -m benchmarks.bench_tshirt --device cuda --motions walk,run --seconds 2 --newton
    python -m benchmarks.bench_tshirt --device cuda --motions walk --seconds 0.5 --batch 128 \
        --batch-prelude 0.2
    python -m benchmarks.bench_tshirt --device cpu --vertices 1000 --motions walk,run --seconds 1

Our side runs the whole job (``benchmarks.scene.run_ours``) at its defaults
(``sim.simulate.SimulationConfig``); ``--substeps``, ``--iterations`` and ``--solver`` change them.
Newton starts from our dressed state at the motion's first frame and plays the same body frames
at the same substeps x sweeps (``benchmarks/newton_ref.py``). Quality for both: ``sim.quality``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from benchmarks.common import add_results_argument, machine, write_result
from benchmarks.scene import (
    FPS,
    add_batch_arguments,
    add_scene_arguments,
    load_scene,
    quality_dict,
    run_batches,
    run_ours,
    scene_sizes,
)


def newton_scene(r, garment, body, fps: float) -> dict:
    """The scene dict of ``newton_ref.run_newton_vbd`` for our result ``r``: the garment from its
    first motion frame, its material, its hems' layers and the body frames it played."""
    from sim.cloth.model import as_cloth_params

    seq = r.sequence
    mat = as_cloth_params(garment.material)
    return {
        "garment_positions": seq.vertices[0], "garment_rest_positions": garment.rest_vertices,
        "garment_faces": garment.faces, "face_layers": garment.face_layers, "pinned": np.zeros(0, np.int64),
        "pin_targets": np.zeros((0, 0, 3), np.float32),
        "density": mat.density, "mu": mat.mu, "lam": mat.lam, "bending": mat.bending, "damping": mat.damping,
        "friction": mat.friction, "thickness": mat.thickness,
        "body_faces": body.faces, "body_vertices": seq.body.vertices, "fps": fps,
    }


def run_newton(r, garment, body, cfg, device: str) -> dict:
    """Newton's figures on the scene of our result ``r``, at our substeps x sweeps."""
    from benchmarks.newton_ref import run_newton_vbd
    from sim.quality import evaluate_sequence

    t0 = time.perf_counter()
    res = run_newton_vbd(newton_scene(r, garment, body, cfg.fps), device=device,
                         substeps=cfg.substeps_for(garment.num_vertices),
                         iterations=cfg.iterations_for(garment.num_vertices),
                         self_contact=True, use_graph=device.startswith("cuda"))
    q = evaluate_sequence(res["positions"], garment.rest_vertices, garment.faces, r.sequence.body.vertices,
                          body.faces, device=device)
    return {"ms_per_frame": res["ms_per_frame"], "graph": res.get("graph"), "quality": quality_dict(q),
            "newton_version": res.get("newton_version"), "notes": res.get("notes"),
            "wall_s": time.perf_counter() - t0}


def parse_args() -> argparse.Namespace:
    from sim.simulate import SimulationConfig

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    ap.add_argument("--substeps", type=int, default=SimulationConfig.substeps,
                    help="substeps per frame (default 0: the job's, 12, or 14 over 10k vertices)")
    ap.add_argument("--iterations", type=int, default=SimulationConfig.iterations,
                    help="sweeps per substep (default 0: the job's, 5, or 8 over 10k vertices)")
    ap.add_argument("--no-self-contact", action="store_true")
    ap.add_argument("--solver", default="{}", help='JSON dict of solver settings, "section.field": value '
                    '(SimulationConfig.solver), e.g. \'{"layout.lanes": 16}\'')
    ap.add_argument("--newton", action="store_true", help="also run Newton's SolverVBD (needs newton)")
    add_batch_arguments(ap)
    ap.add_argument("--tag", default="", help="suffix of the result file's name")
    add_results_argument(ap)
    return ap.parse_args()


def main() -> None:
    from sim.simulate import SimulationConfig

    args = parse_args()
    device, body, garment, edge, motions = load_scene(args)
    cfg = SimulationConfig(fps=FPS, substeps=args.substeps, iterations=args.iterations,
                           self_contact=not args.no_self_contact, solver=json.loads(args.solver),
                           device=device)
    fig: dict = {}
    for name, motion in motions.items():
        ours, r = run_ours(garment, body, motion, cfg)
        fig[name] = {"ours": ours}
        print(name, "ours", json.dumps(ours, indent=1), flush=True)
        if args.newton and r is not None:
            try:
                fig[name]["newton"] = run_newton(r, garment, body, cfg, device)
            except Exception as e:  # reported in the result, not raised: our figures stand alone
                fig[name]["newton"] = {"error": f"{type(e).__name__}: {e}"}
            print(name, "newton", json.dumps(fig[name]["newton"], indent=1, default=str), flush=True)
    if args.batch:
        fig["batched"] = run_batches(garment, body, next(iter(motions.values())), cfg, args)
    sizes = scene_sizes(garment, body, edge, args)
    sizes.update(substeps=cfg.substeps_for(garment.num_vertices),
                 iterations=cfg.iterations_for(garment.num_vertices), self_contact=not args.no_self_contact)
    write_result(f"tshirt_{device.split(':')[0]}{args.tag}",
                 {"machine": machine(device), "sizes": sizes, "config": cfg.to_dict(), "figures": fig},
                 args.results)


if __name__ == "__main__":
    main()
