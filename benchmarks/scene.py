"""The scene of the t-shirt benchmarks (``bench_tshirt``, ``sweep_tshirt``): a cotton t-shirt
template at about ``--vertices`` vertices on the default body, procedural motions built on the
body's own skeleton as ``wrinkles simulate`` and dataset generation build them, the whole job
(``sim.simulate``: settle, blend, motion, a CUDA graph per frame), and the figures of one run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time

import numpy as np

FPS = 30.0


def add_scene_arguments(ap: argparse.ArgumentParser) -> None:
    """Device, t-shirt size, motions, their length, and template or material changes."""
    ap.add_argument("--device", default="auto")
    ap.add_argument("--vertices", type=int, default=5000, help="t-shirt size (default: %(default)s)")
    ap.add_argument("--motions", default="walk,run")
    ap.add_argument("--seconds", type=float, default=2.0, help="motion length [s] (default: %(default)s)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="a template parameter of the t-shirt (`wrinkles garments` lists them), e.g. "
                    "hem_width=0 (repeatable; default: the template's)")
    ap.add_argument("--material-param", action="append", default=[], metavar="KEY=VALUE",
                    help="a field of the t-shirt's cotton (sim.garments.materials.Material), e.g. "
                    "friction=0.2 (repeatable; default: the preset)")


def add_batch_arguments(ap: argparse.ArgumentParser) -> None:
    """``--batch`` sizes of the garment-frames/s runs and their ``--batch-prelude``."""
    ap.add_argument("--batch", default="", help="batch sizes for garment-frames/s, e.g. 1,16,64,256,1024")
    ap.add_argument("--batch-prelude", type=float, default=None,
                    help="seconds of the batched runs' settle and of their way into the motion (a "
                         "procedural motion's ramp, a file's blend) (default: the config's and the "
                         "motion's; shorter keeps 1,024-sequence runs within minutes, the timed motion "
                         "frames are the same)")


def option_error(option: str, e: Exception) -> None:
    """Exit with status 2 and argparse's one-line form, ``PROG: error: OPTION: message``."""
    print(f"{os.path.basename(sys.argv[0])}: error: {option}: {e}", file=sys.stderr)
    raise SystemExit(2)


def numbers(items: list[str], option: str, check) -> dict:
    """``KEY=NUMBER`` items as {key: value}, accepted by ``check(values)``; else exit 2 with a
    one-line error."""
    from pipelines.options import parse_numbers
    from sim.errors import WrinklesInputError

    try:
        out = parse_numbers(items, option)
        check(out)
    except WrinklesInputError as e:
        option_error(option, e)
    return out


def template_params(args: argparse.Namespace) -> dict:
    """``--param`` as {name: value} (``make_params`` checks names and ranges)."""
    from sim.garments.templates import make_params

    return numbers(args.param, "--param", lambda out: make_params("t_shirt", **out))


def material_changes(args: argparse.Namespace) -> dict:
    """``--material-param`` as {field: value} (``Material.with_`` checks the fields)."""
    from sim.garments.materials import get_material

    return numbers(args.material_param, "--material-param", lambda out: get_material("cotton").with_(**out))


def benchmark_motion(name: str, body, seconds: float, betas=None, **params):
    """The procedural motion (or motion file) ``name`` at 30 fps for ``seconds``, on the skeleton
    of ``body`` at ``betas`` (``MotionSkeleton.from_body``, as the CLI and datasets build it)."""
    from sim.motions import MotionSkeleton, load_motion

    skeleton = MotionSkeleton.from_body(body, betas)
    return load_motion(name, fps=FPS, duration=seconds, skeleton=skeleton, **params)


def build_garment(body, vertices: int, material: dict | None = None, **params: float):
    """The t-shirt template at the edge length that gives about ``vertices`` vertices (the vertex
    count goes as 1 / edge^2), in cotton with the fields ``material`` changed, with template
    ``params``, fitted to the mean shape: (garment, edge length [m])."""
    from sim.garments import make_garment
    from sim.garments.materials import get_material
    from sim.garments.templates import TEMPLATES

    t = TEMPLATES["t_shirt"]
    edge = t.coarse * math.sqrt(t.vertices[0] / float(vertices))
    return make_garment("t_shirt", body, None, resolution=edge,
                        material=get_material("cotton").with_(**(material or {})), **params), edge


def load_scene(args: argparse.Namespace):
    """(device, default body, t-shirt, its edge length [m], {motion name: motion})."""
    from sim.bodies.default import load_default_body
    from sim.device import resolve_device

    body = load_default_body()
    garment, edge = build_garment(body, args.vertices, material_changes(args), **template_params(args))
    motions = {n: benchmark_motion(n, body, args.seconds) for n in args.motions.split(",")}
    return resolve_device(args.device), body, garment, edge, motions


def quality_dict(q) -> dict:
    """The JSON-ready figures of a ``sim.quality.QualityReport``."""
    return {"max_edge_strain": q.max_edge_strain, "mean_edge_strain": q.mean_edge_strain,
            "max_stretch": q.max_stretch, "max_compression": q.max_compression,
            "inside_fraction_max": float(np.max(q.inside_fraction)),
            "inside_fraction_mean": float(np.mean(q.inside_fraction)),
            "self_intersections_max": int(np.max(q.self_intersections)),
            "self_intersections_mean": float(np.mean(q.self_intersections)), "finite": bool(q.finite)}


def device_memory_peak_gib(device: str) -> float | None:
    """Peak of Warp's CUDA memory pool so far [GiB] (None on the CPU or without a pool)."""
    from sim.device import warp

    wp = warp()
    if not wp.get_device(device).is_cuda or not wp.is_mempool_enabled(device):
        return None
    return round(wp.get_mempool_used_mem_high(device) / 2**30, 3)


def run_ours(garment, body, motion, cfg, batch: int = 1):
    """Figures of ``batch`` copies of the sequence in one model (JSON-ready) and the first copy's
    ``SimulationResult`` (None when the run stopped). ``ms_per_frame`` is the mean wall time of the
    motion's solver frames, launch to device synchronisation (host copies and checks excluded)."""
    from sim.quality import SimulationError
    from sim.simulate import SimulationJob, simulate_batch

    jobs = [SimulationJob(garment, body, motion, None) for _ in range(batch)]
    t0 = time.perf_counter()
    try:
        results = simulate_batch(jobs, config=cfg)
    except SimulationError as e:
        return {"error": str(e), "wall_s": time.perf_counter() - t0}, None
    r = results[0]
    ms = r.step_ms
    out = {"ms_per_frame": float(ms.mean()), "ms_per_frame_median": float(np.median(ms)),
           "frames": int(len(ms)), "garment_frames_per_s": 1000.0 * batch / float(ms.mean()),
           "wall_s": time.perf_counter() - t0,
           "failed_gates": sorted({g for res in results for g in res.failed_gates}),
           "sequences_failing_gates": sum(1 for res in results if not res.passed)}
    peak = device_memory_peak_gib(cfg.device)
    if peak is not None:
        out["device_memory_peak_gib"] = peak
    if batch == 1:
        out["quality"] = quality_dict(r.quality)
    return out, r


def run_batches(garment, body, motion, cfg, args: argparse.Namespace) -> dict:
    """{batch size: figures} of ``args.batch`` sequences of ``motion`` in one model."""
    if args.batch_prelude is not None:
        cfg = dataclasses.replace(cfg, settle_seconds=args.batch_prelude, blend_seconds=args.batch_prelude)
        if "lead_in" in motion.extra:  # a procedural motion enters through its lead-in (its ramp)
            motion = benchmark_motion(motion.source.removeprefix("procedural:"), body, args.seconds,
                                      ramp=args.batch_prelude)
    out = {}
    for nb in [int(s) for s in args.batch.split(",")]:
        out[str(nb)], _ = run_ours(garment, body, motion, cfg, batch=nb)
        out[str(nb)]["prelude_s"] = cfg.settle_seconds
        print("batch", nb, json.dumps(out[str(nb)]), flush=True)
    return out


def scene_sizes(garment, body, edge: float, args: argparse.Namespace) -> dict:
    """The sizes a t-shirt result records."""
    return {"garment_vertices": garment.num_vertices, "garment_faces": garment.num_faces, "edge_m": edge,
            "body_vertices": int(body.num_vertices), "fps": FPS, "seconds": args.seconds,
            "motions": args.motions.split(",")}
