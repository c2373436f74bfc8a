"""``wrinkles animate --method deepwrinkles``: a DeepWrinkles checkpoint (``learn.methods.deepwrinkles``)
on a body motion, written as USD with the predicted per-frame normal maps.

DeepWrinkles predicts for its garment, from the body's motion, a global shape (the coarse
template posed and deformed) and a tangent-space normal map over the fine garment's UV layout
holding the wrinkles the global shape lacks. The fine and coarse garment meshes it predicts on
are those of the dataset it was trained on, whose sequences all share one garment (a
reference-fit dataset: every garment cut on the mean body and worn by every shape): the
checkpoint keeps its first training sequence's garment (``garment/*`` in its fitted state), or
``--data`` names the dataset to take it from. The body and its motion are ``animate``'s usual
options, posed with the training data's body model.

What the stage holds (``--surface``):

- ``global`` (default, the paper's output): the global shape on the fine garment's mesh, with
  its smooth normals, and the normal maps on its material: the wrinkles are in the shading, the
  way DeepWrinkles renders them;
- ``fine``: the fine garment moved so that its normals match the maps (Guo et al. 2024, Eq. 10;
  the vertices ``wrinkles evaluate`` measures): the wrinkles are in the geometry, and no maps
  (applying them to this surface would add the wrinkles a second time).

The preview draws what the stage holds: with ``global``, the global shape shaded by the normals
of the predicted maps (sampled at the fine vertices); with ``fine``, the fine garment.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError

SURFACES = ("global", "fine")
"""What ``--surface`` writes (module docstring)."""
DIFFUSION_ONLY = {"coarse": "--coarse", "wrinkles": "--wrinkles", "no_wrinkles": "--no-wrinkles",
                  "steps": "--steps", "material": "--material", "sample_latent": "--sample-latent"}
"""Options of ``--method diffusion`` that ``--method deepwrinkles`` refuses when given."""


@dataclass(frozen=True)
class DatasetGarment:
    """The garment a DeepWrinkles model was trained on, from its dataset.

    Attributes:
        arrays: ``learn.deepwrinkles.sequences.STATE_GARMENT_KEYS`` (``fine/face_layers`` where
            stored) as numpy arrays.
        category: the garment category (the prim name of the stage's garment).
        material: its material preset.
        body_model: the body model of the dataset (``"default"`` or a model file).
        fps: the dataset's frame rate [1/s].
        sequence: the id of the sequence the arrays come from.
    """

    arrays: dict[str, np.ndarray]
    category: str
    material: str
    body_model: str
    fps: float
    sequence: str


SHIPPED_KIND = "deepwrinkles"
"""Shipped DeepWrinkles weights: ``pretrained/<category>-deepwrinkles.pt``."""


def check_options(args: argparse.Namespace) -> None:
    """No option of the diffusion method (one-line errors); fills in the defaults of ``--model``
    (the shipped weights of ``--garment``), ``--surface`` (global) and ``--normal-map-bits`` (16)."""
    given = [flag for key, flag in DIFFUSION_ONLY.items() if getattr(args, key, None)]
    if given:
        raise WrinklesInputError(f"{given[0]} applies to --method diffusion, not deepwrinkles")
    args.surface = args.surface or "global"
    args.normal_map_bits = args.normal_map_bits or 16
    if not args.model:
        from learn.animate import pretrained_file, shipped_categories
        from pipelines.simulate_cmd import resolve_template

        category = resolve_template(args.garment)
        args.model = str(pretrained_file(category, SHIPPED_KIND))
        if not Path(args.model).is_file():
            have = shipped_categories(SHIPPED_KIND)
            raise WrinklesInputError(f"no shipped DeepWrinkles model for {category} (shipped: "
                                     f"{', '.join(have) or 'none'}); pass --model "
                                     "(wrinkles train deepwrinkles)")
    if not Path(args.model).is_file():
        raise WrinklesInputError("no such model file", path=args.model)
    if not (args.clearance >= 0 and args.clearance < 0.1):
        raise WrinklesInputError(f"--clearance must be in [0, 0.1) m, got {args.clearance}")


def dataset_garment(root: Path, method) -> DatasetGarment:
    """The garment arrays of the first training sequence of ``root`` (of the model's garment
    categories), checked against the model's template.

    Raises:
        WrinklesInputError: not a dataset, no such sequence, a body-fit dataset, missing arrays,
            or a template other than the model's.
    """
    from learn.deepwrinkles.sequences import GARMENT_KEYS, STATE_GARMENT_KEYS
    from sim.datasets.storage import SequenceFile, body_model_name, read_manifest, sequence_path

    manifest = read_manifest(root)
    wanted = tuple(method.config.garments)
    entries = sorted((sid, e) for sid, e in manifest.get("sequences", {}).items()
                     if e.get("split") == "train" and (not wanted or e.get("garment") in wanted))
    if not entries:
        raise WrinklesInputError("no training sequences" + (f" of {', '.join(wanted)}" if wanted else ""),
                                 path=root)
    sid, entry = entries[0]
    if entry.get("fit", "body") != "reference":
        raise WrinklesInputError("DeepWrinkles animates the garment of a reference-fit dataset "
                                 "([garments] fit = \"reference\"); this one fits each garment to its body",
                                 path=root)
    sf = SequenceFile(root / entry["file"] if "file" in entry else sequence_path(root, sid))
    missing = [k for k in GARMENT_KEYS if k not in sf]
    if missing:
        raise WrinklesInputError(f"sequence {sid} has no {missing[0]!r}: DeepWrinkles needs the fine and "
                                 "coarse garments", path=sf.path)
    arrays = {k: np.asarray(sf[k]) for k in STATE_GARMENT_KEYS if k in sf}
    template = method.state.get("template_faces")
    if template is not None and not np.array_equal(template.numpy(), arrays["coarse/faces"]):
        raise WrinklesInputError(f"the garment of sequence {sid} ({entry.get('garment')}) is not the "
                                 "template the model was trained on: pass the dataset it was trained on",
                                 path=root)
    return DatasetGarment(arrays=arrays, category=str(entry.get("garment") or "garment"),
                          material=str(entry.get("material") or "cotton"),
                          body_model=body_model_name(sf, manifest) or "default",
                          fps=float((manifest.get("config") or {}).get("fps") or 30.0), sequence=sid)


def checkpoint_garment(method) -> DatasetGarment | None:
    """The garment a checkpoint keeps in its fitted state (``garment/*``), or None."""
    from learn.deepwrinkles.sequences import GARMENT_KEYS, STATE_GARMENT_KEYS
    from learn.deepwrinkles.training import tensor_text

    s = method.state
    if any(f"garment/{k}" not in s for k in GARMENT_KEYS):
        return None
    arrays = {k: s[f"garment/{k}"].numpy() for k in STATE_GARMENT_KEYS if f"garment/{k}" in s}
    return DatasetGarment(arrays=arrays, category=tensor_text(s["garment/category"]),
                          material=tensor_text(s["garment/material"]),
                          body_model=tensor_text(s["garment/body_model"]), fps=float(s["garment/fps"]),
                          sequence="(the checkpoint's)")


def motion_sequence(garment: DatasetGarment, bm, frames, trans: np.ndarray) -> dict[str, np.ndarray]:
    """The ``predict_sequence`` input: the garment's arrays and the body's motion as a dataset
    stores it (poses, root translations that pose the body as ``frames``, joints, betas)."""
    return {**garment.arrays,
            "body/poses": np.asarray(bm.motion.poses, np.float32),
            "body/trans": np.asarray(trans, np.float32),
            "body/joints": np.asarray(frames.joints, np.float32),
            "body/betas": np.asarray(bm.betas, np.float32).reshape(-1),
            "body/model": np.asarray(garment.body_model),
            "fps": np.asarray(float(bm.motion.fps))}


def outside(verts: np.ndarray, frames, clearance: float, wdev: str) -> np.ndarray:
    """``verts`` (T, V, 3) moved out of the body to ``clearance`` [m] (0: as they are)."""
    from sim.quality import push_outside

    if not clearance > 0:
        return np.asarray(verts, np.float32)
    return push_outside(verts, frames.vertices, frames.faces, clearance=clearance, device=wdev)


def garment_geometry(pred, fine: np.ndarray, seq: dict, surface: str, frames, clearance: float, wdev: str):
    """(vertices (T, V, 3), vertex normals (T, V, 3), normal maps (T, H, W, 3) or None) of the
    stage's garment for ``--surface`` (module docstring), moved out of the body by ``clearance``;
    ``fine``: the predicted fine garment already moved out."""
    from pipelines.preview import vertex_normals

    if surface == "global":
        verts = outside(pred.extras["global_surface"], frames, clearance, wdev)
        return verts, pred.extras["global_normals"], pred.extras["normal_maps"]
    return fine, np.stack([vertex_normals(v, seq["fine/faces"]) for v in fine]), None


def _model(args: argparse.Namespace):
    """(method, model, its dataset's garment, torch device) of a DeepWrinkles run."""
    from learn.train.distributed import resolve_torch_device
    from learn.train.trainer import load_trained

    dev = resolve_torch_device(args.device)
    method, model, _ = load_trained(args.model, device=dev)
    if method.name != "deepwrinkles":
        raise WrinklesInputError(f"expected a deepwrinkles model, got {method.name}", path=args.model)
    garment = dataset_garment(Path(args.data), method) if args.data else checkpoint_garment(method)
    if garment is None:
        raise WrinklesInputError("this checkpoint keeps no garment: pass --data, the dataset it was "
                                 "trained on", path=args.model)
    if args.body not in ("default", garment.body_model):
        raise WrinklesInputError(f"--body {args.body}: the model was trained on body model "
                                 f"{garment.body_model!r} (its dataset's), which poses its template")
    return method, model, garment, dev


def _stage_track(garment: DatasetGarment, verts: np.ndarray, normals: np.ndarray, maps):
    from usd_io import GarmentTrack

    a = garment.arrays
    return GarmentTrack(name=garment.category, vertices=verts, faces=a["fine/faces"], uvs=a["fine/uvs"],
                        uv_faces=a["fine/uv_faces"], normals=normals, face_layers=a.get("fine/face_layers"),
                        normal_maps=maps)


def _preview(garment: DatasetGarment, verts: np.ndarray, shading, frames, bm) -> list:
    """The preview's meshes: the body and the garment ``verts`` (T, V, 3), shaded by the per-vertex
    normals ``shading`` (T, V, 3) where given."""
    import dataclasses

    from pipelines.simulate_cmd import preview_meshes

    meshes = preview_meshes(_preview_sequence(garment, verts, frames, bm))
    if shading is not None:
        meshes[-1] = dataclasses.replace(meshes[-1], normals=shading)
    return meshes


def _preview_sequence(garment: DatasetGarment, fine: np.ndarray, frames, bm):
    """The garment on the body, for ``preview_meshes``."""
    from sim.garments.materials import get_material
    from sim.garments.types import Garment
    from sim.types import GarmentSequence

    a = garment.arrays
    try:
        material = get_material(garment.material)
    except WrinklesInputError:  # a label of the dataset's own: the preview draws no material
        material = get_material("cotton")
    g = Garment(rest_vertices=a["fine/rest_vertices"], faces=a["fine/faces"], uvs=a["fine/uvs"],
                uv_faces=a["fine/uv_faces"], material=material,
                category=garment.category, name=garment.category, face_layers=a.get("fine/face_layers"))
    return GarmentSequence(vertices=fine, body=frames, garment=g, motion=bm.motion, fps=float(bm.motion.fps))


@dataclass
class Animated:
    """A DeepWrinkles prediction on a body motion (``animate_motion``): what ``run`` writes.

    Attributes:
        garment: the model's garment.
        bm: the body and its motion (``pipelines.options.BodyAndMotion``).
        frames: the posed body (``BodyFrames``).
        pred: the method's ``Prediction``.
        verts, normals, maps: the stage's garment for ``--surface`` (``garment_geometry``).
        seconds: the prediction's time.
    """

    garment: DatasetGarment
    bm: object
    frames: object
    pred: object
    verts: np.ndarray
    normals: np.ndarray
    maps: np.ndarray | None
    seconds: dict

    @property
    def shading(self) -> np.ndarray | None:
        """Per-vertex normals of the maps on the global shape (None on the ``fine`` surface)."""
        return self.pred.extras["detail_normals"] if self.maps is not None else None


def animate_motion(args: argparse.Namespace, loaded=None) -> Animated:
    """The model of ``args`` (``check_options`` done) on its body and motion; ``loaded``: the
    ``_model(args)`` of an earlier call to reuse."""
    import torch

    from pipelines.animate_cmd import grounded_frames
    from pipelines.options import load_body_and_motion
    from sim.device import resolve_device

    method, model, garment, dev = loaded or _model(args)
    torch.manual_seed(args.seed)
    wdev = resolve_device(args.device)
    bm = load_body_and_motion(argparse.Namespace(**{**vars(args), "body": garment.body_model}))
    frames, trans = grounded_frames(bm, wdev)
    seq = motion_sequence(garment, bm, frames, trans)
    t1 = time.perf_counter()
    pred = method.predict_sequence(model, seq, device=dev)
    seconds = {"predict": time.perf_counter() - t1}
    fine = outside(pred.vertices, frames, args.clearance, wdev)
    verts, normals, maps = garment_geometry(pred, fine, seq, args.surface, frames, args.clearance, wdev)
    return Animated(garment=garment, bm=bm, frames=frames, pred=pred, verts=verts, normals=normals,
                    maps=maps, seconds=seconds)


def run(args: argparse.Namespace) -> int:
    """The command (module docstring); returns the exit status."""
    check_options(args)  # before the imports: a usage error answers at once
    from pipelines.outputs import OutputSet, check_stage_outputs, command_line, stage_rig, write_previews
    from pipelines.progress import progress_bar
    from sim.versions import package_versions
    from usd_io import write_stage
    from usd_io.textures import NORMALS_FOLDER_SUFFIX

    t0 = time.perf_counter()
    loaded = _model(args)
    method, _, garment, dev = loaded
    out = args.out or f"out/deepwrinkles_{garment.category}_{Path(args.motion).stem}.usdc"
    paths = check_stage_outputs(out, args.preview, args.sheet, sidecar=".animate.json")
    anim = animate_motion(args, loaded)
    bm, frames, verts, normals, maps = anim.bm, anim.frames, anim.verts, anim.normals, anim.maps
    seconds = anim.seconds
    if not args.quiet and abs(garment.fps - bm.motion.fps) > 1e-6:
        print(f"note: the model was trained at {garment.fps:g} fps; its LSTM reads windows of "
              f"{method.config.window} frames", file=sys.stderr)
    provenance = {"command": command_line(), "method": "deepwrinkles", "model": str(args.model),
                  "data": str(args.data) if args.data else None, "dataset_fps": garment.fps,
                  "garment_sequence": garment.sequence,
                  "surface": args.surface,
                  "normal_map_bits": args.normal_map_bits if maps is not None else None, "device": str(dev),
                  "seed": args.seed, "stage_seconds": {k: round(v, 3) for k, v in seconds.items()},
                  "versions": package_versions("usd-core")}
    betas = [float(b) for b in np.asarray(bm.betas).ravel()]
    metadata = json.loads(json.dumps({**provenance, "motion_params": bm.params, "betas": betas}))
    T = len(verts)
    with OutputSet() as outputs:
        outputs.temp(paths.sidecar).write_text(json.dumps(metadata, indent=2, sort_keys=True) + "\n")
        write_previews(outputs, paths, lambda: _preview(garment, verts, anim.shading, frames, bm),
            num_frames=T, fps=float(bm.motion.fps), camera=args.camera, quiet=args.quiet)
        # last, under its final name: the stage names its maps' folder after itself, and
        # write_stage puts both in place atomically
        with progress_bar(T, "writing USD", quiet=args.quiet) as advance:
            write_stage(paths.usd, body=frames, fps=float(bm.motion.fps), garments=[
                _stage_track(garment, verts, normals, maps)], body_name="Body", metadata=metadata,
                progress=advance, rig=stage_rig(bm.body, bm.betas, frames, points=args.body_points),
                normal_map_bits=args.normal_map_bits)
    if not args.quiet:
        what = "global shape + normal maps" if maps is not None else "fine garment"
        print(f"deepwrinkles {garment.category} ({verts.shape[1]} vertices) on {bm.motion.name}: {T} frames, "
              f"{what}, {dev}, {time.perf_counter() - t0:.1f} s")
        for p in paths.written():
            print(f"  wrote {p}")
        if maps is not None:
            print(f"  wrote {paths.usd.with_name(paths.usd.stem + NORMALS_FOLDER_SUFFIX)}/ ({T} normal maps)")
    return 0
