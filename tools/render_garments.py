"""Pictures and the designs table of the garment catalogue for docs/GARMENTS.md.

    python tools/render_garments.py                   # patterns.png, garments.png, garment_uvs.png
    python tools/render_garments.py --table           # + the designs table (panels, vertex counts)
    PYTHONPATH=<checkout> python tools/render_garments.py --save-meshes DIR
                                                      # that checkout's garments as .npz in DIR
    python tools/render_garments.py --compare DIR     # + garments_hull_vs_sewn.png: DIR's | ours

``patterns.png``: every design's flat pattern drafted for the default body, all at one scale, each
panel in the colour it has on the sewn garment, openings (edges in no seam) drawn heavier.
``garments.png``: every design sewn on the default body and on a tall, heavy one
(``SHAPES``), front and three-quarter views, panels coloured and hems darker.
``garment_uvs.png``: each design's UV layout (its flat pattern packed into [0, 1]², triangle
edges drawn). ``garments_hull_vs_sewn.png``: the garments of another checkout (``--save-meshes``
run with it on the import path) beside this checkout's, same body and views (``COMPARED``).
PNGs are quantised (``save_png``) to stay under 400 KB.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SHAPES = {"default body": "", "height 0.6, weight 0.8": "height=0.6,weight=0.8"}
"""Bodies of ``garments.png`` (label: ``--shape`` value): the default and a tall, heavy one."""
COMPARED = ("t_shirt", "straight_skirt", "trousers", "dress")
"""Designs of ``garments_hull_vs_sewn.png``."""
CAMERAS = ("front", "three_quarter")
SHEET_WIDTH = 1700
"""Width [px] of the garment pictures (192 colours at this width keep them under 400 KB)."""
PATTERN_ROW = 1.6
"""Width [m] of a row of panels in ``patterns.png`` (panels wrap to the next row beyond it)."""
PATTERN_GAP = 0.04
"""Space [m] between panels in ``patterns.png``."""


@dataclass(frozen=True)
class SavedGarment:
    """What the pictures read of a garment (a ``Garment`` or one ``--save-meshes`` wrote)."""

    rest_vertices: np.ndarray
    faces: np.ndarray
    panel_ids: np.ndarray
    panel_names: tuple[str, ...]
    face_layers: np.ndarray

    @classmethod
    def load(cls, path: Path) -> SavedGarment:
        with np.load(path, allow_pickle=False) as z:
            names = tuple(str(n) for n in z["panel_names"])
            return cls(z["rest_vertices"], z["faces"], z["panel_ids"], names, z["face_layers"])

    @property
    def num_vertices(self) -> int:
        return len(self.rest_vertices)


def panel_meshes(g, hem_shade: float = 0.55):
    """One ``PreviewMesh`` per panel, in the panel colours of the UV pictures, and one per panel's
    hem (the faces at least half in it: ``face_layers`` half-way to its most) in a darker shade
    of it (``hem_shade`` times the colour)."""
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


def save_png(image, path: Path, colors: int = 256) -> None:
    """Write a PIL image as a PNG of ``colors`` colours (renders of flat-coloured panels lose
    nothing visible at 256; line drawings need fewer)."""
    image.convert("RGB").quantize(colors=colors, dither=0).save(path, optimize=True)


def _pixel_box(pose, size: tuple[int, int], points: np.ndarray, margin: float) -> np.ndarray:
    """Pixel box (left, top, right, bottom) of ``points`` (N, 3) [m] seen from camera ``pose`` in
    an image of ``size``, grown by ``margin`` of its height on every side."""
    w, h = size
    pos, up = np.array(pose.position), np.array(pose.view_up)
    back = pos - np.array(pose.focal_point)
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    rel = points - pos
    depth = -(rel @ back)
    t = np.tan(np.radians(pose.view_angle) / 2)
    px = ((rel @ right) / (depth * t * w / h) + 1) / 2 * w
    py = (1 - (rel @ up) / (depth * t)) / 2 * h
    m = margin * (py.max() - py.min())
    return np.array([px.min() - m, py.min() - m, px.max() + m, py.max() + m])


class Stage:
    """Garments on bodies, rendered from one camera per view so each shows them at one scale,
    cropped to the garments (``margin`` of their height around them).

    Every scene holds an unseen frame (opacity 0, the box of every body and garment given), so
    the camera ``render_frames`` fits is the same for all; the floor lies under the feet.

    Args:
        scenes: (body vertices, body faces, garment) per picture.
        size: rendered image [px] before cropping; height: the views' height [px] after it.
    """

    def __init__(self, scenes: list, *, size: tuple[int, int] = (1400, 1400), height: int = 320,
                 margin: float = 0.12):
        from pipelines.preview import PreviewMesh, fit_camera

        pts = np.concatenate([np.concatenate([v, g.rest_vertices]) for v, _, g in scenes]).astype(np.float64)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        frame = PreviewMesh("frame", np.array([lo, hi, [lo[0], hi[1], lo[2]]]), np.array([[0, 1, 2]]),
                            opacity=0.0)
        self.scenes = [[PreviewMesh("body", v, f), frame, *panel_meshes(g)] for v, f, g in scenes]
        garments = np.concatenate([g.rest_vertices for _, _, g in scenes]).astype(np.float64)
        self.size, self.height = size, height
        self.boxes = {}
        for cam in CAMERAS:
            box = _pixel_box(fit_camera(lo, hi, cam, size[0] / size[1]), size, garments, margin)
            self.boxes[cam] = tuple(int(v) for v in np.clip(np.round(box), 0, [*size, *size]))

    def views(self, k: int) -> list:
        """The front and three-quarter views of scene ``k``, cropped, ``height`` px tall."""
        from PIL import Image

        from pipelines.preview import render_frames

        out = []
        for cam in CAMERAS:
            im = Image.fromarray(next(render_frames(self.scenes[k], size=self.size, camera=cam)))
            im = im.crop(self.boxes[cam])
            out.append(im.resize((round(im.width * self.height / im.height), self.height), Image.LANCZOS))
        return out


def strip(images: list, label: str, captions: list[str] | None = None, gap: int = 6):
    """Images side by side on white, ``label`` above them, a caption under each (optional)."""
    from PIL import Image, ImageDraw

    top, bottom = 34, 26 if captions else 4
    w = sum(im.width for im in images) + gap * (len(images) - 1)
    h = max(im.height for im in images)
    out = Image.new("RGB", (w, top + h + bottom), "white")
    draw = ImageDraw.Draw(out)
    draw.text((w // 2, top // 2), label, fill="black", anchor="mm", font=_font(22))
    x = 0
    for k, im in enumerate(images):
        out.paste(im, (x, top))
        if captions:
            draw.text((x + im.width // 2, top + h + bottom // 2), captions[k], fill="#444444", anchor="mm",
                      font=_font(16))
        x += im.width + gap
    return out


def flow(cells: list, width: int, pad: int = 20):
    """Cells left to right on a white sheet ``width`` px wide, a new row when one does not fit,
    each row centred and as tall as its tallest cell."""
    from PIL import Image

    rows, row = [], []
    for c in cells:
        if row and sum(x.width + pad for x in row) + c.width + pad > width:
            rows.append(row)
            row = []
        row.append(c)
    rows.append(row)
    heights = [max(c.height for c in r) for r in rows]
    sheet = Image.new("RGB", (width, sum(heights) + pad * (len(rows) + 1)), "white")
    y = pad
    for r, h in zip(rows, heights, strict=True):
        x = (width - sum(c.width for c in r) - pad * (len(r) - 1)) // 2
        for c in r:
            sheet.paste(c, (x, y))
            x += c.width + pad
        y += h + pad
    return sheet


def shrink(image, width: int):
    """``image`` resized to ``width`` px wide (never enlarged)."""
    from PIL import Image

    if image.width <= width:
        return image
    return image.resize((width, round(image.height * width / image.width)), Image.LANCZOS)


def render_designs(path: Path, body) -> None:
    """``garments.png``: every design on the ``SHAPES`` bodies, front and three-quarter views."""
    from sim.bodies.default import parse_shape
    from sim.garments import TEMPLATES, make_garment

    betas = [parse_shape(spec) for spec in SHAPES.values()]
    cells = []
    for name in TEMPLATES:
        made = [make_garment(name, body, b) for b in betas]
        stage = Stage([(body.rest_mesh(b), body.faces, g) for b, g in zip(betas, made, strict=True)])
        views, captions = [], []
        for k, (label, g) in enumerate(zip(SHAPES, made, strict=True)):
            views += stage.views(k)
            captions += [f"{label}: {g.num_vertices:,} v", ""]
        cells.append(strip(views, name, captions))
    save_png(shrink(flow(cells, 2600), SHEET_WIDTH), path, colors=192)


def save_meshes(folder: Path, body) -> None:
    """Each ``COMPARED`` garment of the ``sim`` on the import path, coarse on the default body, as
    ``<name>.npz`` (the ``SavedGarment`` fields)."""
    from sim.garments import make_garment

    folder.mkdir(parents=True, exist_ok=True)
    for name in COMPARED:
        g = make_garment(name, body)
        layers = g.face_layers if g.face_layers is not None else np.ones(len(g.faces), np.float32)
        np.savez(folder / f"{name}.npz", rest_vertices=g.rest_vertices, faces=g.faces, panel_ids=g.panel_ids,
                 panel_names=np.array(g.panel_names), face_layers=layers)


def render_comparison(path: Path, body, folder: Path) -> None:
    """``garments_hull_vs_sewn.png``: each ``COMPARED`` garment saved in ``folder`` beside this
    checkout's, on the default body, front and three-quarter views."""
    from sim.garments import make_garment

    rest = body.rest_mesh(None)
    cells = []
    for name in COMPARED:
        old = SavedGarment.load(folder / f"{name}.npz")
        new = make_garment(name, body)
        stage = Stage([(rest, body.faces, old), (rest, body.faces, new)])
        views = stage.views(0) + stage.views(1)
        captions = [f"hull-fitted: {old.num_vertices:,} v", "", f"sewn: {new.num_vertices:,} v", ""]
        cells.append(strip(views, name, captions))
    save_png(shrink(flow(cells, 2600), SHEET_WIDTH), path, colors=192)


def render_uv_layouts(path: Path, body, *, size: int = 400) -> None:
    """``garment_uvs.png``: each design's UV layout (coarse, default body), 3 per row."""
    from pipelines.garments_cmd import draw_uv_layout
    from sim.garments import TEMPLATES, make_garment

    cells = [strip([draw_uv_layout(make_garment(name, body), size).convert("RGB")], name)
             for name in TEMPLATES]
    save_png(flow(cells, 3 * size + 80), path, colors=64)


def shelf(pattern, width: float = PATTERN_ROW, gap: float = PATTERN_GAP) -> tuple[np.ndarray, float, float]:
    """Panels of ``pattern`` in rows no wider than ``width`` [m], in pattern order, tops aligned
    in each row: (offset (P, 2) [m] to add to each panel's points, used width, height)."""
    boxes = [(p.outline(16).min(axis=0), p.outline(16).max(axis=0)) for p in pattern.panels]
    offsets, rows, row = np.zeros((len(boxes), 2)), [], []
    x = 0.0
    for i, (lo, hi) in enumerate(boxes):
        if row and x + hi[0] - lo[0] > width:
            rows.append(row)
            row, x = [], 0.0
        row.append(i)
        offsets[i, 0] = x - lo[0]
        x += hi[0] - lo[0] + gap
    rows.append(row)
    y, used = 0.0, 0.0
    for r in rows:
        top = max(boxes[i][1][1] - boxes[i][0][1] for i in r)
        for i in r:
            offsets[i, 1] = y - boxes[i][1][1]
            used = max(used, offsets[i, 0] + boxes[i][1][0])
        y -= top + gap
    return offsets, used, -y - gap


def centroid(poly: np.ndarray) -> np.ndarray:
    """Area centroid of a simple polygon (K, 2)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    cross = a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]
    return ((a + b) * cross[:, None]).sum(axis=0) / (3.0 * cross.sum())


def draw_pattern(ax, pattern, offsets: np.ndarray) -> None:
    """Panels filled in their garment colours at ``offsets``, free edges (openings) heavier."""
    from pipelines.garments_cmd import PANEL_COLORS

    free = set(pattern.free_edges())
    for i, p in enumerate(pattern.panels):
        xy = p.outline(32) + offsets[i]
        ax.fill(xy[:, 0], xy[:, 1], facecolor=PANEL_COLORS[i % len(PANEL_COLORS)], edgecolor="#333333",
                linewidth=0.6, alpha=0.85)
        for k, e in enumerate(p.edges):
            if (p.name, k) in free:
                c = p.edge_curve(k, 1 if e.kind == "line" else 32) + offsets[i]
                ax.plot(c[:, 0], c[:, 1], color="black", linewidth=2.0, solid_capstyle="round")
        mid = centroid(xy)
        ax.text(mid[0], mid[1], p.name, fontsize=7, ha="center", va="center")


def render_patterns(path: Path, body, columns: int = 3) -> None:
    """``patterns.png``: every design's pattern for the default body, one scale, 10 cm bars."""
    from matplotlib.figure import Figure
    from PIL import Image

    from sim.garments import TEMPLATES
    from sim.garments.designs import make_pattern

    patterns = {name: make_pattern(name, body) for name in TEMPLATES}
    layouts = {name: shelf(p) for name, p in patterns.items()}
    names = list(patterns)
    cell_w = max(w for _, w, _ in layouts.values()) + 0.05
    title = 0.1  # [m] above each cell's panels
    rows = [names[i:i + columns] for i in range(0, len(names), columns)]
    heights = [max(layouts[n][2] for n in r) + title + 0.04 for r in rows]
    scale = 3.2  # inches per metre of cloth
    total = sum(heights)
    fig = Figure(figsize=(columns * cell_w * scale, total * scale), dpi=110)
    top = 1.0
    for r, h in zip(rows, heights, strict=True):
        for c, name in enumerate(r):
            ax = fig.add_axes((c / columns, top - h / total, 1 / columns, h / total))
            ax.set_xlim(-0.025, cell_w - 0.025)
            ax.set_ylim(title - h, title)
            ax.set_aspect("equal")
            ax.axis("off")
            draw_pattern(ax, patterns[name], layouts[name][0])
            ax.text(0.0, 0.055, f"{name} ({len(patterns[name].panels)} panels)", fontsize=11, weight="bold")
            ax.plot([cell_w - 0.17, cell_w - 0.07], [0.06, 0.06], color="black", linewidth=2)
            ax.text(cell_w - 0.12, 0.072, "10 cm", fontsize=7, ha="center")
        top -= h / total
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    with Image.open(tmp) as im:
        save_png(im, path)
    tmp.unlink()


def print_table(body) -> None:
    """The designs table: panels, edge lengths and vertex counts (coarse, fine) on the default body."""
    from sim.garments import TEMPLATES
    from sim.garments.designs import make_pattern
    from sim.garments.pattern_mesh import mesh_pattern

    print("| design | panels | coarse edge | coarse vertices | fine edge | fine vertices |")
    print("|---|---|---|---|---|---|")
    for name, t in TEMPLATES.items():
        p = make_pattern(name, body)
        counts = [mesh_pattern(p, h).group_count for h in (t.coarse, t.fine)]
        print(f"| {name} | {', '.join(q.name for q in p.panels)} | {t.coarse * 1000:g} mm | {counts[0]:,} | "
              f"{t.fine * 1000:g} mm | {counts[1]:,} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/images", help="directory of the pictures (default: %(default)s)")
    ap.add_argument("--table", action="store_true", help="print the designs table")
    ap.add_argument("--no-images", action="store_true", help="only --table / --compare")
    ap.add_argument("--save-meshes", type=Path, metavar="DIR", help="only save the COMPARED garments to DIR")
    ap.add_argument("--compare", type=Path, metavar="DIR",
                    help="render garments_hull_vs_sewn.png from the garments --save-meshes wrote to DIR")
    args = ap.parse_args()
    from sim.bodies import load_body

    body = load_body()
    if args.save_meshes:
        save_meshes(args.save_meshes, body)
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not args.no_images:
        render_patterns(out / "patterns.png", body)
        render_designs(out / "garments.png", body)
        render_uv_layouts(out / "garment_uvs.png", body)
    if args.compare:
        render_comparison(out / "garments_hull_vs_sewn.png", body, args.compare)
    if args.table:
        print_table(body)


if __name__ == "__main__":
    main()
