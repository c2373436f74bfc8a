"""``wrinkles body``: pose a body with a motion, write USD and a preview."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from pipelines.outputs import (
    OutputSet,
    add_body_points_option,
    check_stage_outputs,
    command_line,
    stage_rig,
    write_previews,
)
from pipelines.progress import progress_bar

HELP = "pose a body with a motion; write an animated USD stage and a preview"
DESCRIPTION = """\
Pose a body with a motion and write it as an animated USD stage (Y up, metres), with an
optional MP4/GIF preview and PNG contact sheet.

The body is the embedded default body (no download, no licence wall) or an SMPL, SMPL-H or
SMPL-X model file you supply (.npz or .pkl). The motion is a name from the procedural
library ('wrinkles motions' lists them) or an AMASS .npz / BVH file. A BVH file's rest pose
(all rotations zero) is read as SMPL's T-pose with the file's own limb directions, so A-pose
and CMU rests come out with the head level and the wrists straight; --rest changes that.

examples:
  wrinkles body --motion walk --out walk.usdc --preview walk.mp4
  wrinkles body --motion run --motion-param speed=3.5 --shape height=0.6,weight=0.3 --out run.usdc
  wrinkles body --body SMPL_NEUTRAL.npz --motion CMU_01_01.npz --fps 30 --out clip.usdc
  wrinkles body --motion capture.bvh --shape 1.0,-0.5 --out capture.usdc --sheet capture.png
  wrinkles body --motion capture.bvh --rest tpose --out capture.usdc
  wrinkles body --motion squat --self-crossings --out squat.usda
  wrinkles body --measurements --shape height=0.6,weight=0.8
  wrinkles body --measurements-json body.json --shape gender=1
"""

def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.options import add_body_arguments, add_common_arguments, add_motion_arguments

    add_motion_arguments(p)
    add_body_arguments(p)
    p.add_argument("--out", required=False, default="out/body.usdc",
                   help="USD stage to write: .usdc or .usd (binary, compact), .usda (text) "
                        "(default: %(default)s)")
    add_body_points_option(p)
    p.add_argument("--preview", default=None, help="preview video to write (.mp4 or .gif)")
    p.add_argument("--sheet", default=None, help="contact sheet PNG to write (8 frames)")
    p.add_argument("--camera", default="three_quarter", choices=("front", "side", "three_quarter"),
                   help="preview camera, fitted once to the whole motion (default: %(default)s)")
    p.add_argument("--no-ground", action="store_true",
                   help="keep the motion's own height instead of standing frame 0 on the floor")
    p.add_argument("--self-crossings", action="store_true",
                   help="also count the frames where the posed body passes through itself (linear "
                        "blend skinning folds the skin through itself at deep flexion: knee pits, "
                        "groin, armpits; a garment caught there may fail the quality gates for the "
                        "body's sake), by joint; printed and kept in the stage's metadata")
    m = p.add_argument_group("measurements")
    m.add_argument("--measurements", action="store_true",
                   help="print the rest body's tailor's measurements instead of posing it: girths "
                        "(tape around the section's convex hull), lengths and landmark heights, in "
                        "cm, with how each is taken; no motion is loaded and no stage is written")
    m.add_argument("--measurements-json", default=None, metavar="FILE",
                   help="write the rest body's measurements to this .json file (metres, the rest "
                        "mesh's frame) instead of posing it; with --measurements the table is "
                        "printed too")
    add_common_arguments(p)


def run(args: argparse.Namespace) -> int:
    from pipelines.options import check_fps, load_body_and_motion
    from pipelines.preview import frames_to_preview_meshes
    from sim.bodies.placement import ground
    from sim.device import resolve_device
    from sim.versions import package_versions

    if args.measurements or args.measurements_json:
        return run_measurements(args)
    t0 = time.perf_counter()
    paths = check_stage_outputs(args.out, args.preview, args.sheet)
    check_fps(args.fps)
    device = resolve_device(args.device)

    bm = load_body_and_motion(args)
    body, betas, motion, params = bm.body, bm.betas, bm.motion, bm.params

    with progress_bar(motion.num_frames, "skinning", quiet=args.quiet) as advance:
        frames = body.pose_motion(motion, betas, device=device, progress=advance)
    dy = 0.0
    if not args.no_ground:
        frames, dy = ground(frames)

    crossings = None
    if args.self_crossings:
        from sim.quality import body_self_crossings

        with progress_bar(frames.num_frames, "self-crossings", quiet=args.quiet) as advance:
            crossings = body_self_crossings(frames.vertices, body.faces, body.rest_mesh(betas), body.weights,
                                            body.joint_names, device=device, progress=advance)
    metadata = {
        "command": command_line(),
        "config": {"motion": motion.name, "motion_source": motion.source, "fps": motion.fps,
                   "frames": motion.num_frames, "body": body.name, "body_source": body.source,
                   "betas": [float(b) for b in body.full_betas(betas)], "params": params,
                   "seed": args.seed, "device": device, "ground_offset_m": dy},
        "versions": package_versions("usd-core"),
    }
    if crossings is not None:
        metadata["self_crossings"] = crossings
    with OutputSet() as outputs:
        write_body_usd(outputs.temp(paths.usd), frames, motion.fps, body.name, metadata, quiet=args.quiet,
                       rig=stage_rig(body, betas, frames, points=args.body_points))
        write_previews(outputs, paths, lambda: frames_to_preview_meshes(frames), num_frames=frames.num_frames,
                       fps=motion.fps, camera=args.camera, quiet=args.quiet)
    if not args.quiet:
        print(f"{motion.name}: {motion.num_frames} frames at {motion.fps:g} fps, body "
              f"{body.name} ({body.num_vertices} vertices), {device}, "
              f"{time.perf_counter() - t0:.1f} s")
        if crossings is not None:
            print("  self-crossings: " + describe_self_crossings(crossings))
        for p in paths.written():
            print(f"  wrote {p}")
    return 0


def run_measurements(args: argparse.Namespace) -> int:
    """``--measurements`` / ``--measurements-json``: the rest body's measurements, table and/or JSON."""
    from pipelines.options import parse_body_shape
    from pipelines.outputs import OutputSet, check_output_path
    from sim.bodies import load_body
    from sim.garments.body_measurements import measure_body, measurement_notes

    path = check_output_path(args.measurements_json, (".json",), "--measurements-json") \
        if args.measurements_json else None
    body = load_body(args.body)
    betas = parse_body_shape(body, args.shape)
    m = measure_body(body, betas)
    if args.measurements:
        print(f"body {body.name}, shape {args.shape or 'mean'}: tailor's measurements at rest [cm]; "
              "heights and points in the rest mesh's frame (Y up, facing +Z, left at +x)")
        print(measurement_table(m.to_dict(), measurement_notes()))
    if path is not None:
        record = {"body": body.name, "body_source": body.source, "shape": args.shape,
                  "betas": [float(b) for b in body.full_betas(betas)], "units": "m",
                  "frame": "rest mesh: T-pose, Y up, facing +Z, the body's left at +x",
                  "measurements": m.to_dict(), "how": measurement_notes()}
        with OutputSet() as outputs:
            outputs.temp(path).write_text(json.dumps(record, indent=1) + "\n")
        if not args.quiet:
            print(f"wrote {path}")
    return 0


def measurement_table(values: dict, notes: dict, width: int = 100) -> str:
    """Rows of name, value in cm and how it is taken (wrapped to ``width`` columns)."""
    import textwrap

    def cm(v) -> str:
        if isinstance(v, dict) and "center" in v:
            return f"centre {cm(v['center'])} width {cm(v['width'])} depth {cm(v['depth'])}"
        if isinstance(v, dict):
            return ", ".join(f"{k} {cm(a)}/{cm(b)}" for k, (a, b) in v.items())
        if isinstance(v, list):
            return ("(" + ", ".join(cm(x) for x in v) + ")") if not isinstance(v[0], list) \
                else " ".join(cm(x) for x in v)
        return f"{round(100 * v, 1) + 0.0:.1f}"  # + 0.0: no "-0.0"

    rows = []
    for name, v in values.items():
        text = cm(v)
        note = textwrap.wrap(notes.get(name, ""), width - 38) or [""]
        if len(text) > 10:  # points and sections: the value on its own line
            rows.append(f"{name:<18} {text}")
            rows += [f"{'':<38}{line}" for line in note]
        else:
            rows.append(f"{name:<18} {text:>10}         {note[0]}")
            rows += [f"{'':<38}{line}" for line in note[1:]]
    return "\n".join(rows)


def describe_self_crossings(c: dict) -> str:
    """``sim.quality.body_self_crossings``' summary in words (one clause, no line break)."""
    n = len(c["per_frame"])
    if not c["frames_with_crossings"]:
        return f"the body does not pass through itself in its {n} frames"
    where = ", ".join(f"{k} {len(v['frames'])}" for k, v in
                      sorted(c["by_joint"].items(), key=lambda kv: -len(kv[1]["frames"])))
    return (f"the body passes through itself in {c['frames_with_crossings']} of {n} frames "
            f"(at most {c['max_edges']} edges; frames by joint: {where}); a garment caught there may fail "
            "the quality gates for the body's sake")


def write_body_usd(path: Path, frames, fps: float, name: str, metadata: dict, *, quiet: bool,
                   rig=None) -> None:
    from usd_io import write_stage

    with progress_bar(frames.num_frames, "writing USD", quiet=quiet) as advance:
        write_stage(path, body=frames, fps=fps, body_name="Body",
                    metadata=json.loads(json.dumps(metadata)),
                    progress=advance, rig=rig)
