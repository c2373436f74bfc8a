# ruff: noqa: B023  (closures timed immediately, inside the loop iteration)
"""Timing of the coarse level's block solve on CUDA (development aid, docs/BENCHMARKS.md, session 31).

Builds the t-shirt's coarse level as the job default does (two levels below ~256 coarse nodes
with the automatic spacing; ``sim.cloth.coarse``), fills its system with a random diagonally
dominant diagonal and right-hand side, and times in CUDA graphs, per launch: the whole block
solve (factor and substitutions in one kernel, the default correction's), the factor alone and
the substitutions with a prepared factor (``coarse_prefactor``'s split). It checks the solve
against numpy's dense solve and the split against the whole solve (the same floats).

``python -m benchmarks.coarse_solve --vertices 5000,12000``
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.bench_tshirt import build_garment
from benchmarks.common import machine, timed_ms, write_result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vertices", default="5000",
                    help="t-shirt sizes, comma-separated (default: %(default)s)")
    ap.add_argument("--instances", type=int, default=1, help="copies of the t-shirt in the model")
    ap.add_argument("--repeats", type=int, default=200, help="graph replays timed (default: %(default)s)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()

    from sim.bodies.default import load_default_body
    from sim.cloth import ClothMaterialParams, ClothModelBuilder, SolverVBD, VBDConfig
    from sim.device import warp

    wp = warp()
    device = "cuda"
    if not wp.is_cuda_available():
        ap.error("needs a CUDA device (the block solve exists on CUDA only)")
    body = load_default_body()

    def timed(launch) -> float:
        return timed_ms(wp, device, launch, args.repeats, graph=True)

    figures = {}
    for size in (int(s) for s in args.vertices.split(",")):
        garment, _ = build_garment(body, size)
        b = ClothModelBuilder()
        for _ in range(args.instances):
            b.add_cloth(garment.rest_vertices, garment.faces, ClothMaterialParams(),
                        face_layers=garment.face_layers)
        m = b.finalize(device)
        solver = SolverVBD(m, VBDConfig(iterations=5, coarse_sweeps=(2,), coarse_spacing=0, coarse_levels=2,
                                        coarse_prefactor=True))
        level = solver.coarse
        if level.block_kernel is None:
            print(f"{size}: the coarse band does not fit a block; skipped", flush=True)
            continue
        t0 = level.templates[0]
        width = t0.band.shape[1] - 1
        nodes = level.node_count
        rng = np.random.default_rng(0)
        dense = t0.stiffness.toarray()
        per = dense.shape[0]
        diag = np.tile(np.diag(dense), args.instances) + rng.uniform(1.0, 1e3, nodes)
        rhs = rng.normal(size=(nodes, 3))
        level._diag.assign(diag.astype(np.float32))
        level._rhs.assign(rhs.astype(np.float32))
        inst = [level.model.instance_count]
        row = {"nodes_per_instance": per, "band": width, "block_threads": level.block_threads}
        whole = wp.zeros_like(level._dx)

        def solve_whole():
            wp.launch_tiled(level.block_kernel, dim=inst, block_dim=level.block_threads,
                            inputs=[level._rhs, level._diag, *level._inst, level._order, level._band_k],
                            outputs=[whole], device=device)

        row["whole_ms"] = timed(solve_whole)
        row["factor_ms"] = timed(level.factor)
        row["substitute_ms"] = timed(level.solve)
        same = bool(np.array_equal(level._dx.numpy(), whole.numpy()))
        exact = np.linalg.solve(dense + np.diag(diag[:per] - np.diag(dense)), rhs[:per])
        err = float(np.abs(whole.numpy()[:per] - exact).max() / np.abs(exact).max())
        row.update(split_same_floats=same, relative_error=err)
        figures[str(m.particle_count // args.instances)] = row
        print(size, row, flush=True)
        if not same or err > 1e-3:
            raise SystemExit(f"coarse_solve: at {size} vertices the split differs from the whole solve "
                             f"({same}) or the solve is off by {err:.2e}")
    write_result(f"coarse_solve_cuda{args.tag}", {"machine": machine(device), "sizes": {
        "vertices": args.vertices, "instances": args.instances, "repeats": args.repeats}, "figures": figures})


if __name__ == "__main__":
    main()
