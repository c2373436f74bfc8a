"""``wrinkles animate --method gsnet``: any garment (a template sewn for the body, or a garment file
modelled around the rest body) animated by a GSNet checkpoint from the body's motion alone, no
simulation, no retraining: the network's garment encoder reads the garment's own mesh
(learn.methods.gsnet). Written as the other methods: USD stage (body + garment with UVs), sidecar
JSON, previews."""

from __future__ import annotations

import argparse
import time
import types
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError

DEFAULT_MODEL = Path(__file__).resolve().parents[1] / "pretrained" / "gsnet.pt"
"""The shipped GSNet release file (pretrained/MODEL_CARD.md), used without ``--model``."""

DEFAULT_RESOLUTION = 0.02
"""Edge length [m] a template garment is sewn at without ``--resolution``: the shipped model's
training data (pipelines/configs/gsnet.toml)."""


def check_options(args: argparse.Namespace) -> None:
    """The other methods' options are refused, and ``--garment`` / ``--resolution`` checked (a
    garment file is animated with its own mesh), in one line, before anything is loaded."""
    from pipelines.simulate_cmd import check_garment_spec

    for key, flag in (("coarse", "--coarse"), ("wrinkles", "--wrinkles"), ("steps", "--steps"),
                      ("data", "--data"), ("surface", "--surface"), ("normal_map_bits", "--normal-map-bits")):
        if getattr(args, key, None) is not None:
            raise WrinklesInputError(f"{flag} does not apply to --method gsnet")
    if args.no_wrinkles or args.sample_latent:
        raise WrinklesInputError("--no-wrinkles / --sample-latent do not apply to --method gsnet")
    if not (args.clearance >= 0 and args.clearance < 0.1):
        raise WrinklesInputError(f"--clearance must be in [0, 0.1) m, got {args.clearance}")
    check_garment_spec(types.SimpleNamespace(garment=args.garment, resolution=args.resolution))


def model_path(args: argparse.Namespace) -> Path:
    path = Path(args.model) if args.model else DEFAULT_MODEL
    if not path.is_file():
        if args.model:
            raise WrinklesInputError("no such model file", path=path)
        raise WrinklesInputError("no shipped GSNet model in this checkout; train one (wrinkles train gsnet "
                                 "--config pipelines/configs/train/gsnet.toml) and pass --model", path=path)
    return path


def load_garment(args: argparse.Namespace, body, betas: np.ndarray):
    """The garment ``--garment`` names (template, garment file or GarmentCode pattern) on the rest
    body of shape ``betas``, in ``--material`` (``pipelines.simulate_cmd.load_garment_arg``)."""
    from pipelines.simulate_cmd import load_garment_arg

    spec = types.SimpleNamespace(garment=args.garment, garment_param=[], material=args.material or "cotton",
                                 material_param=[], resolution=args.resolution or str(DEFAULT_RESOLUTION),
                                 quiet=args.quiet)
    return load_garment_arg(spec, body, np.asarray(betas, np.float32))


def run(args: argparse.Namespace) -> int:
    """The command; returns the exit status."""
    check_options(args)
    from learn.gsnet.data import garment_template, motion_of
    from learn.train.distributed import resolve_torch_device
    from learn.train.trainer import load_trained
    from pipelines.animate_cmd import grounded_frames, write_animation
    from pipelines.animate_deepwrinkles import outside
    from pipelines.options import load_body_and_motion
    from pipelines.outputs import check_stage_outputs
    from sim.device import resolve_device

    t0 = time.perf_counter()
    path = model_path(args)
    out = args.out or f"out/gsnet_{Path(args.garment).stem}_{Path(args.motion).stem}.usdc"
    paths = check_stage_outputs(out, args.preview, args.sheet, sidecar=".animate.json")
    bm = load_body_and_motion(args)
    garment = load_garment(args, bm.body, bm.betas)
    dev, wdev = resolve_torch_device(args.device), resolve_device(args.device)
    method, model, _ = load_trained(path, device=dev)
    if method.name != "gsnet":
        raise WrinklesInputError(f"a {method.name} checkpoint; --method gsnet needs a gsnet one", path=path)
    frames, _ = grounded_frames(bm, wdev)
    template = garment_template(garment, bm.body, bm.betas, neighbours=method.config.skin_neighbours)
    seq = {"body/poses": bm.motion.poses, "body/joints": frames.joints[:, :24], "body/betas": bm.betas}
    transforms, roots = motion_of(seq, bm.body)
    t1 = time.perf_counter()
    verts = method.animate(model, template, transforms, roots, fps=float(bm.motion.fps), device=dev,
                           body_vertices=frames.vertices, body_faces=frames.faces)
    seconds = {"predict": time.perf_counter() - t1}
    verts = outside(verts, frames, args.clearance, wdev)
    provenance = {"method": "gsnet", "model": str(path), "device": str(dev), "garment": str(args.garment),
                  "stage_seconds": {k: round(v, 3) for k, v in seconds.items()}}
    write_animation(args, paths, garment, verts, bm, frames, provenance)
    if not args.quiet:
        print(f"gsnet {garment.name} ({verts.shape[1]} vertices) on {bm.motion.name}: {len(verts)} frames, "
              f"{dev}, {time.perf_counter() - t0:.1f} s")
        for p in paths.written():
            print(f"  wrote {p}")
    return 0

