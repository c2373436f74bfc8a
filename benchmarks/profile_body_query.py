"""Closest-point queries against the moving body (the body-contact kernel's search), by BVH
construction: is the body's tree, built once at rest and refit every substep, a slow one to
query? (development aid, see docs/BENCHMARKS.md, session 14)

Per motion and frame (rest, the motion's first frame, 30 frames in): 5,000 points scattered
within -3..15 mm of the upper half of the default body (where a t-shirt's vertices are) query
``mesh_query_point_sign_normal`` (what ``body_contact_kernel`` calls) and ``..._no_sign``, on
trees built at rest and refit to the frame (what the solver does) and built at the frame, with
Warp's CUDA LBVH and the host's SAH and median constructors. Microseconds per launch of 5,000
queries (wall clock over ``--repeats`` launches, launch overhead included).

``python -m benchmarks.profile_body_query --device cuda``
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from benchmarks.common import machine, write_result

CONSTRUCTORS = ("lbvh", "sah", "median")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda", help="Warp device (cuda or cpu)")
    ap.add_argument("--motions", default="walk,run", help="comma-separated motion names")
    ap.add_argument("--points", type=int, default=5000, help="query points per launch")
    ap.add_argument("--repeats", type=int, default=200, help="launches timed per figure")
    ap.add_argument("--tag", default="", help="suffix of the result file name")
    args = ap.parse_args(argv)

    from sim.bodies.default import load_default_body
    from sim.device import resolve_device, warp
    from sim.garments import make_garment
    from sim.motions import load_motion
    from sim.simulate import SimulationConfig, SimulationJob, _prepare

    wp = warp()
    dev = resolve_device(args.device)

    @wp.kernel
    def q_sign(mesh: wp.uint64, x: wp.array(dtype=wp.vec3), m: float, out: wp.array(dtype=float)):
        i = wp.tid()
        q = wp.mesh_query_point_sign_normal(mesh, x[i], m)
        out[i] = wp.where(q.result, q.sign, 0.0)

    @wp.kernel
    def q_nosign(mesh: wp.uint64, x: wp.array(dtype=wp.vec3), m: float, out: wp.array(dtype=float)):
        i = wp.tid()
        q = wp.mesh_query_point_no_sign(mesh, x[i], m)
        out[i] = wp.where(q.result, float(q.face), -1.0)

    def timed(kernel, mesh, x, margin: float) -> float:
        out = wp.zeros(x.shape[0], dtype=float, device=dev)
        wp.launch(kernel, dim=x.shape[0], inputs=[mesh.id, x, margin, out], device=dev)
        wp.synchronize_device(dev)
        t = time.perf_counter()
        for _ in range(args.repeats):
            wp.launch(kernel, dim=x.shape[0], inputs=[mesh.id, x, margin, out], device=dev)
        wp.synchronize_device(dev)
        return round((time.perf_counter() - t) / args.repeats * 1e6, 1)

    body = load_default_body()
    faces = np.asarray(body.faces, np.int32)
    indices = wp.array(faces.ravel(), dtype=wp.int32, device=dev)
    rng = np.random.default_rng(0)
    garment = make_garment("t_shirt", body, None, resolution=0.02)
    figures: dict = {}
    for name in args.motions.split(","):
        motion = load_motion(name, fps=30.0, duration=2.0)
        tr = _prepare(SimulationJob(garment, body, motion, None), SimulationConfig(), dev, {})
        frames = np.asarray(tr.frames.vertices, np.float32)
        first = tr.n_settle + tr.n_blend
        for frame in sorted({0, first, min(first + 30, len(frames) - 1)}):
            v = frames[frame]
            tri = v[faces]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
            upper = np.nonzero(tri.mean(1)[:, 1] > np.quantile(tri.mean(1)[:, 1], 0.45))[0]
            f = rng.choice(upper, args.points)
            bary = rng.dirichlet([1.0, 1.0, 1.0], args.points)
            p = np.einsum("nk,nkd->nd", bary, tri[f]) + n[f] * rng.uniform(-0.003, 0.015, (args.points, 1))
            x = wp.array(p.astype(np.float32), dtype=wp.vec3, device=dev)
            meshes = {}
            for cons in CONSTRUCTORS:
                refit_points = wp.array(frames[0], dtype=wp.vec3, device=dev)
                refit = wp.Mesh(points=refit_points, indices=indices, bvh_constructor=cons)
                refit_points.assign(v)
                refit.refit()
                meshes[f"rest_refit_{cons}"] = refit
                built_points = wp.array(v, dtype=wp.vec3, device=dev)
                meshes[f"built_{cons}"] = wp.Mesh(points=built_points, indices=indices, bvh_constructor=cons)
            for margin in (0.015, 0.05):
                row = {f"{k}_sign_us": timed(q_sign, mesh, x, margin) for k, mesh in meshes.items()}
                row.update({f"{k}_nosign_us": timed(q_nosign, mesh, x, margin)
                            for k, mesh in meshes.items() if k.startswith("rest_refit")})
                figures[f"{name}_frame{frame}_margin{margin}"] = row
                print(name, frame, margin, json.dumps(row), flush=True)
    write_result(f"profile_body_query_{dev.split(':')[0]}{args.tag}",
                 {"machine": machine(dev), "figures": figures})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
