"""``wrinkles dataset report DIR``: pictures and numbers that show what a dataset holds.

Writes ``contact_sheet.png``, ``uv_examples.png`` (when sequences store UV images),
``histograms.png`` and ``report.json`` (the numbers behind the histograms) into ``DIR/report``
as one all-or-nothing set of files (``REPORT_DESCRIPTION`` says what each shows). The body mesh
is not stored (``sim.datasets.schema``): renders re-pose it only when the dataset's body model
is the embedded default one, and show the garment alone otherwise.

Memory stays bounded on large datasets: arrays are memory-mapped and only
``frames_per_sequence`` evenly spaced frames of the per-face / per-vertex fields are read; the
per-frame quality arrays are read whole (T floats). Each histogram keeps at most
``max_values`` values in all (a seeded random subset per sequence when there are more); its
min, max and mean are exact over every value read, its counts are over the values kept.

pyvista, Pillow and matplotlib are imported only inside the functions that need them
(STYLE.md 7); a missing one raises ``WrinklesInputError`` naming what to install.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipelines.outputs import OutputSet
from sim.datasets.schema import IMAGE_KEYS, SPLITS
from sim.datasets.storage import SequenceFile, body_model_name, read_events, read_manifest, sequence_path
from sim.errors import WrinklesInputError

REPORT_HELP = "pictures and histograms of a synthetic garment dataset"
REPORT_DESCRIPTION = """\
Summarise a dataset made by 'wrinkles dataset generate' as PNG pictures and a JSON file, in
DIR/report (or --out):

  contact_sheet.png  renders of sampled sequences (fine garment at its middle frame, coloured
                     by base strain norm; the body too when the dataset uses the default body)
  uv_examples.png    UV images of a few sequences: strain norm, wrinkle field, world and
                     tangent normals (only when the dataset stores images)
  histograms.png     base strain norm, wrinkle amplitude, penetration and stretch
  generation.png     accepted garment-frames and sequences over the job's time (throughput),
                     rejections by cause (when the dataset has its generation timeline)
  report.json        the files and the numbers behind every histogram

Per-face and per-vertex fields are read at --frames-per-sequence evenly spaced frames of every
accepted sequence; per-frame quality values at every frame. Files appear together or not at all.

examples:
  wrinkles dataset report data/tshirts
  wrinkles dataset report data/tshirts --sequences 16 --frames-per-sequence 4 --out tshirts_report
"""

ProgressCallback = Callable[[int, int], None]

REPORT_DIR = "report"
CONTACT_SHEET = "contact_sheet.png"
UV_EXAMPLES = "uv_examples.png"
HISTOGRAMS = "histograms.png"
REPORT_JSON = "report.json"
GENERATION = "generation.png"
REPORT_FILES = (CONTACT_SHEET, UV_EXAMPLES, HISTOGRAMS, GENERATION, REPORT_JSON)

DEFAULT_SEQUENCES = 8
DEFAULT_FRAMES_PER_SEQUENCE = 8
#: values kept per histogram over the whole dataset (bounds memory; min/max/mean stay exact).
MAX_HISTOGRAM_VALUES = 2_000_000
HISTOGRAM_BINS = 50

#: contact sheet: render (width, height) [px] of one tile, caption band under it, tiles per
#: row, colour key strip at the bottom.
TILE_SIZE: tuple[int, int] = (256, 256)
CAPTION_HEIGHT = 34
SHEET_COLUMNS = 4
LEGEND_HEIGHT = 40
SHEET_CAMERA = "three_quarter"
STRAIN_CMAP = "viridis"
#: the shared colour range tops out at this percentile of the shown strain (one hot spot does
#: not wash out every other tile).
STRAIN_CLIM_PERCENTILE = 99.0
#: the garment is drawn this far out along its normals when the body is shown [m], so skin a
#: fraction of a millimetre under the cloth does not show through (display only).
CLOTH_LIFT = 0.003
#: body model name whose mesh ships with wrinkles (``sim.bodies.default``).
DEFAULT_BODY = "default"

#: UV examples: sequences shown, panel edge [in], resolution [dpi]; masked pixels are this grey.
UV_SEQUENCES = 3
UV_PANEL_INCHES = 2.4
UV_HEADER_INCHES = 0.5
UV_DPI = 100
UV_BACKGROUND: tuple[float, float, float] = (0.9, 0.9, 0.9)
UV_COLUMNS = ("strain norm", "wrinkle (w1, w2, w3 as RGB)", "normals, world", "normals, tangent")

#: histograms figure size [in] and resolution [dpi]: 1100 x 800 px.
HISTOGRAM_FIGSIZE: tuple[float, float] = (11.0, 8.0)
HISTOGRAM_DPI = 100

_INSTALL_HINT = "install the preview extra and matplotlib: pip install 'wrinkles[preview]' matplotlib"


# --------------------------------------------------------------------------- dataset access


@dataclass(frozen=True)
class SequenceEntry:
    """One accepted sequence of the manifest.

    Attributes:
        id: sequence id ("seq-00000").
        path: its sequence file.
        garment: garment category.
        motion: motion name.
        split: "train", "test_id" or "test_ood".
        has_images: the manifest says it stores UV images (None: it does not say).
    """

    id: str
    path: Path
    garment: str
    motion: str
    split: str
    has_images: bool | None


def accepted_sequences(root: str | os.PathLike, manifest: dict) -> list[SequenceEntry]:
    """The manifest's accepted sequences, sorted by id."""
    root = Path(root)
    seqs = manifest.get("sequences") or {}
    if not isinstance(seqs, dict):
        raise WrinklesInputError("'sequences' must be an object of id -> entry", path=root / "manifest.json")
    out = []
    for sid in sorted(seqs):
        e = seqs[sid] if isinstance(seqs[sid], dict) else {}
        path = root / e["file"] if e.get("file") else sequence_path(root, sid)
        res = e.get("image_resolution", "missing")
        out.append(SequenceEntry(id=str(sid), path=path, garment=str(e.get("garment", "?")),
                                 motion=str(e.get("motion", "?")), split=str(e.get("split", "?")),
                                 has_images=None if res == "missing" else bool(res)))
    return out


def sample_sequences(entries: Sequence[SequenceEntry], n: int, seed: int) -> list[SequenceEntry]:
    """Up to ``n`` sequences spread over garments and splits, sorted by id.

    Entries are grouped by (garment, split); groups take turns, ordered so that consecutive
    turns go to different garments first, then to further splits of a garment; within a group
    the pick order is a seeded shuffle.
    """
    groups: dict[tuple[str, str], list[SequenceEntry]] = defaultdict(list)
    for e in entries:
        groups[(e.garment, e.split)].append(e)
    split_rank = {s: i for i, s in enumerate(SPLITS)}
    by_garment: dict[str, list[str]] = defaultdict(list)
    for garment, split in groups:
        by_garment[garment].append(split)
    order = []
    for garment, splits in by_garment.items():
        splits.sort(key=lambda s: (split_rank.get(s, len(SPLITS)), s))
        order += [(k, garment, (garment, s)) for k, s in enumerate(splits)]
    order.sort()
    rng = np.random.default_rng(seed)
    queues = []
    for _, _, key in order:
        g = groups[key]
        queues.append([g[i] for i in rng.permutation(len(g))])
    picked: list[SequenceEntry] = []
    while len(picked) < n and any(queues):
        for q in queues:
            if q and len(picked) < n:
                picked.append(q.pop(0))
    return sorted(picked, key=lambda e: e.id)


def sample_frames(num_frames: int, n: int) -> list[int]:
    """``n`` evenly spaced frame indices in [0, num_frames), first and last included."""
    if num_frames <= n:
        return list(range(num_frames))
    if n == 1:
        return [num_frames // 2]
    return sorted({int(round(x)) for x in np.linspace(0, num_frames - 1, n)})


def _open(entry: SequenceEntry) -> SequenceFile:
    if not entry.path.is_file():
        raise WrinklesInputError(f"sequence {entry.id} is in the manifest but its file is missing",
                                 path=entry.path)
    return SequenceFile(entry.path)


def _array(sf: SequenceFile, name: str) -> np.ndarray:
    if name not in sf:
        raise WrinklesInputError(f"no array {name!r} (schema version 1 requires it)", path=sf.path)
    return sf[name]


def _frame_count(sf: SequenceFile) -> int:
    shape = sf.shape("fine/vertices") if "fine/vertices" in sf else ()
    if len(shape) != 3 or shape[0] < 1:
        raise WrinklesInputError(f"fine/vertices must have shape (T >= 1, V, 3), got {shape}", path=sf.path)
    return int(shape[0])


# --------------------------------------------------------------------------- histograms


@dataclass(frozen=True)
class HistogramSpec:
    """What one histogram shows: its key in report.json, the array, unit, and labels."""

    key: str
    source: str
    unit: str
    label: str
    xlabel: str
    frames: str  # "sampled" (frames_per_sequence per sequence) or "all"
    log_counts: bool = True


HISTOGRAMS_SPECS: tuple[HistogramSpec, ...] = (
    HistogramSpec("strain_norm", "fine/strain_norm", "-", "base strain norm per face",
                  "Green-Lagrange strain norm [-]", "sampled"),
    HistogramSpec("wrinkle_amplitude_mm", "fine/wrinkle[..., 2]", "mm",
                  "wrinkle amplitude |w3| per UV vertex (normal component)", "|w3| [mm]", "sampled"),
    HistogramSpec("penetration_percent", "quality/inside_fraction", "%",
                  "penetration: garment vertices inside the body, per frame", "inside fraction [%]", "all"),
    HistogramSpec("stretch", "quality/edge_strain_max", "-", "stretch: max |l/l0 - 1| per frame",
                  "max edge strain [-]", "all"),
)


@dataclass
class _Accumulator:
    """Exact count/min/max/sum over every finite value seen; a bounded sample for the counts."""

    spec: HistogramSpec
    parts: list[np.ndarray] = field(default_factory=list)
    seen: int = 0
    nonfinite: int = 0
    total: float = 0.0
    lo: float = math.inf
    hi: float = -math.inf
    subsampled: bool = False

    def add(self, values: np.ndarray, cap: int, rng: np.random.Generator) -> None:
        v = np.asarray(values, dtype=np.float32).ravel()
        ok = np.isfinite(v)
        self.nonfinite += int(v.size - np.count_nonzero(ok))
        v = v[ok]
        if v.size == 0:
            return
        self.seen += int(v.size)
        self.total += float(v.sum(dtype=np.float64))
        self.lo = min(self.lo, float(v.min()))
        self.hi = max(self.hi, float(v.max()))
        if v.size > cap:
            v = v[np.sort(rng.choice(v.size, cap, replace=False))]
            self.subsampled = True
        self.parts.append(np.array(v, dtype=np.float32))

    def finish(self, bins: int) -> dict:
        s = self.spec
        out = {"label": s.label, "source": s.source, "unit": s.unit, "frames": s.frames,
               "log_counts": s.log_counts, "values_seen": self.seen, "nonfinite": self.nonfinite}
        if self.seen == 0:
            return {**out, "count": 0, "subsampled": False, "min": None, "max": None, "mean": None,
                    "p50": None, "p99": None, "edges": [], "counts": []}
        sample = np.concatenate(self.parts)
        lo = min(0.0, self.lo)
        hi = self.hi if self.hi > lo else lo + 1.0
        edges = np.linspace(lo, hi, bins + 1)
        counts, _ = np.histogram(sample, bins=edges)
        p50, p99 = (float(x) for x in np.percentile(sample, [50.0, 99.0]))
        return {**out, "count": int(sample.size), "subsampled": self.subsampled, "min": self.lo,
                "max": self.hi, "mean": self.total / self.seen, "p50": p50, "p99": p99,
                "edges": [float(e) for e in edges], "counts": [int(c) for c in counts]}


def _histogram_values(sf: SequenceFile, frames: list[int]) -> dict[str, np.ndarray]:
    """This sequence's values for each histogram (sampled frames of the big arrays)."""
    strain = _array(sf, "fine/strain_norm")
    wrinkle = _array(sf, "fine/wrinkle")
    if wrinkle.ndim != 3 or wrinkle.shape[2] != 3:
        raise WrinklesInputError(f"fine/wrinkle must have shape (T, U, 3), got {wrinkle.shape}", path=sf.path)
    return {
        "strain_norm": np.asarray(strain[frames]),
        "wrinkle_amplitude_mm": np.abs(np.asarray(wrinkle[frames, :, 2], dtype=np.float32)) * np.float32(1e3),
        "penetration_percent": np.asarray(_array(sf, "quality/inside_fraction"), np.float32)
        * np.float32(100),
        "stretch": np.asarray(_array(sf, "quality/edge_strain_max"), np.float32),
    }


def _plot_histograms(stats: dict[str, dict], path: Path, title: str) -> None:
    Figure = _import_matplotlib_figure()
    fig = Figure(figsize=HISTOGRAM_FIGSIZE, dpi=HISTOGRAM_DPI, layout="constrained")
    axes = fig.subplots(2, 2).ravel()
    for ax, spec in zip(axes, HISTOGRAMS_SPECS, strict=True):
        h = stats[spec.key]
        ax.set_title(spec.label, fontsize=10)
        ax.set_xlabel(spec.xlabel, fontsize=9)
        ax.set_ylabel("count (log)" if spec.log_counts else "count", fontsize=9)
        if h["count"] == 0:
            ax.text(0.5, 0.5, "no values", ha="center", va="center", transform=ax.transAxes)
            continue
        edges = np.asarray(h["edges"])
        ax.bar(edges[:-1], h["counts"], width=np.diff(edges), align="edge", log=spec.log_counts,
               color="#3b6fb6", edgecolor="#2a4f85", linewidth=0.4)
        ax.axvline(h["mean"], color="#d2691e", linewidth=1.0, label=f"mean {h['mean']:.4g}")
        ax.axvline(h["p99"], color="#8b0000", linewidth=1.0, linestyle="--", label=f"p99 {h['p99']:.4g}")
        where = "sampled frames" if spec.frames == "sampled" else "all frames"
        note = f"n = {h['count']:,}{' (subsample)' if h['subsampled'] else ''}, {where}\nmax {h['max']:.4g}"
        ax.legend(fontsize=8, loc="upper right", title=note, title_fontsize=8)
        ax.tick_params(labelsize=8)
    fig.suptitle(title, fontsize=11)
    fig.savefig(path, format="png", dpi=HISTOGRAM_DPI)


# --------------------------------------------------------------------------- contact sheet


def _face_to_vertex(values: np.ndarray, faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """Mean of the face values around each vertex, shape (V,) float32 (0 where no face)."""
    total = np.zeros(num_vertices, np.float64)
    count = np.zeros(num_vertices, np.float64)
    for k in range(3):
        total += np.bincount(faces[:, k], weights=values, minlength=num_vertices)
        count += np.bincount(faces[:, k], minlength=num_vertices)
    return (total / np.maximum(count, 1.0)).astype(np.float32)


@dataclass(frozen=True)
class _Tile:
    entry: SequenceEntry
    frame: int
    vertices: np.ndarray      # (V, 3) [m]
    faces: np.ndarray         # (F, 3)
    strain: np.ndarray        # (V,) per-vertex mean of the face strain norm
    body_vertices: np.ndarray | None
    body_faces: np.ndarray | None


def _load_tile(entry: SequenceEntry, manifest: dict, device: str | None) -> _Tile:
    sf = _open(entry)
    T = _frame_count(sf)
    t = T // 2
    verts = np.array(_array(sf, "fine/vertices")[t], dtype=np.float32)
    faces = np.array(_array(sf, "fine/faces"), dtype=np.int32)
    face_strain = np.array(_array(sf, "fine/strain_norm")[t], dtype=np.float64)
    if faces.ndim != 2 or faces.shape[1] != 3 or face_strain.shape != (faces.shape[0],):
        raise WrinklesInputError(f"fine/faces {faces.shape} and fine/strain_norm frames "
                                 f"{face_strain.shape} do not match", path=sf.path)
    if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
        raise WrinklesInputError(f"fine/faces index outside [0, {len(verts) - 1}]", path=sf.path)
    face_strain = np.nan_to_num(face_strain, nan=0.0, posinf=0.0, neginf=0.0)
    strain = _face_to_vertex(face_strain, faces, len(verts))
    body_v = body_f = None
    if body_model_name(sf, manifest) == DEFAULT_BODY:
        from sim.bodies.default import load_default_body

        body = load_default_body()
        betas = np.asarray(_array(sf, "body/betas"), np.float32).reshape(-1)[: body.num_betas]
        poses = np.array(_array(sf, "body/poses")[t: t + 1], dtype=np.float32)
        trans = np.array(_array(sf, "body/trans")[t: t + 1], dtype=np.float32)
        frames = body.pose(betas, poses, trans, device=device)
        body_v, body_f = frames.vertices[0], frames.faces
    return _Tile(entry, t, verts, faces, strain, body_v, body_f)


def _render_tile(tile: _Tile, clim: tuple[float, float], size: tuple[int, int]) -> np.ndarray:
    from pipelines.preview import PreviewMesh, render_frame, vertex_normals

    meshes = []
    verts = tile.vertices
    if tile.body_vertices is not None:
        meshes.append(PreviewMesh(name=f"{tile.entry.id} body", vertices=tile.body_vertices,
                                  faces=tile.body_faces))
        verts = verts + np.float32(CLOTH_LIFT) * vertex_normals(verts, tile.faces)
    meshes.append(PreviewMesh(name=str(tile.entry.path), vertices=verts, faces=tile.faces,
                              scalars=tile.strain, cmap=STRAIN_CMAP, clim=clim))
    return render_frame(meshes, size=size, camera=SHEET_CAMERA)


def contact_sheet_size(num_tiles: int, tile_size: tuple[int, int] = TILE_SIZE) -> tuple[int, int]:
    """(width, height) [px] of a contact sheet with ``num_tiles`` tiles."""
    cols = max(1, min(SHEET_COLUMNS, num_tiles))
    rows = max(1, math.ceil(num_tiles / cols))
    return cols * tile_size[0], rows * (tile_size[1] + CAPTION_HEIGHT) + LEGEND_HEIGHT


def _font(ImageFont, px: int):
    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # Pillow < 10.1: bitmap font, fixed size
        return ImageFont.load_default()


def _compose_sheet(tiles: Sequence[_Tile], images: Sequence[np.ndarray], clim: tuple[float, float],
                   path: Path, tile_size: tuple[int, int]) -> None:
    Image, ImageDraw, ImageFont = _import_pil()
    w, h = tile_size
    width, height = contact_sheet_size(len(tiles), tile_size)
    cols = width // w
    sheet = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    font = _font(ImageFont, 12)
    for k, (tile, img) in enumerate(zip(tiles, images, strict=True)):
        x0, y0 = (k % cols) * w, (k // cols) * (h + CAPTION_HEIGHT)
        sheet.paste(Image.fromarray(img), (x0, y0))
        e = tile.entry
        draw.text((x0 + 6, y0 + h + 3), f"{e.id}  {e.garment}", fill=(30, 32, 36), font=font)
        body = "" if tile.body_vertices is not None else "  (no body)"
        draw.text((x0 + 6, y0 + h + 18), f"{e.motion} | {e.split} | frame {tile.frame}{body}",
                  fill=(90, 92, 98), font=font)
    for c in range(1, cols):
        draw.line([(c * w, 0), (c * w, height - LEGEND_HEIGHT)], fill=(200, 202, 206), width=1)
    # colour key: the strain colour map over the shared range
    cmap = _import_matplotlib_colormap(STRAIN_CMAP)
    y_bar = height - LEGEND_HEIGHT + 22
    bar_w = max(16, width - 16)
    ramp = (cmap(np.linspace(0.0, 1.0, bar_w))[:, :3] * 255).astype(np.uint8)
    sheet.paste(Image.fromarray(np.repeat(ramp[None], 10, axis=0)), (8, y_bar))
    draw.text((8, height - LEGEND_HEIGHT + 5),
              f"base strain norm [-]: {clim[0]:.3g} .. {clim[1]:.3g} (p{STRAIN_CLIM_PERCENTILE:g})",
              fill=(30, 32, 36), font=font)
    sheet.save(path, format="PNG")


# --------------------------------------------------------------------------- UV images


def _has_images(sf: SequenceFile) -> bool:
    return all(k in sf for k in IMAGE_KEYS) and sf.shape("images/strain_norm")[0] > 0


def _uv_row(sf: SequenceFile, t: int) -> dict:
    """The four images of frame ``t`` as display arrays, and their scales."""
    mask = np.asarray(sf["images/mask"]) > 0
    bg = np.asarray(UV_BACKGROUND, np.float32)

    def rgb(x: np.ndarray) -> np.ndarray:
        out = np.clip(x, 0.0, 1.0).astype(np.float32)
        out[~mask] = bg
        return out

    strain = np.asarray(sf["images/strain_norm"][t], np.float32)[..., 0]
    strain = np.nan_to_num(strain, nan=0.0, posinf=0.0, neginf=0.0)
    smax = float(strain[mask].max()) if mask.any() else 0.0
    wr = np.nan_to_num(np.asarray(sf["images/wrinkle"][t], np.float32))
    scale = np.array([float(np.abs(wr[..., c][mask]).max()) if mask.any() else 0.0 for c in range(3)])
    scale = np.where(scale > 0, scale, 1.0)
    return {
        "strain": np.ma.masked_where(~mask, strain), "strain_max": smax,
        "wrinkle": rgb(0.5 + 0.5 * wr / scale.astype(np.float32)), "wrinkle_scale": scale.tolist(),
        "world": rgb(np.asarray(sf["images/normal_world"][t], np.float32) * 0.5 + 0.5),
        "tangent": rgb(np.asarray(sf["images/normal_tangent"][t], np.float32) * 0.5 + 0.5),
        "mask_fraction": float(mask.mean()),
    }


def uv_examples_size(num_rows: int) -> tuple[int, int]:
    """(width, height) [px] of ``uv_examples.png`` with ``num_rows`` sequences."""
    w = len(UV_COLUMNS) * UV_PANEL_INCHES
    h = num_rows * UV_PANEL_INCHES + UV_HEADER_INCHES
    return int(round(w * UV_DPI)), int(round(h * UV_DPI))


def _plot_uv_examples(rows: Sequence[tuple[SequenceEntry, int, dict]], path: Path) -> None:
    Figure = _import_matplotlib_figure()
    cmap = _import_matplotlib_colormap(STRAIN_CMAP).with_extremes(bad=UV_BACKGROUND)
    w, h = uv_examples_size(len(rows))
    fig = Figure(figsize=(w / UV_DPI, h / UV_DPI), dpi=UV_DPI, layout="constrained")
    axes = fig.subplots(len(rows), len(UV_COLUMNS), squeeze=False)
    for r, (entry, t, row) in enumerate(rows):
        ax = axes[r]
        im = ax[0].imshow(row["strain"], cmap=cmap, vmin=0.0, vmax=max(row["strain_max"], 1e-9),
                          interpolation="nearest")
        fig.colorbar(im, ax=ax[0], fraction=0.046, pad=0.02).ax.tick_params(labelsize=6)
        ax[1].imshow(row["wrinkle"], interpolation="nearest")
        ax[2].imshow(row["world"], interpolation="nearest")
        ax[3].imshow(row["tangent"], interpolation="nearest")
        s = row["wrinkle_scale"]
        titles = (f"strain norm (max {row['strain_max']:.3g})",
                  f"wrinkle w1, w2 ±{s[0]:.2g}, ±{s[1]:.2g}; w3 ±{s[2] * 1e3:.2g} mm",
                  "normals, world (n/2 + 1/2)", "normals, tangent (n/2 + 1/2)")
        for a, title in zip(ax, titles, strict=True):
            a.set_title(title, fontsize=7)
            a.set_xticks([])
            a.set_yticks([])
        ax[0].set_ylabel(f"{entry.id}\n{entry.garment} | {entry.motion}\nframe {t}", fontsize=7)
    fig.suptitle("UV images (masked outside the UV layout); wrinkle channels scaled to ±max each", fontsize=8)
    fig.savefig(path, format="png", dpi=UV_DPI)


# --------------------------------------------------------------------------- optional deps


def _import_pil():
    try:
        from PIL import Image, ImageDraw, ImageFont
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise WrinklesInputError(f"the dataset report needs Pillow ({exc}); {_INSTALL_HINT}") from None
    return Image, ImageDraw, ImageFont


def _import_matplotlib_figure():
    try:
        from matplotlib.figure import Figure  # no pyplot: no global backend; PNGs go through Agg
    except ImportError as exc:  # pragma: no cover
        raise WrinklesInputError(f"the dataset report needs matplotlib ({exc}); {_INSTALL_HINT}") from None
    return Figure


def _import_matplotlib_colormap(name: str):
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover
        raise WrinklesInputError(f"the dataset report needs matplotlib ({exc}); {_INSTALL_HINT}") from None
    return matplotlib.colormaps[name]


# --------------------------------------------------------------------------- the report


def _make_dirs(path: Path) -> list[Path]:
    """mkdir -p; returns the directories it created, deepest last."""
    created = []
    p = path
    while not p.exists():
        created.append(p)
        p = p.parent
    if not p.is_dir():
        raise WrinklesInputError("the report directory's parent is a file", path=p)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise WrinklesInputError(f"cannot create the report directory: {e.strerror}", path=path) from None
    return created[::-1]


def _collect_histograms(entries: Sequence[SequenceEntry], frames_per_sequence: int, seed: int,
                        max_values: int, advance: Callable[[], None]) -> tuple[dict, dict]:
    """Histogram numbers over every accepted sequence (sampled frames of the big arrays).

    Returns:
        (key -> numbers as in report.json, sequence length -> frame indices read).
    """
    rng = np.random.default_rng(seed)
    cap = max(1, max_values // len(entries))
    acc = {s.key: _Accumulator(s) for s in HISTOGRAMS_SPECS}
    frames_used: dict[int, list[int]] = {}
    for e in entries:
        sf = _open(e)
        n = _frame_count(sf)
        frames = frames_used.setdefault(n, sample_frames(n, frames_per_sequence))
        for key, values in _histogram_values(sf, frames).items():
            acc[key].add(values, cap, rng)
        del sf
        advance()
    stats = {k: a.finish(HISTOGRAM_BINS) for k, a in acc.items()}
    return stats, {str(n): f for n, f in sorted(frames_used.items())}


def _pick_uv_rows(shown: Sequence[SequenceEntry], entries: Sequence[SequenceEntry]) -> list:
    """Up to ``UV_SEQUENCES`` (entry, frame, images): shown sequences with images first, then
    others the manifest does not say lack them."""
    rows = []
    shown_ids = {e.id for e in shown}
    for e in [*shown, *(e for e in entries if e.id not in shown_ids)]:
        if len(rows) >= UV_SEQUENCES:
            break
        if e.has_images is False:
            continue
        sf = _open(e)
        if _has_images(sf):
            t = min(_frame_count(sf), sf.shape("images/strain_norm")[0]) // 2
            rows.append((e, t, _uv_row(sf, t)))
    return rows


def _sheet_json(tiles: Sequence[_Tile], clim: tuple[float, float], tile_size: tuple[int, int]) -> dict:
    return {"file": CONTACT_SHEET, "tile_size": list(tile_size), "camera": SHEET_CAMERA,
            "color": {"quantity": "fine/strain_norm (per-vertex mean of faces)", "cmap": STRAIN_CMAP,
                      "clim": list(clim), "clim_percentile": STRAIN_CLIM_PERCENTILE},
            "tiles": [{"id": t.entry.id, "garment": t.entry.garment, "motion": t.entry.motion,
                       "split": t.entry.split, "frame": t.frame, "body": t.body_vertices is not None}
                      for t in tiles]}


def _uv_json(rows: Sequence[tuple[SequenceEntry, int, dict]]) -> dict:
    if not rows:
        return {"file": None, "skipped": "no sequence stores UV images"}
    return {"file": UV_EXAMPLES,
            "rows": [{"id": e.id, "frame": t, "strain_max": r["strain_max"],
                      "wrinkle_scale": r["wrinkle_scale"], "mask_fraction": r["mask_fraction"]}
                     for e, t, r in rows]}


def write_report(root: str | os.PathLike, out_dir: str | os.PathLike | None = None, *,
                 sequences: int = DEFAULT_SEQUENCES,
                 frames_per_sequence: int = DEFAULT_FRAMES_PER_SEQUENCE, seed: int = 0,
                 progress: ProgressCallback | None = None, tile_size: tuple[int, int] = TILE_SIZE,
                 max_values: int = MAX_HISTOGRAM_VALUES, device: str | None = "cpu") -> list[Path]:
    """Write the report of a dataset: contact sheet, UV examples, histograms, report.json.

    Args:
        root: the dataset directory (with ``manifest.json``).
        out_dir: where the files go; None = ``root/report``. Created when missing.
        sequences: at most this many sequences in the contact sheet (spread over garments
            and splits); the UV examples take up to ``UV_SEQUENCES`` of them.
        frames_per_sequence: evenly spaced frames of every accepted sequence whose per-face and
            per-vertex fields enter the histograms.
        seed: picks the sequences shown and the histogram subsample (same seed, same report).
        progress: called as ``progress(done, total)``: one step per accepted sequence read for
            the histograms, then one per contact-sheet tile.
        tile_size: (width, height) [px] of one contact-sheet render.
        max_values: values kept per histogram over the whole dataset.
        device: Warp device for re-posing the default body (one frame per tile).

    Returns:
        The written files: the PNGs, then ``report.json``. Files of an earlier report that this
        one does not produce (``uv_examples.png`` when no sequence has images) are removed.

    Raises:
        WrinklesInputError: not a dataset, no accepted sequences, a missing or malformed
            sequence file, bad arguments. Nothing is written then.
    """
    root = Path(root)
    _check_counts(sequences=sequences, frames_per_sequence=frames_per_sequence, max_values=max_values)
    manifest = read_manifest(root)
    entries = accepted_sequences(root, manifest)
    rejected = manifest.get("rejected") or {}
    if not entries:
        raise WrinklesInputError(f"no accepted sequences in the manifest ({len(rejected)} rejected): "
                                 "nothing to report", path=root)
    out_dir = root / REPORT_DIR if out_dir is None else Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise WrinklesInputError("the report directory is a file", path=out_dir)
    shown = sample_sequences(entries, sequences, seed)
    total_steps = len(entries) + len(shown)
    step = 0

    def advance() -> None:
        nonlocal step
        step += 1
        if progress is not None:
            progress(step, total_steps)

    # read every sequence for the histograms before anything is rendered or written
    stats, frames_used = _collect_histograms(entries, frames_per_sequence, seed, max_values, advance)

    tiles = [_load_tile(e, manifest, device) for e in shown]
    shown_strain = np.concatenate([t.strain for t in tiles])
    hi = float(np.percentile(shown_strain, STRAIN_CLIM_PERCENTILE)) if shown_strain.size else 0.0
    clim = (0.0, hi if hi > 0 else 1e-6)

    uv_rows = _pick_uv_rows(shown, entries)
    title = (f"{root.resolve().name}: {len(entries)} accepted, {len(rejected)} rejected sequences; "
             f"strain and wrinkles at up to {frames_per_sequence} evenly spaced frames per sequence")
    report = {
        "dataset": os.fspath(root),
        "files": [],
        "seed": int(seed),
        "sequences": {"accepted": len(entries), "rejected": len(rejected),
                      "frames_per_sequence": int(frames_per_sequence),
                      "sampled_frames_by_length": frames_used},
        "contact_sheet": _sheet_json(tiles, clim, tile_size),
        "uv_examples": _uv_json(uv_rows),
        "histograms": {"file": HISTOGRAMS, "bins": HISTOGRAM_BINS, "max_values": int(max_values),
                       "quantities": stats},
    }
    written = _write_files(out_dir, tiles, clim, tile_size, uv_rows, stats, title, report, advance,
                           (read_events(root), rejected))
    for name in REPORT_FILES:
        stale = out_dir / name
        if stale not in written and stale.is_file():
            stale.unlink()
    return written


def _check_counts(**counts: int) -> None:
    for name, n in counts.items():
        if n < 1:
            raise WrinklesInputError(f"{name} must be >= 1, got {n}")


def _write_files(out_dir: Path, tiles: Sequence[_Tile], clim: tuple[float, float],
                 tile_size: tuple[int, int], uv_rows: list, stats: dict, title: str, report: dict,
                 advance: Callable[[], None], timeline: tuple[list, dict]) -> list[Path]:
    """Render and write the report: every file under a temporary name, renamed together at the
    end; ``report["files"]`` filled in; the generation picture where ``timeline`` (events,
    rejected) has events. The files written, in order; on an error none, and the
    folders made for them removed."""
    created = _make_dirs(out_dir)
    written: list[Path] = []
    try:
        with OutputSet() as out:
            images = []
            for tile in tiles:
                images.append(_render_tile(tile, clim, tile_size))
                advance()
            _compose_sheet(tiles, images, clim, out.temp(out_dir / CONTACT_SHEET), tile_size)
            written.append(out_dir / CONTACT_SHEET)
            if uv_rows:
                _plot_uv_examples(uv_rows, out.temp(out_dir / UV_EXAMPLES))
                written.append(out_dir / UV_EXAMPLES)
            _plot_histograms(stats, out.temp(out_dir / HISTOGRAMS), title)
            written.append(out_dir / HISTOGRAMS)
            report["generation"] = None  # generation_plot.generation_summary, with the picture
            if timeline[0]:
                from pipelines.generation_plot import plot_generation

                report["generation"] = plot_generation(*timeline, out.temp(out_dir / GENERATION), title)
                written.append(out_dir / GENERATION)
            report["files"] = [p.name for p in written]
            out.temp(out_dir / REPORT_JSON).write_text(json.dumps(report, indent=1) + "\n")
            written.append(out_dir / REPORT_JSON)
    except BaseException:
        for d in reversed(created):
            try:
                d.rmdir()
            except OSError:
                pass
        raise
    return written


# --------------------------------------------------------------------------- command line


def add_report_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``wrinkles dataset report``."""
    from pipelines.options import add_common_arguments

    p.add_argument("dataset", metavar="DIR", help="dataset directory (with manifest.json)")
    p.add_argument("--out", default=None, metavar="OUT_DIR",
                   help=f"directory for the report files (default: DIR/{REPORT_DIR})")
    p.add_argument("--sequences", type=int, default=DEFAULT_SEQUENCES,
                   help="sequences in the contact sheet, spread over garments and splits "
                        "(default: %(default)s)")
    p.add_argument("--frames-per-sequence", type=int, default=DEFAULT_FRAMES_PER_SEQUENCE,
                   help="evenly spaced frames per sequence read for the strain and wrinkle histograms "
                        "(default: %(default)s)")
    add_common_arguments(p)


def run_report(args: argparse.Namespace) -> int:
    """``wrinkles dataset report``: write the report; print the files unless --quiet."""
    device = getattr(args, "device", "cpu")
    from pipelines.dataset_cmd import derive_first
    from pipelines.progress import LazyProgressBar

    derive_first(args.dataset, None if device == "auto" else device, quiet=getattr(args, "quiet", False))
    with LazyProgressBar("dataset report", getattr(args, "quiet", False)) as bar:
        written = write_report(args.dataset, args.out, sequences=args.sequences,
                               frames_per_sequence=args.frames_per_sequence, seed=args.seed,
                               progress=bar, device=None if device == "auto" else device)
    if not args.quiet:
        for p in written:
            print(f"  wrote {p}")
    return 0
