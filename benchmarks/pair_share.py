"""Share of particles with stored self-contact pairs (development aid, docs/BENCHMARKS.md, session 31).

Runs the t-shirt benchmark scene (``bench_tshirt``) with the given solver options and reports,
over the motion's last 30 frames, the fraction of particles that take part in a stored pair
(``coarse.has_pairs``: the coarse correction caps their moves and stiffens their coarse
diagonal) in the lists the step's last substep used, and the stored pairs per particle.

``python -m benchmarks.pair_share --solver '{"self_contact_pipeline": true}'``
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from benchmarks.bench_tshirt import add_single_scene_arguments, load_single_scene
from benchmarks.common import machine, write_result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_single_scene_arguments(ap, device="cpu", motion="run", seconds=1.0)
    ap.add_argument("--solver", default="{}", help="JSON dict of VBDConfig fields")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()

    import sim.cloth as cloth
    from sim.simulate import SimulationConfig, SimulationJob, simulate_batch

    device, body, garment, motion = load_single_scene(args)
    cfg = SimulationConfig(fps=30.0, self_contact=True, device=device, solver=json.loads(args.solver))
    rows: list[tuple[float, float]] = []
    base = cloth.SolverVBD

    class Recording(base):
        def step(self, state_in, state_out, control, dt):
            super().step(state_in, state_out, control, dt)
            c = self.config
            d = self.self_contact.datas[(c.substeps - 1) % 2 if c.self_contact_pipeline else 0]
            total = d.vt_count.numpy() + d.tv_total.numpy() + d.ee_total.numpy()
            rows.append((float((total > 0).mean()), float(total.mean())))

    cloth.SolverVBD = Recording
    try:
        t0 = time.perf_counter()
        result = simulate_batch([SimulationJob(garment, body, motion)], config=cfg, failures="return")[0]
        sim_s = time.perf_counter() - t0
    finally:
        cloth.SolverVBD = base
    last = np.asarray(rows[-30:])
    figures = {"simulate_s": sim_s, "frames": len(rows), "with_pairs_mean": float(last[:, 0].mean()),
               "with_pairs_max": float(last[:, 0].max()), "pairs_per_particle": float(last[:, 1].mean()),
               "max_edge_strain": float(getattr(getattr(result, "quality", None), "max_edge_strain", np.nan))}
    write_result(f"pair_share_{device}{args.tag}", {"machine": machine(device), "sizes": {
        "garment_vertices": garment.num_vertices, "motion": args.motion, "seconds": args.seconds,
        "solver": json.loads(args.solver)}, "figures": figures})


if __name__ == "__main__":
    main()
