"""Pictures and figures of the garment templates for docs/GARMENTS.md.

    python tools/render_garments.py                 # docs/images/garments.png, garment_uvs.png
    python tools/render_garments.py --measure       # + the per-template table (counts, times, UVs)

``garments.png``: every template on the default body at rest (coarse), each panel in its own
colour and its hems (``sim.garments.hems``) darker, front and three-quarter views.
``garment_uvs.png``: each template's UV layout (the sewing pattern: panels packed in [0, 1]²,
triangle edges drawn). ``--measure`` prints markdown tables: vertex counts at coarse / fine on
three bodies with generation times, mesh quality, and UV distortion.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

SHAPES = {"mean": "", "tall-heavy": "height=0.7,weight=0.9", "short-slim": "height=0.1,weight=0.1"}
"""Bodies of the measurements (the default body's phenotypes; the same as tests/test_garments.py)."""


def panel_meshes(g, hem_shade: float = 0.55):
    """One ``PreviewMesh`` per panel, in the panel colours of the UV pictures, and one per panel's
    hem (the faces at least half in it: ``Garment.face_layers`` half-way to its most) in a darker
    shade of it (``hem_shade`` times the colour)."""
    from pipelines.garments_cmd import PANEL_COLORS
    from pipelines.preview import PreviewMesh

    out = []
    hem = g.face_layers - 1.0 >= 0.5 * max(float(g.face_layers.max()) - 1.0, 1e-6)
    for pid, name in enumerate(g.panel_names):
        color = PANEL_COLORS[pid % len(PANEL_COLORS)]
        for part, keep in (("", ~hem), ("_hem", hem)):
            f = g.faces[(g.panel_ids == pid) & keep]
            if not len(f):
                continue
            used, local = np.unique(f, return_inverse=True)
            shade = hem_shade if part else 1.0
            out.append(PreviewMesh(name + part, g.rest_vertices[used], local.reshape(-1, 3).astype(np.int32),
                                   color=tuple(shade * c for c in color), smooth=True))
    return out


def _font(px: int):
    from PIL import ImageFont

    return ImageFont.load_default(size=px)


def _pixel_box(meshes, camera: str, size: tuple[int, int], margin: float = 0.03) -> tuple[int, int, int, int]:
    """Pixel box (left, top, right, bottom) of every vertex as ``render_frames`` frames them."""
    from pipelines.preview import fit_camera, sequence_bounds

    w, h = size
    pose = fit_camera(*sequence_bounds(meshes), camera, w / h)
    pos, up = np.array(pose.position), np.array(pose.view_up)
    back = pos - np.array(pose.focal_point)
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    pts = np.concatenate([m.vertices.reshape(-1, 3) for m in meshes]) - pos
    depth = -(pts @ back)
    t = np.tan(np.radians(pose.view_angle) / 2)
    px = ((pts @ right) / (depth * t * w / h) + 1) / 2 * w
    py = (1 - (pts @ up) / (depth * t)) / 2 * h
    mx, my = margin * (px.max() - px.min()), margin * (py.max() - py.min())
    return (max(0, int(px.min() - mx)), max(0, int(py.min() - my)),
            min(w, int(np.ceil(px.max() + mx))), min(h, int(np.ceil(py.max() + my))))


def render_templates(path: Path, body, *, size=(1000, 1000), cell_height: int = 480) -> None:
    """``garments.png``: 4 x 2 cells, each the front and three-quarter views of one template,
    cropped to the body (same scale in every cell)."""
    from PIL import Image, ImageDraw

    from pipelines.preview import PreviewMesh, render_frames
    from sim.garments import TEMPLATES, make_garment

    body_mesh = PreviewMesh("body", body.rest_mesh(None), body.faces)
    cameras = ("front", "three_quarter")
    boxes = {cam: _pixel_box([body_mesh], cam, size) for cam in cameras}
    cells = []
    for name in TEMPLATES:
        g = make_garment(name, body)
        meshes = [body_mesh, *panel_meshes(g)]
        views = []
        for cam in cameras:
            im = Image.fromarray(next(render_frames(meshes, size=size, camera=cam))).crop(boxes[cam])
            views.append(im.resize((round(im.width * cell_height / im.height), cell_height), Image.LANCZOS))
        cell = Image.new("RGB", (sum(v.width for v in views), cell_height + 36), "white")
        x = 0
        for v in views:
            cell.paste(v, (x, 0))
            x += v.width
        label = f"{name} ({g.num_vertices:,} vertices)"
        ImageDraw.Draw(cell).text((cell.width // 2, cell_height + 18), label, fill="black", anchor="mm",
                                  font=_font(22))
        cells.append(cell)
    w, h = cells[0].size
    sheet = Image.new("RGB", (4 * w, 2 * h), "white")
    for k, c in enumerate(cells):
        sheet.paste(c, ((k % 4) * w, (k // 4) * h))
    sheet = sheet.resize((2400, round(sheet.height * 2400 / sheet.width)), Image.LANCZOS)
    sheet.save(path, optimize=True)


def render_uv_layouts(path: Path, body, *, size: int = 560) -> None:
    """``garment_uvs.png``: each template's UV layout (coarse), 4 x 2."""
    from PIL import Image, ImageDraw

    from pipelines.garments_cmd import draw_uv_layout
    from sim.garments import TEMPLATES, make_garment

    sheet = Image.new("RGB", (4 * (size + 20), 2 * (size + 50)), "white")
    for k, name in enumerate(TEMPLATES):
        g = make_garment(name, body)
        x, y = (k % 4) * (size + 20) + 10, (k // 4) * (size + 50)
        sheet.paste(draw_uv_layout(g, size), (x, y + 40))
        ImageDraw.Draw(sheet).text((x + size // 2, y + 20), name, fill="black", anchor="mm", font=_font(24))
    sheet.save(path, optimize=True)


def measure(body) -> None:
    """Print markdown tables: counts and times at coarse / fine on three bodies; mesh and UV quality."""
    from sim.bodies.default import parse_shape
    from sim.garments import TEMPLATES, make_garment
    from sim.garments.panels import corner_angles
    from sim.garments.uv import uv_stats

    betas = {s: parse_shape(spec) for s, spec in SHAPES.items()}
    make_garment("t_shirt", body, resolution=0.05)  # warm-up (imports, first-call costs)
    print("| template | coarse edge | coarse vertices (mean / tall-heavy / short-slim) | fine edge | "
          "fine vertices (mean / tall-heavy / short-slim) | fine time (mean body) |")
    print("|---|---|---|---|---|---|")
    quality = []
    for name, t in TEMPLATES.items():
        row = [name]
        for res in ("coarse", "fine"):
            counts, times = [], []
            for s in SHAPES:
                t0 = time.perf_counter()
                g = make_garment(name, body, betas[s], resolution=res)
                times.append(time.perf_counter() - t0)
                counts.append(f"{g.num_vertices:,}")
                if s == "mean":
                    quality.append((name, res, g))
            row += [f"{getattr(t, res) * 1000:g} mm", " / ".join(counts)]
        row.append(f"{times[0]:.2f} s")
        print("| " + " | ".join(row) + " |", flush=True)
    print()
    print("| template | resolution | edge p95/p5 | longest / median edge | min angle | "
          "UV angle mean / p95 / max | UV area p5 / p95 | texel at 512² | mean edge at 256² | UV fill |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, res, g in quality:
        v, f = g.rest_vertices.astype(np.float64), g.faces
        e = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
        el = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
        ang = corner_angles(v, f)
        s = uv_stats(g.rest_vertices, g.faces, g.uvs, g.uv_faces)
        print(f"| {name} | {res} | {np.percentile(el, 95) / np.percentile(el, 5):.2f} | "
              f"{el.max() / np.median(el):.2f} | {np.min(ang):.0f}° | "
              f"{s.angle_mean:.3f} / {s.angle_p95:.3f} / {s.angle_max:.2f} | "
              f"{s.area_p5:.3f} / {s.area_p95:.3f} | {1000 / (2 * s.texels_per_metre_256):.1f} mm | "
              f"{s.mean_edge_texels_256:.1f} px | {s.fill:.2f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/images", help="directory of the pictures (default: %(default)s)")
    ap.add_argument("--measure", action="store_true", help="print the measurement tables")
    ap.add_argument("--no-images", action="store_true", help="skip the pictures")
    args = ap.parse_args()
    from sim.bodies import load_body

    body = load_body()
    out = Path(args.out)
    if not args.no_images:
        out.mkdir(parents=True, exist_ok=True)
        render_templates(out / "garments.png", body)
        render_uv_layouts(out / "garment_uvs.png", body)
        print(f"wrote {out / 'garments.png'}, {out / 'garment_uvs.png'}")
    if args.measure:
        measure(body)


if __name__ == "__main__":
    main()
