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
crossing edges and per skinning joint the frames and counts, plus the totals.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def crossings_by_frame(vertices: np.ndarray, faces: np.ndarray, device: str) -> np.ndarray:
    """Which body edges cross a non-adjacent body face, per frame: bool (T, E) over
    ``sim.quality.unique_edges(faces)``."""
    from sim.quality import crossing_edges

    return np.stack([crossing_edges(np.asarray(x, np.float32), faces, device=device) for x in vertices])


def summarize(hit: np.ndarray, rest_hit: np.ndarray, edges: np.ndarray, rest: np.ndarray,
              weights: np.ndarray, joint_names: tuple[str, ...]) -> dict:
    """Per frame the edges crossing that do not cross at rest, and per skinning joint (the joint
    with the largest weight at the edge's first vertex) the frames with such edges, the most of
    them in one frame and their rest-pose height range [m]."""
    new = hit & ~rest_hit[None]
    per_frame = new.sum(axis=1)
    owner = np.argmax(weights[edges[:, 0]], axis=1)
    by_joint = {}
    for j in np.unique(owner[new.any(axis=0)]):
        mine = new[:, owner == j]
        frames = np.flatnonzero(mine.any(axis=1))
        cols = np.flatnonzero(owner == j)[mine.any(axis=0)]
        y = 0.5 * (rest[edges[cols, 0], 1] + rest[edges[cols, 1], 1])
        by_joint[joint_names[j]] = {"frames": frames.tolist(), "most_edges": int(mine.sum(axis=1).max()),
                                    "rest_y_m": [round(float(y.min()), 3), round(float(y.max()), 3)]}
    return {"frames_with_crossings": int((per_frame > 0).sum()), "max_edges": int(per_frame.max()),
            "per_frame": per_frame.tolist(), "by_joint": by_joint}


def main() -> None:
    from benchmarks.bench_tshirt import _numbers, _option_error
    from benchmarks.common import machine, write_result
    from sim.bodies.default import load_default_body
    from sim.errors import WrinklesInputError
    from sim.motions import load_motion
    from sim.quality import unique_edges

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--motion", default="run", help="procedural motion or a motion file (default: run)")
    ap.add_argument("--seconds", type=float, default=2.0, help="motion length [s] (default: 2)")
    ap.add_argument("--motion-param", action="append", default=[], metavar="KEY=VALUE",
                    help="a parameter of the procedural motion, e.g. speed=2.5 (repeatable)")
    ap.add_argument("--shape", default="", metavar="B1,B2,...", help="body shape (betas; default: mean)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()
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
    try:
        mot = load_motion(args.motion, fps=30.0, duration=args.seconds, **params)
    except WrinklesInputError as e:
        _option_error("--motion-param" if params else "--motion", e)
    t0 = time.perf_counter()
    frames = body.pose_motion(mot, betas, device=args.device)
    faces = np.asarray(body.faces)
    rest = body.rest_mesh(betas)
    edges = unique_edges(faces)
    rest_hit = crossings_by_frame(rest[None], faces, args.device)[0]
    hit = crossings_by_frame(np.asarray(frames.vertices), faces, args.device)
    out = summarize(hit, rest_hit, edges, rest, np.asarray(body.weights), tuple(body.joint_names))
    out["rest_pose_crossing_edges"] = int(rest_hit.sum())
    wall = time.perf_counter() - t0
    print(f"{args.motion}: {out['frames_with_crossings']} of {len(hit)} frames with body self-crossings "
          f"(at most {out['max_edges']} edges); by joint: "
          + ", ".join(f"{k} {len(v['frames'])} frames" for k, v in out["by_joint"].items()))
    write_result(f"body_crossings_{args.device.split(':')[0]}{args.tag}", {
        "machine": machine(args.device), "motion": args.motion, "motion_params": params,
        "seconds": args.seconds, "shape": [] if betas is None else betas.tolist(), "wall_s": wall, **out})


if __name__ == "__main__":
    main()
