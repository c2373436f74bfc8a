"""Issue 3 benchmark: a ~5k-vertex t-shirt on the default body, walk and run, body and self
collision on; milliseconds per 30 fps frame, quality gates; optionally Newton's SolverVBD on
the same scene in the same run; batched garment-frames per second.

    python -m benchmarks.bench_tshirt --device cuda --newton --batch 1,16,64,256
    python -m benchmarks.bench_tshirt --device cpu --vertices 1000 --seconds 1   (CI scale)

Our side runs the full pipeline (``sim.simulate``: settle on the rest body, blend into the
motion, CUDA graph per frame). ``ms_per_frame`` is the mean wall time of the solver frames of
the motion (launch to device synchronisation; host copies and checks excluded). Newton starts
from our dressed state at the motion's first frame and plays the same body frames at the same
substeps x iterations (``benchmarks/newton_ref.py``). Quality for both: ``sim.quality``.

The solver runs at the job defaults (``sim.simulate.SimulationConfig``: 12 substeps x 5
iterations, 14 x 8 over 10k garment vertices, a coarse-level correction before sweep 2);
``--solver '{"coarse_sweeps": []}'`` turns the correction off.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from benchmarks.common import machine, write_result


def add_scene_arguments(ap: argparse.ArgumentParser) -> None:
    """The scene options the t-shirt benchmarks share: device, t-shirt size, motions, length."""
    ap.add_argument("--device", default="auto")
    ap.add_argument("--vertices", type=int, default=5000, help="t-shirt size (default: %(default)s)")
    ap.add_argument("--motions", default="walk,run")
    ap.add_argument("--seconds", type=float, default=2.0, help="motion length [s]")
    add_material_argument(ap)
    add_skeleton_argument(ap)


def add_skeleton_argument(ap: argparse.ArgumentParser) -> None:
    """``--motion-skeleton``: which skeleton a procedural motion is built on (``benchmark_motion``)."""
    ap.add_argument("--motion-skeleton", choices=("body", "default"), default="body",
                    help="build procedural motions on the body's own skeleton and soles, as `wrinkles "
                    "simulate` and dataset generation do ('body', default since session 48), or on "
                    "SMPL's approximate skeleton ('default', every benchmark figure before session 48: "
                    "7 %% longer strides, the root 3 cm off the body's floor)")


def benchmark_motion(name: str, body, seconds: float, skeleton: str = "body", betas=None, **params):
    """The procedural motion (or motion file) ``name`` at 30 fps for ``seconds``, built on the
    skeleton ``skeleton`` names: ``"body"`` the body's own at ``betas`` (``MotionSkeleton.from_body``,
    what the CLI and dataset generation use), ``"default"`` SMPL's approximate one."""
    from sim.motions import MotionSkeleton, load_motion

    sk = {"skeleton": MotionSkeleton.from_body(body, betas)} if skeleton == "body" else {}
    return load_motion(name, fps=30.0, duration=seconds, **sk, **params)


def add_material_argument(ap: argparse.ArgumentParser) -> None:
    """``--material-param`` and ``--param``: fields of the t-shirt's cotton and parameters of its
    template changed for an experiment."""
    ap.add_argument("--material-param", action="append", default=[], metavar="KEY=VALUE",
                    help="a field of the t-shirt's cotton (sim.garments.materials.Material) for this run, "
                    "e.g. friction=0.2 against skin (repeatable; default: the preset)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="a template parameter of the t-shirt (or of --garment where there is one; "
                    "`wrinkles garments` lists them), e.g. "
                    "neck_fillet=0 or hem_width=0 (repeatable; default: the template's)")


def template_params(args: argparse.Namespace) -> dict:
    """``--param`` as {name: value}; an unknown name or a value out of range (``make_params``
    decides) or a bad number exits with a one-line error."""
    from sim.garments.templates import make_params

    category = getattr(args, "garment", "t_shirt")
    return _numbers(args.param, "--param", lambda out: make_params(category, **out))


def material_changes(args: argparse.Namespace) -> dict:
    """``--material-param`` as {field: value}; an unknown field (``Material.with_`` decides) or a
    bad number exits with a one-line error."""
    from sim.garments.materials import get_material

    return _numbers(args.material_param, "--material-param", lambda out: get_material("cotton").with_(**out))


def _numbers(items: list[str], option: str, check) -> dict:
    """``KEY=NUMBER`` items as {key: value}, accepted by ``check(values)``; else exit 2 with a
    one-line error (``_option_error``)."""
    from pipelines.options import parse_numbers
    from sim.errors import WrinklesInputError

    try:
        out = parse_numbers(items, option)
        check(out)
    except WrinklesInputError as e:
        _option_error(option, e)
    return out


def _option_error(option: str, e: Exception) -> None:
    """Exit with status 2 and argparse's one-line form, ``PROG: error: OPTION: message``."""
    import os

    print(f"{os.path.basename(sys.argv[0])}: error: {option}: {e}", file=sys.stderr)
    raise SystemExit(2)


def load_scene(args: argparse.Namespace):
    """The scene of ``add_scene_arguments``: (device, default body, t-shirt, its edge length [m],
    {motion name: motion})."""
    from sim.bodies.default import load_default_body
    from sim.device import resolve_device

    body = load_default_body()
    garment, edge = build_garment(body, args.vertices, material_changes(args), **template_params(args))
    motions = {n: benchmark_motion(n, body, args.seconds, args.motion_skeleton)
               for n in args.motions.split(",")}
    return resolve_device(args.device), body, garment, edge, motions


def add_single_scene_arguments(ap: argparse.ArgumentParser, device: str = "auto", motion: str = "walk",
                               seconds: float = 1.0) -> None:
    """The options of the one-motion diagnostics (``profile_tshirt``, ``detect_census``,
    ``pair_share``): device, t-shirt size, motion, length."""
    ap.add_argument("--device", default=device)
    ap.add_argument("--vertices", type=int, default=5000, help="t-shirt size (default: %(default)s)")
    ap.add_argument("--motion", default=motion, help="(default: %(default)s)")
    ap.add_argument("--seconds", type=float, default=seconds, help="motion length [s] (default: %(default)s)")
    add_skeleton_argument(ap)


def load_single_scene(args: argparse.Namespace):
    """The scene of ``add_single_scene_arguments``: (device, default body, t-shirt, motion)."""
    from sim.bodies.default import load_default_body
    from sim.device import resolve_device

    body = load_default_body()
    garment, _ = build_garment(body, args.vertices)
    return (resolve_device(args.device), body, garment,
            benchmark_motion(args.motion, body, args.seconds, args.motion_skeleton))


def build_garment(body, vertices: int, material: dict | None = None, category: str = "t_shirt",
                  betas=None, **params: float):
    """The t-shirt template (or the template ``category``) at the edge length that gives about
    ``vertices`` vertices, in cotton with the fields ``material`` changed (``material_changes``),
    with template ``params``, fitted to the body of shape ``betas`` (None: the mean shape)."""
    from sim.garments import make_garment
    from sim.garments.materials import get_material
    from sim.garments.templates import TEMPLATES

    t = TEMPLATES[category]
    edge = t.coarse * math.sqrt(t.vertices[0] / float(vertices))
    return make_garment(category, body, betas, resolution=edge,
                        material=get_material("cotton").with_(**(material or {})), **params), edge


def add_batch_arguments(ap: argparse.ArgumentParser) -> None:
    """Options of the batched garment-frames/s runs the t-shirt benchmarks share."""
    ap.add_argument("--batch", default="", help="batch sizes for garment-frames/s, e.g. 1,16,64,256,1024")
    ap.add_argument("--batch-prelude", type=float, default=None,
                    help="settle and blend seconds (each) of the batched runs (default: the config's 1 s; "
                    "shorter keeps 1024-sequence runs within minutes, the timed motion frames are unchanged)")
    ap.add_argument("--batch-solver", default="{}", help="JSON dict of VBDConfig fields for the batched runs "
                    "only (e.g. lanes and particles_per_block, whose best values depend on the batch size)")


def run_batches(garment, body, motion, cfg, args: argparse.Namespace) -> dict:
    """garment-frames/s of ``args.batch`` sequences in one model, each a JSON-ready dict."""
    import dataclasses

    bcfg = dataclasses.replace(cfg, solver={**cfg.solver, **json.loads(args.batch_solver)})
    if args.batch_prelude is not None:
        bcfg = dataclasses.replace(bcfg, settle_seconds=args.batch_prelude, blend_seconds=args.batch_prelude)
    out = {}
    for nb in [int(s) for s in args.batch.split(",")]:
        out[str(nb)], _ = run_ours(garment, body, motion, bcfg, batch=nb)
        out[str(nb)].update(prelude_s=bcfg.settle_seconds, solver=bcfg.solver)
        print("batch", nb, json.dumps(out[str(nb)]), flush=True)
    return out


def device_memory_peak_gib(device: str) -> float | None:
    """Peak of Warp's CUDA memory pool so far [GiB] (None on the CPU or without a pool)."""
    from sim.device import resolve_device, warp

    wp = warp()
    d = resolve_device(device)
    if not wp.get_device(d).is_cuda or not wp.is_mempool_enabled(d):
        return None
    return round(wp.get_mempool_used_mem_high(d) / 2**30, 3)


def quality_dict(q) -> dict:
    return {"max_edge_strain": q.max_edge_strain, "mean_edge_strain": q.mean_edge_strain,
            "max_stretch": q.max_stretch, "max_compression": q.max_compression,
            "inside_fraction_max": float(np.max(q.inside_fraction)),
            "inside_fraction_mean": float(np.mean(q.inside_fraction)),
            "self_intersections_max": int(np.max(q.self_intersections)),
            "self_intersections_mean": float(np.mean(q.self_intersections)), "finite": bool(q.finite)}


def run_ours(garment, body, motion, cfg, batch: int = 1):
    """Figures of one (batched) run, JSON-ready, and the first sequence's ``SimulationResult``
    (None when the run stopped)."""
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


def run_newton(r, garment, body, cfg, device: str) -> dict:
    from benchmarks.newton_ref import run_newton_vbd
    from sim.cloth.model import as_cloth_params
    from sim.quality import evaluate_sequence

    seq = r.sequence
    mat = as_cloth_params(garment.material)
    scene = {
        "garment_positions": seq.vertices[0], "garment_rest_positions": garment.rest_vertices,
        "garment_faces": garment.faces, "face_layers": garment.face_layers, "pinned": np.zeros(0, np.int64),
        "pin_targets": np.zeros((0, 0, 3), np.float32),
        "density": mat.density, "mu": mat.mu, "lam": mat.lam, "bending": mat.bending, "damping": mat.damping,
        "friction": mat.friction, "thickness": mat.thickness,
        "body_faces": body.faces, "body_vertices": seq.body.vertices, "fps": cfg.fps,
    }
    t0 = time.perf_counter()
    res = run_newton_vbd(scene, device=device, substeps=cfg.substeps_for(garment.num_vertices),
                         iterations=cfg.iterations_for(garment.num_vertices),
                         self_contact=True, use_graph=device.startswith("cuda"))
    x = res["positions"]
    q = evaluate_sequence(x, garment.rest_vertices, garment.faces, seq.body.vertices, body.faces,
                          device=device)
    return {"ms_per_frame": res["ms_per_frame"], "graph": res.get("graph"), "quality": quality_dict(q),
            "newton_version": res.get("newton_version"), "notes": res.get("notes"),
            "wall_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    from sim.simulate import SimulationConfig

    ap.add_argument("--substeps", type=int, default=SimulationConfig.substeps)
    ap.add_argument("--iterations", type=int, default=SimulationConfig.iterations,
                    help="sweeps per substep (default: 0, automatic: 5, 8 over 10k vertices)")
    ap.add_argument("--no-self-contact", action="store_true")
    ap.add_argument("--solver", default="{}", help="JSON dict of extra VBDConfig fields")
    ap.add_argument("--newton", action="store_true", help="also run Newton's SolverVBD (needs newton)")
    add_batch_arguments(ap)
    ap.add_argument("--batch-motion", default=None, help="motion of the batched runs (default: the first)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()
    device, body, garment, edge, motions = load_scene(args)
    cfg = SimulationConfig(fps=30.0, substeps=args.substeps, iterations=args.iterations,
                           self_contact=not args.no_self_contact, solver=json.loads(args.solver),
                           device=device)
    fig: dict = {}
    for name, motion in motions.items():
        ours, r = run_ours(garment, body, motion, cfg)
        entry = {"ours": ours}
        print(name, "ours", json.dumps(ours, indent=1), flush=True)
        if args.newton and r is not None:
            try:
                entry["newton"] = run_newton(r, garment, body, cfg, device)
            except Exception as e:  # report, do not hide
                entry["newton"] = {"error": f"{type(e).__name__}: {e}"}
            print(name, "newton", json.dumps(entry["newton"], indent=1, default=str), flush=True)
        fig[name] = entry
    if args.batch:
        motion = (next(iter(motions.values())) if args.batch_motion is None
                  else benchmark_motion(args.batch_motion, body, args.seconds, args.motion_skeleton))
        fig["batched"] = run_batches(garment, body, motion, cfg, args)
    write_result(f"tshirt_{device.split(':')[0]}{args.tag}", {
        "machine": machine(device),
        "sizes": {"garment_vertices": garment.num_vertices, "garment_faces": garment.num_faces,
                  "edge_m": edge, "body_vertices": int(body.num_vertices) if hasattr(body, "num_vertices")
                  else None, "fps": 30.0, "seconds": args.seconds,
                  "substeps": cfg.substeps_for(garment.num_vertices),
                  "iterations": cfg.iterations_for(garment.num_vertices),
                  "self_contact": not args.no_self_contact, "motion_skeleton": args.motion_skeleton},
        "config": cfg.to_dict(),
        "figures": fig,
    })


if __name__ == "__main__":
    main()
