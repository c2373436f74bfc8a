"""Edge-edge proximity queries on the benchmark t-shirt: the cloth BVH against Warp's hash grid.

Session 35 found that most of a detection query is the BVH walk's chain of dependent node loads
(53 of 86 us for the 5k t-shirt's edge query with a radius that finds nothing). This measures
the same query, with the same distance test and the same answer, through ``wp.HashGrid``
over the edges' midpoints: a candidate edge within ``r`` of edge ``e`` has its midpoint within
``|e| / 2 + l_max / 2 + r`` of ``e``'s. Both run on the garment's rest shape on the default body.
Each query only counts the pairs within ``r`` and finds the nearest distance; it stores no list.

    python -m benchmarks.grid_query_floor --device cuda
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.bench_tshirt import build_garment
from benchmarks.common import machine, timed_ms, write_result


def kernels(wp):
    """(query, bounds) kernels: per edge, the count of non-adjacent edges closer than ``r`` and
    the nearest distance (``r`` if none); each edge's box and midpoint."""

    @wp.func
    def candidate(x: wp.array(dtype=wp.vec3), edges: wp.array(dtype=wp.vec2i), ea: wp.vec2i, e2: int,
                  p1: wp.vec3, q1: wp.vec3, r: float, count: int, dmin: float):
        eb = edges[e2]
        if eb[0] == ea[0] or eb[0] == ea[1] or eb[1] == ea[0] or eb[1] == ea[1]:
            return count, dmin
        st = wp.closest_point_edge_edge(p1, q1, x[eb[0]], x[eb[1]], 1.0e-12)
        if st[2] < r:
            return count + 1, wp.min(dmin, st[2])
        return count, dmin

    @wp.kernel
    def edge_query(x: wp.array(dtype=wp.vec3), edges: wp.array(dtype=wp.vec2i), structure: wp.uint64,
                   use_grid: int, r: float, reach: float, count_out: wp.array(dtype=wp.int32),
                   dmin_out: wp.array(dtype=float)):
        """Through the BVH of the edges' boxes (``use_grid`` 0, ``reach`` unused) or the hash
        grid of their midpoints (searched within ``reach`` plus half the edge's length)."""
        e = wp.tid()
        ea = edges[e]
        p1 = x[ea[0]]
        q1 = x[ea[1]]
        e2 = int(0)
        count = int(0)
        dmin = r
        if use_grid == 0:
            query = wp.bvh_query_aabb(structure, wp.min(p1, q1) - wp.vec3(r), wp.max(p1, q1) + wp.vec3(r))
            while wp.bvh_query_next(query, e2):
                count, dmin = candidate(x, edges, ea, e2, p1, q1, r, count, dmin)
        else:
            cells = wp.hash_grid_query(structure, 0.5 * (p1 + q1), reach + 0.5 * wp.length(q1 - p1))
            while wp.hash_grid_query_next(cells, e2):
                count, dmin = candidate(x, edges, ea, e2, p1, q1, r, count, dmin)
        count_out[e] = count
        dmin_out[e] = dmin

    @wp.kernel
    def bounds(x: wp.array(dtype=wp.vec3), edges: wp.array(dtype=wp.vec2i), lo: wp.array(dtype=wp.vec3),
               hi: wp.array(dtype=wp.vec3), mid: wp.array(dtype=wp.vec3)):
        e = wp.tid()
        a = x[edges[e][0]]
        b = x[edges[e][1]]
        lo[e] = wp.min(a, b)
        hi[e] = wp.max(a, b)
        mid[e] = 0.5 * (a + b)

    return edge_query, bounds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--vertices", type=int, default=5000)
    ap.add_argument("--radii", default="0.0001,0.004,0.01", help="query radii r [m]")
    ap.add_argument("--dims", default="32,64,128", help="hash grid cells per axis")
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--tag", default="")
    args = ap.parse_args()

    import warp as wp

    from sim.bodies.default import load_default_body
    from sim.cloth.model import mesh_edges

    wp.init()
    device = args.device
    garment, _ = build_garment(load_default_body(), args.vertices)
    xv = np.asarray(garment.rest_vertices, np.float32)
    edges_np = np.asarray(mesh_edges(np.asarray(garment.faces)), np.int32)
    lengths = np.linalg.norm(xv[edges_np[:, 0]] - xv[edges_np[:, 1]], axis=1)
    x = wp.array(xv, dtype=wp.vec3, device=device)
    edges = wp.array(edges_np, dtype=wp.vec2i, device=device)
    ne = len(edges_np)
    edge_query, bounds = kernels(wp)
    lo, hi, mid = (wp.zeros(ne, dtype=wp.vec3, device=device) for _ in range(3))
    wp.launch(bounds, dim=ne, inputs=[x, edges], outputs=[lo, hi, mid], device=device)
    bvh = wp.Bvh(lo, hi)
    count = wp.zeros(ne, dtype=wp.int32, device=device)
    dmin = wp.zeros(ne, dtype=float, device=device)
    rows = []
    for r in (float(s) for s in args.radii.split(",")):
        def run_bvh(r=r):
            wp.launch(edge_query, dim=ne, inputs=[x, edges, bvh.id, 0, r, 0.0], outputs=[count, dmin],
                      device=device)

        def refit_bvh():
            wp.launch(bounds, dim=ne, inputs=[x, edges], outputs=[lo, hi, mid], device=device)
            bvh.refit()

        row = {"r": r, "bvh_query_ms": timed_ms(wp, device, run_bvh, args.repeats, graph=True),
               "bvh_bounds_refit_ms": timed_ms(wp, device, refit_bvh, args.repeats, graph=True)}
        run_bvh()
        ref_count, ref_dmin = count.numpy().copy(), dmin.numpy().copy()
        row["pairs"] = int(ref_count.sum())
        reach = r + 0.5 * float(lengths.max())
        for dim in (int(s) for s in args.dims.split(",")):
            grid = wp.HashGrid(dim, dim, dim, device=device)
            cell = reach + 0.5 * float(lengths.max())  # a query reaches at most one cell further
            grid.build(mid, cell)

            def run_grid(r=r, grid=grid, reach=reach):
                wp.launch(edge_query, dim=ne, inputs=[x, edges, grid.id, 1, r, reach], outputs=[count, dmin],
                          device=device)

            def build_grid(grid=grid, cell=cell):
                wp.launch(bounds, dim=ne, inputs=[x, edges], outputs=[lo, hi, mid], device=device)
                grid.build(mid, cell)

            run_grid()
            same = bool(np.array_equal(count.numpy(), ref_count) and np.allclose(dmin.numpy(), ref_dmin))
            row[f"grid{dim}"] = {
                "query_ms": timed_ms(wp, device, run_grid, args.repeats, graph=True),
                "bounds_build_ms": timed_ms(wp, device, build_grid, args.repeats, graph=True),
                "same_pairs": same}
        print(row, flush=True)
        rows.append(row)
    write_result(f"grid_query_floor_{wp.get_device(device).alias.split(':')[0]}{args.tag}",
                 {"benchmark": "grid_query_floor", "command": "python -m benchmarks.grid_query_floor "
                  f"--device {device} --radii {args.radii} --dims {args.dims}", "machine": machine(device),
                  "sizes": {"vertices": int(len(xv)), "edges": int(ne),
                            "edge_length_max": float(lengths.max()),
                            "edge_length_mean": float(lengths.mean())},
                  "rows": rows})


if __name__ == "__main__":
    main()
