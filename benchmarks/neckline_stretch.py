"""How far a run stretches a garment's neckline, against the skin under it.

Reads the per-motion file that ``benchmarks.worst_edges --save PATH`` writes (``PATH_walk.npz``:
the garment's rest mesh and its positions per output frame, the body's positions). The neckline
is the garment's boundary loop that sits highest at rest. Per frame it reports the strain
(length / rest length - 1) of the whole loop and of its front segment (rest z above
``--front-z``), and the same for the skin under it: the polyline through the body vertices
nearest to the loop's vertices at rest, in the body positions the file holds (for a file without
them, the default body posed again through ``--motion``, floor offset of its first frame, as
``sim.simulate`` places it). It also reports the chord between the front segment's two ends,
cloth against skin. Session 29 used it to tell whether the 19k t-shirt's neckline strain comes
from the body (the skin under it stretching) or from the solve (it falls with more sweeps).

    python -m benchmarks.neckline_stretch runs/f19_walk.npz
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def neckline_loop(rest: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Vertex indices, in order around it, of the boundary loop with the highest mean y at rest."""
    import trimesh

    outline = trimesh.Trimesh(rest, faces, process=False).outline()
    loops = [np.asarray(ent.points) for ent in outline.entities]
    loops = [lp[:-1] if len(lp) > 1 and lp[0] == lp[-1] else lp for lp in loops]  # closed: first repeated
    return max(loops, key=lambda lp: float(rest[lp, 1].mean()))


def polyline_strain(points: np.ndarray, rest_points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Strain per frame of the selected segments of a closed polyline: summed length over summed rest
    length, minus 1. ``points`` (T, n, 3), ``rest_points`` (n, 3); segment i runs from point i to
    point i + 1 (the last closes the loop); ``segments`` is a boolean mask (n,)."""
    nxt = np.roll(np.arange(len(rest_points)), -1)
    l0 = np.linalg.norm(rest_points[nxt] - rest_points, axis=-1)[segments].sum()
    length = np.linalg.norm(points[:, nxt] - points, axis=-1)[:, segments].sum(axis=1)
    return length / l0 - 1.0


def stretch_report(x: np.ndarray, rest: np.ndarray, faces: np.ndarray, body_rest: np.ndarray,
                   body_frames: np.ndarray, front_z: float) -> dict:
    """The neckline's figures per frame (see the module docstring) and at the frame where its front
    segment stretches most."""
    from scipy.spatial import cKDTree

    loop = neckline_loop(rest, faces)
    under = cKDTree(body_rest).query(rest[loop])[1]  # the body vertex nearest to each, at rest
    front = rest[loop, 2] > front_z
    nxt_front = front & np.roll(front, -1)  # segments with both ends in front
    side = np.argsort(rest[loop[front], 0])[[0, -1]]  # the front segment's two ends, by x
    ends, ends_under = loop[front][side], under[front][side]
    cloth_all = polyline_strain(x[:, loop], rest[loop], np.ones(len(loop), bool))
    cloth_front = polyline_strain(x[:, loop], rest[loop], nxt_front)
    skin_all = polyline_strain(body_frames[:, under], body_rest[under], np.ones(len(loop), bool))
    skin_front = polyline_strain(body_frames[:, under], body_rest[under], nxt_front)

    def chord(p, p0, i, j):  # distance of two points per frame over their rest distance
        return np.linalg.norm(p[:, i] - p[:, j], axis=1) / np.linalg.norm(p0[i] - p0[j])

    cloth_chord, skin_chord = chord(x, rest, *ends), chord(body_frames, body_rest, *ends_under)
    ring = 1000 * np.linalg.norm(rest[np.roll(loop, -1)] - rest[loop], axis=1)
    gap = 1000 * np.linalg.norm(body_rest[under] - rest[loop], axis=1)
    t = int(cloth_front.argmax())
    return {"loop_vertices": int(len(loop)), "front_vertices": int(front.sum()),
            "rest_length_mm": float(ring.sum()), "skin_distance_at_rest_mm": float(gap.mean()),
            "worst_frame": t,
            "front_strain": float(cloth_front[t]), "front_skin_strain": float(skin_front[t]),
            "loop_strain": float(cloth_all[t]), "loop_skin_strain": float(skin_all[t]),
            "front_chord_ratio": float(cloth_chord[t]), "front_chord_skin_ratio": float(skin_chord[t]),
            "per_frame": {"front": cloth_front.round(4).tolist(), "front_skin": skin_front.round(4).tolist(),
                          "loop": cloth_all.round(4).tolist(), "loop_skin": skin_all.round(4).tolist()}}


def main() -> None:
    from benchmarks.bench_tshirt import benchmark_motion
    from sim.bodies.default import load_default_body
    from sim.bodies.placement import floor_offset, translate_frames

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("npz", help="a file written by worst_edges --save (one motion)")
    ap.add_argument("--motion", default="",
                    help="the motion that file holds (walk, run, ...), to pose the body again where the "
                    "file has no body positions (files written before session 43, so on SMPL's approximate "
                    "skeleton, as every benchmark then built its motions); otherwise unused")
    ap.add_argument("--seconds", type=float, default=2.0, help="motion length [s] of that run")
    ap.add_argument("--front-z", type=float, default=0.1, help="rest z [m] above which the loop is front")
    args = ap.parse_args()
    try:
        d = np.load(args.npz)
        x, rest, faces = d["x"], d["rest"], d["faces"]
        skin = d["body"] if "body" in d.files else None
    except (OSError, KeyError, ValueError) as e:
        ap.exit(2, f"{args.npz}: not a worst_edges --save file ({e})\n")
    body = load_default_body()
    if skin is None:  # pose the body again, as sim.simulate placed it (floor offset of frame 0)
        if not args.motion:
            ap.exit(2, f"{args.npz}: holds no body positions; give --motion (and --seconds) to pose it\n")
        motion = benchmark_motion(args.motion, body, args.seconds, "default")
        frames = body.pose_motion(motion, device="cpu")
        frames = translate_frames(frames, np.array([0.0, floor_offset(frames), 0.0]))
        skin = frames.vertices
    if len(skin) != len(x) or skin.shape[1] != body.num_vertices:
        ap.exit(2, f"{args.npz}: {len(x)} garment frames against body positions of shape {skin.shape} "
                   f"(the default body has {body.num_vertices} vertices)\n")
    r = stretch_report(x, rest, faces, body.rest_mesh(), skin, args.front_z)
    print(json.dumps({k: v for k, v in r.items() if k != "per_frame"}, indent=1))


if __name__ == "__main__":
    main()
