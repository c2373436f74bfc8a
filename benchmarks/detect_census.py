"""What a self-contact detection query finds (development aid, see docs/BENCHMARKS.md, session 31).

Simulates the t-shirt benchmark scene (``bench_tshirt``: ~5k-vertex t-shirt on the default body,
the job default setting), keeps the state every solver step starts from, and on sampled frames of
the motion counts the BVH hits of every detection query (the vertex query on the triangle tree,
the triangle query on the vertex tree, the edge query on the edge tree) with the query boxes of
``sim.cloth.self_contact`` (radius ``max(margin, speed_factor |v - v_ref| h)``), once more with
the margin alone, on trees rebuilt at that state, and once as the lookahead's candidate query
(``SelfContact.query_candidates``, session 36: boxes swept over the substep's motion, the trees'
grown by each primitive's own reach, the queries' by the widened margin). A query thread's work is
its hits: the queries are latency-bound, so the slowest thread sets a launch's length.

``python -m benchmarks.detect_census --device cpu --motion run --seconds 2``
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from benchmarks.bench_tshirt import add_single_scene_arguments, load_single_scene
from benchmarks.common import machine, write_result


def count_kernel(wp):
    """A kernel that counts each query's BVH hits: primitive ``k`` of ``prims`` (up to 4 vertex
    ids, ``nverts`` used), its box grown by the detection's radius (``margin_only``: the margin),
    searched from ``root`` (the instance's, ``SelfContact.find_roots``)."""
    from sim.cloth.self_contact import query_radius, swept

    @wp.kernel
    def count_hits(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), vr: wp.vec3,
                   prims: wp.array(dtype=wp.vec4i), nverts: int, bvh: wp.uint64, root: int, margin: float,
                   speed_factor: float, h: float, margin_only: int, sweep: float,
                   hits: wp.array(dtype=wp.int32), radius: wp.array(dtype=float)):
        k = wp.tid()
        q = prims[k]
        lo = x[q[0]]
        hi = x[q[0]]
        speed = wp.length(v[q[0]] - vr)
        for j in range(1, nverts):
            lo = wp.min(lo, x[q[j]])
            hi = wp.max(hi, x[q[j]])
            speed = wp.max(speed, wp.length(v[q[j]] - vr))
        r = query_radius(margin, speed, h, speed_factor)
        if margin_only != 0:
            r = margin
        if sweep > 0.0:
            for j in range(nverts):
                lo, hi = swept(lo, hi, x[q[j]], v[q[j]], vr, sweep)
        query = wp.bvh_query_aabb(bvh, lo - wp.vec3(r), hi + wp.vec3(r), root)
        n = int(0)
        t = int(0)
        while wp.bvh_query_next(query, t):
            n += 1
        hits[k] = n
        radius[k] = r

    return count_hits


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_single_scene_arguments(ap, device="cpu", motion="run", seconds=2.0)
    ap.add_argument("--frames", type=int, default=15, help="frames sampled from the motion's last 60 "
                    "(default: %(default)s)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()

    import sim.cloth as cloth
    from sim.cloth.self_contact import LOOKAHEAD_SWEEP
    from sim.device import warp
    from sim.simulate import SimulationConfig, SimulationJob, simulate_batch

    wp = warp()
    device, body, garment, motion = load_single_scene(args)
    # the census walks the trees (on CUDA the job default searches clusters instead)
    cfg = SimulationConfig(fps=30.0, self_contact=True, device=device,
                           solver={"self_contact_broadphase": "bvh"})
    seen: dict = {}
    starts: list = []
    base = cloth.SolverVBD

    class Recording(base):
        def step(self, state_in, state_out, control, dt):
            seen.update(solver=self, dt=dt)
            starts.append((state_in.positions.numpy().copy(), state_in.velocities.numpy().copy(),
                           control.instance_velocity.numpy()[0].copy()))
            super().step(state_in, state_out, control, dt)

    cloth.SolverVBD = Recording
    try:
        t0 = time.perf_counter()
        simulate_batch([SimulationJob(garment, body, motion)], config=cfg)
        sim_s = time.perf_counter() - t0
    finally:
        cloth.SolverVBD = base
    solver = seen["solver"]
    sc, m = solver.self_contact, solver.model
    h = seen["dt"] / solver.config.substeps
    tri = m.tri_indices.numpy()
    edges = m.mesh_edge_indices.numpy()
    pad = lambda a: np.c_[a, np.zeros((len(a), 4 - a.shape[1]), int)].astype(np.int32)  # noqa: E731
    # per query: its primitives, their vertex count, and the index of the tree it searches in
    # ``sc.bvhs`` (and ``sc._roots``)
    queries = {"vertex": (pad(np.arange(m.particle_count)[:, None]), 1, 0),
               "triangle": (pad(tri), 3, 1), "edge": (pad(edges), 2, 2)}
    kernel = count_kernel(wp)
    first = max(len(starts) - 60, 0)
    picks = np.unique(np.linspace(first, len(starts) - 1, args.frames).astype(int))
    per_frame = []
    for f in picks:
        x, v, vr = starts[f]
        xd = wp.array(x, dtype=wp.vec3, device=device)
        vd = wp.array(v, dtype=wp.vec3, device=device)
        sc.data.reference = wp.array(vr[None], dtype=wp.vec3, device=device)
        row = {"step": int(f)}
        # (suffix, boxes swept over [s], query margin [m], margin only)
        wide = sc.margin + solver.config.self_contact_lookahead_margin
        modes = (("", 0.0, sc.margin, 0), ("_margin", 0.0, sc.margin, 1),
                 ("_lookahead", LOOKAHEAD_SWEEP * h, wide, 0))
        for suffix, sweep, margin, margin_only in modes:
            sc._update_bounds(xd, vd, sweep, sc.speed_factor * h)
            for bvh in sc.bvhs:
                bvh.rebuild()
            sc.find_roots()
            for name, (prims, nverts, k) in queries.items():
                pd = wp.array(prims, dtype=wp.vec4i, device=device)
                bvh, root = sc.bvhs[k], int(sc._roots[k].numpy()[0])
                hits = wp.zeros(len(prims), dtype=wp.int32, device=device)
                radius = wp.zeros(len(prims), dtype=float, device=device)
                wp.launch(kernel, dim=len(prims),
                          inputs=[xd, vd, wp.vec3(*vr), pd, nverts, bvh.id, root, margin, sc.speed_factor,
                                  h, margin_only, sweep, hits, radius], device=device)
                n, r = hits.numpy(), radius.numpy()
                row[name + suffix] = {"hits_mean": float(n.mean()), "hits_p99": float(np.quantile(n, 0.99)),
                                      "hits_max": int(n.max()), "radius_mean_mm": 1e3 * float(r.mean()),
                                      "radius_max_mm": 1e3 * float(r.max())}
        per_frame.append(row)
        print(json.dumps(row), flush=True)
    summary = {}
    for key in per_frame[0]:
        if key == "step":
            continue
        summary[key] = {"hits_mean": float(np.mean([r[key]["hits_mean"] for r in per_frame])),
                        "hits_p99_max": float(max(r[key]["hits_p99"] for r in per_frame)),
                        "hits_max": int(max(r[key]["hits_max"] for r in per_frame)),
                        "radius_max_mm": float(max(r[key]["radius_max_mm"] for r in per_frame))}
    out = {"machine": machine(device),
           "sizes": {"garment_vertices": int(m.particle_count), "triangles": int(m.tri_count),
                     "edges": int(len(edges)), "motion": args.motion, "seconds": args.seconds,
                     "substeps": solver.config.substeps, "margin_mm": 1e3 * sc.margin},
           "figures": {"simulate_s": sim_s, "summary": summary, "frames": per_frame}}
    print(json.dumps(summary, indent=1))
    write_result(f"detect_census_{device}{args.tag}", out)


if __name__ == "__main__":
    main()
