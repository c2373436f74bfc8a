"""LBS throughput: frames/s skinning the default body over a 1000-frame motion.

Measures (a) device-resident skinning (kernels only, synchronised) and (b) skinning plus the
copy of all vertices to host numpy, the path `wrinkles body` takes.

    python -m benchmarks.bench_lbs --device cpu --repeats 3
    python -m benchmarks.bench_lbs --device cuda --repeats 10
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.common import add_results_argument, machine, write_result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--body", default="default", help="'default' or an SMPL-family model file")
    add_results_argument(ap)
    args = ap.parse_args()

    from sim.bodies import load_body
    from sim.device import resolve_device, warp
    from sim.motions import load_motion

    wp = warp()
    device = resolve_device(args.device)
    body = load_body(args.body)
    motion = load_motion("walk", fps=30.0, duration=args.frames / 30.0)
    poses = body.full_poses(motion.poses[: args.frames])
    trans = motion.trans[: args.frames]
    T = poses.shape[0]
    sk = body.skinner(device)
    betas = np.zeros(body.num_betas, np.float32)

    # warm-up: compile/load kernels, fill caches
    sk.pose_device(betas, poses[:8], trans[:8])
    wp.synchronize_device(device)

    def timed(fn) -> float:
        best = float("inf")
        for _ in range(args.repeats):
            wp.synchronize_device(device)
            t0 = time.perf_counter()
            fn()
            wp.synchronize_device(device)
            best = min(best, time.perf_counter() - t0)
        return best

    t_dev = timed(lambda: sk.pose_device(betas, poses, trans))
    t_host = timed(lambda: sk.pose(betas, poses, trans, chunk=T))
    result = {
        "machine": machine(device),
        "sizes": {"frames": T, "vertices": body.num_vertices, "joints": body.num_joints,
                  "body": body.name, "pose_blend_shapes": body.posedirs is not None},
        "figures": {
            "device_frames_per_s": T / t_dev,
            "device_ms_per_1000_frames": 1000 * t_dev * 1000 / T,
            "with_host_copy_frames_per_s": T / t_host,
            "vertices_per_s_device": T * body.num_vertices / t_dev,
        },
        "method": f"best of {args.repeats}; poses uploaded each call; includes FK + LBS launches",
    }
    write_result(f"lbs_{device.split(':')[0]}", result, args.results)


if __name__ == "__main__":
    main()
