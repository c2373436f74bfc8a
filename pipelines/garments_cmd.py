"""``wrinkles garments``: list the garment templates; export one, fitted to a body, with UVs; write
its sewing pattern; sew a GarmentCode pattern file."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError

HELP = ("list the garment templates (parameters, attachments, sizes); export one as a mesh with UVs or "
        "its sewing pattern; sew a GarmentCode pattern file")
DESCRIPTION = """\
List the garment templates: each is a sewing pattern fitted to a body in its rest pose, with
UVs laid out as the flattened panels. 'wrinkles simulate --garment NAME' uses them; their
parameters are set with '--garment-param KEY=VALUE' here and there.
Resolutions: 'coarse' (about 3,000 vertices on the default body) and 'fine' (about 20,000),
or an edge length in metres; each template has its own edge lengths, fixed across body shapes.

With --export, write one template, fitted to --body/--shape, as a mesh with its UVs (seams
kept) for texturing or editing: .obj (positions + 'vt' per corner), .ply / .glb (vertices split
along UV seams), or .usda / .usdc / .usd (the garment under /World/Garments, face-varying st).
--uv-image draws the UV layout (panels in colour, triangle edges) as a PNG. --body-out writes
the body it is fitted to, in its rest pose and the same frame: model or edit a garment around
it and simulate the file with 'wrinkles simulate --garment FILE --shape <the same>'.
--garment NAME is the same as --export NAME.

--pattern-out writes the sewing pattern (a template's drafted for --body/--shape, or the
--pattern file's placed around that body): .json as a GarmentCode pattern specification, .svg
at full size in millimetres (print it, or convert it to PDF with any SVG tool; --seam-allowance
adds the cutting line) or .png as a picture. Without --out nothing is sewn. --pattern FILE.json
sews a GarmentCode / GarmentCodeData pattern specification (or one --pattern-out wrote) on
--body/--shape in place of a template, its panels where the file puts them: GarmentCodeData's
around a body standing on the floor (y = 0), ours around the body's rest frame
(--pattern-frame; auto picks the one that puts the panels at the body's height).
'wrinkles simulate --garment FILE.json' sews and simulates such a file.

examples:
  wrinkles garments
  wrinkles garments --params
  wrinkles garments --json > garments.json
  wrinkles garments --export t_shirt --out tee.obj --uv-image tee_uv.png --body-out body.obj
  wrinkles garments --export trousers --shape height=0.6,weight=0.3 --resolution fine \\
      --garment-param length=0.95 --out trousers.usda
  wrinkles garments --garment t_shirt --pattern-out tee.svg --seam-allowance 0.01
  wrinkles garments --pattern dress_specification.json --out dress.usda --pattern-out dress.svg
"""

EXPORT_SUFFIXES = (".obj", ".ply", ".glb", ".usda", ".usdc", ".usd")
BODY_SUFFIXES = (".obj", ".ply", ".glb")
PATTERN_SUFFIXES = (".json", ".svg", ".png")
PANEL_COLORS = ((0.85, 0.37, 0.33), (0.33, 0.56, 0.85), (0.38, 0.72, 0.44), (0.93, 0.73, 0.27),
                (0.65, 0.45, 0.80), (0.27, 0.75, 0.75), (0.92, 0.52, 0.72), (0.60, 0.60, 0.60))
"""Panel colours of UV pictures (cycled), linear-ish RGB in [0, 1]."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.options import add_body_arguments
    from sim.garments.garmentcode import FRAMES

    p.add_argument("--params", action="store_true",
                   help="also list each template's parameters (default, unit, meaning)")
    p.add_argument("--json", action="store_true",
                   help="print everything (templates, parameters, resolutions, materials) as JSON")
    e = p.add_argument_group("export")
    e.add_argument("--export", "--garment", dest="export", metavar="NAME", default=None,
                   help="template to write (with --out or --pattern-out); a USD file carries the hems' "
                   "layers as the per-face primvar fabricLayers, an OBJ/PLY/GLB file does not; an import "
                   "makes hems only with 'simulate --garment-param hem_width=0.02'; --garment is the same "
                   "option")
    e.add_argument("--pattern", default=None, metavar="FILE.json",
                   help="sew a GarmentCode / GarmentCodeData pattern specification in place of --export "
                        "NAME (--garment-param takes hem_width and hem_layers only)")
    e.add_argument("--pattern-frame", default="auto", choices=FRAMES,
                   help="where --pattern FILE.json places its panels: around a body standing on the floor "
                        "(GarmentCodeData), around the rest body's own frame (our files), or auto: the one "
                        "that puts the panels at the body's height (default: %(default)s)")
    e.add_argument("--out", default=None, help=f"mesh file to write: {', '.join(EXPORT_SUFFIXES)}")
    e.add_argument("--uv-image", default=None, metavar="PNG", help="also draw the UV layout to this PNG")
    e.add_argument("--body-out", default=None, metavar="FILE",
                   help="also write the body the garment is fitted to, in its rest pose and in the same "
                        "frame (.obj, .ply or .glb): the frame a garment file for 'wrinkles simulate "
                        "--garment FILE' is modelled in (Y up, metres, the pelvis near the origin)")
    e.add_argument("--pattern-out", default=None, metavar="FILE",
                   help="also write the sewing pattern: .json (GarmentCode pattern specification), .svg "
                        "(full size in mm: print it or convert it to PDF) or .png (a picture); without "
                        "--out nothing is sewn")
    e.add_argument("--seam-allowance", type=float, default=0.0, metavar="M",
                   help="with --pattern-out FILE.svg: draw each panel's cutting line this far outside its "
                        "sewing line [m] (default: %(default)s)")
    e.add_argument("--uv-image-size", type=int, default=1024,
                   help="UV picture size [px] (default: %(default)s)")
    e.add_argument("--resolution", default="coarse",
                   help="coarse, fine or an edge length in metres (default: %(default)s)")
    e.add_argument("--garment-param", "--param", dest="garment_param", action="append", default=[],
                   metavar="KEY=VALUE",
                   help="a template parameter, e.g. --garment-param length=0.5 (repeatable; see --params); "
                        "--param is the same option")
    e.add_argument("--material", default="cotton", help="material preset (default: %(default)s)")
    add_body_arguments(e)


# ------------------------------------------------------------------------------- listing


def catalogue() -> dict:
    """Every template with its parameters, resolutions and attachments, and the materials."""
    from dataclasses import asdict

    from sim.garments import MATERIALS, TEMPLATES
    from sim.garments.materials import MATERIAL_UNITS
    from sim.garments.templates import template_parameters

    templates = []
    for name, t in TEMPLATES.items():
        templates.append({
            "name": name, "description": t.description, "attachments": list(t.attachments),
            "resolutions": {r: {"edge_m": getattr(t, r), "vertices_default_body": t.vertices[k]}
                            for k, r in enumerate(("coarse", "fine"))},
            "parameters": [{"name": n, "default": d, "unit": u, "meaning": m}
                           for n, d, u, m in template_parameters(name)],
        })
    return {"templates": templates, "materials": [asdict(m) for m in MATERIALS.values()],
            "material_units": dict(MATERIAL_UNITS)}


def print_listing(cat: dict, *, params: bool) -> None:
    rows = cat["templates"]
    w = max(len(t["name"]) for t in rows)
    print(f"{'template':<{w}}  {'coarse':>16}  {'fine':>16}  attachments")
    for t in rows:
        c, f = t["resolutions"]["coarse"], t["resolutions"]["fine"]
        sizes = [f"{r['vertices_default_body']:>6,} v {r['edge_m'] * 1000:4.1f} mm" for r in (c, f)]
        print(f"{t['name']:<{w}}  {sizes[0]}  {sizes[1]}  {', '.join(t['attachments'])}")
        print(" " * (w + 2) + t["description"])
        if params:
            for p in t["parameters"]:
                unit = f" [{p['unit']}]" if p["unit"] not in ("", "-", "choice") else ""
                value = p["default"] if isinstance(p["default"], str) else f"{p['default']:g}"
                line = f"--garment-param {p['name']}={value}{unit}  {p['meaning']}"
                text = textwrap.fill(line, 100 - w - 4, subsequent_indent="    ")
                print(textwrap.indent(text, " " * (w + 4)))
    print("\nvertices: on the default body (mean shape) with the default parameters; the edge length "
          "is kept on other bodies.")
    print("materials (--material): " + ", ".join(m["name"] for m in cat["materials"]))
    if params:  # the presets' values, with units (simulate's --material-param overrides them)
        units = cat["material_units"]
        names = [m["name"] for m in cat["materials"]]
        print(f"\n{'material field':<26}" + "".join(f"{n:>12}" for n in names))
        for field, unit in units.items():
            label = f"{field} [{unit}]"
            print(f"{label:<26}" + "".join(f"{m[field]:>12.4g}" for m in cat["materials"]))


# ------------------------------------------------------------------------------- export


def write_garment(garment, path: Path, *, metadata: dict | None = None) -> None:
    """Write a garment's rest mesh with its UVs (seams kept) to ``path``; the suffix picks the
    format (see ``EXPORT_SUFFIXES``)."""
    suffix = path.suffix.lower()
    v, f = garment.rest_vertices, garment.faces
    if suffix == ".obj":
        head = [f"# wrinkles garment {garment.name} ({garment.category}), metres, Y up"]
        if metadata:
            head.append("# " + json.dumps(metadata, sort_keys=True))
        corners = np.stack([f + 1, garment.uv_faces + 1], axis=2).reshape(len(f), 6)
        with open(path, "w") as fh:
            fh.write("\n".join(head + [f"o {garment.name}"]) + "\n")
            np.savetxt(fh, v, fmt="v %.7f %.7f %.7f")
            np.savetxt(fh, garment.uvs, fmt="vt %.7f %.7f")
            np.savetxt(fh, corners, fmt="f %d/%d %d/%d %d/%d")
        return
    if suffix in (".ply", ".glb"):
        import trimesh

        # these formats carry one UV per vertex: split vertices along the seams
        corners = np.stack([f.ravel(), garment.uv_faces.ravel()], 1)
        pairs, inv = np.unique(corners, axis=0, return_inverse=True)
        visual = trimesh.visual.TextureVisuals(uv=garment.uvs[pairs[:, 1]])
        mesh = trimesh.Trimesh(v[pairs[:, 0]], inv.reshape(-1, 3), visual=visual, process=False)
        mesh.export(path)
        return
    from usd_io import write_stage
    from usd_io.write import GarmentTrack

    write_stage(path, body=None, fps=30.0, metadata=metadata,
                garments=[GarmentTrack(garment.name, v[None], f, garment.uvs, garment.uv_faces,
                                       face_layers=garment.face_layers)])


def draw_uv_layout(garment, size: int = 1024, *, edges: bool = True):
    """The UV layout as a PIL image: one colour per panel, triangle edges, panel names.

    Returns:
        ``PIL.Image`` (RGB, ``size`` x ``size``), v up.
    """
    from PIL import Image, ImageDraw, ImageFont

    img = Image.new("RGB", (size, size), "white")
    font = ImageFont.load_default(size=max(10, size // 48))
    draw = ImageDraw.Draw(img)
    px = np.stack([garment.uvs[:, 0] * size, (1.0 - garment.uvs[:, 1]) * size], axis=1)
    fills = [tuple(int(255 * c) for c in col) for col in PANEL_COLORS]
    line = (40, 40, 40) if edges else None
    for tri, pid in zip(garment.uv_faces, garment.panel_ids, strict=True):
        draw.polygon([tuple(px[i]) for i in tri], fill=fills[pid % len(fills)], outline=line)
    for pid, name in enumerate(garment.panel_names):
        idx = np.unique(garment.uv_faces[garment.panel_ids == pid])
        if idx.size:
            x, y = px[idx].mean(0)
            draw.text((x, y), name, fill="black", anchor="mm", font=font)
    draw.rectangle([0, 0, size - 1, size - 1], outline=(160, 160, 160))
    return img


def write_pattern(pattern, path: Path, *, seam_allowance: float = 0.0) -> None:
    """Write a sewing pattern to ``path``: .json (GarmentCode), .svg (full size, mm) or .png."""
    from sim.garments.garmentcode import write_garmentcode
    from sim.garments.pattern_drawing import draw_pattern_png, pattern_svg

    suffix = path.suffix.lower()
    if suffix == ".json":
        write_garmentcode(pattern, path)
    elif suffix == ".svg":
        pattern_svg(pattern, path, seam_allowance=seam_allowance)
    else:
        draw_pattern_png(pattern, path)


def read_pattern_file(path: str, rest_vertices: np.ndarray, frame: str = "auto"):
    """The ``Pattern`` of a GarmentCode JSON file, its panels moved around the rest body
    ``rest_vertices`` (V, 3) [m] from the file's ``frame`` (``garmentcode.place_on_body``)."""
    from sim.garments.garmentcode import place_on_body, read_garmentcode

    return place_on_body(read_garmentcode(path), rest_vertices, frame)


def check_pattern_params(params: dict, path: str) -> dict[str, float]:
    """``--garment-param`` of a pattern file: the hems' only (hem_width, hem_layers), checked."""
    from sim.garments.parameters import HEM_SPECS, check_parameter

    other = sorted(set(params) - set(HEM_SPECS))
    if other:
        raise WrinklesInputError(f"--garment-param {other[0]} applies to templates, not to a pattern file "
                                 f"({path}); a pattern file takes hem_width and hem_layers only")
    for k, v in params.items():
        check_parameter(k, v, HEM_SPECS[k], "--garment-param")
    return {k: float(v) for k, v in params.items()}


def sew_pattern_file(pattern, path: str, body, betas: np.ndarray | None, *, resolution: str | float,
                     material, hems: dict[str, float]):
    """The garment of ``pattern`` (read from ``path``, placed around the rest body) sewn on
    ``body`` (``designs.make_pattern_garment``); a pattern that does not mesh or sew is an
    error naming the file."""
    from sim.garments.designs import make_pattern_garment, pattern_edge_length

    pattern_edge_length(pattern, resolution)  # a bad --resolution is not the file's problem
    try:
        return make_pattern_garment(pattern, body, betas, resolution=resolution, material=material,
                                    category="garmentcode", **hems)
    except WrinklesInputError as e:
        if e.path is not None:
            raise
        raise WrinklesInputError(str(e), path=path) from None


def pattern_file_garment(path: str, body, betas: np.ndarray | None, *, resolution: str | float = "coarse",
                         material="cotton", frame: str = "auto", params: dict | None = None):
    """The garment of a GarmentCode pattern file sewn on ``body`` (shape ``betas``) at
    ``resolution``; ``params`` may set the hems (hem_width, hem_layers) and nothing else."""
    hems = check_pattern_params(params or {}, path)
    pattern = read_pattern_file(path, body.rest_mesh(betas), frame)
    return sew_pattern_file(pattern, path, body, betas, resolution=resolution, material=material, hems=hems)


def template_name(name: str) -> str:
    """The template ``--export`` names (an alias too; case, '-', '_' and ' ' ignored)."""
    from sim.garments.templates import TEMPLATES
    from sim.garments.templates import template_name as find

    found = find(name)
    if found is None:
        raise WrinklesInputError(f"--export {name!r}: unknown template; expected one of "
                                 f"{', '.join(TEMPLATES)}")
    return found


def output_paths(args: argparse.Namespace) -> dict[str, Path | None]:
    """The export's output files by option (checked; None where not asked for)."""
    from pipelines.outputs import check_output_path

    if not (args.out or args.pattern_out):
        what = "--export" if args.export else "--pattern"
        raise WrinklesInputError(f"{what} needs --out (a .obj, .ply, .glb or .usd* file) or --pattern-out "
                                 "(a .json, .svg or .png pattern)")
    if not 64 <= args.uv_image_size <= 8192:
        raise WrinklesInputError(f"--uv-image-size must lie in [64, 8192], got {args.uv_image_size}")
    if not 0.0 <= args.seam_allowance <= 0.1:
        raise WrinklesInputError(f"--seam-allowance must lie in [0, 0.1] m, got {args.seam_allowance}")
    if args.seam_allowance and Path(args.pattern_out or "").suffix.lower() != ".svg":
        raise WrinklesInputError("--seam-allowance draws a cutting line in --pattern-out FILE.svg: give one")
    if args.uv_image and not args.out:
        raise WrinklesInputError("--uv-image draws the sewn garment's UVs: it needs --out")
    checks = {"out": ("--out", EXPORT_SUFFIXES), "uv_image": ("--uv-image", (".png",)),
              "body_out": ("--body-out", BODY_SUFFIXES), "pattern_out": ("--pattern-out", PATTERN_SUFFIXES)}
    return {key: check_output_path(getattr(args, key), suffixes, flag) if getattr(args, key) else None
            for key, (flag, suffixes) in checks.items()}


@dataclass(frozen=True)
class Exported:
    """What ``--export NAME`` or ``--pattern FILE.json`` names.

    Attributes:
        category: the template, or "garmentcode" for a pattern file.
        garment: the sewn garment; None when nothing asked for it (``--pattern-out`` alone).
        pattern: the sewing pattern, around the rest body; None for a template without
            ``--pattern-out``.
    """

    category: str
    garment: object | None
    pattern: object | None


def export_source(args: argparse.Namespace, body, betas, params: dict, *, sew: bool) -> Exported:
    """The garment (when ``sew``) and pattern the export's options name."""
    from pipelines.options import parse_resolution
    from sim.garments import make_garment
    from sim.garments.designs import make_pattern
    from sim.garments.parameters import HEM_SPECS
    from sim.garments.templates import make_params

    resolution = parse_resolution(args.resolution)
    if args.pattern:
        hems = check_pattern_params(params, args.pattern)
        pattern = read_pattern_file(args.pattern, body.rest_mesh(betas), args.pattern_frame)
        g = sew_pattern_file(pattern, args.pattern, body, betas, resolution=resolution,
                             material=args.material, hems=hems) if sew else None
        return Exported("garmentcode", g, pattern)
    category = template_name(args.export)
    make_params(category, **params)
    g = make_garment(category, body, betas, resolution=resolution, material=args.material,
                     **params) if sew else None
    own = {k: v for k, v in params.items() if k not in HEM_SPECS}
    return Exported(category, g, make_pattern(category, body, betas, **own) if args.pattern_out else None)


def export(args: argparse.Namespace) -> int:
    from pipelines.options import parse_body_shape, parse_params
    from pipelines.outputs import OutputSet
    from sim.bodies import load_body
    from sim.versions import package_versions

    t0 = time.perf_counter()
    paths = output_paths(args)
    params = parse_params(args.garment_param, "--garment-param")
    body = load_body(args.body)
    betas = parse_body_shape(body, args.shape)
    src = export_source(args, body, betas, params, sew=paths["out"] is not None)
    category, g, pattern = src.category, src.garment, src.pattern
    metadata = {"command": "wrinkles " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
                "config": {"template": category, "params": params, "resolution": args.resolution,
                           "body": body.name, "shape": args.shape, "material": args.material},
                "versions": package_versions()}
    if args.pattern:
        metadata["config"].update(pattern=args.pattern, pattern_frame=args.pattern_frame)
    with OutputSet() as outputs:
        if g is not None:
            write_garment(g, outputs.temp(paths["out"]), metadata=metadata)
        if paths["uv_image"]:
            draw_uv_layout(g, args.uv_image_size).save(outputs.temp(paths["uv_image"]))
        if paths["body_out"]:
            import trimesh

            trimesh.Trimesh(body.rest_mesh(betas), body.faces, process=False).export(
                outputs.temp(paths["body_out"]))
        if paths["pattern_out"]:
            write_pattern(pattern, outputs.temp(paths["pattern_out"]), seam_allowance=args.seam_allowance)
    print(summary(category, g, pattern) + f"; {time.perf_counter() - t0:.1f} s")
    for p in paths.values():
        if p:
            print(f"  wrote {p}")
    return 0


def summary(category: str, garment, pattern) -> str:
    """One line on what was exported: the sewn garment's mesh, else the pattern's pieces."""
    if garment is not None:
        name = category if garment.name == category else f"{garment.name} ({category})"
        return (f"{name}: {garment.num_vertices} vertices, {garment.num_faces} triangles, "
                f"{len(garment.uvs)} UVs, panels {', '.join(garment.panel_names)}; attachments "
                + ", ".join(f"{k} ({len(a)})" for k, a in garment.attachments.items()))
    darts = len(pattern.darts)
    names = ", ".join(p.name for p in pattern.panels)
    return (f"{pattern.name}: pattern of {len(pattern.panels)} panels ({names}), "
            f"{len(pattern.seams) - darts} seams, {darts} darts")


def run(args: argparse.Namespace) -> int:
    if args.export and args.pattern:
        raise WrinklesInputError("--export NAME and --pattern FILE.json each name the garment: give one")
    if args.pattern_frame != "auto" and not args.pattern:
        raise WrinklesInputError("--pattern-frame places the panels of --pattern FILE.json: give one")
    if args.export or args.pattern:
        return export(args)
    if args.out or args.uv_image or args.body_out or args.pattern_out:
        raise WrinklesInputError("--out, --uv-image, --body-out and --pattern-out need --export NAME "
                                 "(or --pattern FILE.json)")
    cat = catalogue()
    if args.json:
        print(json.dumps(cat, indent=1))
    else:
        print_listing(cat, params=args.params)
    return 0
