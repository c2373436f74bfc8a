"""Which of a substep's forked chains sets the live frame: the self-contact detection (main
stream), the bodies' placement and contact (side stream) or the coarse system's factor (its own
side stream), and what the coarse correction's substitution costs, measured on real frames.

    python -m benchmarks.critical_chain --device cuda --motions walk,run --seconds 2

Each chain is run twice per substep in turn (a physics-neutral change: the detection and the
bodies' placement are deterministic and overwrite their outputs), and the t-shirt's full run
is timed as in ``bench_tshirt``. A chain that sets the frame adds its whole length per substep;
one with slack adds only what its double exceeds the other chain by. (Session 41 tried this with
replays of one captured step, the end state restored before each: they ran ~1.8x slower than the
live frames, with or without either chain, and said nothing about the live frame.) The body
contact kernel is not doubled (it is launched once): ``placement x2`` doubles the bodies'
placement only. ``coarse factor x2`` and ``coarse substitution x2`` (session 42) double the coarse
level's factor (``CoarseLevel.factor``, on its side stream) and its exact solve at each
correction (``CoarseLevel.exact_solve``, on the sweeps' chain); both overwrite their outputs
from inputs they do not change.
"""

from __future__ import annotations

import argparse
import json

from benchmarks.bench_tshirt import add_scene_arguments, load_scene, run_ours
from benchmarks.common import machine, write_result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    ap.add_argument("--solver", default="{}", help="JSON dict of extra VBDConfig fields")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()
    from sim.cloth import coarse as CO
    from sim.cloth import self_contact as SC
    from sim.cloth import state as ST
    from sim.simulate import SimulationConfig

    device, body, garment, _, motions = load_scene(args)
    cfg = SimulationConfig(fps=30.0, self_contact=True, solver=json.loads(args.solver), device=device)
    detect, place = SC.SelfContact.detect, ST.BodyCollider.place
    factor, exact = CO.CoarseLevel.factor, CO.CoarseLevel.exact_solve

    def twice(fn):
        def run(*a, **k):
            fn(*a, **k)
            fn(*a, **k)
        return run

    variants = {"base": {}, "detection x2": {"detect": twice(detect)},
                "placement x2": {"place": twice(place)}, "coarse factor x2": {"factor": twice(factor)},
                "coarse substitution x2": {"exact": twice(exact)}}
    fig: dict = {}
    for name, motion in motions.items():
        fig[name] = {}
        for label, patch in variants.items():
            SC.SelfContact.detect = patch.get("detect", detect)
            ST.BodyCollider.place = patch.get("place", place)
            CO.CoarseLevel.factor = patch.get("factor", factor)
            CO.CoarseLevel.exact_solve = patch.get("exact", exact)
            try:
                ours, _ = run_ours(garment, body, motion, cfg)
            finally:
                SC.SelfContact.detect, ST.BodyCollider.place = detect, place
                CO.CoarseLevel.factor, CO.CoarseLevel.exact_solve = factor, exact
            fig[name][label] = {"ms_per_frame": ours.get("ms_per_frame"), "error": ours.get("error"),
                                "failed_gates": ours.get("failed_gates")}
            print(name, label, json.dumps(fig[name][label]), flush=True)
    write_result(f"critical_chain_{device.split(':')[0]}{args.tag}", {
        "machine": machine(device),
        "sizes": {"garment_vertices": garment.num_vertices, "seconds": args.seconds},
        "config": cfg.to_dict(), "figures": fig})


if __name__ == "__main__":
    main()
