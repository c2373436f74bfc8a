"""GSNet's Tables 1-3 on our test splits, from ``wrinkles evaluate`` outputs.

Reads the evaluation folders ``scripts/train_gsnet.sh`` writes (``EVAL/<row>-<split>/metrics.json``)
and writes the tables (markdown) and their JSON:

    python -m benchmarks.gsnet_tables EVAL --out /tmp/gsnet_tables.md \
        --json benchmarks/results/gsnet_tables.json --unseen flared_skirt,hoodie

- Table 1 (GSNet Table 1): every row on test_id and test_ood (with linear blend skinning of the
  body's weights carried to the garment, what GSNet learns to improve on; it and every GSNet row
  end with GSNet's projection out of the body, ``model.projection_margin``, skinned_mlp does
  not), with GSNet's metrics: vertex error, edge elongation / compression (mean |l/l0 - 1|), the
  bending angle between vertex normals, the collision rate; the simulation's own physics columns
  as the last row.
- Table 2 (GSNet Table 2): the same by garment category, seen designs and the held-out ones
  (``--unseen``: in test_ood only).
- Table 3 (GSNet Table 3): GSNet's ablations, without temporal input, without physical
  regression, without learned joint edges; and 4 joint edges a vertex (``model.joint_topk``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROWS = [
    ("gsnet", "GSNet"),
    ("skinned_mlp", "skinning + displacement MLP (skinned_mlp)"),
    ("lbs", "linear blend skinning (the body's weights, nothing learned; GSNet's projection)"),
    ("coarse", "CVAE coarse model (skeleton_cvae)"),
]
ABLATIONS = [
    ("gsnet", "GSNet"),
    ("gsnet_notemp", "without temporal input"),
    ("gsnet_noreg", "without physical regression (the projection kept)"),
    ("gsnet_noedges", "without learned joint edges (body skinning weights)"),
    ("gsnet_top4", "4 joint edges a vertex (joint_topk = 4)"),
]
METRICS = [
    ("ev", "Euclidean error [mm]", 1e3, None),
    ("edge_abs", "edge elong./compr. [%]", 100.0, "edge_abs_gt"),
    ("normal_angle", "normal angle [°]", 180.0 / np.pi, "normal_angle_gt"),
    ("collision", "collision [%]", 100.0, "collision_gt"),
]
"""(key, column, scale, the simulation's key of the same measure)."""


def collect(root: Path) -> dict:
    """{split: {row: {"summary": {...}, "garments": {category: {metric: mean}}}}}."""
    out: dict = {}
    for d in sorted(p for p in root.iterdir() if (p / "metrics.json").is_file()):
        rec = json.loads((d / "metrics.json").read_text())
        row = d.name.rsplit("-", 1)[0]
        by_garment: dict[str, dict[str, list[float]]] = {}
        for s in rec["sequences"]:
            for k, v in s["metrics"].items():
                by_garment.setdefault(s["garment"], {}).setdefault(k, []).append(v)
        out.setdefault(rec["split"], {})[row] = {
            "summary": rec["summary"], "sequences": len(rec["sequences"]),
            "garments": {g: {k: float(np.mean(v)) for k, v in m.items()} for g, m in by_garment.items()},
            "counts": {g: len(next(iter(m.values()))) for g, m in by_garment.items()}}
    return out


def _cells(values: dict, simulation: bool = False) -> str:
    cells = []
    for key, _, scale, gt in METRICS:
        k = gt if simulation else key
        cells.append(f"{values[k] * scale:.3g}" if k is not None and k in values else "–")
    return " | ".join(cells)


def _header(first: str) -> list[str]:
    return [f"| {first} | " + " | ".join(m[1] for m in METRICS) + " |", "|---|" + "---|" * len(METRICS)]


def table1(tables: dict) -> list[str]:
    lines = []
    for split in ("test_id", "test_ood"):
        rows = tables.get(split, {})
        if not rows:
            continue
        lines += [f"### Table 1: {split}", "", *_header("method")]
        for key, label in ROWS:
            if key in rows:
                lines.append(f"| {label} | {_cells(rows[key]['summary'])} |")
        ref = next((rows[k]["summary"] for k, _ in ROWS if k in rows), None)
        if ref is not None:
            lines.append(f"| simulation | {_cells(ref, simulation=True)} |")
        lines.append("")
    return lines


def table2(tables: dict, unseen: set[str]) -> list[str]:
    lines = []
    for split in ("test_id", "test_ood"):
        rows = tables.get(split, {})
        garments = sorted({g for r in rows.values() for g in r["garments"]})
        if not garments:
            continue
        lines += [f"### Table 2: by garment, {split}", "", *_header("garment / method")]
        for g in garments:
            n = next((r["counts"][g] for r in rows.values() if g in r["counts"]), 0)
            tag = " (unseen design)" if g in unseen else ""
            for key, label in ROWS:
                if key in rows and g in rows[key]["garments"]:
                    lines.append(f"| {g}{tag}, {n} seq.: {label} | {_cells(rows[key]['garments'][g])} |")
        lines.append("")
    return lines


def table3(tables: dict) -> list[str]:
    lines = []
    for split in ("test_id", "test_ood"):
        rows = tables.get(split, {})
        present = [(k, label) for k, label in ABLATIONS if k in rows]
        if len(present) < 2:
            continue
        lines += [f"### Table 3: ablations, {split}", "", *_header("GSNet")]
        lines += [f"| {label} | {_cells(rows[k]['summary'])} |" for k, label in present]
        lines.append("")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.gsnet_tables", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("eval", type=Path, help="folder of <row>-<split>/ evaluation outputs")
    ap.add_argument("--out", type=Path, help="markdown file to write (default: print)")
    ap.add_argument("--json", type=Path, help="JSON of the collected figures")
    ap.add_argument("--unseen", default="", help="garment categories no model trained on (comma separated)")
    args = ap.parse_args(argv)
    if not args.eval.is_dir():
        print(f"gsnet_tables: {args.eval}: no such folder", file=__import__("sys").stderr)
        return 2
    tables = collect(args.eval)
    unseen = {g for g in args.unseen.split(",") if g}
    text = "\n".join(table1(tables) + table2(tables, unseen) + table3(tables))
    if args.out:
        args.out.write_text(text + "\n")
    else:
        print(text)
    if args.json:
        args.json.write_text(json.dumps(tables, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
