"""Guo et al. 2024 Tables 1 and 2 on our test splits, from ``wrinkles evaluate`` outputs.

Reads the evaluation folders that ``scripts/train_pretrained.sh`` writes (``EVAL/<garment>-<row>-<split>/
metrics.json``), averages the five sampling seeds of our model (mean and standard deviation), and
writes the tables (markdown) plus a figure:

    python -m benchmarks.wrinkle_tables EVAL --out docs/WRINKLES_TABLES.md \
        --figure docs/images/wrinkle_tables.png \
        --json benchmarks/results/wrinkle_tables.json

Table 1 (in distribution, ``test_id``, on the data's smoothed base): Ev, Ecd, normal-map FD.
Table 2 (out of distribution, ``test_ood``, on the skeleton CVAE's base from the body): the same.
Rows: base mesh alone, the LFGD-style displacement regressor, ours with normal / strain-tensor /
strain-norm conditioning (t-shirt), ours (skirt), DeepWrinkles (``scripts/train_deepwrinkles.sh``'s
evaluations). Also the flicker ratio, the DDIM step sweep and DeepWrinkles' own Table 1 (pixel
errors of its normal maps by temporal term and LR input).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROWS = [
    ("base", "base mesh alone"),
    ("coarse", "CVAE base alone (body -> base)"),
    ("lfgd", "LFGD-style global displacement regressor"),
    ("normal", "ours, normal conditioning"),
    ("tensor", "ours, strain-tensor conditioning"),
    ("ours", "ours, strain-norm conditioning (shipped)"),
    ("deepwrinkles", "DeepWrinkles (Lähner et al. 2018; global shape from the body)"),
    ("dw_release", "DeepWrinkles, shipped size (16 filters, k = 200, 2 LSTM layers)"),
    ("dw_upper", "DeepWrinkles, upper-body joints as controls (Sec. 5.3)"),
]
METRICS = [
    ("ev", "Ev [mm]", 1e3),
    ("ecd", "Ecd [mm²]", 1e6),
    ("normal_fd", "normal-map FD", 1.0),
    ("flicker_ratio", "flicker ratio", 1.0),
    ("spectrum_distance", "spectrum dist.", 1.0),
]
MAP_METRICS = [
    ("nm_l1", "Data (L1)", 100.0),
    ("nm_l2", "L2", 100.0),
    ("nm_temporal", "Temporal (Eq. 4)", 100.0),
]
"""DeepWrinkles' Table 1 rows: pixel errors of its HR normal maps (x 100, as the paper prints them)."""
MAP_COLUMNS = [
    ("dw_truth", "Eq. 4 / true places"),
    ("dw_registration", "Eq. 4 / Registr."),
    ("dw_notemp_registration", "no temp / Registr."),
    ("dw_bs500", "Eq. 4 / BS 500"),
    ("dw_bs200", "Eq. 4 / BS 200"),
    ("deepwrinkles", "Eq. 4 / Regre."),
    ("dw_linear", "Eq. 4 / linear Regre."),
    ("dw_notemp", "no temp / Regre."),
]
"""DeepWrinkles' Table 1 columns: (evaluation row, training temporal term / input of the LR map)."""


def _load(d: Path) -> dict | None:
    f = d / "metrics.json"
    return json.loads(f.read_text()) if f.exists() else None


def collect(root: Path) -> dict:
    """{garment: {split: {row: {metric: (mean, std, n)}}}} and the step sweep."""
    out: dict = {}
    for d in sorted(root.iterdir()):
        rec = _load(d)
        if rec is None:
            continue
        name, split = d.name.rsplit("-", 1)[0], rec["split"]
        garment, row = name.split("-", 1)
        if row.startswith("ours-steps"):
            out.setdefault("steps", {})[int(row[len("ours-steps") :])] = rec["summary"]
            continue
        if row.startswith("ours-s"):
            row = "ours"
        out.setdefault(garment, {}).setdefault(split, {}).setdefault(row, []).append(rec["summary"])
    for garment, splits in out.items():
        if garment == "steps":
            continue
        for rows in splits.values():
            for row, runs in rows.items():
                rows[row] = {
                    k: (
                        float(np.mean([r[k] for r in runs if k in r])),
                        float(np.std([r[k] for r in runs if k in r])),
                        len(runs),
                    )
                    for k, _, _ in METRICS + MAP_METRICS
                    if any(k in r for r in runs)
                }
    return out


def _cell(v, scale: float) -> str:
    mean, std, n = v
    return f"{mean * scale:.3g} ± {std * scale:.2g}" if n > 1 else f"{mean * scale:.3g}"


def markdown(tables: dict) -> str:
    lines = []
    for garment in sorted(k for k in tables if k != "steps"):
        for split, title in (
            ("test_id", "Table 1 — in distribution (data's base)"),
            ("test_ood", "Table 2 — out of distribution (CVAE base from the body)"),
        ):
            rows = tables[garment].get(split)
            if not rows:
                continue
            lines += [
                f"### {garment}: {title}",
                "",
                "| method | " + " | ".join(m[1] for m in METRICS) + " |",
                "|---|" + "---|" * len(METRICS),
            ]
            for key, label in ROWS:
                if key in rows:
                    seeds = rows[key].get("ev", (0, 0, 1))[2]
                    lines.append(
                        f"| {label}{f' ({seeds} seeds)' if seeds > 1 else ''} | "
                        + " | ".join(_cell(rows[key][m], s) if m in rows[key] else "–" for m, _, s in METRICS)
                        + " |"
                    )
            lines.append("")
    lines += map_table(tables)
    if "steps" in tables:
        lines += [
            "### DDIM steps (t-shirt, test_id)",
            "",
            "| steps | Ev [mm] | Ecd [mm²] | normal-map FD |",
            "|---|---|---|---|",
        ]
        for n, s in sorted(tables["steps"].items(), reverse=True):
            lines.append(
                f"| {n} | {s['ev'] * 1e3:.3g} | {s['ecd'] * 1e6:.3g} | "
                f"{s.get('normal_fd', float('nan')):.3g} |"
            )
        lines.append("")
    return "\n".join(lines)


def map_table(tables: dict) -> list[str]:
    """Lähner et al.'s Table 1 on our test_id split (markdown lines; none without DeepWrinkles
    rows): pixel errors of the predicted HR normal maps for models trained with and without Eq. 4's
    temporal term and for the LR map's inputs (registration, blend shapes of 500 / 200 components,
    regression)."""
    lines = []
    for garment in sorted(k for k in tables if k != "steps"):
        rows = tables[garment].get("test_id", {})
        cols = [(key, label) for key, label in MAP_COLUMNS if key in rows and "nm_l1" in rows[key]]
        if not cols:
            continue
        lines += [f"### {garment}: DeepWrinkles' Table 1 (pixel errors x 100, test_id)", "",
                  "| | " + " | ".join(label for _, label in cols) + " |", "|---|" + "---|" * len(cols)]
        for m, label, scale in MAP_METRICS:
            lines.append(f"| {label} | " + " | ".join(
                _cell(rows[key][m], scale) if m in rows[key] else "–" for key, _ in cols) + " |")
        lines.append("")
    return lines


def figure(tables: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    garments = sorted(k for k in tables if k != "steps")
    fig, axes = plt.subplots(len(garments), 3, figsize=(13, 3.4 * len(garments)), squeeze=False)
    for gi, g in enumerate(garments):
        for mi, (m, label, scale) in enumerate(METRICS[:3]):
            ax = axes[gi, mi]
            for si, (split, color) in enumerate((("test_id", "#4C72B0"), ("test_ood", "#DD8452"))):
                rows = tables[g].get(split, {})
                keys = [k for k, _ in ROWS if k in rows and m in rows[k]]
                x = np.array([[k for k, _ in ROWS].index(k) for k in keys]) + (si - 0.5) * 0.38
                ax.bar(
                    x,
                    [rows[k][m][0] * scale for k in keys],
                    0.38,
                    yerr=[rows[k][m][1] * scale for k in keys],
                    color=color,
                    label=split,
                )
            ax.set_xticks(range(len(ROWS)), [k for k, _ in ROWS], rotation=30)
            ax.set_title(f"{g}: {label}")
            if mi == 0:
                ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("eval_root")
    p.add_argument("--out", required=True)
    p.add_argument("--figure")
    p.add_argument("--json")
    a = p.parse_args(argv)
    tables = collect(Path(a.eval_root))
    Path(a.out).write_text(markdown(tables))
    if a.json:
        Path(a.json).write_text(json.dumps(tables, indent=1))
    if a.figure:
        figure(tables, Path(a.figure))
    print(markdown(tables))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
