"""Inference speed of GSNet against the simulator on the same garment: frames per second of
``GSNetMethod.animate`` (encoder, deep skinning, the body search and physical regression of every
frame; what ``wrinkles animate --method gsnet`` runs) for t-shirts of about 5k and 20k vertices on a
walk of the default body, and the cloth solver's milliseconds per frame on the same garment and
motion (``benchmarks.scene.run_ours``, the simulator's defaults). GSNet's paper reports 6-7x the
simulation's speed.

    python -m benchmarks.bench_gsnet --device cuda --vertices 5000,20000 --seconds 2
    python -m benchmarks.bench_gsnet --device cpu --vertices 5000,20000 --seconds 0.5

Without ``--model`` the network is an untrained one of the shipped configuration
(``pipelines/configs/train/gsnet.toml``): its speed does not depend on the weights.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch

from benchmarks.common import add_results_argument, machine, write_result


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--vertices", default="5000,20000", help="garment sizes (comma separated)")
    p.add_argument("--seconds", type=float, default=1.0, help="motion length [s] at 30 fps")
    p.add_argument("--model", help="GSNet checkpoint (default: untrained, shipped configuration)")
    p.add_argument("--joint-topk", default="0", help="joint edges per vertex to time (comma separated; "
                   "0: all 24, the network's own setting without --model)")
    p.add_argument("--no-simulation", action="store_true", help="time GSNet only")
    add_results_argument(p)
    return p.parse_args(argv)


def load_method(path: str | None, device: str):
    from learn.methods.gsnet import GSNetMethod
    from learn.train.config import load_run_config
    from learn.train.trainer import load_trained

    if path:
        method, model, _ = load_trained(path, device=device)
        return method, model
    cfg = load_run_config("pipelines/configs/train/gsnet.toml", overrides={"method": "gsnet"})
    method = GSNetMethod(cfg.model)
    torch.manual_seed(0)
    return method, method.build_model().to(device).eval()


def time_gsnet(method, model, garment, body, motion, device: str) -> dict:
    """Seconds of the template (once per garment) and frames/s of the rollout."""
    from learn.gsnet.data import garment_template, motion_of

    t0 = time.perf_counter()
    template = garment_template(garment, body, np.zeros(body.num_betas, np.float32),
                                neighbours=method.config.skin_neighbours)
    template_s = time.perf_counter() - t0
    frames = body.pose(None, motion.poses, motion.trans, device=device)
    seq = {"body/poses": motion.poses, "body/joints": frames.joints[:, :24], "body/betas": np.zeros(0)}
    transforms, roots = motion_of(seq, body)
    kw = dict(fps=motion.fps, device=torch.device(device), body_vertices=frames.vertices,
              body_faces=frames.faces)
    method.animate(model, template, transforms[:4], roots[:4], **{**kw, "body_vertices": frames.vertices[:4]})
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    sync()
    t0 = time.perf_counter()
    method.animate(model, template, transforms, roots, **kw)
    sync()
    wall = time.perf_counter() - t0
    T = len(roots)
    return {"frames": T, "seconds": wall, "fps": T / wall, "ms_per_frame": 1000 * wall / T,
            "template_s": template_s}


def main(argv: list[str] | None = None) -> int:
    from benchmarks.scene import benchmark_motion, build_garment, run_ours
    from sim.bodies.default import load_default_body
    from sim.simulate import SimulationConfig

    a = parse_args(argv)
    topks = [int(v) for v in a.joint_topk.split(",")]
    if not all(0 <= k <= 24 for k in topks):
        print(f"bench_gsnet: --joint-topk values must be in [0, 24], got {a.joint_topk}", file=sys.stderr)
        return 2
    body = load_default_body()
    method, model = load_method(a.model, a.device)
    motion = benchmark_motion("walk", body, a.seconds)
    rows = []
    for n in [int(v) for v in a.vertices.split(",")]:
        garment, edge = build_garment(body, n)
        row = {"target_vertices": n, "vertices": int(len(garment.rest_vertices)), "edge_m": edge, "gsnet": {}}
        for k in topks:
            model.joint_topk = k  # the weights do not change: a choice of inference
            row["gsnet"][str(k)] = time_gsnet(method, model, garment, body, motion, a.device)
        if not a.no_simulation:
            row["simulation"], _ = run_ours(garment, body, motion, SimulationConfig(device=a.device))
            sim_ms = row["simulation"].get("ms_per_frame")
            if sim_ms:
                row["speedup"] = {k: sim_ms / g["ms_per_frame"] for k, g in row["gsnet"].items()}
        rows.append(row)
        sim = row.get("simulation", {}).get("ms_per_frame", float("nan"))
        print(f"{row['vertices']} vertices: gsnet " + ", ".join(
            f"{g['ms_per_frame']:.1f} ms/frame (top-{k})" for k, g in row["gsnet"].items())
            + f", simulation {sim:.1f} ms/frame", flush=True)
    info = machine(a.device)
    info.update(torch=torch.__version__, torch_threads=torch.get_num_threads())
    write_result(f"gsnet_{'cuda' if a.device.startswith('cuda') else 'cpu'}", {
        "machine": info, "model": a.model or "untrained (pipelines/configs/train/gsnet.toml)",
        "motion": {"name": "walk", "seconds": a.seconds, "fps": motion.fps}, "figures": {"rows": rows}},
        a.results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
