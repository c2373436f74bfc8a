"""Dataset generation end to end: sequences per hour, garment-frames per second and bytes per
frame on disk, for fine garments, coarse garments, and the default fine + coarse.

Each case generates a fresh dataset from one config (t-shirts and straight skirts on sampled
bodies, walk / arm_raise / squat, cotton and jersey, self-contact on, the job's solver defaults
and retries, 256^2 UV images) with ``sim.datasets.generate`` in a temporary folder, and reports
the wall time of the whole job and where it goes (``sim.profiling``: garments; per rung of the
retry ladder the simulation's prelude with the body's part separation, model building, steps
and results; judging; derivation per field; writing). Phases wait for the device at their ends
so GPU work counts where it is launched; ``--no-phases`` times the job without those waits.

    python -m benchmarks.bench_dataset --device cuda --sequences 8 --seconds 1 --batch 8
    python -m benchmarks.bench_dataset --device cpu --sequences 1 --seconds 0.1 --batch 1 --cases coarse \
        --resolution 0.07
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time

from benchmarks.common import add_results_argument, machine, write_result

CONFIG = """\
seed = {seed}
sequences = {sequences}
fps = 30.0
seconds = {seconds}

[garments]
categories = ["t_shirt", "straight_skirt"]
fine_resolution = {fine}
fit = "{fit}"
coarse_resolution = "coarse"

[materials]
names = ["cotton", "jersey_knit"]

[bodies]
betas = 4

[motions]
procedural = ["walk", "arm_raise", "squat"]

[split]
test_fraction = 0.1
ood_motions = ["squat"]

[simulation]
self_contact = true

[derive]
image_resolution = 256
coarse = {coarse}
"""


def parse(text: str, source: str):
    """The generator config of the TOML ``text`` (``source`` names it in errors)."""
    from sim.datasets.config import parse_config

    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover
        import tomli as tomllib
    return parse_config(tomllib.loads(text), source=source)


def generate_in_temp(text: str, source: str, batch: int, device: str, phases: bool = True, workers: int = 0):
    """Generate a dataset from the config TOML ``text`` in a temporary folder, removed after:
    (``GenerateSummary``, wall time [s] of the whole job, manifest, phases: ``PHASES.report()``
    or None, the reader's derivation afterwards: ``{"s", "bytes"}``), each generated line printed.
    ``workers`` > 0: on a local Dask cluster of that many worker processes, worker i on GPU i
    (``sim.datasets.cluster``; no phases: they are timed in the workers)."""
    from sim.datasets import storage as S
    from sim.datasets.generate import generate
    from sim.profiling import PHASES

    cfg = parse(text, source)

    root = tempfile.mkdtemp(prefix="wrinkles-bench-")
    try:
        phases = phases and not workers
        if phases:
            PHASES.start(device)
        t0 = time.perf_counter()
        if workers:
            from sim.datasets.cluster import generate_on_cluster

            s = generate_on_cluster(cfg, root, workers=workers, batch=batch, device=device,
                                    log=lambda m: print(m, flush=True))
        else:
            s = generate(cfg, root, batch=batch, device=device, log=lambda m: print(m, flush=True))
        wall = time.perf_counter() - t0
        report = PHASES.report() if phases else None
        PHASES.stop()
        return s, wall, S.read_manifest(root), report, _derive_on_read(root, device)
    finally:
        PHASES.stop()
        shutil.rmtree(root, ignore_errors=True)


def simulation_alone(text: str, batch: int, device: str) -> dict:
    """The first group of the config TOML ``text`` (its first ``batch`` sequences, fine and coarse
    jobs in one batched model, as ``generate`` simulates them) simulated again on its own: the
    prelude and the clip, no garments made (the garment cache holds them), no judging, deriving
    or writing. ``{"s", "fine_frames", "fine_frames_per_s", "stopped"}`` (every fine job's clip
    frames, stopped ones included): the denominator of the end-to-end ratio."""
    from dataclasses import replace

    from sim.bodies import load_body
    from sim.datasets.generate import group_jobs
    from sim.datasets.sampling import sample_sequences
    from sim.simulate import simulate_batch

    cfg = parse(text, "bench_dataset:alone")
    group = sample_sequences(cfg)[:batch]
    jobs, meta = group_jobs(cfg, load_body(cfg.bodies.model), group, device)
    t0 = time.perf_counter()
    results = simulate_batch(jobs, config=replace(cfg.simulation_config(), device=device), seed=group[0].seed,
                             failures="return")
    seconds = time.perf_counter() - t0
    # every fine job's clip, as the end-to-end "made" counts it: a sequence that stops is frozen in
    # the batch and costs the solver its whole length all the same
    fine = [r for r, m in zip(results, meta, strict=True) if m[-1] == "fine"]
    frames = len(fine) * int(round(cfg.seconds * cfg.fps))
    stopped = sum(not hasattr(r, "sequence") for r in fine)
    return {"s": seconds, "fine_frames": frames, "fine_frames_per_s": frames / seconds, "stopped": stopped}


def _derive_on_read(root: str, device: str) -> dict:
    """What a reader's derivation of the stored dataset costs (``wrinkles dataset derive``):
    wall seconds on ``device`` and the bytes the cache of derived fields takes."""
    from pathlib import Path

    from sim.datasets.fields import DERIVED_DIR, derive_dataset

    t0 = time.perf_counter()
    derive_dataset(root, device=device)
    seconds = time.perf_counter() - t0
    folder = Path(root) / DERIVED_DIR
    return {"s": seconds, "bytes": sum(p.stat().st_size for p in folder.glob("*")) if folder.is_dir() else 0}


def print_phases(name: str, phases: dict, wall: float) -> None:
    """A table of ``phases`` (``PHASES.report()``): seconds, own seconds, share of ``wall``."""
    print(f"{name}: where {wall:.1f} s went (phase: s, outside nested phases, share of the wall time)")
    for path, p in phases.items():
        print(f"  {path:<48} {p['s']:9.2f} s {p['self_s']:9.2f} s {100.0 * p['self_s'] / wall:6.1f} %"
              f"  x{p['calls']}")
    inside = sum(p["self_s"] for p in phases.values())
    rest = wall - inside
    print(f"  {'(outside every phase)':<48} {rest:9.2f} s {'':11} {100.0 * rest / wall:6.1f} %")


def run_case(text: str, name: str, args, device: str) -> dict:
    """One case's figures: its dataset generated (``generate_in_temp``), and with ``--alone`` its
    first group simulated alone (``simulation_alone``) for the end-to-end ratios."""
    s, wall, manifest, phases, derive = generate_in_temp(text, f"bench_dataset:{name}", args.batch, device,
                                                         phases=not args.no_phases, workers=args.workers)
    seqs = list(manifest["sequences"].values())
    frames = sum(e["frames"] for e in seqs)
    made = s.accepted + s.rejected
    clip = int(round(args.seconds * 30.0))  # every sequence's stored frames (accepted or not)
    alone = simulation_alone(text, args.batch, device) if args.alone else None
    return {
        "sequences": made, "accepted": s.accepted, "rejected": s.rejected,
        "rejections": {k: v["reasons"] for k, v in manifest["rejected"].items()},
        "wall_s": wall, "sequences_per_hour": 3600.0 * made / wall,
        "garment_frames_per_s": frames / wall if frames else 0.0,
        "bytes_per_frame": s.bytes / max(frames, 1),
        # the fields a reader derives from the stored ones, all at once, with their cache
        "derive_on_read_s": derive["s"], "derived_bytes_per_frame": derive["bytes"] / max(frames, 1),
        "vertices": sorted({e["vertices"] for e in seqs}),
        "coarse_vertices": sorted({e["coarse_vertices"] for e in seqs if e.get("coarse_vertices")}),
        "simulation_alone": alone,
        # accepted fine frames per second over the same batch's simulation alone; "made" counts
        # every sequence's clip, accepted or not (the engine's overhead without the gates)
        "ratio_accepted": frames / wall / alone["fine_frames_per_s"] if alone else None,
        "ratio_made": made * clip / wall / alone["fine_frames_per_s"] if alone else None,
        "phases": phases,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--sequences", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=1.0, help="motion length [s] (plus 2 s of prelude)")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--cases", default="coarse,fine,fine+coarse")
    ap.add_argument("--resolution", type=float, default=None,
                    help="edge length [m] of every case's garments instead of the templates' coarse / fine "
                    "size (the coarse twin keeps the templates' coarse size)")
    ap.add_argument("--fit", default="body", choices=("body", "reference"),
                    help="[garments] fit: body: a garment sewn for every sequence's shape; reference: one "
                    "per category on the mean shape, the body morphing to the sequence's shape in the settle")
    ap.add_argument("--workers", type=int, default=0,
                    help="generate on a local Dask cluster of this many workers, worker i on GPU i (0: in "
                    "this process; the speed-up over GPUs is the wall time of 1 worker over N's, same run)")
    ap.add_argument("--alone", type=int, default=1, choices=(0, 1),
                    help="1: also time the first group's simulation alone (prelude + clip) for the "
                    "end-to-end ratio")
    ap.add_argument("--warmup", type=int, default=1, choices=(0, 1),
                    help="1: first generate one short fine + coarse sequence of another seed, untimed, so "
                    "that Warp's kernel compilation (once per machine: its kernel cache keeps them) "
                    "counts apart, as warmup_s")
    ap.add_argument("--no-phases", action="store_true",
                    help="time the job without waiting for the device at every phase (no phase table)")
    ap.add_argument("--tag", default="",
                    help="suffix of the result file's name (--tag _ref32: dataset_cuda_ref32.json)")
    add_results_argument(ap)
    args = ap.parse_args()

    from sim.device import resolve_device
    from sim.garments.templates import TEMPLATES

    device = resolve_device(args.device)
    cases = {"coarse": ("coarse", "false"), "fine": ("fine", "false"), "fine+coarse": ("fine", "true")}
    fig = {}
    # every case sews its garments: a garment cache from earlier runs would hide that cost
    cache = os.environ["WRINKLES_CACHE"] = tempfile.mkdtemp(prefix="wrinkles-bench-cache-")
    warmup_s = None
    if args.warmup:
        t0 = time.perf_counter()
        generate_in_temp(CONFIG.format(seed=1000, sequences=1, seconds=0.2,
                                       fine=json.dumps(args.resolution or "fine"), coarse="true",
                                       fit=args.fit),
                         "bench_dataset:warmup", 1, device, phases=False)
        warmup_s = time.perf_counter() - t0
        print(f"warm-up (kernel compilation, untimed): {warmup_s:.1f} s", flush=True)
    for name in args.cases.split(","):
        fine, coarse = cases[name]
        fine = fine if args.resolution is None else args.resolution
        text = CONFIG.format(seed=0, sequences=args.sequences, seconds=args.seconds, fine=json.dumps(fine),
                             coarse=coarse, fit=args.fit)
        fig[name] = run_case(text, name, args, device)
        phases, wall = fig[name]["phases"], fig[name]["wall_s"]
        print(name, json.dumps({k: v for k, v in fig[name].items() if k != "phases"}), flush=True)
        if phases:
            print_phases(name, phases, wall)
    write_result(f"dataset_{device.split(':')[0]}{args.tag}", {
        "machine": machine(device),
        "sizes": {"sequences": args.sequences, "seconds": args.seconds, "batch": args.batch, "fps": 30.0,
                  "image_resolution": 256, "resolution": args.resolution, "fit": args.fit,
                  "workers": args.workers,
                  "edge_m": {c: {"coarse": TEMPLATES[c].coarse, "fine": TEMPLATES[c].fine}
                             for c in ("t_shirt", "straight_skirt")}},
        "warmup_s": warmup_s,
        "figures": fig,
    }, args.results)
    shutil.rmtree(cache, ignore_errors=True)


if __name__ == "__main__":
    main()
