"""Cloth solver core: a cotton sheet (71 x 71 = 5,041 vertices) dropped onto a static sphere of
27,720 triangles, with no body model, garment template or motion around it: milliseconds per
1/30 s frame of ``SolverVBD.step`` for one sheet (plain launches, and on CUDA a CUDA graph), and
on CUDA garment-frames per second of N sheets in one model (CUDA graph).

The solver runs the job's settings for the sheet's size and device (``sim.cloth.job_config``);
``--substeps``, ``--iterations``, ``--self-contact`` and ``--solver`` change them.

    python -m benchmarks.bench_cloth --device cuda --frames 30
    python -m benchmarks.bench_cloth --device cpu --n 21 --frames 3
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from benchmarks.common import add_results_argument, machine, write_result

DT = 1.0 / 30.0
SPHERE_RADIUS = 0.3  # [m], centred at the origin
SHEET_HEIGHT = 0.35  # [m]: 5 cm above the sphere's top


def sheet(n: int, size: float = 1.0, y: float = SHEET_HEIGHT) -> tuple[np.ndarray, np.ndarray]:
    """An ``n`` x ``n`` vertex square of side ``size`` [m] in the plane ``y``, centred on the y
    axis, two triangles per cell with normals along +y: (V, 3) float32, (F, 3) int32."""
    s = np.linspace(0.0, size, n)
    xx, zz = np.meshgrid(s, s)
    v = np.stack([xx.ravel() - size / 2, np.full(xx.size, y), zz.ravel() - size / 2], axis=1)
    f = []
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            f += [(a, a + n, a + 1), (a + 1, a + n, a + n + 1)]
    return v.astype(np.float32), np.asarray(f, np.int32)


def build(instances: int, args: argparse.Namespace, device: str):
    """(model, solver, control, body triangles) of ``instances`` sheets over one sphere."""
    from sim.cloth import BodyCollider, ClothModelBuilder, SolverVBD, job_config
    from sim.device import warp
    from sim.garments.materials import get_material
    from sim.geometry.primitives import uv_sphere

    v, f = sheet(args.n)
    config = job_config(len(v), warp().get_device(device).is_cuda, substeps=args.substeps,
                        iterations=args.iterations, self_contact=args.self_contact,
                        overrides=json.loads(args.solver))
    builder = ClothModelBuilder(max_colors=config.layout.max_colors)
    for _ in range(instances):
        builder.add_cloth(v, f, get_material("cotton"))
    model = builder.finalize(device)
    sv, sf = uv_sphere(SPHERE_RADIUS, n_lat=100, n_lon=140)
    body = BodyCollider(sv, sf, device=device)
    body.set_frame(sv, sv)
    control = model.control()
    for i in range(instances):
        control.set_body(i, body)
    return model, SolverVBD(model, config), control, sf.shape[0]


def ms_per_frame(wp, device: str, step, frames: int) -> float:
    """Mean milliseconds of ``step()`` over ``frames`` calls, synchronised."""
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    for _ in range(frames):
        step()
    wp.synchronize_device(device)
    return 1000.0 * (time.perf_counter() - t0) / frames


def captured(wp, device: str, step):
    """``step`` replayed from a CUDA graph of one call (the capture runs it once)."""
    with wp.ScopedCapture(device=device) as cap:
        step()
    return lambda: wp.capture_launch(cap.graph)


def single(wp, args: argparse.Namespace, device: str) -> tuple[dict, dict]:
    """Figures of one sheet (ms per frame in plain launches and, on CUDA, a CUDA graph; whether
    the positions stayed finite; the closest vertex to the sphere's centre) and the scene's sizes
    and solver settings."""
    model, solver, control, body_triangles = build(1, args, device)
    state = model.state()

    def step():
        solver.step(state, state, control, DT)

    for _ in range(3):
        step()
    fig = {"single_ms_per_frame_launches": ms_per_frame(wp, device, step, args.frames)}
    x = state.positions.numpy()
    fig["single_finite"] = bool(np.isfinite(x).all())
    fig["single_min_radius_m"] = float(np.linalg.norm(x, axis=1).min())
    if wp.get_device(device).is_cuda:
        graph = captured(wp, device, step)
        graph()
        fig["single_ms_per_frame_graph"] = ms_per_frame(wp, device, graph, args.frames)
    sizes = {"cloth_vertices": model.particle_count, "body_triangles": body_triangles, "dt": DT,
             "colors": model.color_count, "config": solver.config.to_dict()}
    return fig, sizes


def batched(wp, args: argparse.Namespace, device: str) -> dict:
    """Per batch size of ``--batch``: ms per frame of that many sheets in one model (CUDA graph)
    and garment-frames per second."""
    out = {}
    for nb in [int(s) for s in args.batch.split(",")]:
        model, solver, control, _ = build(nb, args, device)
        state = model.state()
        solver.step(state, state, control, DT)
        graph = captured(wp, device, lambda s=solver, x=state, c=control: s.step(x, x, c, DT))
        graph()
        frames = max(5, args.frames // max(1, nb // 16))
        ms = ms_per_frame(wp, device, graph, frames)
        out[str(nb)] = {"ms_per_frame": ms, "garment_frames_per_s": 1000.0 * nb / ms}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--n", type=int, default=71, help="sheet vertices per side (default: %(default)s)")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--substeps", type=int, default=0, help="substeps per frame (default 0: the job's)")
    ap.add_argument("--iterations", type=int, default=0, help="sweeps per substep (default 0: the job's)")
    ap.add_argument("--self-contact", action="store_true", help="cloth self-contact on (default: off)")
    ap.add_argument("--solver", default="{}", help='JSON dict of solver settings, "section.field": value '
                    "(sim.cloth.apply_overrides)")
    ap.add_argument("--batch", default="1,16,64,256",
                    help="sheets per model, CUDA only (default: %(default)s)")
    ap.add_argument("--tag", default="", help="suffix of the result file's name")
    add_results_argument(ap)
    args = ap.parse_args()

    from sim.device import resolve_device, warp

    wp = warp()
    device = resolve_device(args.device)
    fig, sizes = single(wp, args, device)
    if wp.get_device(device).is_cuda:
        fig["batched"] = batched(wp, args, device)
    write_result(f"cloth_core_{device.split(':')[0]}{args.tag}",
                 {"machine": machine(device), "sizes": sizes, "figures": fig}, args.results)


if __name__ == "__main__":
    main()
