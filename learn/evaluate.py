"""The evaluation harness: the one path every method's numbers come from.

For each sequence of a dataset split, the method predicts the fine garment from the sequence's
inputs (``Method.predict_sequence``); predictions and ground truth then go through the SAME
derivation (``sim.datasets.derive.Deriver``: base surface, wrinkle field, normals, UV maps)
and the shared metrics (``learn.metrics``):

==================  =====  ==========================================================================
key                 unit   meaning
==================  =====  ==========================================================================
ev                  m      mean L2 vertex distance (Guo et al. 2024 Sec. 4.1 ``Ev``)
ecd                 m^2    symmetric squared Chamfer distance (``Ecd``)
bending_error       rad    mean |angle - angle_gt| of adjacent-face normal angles (GSNet Sec. 4.3)
normal_angle        rad    mean angle between the vertex normals at the ends of each edge, GSNet's
                           "bending angle between vertex normals" (``normal_angle_gt``: of the
                           ground truth)
edge_abs            -      mean |l/l0 - 1| of the prediction (``edge_abs_gt``: of the ground truth)
collision           -      fraction of garment vertices inside the body (``collision_gt``)
flicker_ratio       -      second-difference flicker of the prediction over the ground truth's
spectrum_distance   -      mean |log10 P - log10 P_gt| of the radially averaged power spectra of the
                           UV wrinkle maps (``wavelength``/``wavelength_gt``: dominant wavelength, px)
normal_fd           -      Frechet distance between features of predicted and ground-truth UV
                           tangent-space normal maps, over the whole split, from the project's fixed
                           extractor (``learn.metrics.features``; NOT Inception FID, not comparable
                           with the papers' FID numbers)
nm_l1, nm_l2        -      DeepWrinkles only (``Prediction.metrics``): mean absolute / squared pixel
                           difference of its HR normal maps and the simulation's (Lähner et al.
                           Table 1, "Data")
nm_temporal         -      its Eq. 4 temporal term against the simulation's previous frame ("Temporal")
==================  =====  ==========================================================================

Per-sequence values are means over frames; the summary averages sequences (each sequence counts
once) except ``normal_fd``, a distribution distance over all frames of the split.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from learn.methods.base import Method, Prediction
from sim.errors import WrinklesInputError

METRIC_UNITS = {"ev": "m", "ecd": "m^2", "bending_error": "rad", "normal_angle": "rad",
                "normal_angle_gt": "rad", "edge_abs": "-", "edge_abs_gt": "-",
                "collision": "-", "collision_gt": "-", "flicker_ratio": "-", "spectrum_distance": "-",
                "wavelength": "px", "wavelength_gt": "px", "normal_fd": "-", "nm_l1": "-", "nm_l2": "-",
                "nm_temporal": "-"}
"""Every metric key the harness reports, with its unit."""

FD_NOTE = ("normal_fd: Frechet distance of features from the project's fixed normal-map extractor "
           "(learn.metrics.features), not Inception FID")


@dataclass
class SequenceResult:
    """Metrics of one sequence (means over its frames)."""

    id: str
    garment: str
    frames: int
    vertices: int
    metrics: dict[str, float]
    seconds: float


@dataclass
class Evaluation:
    """What the harness measured on one split.

    Attributes:
        split: the dataset split.
        sequences: per-sequence results, in id order.
        summary: metric -> mean over sequences (``normal_fd`` over all frames).
        examples: a few (sequence id, frame, arrays) for pictures: ``pred``/``gt`` vertices,
            faces, and UV maps when the dataset has a UV layout.
        notes: caveats to print with every table.
    """

    split: str
    sequences: list[SequenceResult]
    summary: dict[str, float]
    examples: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"split": self.split, "summary": self.summary, "units": METRIC_UNITS, "notes": self.notes,
                "sequences": [vars(s) for s in self.sequences]}


def _garment_for(sf, entry: dict):
    from sim.garments.materials import get_material
    from sim.garments.types import Garment

    try:
        material = get_material(entry.get("material") or "cotton")
    except Exception:  # an unknown preset name: the derivation does not use the material
        material = get_material("cotton")
    return Garment(rest_vertices=np.asarray(sf["fine/rest_vertices"]), faces=np.asarray(sf["fine/faces"]),
                   uvs=np.asarray(sf["fine/uvs"]), uv_faces=np.asarray(sf["fine/uv_faces"]),
                   face_layers=np.asarray(sf["fine/face_layers"]) if "fine/face_layers" in sf else None,
                   material=material,
                   category=entry.get("garment", "imported"))


def _body_vertices(sf, body, device: str | None) -> tuple[np.ndarray, np.ndarray] | None:
    if body is None:
        return None
    betas = np.asarray(sf["body/betas"], np.float32).reshape(-1)[: body.num_betas]
    frames = body.pose(betas, np.asarray(sf["body/poses"]), np.asarray(sf["body/trans"]), device=device)
    return frames.vertices, frames.faces


def sequence_metrics(pred: np.ndarray, sf, entry: dict, body, *, derive_config, device: str | None,
                     extractor=None) -> tuple[dict[str, float], dict]:
    """Metrics of one predicted sequence against its ground truth (module table).

    Args:
        pred: predicted positions [m], (T, V, 3).
        sf: the sequence file (``sim.datasets.storage.SequenceFile``).
        entry: its manifest entry; body: the ``BodyModel`` it was simulated on (None: no
            collision metrics).
        derive_config: ``DeriveConfig`` for the base surface and UV maps of both.
        device: Warp device; extractor: ``NormalMapFeatures`` (features of the normal maps).

    Returns:
        (metrics, maps): per-sequence metric means, and per-frame arrays the split-level metrics
        need (``features_pred``/``features_gt`` (T, D), ``wrinkle_pred``/``wrinkle_gt``, ``mask``).
    """
    from learn import metrics as M
    from sim.datasets.derive import Deriver

    gt = np.array(sf["fine/vertices"], np.float32)  # a writable copy (the file is memory-mapped)
    if pred.shape != gt.shape:
        raise ValueError(f"{entry.get('file')}: prediction has shape {pred.shape}, ground truth {gt.shape}")
    faces = np.array(sf["fine/faces"])  # writable copies: torch refuses read-only memory maps
    rest = np.array(sf["fine/rest_vertices"], np.float32)
    p, g = torch.from_numpy(pred).double(), torch.from_numpy(gt).double()
    out = {"ev": float(M.vertex_error(p, g).mean()),
           "ecd": float(M.chamfer_distance(p, g).mean())}
    out["bending_error"] = float(M.bending_error(p, g, faces).mean())
    edges = M.mesh_edges(faces)
    out["normal_angle"] = float(M.vertex_normal_angles(p, faces, edges=edges).mean())
    out["normal_angle_gt"] = float(M.vertex_normal_angles(g, faces, edges=edges).mean())
    r = torch.from_numpy(rest).double()
    out["edge_abs"] = float(M.edge_elongation(p, r, edges).abs_mean.mean())
    out["edge_abs_gt"] = float(M.edge_elongation(g, r, edges).abs_mean.mean())
    posed = _body_vertices(sf, body, device)
    if posed is not None:
        out["collision"] = float(np.mean(M.collision_rate(pred, posed[0], posed[1], device=device)))
        out["collision_gt"] = float(np.mean(M.collision_rate(gt, posed[0], posed[1], device=device)))
    if gt.shape[0] >= 3:
        out["flicker_ratio"] = float(M.flicker_ratio(p, g))
    maps: dict = {}
    if derive_config.image_resolution:
        deriver = Deriver(_garment_for(sf, entry), derive_config, device=device)
        dp, dg = deriver(pred), deriver(gt)
        mask = dg["images/mask"].astype(bool)
        wp_, wg = dp["images/wrinkle"].astype(np.float32), dg["images/wrinkle"].astype(np.float32)
        sp, sg = M.radial_power_spectrum(wp_, mask=mask), M.radial_power_spectrum(wg, mask=mask)
        out["spectrum_distance"] = float(M.spectrum_profile_distance(sp, sg).mean())
        out["wavelength"] = float(M.dominant_wavelength(sp).mean())
        out["wavelength_gt"] = float(M.dominant_wavelength(sg).mean())
        npred = dp["images/normal_tangent"].astype(np.float32)
        ngt = dg["images/normal_tangent"].astype(np.float32)
        maps = {"features_pred": extractor(npred, mask).cpu().numpy(),
                "features_gt": extractor(ngt, mask).cpu().numpy(),
                "normal_pred": npred, "normal_gt": ngt, "wrinkle_pred": wp_, "wrinkle_gt": wg, "mask": mask}
    return out, maps


class BaseOnly(Method):
    """The "base mesh alone" row of Guo et al.'s tables: predicts the base surface itself (the
    data's smoothed ``fine/base``, or a coarse model's base), no wrinkles. Needs no model."""

    name = "base_only"

    def __init__(self):
        super().__init__(None)

    def predict_sequence(self, model, sequence, *, device, base=None) -> Prediction:
        return Prediction(np.asarray(sequence["fine/base"] if base is None else base, np.float32))


def evaluate(method: Method, model: torch.nn.Module, data_root: str | os.PathLike, split: str = "test_id", *,
             device: torch.device | str = "cpu", warp_device: str | None = None,
             max_sequences: int | None = None,
             image_resolution: int | None = None, examples: int = 3, garments: tuple[str, ...] | None = None,
             coarse: tuple[Method, torch.nn.Module] | None = None, predict_options: dict | None = None,
             progress=None) -> Evaluation:
    """Predict every sequence of ``split`` and measure it (module docstring).

    Args:
        method, model: a trained method (``learn.train.trainer.load_trained``).
        data_root: dataset directory; split: ``train``, ``test_id``, ``test_ood`` or ``all``.
        device: torch device of the model; warp_device: Warp device for derivation and bodies.
        max_sequences: evaluate only the first N sequences (id order).
        image_resolution: UV map side for the map metrics (default: the dataset's, else 128;
            0: no map metrics).
        examples: how many (sequence, frame) examples to keep for pictures.
        garments: only these garment categories (default: the method's ``config.garments``, if any).
        coarse: a coarse model ``(method, model)`` (e.g. ``skeleton_cvae``) whose prediction is the
            base surface handed to ``method.predict_sequence(..., base=...)`` (methods that refine a
            base: ``wrinkle_diffusion``, ``displacement_regressor``, :class:`BaseOnly`); None: those
            methods use the data's base (``fine/base``).
        predict_options: more keyword arguments of ``method.predict_sequence`` (e.g. ``seed``,
            ``steps`` of the diffusion).
        progress: ``progress(done, total)`` callback.

    Raises:
        WrinklesInputError: unreadable dataset, an empty split.
    """
    from learn.data import sequence_inputs
    from learn.metrics import NormalMapFeatures
    from sim.datasets.storage import SequenceFile, read_manifest, sequence_path

    root = Path(data_root)
    manifest = read_manifest(root)
    if garments is None:
        garments = tuple(getattr(method.config, "garments", ()) or ()) or None
    if coarse is not None and garments is None:
        garments = tuple(getattr(coarse[0].config, "garments", ()) or ()) or None
    entries = _split_entries(manifest, root, split, garments, max_sequences)
    derive_config = _derive_config(manifest, image_resolution)
    extractor = NormalMapFeatures(device=device) if derive_config.image_resolution else None
    body_for = _BodyCache()
    dev = torch.device(device)

    results, fp, fg, example_list = [], [], [], []
    for k, (sid, entry) in enumerate(entries.items()):
        t0 = time.perf_counter()
        sf = SequenceFile(sequence_path(root, sid) if "file" not in entry else root / entry["file"])
        seq = sequence_inputs(sf, entry, manifest.get("config") or {})
        body_name = str(seq["body/model"])
        opts = dict(predict_options or {})
        if coarse is not None:
            opts["base"] = coarse[0].predict_sequence(coarse[1], seq, device=dev).vertices
        pred: Prediction = method.predict_sequence(model, seq, device=dev, **opts)
        m, maps = sequence_metrics(np.asarray(pred.vertices, np.float32), sf, entry, body_for(body_name),
                                   derive_config=derive_config, device=warp_device, extractor=extractor)
        m.update(pred.metrics)
        if maps:
            fp.append(maps["features_pred"])
            fg.append(maps["features_gt"])
        if len(example_list) < examples:
            example_list.append(_example(sid, seq, pred, maps))
        T, V = seq["fine/vertices"].shape[:2]
        results.append(SequenceResult(id=sid, garment=str(entry.get("garment", "")), frames=int(T),
                                      vertices=int(V), metrics=m,
                                      seconds=time.perf_counter() - t0))
        if progress is not None:
            progress(k + 1, len(entries))
    summary, notes = _summary(results, fp, fg)
    return Evaluation(split=split, sequences=results, summary=summary, examples=example_list, notes=notes)


def _split_entries(manifest: dict, root: Path, split: str, garments: tuple[str, ...] | None,
                   max_sequences: int | None) -> dict[str, dict]:
    """The manifest entries of ``split`` (and ``garments``), in id order, at most ``max_sequences``."""
    from sim.datasets.schema import SPLITS

    if split not in (*SPLITS, "all"):
        raise WrinklesInputError(f"split {split!r}: choose one of {', '.join((*SPLITS, 'all'))}")
    entries = {sid: e for sid, e in sorted(manifest.get("sequences", {}).items())
               if (split == "all" or e.get("split") == split)
               and (not garments or e.get("garment") in garments)}
    if max_sequences is not None:
        entries = dict(list(entries.items())[:max_sequences])
    if not entries:
        raise WrinklesInputError(f"no sequences in split {split!r}"
                                 + (f" for garments {', '.join(garments)}" if garments else ""), path=root)
    return entries


def _derive_config(manifest: dict, image_resolution: int | None):
    """The dataset's derivation (its smoothing length), at ``image_resolution`` (default: the
    dataset's, else 128)."""
    from sim.datasets.config import DeriveConfig

    dcfg = manifest.get("config", {}).get("derive", {}) or {}
    res = image_resolution if image_resolution is not None else (dcfg.get("image_resolution") or 128)
    return DeriveConfig(smoothing_length=float(dcfg.get("smoothing_length", 0.04)),
                        image_resolution=int(res), coarse=False)


class _BodyCache:
    """Body models by name, each loaded once; None for a model file not on this machine (no
    collision metrics)."""

    def __init__(self) -> None:
        self.bodies: dict[str, object] = {}

    def __call__(self, name: str):
        from sim.bodies import load_body

        if name not in self.bodies:
            try:
                self.bodies[name] = load_body(name)
            except WrinklesInputError:
                self.bodies[name] = None
        return self.bodies[name]


SURFACE_SHADINGS = (("global shape", "global_normals"), ("global shape + predicted HR map", "detail_normals"))
"""Shadings of a prediction's base surface in the close-ups: (title, ``Prediction.extras`` key of
its per-vertex normals)."""


def _example(sid: str, seq: dict, pred: Prediction, maps: dict) -> dict:
    """The middle frame of a sequence for pictures: prediction, ground truth, error, UV maps."""
    t = seq["fine/vertices"].shape[0] // 2
    gt_t = seq["fine/vertices"][t]
    ex = {"sequence": sid, "frame": t, "pred": pred.vertices[t], "gt": gt_t,
          "faces": seq["fine/faces"], "error": np.linalg.norm(pred.vertices[t] - gt_t, axis=-1)}
    if maps:
        ex.update({key: maps[key][t] for key in ("normal_pred", "normal_gt", "wrinkle_pred", "wrinkle_gt")})
        ex["mask"] = maps["mask"]
    T = seq["fine/vertices"].shape[0]
    images = {k: np.asarray(v[t]) for k, v in pred.extras.items()
              if np.ndim(v) == 4 and len(v) == T and np.shape(v)[-1] == 3}
    if images:
        ex["method_maps"] = images  # the method's own UV maps (e.g. DeepWrinkles' LR / HR normal maps)
    if "global_surface" in pred.extras:  # a base surface the maps shade (DeepWrinkles' global shape)
        ex["surface"] = np.asarray(pred.extras["global_surface"][t])
        ex["surface_normals"] = {name: np.asarray(pred.extras[key][t]) for name, key in SURFACE_SHADINGS
                                 if key in pred.extras}
    return ex


def _summary(results: list[SequenceResult], fp: list, fg: list) -> tuple[dict[str, float], list[str]]:
    """Every metric's mean over sequences, ``normal_fd`` over all frames; the notes to print."""
    from learn.metrics import frechet_distance

    keys = [k for k in METRIC_UNITS if any(k in r.metrics for r in results)]
    summary = {k: float(np.mean([r.metrics[k] for r in results if k in r.metrics])) for k in keys}
    notes = []
    if fp:
        summary["normal_fd"] = frechet_distance(np.concatenate(fp), np.concatenate(fg))
        notes.append(FD_NOTE)
    return summary, notes


def format_table(ev: Evaluation, *, title: str = "") -> str:
    """The summary as a plain-text table (metric, value, unit), with the notes under it."""
    rows = [(k, f"{v:.6g}", METRIC_UNITS.get(k, "")) for k, v in ev.summary.items()]
    w0 = max([len("metric"), *(len(r[0]) for r in rows)])
    w1 = max([len("value"), *(len(r[1]) for r in rows)])
    head = f"{title}\n" if title else ""
    lines = [f"{'metric':<{w0}}  {'value':>{w1}}  unit", f"{'-' * w0}  {'-' * w1}  ----"]
    lines += [f"{a:<{w0}}  {b:>{w1}}  {c}" for a, b, c in rows]
    frames = sum(s.frames for s in ev.sequences)
    lines += [f"{len(ev.sequences)} sequences, {frames} frames, split {ev.split}"]
    lines += [f"note: {n}" for n in ev.notes]
    return head + "\n".join(lines)
