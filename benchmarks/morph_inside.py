"""Vertices inside the body during a morph settle, per solver setting (development aid, see
docs/BENCHMARKS.md, session 34).

Dresses the mean-shape straight skirt of ``tests/test_reference_fit.py`` (7 cm edges, 164
vertices by default) on a larger body (betas 1.5, -1.0) by the morph settle, keeps the prelude,
and reports per ``substeps x iterations`` setting and ``coarse_prefactor`` on / off the fraction
of garment vertices inside the body at the settle's end and its maximum over the run.

``python -m benchmarks.morph_inside --device cpu --settings 3x3,5x5``
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.common import machine, write_result

TARGET = np.array([1.5, -1.0], np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--settings", default="3x3,5x5", help="substeps x iterations, comma separated")
    ap.add_argument("--resolution", type=float, default=0.07, help="template edge length [m]")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()

    from sim.bodies import load_body
    from sim.garments import make_garment
    from sim.motions import MotionSkeleton, load_motion
    from sim.simulate import SimulationConfig, simulate

    body = load_body()
    skirt = make_garment("straight_skirt", body, None, resolution=args.resolution)
    motion = load_motion("walk", fps=30, duration=0.1, skeleton=MotionSkeleton.from_body(body, TARGET),
                         ramp=0.2)
    rows = []
    for setting in args.settings.split(","):
        sub, it = (int(p) for p in setting.split("x"))
        for prefactor in (False, True):
            cfg = SimulationConfig(fps=30.0, substeps=sub, iterations=it, settle_seconds=0.5,
                                   blend_seconds=0.1, keep_prelude=True, device=args.device,
                                   solver={"coarse_prefactor": prefactor})
            res = simulate(skirt, body, motion, betas=TARGET, garment_betas=np.zeros(2), config=cfg)
            f = res.quality.inside_fraction
            n = cfg.settle_frames
            rows.append({"setting": setting, "coarse_prefactor": prefactor, "settle_frames": n,
                         "inside_at_settle_end": float(f[n]), "inside_max": float(f.max()),
                         "frame_of_max": int(np.argmax(f))})
            print(rows[-1], flush=True)
    write_result(f"morph_inside_{args.device}{args.tag}",
                 {"machine": machine(args.device), "garment_vertices": skirt.num_vertices, "rows": rows})


if __name__ == "__main__":
    main()
