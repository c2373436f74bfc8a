"""``wrinkles train``: train a method on a dataset with the shared trainer (learn.train)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from sim.errors import WrinklesInputError

HELP = "train a garment model on a dataset (checkpoints, resume, EMA, TensorBoard, DDP)"
DESCRIPTION = """\
Train a method (learn.methods.METHODS) on a wrinkles dataset with the shared trainer.

The run directory gets config.json (the resolved config), checkpoints/last.pt (+ numbered ones),
metrics.jsonl, curves.png and tensorboard/ (view with: tensorboard --logdir RUN). Checkpoints are
written atomically; Ctrl-C finishes the current step, writes a checkpoint and stops; --resume
continues bit-exactly (on CPU) from the last checkpoint. Configs are TOML files with the tables
[train], [optim] and [model] (unknown keys are refused); --set overrides single keys.

Methods:
  skinned_mlp        baseline: garment skinned by body weights + a per-vertex pose/shape MLP offset
  skeleton_cvae      Guo et al. coarse model (alias: coarse): SSDR virtual skeleton + pose/shape CVAE
  wrinkle_diffusion  Guo et al. wrinkles (alias: wrinkles): strain-conditioned UV diffusion, DDIM
  displacement_regressor  LFGD-style baseline: world-frame displacement maps regressed from the base
  deepwrinkles       Lähner et al. 2018: registered subspace, pose-to-shape LSTM, normal-map cGAN
  gsnet              GSNet: graph skinning network, one model for garments of any topology

Multi-GPU (or multi-process CPU, gloo): launch through torchrun, the global batch is split:
  torchrun --nproc_per_node 4 -m pipelines.cli train skinned_mlp --data DIR --out RUN

examples:
  wrinkles train coarse --data data/tshirt --out runs/tshirt-coarse --steps 20000
  wrinkles train wrinkles --data data/tshirt --out runs/tshirt-wrinkles --set model.conditioning=strain_tensor
  wrinkles train skinned_mlp --data data/sample --out runs/mlp --steps 2000
  wrinkles train deepwrinkles --data data/tshirt --out runs/dw \
      --config pipelines/configs/train/deepwrinkles.toml --device cuda
  wrinkles train gsnet --data data/gsnet --out runs/gsnet --config pipelines/configs/train/gsnet.toml
  wrinkles train skinned_mlp --data data/sample --out runs/mlp --config my.toml --set optim.lr=3e-4
  wrinkles train skinned_mlp --data data/sample --out runs/mlp --resume --steps 4000
  wrinkles evaluate --model runs/mlp/checkpoints/last.pt --data data/sample --split test_id
"""


def _parse_set(text: str) -> tuple[str, object]:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"--set {text!r}: expected key=value, e.g. optim.lr=3e-4")
    from pipelines.options import toml_value

    key, raw = text.split("=", 1)
    return key.strip(), toml_value(raw)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("method", help="the method to train (listed above)")
    p.add_argument("--data", required=True, help="dataset directory (wrinkles dataset generate)")
    p.add_argument("--out", required=True, help="run directory (created)")
    p.add_argument("--config", help="TOML file with [train], [optim], [model] tables")
    p.add_argument("--set", dest="overrides", type=_parse_set, action="append", default=[],
                   metavar="KEY=VALUE",
                   help="override one config key, e.g. --set train.batch_size=16 (repeatable)")
    p.add_argument("--steps", type=int, help="total optimizer steps (train.steps)")
    p.add_argument("--batch-size", type=int, help="global batch size (train.batch_size)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument("--device", help="torch device: auto, cpu, cuda, cuda:N (train.device)")
    p.add_argument("--seed", type=int, help="run seed (train.seed)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress (bar or lines)")


def resolve_config(args: argparse.Namespace):
    """The run config from --config, the method name and the command-line overrides."""
    from learn.train.config import apply_overrides, run_config_from_dict
    from sim.datasets.config import _load_toml

    data: dict = _load_toml(Path(args.config)) if args.config else {}
    from learn.methods import METHOD_ALIASES

    if "method" in data and data["method"] != METHOD_ALIASES.get(args.method, args.method):
        raise WrinklesInputError(f"the config is for method {data['method']!r}, not {args.method!r}",
                                 path=args.config)
    from learn.methods import METHOD_ALIASES

    args.method = METHOD_ALIASES.get(args.method, args.method)
    data = {**data, "method": args.method}
    overrides = dict(args.overrides)
    for flag, key in (("steps", "train.steps"), ("batch_size", "train.batch_size"),
                      ("device", "train.device"), ("seed", "train.seed")):
        if getattr(args, flag) is not None:
            overrides[key] = getattr(args, flag)
    return run_config_from_dict(apply_overrides(data, overrides), source=args.config or "command line")


def run(args: argparse.Namespace) -> int:
    from learn.train.trainer import Trainer, describe
    from pipelines.progress import progress_bar
    from sim.datasets.storage import read_manifest

    cfg = resolve_config(args)
    read_manifest(args.data)  # a missing or broken dataset fails here, before training
    main_process = int(os.environ.get("RANK", "0")) == 0
    if int(os.environ.get("WORLD_SIZE", "1")) == 1:
        # on the GPU if there is one (under torchrun each rank derives what it reads: run 'wrinkles
        # dataset derive' first)
        from pipelines.dataset_cmd import derive_first

        derive_first(args.data, None, quiet=args.quiet)
    with progress_bar(cfg.train.steps, f"train {cfg.method}", quiet=args.quiet or not main_process,
                      unit="step") as advance:
        summary = Trainer(cfg, args.data, args.out, resume=args.resume, progress=advance).fit()
    if main_process:
        print(describe(summary), file=sys.stderr)
    return 130 if summary.interrupted else 0
