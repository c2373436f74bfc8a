"""``wrinkles animate``: a body motion in, a wrinkled garment out, written as USD (body + garment
with UVs) and previews: Guo et al. 2024's learned pipeline (learn.animate, ``--method diffusion``)
or a DeepWrinkles checkpoint (pipelines.animate_deepwrinkles, ``--method deepwrinkles``)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from pipelines.outputs import (
    DEFAULT_USD_SUFFIX,
    OutputSet,
    add_body_points_option,
    check_stage_outputs,
    command_line,
    stage_rig,
    write_previews,
)
from pipelines.progress import progress_bar
from sim.errors import WrinklesInputError

HELP = "animate a garment with learned wrinkles (CVAE + strain diffusion, or DeepWrinkles); USD + video"
DESCRIPTION = """\
Animate a garment on a moving body with a learned model, no simulation. By default (--method
diffusion) Guo et al. 2024's pipeline: body pose and shape -> CVAE -> 64 virtual bones -> LBS
base mesh -> Green-Lagrange strain map -> DDIM wrinkle diffusion -> wrinkles decoded onto the
base -> USD stage + preview.

Without --coarse/--wrinkles the shipped default models of --garment are used (pretrained/, see
pretrained/MODEL_CARD.md: t_shirt and straight_skirt). The garment is the models' own cut (the
mean-shape template they were trained on), worn by the body --shape gives. --steps trades speed
for detail (50 = the paper's setting; 10-20 is a good preview on a CPU). Frames share one initial
noise and are guided toward their neighbours while denoising, so the wrinkles do not flicker.

--method deepwrinkles animates a DeepWrinkles checkpoint (--model, 'wrinkles train deepwrinkles'):
body motion -> LSTM -> global shape (the coarse template, posed) -> LR normal map -> cGAN -> HR
normal map of the wrinkles. Its garment is the one of the dataset it was trained on
(reference-fit: one garment for every body), kept in the checkpoint, or taken from the first
training sequence of --data; the body is posed with the training data's body model. The stage
holds (--surface global, default) the global shape on the fine garment's mesh with the predicted
normal maps on its material (per-frame 16-bit PNGs in <stage>_normals/ beside the stage: the
wrinkles are in the shading, as DeepWrinkles renders them; Blender imports the first frame's
map), or (--surface fine) the fine garment moved to match the maps (the wrinkles in the geometry,
no maps: on that surface they would count twice). Previews draw the fine garment either way.

--method gsnet animates any garment with a GSNet checkpoint (--model, 'wrinkles train gsnet'):
--garment is a template sewn for the body --shape gives (at --resolution), a garment file modelled
around the rest body (as 'wrinkles simulate' takes it) or a GarmentCode pattern, in --material;
the network reads the garment's own mesh, so a design it never saw needs no retraining. Body
motion -> garment encoder + deep skinning (learned garment-joint edges) -> physical regression
of the vertices inside the body, frame by frame from the previous frames.

--body/--shape/--motion/--motion-param/--rest/--duration/--fps are those of 'wrinkles body'.

examples:
  wrinkles animate --garment tshirt --motion walk --duration 2 --out out/tshirt_walk.usdc \\
      --preview out/tshirt_walk.mp4
  wrinkles animate --garment skirt --motion squat --shape 1.0,-0.5 --steps 20 --out skirt.usdc
  wrinkles animate --garment tshirt --motion CMU_01_01.npz --fps 30 --steps 50 --device cuda \\
      --out walk.usdc --sheet walk.png
  wrinkles animate --coarse runs/coarse/checkpoints/last.pt --wrinkles runs/wr/checkpoints/last.pt \\
      --motion run --out mine.usda
  wrinkles animate --method deepwrinkles --model runs/dw/checkpoints/last.pt \\
      --motion walk --shape height=0.6 --out out/dw_walk.usdc --preview out/dw_walk.mp4
  wrinkles animate --method gsnet --model runs/gsnet/checkpoints/last.pt --garment flared_skirt \\
      --motion run --material silk --out out/skirt_run.usdc --preview out/skirt_run.mp4
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.options import add_body_arguments, add_common_arguments, add_motion_arguments

    g = p.add_argument_group("garment and models")
    g.add_argument(
        "--method",
        default="diffusion",
        choices=("diffusion", "deepwrinkles", "gsnet"),
        help="diffusion: Guo et al. 2024's CVAE + strain diffusion (--coarse/--wrinkles or the shipped "
        "models); deepwrinkles: Lahner et al. 2018 (--model, else the shipped one of --garment); "
        "gsnet: the graph skinning network, any garment (--model, else the shipped one) "
        "(default: %(default)s)",
    )
    g.add_argument(
        "--garment",
        default="t_shirt",
        help="garment category of the shipped models: t_shirt (tshirt), straight_skirt (skirt) "
        "(default: %(default)s; ignored with --coarse, and with --method deepwrinkles --model); "
        "--method gsnet: any template (sewn for the body) or garment file around the rest body",
    )
    g.add_argument("--coarse", help="skeleton_cvae checkpoint (default: the shipped one of --garment)")
    g.add_argument("--wrinkles", help="wrinkle_diffusion checkpoint (default: the shipped one of --garment)")
    g.add_argument("--no-wrinkles", action="store_true", help="write the coarse base mesh only")
    g.add_argument("--steps", type=int, help="DDIM steps (default: the model's, 50)")
    g.add_argument("--material", help="material label of the wrinkle model (default: its first); "
                   "--method gsnet: the garment's material preset (default: cotton)")
    g.add_argument(
        "--sample-latent",
        action="store_true",
        help="draw the CVAE latent z ~ N(0, I) instead of its mean (another plausible fit)",
    )
    d = p.add_argument_group("--method deepwrinkles / gsnet")
    d.add_argument("--model", help="DeepWrinkles or GSNet checkpoint or release file ('wrinkles train "
                   "deepwrinkles' / 'wrinkles train gsnet')")
    d.add_argument("--resolution", help="--method gsnet: edge length [m] a template garment is sewn at "
                   "(default: 0.02, the shipped model's data)")
    d.add_argument("--data", help="the dataset the model was trained on: its first training sequence "
                   "gives the garment meshes (default: the garment the checkpoint keeps)")
    d.add_argument("--surface", choices=("global", "fine"), help="global: the global shape + normal maps; "
                   "fine: the fine garment moved to match the maps, no maps (default: global)")
    d.add_argument("--normal-map-bits", type=int, choices=(8, 16),
                   help="bit depth of the normal-map PNGs (default: 16; 8: files several times smaller)")
    g.add_argument(
        "--clearance",
        type=float,
        default=0.002,
        help="move garment vertices that end inside the body (or closer than this [m]) out to this "
        "distance from the skin, on the base and on the result (0: off; default: %(default)s)",
    )
    m = p.add_argument_group("body and motion")
    add_motion_arguments(m)
    add_body_arguments(m)
    o = p.add_argument_group("outputs")
    o.add_argument(
        "--out", help="USD stage to write: .usdc or .usd (binary crate) or .usda (text: larger and slower "
        "to open, for reading and diffing) (default: out/<garment>_<motion>.usdc; "
        "out/deepwrinkles_<garment>_<motion>.usdc with --method deepwrinkles)"
    )
    add_body_points_option(o)
    o.add_argument("--preview", help="preview video to write (.mp4 or .gif)")
    o.add_argument("--sheet", help="contact sheet PNG to write (8 frames)")
    o.add_argument(
        "--camera",
        default="three_quarter",
        choices=("front", "side", "three_quarter"),
        help="preview camera (default: %(default)s)",
    )
    add_common_arguments(p)


def _model_paths(args: argparse.Namespace) -> tuple[Path, Path | None]:
    from learn.animate import available_pretrained, pretrained_paths
    from pipelines.simulate_cmd import resolve_template

    if args.coarse:
        c = Path(args.coarse)
        w = Path(args.wrinkles) if args.wrinkles else None
        if w is None and not args.no_wrinkles:
            raise WrinklesInputError("--coarse needs --wrinkles (or --no-wrinkles)")
    else:
        category = resolve_template(args.garment)
        c, w = pretrained_paths(category)
        if not c.exists():
            have = available_pretrained()
            raise WrinklesInputError(
                f"no shipped models for {category} (shipped: {', '.join(have) or 'none'}); "
                "train your own (wrinkles train coarse / wrinkles) and pass --coarse "
                "and --wrinkles"
            )
        if args.wrinkles:
            w = Path(args.wrinkles)
    for path in (c, w):
        if path is not None and not path.is_file():
            raise WrinklesInputError("no such model file", path=path)
    return c, None if args.no_wrinkles else w


def _check_options(args: argparse.Namespace) -> None:
    if args.steps is not None and args.steps < 1:
        raise WrinklesInputError(f"--steps must be >= 1, got {args.steps}")
    if not (args.clearance >= 0 and args.clearance < 0.1):
        raise WrinklesInputError(f"--clearance must be in [0, 0.1) m, got {args.clearance}")


def grounded_frames(bm, device: str):
    """The body posed by the motion, stood on the floor at frame 0, and the motion's root
    translations moved with it."""
    from sim.bodies.placement import floor_offset, translate_frames

    frames = bm.body.pose(bm.betas, bm.motion.poses, bm.motion.trans, device=device)
    dy = floor_offset(frames, frame=0)
    frames = translate_frames(frames, np.array([0.0, dy, 0.0]))
    trans = bm.motion.trans + np.array([0.0, dy, 0.0], np.float32)
    return frames, trans


def write_animation(args: argparse.Namespace, paths, garment, verts: np.ndarray, bm, frames,
                    provenance: dict) -> None:
    """The stage, its sidecar JSON and the previews (``paths``: ``check_stage_outputs``) of a
    garment animated on ``bm``'s body (``frames``), all or none; ``provenance`` gains the command
    line, the seed and the versions."""
    from pipelines.simulate_cmd import preview_meshes, write_sequence_usd
    from sim.types import GarmentSequence
    from sim.versions import package_versions

    provenance = {"command": command_line(), **provenance, "seed": args.seed,
                  "versions": package_versions("usd-core")}
    seq = GarmentSequence(vertices=verts, body=frames, garment=garment, motion=bm.motion,
                          fps=float(bm.motion.fps), provenance=provenance)
    betas = [float(b) for b in np.asarray(bm.betas).ravel()]
    metadata = json.loads(json.dumps({**provenance, "motion_params": bm.params, "betas": betas}))
    with OutputSet() as outputs:
        write_sequence_usd(outputs.temp(paths.usd), seq, metadata, quiet=args.quiet,
                           rig=stage_rig(bm.body, bm.betas, frames, points=args.body_points))
        outputs.temp(paths.sidecar).write_text(json.dumps(metadata, indent=2, sort_keys=True) + "\n")
        write_previews(outputs, paths, lambda: preview_meshes(seq), num_frames=len(verts), fps=seq.fps,
                       camera=args.camera, quiet=args.quiet)


def _garment(pipe, material: str | None):
    """The models' garment with the wrinkle model's material (its first unless named)."""
    from sim.garments.materials import get_material
    from sim.garments.types import Garment

    material = material or (
        pipe.wrinkles.materials[0] if pipe.wrinkles and pipe.wrinkles.materials else "cotton"
    )
    return Garment(
        rest_vertices=pipe.rest,
        faces=pipe.faces,
        uvs=pipe.uvs,
        uv_faces=pipe.uv_faces,
        face_layers=pipe.face_layers,
        material=get_material(material),
        attachments={},
        category=pipe.category,
        name=pipe.category,
    )


def _check_method_options(args: argparse.Namespace) -> None:
    """The options of the other method are refused (one line)."""
    if args.method == "gsnet":
        return  # pipelines.animate_gsnet.check_options
    if args.resolution is not None:
        raise WrinklesInputError("--resolution applies to --method gsnet")
    if args.method == "deepwrinkles":
        return
    for key, flag in (("model", "--model"), ("data", "--data"), ("surface", "--surface"),
                      ("normal_map_bits", "--normal-map-bits")):
        if getattr(args, key) is not None:
            raise WrinklesInputError(f"{flag} applies to --method deepwrinkles")


def run(args: argparse.Namespace) -> int:
    _check_method_options(args)
    if args.method == "deepwrinkles":
        from pipelines.animate_deepwrinkles import run as run_deepwrinkles

        return run_deepwrinkles(args)
    if args.method == "gsnet":
        from pipelines.animate_gsnet import run as run_gsnet

        return run_gsnet(args)
    return _run_diffusion(args)


def _run_diffusion(args: argparse.Namespace) -> int:
    import torch

    from learn.animate import WrinklePipeline
    from learn.train.distributed import resolve_torch_device
    from pipelines.options import load_body_and_motion
    from sim.device import resolve_device

    t0 = time.perf_counter()
    _check_options(args)
    coarse, wrinkles = _model_paths(args)
    label = Path(args.garment).stem if not args.coarse else coarse.stem
    out = args.out or f"out/{label}_{Path(args.motion).stem}{DEFAULT_USD_SUFFIX}"
    paths = check_stage_outputs(out, args.preview, args.sheet, sidecar=".animate.json")
    dev = resolve_torch_device(args.device)
    wdev = resolve_device(args.device)
    torch.manual_seed(args.seed)

    pipe = WrinklePipeline(coarse, wrinkles, device=dev)
    bm = load_body_and_motion(args)
    body_name = pipe.coarse.state.get("body_model", "default")
    if body_name not in ("default", str(args.body)) and not args.coarse:
        print(f"note: the models were trained on body model {body_name!r}", file=sys.stderr)
    frames, trans = grounded_frames(bm, wdev)
    T = len(trans)
    steps = args.steps or (pipe.wrinkles.config.sample_steps if pipe.wrinkles else 0)
    # the diffusion is nearly all of the time (the coarse stage, strain and decoding take ~1 %)
    stage = f"wrinkle sampling ({steps} DDIM steps)"
    with progress_bar(T, stage, quiet=args.quiet or wrinkles is None) as advance:
        res = pipe(
            bm.motion.poses,
            trans,
            bm.betas,
            steps=args.steps,
            material=args.material,
            seed=args.seed,
            sample_latent=args.sample_latent,
            progress=advance,
            body_vertices=frames.vertices,
            body_faces=frames.faces,
            clearance=args.clearance,
        )
    provenance = {
        "coarse_model": str(coarse),
        "wrinkle_model": None if wrinkles is None else str(wrinkles),
        "ddim_steps": steps,
        "device": str(dev),
        "stage_seconds": {k: round(v, 3) for k, v in res.seconds.items()},
    }
    write_animation(args, paths, _garment(pipe, args.material), res.vertices, bm, frames, provenance)
    if not args.quiet:
        what = f"{steps} DDIM steps" if wrinkles is not None else "base only"
        print(
            f"{pipe.category} ({len(pipe.rest)} vertices) on {bm.motion.name}: {T} frames, {what}, {dev}, "
            f"{time.perf_counter() - t0:.1f} s"
        )
        for p in paths.written():
            print(f"  wrote {p}")
    return 0
