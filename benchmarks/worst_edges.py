"""Where a t-shirt run's edge strain sits: its most stretched edges, with place and shape.

One run of the benchmark t-shirt (``bench_tshirt.build_garment``; ``--garment`` another template,
session 42) on the default body at the job defaults (``SimulationConfig``; ``--solver`` adds
``VBDConfig`` fields, ``--sim`` ``SimulationConfig`` fields), then per mesh edge the
largest ``|l / l0 - 1|`` over the motion's frames, as the max-strain gate takes it (an edge crumpled to half
its length fails it as one stretched by half; each listed edge's strain is signed: negative is
compression; before session 46 only stretch was ranked). Written: the run's maximum and mean
strain, how many edges exceed 0.2 and the 0.35 gate, and the worst edges with their frame, rest
length, triangles per end vertex, panel and rest position, and how far the body's own skin within
5 cm of the worst edge is stretched at its frame (``skin_under_worst``). The max-strain gate is
set by a few edges; this shows whether they sit at a feature of the pattern (session 26: the
neckline's square corners) or spread over the garment. It also lists, per sequence, the frames
with self-intersections and the edges that cross at the first of them, and where the body holds
the most garment vertices inside it (per panel, with their mean rest position); ``--copies K``
runs the same motions K times in one batched model beside the runs alone, to tell a batch's result
from a single garment's.

    python -m benchmarks.worst_edges --device cuda --vertices 20000 --motion run --tag _19k_run
    python -m benchmarks.worst_edges --device cpu --garment trousers --vertices 3000 --motion run
    python -m benchmarks.worst_edges --device cpu --vertices 1000 --seconds 0.5 --param neck_fillet=0
    python -m benchmarks.worst_edges --vertices 20000 --setting 20x5 --motion walk,run --copies 8
    python -m benchmarks.worst_edges --device cuda --vertices 20000 --motion walk --save f19.npz  # then
    python -m benchmarks.neckline_stretch f19_walk.npz --motion walk

A dataset's rejected sequence (``rejections.jsonl``: ``betas``, ``garment_params``,
``motion_params``, ``vertices``) runs again with ``--shape`` (the garment fitted to that body, as a
dataset's ``fit = "body"``), ``--param`` and ``--motion-param``:

    python -m benchmarks.worst_edges --device cuda --garment tank_top --vertices 19000 --motion walk \
        --shape 0.8,-1.2,0.3,0.5 --motion-param speed=1.62 --motion-param arm_swing=1.1
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time

import numpy as np

from benchmarks.common import machine, write_result
from pipelines.options import join_negative_values


def _edge_rows(keys, worst, strain, rest, e, tris, panel, names) -> list[dict]:
    """One dict per edge index in ``keys``: its strain and frame (unless ``worst`` is None), rest
    length, triangles per end, panel and rest position."""
    rows = []
    for k in keys:
        a, b = (int(i) for i in e[k])
        row = {"edge": [a, b]}
        if worst is not None:  # signed: a negative strain is a compressed (crumpled) edge
            t = int(np.abs(strain[:, k]).argmax())
            row.update(strain=float(strain[t, k]), frame=t)
        row.update({"rest_length_mm": float(1000.0 * np.linalg.norm(rest[a] - rest[b])),
                    "triangles": [int(tris[a]), int(tris[b])], "panel": names[panel[a]],
                    "rest_position": np.round(rest[a], 4).tolist()})
        rows.append(row)
    return rows


def _inside_rows(result, g, t: int, panel: np.ndarray, device: str) -> dict:
    """The garment vertices inside the body at frame ``t`` (the worst): their count, and per
    panel how many, how deep at most [mm] and their mean rest position."""
    from sim.cloth.state import BodyCollider

    seq = result.sequence
    body = BodyCollider(seq.body.vertices[t], seq.body.faces, device=device)
    d = body.signed_distance(np.asarray(seq.vertices[t], np.float32), max_dist=0.1)
    ins = np.flatnonzero(d < 0.0)
    rows = {}
    for p in np.unique(panel[ins]):
        k = ins[panel[ins] == p]
        rows[g.panel_names[p]] = {"vertices": int(len(k)), "deepest_mm": float(-1000.0 * d[k].min()),
                                  "mean_rest_position": np.round(g.rest_vertices[k].mean(axis=0), 3).tolist()}
    return {"frame": t, "vertices": int(len(ins)), "by_panel": rows}


def _skin_under(result, body_rest: np.ndarray, point: np.ndarray, t: int, device: str,
                reach: float = 0.05) -> dict:
    """How far the body's own skin is stretched at frame ``t`` near ``point`` [m]: the strain
    (``l / l0 - 1`` against the body's rest mesh) of the body edges whose midpoints lie within
    ``reach`` of it. Skinning alone (no pose correctives) stretches the skin at the crotch and the
    knees; cloth held there by friction and pressure follows it (session 43)."""
    from sim.quality import edge_strain, unique_edges

    seq = result.sequence
    e = unique_edges(seq.body.faces)
    bx = np.asarray(seq.body.vertices[t], np.float32)
    near = np.linalg.norm(0.5 * (bx[e[:, 0]] + bx[e[:, 1]]) - point, axis=1) < reach
    if not near.any():
        return {"edges": 0}
    s = edge_strain(bx[None], body_rest, seq.body.faces, device=device)[0][near]
    return {"reach_m": reach, "edges": int(near.sum()), "max": float(s.max()),
            "p90": float(np.percentile(s, 90)), "mean": float(s.mean())}


def describe(result, g, device: str, n_worst: int, body_rest: np.ndarray | None = None) -> dict:
    """One sequence's strain and crossing figures: the worst edges, and the edges that cross a
    face at the first frame with crossings (panel and rest position of each)."""
    from sim.quality import SimulationError, crossing_edges, edge_strain, unique_edges

    if isinstance(result, SimulationError):
        return {"error": str(result)}
    rest = g.rest_vertices
    e = unique_edges(g.faces)
    x = result.sequence.vertices
    # the quality gates' own strain (l / l0 - 1 per edge and frame) ranked as the gate ranks it, by
    # |l / l0 - 1| (a crumpled edge fails it too), so the worst edge is the gate's
    strain = edge_strain(x, rest, g.faces, device=device)
    size = np.abs(strain)
    worst = size.max(axis=0)
    tris = np.bincount(g.faces.ravel(), minlength=len(rest))
    panel = np.full(len(rest), -1)
    panel[g.faces.ravel()] = np.repeat(g.panel_ids, 3)
    crossings = np.asarray(result.quality.self_intersections)
    out = {"ms_per_frame": float(np.mean(result.step_ms)), "failed_gates": list(result.failed_gates),
           "max_strain": float(worst.max()), "mean_strain": float(size.mean()),
           "edges_over_0.2": int((worst > 0.2).sum()), "edges_over_0.35": int((worst > 0.35).sum()),
           "worst": _edge_rows(np.argsort(-worst)[:n_worst], worst, strain, rest, e, tris, panel,
                               g.panel_names),
           "crossings_per_frame": {int(t): int(c) for t, c in enumerate(crossings) if c},
           # when it happens: per frame the largest |strain| and the edges over the 0.35 gate (session 46:
           # the fine pants' runs stretch a thousand edges at once, at each stride)
           "strain_per_frame": np.round(size.max(axis=1), 4).tolist(),
           "edges_over_0.35_per_frame": (size > 0.35).sum(axis=1).tolist()}
    if body_rest is not None:  # the skin under the worst edge, at its worst frame
        k = int(worst.argmax())
        t = int(np.abs(strain[:, k]).argmax())
        out["skin_under_worst"] = _skin_under(result, body_rest, 0.5 * (x[t][e[k, 0]] + x[t][e[k, 1]]), t,
                                              device)
    inside = np.asarray(result.quality.inside_fraction)
    if inside.any():
        out["inside"] = _inside_rows(result, g, int(inside.argmax()), panel, device)
    if crossings.any():
        t = int(np.flatnonzero(crossings)[0])
        hit = np.flatnonzero(crossing_edges(x[t], g.faces, device=device))
        out["first_crossing_frame"] = t
        out["crossing_edges"] = _edge_rows(hit[:20], None, None, rest, e, tris, panel, g.panel_names)
    return out


def main() -> None:
    from benchmarks.bench_tshirt import (
        _numbers,
        _option_error,
        add_material_argument,
        add_skeleton_argument,
        benchmark_motion,
        build_garment,
        material_changes,
        template_params,
    )
    from sim.bodies.default import load_default_body
    from sim.device import resolve_device
    from sim.errors import WrinklesInputError
    from sim.simulate import SimulationConfig, SimulationJob, simulate_batch

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--garment", default="t_shirt", help="template (default: %(default)s)")
    ap.add_argument("--vertices", type=int, default=5000, help="garment size (default: %(default)s)")
    ap.add_argument("--motion", default="walk",
                    help="motion, or a comma list of motions (default: %(default)s)")
    ap.add_argument("--seconds", type=float, default=2.0, help="motion length [s]")
    ap.add_argument("--setting", default="", metavar="SxI",
                    help="substeps x sweeps, e.g. 20x5 (default: the job default, SimulationConfig)")
    ap.add_argument("--solver", default="{}", help="JSON dict of extra VBDConfig fields")
    ap.add_argument("--sim", default="{}", metavar="JSON",
                    help='JSON dict of SimulationConfig fields, e.g. \'{"pinned": []}\' (no waistband pin) '
                    "or '{\"self_contact\": false}' (default: none)")
    ap.add_argument("--copies", type=int, default=0, metavar="K",
                    help="also run every motion K times in one batched model and report each member, "
                    "beside the runs alone (default: %(default)s, off)")
    ap.add_argument("--keep-prelude", action="store_true",
                    help="count the settle and blend frames too (frame 0 is then the settle's first)")
    ap.add_argument("--worst", type=int, default=15, help="edges to list (default: %(default)s)")
    ap.add_argument("--save", default="", metavar="PATH.npz",
                    help="also write each alone run's garment positions per frame (float32), the rest "
                    "mesh and the body's positions and faces, one file per motion (PATH_walk.npz, ...), "
                    "for a look at the worst frames (default: off)")
    ap.add_argument("--shape", default="", metavar="B1,B2,...",
                    help="body shape (betas, comma-separated; the rest 0), the garment fitted to it "
                    "(default: the mean shape)")
    ap.add_argument("--motion-param", action="append", default=[], metavar="KEY=VALUE",
                    help="a parameter of the procedural motion, e.g. speed=1.6 (repeatable; `wrinkles "
                    "motions` lists them)")
    add_material_argument(ap)
    add_skeleton_argument(ap)
    ap.add_argument("--tag", default="")
    args = ap.parse_args(join_negative_values(sys.argv[1:]))
    material = material_changes(args)
    params = template_params(args)
    motion_params = _numbers(args.motion_param, "--motion-param", lambda out: None)
    try:
        shape = [float(b) for b in args.shape.split(",")] if args.shape else []
    except ValueError:
        ap.error(f"--shape: expected comma-separated numbers, got {args.shape!r}")
    setting = {}
    if args.setting:
        m = re.fullmatch(r"(\d+)x(\d+)", args.setting)
        if m is None:
            ap.error(f"--setting: expected SUBSTEPSxSWEEPS such as 20x5, got {args.setting!r}")
        setting = {"substeps": int(m[1]), "iterations": int(m[2])}
    sim_fields = {}
    for option in ("--solver", "--sim"):
        try:
            fields = json.loads(getattr(args, option[2:]))
            if not isinstance(fields, dict):
                raise ValueError("expected a JSON object")
            if option == "--sim":
                taken = sorted(set(fields) & {"device", "solver", "keep_prelude", "substeps", "iterations"})
                if taken:  # those have their own options, and the result file records those
                    raise ValueError(f"{', '.join(taken)}: use --device / --solver / --keep-prelude / "
                                     "--setting")
                if not isinstance(fields.get("pinned", []), list):
                    raise ValueError("pinned: expected a list of attachment set names, e.g. [\"waistband\"]")
                SimulationConfig(**fields)  # unknown or bad fields fail here, before any simulation
                sim_fields = fields
        except (ValueError, TypeError) as e:
            _option_error(option, e)
    device = resolve_device(args.device)
    body = load_default_body()
    try:
        betas = body.full_betas(np.asarray(shape, np.float32)) if shape else None
    except WrinklesInputError as e:
        _option_error("--shape", e)
    names = args.motion.split(",")
    try:
        motions = [benchmark_motion(n, body, args.seconds, args.motion_skeleton, betas, **motion_params)
                   for n in names]
    except WrinklesInputError as e:
        _option_error("--motion-param", e)
    try:
        g, _ = build_garment(body, args.vertices, material, args.garment, betas=betas, **params)
    except WrinklesInputError as e:  # a size (edge length) or a parameter the template refuses on this body
        _option_error("--vertices / --param" if params else "--vertices", e)
    cfg = SimulationConfig(**{"device": device, "solver": json.loads(args.solver),
                              "keep_prelude": args.keep_prelude, **setting, **sim_fields})
    runs, frames = {}, {}
    t0 = time.perf_counter()
    for n, mot in zip(names, motions, strict=True):
        r = simulate_batch([SimulationJob(g, body, mot, betas)], config=cfg, failures="return")[0]
        b = betas if betas is not None else (
            None if mot.betas is None else np.asarray(mot.betas).reshape(-1)[: body.num_betas])
        runs[f"alone {n}"] = describe(r, g, device, args.worst, body.rest_mesh(b))
        if args.save and not isinstance(r, Exception):
            frames[n] = (np.asarray(r.sequence.vertices, dtype=np.float32),
                         np.asarray(r.sequence.body.vertices, dtype=np.float32), r.sequence.body.faces)
    if args.copies > 0:
        jobs = [SimulationJob(g, body, mot, betas) for _ in range(args.copies) for mot in motions]
        results = simulate_batch(jobs, config=cfg, failures="return")
        for k, r in enumerate(results):
            label = f"batch of {len(jobs)}, member {k} {names[k % len(names)]}"
            runs[label] = describe(r, g, device, args.worst)
    wall = time.perf_counter() - t0
    for label, d in runs.items():
        print(f"{label}: max strain {d.get('max_strain', float('nan')):.3f}, crossings by frame "
              f"{d.get('crossings_per_frame', d.get('error'))}", flush=True)
    for n, (x, bx, bf) in frames.items():  # one file per motion: PATH_walk.npz, ...
        np.savez_compressed(re.sub(r"(\.npz)?$", f"_{n}.npz", args.save, count=1), rest=g.rest_vertices,
                            faces=g.faces, panel_ids=g.panel_ids, panel_names=np.asarray(g.panel_names),
                            x=x, body=bx, body_faces=bf)
    first = runs[f"alone {names[0]}"]
    write_result(f"worst_edges_{device.split(':')[0]}{args.tag}", {
        "machine": machine(device), "garment": args.garment, "vertices": len(g.rest_vertices),
        "motion": args.motion,
        "seconds": args.seconds, "setting": args.setting or "default", "solver": json.loads(args.solver),
        "sim": sim_fields,
        "params": params, "material": material, "shape": shape, "motion_params": motion_params,
        "motion_skeleton": args.motion_skeleton,
        "copies": args.copies, "wall_s": wall, **first, "runs": runs,
    })


if __name__ == "__main__":
    main()
