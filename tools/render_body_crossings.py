"""Where the skinned default body passes through itself: a picture for docs/BENCHMARKS.md.

    python tools/render_body_crossings.py            # docs/images/body_self_crossings.png

For each motion (squat, jump, arm_raise; 4 s, built on the body's own skeleton as ``wrinkles
body`` builds it), the frame with the most self-crossing edges (``sim.quality.body_self_crossings``,
beyond those crossing at rest), the body drawn grey with the vertices of those edges in red, from
the side that shows them (the knee pits from the side, the armpits from the front).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

CASES = (("squat", "three_quarter"), ("jump", "front"), ("arm_raise", "front"))
"""(motion, camera). The run's crossings (the knee pits) fold inside the crease: nothing shows."""


def crossing_frame(body, motion: str, seconds: float):
    """(posed vertices (V, 3) at the motion's worst frame, that frame, per-vertex 0/1 marks of the
    edges crossing there but not at rest, the summary)."""
    from sim.motions import MotionSkeleton, load_motion
    from sim.quality import body_self_crossings, crossing_edges, unique_edges

    mot = load_motion(motion, fps=30.0, duration=seconds, skeleton=MotionSkeleton.from_body(body, None))
    frames = body.pose_motion(mot, None, device="cpu")
    rest = body.rest_mesh(None)
    summary = body_self_crossings(frames.vertices, body.faces, rest, body.weights, body.joint_names,
                                  device="cpu")
    t = int(np.argmax(summary["per_frame"]))
    e = unique_edges(body.faces)
    new = crossing_edges(frames.vertices[t], body.faces, device="cpu") & ~crossing_edges(rest, body.faces,
                                                                                          device="cpu")
    marks = np.zeros(len(rest), np.float32)
    marks[e[new].ravel()] = 1.0
    return frames.vertices[t], t, marks, summary


def main() -> None:
    from PIL import Image, ImageDraw

    from pipelines.preview import PreviewMesh, render_frames
    from sim.bodies.default import load_default_body
    from tools.render_garments import _font

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/images/body_self_crossings.png")
    ap.add_argument("--seconds", type=float, default=4.0)
    args = ap.parse_args()
    body = load_default_body()
    cells = []
    for motion, camera in CASES:
        x, t, marks, s = crossing_frame(body, motion, args.seconds)
        mesh = PreviewMesh("body", x, body.faces, scalars=marks, cmap="Reds", clim=(-0.35, 1.0))
        im = Image.fromarray(next(render_frames([mesh], size=(700, 900), camera=camera, shadows=False)))
        cell = Image.new("RGB", (im.width, im.height + 70), "white")
        cell.paste(im, (0, 0))
        here = [k for k, v in s["by_joint"].items() if t in v["frames"]]  # the joints at this frame
        joints = ", ".join(here[:4]) + (f" and {len(here) - 4} more" if len(here) > 4 else "")
        draw = ImageDraw.Draw(cell)
        draw.text((im.width // 2, im.height + 18), f"{motion}: {s['frames_with_crossings']} of "
                  f"{len(s['per_frame'])} frames cross", fill="black", anchor="mm", font=_font(26))
        draw.text((im.width // 2, im.height + 50), f"frame {t}: {s['per_frame'][t]} edges ({joints})",
                  fill="black", anchor="mm", font=_font(18))
        cells.append(cell)
        print(f"{motion}: frame {t}, {s['per_frame'][t]} edges; {s['frames_with_crossings']} frames",
              flush=True)
    sheet = Image.new("RGB", (sum(c.width for c in cells), max(c.height for c in cells)), "white")
    x0 = 0
    for c in cells:
        sheet.paste(c, (x0, 0))
        x0 += c.width
    sheet = sheet.resize((1800, round(sheet.height * 1800 / sheet.width)), Image.LANCZOS)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    sheet.save(args.out, optimize=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
