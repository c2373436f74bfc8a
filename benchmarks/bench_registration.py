"""DeepWrinkles' registration (Lähner et al. 2018, Sec. 3.1, Eq. 1-2) against the simulation's truth.

Each chosen sequence of a dataset (made with coarse twins) is scanned by the virtual camera ring
(``sim.scans.scanner``) frame by frame and its coarse template registered to the point cloud
(``learn.deepwrinkles.registrations.register_sequence``) in several variants:

- ``default``: the garment weights (``learn.deepwrinkles.registrations.GARMENT_REGISTRATION_SETTINGS``),
  the boundary term on and tracking (each frame starts from the previous registration moved by
  the skinning's change), as DeepWrinkles' training registers;
- ``no_boundary``: the same without E_bound (``use_boundary=False``);
- ``no_tracking``: the boundary term on, each frame starting from the skinned template;
- ``paper_weights``: the paper's ω_r = ω_s = 500, ω_b = 10 on a 4 cm grid (``RegistrationConfig()``);
- ``skinned`` (the baseline, always measured): the template skinned to the frame's pose, no
  registration at all, the place every registration starts from.

Every variant sees the same scans (the noise seed of frame t is ``--seed`` + t) and is compared
with the template's true places on the simulated fine frames (through the shared sewing
pattern). Reported per variant: mean and 95th percentile of the vertex error, split into the
part along the truth surface's normal and the part across it (sliding along the surface, which
closest points cannot see), and the distance to the fine surface anywhere (off the surface: what
the scan can see); the same on the template's open border
(hems, cuffs, neckline: where E_bound acts), in a band within ``--border-cells`` registration
cells of it (edge-path distance on the rest template) and beyond that band; seconds per frame
(the scan included); and the share of template vertices holding a data pair in the last round.

    python -m benchmarks.bench_registration --data DATASET --sequences 4 --frames 4 --tag _dev
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from benchmarks.common import add_results_argument, machine, write_result

VARIANTS = {
    "default": ("garment weights, boundary term on, tracking", {}, True),
    "no_boundary": ("garment weights, boundary term off, tracking", {"use_boundary": False}, True),
    "no_tracking": ("garment weights, boundary term on, every frame from the skinned template", {}, False),
    "paper_weights": ("the paper's weights on a 4 cm grid, boundary term on, tracking", None, True),
}
"""name: (description, ``RegistrationConfig`` fields over the garment weights (None: the library's
defaults, the paper's), tracking)."""
BASELINE = "skinned"
BASELINE_DESCRIPTION = "the template skinned to the frame's pose, no registration"
GROUPS = ("all", "border", "band", "interior")
"""Vertex groups: every template vertex; those on the open border; those within the band
(border included); those beyond it."""
MM = 1000.0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True, help="dataset directory (with manifest.json)")
    ap.add_argument("--sequences", type=int, default=None,
                    help="how many sequences (default: all of --split); taken in turn from each motion "
                    "so that a few cover every motion")
    ap.add_argument("--split", default="all", help="'all' (default) or one split: train, test_id, ...")
    ap.add_argument("--frames", type=int, default=4,
                    help="frames per sequence: consecutive from --start when a chosen variant tracks "
                    "(tracking needs the frame before), else evenly spaced over the sequence")
    ap.add_argument("--start", type=int, default=0, help="first frame of the consecutive frames")
    ap.add_argument("--variants", default=",".join(VARIANTS),
                    help=f"comma-separated, of {', '.join(VARIANTS)} (the skinned baseline always runs)")
    ap.add_argument("--border-cells", type=float, default=2.0,
                    help="width of the border band in registration cells (RegistrationConfig.cell)")
    ap.add_argument("--seed", type=int, default=0, help="scan noise seed (frame t uses seed + t)")
    ap.add_argument("--device", default="cpu", help="Warp device of the scans and skinning")
    ap.add_argument("--tag", default="", help="suffix of the result file's name (--tag _dev: "
                    "registration_cpu_dev.json)")
    add_results_argument(ap)
    args = ap.parse_args(argv)
    names = [v for v in args.variants.split(",") if v]
    unknown = [v for v in names if v not in VARIANTS]
    if unknown or not names:
        ap.error(f"--variants: unknown {unknown or 'empty list'}; expected some of {', '.join(VARIANTS)}")
    args.variants = names
    if args.frames < 1 or (args.sequences is not None and args.sequences < 1) or args.start < 0:
        ap.error("--frames and --sequences must be >= 1, --start >= 0")
    if not (args.data / "manifest.json").is_file():
        ap.error(f"--data: {args.data} has no manifest.json (not a dataset directory)")
    return args


def pick_sequences(manifest: dict, split: str, count: int | None) -> list[str]:
    """Sequence ids of ``split`` with a coarse twin, ``count`` of them (None: all) taken in turn
    from each motion (manifest order within a motion) so that a few cover every motion."""
    by_motion: dict[str, list[str]] = defaultdict(list)
    for sid, e in manifest["sequences"].items():
        if (split == "all" or e.get("split") == split) and e.get("coarse_vertices"):
            by_motion[str(e.get("motion"))].append(sid)
    order = []
    queues = list(by_motion.values())
    while any(queues):
        order += [q.pop(0) for q in queues if q]
    return order if count is None else order[:count]


def pick_frames(T: int, count: int, consecutive: bool, start: int) -> np.ndarray:
    """``count`` frame indices of a T-frame sequence: consecutive from ``start`` (shifted back to
    fit), or evenly spaced over all T."""
    count = min(count, T)
    if consecutive:
        first = min(start, T - count)
        return np.arange(first, first + count)
    return np.unique(np.round(np.linspace(0, T - 1, count)).astype(np.int64))


def load_sequence(root: Path, sid: str) -> tuple[dict, object]:
    """The sequence's arrays (images left out) and its ``SequenceFile``."""
    from sim.datasets.storage import SequenceFile, sequence_path

    sf = SequenceFile(sequence_path(root, sid))
    return {k: sf[k] for k in sf.keys() if not k.startswith("images")}, sf


def vertex_groups(rest: np.ndarray, faces: np.ndarray, width: float) -> dict[str, np.ndarray]:
    """Boolean masks (V,) of ``GROUPS`` on the template: the open border (``boundary_vertices``),
    the band within ``width`` [m] of it along the rest template's edges, and the rest."""
    from sim.garments.hems import boundary_vertices, distance_to_boundary

    border = np.zeros(len(rest), bool)
    border[boundary_vertices(faces)] = True
    band = distance_to_boundary(rest, faces) <= width
    band |= border
    return {"all": np.ones(len(rest), bool), "border": border, "band": band, "interior": ~band}


def surface_distance(vertices: np.ndarray, fine: np.ndarray, fine_faces: np.ndarray) -> np.ndarray:
    """Per frame and vertex [mm] (n, V): the distance of each vertex to the nearest point of the
    simulated fine garment's surface in that frame (what a scan of it can measure)."""
    from sim.dressing import bind_to_surface

    out = np.empty(np.shape(vertices)[:2])
    for i, (v, f) in enumerate(zip(vertices, fine, strict=True)):
        out[i] = np.linalg.norm(bind_to_surface(v, f, fine_faces, device="cpu", max_dist=10.0).offset, axis=1)
    return out * MM


def error_parts(vertices: np.ndarray, truth: np.ndarray, normals: np.ndarray, fine: np.ndarray,
                fine_faces: np.ndarray) -> dict[str, np.ndarray]:
    """Per frame and vertex [mm] (n, V): the distance to the truth (``total``), its part along
    the truth template's unit vertex normal (``normal``, absolute) and across it (``tangential``:
    sliding along the surface), and the distance to the fine surface anywhere (``surface``)."""
    d = (np.asarray(vertices, np.float64) - truth) * MM
    along = np.sum(d * normals, axis=-1)
    total = np.linalg.norm(d, axis=-1)
    return {"total": total, "normal": np.abs(along),
            "tangential": np.sqrt(np.maximum(total ** 2 - along ** 2, 0.0)),
            "surface": surface_distance(vertices, fine, fine_faces)}


def group_figures(parts: dict[str, np.ndarray], mask: np.ndarray) -> dict:
    """Mean, 95th percentile and RMS [mm] of each error part (``error_parts``) of the vertices in
    ``mask`` over all frames."""
    out = {"vertices": int(mask.sum())}
    if not mask.any():
        return out
    for key, e in parts.items():
        sel = e[:, mask]
        out[f"{key}_mean_mm"] = float(sel.mean())
        out[f"{key}_p95_mm"] = float(np.percentile(sel, 95))
        out[f"{key}_rms_mm"] = float(np.sqrt(np.mean(sel ** 2)))
    return out


def figures(parts: dict[str, np.ndarray], groups: dict[str, np.ndarray]) -> dict:
    """``group_figures`` of every vertex group."""
    return {g: group_figures(parts, groups[g]) for g in GROUPS}


def registration_config(name: str):
    """The ``RegistrationConfig`` of variant ``name``."""
    from learn.deepwrinkles.registrations import garment_registration
    from sim.scans.registration import RegistrationConfig

    fields = VARIANTS[name][1]
    return RegistrationConfig() if fields is None else dataclasses.replace(garment_registration(), **fields)


def run_variant(seq: dict, body, rig, frames: np.ndarray, name: str, args) -> tuple:
    """Register ``frames`` of the sequence with variant ``name``: (``RegisteredSequence``, wall
    seconds, process CPU seconds)."""
    from learn.deepwrinkles.registrations import register_sequence

    t0, c0 = time.perf_counter(), time.process_time()
    reg = register_sequence(seq, body, frames=frames, registration_config=registration_config(name),
                            tracking=VARIANTS[name][2], seed=args.seed, device=args.device, rig=rig)
    return reg, time.perf_counter() - t0, time.process_time() - c0


def scan_seconds(seq: dict, body, frame: int, args) -> tuple[float, int]:
    """Wall seconds of one scan of ``frame`` (the share of a registered frame's time that is the
    scanner's) and its point count."""
    from sim.scans.scanner import scan_garment

    betas = np.asarray(seq["body/betas"], np.float32).reshape(-1)[: body.num_betas]
    pose = body.pose(betas, np.asarray(seq["body/poses"])[frame:frame + 1],
                     np.asarray(seq["body/trans"])[frame:frame + 1], device=args.device)
    t0 = time.perf_counter()
    scan = scan_garment(np.asarray(seq["fine/vertices"])[frame], np.asarray(seq["fine/faces"], np.int32),
                        np.asarray(seq["body/joints"], np.float64)[frame, 0], body_vertices=pose.vertices[0],
                        body_faces=pose.faces, seed=args.seed + frame, device=args.device)
    return time.perf_counter() - t0, len(scan.points)


def run_sequence(root: Path, sid: str, entry: dict, manifest: dict, args) -> tuple[dict, dict]:
    """Every variant on one sequence: (its JSON row, per variant the error parts and masks that
    the summary pools)."""
    from learn.deepwrinkles.registrations import sequence_rig, template_truth
    from sim.bodies import load_body
    from sim.datasets.storage import body_model_name
    from sim.geometry.frames import vertex_normals

    seq, sf = load_sequence(root, sid)
    body = load_body(body_model_name(sf, manifest) or "default")
    T = int(np.asarray(seq["fine/vertices"]).shape[0])
    frames = pick_frames(T, args.frames, any(VARIANTS[v][2] for v in args.variants), args.start)
    rig = sequence_rig(seq, body)
    faces = rig.faces
    cell = registration_config(args.variants[0]).cell
    groups = vertex_groups(rig.rest, faces, args.border_cells * cell)
    fine_faces = np.asarray(seq["fine/faces"])
    t0 = time.perf_counter()
    truth = template_truth(seq).evaluate(fine_faces, np.asarray(seq["fine/vertices"])[frames])
    setup_s = time.perf_counter() - t0  # what register_sequence repeats once per call, after its frames
    normals = vertex_normals(truth, faces, device="cpu")
    scan_s, points = scan_seconds(seq, body, int(frames[0]), args)
    fine = np.asarray(seq["fine/vertices"])[frames]
    pooled = {BASELINE: error_parts(rig.skinned(frames), truth, normals, fine, fine_faces)}
    row = {"id": sid, "split": entry.get("split"), "motion": entry.get("motion"),
           "material": entry.get("material"), "frames": frames.tolist(),
           "fine_vertices": entry.get("vertices"),
           "template_vertices": len(rig.rest), "scan_points": points, "scan_s": scan_s,
           "setup_s": setup_s,
           "group_vertices": {g: int(m.sum()) for g, m in groups.items()}, "variants": {}}
    row["variants"][BASELINE] = _variant_row(pooled[BASELINE], groups)
    for name in args.variants:
        reg, wall, cpu = run_variant(seq, body, rig, frames, name, args)
        np.testing.assert_allclose(reg.truth, truth, atol=1e-6)  # the same truth for every variant
        pooled[name] = error_parts(reg.vertices, truth, normals, fine, fine_faces)
        row["variants"][name] = _variant_row(pooled[name], groups, wall=wall - setup_s, cpu=cpu - setup_s,
                                             frames=len(frames),
                                             paired=reg.pairs / len(rig.rest))
        e = row["variants"][name]
        print(f"{sid} {row['motion']:<12s} {name:<12s} mean {e['all']['total_mean_mm']:6.2f} mm  "
              f"border {e['border'].get('total_mean_mm', float('nan')):6.2f} mm  "
              f"{e['s_per_frame']:5.2f} s/frame  paired {100 * e['paired_share']:5.1f} %", flush=True)
    return row, {"parts": pooled, "groups": groups}


def _variant_row(parts: dict, groups: dict, *, wall: float | None = None, cpu: float | None = None,
                 frames: int = 0, paired: np.ndarray | None = None) -> dict:
    """One variant's figures on one sequence: ``figures`` plus, for a registration, its time and
    paired share (mean over frames, and per frame)."""
    out = figures(parts, groups)
    out["per_frame_mean_mm"] = [round(float(x), 3) for x in parts["total"].mean(axis=1)]
    if wall is not None:
        out.update(s_per_frame=wall / frames, cpu_s_per_frame=cpu / frames,
                   paired_share=float(np.mean(paired)),
                   paired_share_per_frame=[round(float(p), 4) for p in paired])
    return out


def pool(per_sequence: list[dict], rows: list[dict], names: list[str]) -> dict:
    """Figures over every sequence and frame together, per variant (the baseline first)."""
    out = {}
    for name in [BASELINE, *names]:
        parts = {k: np.concatenate([s["parts"][name][k].ravel() for s in per_sequence])[None]
                 for k in ("total", "normal", "tangential", "surface")}
        groups = {g: np.concatenate([np.broadcast_to(s["groups"][g], s["parts"][name]["total"].shape).ravel()
                                     for s in per_sequence]) for g in GROUPS}
        out[name] = figures(parts, groups)
        out[name]["description"] = BASELINE_DESCRIPTION if name == BASELINE else VARIANTS[name][0]
        if name != BASELINE:
            runs = [r["variants"][name] for r in rows]
            frames = np.array([len(r["frames"]) for r in rows], float)
            for key in ("s_per_frame", "cpu_s_per_frame", "paired_share"):
                out[name][key] = float(np.sum([v[key] for v in runs] * frames) / frames.sum())
    return out


def table(summary: dict) -> str:
    """The pooled figures as a markdown table [mm]."""
    head = ("| variant | mean | p95 | normal mean | tangential mean | off surface mean | border mean "
            "| band mean | band p95 "
            "| interior mean | s/frame | paired |")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for name, f in summary.items():
        def cell(group, key, f=f):
            v = f[group].get(key)
            return "-" if v is None else f"{v:.2f}"
        timing = "- | -"
        if "s_per_frame" in f:
            timing = f"{f['s_per_frame']:.2f} | {100 * f['paired_share']:.1f} %"
        lines.append(f"| {name} | {cell('all', 'total_mean_mm')} | {cell('all', 'total_p95_mm')} "
                     f"| {cell('all', 'normal_mean_mm')} | {cell('all', 'tangential_mean_mm')} "
                     f"| {cell('all', 'surface_mean_mm')} "
                     f"| {cell('border', 'total_mean_mm')} | {cell('band', 'total_mean_mm')} "
                     f"| {cell('band', 'total_p95_mm')} | {cell('interior', 'total_mean_mm')} | {timing} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    from sim.datasets.storage import read_manifest
    from sim.device import resolve_device
    from sim.scans.scanner import ScanConfig

    args = parse_args(argv)
    args.device = resolve_device(args.device)
    manifest = read_manifest(args.data)
    ids = pick_sequences(manifest, args.split, args.sequences)
    if not ids:
        raise SystemExit(f"{args.data}: no sequence of split {args.split!r} has a coarse twin")
    rows, pooled = [], []
    t0 = time.perf_counter()
    for sid in ids:
        row, parts = run_sequence(args.data, sid, manifest["sequences"][sid], manifest, args)
        rows.append(row)
        pooled.append(parts)
    summary = pool(pooled, rows, args.variants)
    frames = sum(len(r["frames"]) for r in rows)
    print(f"\nvertex error against the simulation [mm], pooled over {len(rows)} sequences x {frames} frames\n"
          f"{table(summary)}\n", flush=True)
    first = rows[0]
    write_result(f"registration_{args.device.split(':')[0]}{args.tag}", {
        "machine": machine(args.device),
        "dataset": {"path": str(args.data.resolve()), "split": args.split, "sequences": ids,
                    "garments": sorted({manifest["sequences"][s].get("garment") for s in ids}),
                    "fine_vertices": sorted({r["fine_vertices"] for r in rows}),
                    "template_vertices": sorted({r["template_vertices"] for r in rows})},
        "sizes": {"sequences": len(rows), "frames_per_sequence": args.frames,
                  "frames": "consecutive" if any(VARIANTS[v][2] for v in args.variants) else "evenly spaced",
                  "group_vertices": first["group_vertices"], "border_cells": args.border_cells,
                  "border_band_m": args.border_cells * registration_config(args.variants[0]).cell},
        "configs": {"scan": dataclasses.asdict(ScanConfig()), "seed": args.seed,
                    "registration": {v: dataclasses.asdict(registration_config(v)) for v in args.variants},
                    "tracking": {v: VARIANTS[v][2] for v in args.variants}},
        "figures": summary,
        "per_sequence": rows,
        "wall_s": time.perf_counter() - t0,
        "table": table(summary),
        "method": "errors [mm] against the template's true places on the simulated fine frames; normal: "
                  "the part along the truth template's vertex normal, tangential: the rest, surface: "
                  "distance to the closest point of the fine frame's surface; s/frame: "
                  "register_sequence's wall time (scan + registration) over its frames; paired: data pairs "
                  "kept in a frame's last round over template vertices",
    }, args.results)


if __name__ == "__main__":
    main()
