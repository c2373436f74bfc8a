"""The retargeting figure of docs/DEEPWRINKLES.md (Lähner et al. 2018, Sec. 5.3): one DeepWrinkles
model on bodies of several shapes, inside and outside its training range, at one frame of one
motion.

    python tools/render_retargeting.py --model pretrained/t_shirt-deepwrinkles.pt \\
        --shape 0,0 --shape 2,-1 --shape 3.5,-2.5 --motion walk --frame 20 \\
        --out docs/images/deepwrinkles_retargeting.png

Each shape is a column: the body in clay with the garment's global shape shaded by the predicted
HR normal map (top row) and by its own normals (bottom row: what the map adds). The tangent-space
map is predicted once per frame and applies to the global shape of any body shape: the template
follows the shape through Eq. 5's offsets before skinning.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


CROP = ((0.16, 0.66), (0.1, 0.9))
"""The close-up's share of a full-body render (rows, columns): the torso and the arms."""


def parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", help="DeepWrinkles checkpoint or release file (default: the shipped one)")
    ap.add_argument("--data", help="the dataset it was trained on, where the checkpoint keeps no garment")
    ap.add_argument("--shape", action="append", required=True,
                    help="a body shape as 'wrinkles animate --shape' takes it (repeat: one column each)")
    ap.add_argument("--motion", default="walk", help="motion (default: %(default)s)")
    ap.add_argument("--duration", type=float, default=1.0, help="seconds of motion (default: %(default)s)")
    ap.add_argument("--frame", type=int, default=-1, help="the frame to draw (default: the last)")
    ap.add_argument("--camera", default="front", choices=("front", "side", "three_quarter"))
    ap.add_argument("--device", default="cpu", help="torch / Warp device (default: %(default)s)")
    ap.add_argument("--out", type=Path, required=True, help="the PNG to write")
    return ap.parse_args(argv)


def animate_args(args: argparse.Namespace, shape: str) -> argparse.Namespace:
    """``wrinkles animate --method deepwrinkles`` options of one column, checked."""
    from pipelines.animate_deepwrinkles import check_options
    from pipelines.cli import build_parser

    argv = ["animate", "--method", "deepwrinkles", "--motion", args.motion, "--duration", str(args.duration),
            f"--shape={shape}", "--device", args.device, "-q"]
    argv += ["--model", args.model] if args.model else []
    argv += ["--data", args.data] if args.data else []
    a = build_parser().parse_args(argv)
    check_options(a)
    return a


def column(anim, frame: int, camera: str) -> list:
    """The column's two renders (RGB arrays): shaded by the map, then by the surface's own normals."""
    from pipelines.animate_deepwrinkles import _preview
    from pipelines.preview import render_frame

    images = []
    for shading in (anim.shading, None):
        meshes = _preview(anim.garment, anim.verts, shading, anim.frames, anim.bm)
        img = render_frame(meshes, frame, size=(420, 560), camera=camera)
        H, W = img.shape[:2]
        (y0, y1), (x0, x1) = CROP
        images.append(img[int(y0 * H): int(y1 * H), int(x0 * W): int(x1 * W)])
    return images


def main(argv: list[str] | None = None) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from pipelines.animate_deepwrinkles import _model, animate_motion
    from sim.errors import WrinklesInputError

    args = parse(argv)
    try:
        loaded, columns = None, []
        for shape in args.shape:
            a = animate_args(args, shape)
            loaded = loaded or _model(a)
            anim = animate_motion(a, loaded)
            T = len(anim.verts)
            if not -T <= args.frame < T:
                raise WrinklesInputError(f"--frame {args.frame}: the motion has {T} frames")
            betas = np.asarray(anim.bm.betas, np.float32).ravel()
            columns.append((f"shape {shape} (|β| = {np.linalg.norm(betas):.1f})",
                            column(anim, args.frame % T, args.camera)))
    except WrinklesInputError as e:
        print(f"render_retargeting: error: {e}", file=sys.stderr)
        return 2
    fig, axes = plt.subplots(2, len(columns), figsize=(3.9 * len(columns), 6.6), squeeze=False)
    for j, (title, images) in enumerate(columns):
        for i, (img, what) in enumerate(zip(images, ("global shape + predicted HR map", "global shape alone"),
                                            strict=True)):
            axes[i, j].imshow(img)
            axes[i, j].set_title(f"{title}\n{what}", fontsize=9)
            axes[i, j].axis("off")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=100)
    plt.close(fig)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
