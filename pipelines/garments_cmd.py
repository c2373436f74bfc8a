"""``wrinkles garments``: list the garment templates; export one, fitted to a body, with UVs."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError

HELP = "list the garment templates (parameters, attachments, sizes); export one as a mesh with UVs"
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

examples:
  wrinkles garments
  wrinkles garments --params
  wrinkles garments --json > garments.json
  wrinkles garments --export t_shirt --out tee.obj --uv-image tee_uv.png --body-out body.obj
  wrinkles garments --export trousers --shape height=0.6,weight=0.3 --resolution fine \\
      --garment-param length=0.95 --out trousers.usda
"""

EXPORT_SUFFIXES = (".obj", ".ply", ".glb", ".usda", ".usdc", ".usd")
BODY_SUFFIXES = (".obj", ".ply", ".glb")
PANEL_COLORS = ((0.85, 0.37, 0.33), (0.33, 0.56, 0.85), (0.38, 0.72, 0.44), (0.93, 0.73, 0.27),
                (0.65, 0.45, 0.80), (0.27, 0.75, 0.75), (0.92, 0.52, 0.72), (0.60, 0.60, 0.60))
"""Panel colours of UV pictures (cycled), linear-ish RGB in [0, 1]."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.options import add_body_arguments

    p.add_argument("--params", action="store_true",
                   help="also list each template's parameters (default, unit, meaning)")
    p.add_argument("--json", action="store_true",
                   help="print everything (templates, parameters, resolutions, materials) as JSON")
    e = p.add_argument_group("export")
    e.add_argument("--export", metavar="NAME", default=None,
                   help="template to write (needs --out); a USD file carries the hems' layers as the "
                   "per-face primvar fabricLayers, an OBJ/PLY/GLB file does not; an import makes hems "
                   "only with 'simulate --garment-param hem_width=0.02'")
    e.add_argument("--out", default=None, help=f"mesh file to write: {', '.join(EXPORT_SUFFIXES)}")
    e.add_argument("--uv-image", default=None, metavar="PNG", help="also draw the UV layout to this PNG")
    e.add_argument("--body-out", default=None, metavar="FILE",
                   help="also write the body the garment is fitted to, in its rest pose and in the same "
                        "frame (.obj, .ply or .glb): the frame a garment file for 'wrinkles simulate "
                        "--garment FILE' is modelled in (Y up, metres, the pelvis near the origin)")
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


def template_name(name: str) -> str:
    """The template ``--export`` names (an alias too; case, '-', '_' and ' ' ignored)."""
    from sim.garments.templates import TEMPLATES
    from sim.garments.templates import template_name as find

    found = find(name)
    if found is None:
        raise WrinklesInputError(f"--export {name!r}: unknown template; expected one of "
                                 f"{', '.join(TEMPLATES)}")
    return found


def export(args: argparse.Namespace) -> int:
    from pipelines.options import parse_body_shape, parse_params, parse_resolution
    from pipelines.outputs import OutputSet, check_output_path
    from sim.bodies import load_body
    from sim.garments import make_garment
    from sim.versions import package_versions

    t0 = time.perf_counter()
    if not args.out:
        raise WrinklesInputError("--export needs --out (a .obj, .ply, .glb or .usd* file)")
    out = check_output_path(args.out, EXPORT_SUFFIXES, "--out")
    out_png = check_output_path(args.uv_image, (".png",), "--uv-image") if args.uv_image else None
    out_body = check_output_path(args.body_out, BODY_SUFFIXES, "--body-out") if args.body_out else None
    if not 64 <= args.uv_image_size <= 8192:
        raise WrinklesInputError(f"--uv-image-size must lie in [64, 8192], got {args.uv_image_size}")
    category = template_name(args.export)
    params = parse_params(args.garment_param, "--garment-param")
    body = load_body(args.body)
    betas = parse_body_shape(body, args.shape)
    g = make_garment(category, body, betas, resolution=parse_resolution(args.resolution),
                     material=args.material, **params)
    metadata = {"command": "wrinkles " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
                "config": {"template": category, "params": params, "resolution": args.resolution,
                           "body": body.name, "shape": args.shape, "material": args.material},
                "versions": package_versions()}
    with OutputSet() as outputs:
        write_garment(g, outputs.temp(out), metadata=metadata)
        if out_png:
            draw_uv_layout(g, args.uv_image_size).save(outputs.temp(out_png))
        if out_body:
            import trimesh

            trimesh.Trimesh(body.rest_mesh(betas), body.faces, process=False).export(outputs.temp(out_body))
    print(f"{category}: {g.num_vertices} vertices, {g.num_faces} triangles, {len(g.uvs)} UVs, "
          f"panels {', '.join(g.panel_names)}; attachments "
          + ", ".join(f"{k} ({len(a)})" for k, a in g.attachments.items())
          + f"; {time.perf_counter() - t0:.1f} s")
    for p in (out, out_png, out_body):
        if p:
            print(f"  wrote {p}")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.export:
        return export(args)
    if args.out or args.uv_image or args.body_out:
        raise WrinklesInputError("--out, --uv-image and --body-out need --export NAME")
    cat = catalogue()
    if args.json:
        print(json.dumps(cat, indent=1))
    else:
        print_listing(cat, params=args.params)
    return 0
