"""The instruction budget of the batched target (docs/BENCHMARKS.md, session 53): how many
instructions one particle-sweep may execute at all for a batch to reach its garment-frames/s,
against what the contact-free sweep executes (Nsight Compute on one colour launch of
``benchmarks.batch_floor``).

A GPU issues at most one warp instruction per scheduler per cycle: ``SMs x 4 x 32`` thread
instructions per cycle, and Hopper's FP32 pipes take one FP32 instruction per lane per cycle, so
the same rate bounds the FP32 arithmetic (FFMA, FMUL, FADD). At a target of ``T`` garment-frames
per second, a garment of ``V`` vertices swept ``S`` times a frame leaves every particle-sweep
``SMs x 128 x f / (T x V x S)`` thread instructions, for everything a frame does (contact,
detection and the rest amortised over it). The report's executed thread instructions and FP32
instructions divided by the launch's particles (one colour of the batch) are what the sweep
alone needs; at full issue they give the ceilings ``SMs x 128 x f / (V x S x instructions)``.

Usage (the ncu text from ``ncu --set full --metrics smsp__sass_thread_inst_executed.sum,
smsp__sass_thread_inst_executed_op_ffma_pred_on.sum,..._fmul_...,..._fadd_...`` printed as
details, the floor JSON of the same batch)::

    python -m benchmarks.ncu_budget benchmarks/results/ncu_floor_threads_s53.txt \\
        benchmarks/results/batch_floor_cuda_s53_terms.json --batch 256 --tag _s53_threads
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from benchmarks.common import write_result

ISSUE_PER_SM = 4 * 32
"""Thread instructions an SM issues per cycle at most (4 schedulers, a warp instruction each)."""

FP32_OPS = ("ffma", "fmul", "fadd")

_METRICS = {
    "thread_instructions": r"smsp__sass_thread_inst_executed\.sum",
    **{op: rf"smsp__sass_thread_inst_executed_op_{op}_pred_on\.sum" for op in FP32_OPS},
    "sm_count": r"# SMs",
    "sm_ghz": r"SM Frequency",
    "duration_us": r"Duration",
    "issue_busy_pct": r"Issue Slots Busy",
    "registers": r"Registers Per Thread",
    "achieved_occupancy_pct": r"Achieved Occupancy",
}


def read_ncu(text: str, source: str = "report") -> dict:
    """The figures ``_METRICS`` names from an Nsight Compute details page of **one** kernel
    launch (the first value of each). Raises ValueError naming ``source`` and what is missing,
    or when the page holds more than one launch."""
    out = {}
    if len(re.findall(r"^\s*Section: GPU Speed Of Light Throughput", text, re.M)) > 1:
        raise ValueError(f"{source}: more than one kernel launch in the report; "
                         "profile one (--launch-count 1)")
    for key, name in _METRICS.items():
        m = re.search(rf"^\s*{name}\s+(?:\S+\s+)?([\d,]+(?:\.\d+)?)\s*$", text, re.M)
        if m is None:
            raise ValueError(f"{source}: no '{name.replace(chr(92), '')}' in the report "
                             "(run ncu with --set full and the metrics in this module's docstring)")
        out[key] = float(m.group(1).replace(",", ""))
    unit = re.search(r"^\s*SM Frequency\s+(\S+)\s", text, re.M).group(1).lower()
    out["sm_ghz"] /= {"ghz": 1.0, "mhz": 1e3, "hz": 1e9}.get(unit, 1.0)  # ncu picks the unit it prints
    return out


def budget(ncu: dict, particles_per_launch: float, vertices: int, sweeps: int, batch: int,
           target: float) -> dict:
    """The budget and the ceilings (module docstring) from one launch's ``ncu`` figures
    (``read_ncu``) over ``particles_per_launch`` particles (the command takes a colour's mean
    size: the profiled colour is not known; the three differ by well under 1 %), for garments
    of ``vertices`` swept
    ``sweeps`` times a frame, batches of ``batch`` garments and ``target`` garment-frames/s."""
    rate = ncu["sm_count"] * ISSUE_PER_SM * ncu["sm_ghz"] * 1e9  # thread instructions / s
    per_sweep = ncu["thread_instructions"] / particles_per_launch
    fp32 = sum(ncu[op] for op in FP32_OPS) / particles_per_launch
    sweeps_per_garment_frame = vertices * sweeps

    def ceiling(instructions: float) -> float:
        return rate / (sweeps_per_garment_frame * instructions)

    return {
        "issue_rate_thread_instr_per_s": rate,
        "budget_instr_per_particle_sweep": rate / (target * sweeps_per_garment_frame),
        "instr_per_particle_sweep": per_sweep,
        "fp32_instr_per_particle_sweep": fp32,
        "fp32_share": fp32 / per_sweep,
        "issue_busy_pct": ncu["issue_busy_pct"],
        "ceiling_gf_s_all_instructions_full_issue": ceiling(per_sweep),
        "ceiling_gf_s_fp32_only_full_issue": ceiling(fp32),
        "frame_ms_at_batch_fp32_only_full_issue": 1e3 * batch / ceiling(fp32),
        "frame_ms_at_batch_target": 1e3 * batch / target,
        "batch": batch,
        "target_garment_frames_per_s": target,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("ncu", type=Path, help="ncu details text of one colour launch of batch_floor")
    ap.add_argument("floor", type=Path, help="batch_floor JSON holding the profiled batch (its sizes)")
    ap.add_argument("--batch", type=int, required=True, help="the profiled batch (t-shirts per model)")
    ap.add_argument("--at", type=int, default=1024, help="the batch whose frame time to bound (default 1024)")
    ap.add_argument("--target", type=float, default=0.0, help="garment-frames/s (default: the floor JSON's)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args(argv)
    try:
        ncu = read_ncu(args.ncu.read_text(errors="replace"), str(args.ncu))
        floor = json.loads(args.floor.read_text())
        b = floor["batches"][str(args.batch)]
        target = args.target or float(floor["target_garment_frames_per_s"])
        vertices, sweeps = int(floor["vertices"]), int(b["sweeps_per_frame"])
        particles_per_launch = b["particles"] / b["colors"]
    except OSError as e:
        print(f"{e.filename}: {e.strerror}", file=sys.stderr)
        return 2
    except (ValueError, KeyError) as e:
        where = args.floor if isinstance(e, KeyError) else ""
        print(f"{where}{': no batch or field ' if where else ''}{e}", file=sys.stderr)
        return 2
    res = budget(ncu, particles_per_launch, vertices, sweeps, args.at, target)
    res.update({"ncu": ncu, "ncu_report": str(args.ncu), "floor": str(args.floor),
                "profiled_batch": args.batch, "vertices": vertices, "sweeps_per_frame": sweeps,
                "particles_per_launch": particles_per_launch})
    write_result(f"ncu_budget{args.tag}", res)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
