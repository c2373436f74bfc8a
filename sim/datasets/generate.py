"""Generate a dataset: sample, simulate (fine and coarse), gate, derive, store; resumable.

``generate(cfg, out, shard=i, shards=n, resume=...)`` makes the sequences of shard ``i``
(indices ``i, i + n, ...``) in groups of ``batch`` (one batched simulation each; a group's
fine and coarse garments share one model). After every group the shard's part file
(``parts/shard-i-of-n.json``) is rewritten atomically; a sequence file appears only when
complete. A run killed at any point and started again with ``resume=True`` skips what is
recorded, recovers a sequence file written just before the kill (its manifest entry is inside
it), and redoes the rest, in the same groups: on one device, the same config, seed and batch
give byte-identical sequence files however often the run was interrupted.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.datasets import storage as S
from sim.datasets.config import DatasetConfig
from sim.datasets.fields import DERIVE_META
from sim.datasets.sampling import SequenceSpec, sample_sequences, select_indices
from sim.errors import WrinklesInputError
from sim.memo import LRU, content_key
from sim.profiling import phase

Log = Callable[[str], None]


@dataclass
class GenerateSummary:
    """What one ``generate`` call did."""

    accepted: int = 0
    rejected: int = 0
    skipped: int = 0
    recovered: int = 0
    seconds: float = 0.0
    garment_frames: int = 0
    bytes: int = 0


def _entry_quality(q, wrinkle: np.ndarray, strain_norm: np.ndarray) -> dict:
    return {"max_edge_strain": float(q.max_edge_strain), "mean_edge_strain": float(q.mean_edge_strain),
            "max_stretch": float(q.max_stretch), "max_compression": float(q.max_compression),
            "inside_fraction_max": float(q.inside_fraction.max(initial=0.0)),
            "inside_fraction_mean": float(q.inside_fraction.mean()) if q.inside_fraction.size else 0.0,
            "self_intersections_max": int(q.self_intersections.max(initial=0)),
            "wrinkle_rms": float(np.sqrt(np.mean(np.square(wrinkle, dtype=np.float64)))),
            "wrinkle_max": float(np.abs(wrinkle).max(initial=0.0)),
            "strain_norm_mean": float(strain_norm.mean()),
            "strain_norm_max": float(strain_norm.max(initial=0.0))}


class _Shard:
    """The part file of one shard: accepted and rejected sequences, rewritten atomically."""

    def __init__(self, root: Path, cfg_dict: dict, shard: int, shards: int, resume: bool):
        self.path = S.part_path(root, shard, shards)
        self.data = {"config": cfg_dict, "shard": shard, "shards": shards, "sequences": {}, "rejected": {}}
        if self.path.exists():
            if not resume:
                raise WrinklesInputError(f"shard {shard}/{shards} was already started here; pass --resume to "
                                         "continue it, or choose another --out", path=root)
            old = json.loads(self.path.read_text())
            if old.get("config") != cfg_dict:
                _refuse_other_simulator(old.get("config"), cfg_dict, root)
                raise WrinklesInputError("--resume with a different config than the one this dataset was "
                                         "started with (see config.json)", path=root)
            self.data = old

    def save(self) -> None:
        S.atomic_write_json(self.path, self.data)

    def event(self, sid: str, outcome: str, frames: int) -> None:
        """Append when sequence ``sid`` was done, and how (``S.events_path``: the timeline of a
        job, for ``wrinkles dataset report``; not part of the dataset's bytes)."""
        line = {"id": sid, "outcome": outcome, "frames": int(frames), "time": round(time.time(), 3),
                "shard": self.data["shard"]}
        with open(S.events_path(self.path), "a") as f:
            f.write(json.dumps(line, sort_keys=True) + "\n")


def _refuse_other_simulator(old: dict | None, cfg_dict: dict, root: Path) -> None:
    """The error for a dataset whose config matches but whose simulator defaults do not (or that
    has no record of them): continuing it would mix two physics."""
    if isinstance(old, dict) and {k: v for k, v in old.items() if k != "simulator"} == \
            {k: v for k, v in cfg_dict.items() if k != "simulator"}:
        raise WrinklesInputError("this dataset was made with other simulator defaults (automatic substeps, "
                                 "garment hems and their rule, the colouring of the device kind, the retries "
                                 "at more substeps, the automatic sweeps, the templates' default "
                                 "parameters, the gaits' cadence, how procedural motions begin) than this "
                                 "version's on this device, and "
                                 "continuing it would mix two physics; choose another --out", path=root)


def _check_root(root: Path, cfg_dict: dict, resume: bool) -> None:
    cfg_path = root / "config.json"
    if cfg_path.exists():
        old = json.loads(cfg_path.read_text())
        if old != cfg_dict:
            _refuse_other_simulator(old, cfg_dict, root)
            raise WrinklesInputError("this directory holds a dataset made with a different config "
                                     "(config.json); choose another --out", path=root)
    elif root.exists() and any(p.name not in (S.PARTS_DIR, S.SEQUENCE_DIR) for p in root.iterdir()):
        raise WrinklesInputError("exists and is not an empty directory or a dataset of this config",
                                 path=root)


@dataclass
class _Run:
    """What every group of one ``generate`` call shares."""

    cfg: DatasetConfig
    body: object
    root: Path
    part: _Shard
    device: str
    summary: GenerateSummary
    log: Log
    derivers: LRU = dataclasses.field(default_factory=lambda: LRU(DERIVERS))

    def deriver(self, garment):
        """The ``Deriver`` of ``garment``'s rest mesh (its base smoother's factorisation is ~2 s for
        a 20k-vertex garment), made once per mesh: sequences of a reference-fit garment share it.
        Keeps the ``DERIVERS`` meshes used last."""
        g = garment
        key = content_key(g.rest_vertices, g.faces, g.uvs, g.uv_faces, g.face_layers)
        fresh = key not in self.derivers
        made = self.derivers.get_or_make(key, lambda: self._new_deriver(garment))
        if fresh:
            self._evict()
        return made

    def _new_deriver(self, garment):
        from sim.datasets.derive import Deriver

        with phase("setup"):  # images are derived where they are read
            settings = dataclasses.replace(self.cfg.derive, image_resolution=0)
            return Deriver(garment, settings, device=self.device)

    def _evict(self) -> None:
        """Drop the least recently used derivers beyond ``DERIVERS``, or while their dense
        smoothers' device memory is over the device's ``dense_budget`` (the newest one stays)."""
        from sim.device import device_name
        from sim.geometry.smoothing import dense_budget

        budget = dense_budget(device_name(self.device))

        def held() -> int:
            return sum(d.smoother.device_bytes for d in self.derivers.values())

        while len(self.derivers) > self.derivers.size or (len(self.derivers) > 1 and held() > budget):
            self.derivers.popitem(last=False)


DERIVERS = 16
"""Garment meshes whose ``Deriver`` a generation keeps (``_Run.deriver``): more than the templates,
so a reference-fit dataset of every category derives each one's mesh once."""


def generate(cfg: DatasetConfig, out: str | os.PathLike, *, shard: int = 0, shards: int = 1,
             resume: bool = False, batch: int = 1, device: str | None = None,
             progress: Callable[[int, int], None] | None = None,
             log: Log | None = None, splits: Sequence[str] | None = None,
             combine: bool = True) -> GenerateSummary:
    """Make (or continue) shard ``shard`` of ``shards`` of the dataset in ``out``.

    Args:
        cfg: the validated generator config.
        out: dataset directory (created; may hold other shards of the same config).
        shard, shards: which share of the sequences this call makes.
        resume: continue a started shard (otherwise a started shard is an error).
        batch: sequences simulated together in one batched model.
        device: Warp device (None: the config's simulation device).
        progress: ``progress(done, total)`` over this shard's sequences.
        log: one line per accepted / rejected sequence.
        splits: make only the sequences of these splits (e.g. the test splits again on another
            machine); None: all. A sequence's split comes from the config, not from this run.
        combine: rebuild ``out/manifest.json`` from every part at the end (a task of a cluster
            job leaves that to the driver, ``sim.datasets.cluster``).

    Returns:
        counts and timings.
    """
    from sim.bodies import load_body
    from sim.device import resolve_device

    if not (0 <= shard < shards):
        raise WrinklesInputError(f"--shard {shard}/{shards}: need 0 <= i < n")
    if batch < 1:
        raise WrinklesInputError(f"--batch must be >= 1, got {batch}")
    specs = sample_sequences(cfg)
    mine = select_indices(specs, shard, shards, splits)
    root = Path(out)
    sim_cfg = cfg.simulation_config()
    dev = resolve_device(device if device is not None else sim_cfg.device)
    cfg_dict = config_record(cfg, dev)
    part = _open_shard(root, cfg_dict, shard, shards, resume)
    body = load_body(cfg.bodies.model)  # once: an SMPL file is not re-read for every group
    _remove_stale_temporaries(root, part, [specs[k] for k in mine])
    run = _Run(cfg, body, root, part, dev, GenerateSummary(), log or (lambda s: None))
    t0 = time.perf_counter()
    done = 0
    for group in [mine[k:k + batch] for k in range(0, len(mine), batch)]:
        todo = [sp for sp in (specs[k] for k in group) if not _recorded(run, sp)]
        if todo:
            # the whole group is simulated as in an uninterrupted run (same batch composition)
            _make_group(run, sim_cfg, [specs[k] for k in group], {s.id for s in todo})
        done += len(group)
        if progress is not None:
            progress(done, len(mine))
    run.summary.seconds = time.perf_counter() - t0
    if combine:
        finish_dataset(root, cfg_dict)
    return run.summary


def config_record(cfg: DatasetConfig, device: str) -> dict:
    """The config a dataset records (``config.json``, every part): the generator config and the
    simulator defaults of ``device``'s kind."""
    from sim.device import warp
    from sim.simulate import simulator_defaults

    return {**cfg.to_dict(), "simulator": simulator_defaults(cuda=warp().get_device(device).is_cuda)}


def prepare_dataset(root: Path, cfg_dict: dict, resume: bool, started: Sequence[Path] = ()) -> None:
    """The dataset's folders and ``config.json`` made where missing. Refused: a folder of another
    config, or (without ``resume``) a part in ``started`` that exists already."""
    _check_root(root, cfg_dict, resume)
    (root / S.SEQUENCE_DIR).mkdir(parents=True, exist_ok=True)
    (root / S.PARTS_DIR).mkdir(parents=True, exist_ok=True)
    if not (root / "config.json").exists():
        S.atomic_write_json(root / "config.json", cfg_dict)
    if not resume and any(p.exists() for p in started):
        raise WrinklesInputError("this dataset was already started here; pass --resume to continue it, or "
                                 "choose another --out", path=root)


def finish_dataset(root: Path, cfg_dict: dict) -> None:
    """``manifest.json`` and ``rejections.jsonl`` rebuilt from every part."""
    S.combine_parts(root, config=cfg_dict)
    _write_rejections(root)


def _open_shard(root: Path, cfg_dict: dict, shard: int, shards: int, resume: bool) -> _Shard:
    """The dataset's folders and ``config.json`` made where missing, and this shard's part."""
    prepare_dataset(root, cfg_dict, resume)
    return _Shard(root, cfg_dict, shard, shards, resume)


def _remove_stale_temporaries(root: Path, part: _Shard, specs: list[SequenceSpec]) -> None:
    """Temp files a killed run of this shard left (other shards' are theirs: they may be running)."""
    stale = [part.path.with_name(f".{part.path.name}.tmp")]
    stale += [(p := S.sequence_path(root, sp.id)).with_name(f".{p.name}.tmp") for sp in specs]
    for t in stale:
        for f in t.parent.glob(t.name + "*"):
            f.unlink(missing_ok=True)


def _recorded(run: _Run, sp: SequenceSpec) -> bool:
    """Whether ``sp`` is done: in the shard's part (skipped), or a sequence file written just
    before an interruption (its entry is inside; recorded now)."""
    part = run.part
    if sp.id in part.data["sequences"] or sp.id in part.data["rejected"]:
        run.summary.skipped += 1
        return True
    path = S.sequence_path(run.root, sp.id)
    if not path.exists():
        return False
    entry = json.loads(S.SequenceFile(path).metadata["entry"])
    entry.update(sha256=S.file_sha256(path), bytes=path.stat().st_size)
    part.data["sequences"][sp.id] = entry
    part.save()
    run.summary.recovered += 1
    return True


def _write_rejections(root: Path) -> None:
    lines = []
    for p in sorted((root / S.PARTS_DIR).glob("shard-*-of-*.json")):
        for sid, r in sorted(json.loads(p.read_text()).get("rejected", {}).items()):
            lines.append(json.dumps({"id": sid, **r}, sort_keys=True))
    S.atomic_write_bytes(root / S.REJECTIONS, ("\n".join(lines) + ("\n" if lines else "")).encode())


def sequence_inputs(cfg: DatasetConfig, sp: SequenceSpec, body):
    """The body shape (padded betas) and the motion of one sequence, built for that body: a
    procedural motion on its joints and soles, a BVH file's rest aligned to its joints, an AMASS
    file's Z-up translation exact for its pelvis."""
    from sim.motions import MotionSkeleton, load_motion
    from sim.motions.amass import place_pelvis

    betas = body.full_betas(sp.betas)
    motion = load_motion(sp.motion, fps=cfg.fps, duration=cfg.seconds,
                         skeleton=MotionSkeleton.from_body(body, betas), **sp.motion_params)
    return betas, place_pelvis(motion, body.rest_joints(betas)[body.body_joint_map[0]])


def garment_betas(cfg: DatasetConfig, body, betas: np.ndarray) -> np.ndarray:
    """The shape (padded betas, float32 (B,)) a sequence's garments are built on: its own
    ``betas`` with ``[garments] fit = "body"``, the mean shape (zeros) with "reference"."""
    if cfg.garments.fit == "reference":
        return body.full_betas(None)
    return np.asarray(betas, np.float32)


def _make_group(run: _Run, sim_cfg, group: list[SequenceSpec], wanted: set[str],
                retries: tuple[int, ...] | None = None, tried: tuple[int, ...] = (),
                attempts: dict[str, list[dict]] | None = None) -> None:
    """Simulate, judge, derive and write one batch of sequences. A sequence whose simulation
    fails (NaN / explosion) is frozen inside the batch while the others run on. The failed ones
    and those that fail a quality gate are then simulated again, batched together, at the
    substeps of the config's retries (``SimulationConfig.retry_substeps``: 20 and then 24
    instead of 12 by default, none for a fine garment: a step too long for a fast motion
    fails most fast sequences that fail, and an explosion is usually a step too large for a fast
    motion or a soft fabric) until they pass; a sequence that fails at the last is rejected with
    its reasons and the substeps tried. The provenance records the substeps a sequence used.
    ``retries``: the substeps still to try (None: the config's); ``tried``: those tried before;
    ``attempts``: per sequence id, the earlier rungs' substeps and reasons, kept with a rejection
    (``attempts``) and in an accepted sequence's provenance (``failed_attempts``), so what each rung
    of the ladder did is on record."""
    from dataclasses import replace

    from sim.simulate import simulate_batch

    sim_cfg = replace(sim_cfg, device=run.device)
    attempts = attempts or {}
    with phase("garments"):
        jobs, meta = group_jobs(run.cfg, run.body, group, run.device)
    with phase(f"simulation rung {len(tried) + 1}"):
        results = simulate_batch(jobs, config=sim_cfg, seed=group[0].seed, failures="return")
    largest = max(j.garment.num_vertices for j in jobs)
    substeps = sim_cfg.substeps_for(largest)
    if retries is None:
        retries = sim_cfg.retry_substeps(largest)
    with phase("judge"):
        by_seq, reasons_of = _judge(group, meta, results, substeps)
    # every failing sequence of the group is retried, wanted or not (one that is done, or not in
    # --splits): a retry batch is then the same on a resumed or split run, and so are its floats
    retried = [sp for sp in group if reasons_of[sp.id]] if retries else []
    if not any(sp.id in wanted for sp in retried):
        retried = []
    for sp in group:
        if sp.id not in wanted or (reasons_of[sp.id] and retries):
            continue  # a failing one is written by its retry, below
        if reasons_of[sp.id]:
            _reject(run, sp, by_seq[sp.id], reasons_of[sp.id],
                    substeps=[*tried, substeps],
                    attempts=[*attempts.get(sp.id, []), {"substeps": substeps, "reasons": reasons_of[sp.id]}])
        else:
            _accept(run, sp, by_seq[sp.id], attempts.get(sp.id))
    if retried:  # after the batch's good results are stored: an interrupted retry loses only itself
        for sp in retried:
            if sp.id in wanted:
                run.log(f"{sp.id}: {'; '.join(reasons_of[sp.id])}; retrying at {retries[0]} substeps")
        _make_group(run, replace(sim_cfg, substeps=retries[0]), retried,
                    {sp.id for sp in retried if sp.id in wanted}, retries=retries[1:],
                    tried=(*tried, substeps),
                    attempts={sp.id: [*attempts.get(sp.id, []),
                                      {"substeps": substeps, "reasons": reasons_of[sp.id]}]
                              for sp in retried})


def group_jobs(cfg: DatasetConfig, body, group: list[SequenceSpec],
                device: str) -> tuple[list, list[tuple]]:
    """The simulation jobs of a group (fine, and coarse where the config derives it, per
    sequence) and, per job, ``(spec, garment, motion, betas, kind)``; the group's garments are
    made together, the new ones sewn in one batch on ``device``."""
    from dataclasses import replace

    from sim.garments.designs import GarmentRequest
    from sim.garments.templates import make_garments
    from sim.simulate import SimulationJob

    kinds = {"fine": cfg.garments.fine_resolution}
    if cfg.derive.coarse:
        kinds["coarse"] = cfg.garments.coarse_resolution
    reference = cfg.garments.fit == "reference"
    if reference:  # one cut for every material: the clearance of the thickest fabric
        from sim.garments.materials import get_material

        cut_material = max(cfg.materials.names, key=lambda m: get_material(m).thickness)
    orders: dict[tuple, GarmentRequest] = {}  # "reference" fit: one cut per category / params
    wanted = []
    for sp in group:
        betas, motion = sequence_inputs(cfg, sp, body)
        gbetas = garment_betas(cfg, body, betas)
        for kind, resolution in kinds.items():
            gkey = (sp.category, kind, None if reference else sp.material,
                    json.dumps(sp.garment_params, sort_keys=True), gbetas.tobytes())
            orders.setdefault(gkey, GarmentRequest(sp.category, body, gbetas, resolution,
                                                   cut_material if reference else sp.material, sp.category,
                                                   dict(sp.garment_params)))
            wanted.append((sp, betas, motion, gbetas, kind, gkey))
    # the group's new garments sewn in one batch
    garments = dict(zip(orders, make_garments(list(orders.values()), device=device), strict=True))
    jobs, meta = [], []
    for sp, betas, motion, gbetas, kind, gkey in wanted:
        garment = garments[gkey]
        if reference:
            garment = replace(garment, material=get_material(sp.material))
        jobs.append(SimulationJob(garment, body, motion, betas=betas, name=f"{sp.id} {kind}",
                                  garment_betas=None if cfg.garments.fit == "body" else gbetas))
        meta.append((sp, garment, motion, betas, kind))
    return jobs, meta


def _judge(group: list[SequenceSpec], meta: list[tuple], results: list,
           substeps: int) -> tuple[dict[str, dict], dict[str, list[str]]]:
    """Per sequence id: its ``{"spec", "motion", "betas", "fine": (garment, result)[, "coarse":
    ...]}``, and why it fails (empty: it passed); a result is a ``SimulationResult`` or the
    ``SimulationError`` that stopped it."""
    from sim.quality import SimulationError

    failed = {sp.id: r for (sp, *_), r in zip(meta, results, strict=True) if isinstance(r, SimulationError)}
    by_seq: dict[str, dict] = {}
    for k, (sp, garment, motion, betas, kind) in enumerate(meta):
        by_seq.setdefault(sp.id, {"spec": sp, "motion": motion, "betas": betas})[kind] = (garment, results[k])
    reasons_of: dict[str, list[str]] = {}
    for sp in group:
        item = by_seq[sp.id]
        if sp.id in failed:
            reasons_of[sp.id] = [f"{failed[sp.id]} (at {substeps} substeps)"]
        else:
            reasons_of[sp.id] = [f"fine: {r}" for r in item["fine"][1].failed_gates]
            if "coarse" in item:
                reasons_of[sp.id] += [f"coarse: {r}" for r in item["coarse"][1].failed_gates]
    return by_seq, reasons_of


def _reject(run: _Run, sp: SequenceSpec, item: dict, reasons: list[str], *, substeps: list[int],
            attempts: list[dict]) -> None:
    """Record a sequence that failed at its last rung, with everything needed to simulate it
    again (``wrinkles simulate``, ``benchmarks.worst_edges --shape --motion-param``): its body,
    garment and motion parameters and its seed."""
    from sim.quality import SimulationError, garment_body_crossings, short_crossings

    cfg = run.cfg
    fine_g, fine_r = item["fine"]
    rejected = {"index": sp.index, "garment": sp.category,
                "motion": sp.motion_label, "material": sp.material,
                "reasons": reasons, "substeps": substeps, "attempts": attempts,
                "seed": sp.seed, "split": sp.split, "betas": list(sp.betas),
                "fit": cfg.garments.fit, "garment_params": sp.garment_params,
                "motion_source": sp.motion, "motion_params": sp.motion_params,
                "vertices": int(fine_g.num_vertices)}
    run.part.data["rejected"][sp.id] = rejected
    if not isinstance(fine_r, SimulationError):  # where the body passes through itself near the cloth
        rejected["body_self_crossings"] = short_crossings(garment_body_crossings(
            run.body, item["betas"], fine_g, fine_r.sequence.body.vertices, device=run.device))
    run.part.save()
    run.part.event(sp.id, "rejected", 0)
    run.summary.rejected += 1
    run.log(f"{sp.id} rejected ({sp.category}, {sp.motion_label}): {'; '.join(reasons)}")


def _accept(run: _Run, sp: SequenceSpec, item: dict, failed_attempts: list[dict] | None) -> None:
    """Derive a passing sequence's arrays, write its file and record its manifest entry."""
    cfg = run.cfg
    fine_g, fine_r = item["fine"]
    seq = fine_r.sequence
    with phase("derive"):
        arrays, derived = _sequence_arrays(run, item)
    T = seq.vertices.shape[0]
    entry = {"file": f"{S.SEQUENCE_DIR}/{sp.id}{S.SUFFIX}", "frames": int(T), "split": sp.split,
             "index": sp.index, "seed": sp.seed, "garment": sp.category,
             "garment_params": sp.garment_params, "material": sp.material, "motion": sp.motion_label,
             "motion_params": sp.motion_params,
             "betas": list(sp.betas), "fit": cfg.garments.fit,
             "garment_betas": list(sp.betas) if cfg.garments.fit == "body" else [0.0] * len(sp.betas),
             "vertices": int(fine_g.num_vertices),
             "faces": int(fine_g.num_faces), "uvs": int(len(fine_g.uvs)),
             "coarse_vertices": int(item["coarse"][0].num_vertices) if "coarse" in item else None,
             "image_resolution": [res, res] if (res := cfg.derive.image_resolution) else None,
             "quality": _entry_quality(fine_r.quality, derived["fine/wrinkle"],
                                       derived["fine/strain_norm"])}
    prov = {**seq.provenance, "seed": sp.seed}
    if failed_attempts:  # the rungs it failed before the one it passed at
        prov["failed_attempts"] = failed_attempts
    meta_json = {"entry": json.dumps(entry, sort_keys=True),
                 "sequence": json.dumps(sp.to_json(), sort_keys=True),
                 "provenance": json.dumps(_stable(prov), sort_keys=True, default=str),
                 "body": json.dumps({"model": cfg.bodies.model, "name": getattr(run.body, "name", "body")}),
                 DERIVE_META: json.dumps(dataclasses.asdict(cfg.derive), sort_keys=True)}
    path = S.sequence_path(run.root, sp.id)
    with phase("write"):
        sha = S.write_sequence(path, arrays, meta_json)
    entry.update(sha256=sha, bytes=path.stat().st_size)
    run.part.data["sequences"][sp.id] = entry
    run.part.save()
    run.part.event(sp.id, "accepted", T)
    run.summary.accepted += 1
    run.summary.garment_frames += T
    run.summary.bytes += entry["bytes"]
    run.log(f"{sp.id} accepted ({sp.category}, {sp.material}, {sp.motion_label}, {sp.split}): {T} frames, "
            f"{entry['bytes'] / 2**20:.1f} MiB")


def _sequence_arrays(run: _Run, item: dict) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The arrays a sequence file stores (``sim.datasets.schema``: positions, rest garments, the
    body's motion, the per-frame quality) and the fine fields derived from the stored positions
    (as a reader derives them, ``sim.datasets.fields``) that the manifest's quality summary
    reads."""
    from sim.datasets.fields import FINE_DERIVED
    from sim.quality import edge_strain

    body, device = run.body, run.device
    fine_g, fine_r = item["fine"]
    seq = fine_r.sequence
    arrays, fine = _positions("fine/vertices", seq.vertices, run.cfg.derive.positions)
    derived = run.deriver(fine_g)(fine)
    arrays.update({k: v for k, v in derived.items() if k not in (*FINE_DERIVED, "fine/vertices")})
    if "coarse" in item:
        coarse_g, coarse_r = item["coarse"]
        arrays.update(_positions("coarse/vertices", coarse_r.sequence.vertices, run.cfg.derive.positions)[0])
        arrays.update({"coarse/rest_vertices": coarse_g.rest_vertices, "coarse/faces": coarse_g.faces,
                       "coarse/uvs": coarse_g.uvs, "coarse/uv_faces": coarse_g.uv_faces})
    poses = np.asarray(seq.motion.poses, np.float32)
    trans = np.asarray(seq.motion.trans, np.float32)
    # the simulated body may stand on the floor by a constant offset: fold it into trans so
    # body.pose(betas, poses, trans) gives the simulated body back
    posed = body.pose(item["betas"], poses[:1], trans[:1])
    trans = trans + (seq.body.joints[0, 0] - posed.joints[0, 0]).astype(np.float32)
    with phase("edge strain"):
        fine_strain = edge_strain(seq.vertices, fine_g.rest_vertices, fine_g.faces, device=device,
                                  rest_lengths=fine_g.rest_edge_lengths())
    arrays.update({"body/poses": poses, "body/trans": trans,
                   "body/joints": np.asarray(seq.body.joints, np.float32),
                   "body/betas": np.asarray(item["betas"], np.float32),
                   "quality/edge_strain_max": np.abs(fine_strain).max(axis=1).astype(np.float32),
                   "quality/inside_fraction": np.asarray(fine_r.quality.inside_fraction, np.float32),
                   "quality/self_intersections": np.asarray(fine_r.quality.self_intersections, np.int32)})
    return arrays, derived


def _positions(name: str, x: np.ndarray, form: str) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The stored arrays of positions ``x`` in ``form`` ("f32" or "i16", ``[derive] positions``)
    and the positions a reader gets back from them."""
    from sim.datasets.quantize import SUFFIXES, dequantize, quantized_arrays

    if form == "f32":
        x = np.asarray(x, np.float32)
        return {name: x}, x
    stored = quantized_arrays(name, x)
    return stored, dequantize(*(stored[name + s] for s in SUFFIXES))


def _stable(prov: dict) -> dict:
    """Provenance without what changes between identical runs (timings)."""
    return {k: v for k, v in prov.items() if k not in ("timings", "wall_seconds", "date")}
