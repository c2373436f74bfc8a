"""Sewn garments on body shapes in motion: how they sew, how they wrinkle, whether the skin stays
under the cloth, and how many random garments pass the quality gates.

    python -m benchmarks.bench_garments --device cuda --shapes mean --workers 8 --time-limit 420
    python -m benchmarks.bench_garments --device cuda --no-table --population 100 --seed 0 \\
        --population-resolution coarse --workers 8 --time-limit 420 --tag _population
    python -m benchmarks.bench_garments --device cpu --designs t_shirt --shapes mean --motions walk \\
        --resolution 0.06 --seconds 0.2 --prelude 0.2

The table (unless ``--no-table``): every design (``sim.garments.designs``) drafted for, sewn on
and simulated on every body shape (``SHAPES``) in every motion, at ``--resolution``. Per
garment: vertex count, sewing time (draft, flat mesh, sewing on the body with the cloth solver),
the seam gap when the seams were merged, and the sewn rest shape's strain against its flat
pattern. Per sequence (the whole job, ``sim.simulate``: settle, lead-in, the motion; the
figures over the motion's frames): the wrinkle field |x - base| with base the 5 cm smooth base of
the frame (``sim.geometry.smoothing``; on CUDA the same linear system solved by conjugate
gradients on the GPU, checked against the sparse LU once per run), as rms and 99th percentile
[mm] over vertices and frames; skin through cloth (``sim.coverage``), max and mean over frames
[%]; the quality gates and edge strain (``sim.quality``).

The population (``--population N --seed S``): N random draws of a design, its fit, a body shape
(the leading ``SHAPE_COMPONENTS`` betas ~ N(0, 1) clipped at +-``SHAPE_CLIP``), a material preset
and a motion (``POPULATION_MOTIONS``), each sewn on its body and simulated through the job's
retry ladder (``SimulationConfig.retry_substeps``: a sequence that fails its gates or stops runs
again at more substeps), counting those that pass.

Run time: ``--workers`` sews in that many processes at once; ``--batch`` /
``--population-batch`` sequences share one batched cloth model; ``--prelude`` shortens the
settle and the lead-in; ``--time-limit`` starts no new batch, rung or sewing past that many
seconds and lists what it skipped, so a run ends within a device call. The JSON is written after
every batch (``complete``: false until the run ends), so a run stopped from outside leaves what
it measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.common import add_results_argument, machine, write_result
from benchmarks.scene import FPS, numbers, option_error, quality_dict

SHAPES = {"mean": {}, "plus2": {0: 2.0}, "minus2": {0: -2.0}, "heavy": {2: -2.0}, "slim": {2: 2.0}}
"""Named body shapes of the default body, as {beta index: value} in standard deviations: ``plus2``
/ ``minus2`` the first component at +-2 sigma (2.02 m / 1.41 m tall, chest 1.13 / 0.87 m against
1.71 m and 0.99 m of the mean), ``heavy`` / ``slim`` the third (waist 0.99 / 0.59 m)."""
TABLE_SHAPES = ("mean", "plus2", "minus2")
TABLE_MOTIONS = ("walk", "arm_raise", "squat")
POPULATION_MOTIONS = ("walk", "run", "jump", "arm_raise", "squat")
SHAPE_COMPONENTS = 4
"""Leading betas drawn for a population member (the rest 0), as datasets draw them."""
SHAPE_CLIP = 2.0
"""|beta| limit of a population member's shape [standard deviations]."""
SMOOTHING_LENGTH = 0.05
"""Length [m] of the smooth base the wrinkle field is measured against."""
CG_TOLERANCE = 1e-10
"""Relative residual at which the GPU's conjugate-gradient solve of the smoothing stops."""


@dataclass(frozen=True)
class GarmentSpec:
    """One garment to sew: a design with its parameters on a body shape, in a material, at a
    resolution ("coarse", "fine" or an edge length [m])."""

    design: str
    shape: str
    betas: tuple[float, ...]
    material: str = "cotton"
    params: tuple[tuple[str, object], ...] = ()
    resolution: str | float = "fine"
    material_changes: tuple[tuple[str, float], ...] = ()


def shape_betas(body, spec: dict[int, float]) -> np.ndarray:
    """The body's betas with the components of ``spec`` set."""
    b = np.zeros(body.num_betas, np.float32)
    for k, v in spec.items():
        b[k] = v
    return b


def rest_strain(garment) -> tuple[float, float]:
    """Max and mean |l / l_flat - 1| of the sewn rest shape's face edges against the flat pattern."""
    x = garment.rest_vertices[garment.faces].astype(np.float64)
    flat = garment.flat_corners()
    idx = np.array([[1, 0], [2, 1], [0, 2]])
    l3 = np.linalg.norm(x[:, idx[:, 0]] - x[:, idx[:, 1]], axis=2)
    l2 = np.linalg.norm(flat[:, idx[:, 0]] - flat[:, idx[:, 1]], axis=2)
    s = np.abs(l3 / np.maximum(l2, 1e-12) - 1.0)
    return float(s.max()), float(s.mean())


def sew_one(spec: GarmentSpec, device: str):
    """Draft, mesh and sew ``spec`` (a worker's task): ``(garment or None, figures)``; a design
    that cannot be drafted or sewn gives its error in the figures."""
    from sim.bodies.default import load_default_body
    from sim.garments.designs import edge_length, garment_of, make_pattern
    from sim.garments.materials import get_material
    from sim.garments.sewing import sew_pattern

    body = load_default_body()
    betas = np.asarray(spec.betas, np.float32)
    info = {"design": spec.design, "shape": spec.shape, "material": spec.material, **dict(spec.params),
            **dict(spec.material_changes)}
    t0 = time.perf_counter()
    try:
        mat = get_material(spec.material).with_(**dict(spec.material_changes))
        pattern = make_pattern(spec.design, body, betas, **dict(spec.params))
        sewn = sew_pattern(pattern, np.asarray(body.rest_mesh(betas)), np.asarray(body.faces),
                           edge_length(spec.resolution, spec.design), mat, device=device)
        g = garment_of(pattern, sewn, mat, category=spec.design, name=spec.design)
    except Exception as e:  # reported per garment: the other garments stand alone
        info.update(error=f"{type(e).__name__}: {e}", sewing_s=time.perf_counter() - t0)
        return None, info
    smax, smean = rest_strain(g)
    info.update(vertices=g.num_vertices, faces=g.num_faces, sewing_s=time.perf_counter() - t0,
                seam_gap_mm=1000.0 * sewn.seam_gap, rest_strain_max=smax, rest_strain_mean=smean)
    return g, info


class Clock:
    """Wall time since the start, progress lines stamped with it, and the ``--time-limit``;
    ``batch_s``: the last batch's time, simulation and figures, which the next is expected to take."""

    def __init__(self, limit: float):
        self.t0 = time.perf_counter()
        self.limit = limit
        self.batch_s = 0.0

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def log(self, text: str) -> None:
        print(f"[{self.elapsed:7.1f} s] {text}", flush=True)

    def over(self, needed: float = 0.0) -> bool:
        """Whether work expected to take ``needed`` seconds would end past the limit."""
        return self.limit > 0 and self.elapsed + needed > self.limit


def sew_all(specs: list[GarmentSpec], device: str, workers: int, clock: Clock) -> list[tuple]:
    """Every spec sewn, in order, in ``workers`` processes (0: here): ``[(garment, figures)]``.
    Past the time limit the specs not yet begun are not sewn (figures ``skipped``)."""
    out: list = [None] * len(specs)

    def done(k: int, result) -> None:
        out[k] = result
        info = result[1]
        what = info.get("error") or (f"{info['vertices']} vertices, seam gap {info['seam_gap_mm']:.2f} mm, "
                                     f"rest strain {info['rest_strain_max']:.3f}")
        clock.log(f"sewn {specs[k].design} on {specs[k].shape} ({info['sewing_s']:.1f} s): {what}")

    def skip(k: int) -> None:
        out[k] = (None, {"design": specs[k].design, "shape": specs[k].shape, "skipped": "time limit"})

    if workers <= 0:
        for k, s in enumerate(specs):
            if clock.over():
                skip(k)
            else:
                done(k, sew_one(s, device))
        return out
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(sew_one, s, device): k for k, s in enumerate(specs)}
        for f, k in futures.items():
            if clock.over() and f.cancel():
                skip(k)
                continue
            try:
                done(k, f.result())
            except Exception as e:  # a worker that died: its garment is reported, not the run lost
                out[k] = (None, {"design": specs[k].design, "shape": specs[k].shape,
                                 "error": f"{type(e).__name__}: {e}"})
    return out


def cg_smoother(rest: np.ndarray, faces: np.ndarray, device: str):
    """``smooth(x (T, V, 3)) -> (T, V, 3)``: the smooth base of ``sim.geometry.smoothing`` (the same
    system (M + t B) x = M x_fine, frame centres removed first), solved by Jacobi-preconditioned
    conjugate gradients in float64 with torch on ``device`` instead of the sparse LU."""
    import scipy.sparse as sp
    import torch

    from sim.geometry.smoothing import hessian_energy, smoothing_stiffness

    mass, B = hessian_energy(rest, faces)
    mass = np.where(mass > 0, mass, max(float(mass.mean()), 1e-12))
    A = (sp.diags(mass) + smoothing_stiffness(SMOOTHING_LENGTH) * B).tocsr()
    dev = torch.device("cuda" if device.startswith("cuda") else "cpu")
    At = torch.sparse_csr_tensor(torch.from_numpy(A.indptr.astype(np.int64)),
                                 torch.from_numpy(A.indices.astype(np.int64)), torch.from_numpy(A.data),
                                 size=A.shape, device=dev)
    inv_diag = torch.from_numpy(1.0 / A.diagonal()).to(dev)[:, None]
    m = torch.from_numpy(mass).to(dev)

    def smooth(x: np.ndarray) -> np.ndarray:
        X = torch.from_numpy(np.asarray(x, np.float64)).to(dev)
        T, V = X.shape[:2]
        c = torch.einsum("v,tvc->tc", m, X) / m.sum()
        x0 = (X - c[:, None]).permute(1, 0, 2).reshape(V, 3 * T)
        sol = _pcg(At, inv_diag, x0 * m[:, None], x0)
        return (sol.reshape(V, T, 3).permute(1, 0, 2) + c[:, None]).cpu().numpy().astype(np.float32)

    return smooth


def _pcg(A, inv_diag, b, x, *, maxiter: int = 20000):
    """Jacobi-preconditioned conjugate gradients on every column of ``b`` at once from ``x`` (the
    frames themselves: their smooth base differs by the wrinkles), to a relative residual of
    ``CG_TOLERANCE`` per column."""
    import torch

    x = x.clone()
    r = b - A @ x
    z = r * inv_diag
    p = z.clone()
    rz = (r * z).sum(0)
    bnorm = b.norm(dim=0).clamp_min(1e-300)
    for it in range(maxiter):
        Ap = A @ p
        pAp = (p * Ap).sum(0)
        alpha = torch.where(pAp > 0, rz / pAp.clamp_min(1e-300), torch.zeros_like(rz))
        x += alpha * p
        r -= alpha * Ap
        if it % 10 == 9 and float((r.norm(dim=0) / bnorm).max()) < CG_TOLERANCE:
            return x
        z = r * inv_diag
        rz_new = (r * z).sum(0)
        p = z + torch.where(rz > 0, rz_new / rz.clamp_min(1e-300), torch.zeros_like(rz)) * p
        rz = rz_new
    raise RuntimeError(f"smoothing: conjugate gradients did not reach {CG_TOLERANCE:g} in {maxiter} "
                       "iterations")


class Smoothing:
    """The smooth base of a garment's frames by ``method`` ("lu": ``sim.geometry.smoothing``, "cg":
    ``cg_smoother``), one solver kept per garment; ``check_mm`` is the largest difference [mm]
    between the two on the first frames of the first garment (None for "lu")."""

    def __init__(self, method: str, device: str):
        self.method, self.device = method, device
        self.check_mm: float | None = None
        self._key: int | None = None
        self._solve = None

    def base(self, vertices: np.ndarray, garment) -> np.ndarray:
        from sim.geometry.smoothing import BaseSmoother

        if self._key != id(garment):
            self._key = id(garment)
            self._solve = (BaseSmoother(garment.rest_vertices, garment.faces, length=SMOOTHING_LENGTH).smooth
                           if self.method == "lu" else cg_smoother(garment.rest_vertices, garment.faces,
                                                                   self.device))
        base = self._solve(vertices)
        if self.method == "cg" and self.check_mm is None:
            from sim.geometry.smoothing import smooth_base

            lu = smooth_base(vertices[:2], garment.rest_vertices, garment.faces, length=SMOOTHING_LENGTH)
            self.check_mm = 1000.0 * float(np.abs(lu - base[:2]).max())
        return base


def wrinkle_field(vertices: np.ndarray, garment, smoothing: Smoothing) -> dict:
    """rms and 99th percentile [mm] of |x - base| over every vertex of every frame."""
    d = np.linalg.norm(vertices - smoothing.base(vertices, garment), axis=2)
    return {"wrinkle_rms_mm": 1000.0 * float(np.sqrt(np.mean(d * d))),
            "wrinkle_p99_mm": 1000.0 * float(np.percentile(d, 99.0))}


def skin_figures(result, garment, body, betas: np.ndarray, device: str) -> dict:
    """Skin through cloth over the sequence's frames [%] (max and mean over frames; deeper than
    1 mm; its greatest depth [mm]), and the most skin the cloth slid off in a frame [%]."""
    from sim.coverage import EXPOSED, THROUGH, covered_vertices, skin_sides

    covered = covered_vertices(np.asarray(body.rest_mesh(betas)), body.faces, garment.rest_vertices,
                               garment.faces, device=device)
    seq = result.sequence
    sides = skin_sides(seq.body.vertices, seq.vertices, garment.faces, covered, device=device)
    through = 100.0 * sides.fraction(THROUGH)
    depth = sides.distance[sides.side == THROUGH]
    return {"covered_body_vertices": int(covered.sum()), "skin_through_max_pct": float(through.max()),
            "skin_through_mean_pct": float(through.mean()),
            "skin_through_1mm_max_pct": float(100.0 * sides.deeper_than(0.001).max()),
            "skin_through_depth_max_mm": 1000.0 * float(depth.max()) if depth.size else 0.0,
            "exposed_max_pct": float(100.0 * sides.fraction(EXPOSED).max())}


# ------------------------------------------------------------------------------- simulation


def motion_of(name: str, body, betas: np.ndarray, args: argparse.Namespace):
    """Procedural motion ``name`` for ``args.seconds`` on the skeleton of ``body`` at ``betas``, its
    lead-in ``args.prelude`` long where given."""
    from benchmarks.scene import benchmark_motion

    extra = {} if args.prelude is None else {"ramp": args.prelude}
    return benchmark_motion(name, body, args.seconds, betas, **extra)


def sim_config(args: argparse.Namespace, device: str):
    from sim.simulate import SimulationConfig

    solver = {}
    for item in args.solver_param:
        key, _, value = item.partition("=")
        solver[key] = json.loads(value)
    cfg = SimulationConfig(fps=FPS, device=device, solver=solver)
    if args.prelude is not None:
        cfg = dataclasses.replace(cfg, settle_seconds=args.prelude, blend_seconds=args.prelude)
    return cfg


def simulate_ladder(jobs: list, cfg, clock: Clock, *, ladder: bool, batch: int, label: str,
                    figures: Callable, save: Callable) -> list[dict]:
    """Every job simulated in batches of ``batch`` (``simulate_batch``, a failing sequence frozen
    while the others run on), then, with ``ladder``, those that fail their gates or stop again,
    batched together, at each of the retry ladder's substeps until they pass. Per job, the
    figures of its last run: ``run_figures`` and, of a run that finished, ``figures(k, result)``,
    taken as its batch ends (the results are not kept); ``save(runs)`` after every batch."""
    from sim.simulate import simulate_batch

    largest = max(j.garment.num_vertices for j in jobs)
    counts = [cfg.substeps_for(largest), *(cfg.retry_substeps(largest) if ladder else ())]
    out: list[dict] = [{"substeps": [], "passed": False} for _ in jobs]
    todo = list(range(len(jobs)))
    for n in counts:
        chunks = [todo[i:i + batch] for i in range(0, len(todo), batch)]
        for c, chunk in enumerate(chunks):
            if clock.over(clock.batch_s):
                for k in chunk:
                    out[k]["skipped"] = f"time limit before {n} substeps"
                continue
            t0 = time.perf_counter()
            clock.log(f"{label}: {len(chunk)} sequences at {n} substeps (batch {c + 1} of {len(chunks)})")
            try:
                res = simulate_batch([jobs[k] for k in chunk], config=dataclasses.replace(cfg, substeps=n),
                                     failures="return")
            except Exception as e:  # the whole batch failed: each of its jobs says why
                res = [e] * len(chunk)
            wall = time.perf_counter() - t0
            for k, r in zip(chunk, res, strict=True):
                out[k] = run_figures(r, [*out[k]["substeps"], n], len(chunk), wall)
                if hasattr(r, "sequence"):
                    out[k].update(figures(k, r))
            clock.batch_s = time.perf_counter() - t0
            ms = [out[k]["ms_per_frame"] for k in chunk if out[k].get("ms_per_frame")]
            clock.log(f"{label}: {sum(out[k]['passed'] for k in chunk)} of {len(chunk)} pass at {n} substeps "
                      f"(simulated in {wall:.1f} s, {max(ms, default=0.0):.1f} ms per batched frame; "
                      f"figures {clock.batch_s - wall:.1f} s)")
            save(out)
        todo = [k for k in todo if "skipped" not in out[k] and not out[k]["passed"]]
        if not todo:
            break
    return out


def run_figures(r, substeps: list[int], batch: int, wall: float) -> dict:
    """The JSON-ready figures of one run, a ``SimulationResult`` or the error that stopped it:
    gates, strain, the substeps tried so far, the batch's size and wall time [s]."""
    out = {"substeps": substeps, "passed": False, "batch": batch, "batch_wall_s": wall}
    if not hasattr(r, "sequence"):
        out["error"] = f"{type(r).__name__}: {r}"
        return out
    out.update(passed=bool(r.passed), frames=int(r.sequence.num_frames), failed_gates=list(r.failed_gates),
               max_edge_strain=float(r.quality.max_edge_strain), quality=quality_dict(r.quality),
               ms_per_frame=float(r.step_ms.mean()) if r.step_ms.size else None)
    return out


def guarded(take: Callable[[], dict]) -> dict:
    """``take()``, or its error as ``figures_error``: one sequence's figures stand alone."""
    try:
        return take()
    except Exception as e:
        return {"figures_error": f"{type(e).__name__}: {e}"}


# ------------------------------------------------------------------------------- the table


def table(args: argparse.Namespace, body, device: str, clock: Clock, smoothing: Smoothing,
          report: Report) -> None:
    """Every design sewn on every shape (``garments``) and simulated in every motion (``rows``),
    into ``report.result["table"]``, saved after every batch."""
    from sim.simulate import SimulationJob

    shapes = {s: shape_betas(body, SHAPES[s]) for s in args.shapes}
    specs = [GarmentSpec(d, s, tuple(float(b) for b in shapes[s]), args.material,
                         design_overrides(d, args.design_param), args.resolution,
                         tuple(args.material_changes.items()))
             for s in args.shapes for d in args.designs]
    sewn = sew_all(specs, device, args.workers, clock)
    out = report.result["table"] = {"garments": [info for _, info in sewn], "rows": []}
    report.save()
    motions = {(s, m): motion_of(m, body, shapes[s], args) for s in args.shapes for m in args.motions}
    jobs, heads = [], []
    for spec, (g, _) in zip(specs, sewn, strict=True):  # by shape: a batch's jobs share its bodies
        for m in args.motions if g is not None else ():
            jobs.append(SimulationJob(g, body, motions[(spec.shape, m)], betas=shapes[spec.shape],
                                      name=f"{spec.design}/{spec.shape}/{m}"))
            heads.append({"design": spec.design, "shape": spec.shape, "motion": m, "material": spec.material,
                          **dict(spec.params), "vertices": g.num_vertices})

    def figures(k: int, r) -> dict:
        g = jobs[k].garment
        if args.frames_out is not None:
            save_frames(args.frames_out / (jobs[k].name.replace("/", "_") + ".npz"), r.sequence, g,
                        args.frames_every)
        return guarded(lambda: {**wrinkle_field(r.sequence.vertices, g, smoothing),
                                **skin_figures(r, g, body, jobs[k].betas, device)})

    def save(runs: list[dict]) -> None:
        out["rows"] = [{**h, **run} for h, run in zip(heads, runs, strict=True) if run["substeps"]]
        report.save()

    runs = simulate_ladder(jobs, sim_config(args, device), clock, ladder=args.table_retries, batch=args.batch,
                           label="table", figures=figures, save=save) if jobs else []
    out["rows"] = [{**h, **run} for h, run in zip(heads, runs, strict=True)]
    for row in out["rows"]:
        clock.log(table_line(row))
    out["summary"] = table_summary(sewn, out["rows"])


def save_frames(path, sequence, garment, every: int) -> None:
    """Every ``every``-th frame of a sequence (and its last) as .npz, written atomically:
    ``garment`` (T, V, 3) and ``body`` (T, Vb, 3) positions [m], ``garment_faces``, ``body_faces``,
    ``panel_ids`` and ``frames`` (their indices in the motion), for pictures (tools/render_closeups.py),
    and ``rest`` (V, 3) with ``rest_edge_lengths`` (``Garment.rest_edge_lengths``: the flat
    pattern's, in ``sim.quality.unique_edges`` order) for the edge strain.
    Positions stay float32: float16 steps ~1 mm at 1-2 m, and the skin would show through the
    cloth in the pictures."""
    import os
    import tempfile

    n = int(sequence.num_frames)
    idx = np.unique(np.append(np.arange(0, n, max(1, every)), n - 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npz")
    os.close(fd)
    try:
        np.savez_compressed(tmp, garment=np.asarray(sequence.vertices, np.float32)[idx],
                            body=np.asarray(sequence.body.vertices, np.float32)[idx],
                            garment_faces=np.asarray(garment.faces, np.int32),
                            body_faces=np.asarray(sequence.body.faces, np.int32),
                            panel_ids=np.asarray(garment.panel_ids, np.int32), frames=idx.astype(np.int32),
                            rest=np.asarray(garment.rest_vertices, np.float32),
                            rest_edge_lengths=np.asarray(garment.rest_edge_lengths(), np.float32))
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def design_overrides(design: str, items: list[str]) -> tuple[tuple[str, object], ...]:
    """The ``--design-param KEY=VALUE`` settings that ``design`` has (a JSON number or a word)."""
    from sim.garments.designs import designs
    from sim.garments.parameters import parameter_specs

    known = parameter_specs(designs()[design].params)
    out = []
    for item in items:
        key, _, text = item.partition("=")
        if key in known:
            try:
                value = json.loads(text)
            except json.JSONDecodeError:
                value = text
            out.append((key, value))
    return tuple(out)


def table_line(row: dict) -> str:
    """One row of the table in words."""
    head = f"{row['design']:>14} {row['shape']:>7} {row['motion']:>9}"
    if "skin_through_max_pct" not in row:
        return f"{head}  {row.get('error') or row.get('skipped') or row.get('figures_error')}"
    gates = "pass" if row["passed"] else "; ".join(row["failed_gates"]) or "fail"
    return (f"{head}  wrinkles {row['wrinkle_rms_mm']:5.2f} / {row['wrinkle_p99_mm']:5.2f} mm  skin through "
            f"{row['skin_through_max_pct']:6.3f} % (mean {row['skin_through_mean_pct']:6.3f}, > 1 mm "
            f"{row['skin_through_1mm_max_pct']:6.3f})  strain {row['max_edge_strain']:.3f}  {gates}")


def table_summary(sewn: list[tuple], rows: list[dict]) -> dict:
    """The table's figures against the targets: medians and extremes over its sequences."""
    done = [r for r in rows if "skin_through_max_pct" in r]
    ok = [info for g, info in sewn if g is not None]
    out = {"garments_sewn": len(ok), "garments": len(sewn), "sequences": len(rows), "simulated": len(done),
           "passed": sum(r["passed"] for r in rows)}
    if ok:
        out.update(seam_gap_mm_max=max(i["seam_gap_mm"] for i in ok),
                   sewing_s_median=float(np.median([i["sewing_s"] for i in ok])),
                   vertices_range=[min(i["vertices"] for i in ok), max(i["vertices"] for i in ok)])
    if done:
        for key in ("wrinkle_rms_mm", "wrinkle_p99_mm"):
            v = [r[key] for r in done]
            out[key] = {"median": float(np.median(v)), "min": float(np.min(v)), "max": float(np.max(v))}
        out["skin_through_max_pct"] = max(r["skin_through_max_pct"] for r in done)
        out["sequences_skin_through_over_0.1_pct"] = sum(r["skin_through_max_pct"] > 0.1 for r in done)
    return out


# ------------------------------------------------------------------------------- the population


def draw_population(n: int, seed: int, body, resolution: str | float) -> list[tuple[GarmentSpec, str]]:
    """``n`` random (garment, motion) draws from ``seed``: every draw takes the same random numbers
    (design, fit, shape, material, motion), so draw k is the same in any population size."""
    from sim.garments.designs import designs
    from sim.garments.materials import MATERIALS
    from sim.garments.parameters import parameter_specs

    table_ = designs()
    names, mats = sorted(table_), sorted(MATERIALS)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        d = names[rng.integers(len(names))]
        fit = parameter_specs(table_[d].params).get("fit")
        choice = rng.integers(1 << 30)
        betas = np.zeros(body.num_betas, np.float32)
        betas[:SHAPE_COMPONENTS] = np.clip(rng.normal(size=SHAPE_COMPONENTS), -SHAPE_CLIP, SHAPE_CLIP)
        mat = mats[rng.integers(len(mats))]
        motion = POPULATION_MOTIONS[rng.integers(len(POPULATION_MOTIONS))]
        params = (("fit", fit.choices[choice % len(fit.choices)]),) if fit is not None else ()
        label = "(" + ", ".join(f"{b:+.2f}" for b in betas[:SHAPE_COMPONENTS]) + ")"
        out.append((GarmentSpec(d, label, tuple(float(b) for b in betas), mat, params, resolution), motion))
    return out


def population(args: argparse.Namespace, body, device: str, clock: Clock, report: Report) -> None:
    """The drawn population sewn, simulated through the retry ladder and counted, into
    ``report.result["population"]``, saved after every batch."""
    from sim.simulate import SimulationJob

    draws = draw_population(args.population, args.seed, body, args.population_resolution)
    sewn = sew_all([s for s, _ in draws], device, args.workers, clock)
    members = []
    for (spec, m), (_, info) in zip(draws, sewn, strict=True):
        members.append({"design": spec.design, "fit": dict(spec.params).get("fit"), "shape": spec.shape,
                        "material": spec.material, "motion": m, "passed": False,
                        **{k: info[k] for k in ("vertices", "sewing_s", "seam_gap_mm", "rest_strain_max",
                                                "error", "skipped") if k in info}})
    out = report.result["population"] = {"size": len(members), "seed": args.seed,
                                         "resolution": args.population_resolution}
    jobs, index = [], []
    for k, ((spec, m), (g, _)) in enumerate(zip(draws, sewn, strict=True)):
        if g is not None:
            betas = np.asarray(spec.betas, np.float32)
            jobs.append(SimulationJob(g, body, motion_of(m, body, betas, args), betas=betas,
                                      name=f"member {k}: {spec.design} {m}"))
            index.append(k)

    def save(runs: list[dict]) -> None:
        for k, run in zip(index, runs, strict=True):
            if run["substeps"] or "skipped" in run:
                members[k].update(run)
        passing = sum(m["passed"] for m in members)
        out.update(passing=passing, pass_rate=passing / max(len(members), 1),
                   not_sewn=sum(1 for g, _ in sewn if g is None), by=pass_counts(members), members=members)
        report.save()

    def figures(k: int, r) -> dict:
        return guarded(lambda: skin_figures(r, jobs[k].garment, body, jobs[k].betas, device))

    runs = simulate_ladder(jobs, sim_config(args, device), clock, ladder=True, batch=args.population_batch,
                           label="population", figures=figures, save=save) if jobs else []
    save(runs)


def pass_counts(members: list[dict]) -> dict:
    """``{"design" | "motion" | "material": {value: "passing of drawn"}}``."""
    out = {}
    for key in ("design", "motion", "material"):
        values = sorted({m[key] for m in members})
        out[key] = {v: f"{sum(m['passed'] for m in members if m[key] == v)} of "
                       f"{sum(1 for m in members if m[key] == v)}" for v in values}
    return out


class Report:
    """The result being written: ``save()`` after every batch (silently, ``complete`` false), so a
    run stopped from outside leaves what it measured; ``finish()`` writes and prints it whole."""

    def __init__(self, name: str, folder, result: dict):
        self.name, self.folder, self.result = name, folder, result

    def save(self) -> None:
        import datetime as dt
        import os
        from pathlib import Path

        from benchmarks.common import command_line

        text = json.dumps({"benchmark": self.name, "date": dt.datetime.now(dt.timezone.utc).isoformat(
            timespec="seconds"), "command": command_line(), **self.result, "complete": False}, indent=2)
        folders = [Path(self.folder)] + ([Path(os.environ["OUT"])] if os.environ.get("OUT") else [])
        for f in folders:
            f.mkdir(parents=True, exist_ok=True)
            tmp = f / f"{self.name}.json.tmp"
            tmp.write_text(text + "\n")
            os.replace(tmp, f / f"{self.name}.json")

    def finish(self) -> None:
        write_result(self.name, {**self.result, "complete": True}, self.folder)


# ------------------------------------------------------------------------------- the command


def names(text: str, known, option: str) -> tuple[str, ...]:
    """Comma-separated names, each one of ``known``; else exit 2 with a one-line error."""
    out = tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [s for s in out if s not in known]
    if bad or not out:
        option_error(option, ValueError(f"unknown {', '.join(map(repr, bad)) or 'empty list'}; expected "
                                        f"{', '.join(known)}"))
    return out


def resolution(text: str, option: str) -> str | float:
    """"coarse", "fine" or an edge length [m]; else exit 2."""
    if text in ("coarse", "fine"):
        return text
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (np.isfinite(v) and 0.002 <= v <= 0.2):
        option_error(option, ValueError(f"expected coarse, fine or an edge length in metres (0.002-0.2), "
                                        f"got {text!r}"))
    return v


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    from sim.garments.designs import designs
    from sim.motions import PROCEDURAL_MOTIONS

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto", help="Warp device: auto, cpu, cuda (default: %(default)s)")
    ap.add_argument("--designs", default=",".join(designs()), help="the table's designs (default: every one)")
    ap.add_argument("--shapes", default=",".join(TABLE_SHAPES),
                    help=f"the table's body shapes, of {', '.join(SHAPES)} (default: %(default)s)")
    ap.add_argument("--motions", default=",".join(TABLE_MOTIONS),
                    help="the table's motions (default: %(default)s)")
    ap.add_argument("--resolution", default="fine", help="the table's garments: coarse, fine or an edge "
                    "length [m] (default: %(default)s)")
    ap.add_argument("--seconds", type=float, default=2.5, help="motion length [s] (default: %(default)s: one "
                    "squat, an arm raise and back)")
    ap.add_argument("--prelude", type=float, default=None, help="seconds of the settle and of the lead-in "
                    "into the motion (default: the job's, 1 s each)")
    ap.add_argument("--no-table", action="store_true", help="skip the table")
    ap.add_argument("--table-retries", action="store_true", help="run the table's sequences through the "
                    "retry ladder too (default: once, at the job's substeps)")
    ap.add_argument("--population", type=int, default=0, help="random draws to simulate (default: none)")
    ap.add_argument("--seed", type=int, default=0, help="the population's seed (default: %(default)s)")
    ap.add_argument("--population-resolution", default="coarse",
                    help="the population's garments (default: %(default)s)")
    ap.add_argument("--batch", type=int, default=9, help="table sequences per batched model (default: "
                    "%(default)s)")
    ap.add_argument("--population-batch", type=int, default=25,
                    help="population sequences per batched model (default: %(default)s)")
    ap.add_argument("--workers", type=int, default=0, help="processes that sew garments at once (default 0: "
                    "sew in this one)")
    ap.add_argument("--solver-param", action="append", default=[], metavar="KEY=VALUE",
                    help="a solver setting over the job's, e.g. body_contact.offset=0.001 (repeatable)")
    ap.add_argument("--material", default="cotton", help="the table's material preset (default: %(default)s)")
    ap.add_argument("--material-param", action="append", default=[], metavar="KEY=VALUE",
                    help="a field of the table's material over its preset (sim.garments.materials.Material), "
                         "e.g. friction=0.2 (repeatable)")
    ap.add_argument("--design-param", action="append", default=[], metavar="KEY=VALUE",
                    help="a design parameter over the defaults, for the designs that have it, e.g. "
                         "fit=loose (repeatable)")
    ap.add_argument("--frames-out", type=Path, default=None, metavar="DIR",
                    help="write each table sequence's frames (float32 .npz: garment, body, faces) to DIR")
    ap.add_argument("--frames-every", type=int, default=5, help="with --frames-out, every Nth frame and "
                    "the last (default: %(default)s)")
    ap.add_argument("--smoothing", choices=("auto", "lu", "cg"), default="auto", help="the smooth base's "
                    "solver: lu (sparse LU, CPU), cg (conjugate gradients with torch on the device), auto: "
                    "cg on CUDA, else lu (default: %(default)s)")
    ap.add_argument("--time-limit", type=float, default=0.0, help="seconds after which no new sewing, batch "
                    "or retry starts; what is left is listed as skipped (default 0: none)")
    ap.add_argument("--tag", default="", help="suffix of the result file's name")
    add_results_argument(ap)
    args = ap.parse_args(argv)
    args.designs = names(args.designs, tuple(designs()), "--designs")
    args.shapes = names(args.shapes, tuple(SHAPES), "--shapes")
    args.motions = names(args.motions, tuple(PROCEDURAL_MOTIONS), "--motions")
    args.resolution = resolution(args.resolution, "--resolution")
    check_table_garments(args)
    args.population_resolution = resolution(args.population_resolution, "--population-resolution")
    for option in ("seconds", "batch", "population_batch", "frames_every"):
        if not getattr(args, option) > 0:
            option_error("--" + option.replace("_", "-"), ValueError("must be positive"))
    if args.population < 0 or args.workers < 0 or (args.prelude is not None and args.prelude < 0.04):
        option_error("--population/--workers/--prelude",
                     ValueError("counts must be >= 0, the prelude >= 0.04 s"))
    return args


def check_table_garments(args: argparse.Namespace) -> None:
    """``--material`` is a preset, every ``--material-param`` KEY=NUMBER a field of it; every
    ``--design-param`` is KEY=VALUE, a parameter of one of the table's designs with a valid value
    (else the option's error, exit 2)."""
    from sim.garments.designs import design_params
    from sim.garments.materials import MATERIALS, get_material

    if args.material not in MATERIALS:
        option_error("--material", ValueError(f"unknown preset {args.material!r}; expected one of "
                                              f"{', '.join(sorted(MATERIALS))}"))
    args.material_changes = numbers(args.material_param, "--material-param",
                                    lambda out: get_material(args.material).with_(**out))
    for item in args.design_param:
        key = item.partition("=")[0]
        if "=" not in item or not any(k == key for d in args.designs for k, _ in design_overrides(d, [item])):
            option_error("--design-param", ValueError(f"{item!r}: expected KEY=VALUE with KEY a parameter "
                                                      "of one of the table's designs"))
    for d in args.designs:
        try:
            design_params(d, **dict(design_overrides(d, args.design_param)))
        except Exception as e:
            option_error("--design-param", e)


def edge_lengths(resolution: str | float, names) -> float | dict[str, float]:
    """The edge length [m] of a resolution in metres, or each design's at a named one."""
    from sim.garments.designs import edge_length

    if not isinstance(resolution, str):
        return float(resolution)
    return {n: edge_length(resolution, n) for n in names}


def main(argv: list[str] | None = None) -> None:
    from sim.bodies.default import load_default_body
    from sim.device import resolve_device
    from sim.garments.designs import designs

    args = parse_args(argv)
    clock = Clock(args.time_limit)
    device = resolve_device(args.device)
    body = load_default_body()
    method = args.smoothing if args.smoothing != "auto" else ("cg" if device.startswith("cuda") else "lu")
    smoothing = Smoothing(method, device)
    cfg = sim_config(args, device)
    sizes = {"body_vertices": int(body.num_vertices), "fps": FPS, "seconds": args.seconds,
             "settle_s": cfg.settle_seconds, "designs": list(args.designs),
             "shapes": {s: {str(k): v for k, v in SHAPES[s].items()} for s in args.shapes},
             "motions": list(args.motions), "resolution": args.resolution,
             "edge_m": edge_lengths(args.resolution, args.designs),
             "smoothing": {"length_m": SMOOTHING_LENGTH, "solver": method},
             "material": args.material, "material_params": list(args.material_param),
             "design_params": list(args.design_param),
             "workers": args.workers, "time_limit_s": args.time_limit}
    report = Report(f"garments_{device.split(':')[0]}{args.tag}", args.results,
                    {"machine": machine(device), "sizes": sizes, "config": cfg.to_dict()})
    if args.population:
        sizes.update(population_motions=list(POPULATION_MOTIONS), shape_components=SHAPE_COMPONENTS,
                     shape_clip=SHAPE_CLIP,
                     population_edge_m=edge_lengths(args.population_resolution, list(designs())))
    if not args.no_table:
        table(args, body, device, clock, smoothing, report)
    if args.population:
        population(args, body, device, clock, report)
    report.result.update(smoothing_check_mm=smoothing.check_mm, wall_s=clock.elapsed)
    report.finish()
    print_summary(report.result)


def print_summary(result: dict) -> None:
    """The table and the population's count, last in the output."""
    if "table" in result:
        for row in result["table"]["rows"]:
            print(table_line(row))
        print("table:", json.dumps(result["table"]["summary"]))
    if "population" in result:
        p = result["population"]
        print(f"population: {p['passing']} of {p['size']} pass ({p['not_sewn']} not sewn); by motion "
              f"{json.dumps(p['by']['motion'])}")
    print(f"wall time {result['wall_s']:.1f} s")


if __name__ == "__main__":
    main()
