"""``wrinkles body``: pose a body with a motion, write USD and a preview."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from pipelines.outputs import OutputSet, check_output_path
from pipelines.progress import progress_bar
from sim.errors import WrinklesInputError

HELP = "pose a body with a motion; write an animated USD stage and a preview"
DESCRIPTION = """\
Pose a body with a motion and write it as an animated USD stage (Y up, metres), with an
optional MP4/GIF preview and PNG contact sheet.

The body is the embedded default body (no download, no licence wall) or an SMPL, SMPL-H or
SMPL-X model file you supply (.npz or .pkl). The motion is a name from the procedural
library ('wrinkles motions' lists them) or an AMASS .npz / BVH file.

examples:
  wrinkles body --motion walk --out walk.usda --preview walk.mp4
  wrinkles body --motion run --param speed=3.5 --shape height=0.9,weight=0.3 --out run.usdc
  wrinkles body --body SMPL_NEUTRAL.npz --motion CMU_01_01.npz --fps 30 --out clip.usda
  wrinkles body --motion capture.bvh --shape 1.0,-0.5 --out capture.usda --sheet capture.png
"""

USD_SUFFIXES = (".usda", ".usdc", ".usd")
PREVIEW_SUFFIXES = (".mp4", ".gif")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.cli import add_common_arguments

    p.add_argument("--motion", default="walk",
                   help="procedural motion name, or an AMASS .npz / .bvh file (default: %(default)s)")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="a procedural motion parameter, e.g. --param speed=1.6 (repeatable; "
                        "'wrinkles motions' lists each motion's parameters)")
    p.add_argument("--duration", type=float, default=None,
                   help="length of a procedural motion [s] (default: the motion's own)")
    p.add_argument("--fps", type=float, default=30.0,
                   help="output frame rate [1/s]; files are resampled to it (default: %(default)s)")
    p.add_argument("--body", default="default",
                   help="'default' (embedded body) or an SMPL/SMPL-H/SMPL-X model file (.npz/.pkl)")
    p.add_argument("--shape", default=None,
                   help="body shape: comma-separated betas ('0.5,-1.2') or, for the default body, "
                        "named phenotype values ('height=0.8,weight=0.3')")
    p.add_argument("--out", required=False, default="out/body.usda",
                   help="USD stage to write: .usda (text), .usdc or .usd (binary) "
                        "(default: %(default)s)")
    p.add_argument("--preview", default=None, help="preview video to write (.mp4 or .gif)")
    p.add_argument("--sheet", default=None, help="contact sheet PNG to write (8 frames)")
    p.add_argument("--camera", default="three_quarter", choices=("front", "side", "three_quarter"),
                   help="preview camera, fitted once to the whole motion (default: %(default)s)")
    p.add_argument("--no-ground", action="store_true",
                   help="keep the motion's own height instead of standing frame 0 on the floor")
    add_common_arguments(p)


def parse_params(items: list[str]) -> dict[str, float | str]:
    """``["speed=1.5", "side=left"]`` -> ``{"speed": 1.5, "side": "left"}``."""
    out: dict[str, float | str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise WrinklesInputError(f"--param {item!r}: expected KEY=VALUE")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            out[key.strip()] = value.strip()
    return out


def run(args: argparse.Namespace) -> int:
    from sim.bodies import load_body
    from sim.bodies.placement import ground
    from sim.device import resolve_device
    from sim.motions import MotionSkeleton, accepts_parameter, load_motion

    t0 = time.perf_counter()
    out_usd = check_output_path(args.out, USD_SUFFIXES, "--out")
    out_preview = check_output_path(args.preview, PREVIEW_SUFFIXES, "--preview") if args.preview else None
    out_sheet = check_output_path(args.sheet, (".png",), "--sheet") if args.sheet else None
    if not (np.isfinite(args.fps) and args.fps > 0):
        raise WrinklesInputError(f"--fps must be a positive number, got {args.fps}")
    device = resolve_device(args.device)

    body = load_body(args.body)
    betas = parse_body_shape(body, args.shape)
    params = parse_params(args.param)
    if accepts_parameter(args.motion, "seed"):
        params.setdefault("seed", args.seed)
    # procedural motions place the feet with this body's own joints and soles
    motion = load_motion(args.motion, fps=args.fps, duration=args.duration,
                         skeleton=MotionSkeleton.from_body(body, betas), **params)

    with progress_bar(motion.num_frames, "skinning", quiet=args.quiet) as advance:
        frames = body.pose_motion(motion, betas, device=device, progress=advance)
    dy = 0.0
    if not args.no_ground:
        frames, dy = ground(frames)

    metadata = {
        "command": "wrinkles " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
        "config": {"motion": motion.name, "motion_source": motion.source, "fps": motion.fps,
                   "frames": motion.num_frames, "body": body.name, "body_source": body.source,
                   "betas": [float(b) for b in body.full_betas(betas)], "params": params,
                   "seed": args.seed, "device": device, "ground_offset_m": dy},
        "versions": _versions(),
    }
    with OutputSet() as outputs:
        write_body_usd(outputs.temp(out_usd), frames, motion.fps, body.name, metadata, quiet=args.quiet)
        if out_preview or out_sheet:
            from pipelines.preview import frames_to_preview_meshes, write_contact_sheet, write_video

            meshes = frames_to_preview_meshes(frames)
            if out_preview:
                with progress_bar(frames.num_frames, "preview", quiet=args.quiet) as advance:
                    write_video(meshes, outputs.temp(out_preview), fps=motion.fps, camera=args.camera,
                                progress=advance)
            if out_sheet:
                write_contact_sheet(meshes, outputs.temp(out_sheet), fps=motion.fps, camera=args.camera)
    written = [p for p in (out_usd, out_preview, out_sheet) if p]
    if not args.quiet:
        print(f"{motion.name}: {motion.num_frames} frames at {motion.fps:g} fps, body "
              f"{body.name} ({body.num_vertices} vertices), {device}, "
              f"{time.perf_counter() - t0:.1f} s")
        for p in written:
            print(f"  wrote {p}")
    return 0


def parse_body_shape(body, spec: str | None) -> np.ndarray | None:
    """Betas from ``--shape`` for this body (phenotype names only for the default body)."""
    if spec is None:
        return None
    if body.kind == "default":
        from sim.bodies.default import parse_shape

        return parse_shape(spec)
    try:
        return np.array([float(x) for x in spec.split(",") if x.strip()], dtype=np.float32)
    except ValueError as e:
        raise WrinklesInputError(
            f"--shape {spec!r}: an SMPL-family body takes comma-separated betas "
            f"(named phenotypes are for the default body)") from e


def write_body_usd(path: Path, frames, fps: float, name: str, metadata: dict, *, quiet: bool) -> None:
    from usd_io import write_stage

    with progress_bar(frames.num_frames, "writing USD", quiet=quiet) as advance:
        write_stage(path, body=frames, fps=fps, body_name="Body",
                    metadata=json.loads(json.dumps(metadata)),
                    progress=advance)


def _versions() -> dict[str, str]:
    import importlib.metadata as md

    out = {}
    for pkg in ("wrinkles", "warp-lang", "numpy", "usd-core"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out
