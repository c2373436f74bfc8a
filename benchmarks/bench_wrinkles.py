"""Inference speed of the wrinkle pipeline (issue 6): frames per second of ``learn.animate``
(CVAE base + strain map + DDIM wrinkles + decode) at 50 / 20 / 10 DDIM steps, per stage.

    python -m benchmarks.bench_wrinkles --coarse pretrained/t_shirt-coarse.pt \
        --wrinkles pretrained/t_shirt-wrinkles.pt --device cuda --frames 60

The quality at each step count comes from ``wrinkles evaluate --steps N`` (docs/WRINKLES.md).
Writes ``benchmarks/results/wrinkles_<device>.json`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch


def main(argv: list[str] | None = None) -> int:
    from learn.animate import WrinklePipeline, pretrained_paths
    from sim.motions import procedural_motion

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--garment", default="t_shirt")
    p.add_argument("--coarse")
    p.add_argument("--wrinkles")
    p.add_argument("--device", default="cpu")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--steps", type=int, nargs="+", default=[50, 20, 10])
    p.add_argument("--out")
    a = p.parse_args(argv)
    c, w = pretrained_paths(a.garment)
    pipe = WrinklePipeline(a.coarse or c, a.wrinkles or w, device=a.device)
    motion = procedural_motion("walk", duration=a.frames / 30.0 + 0.1, fps=30.0)
    poses, trans = motion.poses[: a.frames], motion.trans[: a.frames]
    betas = np.zeros(4, np.float32)
    pipe(poses[:8], trans[:8], betas, steps=2)  # warm-up (allocations, kernels)
    rows = []
    for s in a.steps:
        t0 = time.perf_counter()
        r = pipe(poses, trans, betas, steps=s)
        wall = time.perf_counter() - t0
        rows.append(
            {
                "steps": s,
                "frames": len(poses),
                "seconds": wall,
                "fps": len(poses) / wall,
                "ms_per_frame": 1000 * wall / len(poses),
                "stage_seconds": {k: round(v, 4) for k, v in r.seconds.items()},
            }
        )
        print(
            f"{s:3d} steps: {rows[-1]['fps']:.2f} frames/s ({rows[-1]['ms_per_frame']:.1f} ms/frame) "
            f"stages {rows[-1]['stage_seconds']}"
        )
    dev = torch.cuda.get_device_name() if a.device.startswith("cuda") else platform.processor() or "cpu"
    out = Path(
        a.out or f"benchmarks/results/wrinkles_{'cuda' if a.device.startswith('cuda') else 'cpu'}.json"
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "device": dev,
                "torch_threads": torch.get_num_threads(),
                "garment": pipe.category,
                "vertices": int(len(pipe.rest)),
                "resolution": int(pipe.maps().resolution),
                "infer_batch": pipe.wrinkles.config.infer_batch,
                "rows": rows,
            },
            indent=1,
        )
    )
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
