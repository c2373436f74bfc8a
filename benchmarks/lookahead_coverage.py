"""Whether the self-contact lookahead's candidates hold every pair a detection finds (development aid,
docs/BENCHMARKS.md, session 36).

Runs the t-shirt benchmark scene (``bench_tshirt``) with ``VBDConfig.self_contact_lookahead`` on and,
after every substep's ``SelfContact.remeasure``, runs a full tree detection at the same positions,
velocities and reference velocities on a second ``SelfContact`` with the same settings and no
lookahead. Per substep it compares the two sets of stored pairs (vertex-triangle, triangle-vertex and
edge-edge lists): the pairs the detection stored and the remeasure missed (candidates the query a
substep earlier did not see), and any the remeasure stored that the detection did not (there should
be none). Missed pairs are binned by their distance: closer than the contact radius (acting now), or
only within the query radius (they may act during the substep's sweeps).

``python -m benchmarks.lookahead_coverage --device cpu --motion run --seconds 1``
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from benchmarks.bench_tshirt import add_single_scene_arguments, load_single_scene
from benchmarks.common import machine, write_result

KINDS = (("vt", "tri"), ("tv", "vertex"), ("ee", "edge"))


def stored_pairs(sc, kind: str, ids: str) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of one kind of ``sc``'s lists (``SelfContactData``) as sorted int64 keys
    ``owner * 2^32 + partner``, and their stored distances in the same order."""
    count = getattr(sc, f"{kind}_count").numpy()
    cap = getattr(sc, f"{kind}_capacity")
    table = getattr(sc, f"{kind}_{ids}").numpy().reshape(len(count), cap)
    dist = getattr(sc, f"{kind}_dist").numpy().reshape(len(count), cap)
    used = np.arange(cap)[None, :] < count[:, None]
    owner = np.nonzero(used)[0].astype(np.int64)
    keys = (owner << 32) + table[used].astype(np.int64)
    order = np.argsort(keys)
    return keys[order], dist[used][order]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_single_scene_arguments(ap, device="cpu", motion="run", seconds=1.0)
    ap.add_argument("--solver", default="{}", help="JSON dict of further VBDConfig fields")
    ap.add_argument("--tag", default="")
    args = ap.parse_args()

    from sim.cloth import self_contact as contact
    from sim.simulate import SimulationConfig, SimulationJob, simulate_batch

    device, body, garment, motion = load_single_scene(args)
    solver = {**json.loads(args.solver), "self_contact_lookahead": True}
    cfg = SimulationConfig(fps=30.0, self_contact=True, device=device, solver=solver)
    totals = {kind: {"detected": 0, "missed": 0, "missed_in_contact": 0, "extra": 0} for kind, _ in KINDS}
    substeps_with_misses = [0]
    substeps = [0]
    worst = [np.inf]  # the smallest distance of a missed pair
    base_init, base_remeasure = contact.SelfContact.__init__, contact.SelfContact.remeasure

    def init(self, model, **kwargs):
        base_init(self, model, **kwargs)
        self.shadow_args = kwargs

    def remeasure(self, x0, v, h):
        base_remeasure(self, x0, v, h)
        if not hasattr(self, "shadow"):
            self.shadow = contact.SelfContact(self.model, **{**self.shadow_args, "lookahead": None})
        self.shadow.detect(x0, v, h, reference=self.data.reference)
        missed_any = False
        for kind, ids in KINDS:
            got, _ = stored_pairs(self.data, kind, ids)
            want, dist = stored_pairs(self.shadow.data, kind, ids)
            miss = ~np.isin(want, got)
            t = totals[kind]
            t["detected"] += len(want)
            t["missed"] += int(miss.sum())
            t["missed_in_contact"] += int((dist[miss] < self.data.radius).sum())
            t["extra"] += int((~np.isin(got, want)).sum())
            if miss.any():
                missed_any = True
                worst[0] = min(worst[0], float(dist[miss].min()))
        substeps[0] += 1
        substeps_with_misses[0] += int(missed_any)

    contact.SelfContact.__init__, contact.SelfContact.remeasure = init, remeasure
    try:
        t0 = time.perf_counter()
        result = simulate_batch([SimulationJob(garment, body, motion)], config=cfg, failures="return")[0]
        sim_s = time.perf_counter() - t0
    finally:
        contact.SelfContact.__init__, contact.SelfContact.remeasure = base_init, base_remeasure
    detected = sum(t["detected"] for t in totals.values())
    missed = sum(t["missed"] for t in totals.values())
    quality = getattr(result, "quality", None)
    figures = {
        "simulate_s": sim_s, "substeps": substeps[0], "substeps_with_misses": substeps_with_misses[0],
        "pairs_detected": detected, "pairs_missed": missed,
        "missed_fraction": missed / max(detected, 1),
        "closest_missed_m": None if np.isinf(worst[0]) else worst[0],
        "per_kind": totals,
        "max_edge_strain": float(getattr(quality, "max_edge_strain", np.nan)),
        "failed_gates": list(getattr(result, "failed_gates", []) or []),
    }
    print(json.dumps(figures, indent=1))
    write_result(f"lookahead_coverage_{device}{args.tag}", {
        "machine": machine(device),
        "sizes": {"garment_vertices": garment.num_vertices, "motion": args.motion, "seconds": args.seconds,
                  "solver": solver},
        "figures": figures})


if __name__ == "__main__":
    main()
