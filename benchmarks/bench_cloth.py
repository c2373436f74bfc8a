"""Cloth solver core timing: a 5k-vertex sheet draped over a 28k-triangle sphere.

NOT yet the issue-3 benchmark (t-shirt on the default body, walk/run, self-collision on): the
garment templates and self-collision are not finished. This measures the VBD step at the
reference settings (10 substeps x 10 iterations per 1/30 s frame), with and without CUDA graph
capture, and batched throughput (N independent sheets in one model).

    python -m benchmarks.bench_cloth --device cuda
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from benchmarks.common import machine, write_result


def sheet(n: int, size: float, y: float):
    from tests.test_cloth_solver import grid

    v, f = grid(n, n, size, size, plane="xz")
    v = v + np.array([-size / 2, y, -size / 2], np.float32)
    return v, f


def build(instances: int, n: int, device: str, substeps: int, iterations: int, *, self_contact: bool = False,
          lanes: int = 16, broadphase: str = "auto"):
    from sim.cloth import BodyCollider, ClothModelBuilder, SolverVBD
    from sim.cloth.solver_vbd import VBDConfig
    from sim.garments.materials import get_material
    from tests.test_cloth_solver import uv_sphere

    mat = get_material("cotton")
    b = ClothModelBuilder()
    v, f = sheet(n, 1.0, 0.35)
    for _ in range(instances):
        b.add_cloth(v, f, mat)
    model = b.finalize(device)
    sv, sf = uv_sphere((0.0, 0.0, 0.0), 0.3, n_lat=100, n_lon=140)
    body = BodyCollider(sv, sf, device=device)
    body.set_frame(sv, sv)
    control = model.control()
    for i in range(instances):
        control.set_body(i, body)
    solver = SolverVBD(model, VBDConfig(substeps=substeps, iterations=iterations, self_contact=self_contact,
                                        lanes=lanes, self_contact_broadphase=broadphase))
    return model, solver, control, sf.shape[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--n", type=int, default=71, help="sheet vertices per side (71 -> 5041)")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--substeps", type=int, default=10)
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--batch", default="1,16,64,256")
    ap.add_argument("--self-contact", action="store_true", help="cloth self-collision on")
    ap.add_argument("--lanes", type=int, default=16, help="GPU threads per particle in the solve")
    ap.add_argument("--tag", default="", help="suffix of the result file name")
    args = ap.parse_args()
    opts = {"self_contact": args.self_contact, "lanes": args.lanes}

    from sim.device import resolve_device, warp

    wp = warp()
    device = resolve_device(args.device)
    dt = 1.0 / 30.0
    fig: dict = {}

    model, solver, control, body_tris = build(1, args.n, device, args.substeps, args.iterations, **opts)
    state = model.state()
    for _ in range(3):
        solver.step(state, state, control, dt)
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    for _ in range(args.frames):
        solver.step(state, state, control, dt)
    wp.synchronize_device(device)
    fig["single_ms_per_frame_launches"] = 1000 * (time.perf_counter() - t0) / args.frames
    x = state.positions.numpy()
    fig["single_finite"] = bool(np.isfinite(x).all())
    fig["single_min_radius_m"] = float(np.linalg.norm(x, axis=1).min())

    if device.startswith("cuda"):
        try:
            with wp.ScopedCapture(device=device) as cap:
                solver.step(state, state, control, dt)
            graph = cap.graph
            wp.capture_launch(graph)
            wp.synchronize_device(device)
            t0 = time.perf_counter()
            for _ in range(args.frames):
                wp.capture_launch(graph)
            wp.synchronize_device(device)
            fig["single_ms_per_frame_graph"] = 1000 * (time.perf_counter() - t0) / args.frames
        except Exception as e:  # report, do not hide: graph capture is a target of issue 3
            fig["graph_capture_error"] = f"{type(e).__name__}: {e}"

        batch = {}
        for nb in [int(s) for s in args.batch.split(",")]:
            model_b, solver_b, control_b, _ = build(nb, args.n, device, args.substeps,
                                                    args.iterations, **opts)
            st = model_b.state()
            solver_b.step(st, st, control_b, dt)
            try:
                with wp.ScopedCapture(device=device) as cap:
                    solver_b.step(st, st, control_b, dt)
                run = lambda g=cap.graph: wp.capture_launch(g)  # noqa: E731
                mode = "graph"
            except Exception:
                def run(s=solver_b, x=st, c=control_b):
                    s.step(x, x, c, dt)

                mode = "launches"
            run()
            wp.synchronize_device(device)
            frames = max(5, args.frames // max(1, nb // 16))
            t0 = time.perf_counter()
            for _ in range(frames):
                run()
            wp.synchronize_device(device)
            el = time.perf_counter() - t0
            batch[str(nb)] = {"mode": mode, "ms_per_frame": 1000 * el / frames,
                              "garment_frames_per_s": nb * frames / el}
        fig["batched"] = batch

    print(json.dumps(fig, indent=1))
    write_result(f"cloth_core_{device.split(':')[0]}{args.tag}", {
        "machine": machine(device),
        "sizes": {"cloth_vertices": model.particle_count, "body_triangles": body_tris,
                  "substeps": args.substeps, "iterations": args.iterations, "dt": dt,
                  "colors": model.color_count, "self_collision": args.self_contact,
                  "lanes": args.lanes},
        "figures": fig,
        "note": "sheet on a static sphere; not the t-shirt-on-body benchmark of issue 3",
    })


if __name__ == "__main__":
    main()
