# ruff: noqa: B023  (closures timed immediately, inside the loop iteration)
"""Phase timings of one VBD substep (development aid): self-contact detection kernels, BVH
refits, one Gauss-Seidel sweep. ``python -m benchmarks.profile_cloth --device cuda``."""

from __future__ import annotations

import argparse
import json
import time

from benchmarks.bench_cloth import build


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--n", type=int, default=71)
    ap.add_argument("--batch", default="1,64")
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    from sim.device import warp

    wp = warp()
    out = {}
    for nb in [int(s) for s in args.batch.split(",")]:
        # the trees' refits and single queries are timed: the tree broadphase on every device
        model, solver, control, _ = build(nb, args.n, args.device, 10, 10, self_contact=True,
                                          broadphase="bvh")
        state = model.state()
        for _ in range(5):
            solver.step(state, state, control, 1.0 / 30.0)
        sc = solver.self_contact
        h = 1.0 / 300.0
        x, v = state.positions, state.velocities

        def timed(fn):
            fn()
            wp.synchronize_device(args.device)
            t0 = time.perf_counter()
            for _ in range(args.repeats):
                fn()
            wp.synchronize_device(args.device)
            return 1000 * (time.perf_counter() - t0) / args.repeats

        res = {
            "detect_total_ms": timed(lambda: sc.detect(x, v, h)),
            "bounds_ms": timed(lambda: sc._update_bounds(x)),
            "refit_tri_ms": timed(lambda: sc.tri_bvh.refit()),
            "refit_edge_ms": timed(lambda: sc.edge_bvh.refit()),
            "detect_vertex_ms": timed(lambda: sc.query_vertices(x, v, h)),
            "detect_triangle_ms": timed(lambda: sc.query_triangles(x, v, h)),
            "detect_edge_ms": timed(lambda: sc.query_edges(x, v, h)),
            "vt_pairs_mean": float(sc.data.vt_count.numpy().mean()),
            "tv_pairs_mean": float(sc.data.tv_count.numpy().mean()),
            "ee_pairs_mean": float(sc.data.ee_count.numpy().mean()),
        }
        solver_plain = type(solver)(model, type(solver.config)(substeps=1, iterations=1))
        solver_sc = type(solver)(model, type(solver.config)(substeps=1, iterations=1, self_contact=True))
        res["one_substep_1iter_plain_ms"] = timed(lambda: solver_plain.step(state, state, control, h))
        res["one_substep_1iter_sc_ms"] = timed(lambda: solver_sc.step(state, state, control, h))
        out[str(nb)] = res
        print(nb, json.dumps(res, indent=1), flush=True)


if __name__ == "__main__":
    main()
