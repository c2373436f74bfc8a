"""Where the skinned body passes through itself during a motion (session 46).

The default body is skinned by linear blend skinning without pose correctives: at deep joint
flexion its own surfaces interpenetrate (the calf into the thigh behind a bent knee, the thigh
into the belly at the groin). Cloth caught in such a place has no position outside the body, and
the garment gates fail there for the body's sake, not the solver's. This counts, per frame, the
body's edges that cross one of its own faces beyond those already crossing in the rest pose
(the default mesh has a few at the toes), and names where they are: the joint that skins each
crossing edge most, with the rest-pose height range of those edges.

    python -m benchmarks.body_crossings --device cpu --motion run
    python -m benchmarks.body_crossings --device cuda --motion run --motion-param speed=2.5 --tag _v25
    python -m benchmarks.body_crossings --motion walk --shape 0.976,1.063,0.338,-1.598

Writes ``benchmarks/results/body_crossings_<device><tag>.json``: per frame the count of new
crossing edges and per skinning joint the frames and counts, plus the totals
(``sim.quality.body_self_crossings``; ``wrinkles body --self-crossings`` prints the same).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from pipelines.options import join_negative_values


def main() -> None:
    from benchmarks.bench_tshirt import _numbers, _option_error
    from benchmarks.common import machine, write_result
    from sim.bodies.default import load_default_body
    from sim.errors import WrinklesInputError
    from sim.motions import MotionSkeleton, load_motion
    from sim.quality import body_self_crossings
    from sim.simulate import resolve_betas

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--motion", default="run", help="procedural motion or a motion file (default: run)")
    ap.add_argument("--seconds", type=float, default=2.0, help="motion length [s] (default: 2)")
    ap.add_argument("--motion-param", action="append", default=[], metavar="KEY=VALUE",
                    help="a parameter of the procedural motion, e.g. speed=2.5 (repeatable)")
    ap.add_argument("--shape", default="", metavar="B1,B2,...", help="body shape (betas; default: mean)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args(join_negative_values(sys.argv[1:]))
    params = _numbers(args.motion_param, "--motion-param", lambda out: None)
    body = load_default_body()
    betas = None
    if args.shape:
        try:
            betas = np.array([float(s) for s in args.shape.split(",")], np.float32)
        except ValueError as e:
            _option_error("--shape", e)
        if betas.size > body.num_betas:
            _option_error("--shape", f"{betas.size} betas for a body of {body.num_betas}")
    try:  # as `wrinkles body` builds it: the feet placed with this body's own joints and soles
        mot = load_motion(args.motion, fps=30.0, duration=args.seconds,
                          skeleton=MotionSkeleton.from_body(body, betas), **params)
    except WrinklesInputError as e:
        _option_error("--motion-param" if params else "--motion", e)
    betas = resolve_betas(body, mot, betas)  # a motion file's own shape where --shape is not given
    t0 = time.perf_counter()
    frames = body.pose(betas, mot.poses, mot.trans, device=args.device)
    out = body_self_crossings(frames.vertices, body.faces, body.rest_mesh(betas), body.weights,
                              body.joint_names, device=args.device)
    wall = time.perf_counter() - t0
    print(f"{args.motion}: {out['frames_with_crossings']} of {len(out['per_frame'])} frames with body "
          f"self-crossings (at most {out['max_edges']} edges); by joint: "
          + ", ".join(f"{k} {len(v['frames'])} frames" for k, v in out["by_joint"].items()))
    write_result(f"body_crossings_{args.device.split(':')[0]}{args.tag}", {
        "machine": machine(args.device), "motion": args.motion, "motion_params": params,
        "seconds": args.seconds, "shape": np.asarray(betas).tolist(), "wall_s": wall, **out})


if __name__ == "__main__":
    main()
