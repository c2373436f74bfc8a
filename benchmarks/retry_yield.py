"""How many sequences of a dataset pass their quality gates with and without the retries at more
substeps (``SimulationConfig.retry_factors``, session 43), and at what cost in time.

Each case generates a fresh dataset from one config with ``sim.datasets.generate``: every
template (or ``--garments``), the walk and the run at the sampled bodies (4 betas), cotton, self
contact on, the job default's substeps, no UV images and no coarse twin (the garments at
``--resolution``). It reports accepted and rejected sequences per template and motion, the
substeps each accepted sequence was simulated at (from its provenance) and those a rejection tried,
and the job's wall time. A case is the ``[simulation] retry_factors`` (a list; null: the
default) or a JSON object of ``[simulation]`` fields (e.g. ``{"iterations": 5, "retry_factors":
[]}``: session 44's sweeps against the former 5 at the fine size).

    python -m benchmarks.retry_yield --device cuda --sequences 32 --batch 8
    python -m benchmarks.retry_yield --device cuda --resolution fine --sequences 8 \
        --cases '{"14x5": {"iterations": 5, "retry_factors": []}, "default, no retries": []}'
    python -m benchmarks.retry_yield --device cpu --sequences 4 --batch 2 --garments t_shirt --seconds 0.3
"""

from __future__ import annotations

import argparse
import json
from collections import Counter

from benchmarks.common import machine, write_result

CONFIG = """\
seed = {seed}
sequences = {sequences}
fps = 30.0
seconds = {seconds}

[garments]
categories = {garments}
fine_resolution = "{resolution}"
coarse_resolution = "coarse"

[materials]
names = ["cotton"]

[bodies]
betas = 4

[motions]
procedural = ["walk", "run"]

[split]
test_fraction = 0.0

[simulation]
self_contact = true
{simulation}

[derive]
image_resolution = 0
coarse = false
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--sequences", type=int, default=32)
    ap.add_argument("--seconds", type=float, default=2.0, help="motion length [s] (plus 2 s of prelude)")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0, help="the dataset's sampling seed")
    ap.add_argument("--garments", default="all", help="template names, comma-separated (default: all)")
    ap.add_argument("--resolution", default="coarse", help="coarse or fine (default: %(default)s)")
    ap.add_argument("--cases", default='{"no retries": [], "default": null}',
                    help="JSON object: case name -> retry_factors (null: the default for the resolution, "
                    "default_retry_factors), or "
                    "case name -> object of [simulation] fields")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()

    from benchmarks.bench_dataset import generate_in_temp
    from sim.datasets import storage as S
    from sim.device import resolve_device
    from sim.garments.templates import TEMPLATES
    from sim.simulate import FINE_GARMENT_VERTICES as FINE
    from sim.simulate import default_iterations, default_retry_factors, default_substeps

    garments = list(TEMPLATES) if args.garments == "all" else args.garments.split(",")
    try:
        cases = json.loads(args.cases)
        assert isinstance(cases, dict)
    except (ValueError, AssertionError):
        raise SystemExit(f"retry_yield: --cases must be a JSON object, got {args.cases!r}") from None
    device = resolve_device(args.device)

    def substeps_used(root: str) -> dict:
        """Per accepted sequence, the substeps it was simulated at (its provenance's config; 0,
        automatic, is the default for its size), with ``xI`` where its sweeps were not 5, and the
        rungs it failed before (``failed_attempts``: substeps and reasons)."""
        out = {}
        for sid, e in S.read_manifest(root)["sequences"].items():
            prov = S.SequenceFile(f"{root}/{e['file']}").json("provenance")
            c = prov["config"]
            n = c["substeps"] or default_substeps(e["vertices"])
            i = c["iterations"] or default_iterations(e["vertices"])
            out[sid] = (f"{n}" if i == 5 else f"{n}x{i}", prov.get("failed_attempts", []))
        return out

    fig = {}
    for name, case in cases.items():
        fields = dict(case) if isinstance(case, dict) else {"retry_factors": case}
        if fields.get("retry_factors") is None:  # automatic: the resolution's default
            fields.pop("retry_factors", None)
            fine = args.resolution == "fine"
            factors = list(default_retry_factors(FINE + 1 if fine else 0))
        else:
            factors = fields["retry_factors"]
        text = CONFIG.format(seed=args.seed, sequences=args.sequences, seconds=args.seconds,
                             garments=json.dumps(garments), resolution=args.resolution,
                             simulation="\n".join(f"{k} = {json.dumps(v)}" for k, v in fields.items()))
        s, wall, manifest, used = generate_in_temp(text, f"retry_yield:{name}", args.batch, device,
                                                   substeps_used)
        by = {}
        for sid, e in manifest["sequences"].items():
            row = by.setdefault(f"{e['garment']} {e['motion']}", {"accepted": Counter(), "rejected": 0})
            row["accepted"][str(used[sid][0])] += 1
            if used[sid][1]:  # the rungs an accepted sequence failed first (session 46)
                row.setdefault("retried", []).append({"accepted_at": used[sid][0], "attempts": used[sid][1]})
        for r in manifest["rejected"].values():
            row = by.setdefault(f"{r['garment']} {r['motion']}", {"accepted": Counter(), "rejected": 0})
            row["rejected"] += 1
            row.setdefault("reasons", []).append({"substeps": r.get("substeps"), "reasons": r["reasons"],
                                                  "attempts": r.get("attempts", [])})
        fig[name] = {"retry_factors": factors, "simulation": fields, "sequences": s.accepted + s.rejected,
                     "accepted": s.accepted, "rejected": s.rejected, "wall_s": wall,
                     "by_garment_motion": {k: {**v, "accepted": dict(v["accepted"])}
                                           for k, v in sorted(by.items())}}
        print(name, json.dumps({k: v for k, v in fig[name].items() if k != "by_garment_motion"}), flush=True)
        for k, v in sorted(by.items()):
            print(f"   {k:28s} accepted at substeps {dict(v['accepted'])}  rejected {v['rejected']}",
                  flush=True)
        write_result(f"retry_yield_{device.split(':')[0]}{args.tag}", {  # after every case
            "machine": machine(device),
            "sizes": {"sequences": args.sequences, "seconds": args.seconds, "batch": args.batch,
                      "seed": args.seed, "garments": garments, "resolution": args.resolution},
            "figures": fig, "complete": len(fig) == len(cases)})


if __name__ == "__main__":
    main()
