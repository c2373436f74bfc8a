"""Inference speed of the wrinkle model: frames per second of ``learn.animate``'s whole model path
(CVAE base, strain map, DDIM wrinkles, decode; what ``wrinkles animate`` runs) at 50 / 20 / 10
DDIM steps, with each stage's seconds, on a procedural walk of the default body.

    python -m benchmarks.bench_wrinkles --device cuda --frames 60
    python -m benchmarks.bench_wrinkles --device cpu --frames 30

The shipped models of ``--garment`` are used unless ``--coarse`` / ``--wrinkles`` name others. The
quality at each step count comes from ``wrinkles evaluate --steps N`` (docs/WRINKLES.md).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from benchmarks.common import add_results_argument, machine, write_result


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--garment", default="t_shirt")
    p.add_argument("--coarse", help="CVAE checkpoint (default: the shipped one of --garment)")
    p.add_argument("--wrinkles", help="wrinkle-model checkpoint (default: the shipped one of --garment)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--steps", type=int, nargs="+", default=[50, 20, 10])
    add_results_argument(p)
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    from learn.animate import WrinklePipeline, pretrained_paths
    from sim.motions import procedural_motion

    a = parse_args(argv)
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
        rows.append({"steps": s, "frames": len(poses), "seconds": wall, "fps": len(poses) / wall,
                     "ms_per_frame": 1000 * wall / len(poses),
                     "stage_seconds": {k: round(v, 4) for k, v in r.seconds.items()}})
        print(f"{s:3d} steps: {rows[-1]['fps']:.2f} frames/s ({rows[-1]['ms_per_frame']:.1f} ms/frame) "
              f"stages {rows[-1]['stage_seconds']}", flush=True)
    info = machine(a.device)
    info.update(torch=torch.__version__, torch_threads=torch.get_num_threads())
    write_result(f"wrinkles_{'cuda' if a.device.startswith('cuda') else 'cpu'}", {
        "machine": info,
        "sizes": {"garment": pipe.category, "vertices": int(len(pipe.rest)),
                  "resolution": int(pipe.maps().resolution), "infer_batch": pipe.wrinkles.config.infer_batch},
        "figures": {"rows": rows},
    }, a.results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
