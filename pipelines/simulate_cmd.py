"""``wrinkles simulate``: dress a garment on a body, simulate it through a motion, write USD,
the quality report and previews."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from pipelines.outputs import (
    DEFAULT_USD_SUFFIX,
    OutputSet,
    StageOutputs,
    add_body_points_option,
    check_stage_outputs,
    command_line,
    stage_rig,
    write_previews,
)
from pipelines.progress import progress_bar
from sim.errors import WrinklesInputError

HELP = "simulate a garment on a moving body; write USD (body + garment with UVs) and previews"
DESCRIPTION = """\
Dress a garment on a body and simulate it through a motion with the Warp cloth solver (VBD).

The garment is placed on the body in its rest pose and settles there (--settle seconds), then
the body blends from rest into the motion's first pose (--blend seconds) and plays the motion.
That prelude is dropped from the output: the sequence starts at the motion's first frame with
the garment at rest on the body (--keep-prelude keeps it). Attachment sets named by --pin
(default: the waistband, where the garment has one) follow the skin; everything else is free
cloth.

Every frame is checked for NaN/explosion: a run that blows up stops at that frame, naming it
and the cause; when its last retry (below) stops too, that is one line, exit status 1, and
nothing is written. Every sequence gets a quality report (edge strain, fraction of garment
vertices inside the body, self-intersections) judged against quality gates (--gate). A sequence
that fails them, or stops, is simulated again at more substeps (--retry: 5/3 and then 2 times,
20 and 24 of the automatic 12: fast motions need shorter steps than the default's; a garment
over 10k vertices is not retried: more substeps rescue almost none of its failures); one that
fails at the last is an error
(exit 1, nothing written) unless --allow-failed-gates. When the gates fail, the skinned body is
checked for passing through itself within 5 cm of the garment (knee pits, groin, armpits at
deep flexion; 'wrinkles body --self-crossings'): cloth caught there may fail the gates for the
body's sake, and the error says where. The report is stored in the stage's metadata and in a
sidecar <out stem>.quality.json with the gates, the resolved config and the seed.

--garment is a template (straight_skirt, flared_skirt, shorts, trousers, tank_top, t_shirt,
long_sleeve, dress; aliases such as tshirt, tee, skirt, pants, tank) fitted to the body's
shape, or a garment file (.obj/.ply/.glb/.gltf/.off/.stl/.usd*) with UVs, in metres, modelled
around the body in its rest pose in the body's own frame (Y up, the pelvis near the origin, not
the floor-standing frame of the output stages): 'wrinkles garments --export NAME --body-out
body.obj' writes a template and that body to start from. A file far from the body or in other
units is refused. A GarmentCode / GarmentCodeData pattern file (.json) is sewn on the body at
--resolution first, as 'wrinkles garments --pattern FILE.json' does.
--body/--shape/--motion/--motion-param/--rest/--duration/--fps are those of 'wrinkles body'.

examples:
  wrinkles simulate --garment tshirt --motion walk --material cotton --out tshirt_walk.usdc \\
      --preview tshirt_walk.mp4
  wrinkles simulate --garment straight_skirt --garment-param length=0.45 --motion squat \\
      --shape height=0.6,weight=0.3 --resolution fine --out skirt.usdc --sheet skirt.png
  wrinkles simulate --garment trousers --material denim --motion run --duration 2 \\
      --substeps 20 --out jeans_run.usda
  wrinkles simulate --garment my_dress.obj --material silk --motion CMU_01_01.npz \\
      --fps 30 --out dress.usdc --allow-failed-gates
"""

CLOTH_PREVIEW_COLOR: tuple[float, float, float] = (0.22, 0.38, 0.72)
PATTERN_SUFFIX = ".json"
"""A ``--garment`` file with this suffix is a GarmentCode pattern, sewn before simulating."""
PREVIEW_CLOTH_LIFT = 0.003
"""Previews draw the garment this far out along its normals [m] so skin a fraction of a
millimetre below the cloth does not show through it (display only; USD holds the true points)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.options import add_body_arguments, add_common_arguments, add_motion_arguments

    g = p.add_argument_group("garment")
    g.add_argument("--garment", default="t_shirt",
                   help="template name or alias, a garment mesh file with UVs, or a GarmentCode pattern "
                        "file (.json) to sew (default: %(default)s)")
    g.add_argument("--garment-param", action="append", default=[], metavar="KEY=VALUE",
                   help="a template parameter [m or -], e.g. length=0.5, ease=0.02, sleeve_length=0.5 "
                        "(repeatable; an unknown key lists the template's parameters); every template "
                        "has hems, hem_width=0.02 hem_layers=3 (hem_width=0: none), and a garment file "
                        "takes those two only (its default: no hems)")
    g.add_argument("--resolution", default=None,
                   help="template mesh resolution: coarse (about 3,000 vertices; edges of 14.5-23.5 mm "
                        "by template, 'wrinkles garments' lists them), fine (about 20,000; 5.5-9 mm) or "
                        "an edge length in metres (default: coarse; a garment mesh file keeps its own mesh, "
                        "a pattern file .json is meshed at about the same vertex counts)")
    g.add_argument("--material", default="cotton",
                   help="material preset: cotton, denim, silk, polyester, jersey_knit, leather "
                        "(default: %(default)s)")
    g.add_argument("--material-param", action="append", default=[], metavar="KEY=VALUE",
                   help="override a material field in SI units, e.g. damping=2e-5, friction=0.3, "
                        "thickness=0.001 (repeatable)")
    m = p.add_argument_group("body and motion")
    add_motion_arguments(m)
    add_body_arguments(m)
    m.add_argument("--no-ground", action="store_true",
                   help="keep the motion's own height instead of standing its first frame on the floor")
    from sim.simulate import SimulationConfig

    s = p.add_argument_group("simulation")
    s.add_argument("--substeps", type=int, default=SimulationConfig.substeps,
                   help="solver substeps per frame (default: 0, automatic: 12, or 14 for a garment of "
                   "more than 10k vertices)")
    s.add_argument("--iterations", type=int, default=SimulationConfig.iterations,
                   help="VBD iterations (Gauss-Seidel sweeps) per substep (default: 0, automatic: 5, or 8 "
                   "for a garment of more than 10k vertices)")
    s.add_argument("--coarse-sweeps", default="auto",
                   help="comma-separated sweeps (0 .. iterations-1) before which a coarse-level correction "
                        "carries forces across the garment, 'none', or 'auto': before sweep 2 where there "
                        "are 3 or more (default: %(default)s)")
    s.add_argument("--settle", type=float, default=1.0,
                   help="seconds the garment settles on the body at rest (default: %(default)s)")
    s.add_argument("--blend", type=float, default=1.0,
                   help="seconds of the transition from rest to the motion's first pose "
                        "(default: %(default)s)")
    s.add_argument("--keep-prelude", action="store_true",
                   help="keep the settle and blend frames in the outputs")
    s.add_argument("--pin", default=None,
                   help="comma-separated attachment sets pinned to the skin, of those the garment has "
                        "('wrinkles garments' lists them: waistband, shoulders, hem, cuffs), or 'none' "
                        "(default: the waistband where the garment has one; tops hang free)")
    s.add_argument("--self-collision", dest="self_collision", action=argparse.BooleanOptionalAction,
                   default=True, help="cloth self-collision (vertex-triangle and edge-edge) on/off "
                   "(default: on; --no-self-collision is ~3x faster and lets folds pass through each other)")
    s.add_argument("--solver-param", action="append", default=[], metavar="KEY=VALUE",
                   help="a further VBD solver setting as section.field=VALUE, e.g. "
                   "body_contact.stiffness=2e5 or self_contact.radius=0.004 (sections: stepping, "
                   "body_contact, self_contact, coarse, layout; repeatable)")
    s.add_argument("--gate", action="append", default=[], metavar="KEY=VALUE",
                   help="a quality gate: max_edge_strain (default 0.35), max_inside_fraction (0.01), "
                        "max_self_intersections (0) (repeatable)")
    s.add_argument("--allow-failed-gates", action="store_true",
                   help="write the outputs of a sequence that fails the quality gates (exit 0)")
    s.add_argument("--retry", action=argparse.BooleanOptionalAction, default=True,
                   help="a sequence that fails a quality gate or stops (NaN, explosion) is simulated "
                        "again at 5/3 and then 2 times the substeps (20 and 24 of the automatic 12; a "
                        "garment over 10k vertices: no retries) until it passes; "
                        "the written one's substeps and the other runs are in the quality report; with "
                        "--allow-failed-gates the last run that finished is written if none passes (up to "
                        "4.7x the time of one run) "
                        "(default: on)")
    add_output_arguments(p.add_argument_group("outputs"))
    add_common_arguments(p)


def add_output_arguments(o) -> None:
    """``--out``, ``--body-points``, ``--preview``, ``--sheet``, ``--camera``."""
    o.add_argument("--out", default=None,
                   help="USD stage to write: .usdc or .usd (binary crate) or .usda (text: larger and "
                        "slower to open, for reading and diffing) (default: out/GARMENT_MOTION.usdc); "
                        "the quality report goes beside it as <stem>.quality.json")
    add_body_points_option(o)
    o.add_argument("--preview", default=None, help="preview video to write (.mp4 or .gif)")
    o.add_argument("--sheet", default=None, help="contact sheet PNG to write (8 frames)")
    o.add_argument("--camera", default="three_quarter", choices=("front", "side", "three_quarter"),
                   help="preview camera, fitted once to the whole sequence (default: %(default)s)")


# ------------------------------------------------------------------------------- parsing


def resolve_template(name: str) -> str:
    """A template category from a name or alias (case, '-' and '_' ignored)."""
    from sim.garments.templates import GARMENT_ALIASES, TEMPLATES, template_name

    found = template_name(name)
    if found is not None:
        return found
    raise WrinklesInputError(f"--garment {name!r}: unknown garment; expected a template ("
                             f"{', '.join(TEMPLATES)}), an alias ({', '.join(GARMENT_ALIASES)}) or a "
                             "mesh file (.obj, .ply, .glb, .usd ...)")


def is_garment_file(spec: str) -> bool:
    from sim.garments.io import MESH_SUFFIXES, USD_SUFFIXES

    suffixes = MESH_SUFFIXES + USD_SUFFIXES + (PATTERN_SUFFIX,)
    return Path(spec).suffix.lower() in suffixes or os.sep in spec or "/" in spec


def is_pattern_file(spec: str) -> bool:
    """``--garment`` names a GarmentCode pattern file, sewn before it is simulated."""
    return Path(spec).suffix.lower() == PATTERN_SUFFIX


def parse_pins(spec: str | None) -> tuple[str, ...]:
    """``--pin``: the attachment sets named, () for 'none', the default for None."""
    from sim.simulate import DEFAULT_PINNED

    if spec is None:
        return DEFAULT_PINNED
    names = tuple(s.strip() for s in spec.split(",") if s.strip())
    return () if names in ((), ("none",)) else names


def check_pins(spec: str | None, garment) -> None:
    """Attachment sets named by ``--pin`` must be the garment's own (the default may name a set
    a garment lacks: a top has no waistband and hangs free)."""
    if spec is None:
        return
    missing = [n for n in parse_pins(spec) if n not in garment.attachments]
    if missing:
        have = ", ".join(sorted(garment.attachments)) or "none"
        raise WrinklesInputError(f"--pin {missing[0]}: {garment.name} has no such attachment set; "
                                 f"it has: {have} (or --pin none)")


def parse_sweeps(spec: str) -> tuple[int, ...] | None:
    """``--coarse-sweeps``: comma-separated sweep indices, 'none' or 'auto' (None)."""
    word = spec.strip().lower()
    if word == "auto":
        return None
    if word in ("none", ""):
        return ()
    try:
        return tuple(int(k) for k in spec.split(","))
    except ValueError:
        raise WrinklesInputError(f"--coarse-sweeps {spec!r}: expected comma-separated sweep indices "
                                 "(e.g. 2 or 1,3), 'none' or 'auto'") from None


def parse_solver_params(items: list[str]) -> dict[str, float]:
    """``--solver-param KEY=VALUE`` items: the solver settings they override."""
    from pipelines.options import parse_numbers

    return parse_numbers(items, "--solver-param")


def build_config(args: argparse.Namespace, device: str):
    """The ``SimulationConfig`` of the command line (validated)."""
    from pipelines.options import parse_numbers
    from sim.quality import QualityGates
    from sim.simulate import SimulationConfig

    gates = parse_numbers(args.gate, "--gate")
    if "max_self_intersections" in gates:
        gates["max_self_intersections"] = int(gates["max_self_intersections"])
    known = {f for f in QualityGates.__dataclass_fields__}
    if set(gates) - known:
        raise WrinklesInputError(f"--gate: unknown gate(s) {sorted(set(gates) - known)}; expected "
                                 f"{', '.join(sorted(known))}")
    return SimulationConfig(
        fps=float(args.fps), substeps=args.substeps, iterations=args.iterations,
        coarse_sweeps=parse_sweeps(args.coarse_sweeps),
        settle_seconds=args.settle, blend_seconds=args.blend, keep_prelude=args.keep_prelude,
        pinned=parse_pins(args.pin), ground=not args.no_ground, self_contact=args.self_collision,
        solver=parse_solver_params(args.solver_param), gates=QualityGates(**gates),
        **({} if args.retry else {"retry_factors": ()}), device=device)


def material_arg(args: argparse.Namespace):
    """The ``Material`` of ``--material`` with the ``--material-param`` overrides."""
    from pipelines.options import parse_numbers
    from sim.garments import get_material

    material = get_material(args.material)
    overrides = parse_numbers(args.material_param, "--material-param")
    text = sorted(set(overrides) & {"name", "source"})
    if text:
        from sim.garments.materials import MATERIAL_UNITS

        raise WrinklesInputError(f"--material-param {text[0]}: not a number field; the fields are "
                                 + ", ".join(f"{k} [{u}]" for k, u in MATERIAL_UNITS.items()))
    if overrides:
        material = material.with_(name=f"{material.name}*", **overrides)
    return material


def load_garment_arg(args: argparse.Namespace, body, betas: np.ndarray):
    """The garment ``--garment`` names, with ``--material`` (+ overrides) and its parameters."""
    from pipelines.options import parse_params, parse_resolution
    from sim.garments import make_garment

    material = material_arg(args)
    params = parse_params(args.garment_param, "--garment-param")
    if is_pattern_file(args.garment):
        from pipelines.garments_cmd import pattern_file_garment

        return pattern_file_garment(args.garment, body, betas, material=material, params=params,
                                    resolution=parse_resolution(args.resolution or "coarse"))
    if is_garment_file(args.garment):
        return garment_file_arg(args, material, params, body, betas)
    category = resolve_template(args.garment)
    return make_garment(category, body, betas, resolution=parse_resolution(args.resolution or "coarse"),
                        material=material, **params)


def garment_file_arg(args: argparse.Namespace, material, params: dict[str, float], body, betas: np.ndarray):
    """The garment file ``--garment`` names (hem parameters only), checked to sit around the
    rest body; what reading it repaired is said on stderr."""
    from pipelines.garment_files import load_garment_file
    from sim.garments.io import check_garment_on_body, describe_drops

    other = sorted(set(params) - {"hem_width", "hem_layers"})
    if other:
        raise WrinklesInputError(f"--garment-param {other[0]} applies to templates, not to a garment "
                                 f"file ({args.garment}); a file takes hem_width and hem_layers only")
    garment = load_garment_file(args.garment, material=material, **params)
    check_garment_on_body(garment, body.rest_mesh(betas), args.garment)
    dropped = describe_drops(garment.repairs)
    if dropped and not args.quiet:
        print(f"wrinkles simulate: {args.garment}: repaired: {dropped}", file=sys.stderr)
    return garment


# ------------------------------------------------------------------------------- the command


def check_garment_spec(args: argparse.Namespace) -> None:
    """``--garment`` names a template, or a file without ``--resolution`` (before loading anything)."""
    from pipelines.options import parse_resolution

    if is_pattern_file(args.garment):
        from sim.garments.garmentcode import read_garmentcode

        read_garmentcode(args.garment)  # a bad file is refused before anything is loaded
    elif not is_garment_file(args.garment):
        resolve_template(args.garment)
    elif args.resolution is not None:
        raise WrinklesInputError(f"--resolution applies to templates; a garment file ({args.garment}) "
                                 "is simulated with its own mesh")
    parse_resolution(args.resolution or "coarse")


@dataclasses.dataclass
class Runs:
    """The runs of one sequence at rising substeps (``--retry``).

    Attributes:
        counts: the substeps of each run to try, in order.
        attempts: every run made, in order: its substeps and why it was not enough.
        finished: ``(SimulationResult, SimulationConfig)`` of the runs that finished, last one last.
        why: why the last run made was not enough ("" when it passed).
    """

    counts: list[int]
    attempts: list[dict] = dataclasses.field(default_factory=list)
    finished: list = dataclasses.field(default_factory=list)
    why: str = ""

    def tried(self) -> str:
        """" (at 12, 20 substeps)" where more than one run failed, else ""."""
        if len(self.attempts) > 1:
            return f" (at {', '.join(str(a['substeps']) for a in self.attempts)} substeps)"
        return ""


def simulate_with_retries(args: argparse.Namespace, garment, bm, config) -> Runs:
    """Simulate at the garment's substeps, then (``--retry``) at each retry count until a run
    passes the quality gates."""
    from sim.quality import SimulationError
    from sim.simulate import simulate

    total = config.solver_steps(bm.motion)
    runs = Runs(counts=[config.substeps_for(garment.num_vertices)])
    if args.retry:
        runs.counts += config.retry_substeps(garment.num_vertices)
    for k, n in enumerate(runs.counts):
        if k:
            config = dataclasses.replace(config, substeps=n)
        label = f"simulating {garment.name}" + (f" at {n} substeps" if k else "")
        try:
            with progress_bar(total, label, quiet=args.quiet) as advance:
                result = simulate(garment, bm.body, bm.motion, betas=bm.betas, config=config, seed=args.seed,
                                  progress=advance)
        except SimulationError as e:
            runs.why = str(e)
            runs.attempts.append({"substeps": n, "error": runs.why})
        else:
            runs.finished.append((result, config))
            if result.passed:
                break
            runs.why = "quality gates failed: " + "; ".join(result.failed_gates)
            runs.attempts.append({"substeps": n, "failed_gates": list(result.failed_gates)})
        if k + 1 < len(runs.counts) and not args.quiet:
            print(f"wrinkles simulate: {runs.why} (at {n} substeps); retrying at {runs.counts[k + 1]} "
                  "substeps", file=sys.stderr)
    return runs


def body_self_crossings(args: argparse.Namespace, result, bm, garment,
                        device: str) -> tuple[dict | None, str | None]:
    """Where the skinned body passes through itself near the garment, and that in words, when
    the run failed its gates (cloth caught in a fold of the skin fails them for the body's sake);
    ``(None, None)`` when it passed."""
    if not result.failed_gates:
        return None, None
    from pipelines.body_cmd import describe_self_crossings
    from sim.quality import garment_body_crossings

    seq = result.sequence
    with progress_bar(seq.num_frames, "body self-crossings", quiet=args.quiet) as advance:
        crossings = garment_body_crossings(bm.body, bm.betas, garment, seq.body.vertices, device=device,
                                           progress=advance)
    note = describe_self_crossings(crossings) if crossings["frames_with_crossings"] else None
    return crossings, note


def stage_metadata(args: argparse.Namespace, result, config, garment, bm, attempts: list[dict],
                   crossings: dict | None) -> dict:
    """The quality report, the resolved config and the provenance, as stored in the stage and
    its ``.quality.json`` sidecar (JSON types only)."""
    from pipelines.options import parse_params
    from sim.versions import package_versions

    report = {
        "passed": result.passed,
        "failed_gates": list(result.failed_gates),
        "attempts": attempts,
        "gates": config.to_dict()["gates"],
        "quality": result.quality.to_json(),
        "config": config.to_dict(),
        # the automatic settings (0 in the config) as this garment ran them
        "resolved": {"substeps": config.substeps_for(garment.num_vertices),
                     "iterations": config.iterations_for(garment.num_vertices)},
        "seed": args.seed,
    }
    if crossings is not None:  # where the body passes through itself, when the gates failed
        from sim.quality import short_crossings

        report["body_self_crossings"] = short_crossings(crossings)
    metadata = {
        "command": command_line(),
        **report,
        "provenance": {**result.sequence.provenance, "versions": package_versions("usd-core")},
        "motion_params": bm.params,
        "garment_params": parse_params(args.garment_param, "--garment-param"),
        "material": dataclasses.asdict(garment.material),
    }
    if garment.repairs:  # what reading the garment file repaired
        metadata["garment_repairs"] = dict(garment.repairs)
    return json.loads(json.dumps(metadata))


def print_summary(result, garment, bm, device: str, seconds: float, body_note: str | None,
                  paths: StageOutputs) -> None:
    seq, quality = result.sequence, result.quality
    inside = 100.0 * float(quality.inside_fraction.max())
    print(f"{garment.name} ({garment.num_vertices} vertices, {garment.material.name}) on "
          f"{bm.motion.name}: {seq.num_frames} frames at {seq.fps:g} fps, {device}, {seconds:.1f} s")
    print(f"  edge strain max {quality.max_edge_strain:.3f} mean {quality.mean_edge_strain:.4f}, "
          f"inside the body max {inside:.2f}%, self-intersections max "
          f"{int(quality.self_intersections.max())}: "
          + ("gates passed" if result.passed else "GATES FAILED: " + "; ".join(result.failed_gates)))
    if body_note:
        print(f"  {body_note}")
    for p in paths.written():
        print(f"  wrote {p}")


def run(args: argparse.Namespace) -> int:
    from pipelines.options import check_fps, load_body_and_motion
    from sim.device import resolve_device

    t0 = time.perf_counter()
    check_fps(args.fps)
    garment_label = Path(args.garment).stem if is_garment_file(args.garment) else args.garment
    out = args.out or f"out/{garment_label}_{Path(args.motion).stem}{DEFAULT_USD_SUFFIX}"
    paths = check_stage_outputs(out, args.preview, args.sheet, sidecar=".quality.json")
    check_garment_spec(args)
    device = resolve_device(args.device)
    config = build_config(args, device)

    bm = load_body_and_motion(args)
    garment = load_garment_arg(args, bm.body, bm.betas)
    check_pins(args.pin, garment)

    runs = simulate_with_retries(args, garment, bm, config)
    if not runs.finished:
        print(f"wrinkles simulate: {runs.why}{runs.tried()}", file=sys.stderr)
        return 1
    # the run written: the one that passed, else the last that finished (with its failed gates)
    result, config = runs.finished[-1]
    attempts = [a for a in runs.attempts if a["substeps"] != config.substeps_for(garment.num_vertices)]
    crossings, body_note = body_self_crossings(args, result, bm, garment, device)
    if result.failed_gates and not args.allow_failed_gates:
        print(f"wrinkles simulate: quality gates failed: {'; '.join(result.failed_gates)}{runs.tried()} "
              "(nothing written; --allow-failed-gates writes it anyway; more --substeps than "
              f"{runs.counts[-1]} or --iterations than {config.iterations_for(garment.num_vertices)} lower "
              "strain and crossings, at their cost in time)" + (f"; {body_note}" if body_note else ""),
              file=sys.stderr)
        return 1

    metadata = stage_metadata(args, result, config, garment, bm, attempts, crossings)
    seq = result.sequence
    with OutputSet() as outputs:
        write_sequence_usd(outputs.temp(paths.usd), seq, metadata, quiet=args.quiet,
                           rig=stage_rig(bm.body, bm.betas, seq.body, points=args.body_points))
        outputs.temp(paths.sidecar).write_text(json.dumps(metadata, indent=2, sort_keys=True) + "\n")
        write_previews(outputs, paths, lambda: preview_meshes(seq), num_frames=seq.num_frames, fps=seq.fps,
                       camera=args.camera, quiet=args.quiet)
    if not args.quiet:
        print_summary(result, garment, bm, device, time.perf_counter() - t0, body_note, paths)
    return 0


def write_sequence_usd(path: Path, seq, metadata: dict, *, quiet: bool, rig=None) -> None:
    """Body (a UsdSkel rig when ``rig`` is given, else a point cache) and garment (UVs,
    per-frame normals) in one stage."""
    from pipelines.preview import vertex_normals
    from usd_io import GarmentTrack, write_stage

    g = seq.garment
    normals = np.stack([vertex_normals(v, g.faces) for v in seq.vertices])
    track = GarmentTrack(name=g.name, vertices=seq.vertices, faces=g.faces, uvs=g.uvs, uv_faces=g.uv_faces,
                         normals=normals, face_layers=g.face_layers)
    with progress_bar(seq.num_frames, "writing USD", quiet=quiet) as advance:
        write_stage(path, body=seq.body, fps=seq.fps, garments=[track], body_name="Body", metadata=metadata,
                    progress=advance, rig=rig)


def preview_meshes(seq) -> list:
    """Body in clay, the garment in blue over it (lifted ``PREVIEW_CLOTH_LIFT`` along its normals)."""
    from pipelines.preview import PreviewMesh, frames_to_preview_meshes, vertex_normals

    g = seq.garment
    lifted = np.stack([v + PREVIEW_CLOTH_LIFT * vertex_normals(v, g.faces) for v in seq.vertices])
    return [*frames_to_preview_meshes(seq.body),
            PreviewMesh(name=g.name, vertices=lifted, faces=g.faces, color=CLOTH_PREVIEW_COLOR)]
