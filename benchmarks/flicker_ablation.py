"""Temporal coherence of the wrinkle diffusion (issue 6): flicker with and without the shared initial
noise and the neighbour guidance, on one split, same model and seed.

    python -m benchmarks.flicker_ablation --model pretrained/t_shirt-wrinkles.pt --data data/tshirt \
        --split test_id --out benchmarks/results/flicker.json

``flicker_ratio`` is the harness's (frame-to-frame change of the predicted surface over that of the
simulation; 1 = as lively as the simulation, above = flicker).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    from learn.evaluate import evaluate
    from learn.train.trainer import load_trained

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True)
    p.add_argument("--data", required=True)
    p.add_argument("--split", default="test_id")
    p.add_argument("--device", default="cpu")
    p.add_argument("--max-sequences", type=int, default=6)
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)
    method, model, _ = load_trained(a.model, device=a.device)
    base_cfg = method.config
    rows = {}
    for name, kw in (
        ("independent noise, no guidance", {"shared_noise": False, "temporal_weight": 0.0}),
        ("shared noise", {"shared_noise": True, "temporal_weight": 0.0}),
        ("shared noise + neighbour guidance (default)", {}),
    ):
        method.config = dataclasses.replace(base_cfg, **kw)
        ev = evaluate(
            method,
            model,
            a.data,
            a.split,
            device=a.device,
            max_sequences=a.max_sequences,
            predict_options={"steps": a.steps},
        )
        rows[name] = {
            k: ev.summary[k] for k in ("flicker_ratio", "ev", "ecd", "normal_fd") if k in ev.summary
        }
        print(name, rows[name])
    Path(a.out).write_text(
        json.dumps({"model": a.model, "split": a.split, "steps": a.steps, "rows": rows}, indent=1)
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
