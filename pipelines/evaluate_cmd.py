"""``wrinkles evaluate``: the shared evaluation harness (learn.evaluate) from the command line."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError

HELP = "evaluate a trained model on a dataset split: table, JSON, example images"
DESCRIPTION = """\
Evaluate a checkpoint (wrinkles train) on a dataset split with the shared metrics
(learn.evaluate): Ev and Ecd against the simulated garment, bending-angle error, edge stretch,
collision rate with the body, flicker, the UV wrinkle-map power spectrum, and the Frechet distance
of UV normal-map features from the project's fixed extractor (NOT Inception FID; the papers' FID
numbers are not comparable).

Writes into --out (default: <checkpoint dir>/../eval-<split>):
  metrics.json       summary, units, notes and per-sequence metrics
  uv_examples.png    predicted vs simulated UV normal and wrinkle maps of a few frames
  renders.png        predicted vs simulated garment, coloured by the per-vertex error, with a
                     colour bar in mm
  method_maps.png    the method's own UV maps where it has them (DeepWrinkles: LR input,
                     predicted HR, simulated HR normal maps)
  closeups.png       DeepWrinkles: the simulated garment, the global shape, the LR and predicted
                     HR maps, and the global shape shaded by the predicted HR map, side by side

Guo et al.'s two stages: --model is the wrinkle model (wrinkle_diffusion or the
displacement_regressor baseline) and --coarse the skeleton_cvae that makes the base from the body
(without --coarse, the data's smoothed base is used: the in-distribution setting of their
Table 1). --model base evaluates the base surface alone (no wrinkles).

examples:
  wrinkles evaluate --model runs/mlp/checkpoints/last.pt --data data/sample --split test_id
  wrinkles evaluate --model runs/wrinkles/checkpoints/last.pt --data data/tshirt --split test_id --steps 20
  wrinkles evaluate --model runs/wrinkles/checkpoints/last.pt --coarse runs/coarse/checkpoints/last.pt \\
      --data data/tshirt --split test_ood
  wrinkles evaluate --model base --coarse runs/coarse/checkpoints/last.pt --data data/tshirt --split test_ood
  wrinkles evaluate --model runs/mlp/checkpoints/last.pt --data data/big --split test_ood --max-sequences 50
  wrinkles evaluate --model runs/dw/checkpoints/last.pt --data data/tshirt --predict lr_input=subspace \\
      --predict components=200 --out runs/dw/eval-bs200
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.options import add_common_arguments

    p.add_argument("--model", required=True,
                   help="checkpoint file (RUN/checkpoints/last.pt), or 'base' for the base surface alone")
    p.add_argument("--coarse", help="skeleton_cvae checkpoint that makes the base surface from the body")
    p.add_argument("--steps", type=int,
                   help="DDIM steps of a wrinkle_diffusion model (default: its config's)")
    p.add_argument("--sample-seed", type=int, default=0, help="seed of the diffusion's noise (default: 0)")
    p.add_argument("--predict", action="append", default=[], metavar="KEY=VALUE",
                   help="a keyword of the method's prediction (repeatable; TOML values, bare words as text), "
                   "e.g. DeepWrinkles' lr_input=registration|subspace|regression and components=200")
    p.add_argument("--data", required=True, help="dataset directory")
    p.add_argument("--split", default="test_id", choices=("train", "test_id", "test_ood", "all"),
                   help="dataset split (default: %(default)s)")
    p.add_argument("--out", help="output directory (default: next to the run, eval-<split>)")
    p.add_argument("--max-sequences", type=int, help="evaluate only the first N sequences")
    p.add_argument("--image-resolution", type=int,
                   help="UV map side for the map metrics (default: the dataset's, else 128; 0: none)")
    p.add_argument("--no-ema", action="store_true", help="use the raw weights, not the EMA weights")
    p.add_argument("--no-images", action="store_true", help="skip the example pictures")
    add_common_arguments(p, seed=False)


def _predict_options(items: list[str], method) -> dict:
    """``--predict KEY=VALUE`` pairs as keyword arguments of ``method.predict_sequence``."""
    import inspect

    from pipelines.options import toml_value

    internal = {"self", "model", "sequence", "device", "base"}  # the harness's own
    known = set(inspect.signature(method.predict_sequence).parameters) - internal
    out = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or key.strip() not in known:
            raise WrinklesInputError(f"--predict {item!r}: expected KEY=VALUE with KEY one of "
                                     f"{', '.join(sorted(known)) or '(none for this method)'}")
        out[key.strip()] = toml_value(raw)
    return out


def _default_out(model: Path, split: str) -> Path:
    run = model.parent.parent if model.parent.name == "checkpoints" else model.parent
    return run / f"eval-{split}"


def run(args: argparse.Namespace) -> int:
    import torch

    from learn.evaluate import evaluate, format_table
    from learn.train.distributed import resolve_torch_device
    from learn.train.trainer import load_trained
    from pipelines.progress import progress_bar
    from sim.datasets.storage import read_manifest
    from sim.device import resolve_device

    model_path = Path(args.model)
    read_manifest(args.data)
    if args.max_sequences is not None and args.max_sequences < 1:
        raise WrinklesInputError(f"--max-sequences must be >= 1, got {args.max_sequences}")
    dev = resolve_torch_device(args.device)
    wdev = resolve_device(args.device)
    if args.model == "base":
        from learn.evaluate import BaseOnly

        method, model, ckpt = BaseOnly(), None, {"config": {"method": "base_only"}, "step": 0}
        if not args.out:
            raise WrinklesInputError("--model base needs --out")
    else:
        method, model, ckpt = load_trained(model_path, device=dev, use_ema=not args.no_ema)
    coarse = None
    if args.coarse:
        cm, cmodel, _ = load_trained(args.coarse, device=dev, use_ema=not args.no_ema)
        if cm.name != "skeleton_cvae":
            raise WrinklesInputError(f"--coarse must be a skeleton_cvae checkpoint, got {cm.name}",
                                     path=args.coarse)
        coarse = (cm, cmodel)
    opts = {}
    if method.name == "wrinkle_diffusion":
        opts = {"seed": args.sample_seed, **({"steps": args.steps} if args.steps else {})}
    opts.update(_predict_options(args.predict, method))
    out = Path(args.out) if args.out else _default_out(model_path, args.split)
    from pipelines.dataset_cmd import derive_first

    derive_first(args.data, wdev, split=args.split, quiet=args.quiet)
    with progress_bar(0, f"evaluate {args.split}", quiet=args.quiet, unit="sequence") as bar:
        ev = evaluate(method, model, args.data, args.split, device=dev, warp_device=wdev,
                      max_sequences=args.max_sequences, image_resolution=args.image_resolution, progress=bar,
                      coarse=coarse, predict_options=opts)
    title = (f"{ckpt['config']['method']} @ step {ckpt['step']} ({model_path}) on {args.data} [{args.split}]"
             f"{'' if args.no_ema or 'ema' not in ckpt else ', EMA weights'}"
             f"{f' on the base of {args.coarse}' if args.coarse else ''}")
    # write everything into a temporary directory, then move it into place: no partial output
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        record = {"model": os.fspath(model_path), "method": ckpt["config"]["method"], "step": ckpt["step"],
                  "coarse": args.coarse, "predict_options": opts,
                  "ema": not args.no_ema and "ema" in ckpt, "data": os.fspath(args.data),
                  "device": str(dev), "torch": str(torch.__version__), **ev.to_json()}
        (tmp / "metrics.json").write_text(json.dumps(record, indent=1))
        if not args.no_images and ev.examples:
            write_example_images(ev.examples, tmp)
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    print(format_table(ev, title=title))
    print(f"wrote {out}", file=sys.stderr)
    return 0


def _normal_gain(n: np.ndarray, mask: np.ndarray) -> float:
    """Contrast gain for the tangent components of a tangent-space normal map (they are small)."""
    xy = np.linalg.norm(np.asarray(n, np.float32)[..., :2][mask], axis=-1)
    return float(0.9 / max(np.percentile(xy, 99) if xy.size else 1.0, 0.05))


def _normal_rgb(n: np.ndarray, mask: np.ndarray, gain: float = 1.0) -> np.ndarray:
    n = np.asarray(n, np.float32).copy()
    n[..., :2] *= gain
    rgb = np.clip(0.5 * (n + 1.0), 0.0, 1.0)
    rgb[~mask] = 1.0
    return rgb


def write_example_images(examples: list[dict], out_dir: Path) -> list[Path]:
    """``uv_examples.png`` (normal and wrinkle maps, prediction vs simulation), ``renders.png``
    (garments coloured by the per-vertex error) and, where the method has them, ``method_maps.png``
    and ``closeups.png`` for a few example frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    uv = [e for e in examples if "normal_pred" in e]
    if uv:
        fig, axes = plt.subplots(len(uv), 4, figsize=(11, 2.9 * len(uv)), squeeze=False)
        for row, e in zip(axes, uv, strict=True):
            mask = e["mask"]
            wmax = float(np.abs(e["wrinkle_gt"][..., 2][mask]).max() or 1e-3) if mask.any() else 1e-3
            k = _normal_gain(e["normal_gt"], mask)
            panels = [(_normal_rgb(e["normal_pred"], mask, k), f"predicted normals (xy x{k:.1f})", None),
                      (_normal_rgb(e["normal_gt"], mask, k), f"simulated normals (xy x{k:.1f})", None),
                      (np.where(mask, e["wrinkle_pred"][..., 2], np.nan), "predicted wrinkle w3 [m]", wmax),
                      (np.where(mask, e["wrinkle_gt"][..., 2], np.nan), "simulated wrinkle w3 [m]", wmax)]
            for ax, (img, name, lim) in zip(row, panels, strict=True):
                if lim is None:
                    ax.imshow(img)
                else:
                    im = ax.imshow(img, cmap="RdBu_r", vmin=-lim, vmax=lim)
                    fig.colorbar(im, ax=ax, fraction=0.046)
                ax.set_title(f"{e['sequence']} t={e['frame']}\n{name}", fontsize=8)
                ax.axis("off")
        fig.tight_layout()
        written.append(out_dir / "uv_examples.png")
        fig.savefig(written[-1], dpi=100)
        plt.close(fig)
    own = [e for e in examples if "method_maps" in e]
    if own:
        written.append(_method_maps(own, out_dir / "method_maps.png"))
    try:
        written.append(_renders(examples, out_dir / "renders.png"))
        shaded = [e for e in examples if e.get("surface_normals") and "method_maps" in e
                  and all(key in e["method_maps"] for _, key in CLOSEUP_MAPS)]
        if shaded:
            written.append(_closeups(shaded, out_dir / "closeups.png"))
    except ImportError as e:  # pyvista missing: the UV pictures and numbers still stand
        print(f"note: no renders.png ({e})", file=sys.stderr)
    return written


CLOSEUP_MAPS = (("LR map (input)", "lr_maps"), ("predicted HR map", "normal_maps"))
"""The UV maps of a close-up row: (title, ``method_maps`` key)."""


def _closeups(examples: list[dict], path: Path) -> Path:
    """``closeups.png``: per example frame, the simulated garment, the base surface under each of
    its shadings (DeepWrinkles: the global shape, then shaded by the predicted HR map) and the
    method's LR / HR maps, side by side (Lähner et al. 2018, Fig. 1 and 10)."""
    import matplotlib.pyplot as plt

    from pipelines.preview import PreviewMesh, render_frame

    colour = (0.78, 0.80, 0.86)
    rows = []
    for e in examples:

        def render(vertices, normals=None, e=e):
            mesh = PreviewMesh("garment", vertices, e["faces"], color=colour, normals=normals)
            return render_frame([mesh], size=(360, 420), floor=False, shadows=False)

        shadings = list(e["surface_normals"].items())
        tiles = [("simulated", render(e["gt"])), (shadings[0][0], render(e["surface"], shadings[0][1]))]
        maps = e["method_maps"]
        mask = np.linalg.norm(maps[CLOSEUP_MAPS[-1][1]], axis=-1) > 0.5
        k = _normal_gain(maps[CLOSEUP_MAPS[-1][1]], mask)
        tiles += [(f"{name} (xy x{k:.1f})", _normal_rgb(maps[key], mask, k)) for name, key in CLOSEUP_MAPS]
        tiles += [(name, render(e["surface"], n)) for name, n in shadings[1:]]
        rows.append((e, tiles))
    cols = max(len(t) for _, t in rows)
    fig, axes = plt.subplots(len(rows), cols, figsize=(2.9 * cols, 3.3 * len(rows)), squeeze=False)
    for ax_row, (e, tiles) in zip(axes, rows, strict=True):
        for ax in ax_row:
            ax.axis("off")
        for ax, (name, img) in zip(ax_row, tiles, strict=False):
            ax.imshow(img)
            ax.set_title(f"{e['sequence']} t={e['frame']}\n{name}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _method_maps(examples: list[dict], path: Path) -> Path:
    """``method_maps.png``: the method's own UV normal maps of each example frame side by side
    (DeepWrinkles: LR input, predicted HR, the simulation's HR), one contrast gain per row."""
    import matplotlib.pyplot as plt

    names = list(examples[0]["method_maps"])
    fig, axes = plt.subplots(len(examples), len(names), figsize=(2.8 * len(names), 2.9 * len(examples)),
                             squeeze=False)
    for row, e in zip(axes, examples, strict=True):
        maps = e["method_maps"]
        mask = np.linalg.norm(maps[names[0]], axis=-1) > 0.5
        k = _normal_gain(maps[names[-1]], mask)
        for ax, name in zip(row, names, strict=True):
            ax.imshow(_normal_rgb(maps[name], mask, k))
            ax.set_title(f"{e['sequence']} t={e['frame']}\n{name} (xy x{k:.1f})", fontsize=8)
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


ERROR_CMAP = "magma"
"""Colour map of the per-vertex error in ``renders.png`` (0 at its dark end)."""


def _renders(examples: list[dict], path: Path) -> Path:
    """Predicted (left) and simulated (right) garments side by side, the prediction coloured by
    its per-vertex error, with a colour bar in mm from 0 to the frame's 99th percentile. The
    bars' places and ranges are in the PNG's text chunk ``colour_bars`` (JSON: one per tile,
    ``box`` in sheet pixels)."""
    from PIL import Image, ImageDraw
    from PIL.PngImagePlugin import PngInfo

    from pipelines.preview import PreviewMesh, add_colour_bar, render_frame

    tiles, bars = [], []
    for e in examples:
        vmax = float(np.percentile(e["error"], 99)) or 1e-3
        width = float(np.ptp(np.asarray(e["gt"])[:, 0]))
        offset = np.float32([1.2 * width + 0.05, 0.0, 0.0])  # side by side, a gap between
        meshes = [PreviewMesh(name="predicted", vertices=np.asarray(e["pred"], np.float32) - offset / 2,
                              faces=e["faces"], scalars=e["error"], cmap=ERROR_CMAP, clim=(0.0, vmax)),
                  PreviewMesh(name="simulated", vertices=np.asarray(e["gt"], np.float32) + offset / 2,
                              faces=e["faces"])]
        rendered = render_frame(meshes, size=(640, 400))
        rgb, bar = add_colour_bar(rendered, cmap=ERROR_CMAP, clim=(0.0, vmax * 1000.0), units="mm",
                                  label="error")
        img = Image.fromarray(rgb)
        title = f"{e['sequence']} t={e['frame']}: predicted (coloured by its error) | simulated"
        ImageDraw.Draw(img).text((8, 8), title, fill=(0, 0, 0))
        y = sum(t.height for t in tiles)
        x0, y0, x1, y1 = bar.box
        bars.append({**bar.to_json(sequence=str(e["sequence"]), frame=int(e["frame"])),
                     "box": [x0, y0 + y, x1, y1 + y]})
        tiles.append(img)
    sheet = Image.new("RGB", (tiles[0].width, sum(t.height for t in tiles)), "white")
    y = 0
    for t in tiles:
        sheet.paste(t, (0, y))
        y += t.height
    info = PngInfo()
    info.add_text("colour_bars", json.dumps(bars))
    sheet.save(path, pnginfo=info)
    return path
