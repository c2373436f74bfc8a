# ruff: noqa: B023  (closures timed immediately, inside the loop iteration)
"""Phase timings of the t-shirt step mid-motion (development aid, see docs/BENCHMARKS.md).

Simulates the benchmark scene (``bench_tshirt``: ~5k-vertex t-shirt, default body, walk),
then, on the live end state, times: the whole solver step (plain launches and CUDA graph),
self-contact detection, one Gauss-Seidel sweep with and without the self-contact terms, and
whole steps of solver variants (lanes, capacity, iterations). Pair statistics are printed too.

``python -m benchmarks.profile_tshirt --device cuda --seconds 1``
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import time

import numpy as np

from benchmarks.bench_tshirt import add_single_scene_arguments, load_single_scene
from benchmarks.common import machine, timed_ms, write_result


class _NoCapture:
    """Stands in for ``wp.ScopedCapture`` in ``simulate_batch`` with ``--live-frames``: the
    capture fails, so the simulation falls back to plain launches (which CUDA activity timing
    sees one by one)."""

    def __init__(self, *args, **kwargs):
        pass

    def __enter__(self):
        raise RuntimeError("no CUDA graph while profiling live frames")

    def __exit__(self, *exc):
        return False


def kernel_breakdown(wp, device: str, fn) -> dict:
    """GPU time [ms] of every kernel ``fn`` launches (CUDA activity timing of one plain run, after
    a warm-up run), summed by kernel name, largest first, with launch counts: where a step's
    time goes."""
    if not wp.get_device(device).is_cuda:
        return {}
    fn()
    return kernel_timings(wp, device, fn)


def kernel_timings(wp, device: str, fn) -> dict:
    """``kernel_breakdown`` of one run of ``fn``, without the warm-up."""
    if not wp.get_device(device).is_cuda:
        fn()
        return {}
    with wp.ScopedTimer("step", print=False, synchronize=True,
                        cuda_filter=wp.TIMING_KERNEL | wp.TIMING_KERNEL_BUILTIN) as timer:
        fn()
    total: dict = {}
    for r in timer.timing_results:
        name = r.name.split("_cuda_kernel")[0]
        ms, count = total.get(name, (0.0, 0))
        total[name] = (ms + r.elapsed, count + 1)
    ranked = sorted(total.items(), key=lambda kv: -kv[1][0])
    return {k: {"ms": round(ms, 4), "launches": c} for k, (ms, c) in ranked}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_single_scene_arguments(ap)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--batch", type=int, default=1, help="t-shirts in the one model (default: %(default)s)")
    ap.add_argument("--solver", default="{}", help="JSON dict of VBDConfig fields of the base solver")
    ap.add_argument("--tag", default="")
    ap.add_argument("--live-frames", type=int, default=0,
                    help="also time every kernel of the last N frames as simulated (plain launches, "
                    "no CUDA graph): the breakdown of real frames, not of a replayed step")
    ap.add_argument("--variants", default='[{"lanes": 8}, {"lanes": 32}, {"self_contact_capacity": 8}, '
                    '{"iterations": 5}, {"self_contact": false}]',
                    help="JSON list of VBDConfig overrides timed as whole graphed steps")
    args = ap.parse_args()

    import sim.cloth as cloth
    from sim.cloth import self_contact as SC
    from sim.cloth.self_contact import disabled_data
    from sim.device import warp
    from sim.simulate import SimulationConfig, SimulationJob, simulate_batch

    wp = warp()
    device, body, garment, motion = load_single_scene(args)
    cfg = SimulationConfig(fps=30.0, self_contact=True, solver=json.loads(args.solver), device=device)

    seen: dict = {}
    base_cls = cloth.SolverVBD
    frames = collections.deque(maxlen=max(args.live_frames, 1))  # kernel timings of the last steps
    recording = {"on": True}

    class Recording(base_cls):
        def step(self, state_in, state_out, control, dt):
            seen.update(solver=self, state=state_out, control=control, dt=dt)
            if args.live_frames and recording["on"]:
                frames.append(kernel_timings(wp, device, lambda: super(Recording, self).step(
                    state_in, state_out, control, dt)))
                return
            super().step(state_in, state_out, control, dt)

    cloth.SolverVBD = Recording
    capture = wp.ScopedCapture
    if args.live_frames:
        wp.ScopedCapture = _NoCapture  # plain launches, so every live frame's kernels are timed
    try:
        t0 = time.perf_counter()
        simulate_batch([SimulationJob(garment, body, motion) for _ in range(args.batch)], config=cfg)
        sim_s = time.perf_counter() - t0
    finally:
        cloth.SolverVBD = base_cls
        wp.ScopedCapture = capture
        recording["on"] = False
    live: dict = {}  # kernel name -> [ms per frame, launches] over the last frames
    for f in frames if args.live_frames else ():
        for k, r in f.items():
            acc = live.setdefault(k, [0.0, 0])
            acc[0] += r["ms"] / len(frames)
            acc[1] += r["launches"]
    if live:
        ranked = sorted(live.items(), key=lambda kv: -kv[1][0])
        live_ms = {k: {"ms_per_frame": round(ms, 4), "launches": c} for k, (ms, c) in ranked}
        print(json.dumps({"live_frames": args.live_frames, "kernels": live_ms}, indent=1), flush=True)
    solver, state, control, dt = seen["solver"], seen["state"], seen["control"], seen["dt"]
    m = solver.model
    vcfg = solver.config
    h = dt / vcfg.substeps

    def timed(fn, graph: bool = False) -> float:
        return timed_ms(wp, device, fn, args.repeats, graph)

    def sweep(sc_data):
        return lambda: solver.sweep(state.positions, sc_data, vcfg.friction_epsilon * h, h)

    def keep_lists(data, keep: tuple[str, ...]):
        """``data`` with every vertex gathered from the pair lists (its gather records switched
        off) and the pair totals of the lists not in ``keep`` ("vt", "tv", "ee") zeroed: a sweep
        that evaluates only those pair kinds (where the self-contact time goes)."""
        out = SC.SelfContactData()
        for name in SC.SelfContactData.vars:
            setattr(out, name, getattr(data, name))
        out.pair_first = wp.full_like(data.pair_first, -1)
        for kind, field in (("vt", "vt_count"), ("tv", "tv_total"), ("ee", "ee_total")):
            if kind not in keep:
                setattr(out, field, wp.zeros_like(getattr(data, field)))
        return out

    sc = solver.self_contact
    x, v = state.positions, state.velocities
    sizes = np.diff(np.asarray(m.color_offsets))
    saved = (wp.clone(x), wp.clone(v), wp.clone(state.accelerations))

    def restore():
        wp.copy(x, saved[0])
        wp.copy(v, saved[1])
        wp.copy(state.accelerations, saved[2])

    trees = sc.clusters is None  # the cluster broadphase has no trees and no single queries

    def kernels(tag: str) -> dict:
        if not trees:
            return {}
        return {
            f"detect_vertex{tag}_ms": timed(lambda: sc.query_vertices(x, v, h), graph=True),
            f"detect_triangle{tag}_ms": timed(lambda: sc.query_triangles(x, v, h), graph=True),
            f"detect_edge{tag}_ms": timed(lambda: sc.query_edges(x, v, h), graph=True),
        }

    res = {
        "simulate_s": sim_s,
        "colors": int(m.color_count),
        "color_sizes": [int(s) for s in sizes],
        "step_plain_ms": restore() or timed(lambda: solver.step(state, state, control, dt)),
        "step_graph_ms": restore() or timed(lambda: solver.step(state, state, control, dt), graph=True),
        "detect_plain_ms": timed(lambda: sc.detect(x, v, h)),
        "detect_graph_ms": timed(lambda: sc.detect(x, v, h), graph=True),
        **({"bounds_boxes_ms": timed(lambda: sc._update_bounds(x), graph=True),
            "refit_tri_ms": timed(lambda: sc.tri_bvh.refit(), graph=True),
            "refit_edge_ms": timed(lambda: sc.edge_bvh.refit(), graph=True)} if trees else
           {"clusters_marked_per_query": sc.clusters.marked()}),
        **kernels(""),
        "sweep_sc_graph_ms": timed(sweep(sc.data), graph=True),
        "sweep_nosc_graph_ms": timed(sweep(disabled_data(device)), graph=True),
        **{f"sweep_sc_{'_'.join(keep) or 'nopairs'}_graph_ms":
           timed(sweep(keep_lists(sc.data, keep)), graph=True) for keep in ((), ("vt",), ("tv",), ("ee",))},
        "sweep_sc_lists_graph_ms": timed(sweep(keep_lists(sc.data, ("vt", "tv", "ee"))), graph=True),
    }
    totals = (sc.data.vt_count.numpy() + sc.data.tv_total.numpy() + sc.data.ee_total.numpy())
    res["vertex_pair_totals"] = {"mean": float(totals.mean()), "max": int(totals.max()),
                                 "nonzero": int((totals > 0).sum()),
                                 "quantiles_99_999": [float(q) for q in np.quantile(totals, [0.99, 0.999])],
                                 "pool_records": int(sc.data.pair_cursor.numpy()[0]),
                                 "pool_size": int(sc.data.pool_size)}
    # vertices with more records than the solve's lanes, per colour (the heavy-vertex blocks)
    records = sc.data.pair_count.numpy()
    order = m.color_vertices.numpy()
    offsets = np.asarray(m.color_offsets)
    colours = [records[order[a:b]] for a, b in zip(offsets[:-1], offsets[1:], strict=True)]
    res["heavy_vertices"] = {"threshold": int(sc.data.heavy_threshold), "cap": int(sc.data.heavy_cap),
                             "per_color": [int((r > solver._lanes).sum()) for r in colours],
                             "max_records_per_color": [int(r.max()) for r in colours]}
    res["step_kernels_ms"] = kernel_breakdown(wp, device,
                                              lambda: (restore(), solver.step(state, state, control, dt)))
    for name in ("vt", "tv", "ee"):
        cnt = getattr(sc.data, f"{name}_count").numpy()
        cap = getattr(sc.data, f"{name}_capacity")
        res[f"{name}_pairs"] = {"mean": float(cnt.mean()), "max": int(cnt.max()),
                                "full_fraction": float((cnt >= cap).mean())}
    restore()
    if trees:
        sc._update_bounds(x)
        res["rebuild_tri_ms"] = timed(lambda: sc.tri_bvh.rebuild(), graph=True)
        res["rebuild_edge_ms"] = timed(lambda: sc.edge_bvh.rebuild(), graph=True)
        sc.find_roots()  # the rebuilt trees' instance roots, for the queries below
        res.update(kernels("_rebuilt"))
        sc.tri_bvh.refit()  # the same boxes: a refit tree should query as fast as the rebuilt one
        sc.edge_bvh.refit()
        res.update(kernels("_rebuilt_refit"))
    if live:
        res["live_kernels"] = {"frames": args.live_frames, "kernels": live_ms}
    print(json.dumps(res, indent=1), flush=True)
    variants = {}
    for over in json.loads(args.variants):
        restore()
        s2 = base_cls(m, dataclasses.replace(vcfg, **over))
        variants[json.dumps(over)] = timed(lambda: s2.step(state, state, control, dt), graph=True)
        print(json.dumps(over), f"{variants[json.dumps(over)]:.2f} ms/step", flush=True)
    res["variants_step_graph_ms"] = variants
    write_result(f"profile_tshirt_{device.split(':')[0]}{args.tag}", {
        "machine": machine(device),
        "sizes": {"garment_vertices": garment.num_vertices, "batch": args.batch, "motion": args.motion,
                  "seconds": args.seconds, "solver": json.loads(args.solver),
                  "substeps": vcfg.substeps, "iterations": vcfg.iterations},
        "figures": res})


if __name__ == "__main__":
    main()
