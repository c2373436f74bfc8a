"""Where a kernel's instructions and stall samples go, per source line and per file, from an
Nsight Compute report's source page (development aid, docs/BENCHMARKS.md session 33).

On the device machine (``ncu`` at ``/usr/local/cuda/bin/ncu``), with Warp's line info on so the
SASS maps to the Python source (``wp.config.lineinfo = True`` before the kernels compile)::

    ncu --kernel-name regex:solve_color_p8_l16_fused --launch-skip 3000 --launch-count 1 \\
        --set full --import-source yes -f -o solve python run_with_lineinfo.py ...
    ncu --import solve.ncu-rep --page source --print-source cuda,sass --csv > solve.csv

then ``python -m benchmarks.ncu_lines solve.csv --top 40``. Without line info (a report
printed with ``--print-source sass``) it gives the totals and the instruction mix only.
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections import Counter, defaultdict
from pathlib import Path

SAMPLES = "Warp Stall Sampling (All Samples)"
EXECUTED = "Instructions Executed"


def _number(text: str) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return 0.0


def _mnemonic(text: str) -> str:
    """``FFMA`` of ``@!P0 FFMA.FTZ R1, ...``."""
    words = text.split()
    if words and words[0].startswith("@"):
        words = words[1:]
    return words[0].split(".")[0] if words else ""


def read_report(path: Path) -> tuple[dict, list]:
    """Per (file, line): [stall samples, warp instructions executed, SASS instructions, source];
    and every SASS row as (mnemonic, samples, executed)."""
    lines: dict = defaultdict(lambda: [0.0, 0.0, 0, ""])
    sass: dict = {}
    header = None
    current_file, current_line = "", ""
    with open(path, newline="") as f:
        for row in csv.reader(f):
            if not row:
                continue
            if row[0] in ("File Path", "File Name"):
                current_file = Path(row[1]).name
                continue
            if row[0] in ("Line No", "Address"):
                header = row
                continue
            if header is None or len(row) != len(header):
                continue
            if header[0] == "Address":  # a SASS-only report
                sass[row[0]] = (_mnemonic(row[1]), _number(row[header.index(SAMPLES)]),
                                _number(row[header.index(EXECUTED)]))
                continue
            samples = header.index(SAMPLES)
            executed = header.index(EXECUTED)
            if row[0]:  # a source line's summary row
                current_line = row[0]
                entry = lines[(current_file, current_line)]
                entry[0] += _number(row[samples])
                entry[1] += _number(row[executed])
                entry[3] = row[1]
            elif row[2] not in ("", "..."):
                lines[(current_file, current_line)][2] += 1
                # an inlined instruction can be listed under more than one source line: by address
                sass[row[2]] = (_mnemonic(row[3]), _number(row[samples]), _number(row[executed]))
    return dict(lines), list(sass.values())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("report", type=Path, help="CSV of ncu --page source --csv")
    parser.add_argument("--top", type=int, default=30, help="source lines to list (default: 30)")
    args = parser.parse_args(argv)
    if not args.report.is_file():
        print(f"ncu_lines: {args.report}: no such file", file=sys.stderr)
        return 2
    lines, sass = read_report(args.report)
    if not sass:
        print(f"ncu_lines: {args.report}: no SASS rows (not an ncu source-page CSV?)", file=sys.stderr)
        return 2
    total_s = sum(s for _, s, _ in sass) or 1.0
    total_e = sum(e for _, _, e in sass) or 1.0
    print(f"SASS instructions {len(sass)}, executed {sum(e > 0 for _, _, e in sass)}; "
          f"warp instructions executed {total_e:.0f}; stall samples {total_s:.0f}")
    mix = Counter()
    for mnemonic, _, e in sass:
        mix[mnemonic] += e
    shares = ", ".join(f"{m} {100 * e / total_e:.1f}%" for m, e in mix.most_common(10))
    print(f"mix (warp instructions): {shares}")
    if lines:
        files: dict = defaultdict(lambda: [0.0, 0.0, 0])
        for (name, _), (s, e, n, _) in lines.items():
            files[name][0] += s
            files[name][1] += e
            files[name][2] += n
        print(f"\n{'file':24s} {'samples':>8s} {'executed':>9s} {'SASS':>5s}")
        for name, (s, e, n) in sorted(files.items(), key=lambda kv: -kv[1][0]):
            print(f"{name:24s} {100 * s / total_s:7.1f}% {100 * e / total_e:8.1f}% {n:5d}")
        print(f"\n{'file':18s} {'line':>5s} {'samples':>8s} {'executed':>9s} {'SASS':>5s}  source")
        for (name, line), (s, e, n, src) in sorted(lines.items(), key=lambda kv: -kv[1][0])[:args.top]:
            print(f"{name[:18]:18s} {line:>5s} {100 * s / total_s:7.1f}% {100 * e / total_e:8.1f}% {n:5d}  "
                  f"{src.strip()[:70]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
