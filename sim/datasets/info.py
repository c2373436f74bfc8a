"""Counts and statistics of a dataset, from its manifest alone (``wrinkles dataset info``;
numpy and the standard library: no torch)."""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Mapping

import numpy as np

from sim.datasets.schema import SPLITS
from sim.datasets.storage import read_manifest

ALL_SPLITS = "all"


def manifest_statistics(manifest: Mapping, *, split: str = ALL_SPLITS) -> dict:
    """Summary of a dataset manifest, for ``wrinkles dataset info`` (JSON-serialisable).

    Args:
        manifest: as returned by ``sim.datasets.storage.read_manifest``.
        split: summarise only this split (``"all"``: every sequence).

    Returns:
        a dict with

        - ``sequences``, ``frames``, ``bytes``: totals of the accepted sequences (in ``split``);
        - ``rejected``: number of rejected sequences (whole dataset: rejections have no split);
        - ``splits``, ``garments``, ``materials``, ``motions``: per value of that manifest field,
          ``{"sequences": n, "frames": f, "bytes": b}``, sorted by name;
        - ``garment_splits``: ``{garment: {split: sequences}}``;
        - ``quality``: per manifest quality field, ``{"mean", "max", "min", "count"}`` over the
          sequences (each sequence weighs one, whatever its length; non-finite values are left
          out of mean/min/max and counted in ``"nonfinite"``);
        - ``image_resolutions``: ``{"HxW": sequences}`` (``"none"`` for no images).
    """
    if split != ALL_SPLITS and split not in SPLITS:
        raise ValueError(f"split {split!r}: choose one of {', '.join((*SPLITS, ALL_SPLITS))}")
    entries = [e for _, e in sorted(manifest.get("sequences", {}).items())
               if split == ALL_SPLITS or e.get("split") == split]

    def group(field: str) -> dict:
        out: dict[str, dict] = {}
        for e in entries:
            g = out.setdefault(str(e.get(field)), {"sequences": 0, "frames": 0, "bytes": 0})
            g["sequences"] += 1
            g["frames"] += int(e.get("frames", 0))
            g["bytes"] += int(e.get("bytes", 0))
        return dict(sorted(out.items()))

    garment_splits: dict[str, dict[str, int]] = {}
    for e in entries:
        row = garment_splits.setdefault(str(e.get("garment")), {})
        row[str(e.get("split"))] = row.get(str(e.get("split")), 0) + 1
    resolutions: dict[str, int] = {}
    for e in entries:
        r = e.get("image_resolution")
        name = f"{r[0]}x{r[1]}" if r else "none"
        resolutions[name] = resolutions.get(name, 0) + 1

    values: dict[str, list[float]] = {}
    for e in entries:
        for k, v in (e.get("quality") or {}).items():
            if v is not None:
                values.setdefault(k, []).append(float(v))
    quality = {}
    for k, vs in sorted(values.items()):
        a = np.asarray(vs, np.float64)
        fin = a[np.isfinite(a)]
        q = {"count": int(a.size), "nonfinite": int(a.size - fin.size)}
        if fin.size:
            q.update(mean=float(fin.mean()), min=float(fin.min()), max=float(fin.max()))
        else:
            q.update(mean=None, min=None, max=None)
        quality[k] = q

    return {
        "split": split,
        "sequences": len(entries),
        "frames": sum(int(e.get("frames", 0)) for e in entries),
        "bytes": sum(int(e.get("bytes", 0)) for e in entries),
        "rejected": len(manifest.get("rejected", {})),
        "splits": group("split"),
        "garments": group("garment"),
        "materials": group("material"),
        "motions": group("motion"),
        "garment_splits": dict(sorted((g, dict(sorted(r.items()))) for g, r in garment_splits.items())),
        "image_resolutions": dict(sorted(resolutions.items())),
        "quality": quality,
    }


def rejection_kind(reason: str) -> str:
    """A rejection reason by kind, keeping which garment failed ("fine: edge strain") or that
    the simulation stopped ("stopped: explosion")."""
    where = reason.split(":", 1)[0]
    return f"{'stopped' if where.startswith('simulation failed') else where}: {_kind(reason)}"


def _kind(reason: str) -> str:
    r = reason.lower()
    kinds = {"self-intersection": "self-intersection", "edge strain": "edge strain",
             "inside the body": "inside the body", "non-finite": "non-finite", "explo": "explosion",
             "speed": "speed", "stretch": "stretch"}
    for k, name in kinds.items():
        if k in r:
            return name
    return reason.split(":", 1)[-1].strip()[:40]


def dataset_statistics(root: str | os.PathLike, *, split: str = ALL_SPLITS) -> dict:
    """:func:`manifest_statistics` of the dataset in ``root``, plus ``root``, ``bytes_per_frame``,
    the fine / coarse vertex counts, the rejection reasons by kind, the quality ``gates`` the
    sequences passed, ``accepted_share`` (accepted of all made), the schema version, the stored
    ``positions`` format, and ``derived_cached``: sequences whose derived fields are in the
    dataset's cache (``sim.datasets.fields``)."""
    m = read_manifest(root)
    s = manifest_statistics(m, split=split)
    entries = [e for e in m["sequences"].values() if split == ALL_SPLITS or e.get("split") == split]
    reasons: Counter = Counter()
    for r in m.get("rejected", {}).values():
        for text in r.get("reasons", []):
            reasons[rejection_kind(text)] += 1
    s.update(root=os.fspath(root), bytes_per_frame=s["bytes"] / max(s["frames"], 1),
             vertices={"fine": sorted({int(e["vertices"]) for e in entries}),
                       "coarse": sorted({int(e["coarse_vertices"]) for e in entries
                                         if e.get("coarse_vertices")})},
             rejection_reasons=dict(reasons.most_common()))
    made = len(m.get("sequences", {})) + s["rejected"]
    s.update(schema_version=m.get("schema_version"), gates=_gates(m.get("config") or {}),
             positions=((m.get("config") or {}).get("derive") or {}).get("positions", "f32"),
             accepted_share=len(m.get("sequences", {})) / made if made else None,
             derived_cached=_derived_cached(root, entries))
    return s


def _gates(config: Mapping) -> dict:
    """The quality gates of a generator config (``[simulation] gates``, defaults filled in)."""
    import dataclasses

    from sim.quality import QualityGates

    given = ((config.get("simulation") or {}).get("gates") or {})
    return {**dataclasses.asdict(QualityGates()), **given}


def _derived_cached(root, entries: list[dict]) -> int:
    """How many of ``entries`` have a file in the dataset's cache of derived fields (current or
    not: checking needs each sequence's checksum; ``wrinkles dataset derive`` makes them current)."""
    from pathlib import Path

    from sim.datasets.fields import DERIVED_DIR

    folder = Path(root) / DERIVED_DIR
    return sum((folder / Path(e["file"]).name).exists() for e in entries) if folder.is_dir() else 0


def format_statistics(s: dict) -> str:
    """A plain-text table of :func:`dataset_statistics`."""
    share = "" if s.get("accepted_share") is None else f", {100 * s['accepted_share']:.0f} % accepted"
    lines = [f"{s['root']}: {s['sequences']} sequences ({s['rejected']} rejected{share}), "
             f"{s['frames']} frames, "
             f"{s['bytes'] / 2**20:.1f} MiB, {s['bytes_per_frame'] / 1024:.1f} KiB per frame"]
    if "gates" in s:
        lines.append(f"  storage:   schema {s['schema_version']}, positions {s['positions']}, derived fields "
                     f"cached for {s['derived_cached']} of {s['sequences']} ('wrinkles dataset derive')")
        lines.append("  gates:     " + ", ".join(f"{k} {v}" for k, v in s["gates"].items()))
    if s["sequences"]:
        lines.append(f"  vertices: fine {s['vertices']['fine']}, coarse {s['vertices']['coarse']}")
    for key in ("splits", "garments", "materials", "motions"):
        items = ", ".join(f"{k} {v['sequences']} ({v['frames']} frames)" for k, v in s[key].items())
        lines.append(f"  {key + ':':11s}{items}")
    lines.append("  images:    " + ", ".join(f"{k} {v}" for k, v in s["image_resolutions"].items()))
    if s["quality"]:
        lines.append(f"  {'quality over sequences':28s}{'mean':>10s}{'min':>10s}{'max':>10s}")
        for k, q in s["quality"].items():
            if q["mean"] is not None:
                lines.append(f"    {k:26s}{q['mean']:10.4g}{q['min']:10.4g}{q['max']:10.4g}")
    if s["rejection_reasons"]:
        lines.append("  rejections: " + ", ".join(f"{k} x{v}" for k, v in s["rejection_reasons"].items()))
    return "\n".join(lines)
