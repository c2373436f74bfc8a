"""Physics-loss throughput: forward and forward + backward of every term, Warp vs plain torch.

A t-shirt template at the resolution giving about ``--vertices`` vertices on the default body
(13,348 vertices, 26,692 faces); ``--batch`` random deformations of it (5 mm noise) with their
previous positions, and per-sample bodies (the rest body shifted by a few mm). Each term (and
the SNUG/HOOD-style and GSNet-style sums) is timed after warm-up, synchronised, median of
``--repeats``: ``forward`` under ``torch.no_grad``, ``forward_backward`` = energy.sum().backward()
wrt the garment positions. The plain-torch references (``learn.losses.reference``, float32 on
the same device) are timed the same way. The collision search alone (BVH vs full scan, vertex
vs face anchors) is timed separately.

    python -m benchmarks.bench_losses --device cpu --batch 4 --repeats 3
    python -m benchmarks.bench_losses --device cuda --batch 64 --vertices 5000

On the CPU the Warp kernels run on one thread; at batch 64 a full run takes many minutes (the
dense reference search alone ~6 s per call): use --repeats 3 --warmup 1, or --no-reference.

Needs torch, numpy, scipy and warp only (no trimesh / usd / pyvista).
"""

from __future__ import annotations

import argparse
import math
import resource
import statistics
import time

import numpy as np
import torch

from benchmarks.common import add_results_argument, machine, write_result


def build_garment(target_vertices: int):
    """A t-shirt on the default body with about ``target_vertices`` vertices (edge length
    scaled from the template's coarse resolution: vertex count ~ 1 / h^2)."""
    from sim.bodies import load_body
    from sim.garments import make_garment
    from sim.garments.templates import TEMPLATES

    body = load_body()
    t = TEMPLATES["t_shirt"]
    h = t.coarse * math.sqrt(t.vertices[0] / target_vertices)
    return body, make_garment("t_shirt", body, resolution=h), h


def make_terms(topology, body_faces, dt):
    """(name, warp module, reference function of (x, x_prev, x_prev2, body)) for every term."""
    from learn.losses import (
        BendingLoss,
        CollisionLoss,
        GravityLoss,
        GSNetBendingLoss,
        GSNetCollisionLoss,
        GSNetEdgeLoss,
        InertiaLoss,
        MembraneLoss,
    )
    from learn.losses import reference as R

    m, b = MembraneLoss(topology), BendingLoss(topology)
    g, i = GravityLoss(topology), InertiaLoss(topology, dt=dt)
    col = CollisionLoss(topology, body_faces=body_faces, eps=4e-3)
    colf = CollisionLoss(topology, body_faces=body_faces, eps=4e-3, anchor="face")
    gcol = GSNetCollisionLoss(topology, body_faces=body_faces)
    ge, gb = GSNetEdgeLoss(topology), GSNetBendingLoss(topology)
    terms = [
        ("membrane", lambda x, xp, xpp, bv: m.energy(x),
         lambda x, xp, xpp, bv: R.membrane_energy(x, topology, m.mu, m.lam)),
        ("bending", lambda x, xp, xpp, bv: b.energy(x),
         lambda x, xp, xpp, bv: R.bending_energy(x, topology, b.bending)),
        ("collision_vertex", lambda x, xp, xpp, bv: col.energy(x, bv),
         lambda x, xp, xpp, bv: R.collision_energy(x, bv, body_faces, stiffness=col.stiffness, eps=col.eps,
                                                   power=3.0)),
        ("collision_face", lambda x, xp, xpp, bv: colf.energy(x, bv),
         lambda x, xp, xpp, bv: R.collision_energy(x, bv, body_faces, stiffness=colf.stiffness, eps=colf.eps,
                                                   power=3.0, anchor="face")),
        ("inertia", lambda x, xp, xpp, bv: i.energy(x, xp, xpp),
         lambda x, xp, xpp, bv: R.inertia_energy(x, xp, xpp, topology, i.density, dt)),
        ("gravity", lambda x, xp, xpp, bv: g.energy(x),
         lambda x, xp, xpp, bv: R.gravity_energy(x, topology, g.density)),
        ("gsnet_edge", lambda x, xp, xpp, bv: ge.energy(x),
         lambda x, xp, xpp, bv: R.edge_energy(x, topology)),
        ("gsnet_bending", lambda x, xp, xpp, bv: gb.energy(x),
         lambda x, xp, xpp, bv: R.gsnet_bending_energy(x, topology)),
        ("gsnet_collision", lambda x, xp, xpp, bv: gcol.energy(x, bv),
         lambda x, xp, xpp, bv: R.collision_energy(x, bv, body_faces, stiffness=1.0, eps=gcol.eps,
                                                   power=2.0)),
    ]
    by_name = {n: (w, r) for n, w, r in terms}

    def summed(names, which):
        def f(*args):
            return sum(by_name[n][which](*args) for n in names)
        return f

    snug = ("membrane", "bending", "collision_vertex", "inertia", "gravity")
    gsnet = ("gsnet_edge", "gsnet_bending", "gsnet_collision")
    terms.append(("sum_snug_hood", summed(snug, 0), summed(snug, 1)))
    terms.append(("sum_gsnet", summed(gsnet, 0), summed(gsnet, 1)))
    return terms, {"collision_vertex": col, "collision_face": colf}


def timed(fn, sync, repeats: int, warmup: int) -> float:
    """Median wall time [s] of ``fn()`` after ``warmup`` calls, synchronised."""
    for _ in range(warmup):
        fn()
    sync()
    times = []
    for _ in range(repeats):
        sync()
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto")
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--vertices", type=int, default=5000, help="target garment vertex count")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--search-repeats", type=int, default=3,
                    help="repeats (after one warm-up) of the search-only timings (the cpu full scan is slow)")
    ap.add_argument("--no-reference", action="store_true", help="skip the plain-torch references")
    add_results_argument(ap)
    return ap.parse_args()


def deformed_batch(topology, body, bsz: int, tdev):
    """``bsz`` garments at rest plus 5 mm of noise, their two previous positions, and the rest
    body shifted by a few mm per sample (seeded)."""
    gen = torch.Generator().manual_seed(0)
    nv = topology.num_vertices
    rest = torch.as_tensor(topology.rest_vertices)
    x = (rest[None] + 0.005 * torch.randn((bsz, nv, 3), generator=gen)).to(tdev)
    xp = (x.cpu() - 0.003 + 0.001 * torch.randn((bsz, nv, 3), generator=gen)).to(tdev)
    xpp = (xp.cpu() - 0.003 + 0.001 * torch.randn((bsz, nv, 3), generator=gen)).to(tdev)
    bv = (torch.as_tensor(body.rest_mesh(), dtype=torch.float32)[None]
          + 0.004 * torch.randn((bsz, 1, 3), generator=gen)).to(tdev)
    return x, xp, xpp, bv


def time_term(fn, batch: tuple, sync, args, tdev) -> dict:
    """Forward and forward + backward figures of one implementation of a term."""
    x, xp, xpp, bv = batch
    bsz = x.shape[0]
    if tdev.type == "cuda":
        torch.cuda.reset_peak_memory_stats(tdev)
    xg = x.clone().requires_grad_(True)

    def fwd():
        with torch.no_grad():
            return fn(x, xp, xpp, bv)

    def fwd_bwd():
        xg.grad = None
        fn(xg, xp, xpp, bv).sum().backward()

    try:
        t_f = timed(fwd, sync, args.repeats, args.warmup)
        t_fb = timed(fwd_bwd, sync, args.repeats, args.warmup)
    except (RuntimeError, MemoryError) as exc:  # e.g. the dense reference search out of memory
        return {"error": str(exc).splitlines()[0][:200]}
    r = {"forward_ms": 1e3 * t_f, "forward_backward_ms": 1e3 * t_fb,
         "forward_samples_per_s": bsz / t_f, "forward_backward_samples_per_s": bsz / t_fb}
    if tdev.type == "cuda":
        r["torch_peak_mb"] = torch.cuda.max_memory_allocated(tdev) / 2**20
    return r


def time_terms(terms: list, batch: tuple, sync, args, tdev) -> dict:
    """{term: {"warp": figures, "torch": figures}}, each term printed as it is timed."""
    rows = {}
    nan = float("nan")
    for name, warp_fn, ref_fn in terms:
        impls = [("warp", warp_fn)] + ([] if args.no_reference else [("torch", ref_fn)])
        rows[name] = {impl: time_term(fn, batch, sync, args, tdev) for impl, fn in impls}
        w, ref = rows[name].get("warp", {}), rows[name].get("torch", {})
        print(f"{name:18s} warp fwd {w.get('forward_ms', nan):9.3f} ms  fwd+bwd "
              f"{w.get('forward_backward_ms', nan):9.3f} ms | torch fwd "
              f"{ref.get('forward_ms', nan):9.3f} ms  fwd+bwd {ref.get('forward_backward_ms', nan):9.3f} ms "
              f"{ref.get('error', '')}", flush=True)
    return rows


def time_search(topology, collisions: dict, bf, batch: tuple, sync, repeats: int) -> dict:
    """The collision terms' nearest-anchor search alone (no energy, no gradient): BVH against a
    full scan, body-vertex against body-face anchors."""
    from learn.losses import CollisionLoss

    x, _, _, bv = batch
    search = {}
    for anchor in ("vertex", "face"):
        for method in ("bvh", "brute"):
            mod = collisions[f"collision_{anchor}"] if method == "bvh" else CollisionLoss(
                topology, body_faces=bf, anchor=anchor, search=method)
            t = timed(lambda mod=mod: mod.nearest_anchors(x, bv), sync, repeats, 1)
            search[f"{anchor}_{method}"] = {"ms": 1e3 * t, "samples_per_s": x.shape[0] / t}
            print(f"search {anchor:6s} {method:5s} {1e3 * t:9.3f} ms", flush=True)
    return search


def main() -> None:
    args = parse_args()
    from sim.device import resolve_device, warp
    from sim.losses import topology_of

    wp = warp()
    device = resolve_device(args.device)
    tdev = torch.device(device if device.startswith("cuda") else "cpu")

    def sync():
        if tdev.type == "cuda":
            torch.cuda.synchronize(tdev)

    t0 = time.perf_counter()
    body, garment, h = build_garment(args.vertices)
    topology = topology_of(garment)
    setup_s = time.perf_counter() - t0
    batch = deformed_batch(topology, body, args.batch, tdev)
    bf = body.faces.astype(np.int32)
    terms, collisions = make_terms(topology, bf, dt=1.0 / 30.0)
    rows = time_terms(terms, batch, sync, args, tdev)
    search = time_search(topology, collisions, bf, batch, sync, args.search_repeats)

    info = machine(device)
    info["torch"] = torch.__version__
    mem = {"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    if tdev.type == "cuda":
        mem["warp_mempool_high_mb"] = wp.get_mempool_used_mem_high(device) / 2**20
    write_result(f"losses_{device.split(':')[0]}", {
        "machine": info,
        "sizes": {"batch": args.batch, "garment_vertices": topology.num_vertices,
                  "garment_faces": topology.num_faces, "garment_edges": len(topology.edges),
                  "hinges": len(topology.hinges), "edge_length_m": h, "body_vertices": int(body.num_vertices),
                  "body_faces": len(bf), "garment": "t_shirt on the default body (rest pose)"},
        "figures": {"terms": rows, "collision_search": search, "memory": mem},
        "method": (f"median of {args.repeats} after {args.warmup} warm-up calls (search alone: "
                   f"{args.search_repeats} after 1), synchronised; forward under "
                   "no_grad, forward_backward = energy.sum().backward() wrt garment positions (float32); "
                   "'torch' = learn.losses.reference on the same device; setup (template build) "
                   f"{setup_s:.1f} s not included"),
    }, args.results)


if __name__ == "__main__":
    main()
