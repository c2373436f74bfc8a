"""``wrinkles dataset``: generate synthetic garment datasets, inspect them, report on them."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from sim.errors import WrinklesInputError

HELP = "generate a synthetic garment dataset (resumable, sharded); info, report, derive, combine"
DESCRIPTION = """\
Synthetic garment datasets for the wrinkle models (sim.datasets; layout in sim/datasets/storage.py,
arrays in sim/datasets/schema.py).

  generate  sample garments, materials, body shapes and motions from a TOML config, simulate
            each sequence at fine (and coarse) resolution, reject those that fail the quality
            gates (logged with why in rejections.jsonl), and store one file per sequence: the
            positions, the rest garments, the body's motion and the quality record (the base
            surface, wrinkle field, strain, normals and UV images are derived from them where
            they are read, and cached: 'derive').
            Resumable (--resume) and sharded (--shard i/n); the same config and seed give
            byte-identical sequence files on the same device.
  info      counts and statistics of a dataset
  report    PNGs: contact sheet of renders, example UV images, histograms
  derive    derive every sequence's base, wrinkle, strain, normals and UV images into the cache
            (DIR/derived/) ahead of training; readers derive them on first use otherwise
  combine   rebuild manifest.json from the shard parts (after copying shards together)

examples:
  wrinkles dataset generate --config sample --out data/sample
  wrinkles dataset generate --config my.toml --out data/big --shard 0/4 --device cuda:0
  wrinkles dataset generate --config my.toml --out data/big --shard 0/4 --resume
  wrinkles dataset generate --config my.toml --out data/big --batch 64 --workers 4 --device cuda
  wrinkles dataset generate --config my.toml --out /shared/big --batch 64 --scheduler tcp://head:8786
  wrinkles dataset generate --config my.toml --out data/big-test --splits test_id,test_ood --device cuda
  wrinkles dataset info data/sample
  wrinkles dataset report data/sample
"""


def _shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--shard {text!r}: expected i/n, e.g. 0/4") from None
    if not (n >= 1 and 0 <= i < n):
        raise argparse.ArgumentTypeError(f"--shard {text!r}: need n >= 1 and 0 <= i < n")
    return i, n


def _splits(text: str) -> tuple[str, ...]:
    return tuple(x.strip() for x in text.split(",") if x.strip())  # checked by select_indices


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.options import add_common_arguments

    sub = p.add_subparsers(dest="dataset_command", metavar="ACTION")
    g = sub.add_parser("generate", help="generate (or resume) a dataset from a config",
                       description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    g.add_argument("--config", required=True,
                   help="generator config: a TOML file, or 'sample' (the shipped small config, "
                        "pipelines/configs/sample.toml; runs on a CPU in about a minute)")
    g.add_argument("--out", required=True, help="dataset directory")
    g.add_argument("--shard", type=_shard, default=(0, 1), metavar="i/n",
                   help="make sequences i, i+n, i+2n, ... (default: 0/1, all of them)")
    g.add_argument("--resume", action="store_true", help="continue a started shard")
    g.add_argument("--batch", type=int, default=1,
                   help="sequences simulated together in one batched model (GPU throughput; "
                        "default: %(default)s)")
    g.add_argument("--workers", type=int, default=None, metavar="N",
                   help="spread the batches over a local Dask cluster of N worker processes (with several "
                        "GPUs, worker i uses GPU i mod GPUs); needs pip install 'wrinkles[distributed]'")
    g.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="spread the batches over a running Dask cluster (dask-jobqueue on Slurm/PBS, "
                        "dask-kubernetes, dask scheduler + dask worker): every worker must see --out")
    g.add_argument("--splits", type=_splits, default=None, metavar="S[,S]",
                   help="make only the sequences of these splits (train, test_id, test_ood), e.g. the "
                        "test sets again on another machine (default: all)")
    add_common_arguments(g, seed=False)
    g.set_defaults(_action=run_generate)

    i = sub.add_parser("info", help="print counts and statistics of a dataset")
    i.add_argument("root", help="dataset directory")
    i.add_argument("--json", action="store_true", help="print JSON instead of a table")
    i.set_defaults(_action=run_info)

    from pipelines.dataset_report import REPORT_DESCRIPTION, REPORT_HELP, add_report_arguments

    r = sub.add_parser("report", help=REPORT_HELP, description=REPORT_DESCRIPTION,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    add_report_arguments(r)
    r.set_defaults(_action=_run_report)

    d = sub.add_parser("derive", help="derive every sequence's derived fields into the cache, ahead of "
                       "training",
                       description="Sequence files store positions, rest garments, the body's motion and "
                       "quality; the base surface, wrinkle field, strain, normals and UV images are derived "
                       "from them on first read and cached in DIR/derived/ (sim/datasets/fields.py). This "
                       "derives them all now, on --device (a GPU is much faster than the CPU a data "
                       "loader would use).")
    d.add_argument("root", help="dataset directory")
    d.add_argument("--split", default=None, help="only this split (train, test_id, test_ood; default: all)")
    add_common_arguments(d, seed=False)
    d.set_defaults(_action=run_derive)

    c = sub.add_parser("combine", help="rebuild manifest.json from parts/ (shards copied together)")
    c.add_argument("root", help="dataset directory")
    c.add_argument("--verify", action="store_true", help="re-hash every sequence file")
    c.set_defaults(_action=run_combine)


def run(args: argparse.Namespace) -> int:
    action = getattr(args, "_action", None)
    if action is None:
        print("wrinkles dataset: choose an action: generate, info, report, derive, combine "
              "(wrinkles dataset --help)", file=sys.stderr)
        return 2
    return action(args)


def _run_report(args: argparse.Namespace) -> int:
    from pipelines.dataset_report import run_report

    return run_report(args)


def run_generate(args: argparse.Namespace) -> int:
    from pipelines.progress import progress_bar
    from sim.datasets.config import load_config
    from sim.datasets.generate import generate
    from sim.datasets.sampling import sample_sequences, select_indices
    from sim.device import resolve_device

    cfg = load_config(args.config)  # every check, user motion files included, before simulating
    device = resolve_device(args.device) if args.scheduler is None else args.device  # the workers' GPUs
    shard, shards = args.shard
    distributed = args.workers is not None or args.scheduler is not None
    if distributed and (shards != 1 or args.workers is not None and args.scheduler is not None):
        raise WrinklesInputError("--workers / --scheduler: one of them, and without --shard (the cluster "
                                 "job makes every shard)")
    if distributed:
        shard, shards = 0, 1  # all of it
    n = len(select_indices(sample_sequences(cfg), shard, shards, args.splits))
    where = (f"on {args.workers} workers" if args.workers else f"on {args.scheduler}") if distributed else \
        f"shard {shard}/{shards}"
    t0 = time.perf_counter()
    log = None if args.quiet else (lambda s: print(s, file=sys.stderr))
    try:
        with progress_bar(n, f"dataset {where}", quiet=args.quiet, unit="sequence") as advance:
            if distributed:
                from sim.datasets.cluster import generate_on_cluster

                summary = generate_on_cluster(cfg, args.out, workers=args.workers, scheduler=args.scheduler,
                                              batch=args.batch, device=args.device, resume=args.resume,
                                              splits=args.splits, progress=advance, log=log)
            else:
                summary = generate(cfg, args.out, shard=shard, shards=shards, resume=args.resume,
                                   batch=args.batch, device=device, progress=advance, splits=args.splits,
                                   log=log)
    except KeyboardInterrupt as e:
        from pipelines.interrupts import interruption

        how, code = interruption(e)
        print(f"wrinkles dataset generate: {how}; finished sequences are kept, run again with --resume "
              "to continue", file=sys.stderr)
        return code
    gfs = summary.garment_frames / summary.seconds if summary.seconds > 0 else 0.0
    print(f"{args.out}: {summary.accepted} accepted, {summary.rejected} rejected, "
          f"{summary.skipped} already done, {summary.recovered} recovered; "
          f"{summary.garment_frames} frames, {summary.bytes / 2**20:.1f} MiB in "
          f"{time.perf_counter() - t0:.1f} s ({gfs:.1f} garment-frames/s, {device})")
    return 0


def run_combine(args: argparse.Namespace) -> int:
    from sim.datasets import storage as S

    root = Path(args.root)
    cfg_path = root / "config.json"
    if not cfg_path.exists():
        raise WrinklesInputError("no config.json: not a dataset directory", path=root)
    m = S.combine_parts(root, config=json.loads(cfg_path.read_text()), verify=args.verify)
    print(f"{root / S.MANIFEST}: {len(m['sequences'])} sequences, {len(m['rejected'])} rejected")
    return 0


def derive_first(root, device: str | None, *, split: str | None = None,
                 quiet: bool = False) -> tuple[int, int]:
    """Fill the dataset's cache of derived fields (``sim.datasets.fields.derive_dataset``) on
    ``device`` with a progress bar, before a command reads them (a reader would derive them on
    the CPU, one sequence at a time). Returns ``(derived now, current already)``."""
    from pipelines.progress import progress_bar
    from sim.datasets.fields import derive_dataset

    what = "derive fields" if split is None else f"derive fields of {split}"
    with progress_bar(0, what, quiet=quiet, unit="sequence") as advance:
        return derive_dataset(root, device=device, split=split, progress=advance)


def run_derive(args: argparse.Namespace) -> int:
    from sim.datasets.schema import SPLITS
    from sim.device import resolve_device

    if args.split is not None and args.split not in SPLITS:
        raise WrinklesInputError(f"--split {args.split!r}: choose one of {', '.join(SPLITS)}")
    device = resolve_device(args.device)
    made, current = derive_first(args.root, device, split=args.split, quiet=args.quiet)
    print(f"{args.root}: derived {made} sequences, {current} were current ({device})")
    return 0


def run_info(args: argparse.Namespace) -> int:
    from sim.datasets.info import dataset_statistics, format_statistics

    stats = dataset_statistics(args.root)
    print(json.dumps(stats, indent=1) if args.json else format_statistics(stats))
    return 0
