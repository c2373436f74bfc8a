"""Close-ups of simulated garments on the body for docs/GARMENTS.md, from the frames that
``python -m benchmarks.bench_garments --frames-out DIR`` writes.

    python tools/render_closeups.py DIR/t_shirt_mean_arm_raise.npz:shoulders \\
        DIR/t_shirt_mean_squat.npz:waist DIR/t_shirt_mean_walk.npz:torso --out docs/images/closeups.png

Each ``FILE[:REGION]`` is one picture: its last frame (``--frame`` picks another stored one),
front and three-quarter views, cropped to the garment's points in a band of the body's height
(``REGIONS``: shoulders, torso, waist, knees; all: the whole garment), panels coloured as in
garments.png, the body in skin grey.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_garments import CAMERAS, _pixel_box, flow, save_png, shrink, strip  # noqa: E402

REGIONS = {"shoulders": (0.68, 0.86), "torso": (0.55, 0.86), "waist": (0.45, 0.66), "knees": (0.2, 0.4),
           "all": (0.0, 1.0)}
"""Bands of the body's height (shares from its lowest to its highest point) a close-up shows."""
PANEL_COLORS = np.array([[0.36, 0.55, 0.80], [0.85, 0.52, 0.32], [0.45, 0.70, 0.45], [0.80, 0.42, 0.55],
                         [0.62, 0.52, 0.80], [0.80, 0.72, 0.35], [0.40, 0.70, 0.72], [0.70, 0.45, 0.35]])
"""Panel colours, by panel index (cycled)."""


FIELDS = ("garment", "body", "garment_faces", "body_faces", "panel_ids", "frames")
"""The arrays of a frames file."""


def refuse(message: str) -> None:
    """Exit with status 2 and a one-line error."""
    print(f"render_closeups: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def read_frames(path: Path, frame: int | None) -> tuple[dict, int]:
    """The arrays of a frames file and the stored frame to draw (``frame``: a motion frame index
    it stores; None: its last)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in FIELDS}
    except (OSError, KeyError, ValueError) as e:
        refuse(f"{path}: not a frames file of bench_garments --frames-out ({e})")
    frames = data["frames"].tolist()
    if frame is None:
        return data, len(frames) - 1
    if frame not in frames:
        refuse(f"{path}: frame {frame} is not stored (stored: {frames})")
    return data, frames.index(frame)


def scene(data: dict, k: int) -> list:
    """The body and one mesh per garment panel at stored frame ``k``."""
    from pipelines.preview import PreviewMesh

    g = data["garment"][k].astype(np.float32)
    skin = (0.78, 0.74, 0.70)
    out = [PreviewMesh("body", data["body"][k].astype(np.float32), data["body_faces"], color=skin)]
    faces, panels = data["garment_faces"], data["panel_ids"]
    for p in np.unique(panels):
        color = tuple(PANEL_COLORS[p % len(PANEL_COLORS)])
        out.append(PreviewMesh(f"panel {p}", g, faces[panels == p], color=color))
    return out


def closeup(data: dict, k: int, region: str, *, size=(1400, 1400), height: int = 420) -> list:
    """Front and three-quarter views of stored frame ``k``, cropped to the garment in ``region``."""
    from PIL import Image

    from pipelines.preview import fit_camera, render_frames

    body, g = data["body"][k].astype(np.float64), data["garment"][k].astype(np.float64)
    lo_y, hi_y = body[:, 1].min(), body[:, 1].max()
    a, b = REGIONS[region]
    band = g[(g[:, 1] >= lo_y + a * (hi_y - lo_y)) & (g[:, 1] <= lo_y + b * (hi_y - lo_y))]
    if len(band) == 0:
        band = g
    pts = np.concatenate([body, g])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    views = []
    for cam in CAMERAS:
        box = _pixel_box(fit_camera(lo, hi, cam, size[0] / size[1]), size, band, 0.08)
        box = tuple(int(v) for v in np.clip(np.round(box), 0, [*size, *size]))
        im = Image.fromarray(next(render_frames(scene(data, k), size=size, camera=cam, floor=False)))
        im = im.crop(box)
        views.append(im.resize((round(im.width * height / im.height), height), Image.LANCZOS))
    return views


def parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pictures", nargs="+", metavar="FILE[:REGION]",
                    help=f"a frames .npz and the region to show ({', '.join(REGIONS)}; default all)")
    ap.add_argument("--frame", type=int, default=None,
                    help="the motion frame to draw (default: the last stored)")
    ap.add_argument("--out", type=Path, default=Path("docs/images/closeups.png"), help="the PNG to write")
    args = ap.parse_args(argv)
    args.items = []
    for item in args.pictures:
        path, _, region = item.partition(":")
        region = region or "all"
        if region not in REGIONS:
            ap.error(f"{item}: unknown region {region!r}; expected one of {', '.join(REGIONS)}")
        if not Path(path).is_file():
            ap.error(f"{path}: no such file")
        args.items.append((Path(path), region))
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    cells = []
    for path, region in args.items:
        data, k = read_frames(path, args.frame)
        label = f"{path.stem.replace('_', ' ')}, frame {int(data['frames'][k])}, {region}"
        cells.append(strip(closeup(data, k, region), label))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_png(shrink(flow(cells, 2000), 1800), args.out, colors=192)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
