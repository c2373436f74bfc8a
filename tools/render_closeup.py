"""Close-up of the shipped wrinkle model for docs/WRINKLES.md: the CVAE base mesh (left) and the
same frame with the sampled wrinkles decoded onto it (right), garment only.

    python tools/render_closeup.py                       # docs/images/animate_closeup.png
    python tools/render_closeup.py --garment straight_skirt --out skirt.png --steps 20
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--garment", default="t_shirt", choices=["t_shirt", "straight_skirt"])
    ap.add_argument("--motion", default="walk")
    ap.add_argument("--frames", type=int, default=24, help="frames of the motion; the last is drawn")
    ap.add_argument("--steps", type=int, default=50, help="DDIM steps")
    ap.add_argument("--out", default="docs/images/animate_closeup.png")
    args = ap.parse_args(argv)

    from PIL import Image

    from learn.animate import WrinklePipeline
    from pipelines.preview import PreviewMesh, render_frames
    from sim.bodies import load_body
    from sim.motions import MotionSkeleton, load_motion

    root = Path(__file__).resolve().parents[1] / "pretrained"
    body = load_body()
    motion = load_motion(args.motion, fps=30, duration=args.frames / 30.0,
                         skeleton=MotionSkeleton.from_body(body, None))
    pipe = WrinklePipeline(root / f"{args.garment}-coarse.pt", root / f"{args.garment}-wrinkles.pt")
    t = min(args.frames, motion.num_frames)
    res = pipe(np.asarray(motion.poses, np.float32)[:t], np.asarray(motion.trans, np.float32)[:t],
               np.zeros(10, np.float32), steps=args.steps)
    images = []
    for name, v in (("base", res.base), ("wrinkled", res.vertices)):
        mesh = PreviewMesh(name, v[t - 1:t].astype(np.float32), pipe.faces.astype(np.int32),
                           color=(0.25, 0.4, 0.8))
        images.append(next(render_frames([mesh], [0], size=(700, 700), camera="three_quarter", floor=False,
                                         shadows=False)))
    Image.fromarray(np.concatenate(images, axis=1)).save(args.out)
    d = np.linalg.norm(res.vertices[t - 1] - res.base[t - 1], axis=-1)
    print(f"wrote {args.out}: wrinkle displacement rms {1000 * np.sqrt((d ** 2).mean()):.2f} mm, "
          f"max {1000 * d.max():.1f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
