"""DeepWrinkles' prediction of one sequence (the inference path of ``learn.methods.deepwrinkles``):
body motion -> subspace coefficients -> global shape -> LR maps -> HR maps -> fine geometry."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np
import torch

from learn.methods.base import Prediction


@torch.no_grad()
def coefficients(method, model, controls: np.ndarray, device: torch.device,
                 regressor: str = "") -> np.ndarray:
    """Subspace coefficients (T, k) of a sequence's control vectors (T, C): the LSTM's last output
    of the window ending at each frame, or the linear map (``regressor``, default
    ``config.regressor``)."""
    from learn.deepwrinkles.regression import LinearPoseToShape, windows

    s = method.state
    ctl = method.normalise_controls(controls)
    if (regressor or method.config.regressor) == "linear":
        return LinearPoseToShape(s["linear"].numpy())(ctl)
    win = torch.from_numpy(windows(ctl, method.config.window)).to(device)
    dtype = next(model.regressor.parameters()).dtype
    out = model.regressor(win.to(dtype))[:, -1].float().cpu().numpy()
    return out * s["coefficient_scale"].numpy()


@torch.no_grad()
def generate(method, model, lr: np.ndarray, mask: np.ndarray, device: torch.device) -> np.ndarray:
    """HR maps (T, H, W, 3), unit vectors inside ``mask``, from LR maps (T, H, W, 3)."""
    gen = model.generator
    dtype = next(gen.parameters()).dtype
    out = []
    for s in range(0, len(lr), method.config.infer_batch):
        x = torch.from_numpy(
            np.ascontiguousarray(lr[s : s + method.config.infer_batch].transpose(0, 3, 1, 2))
        )
        y = gen(x.to(device, dtype)).float().cpu().numpy().transpose(0, 2, 3, 1)
        out.append(y)
    y = np.concatenate(out)
    y = y / np.maximum(np.linalg.norm(y, axis=-1, keepdims=True), 1e-6)
    return (y * mask[..., None]).astype(np.float32)


LR_INPUTS = ("regression", "registration", "subspace")
"""Where a prediction's global shape comes from (the paper's Table 1 columns): the pose-to-shape
regression (the method's use), the sequence's registrations (needs its fine frames), or the
registrations projected on the subspace's first ``components`` ("BS k")."""


def global_shapes(method, model, prep, lr_input: str, components: int, device,
                  regressor: str = "", source: str = "") -> np.ndarray:
    """Template positions (T, Vc, 3) of a sequence's global shape from ``lr_input`` (the
    registration inputs need the sequence's fine frames and its file, ``"sequence/path"``, for
    the registrations' cache; ``source`` "registration" or "simulation" overrides the model's
    ``config.source`` for them)."""
    from learn.methods.deepwrinkles import SOURCES
    from sim.datasets.storage import SequenceFile
    from sim.errors import WrinklesInputError

    if lr_input not in LR_INPUTS:
        raise WrinklesInputError(f"lr_input {lr_input!r}: expected one of {', '.join(LR_INPUTS)}")
    sub = method.subspace()
    if lr_input == "regression":
        from learn.methods.deepwrinkles import REGRESSORS

        if regressor and regressor not in REGRESSORS:
            raise WrinklesInputError(f"regressor {regressor!r}: expected one of {', '.join(REGRESSORS)}")
        return prep.posed(sub.decode(coefficients(method, model, prep.controls, device, regressor)))
    if "sequence/path" not in prep.seq or "fine/vertices" not in prep.seq:
        raise WrinklesInputError(f"lr_input {lr_input!r} registers a dataset sequence's fine frames: "
                                 "this sequence has none")
    scan_device = str(device) if str(device).startswith("cuda") else "cpu"
    if source and source not in SOURCES:
        raise WrinklesInputError(f"source {source!r}: expected one of {', '.join(SOURCES)}")
    settings = dataclasses.replace(method.settings(), source=source) if source else method.settings()
    prep.register(SequenceFile(str(prep.seq["sequence/path"])), settings, device=scan_device)
    if lr_input == "registration":
        return prep.posed(prep.normalised)
    k = components or sub.size
    if not 1 <= k <= sub.size:
        raise WrinklesInputError(f"components must be in 1..{sub.size}, got {k}")
    return prep.posed(sub.decode(sub.encode(prep.normalised, k)))


def map_metrics(hr: np.ndarray, truth: np.ndarray, mask: np.ndarray, temporal_kind: str = "eq4") -> dict:
    """Pixel-wise errors of predicted HR maps against the simulation's (T, H, W, 3), the paper's
    Table 1 rows: ``nm_l1`` / ``nm_l2`` (mean absolute / squared difference over covered pixels,
    Eq. 4's data term) and ``nm_temporal`` (Eq. 4's temporal term: each frame against the
    simulation's previous frame)."""
    from learn.deepwrinkles.cgan import temporal_term

    m = mask[None, ..., None].astype(np.float32)
    n = max(float(m.sum()) * hr.shape[0] * 3, 1.0)
    d = (hr - truth) * m
    out = {"nm_l1": float(np.abs(d).sum() / n), "nm_l2": float((d * d).sum() / n)}
    if len(hr) > 1:
        g = torch.from_numpy(np.ascontiguousarray(hr[1:].transpose(0, 3, 1, 2)))
        p = torch.from_numpy(np.ascontiguousarray(truth[:-1].transpose(0, 3, 1, 2)))
        out["nm_temporal"] = float(
            temporal_term(g, p, torch.from_numpy(mask.astype(np.float32)), kind=temporal_kind)
        )
    return out


@torch.no_grad()
def predict(
    method,
    model,
    sequence: Mapping[str, np.ndarray],
    *,
    device: torch.device,
    lr_input: str = "regression",
    components: int = 0,
    regressor: str = "",
    source: str = "",
) -> Prediction:
    """A whole sequence (``Method.predict_sequence``): fine vertices from Guo et al.'s Eq. 10 on
    the global shape's fine surface, with ``extras``: ``normal_maps`` (HR, T x H x W x 3),
    ``lr_maps``, ``global_shape`` (template positions, T x Vc x 3) and the global shape on the
    fine mesh (``global_surface``, ``global_normals``, T x V x 3, what the maps apply to) and its
    normals from the HR maps (``detail_normals``: the normal-mapped look, T x V x 3); where
    the sequence has its simulated fine frames, also ``hr_truth`` and the map metrics
    (``map_metrics``).

    Args:
        lr_input, components: the global shape's source (``LR_INPUTS``) and, for "subspace", k.
        regressor: "lstm" or "linear" for the "regression" input (default: ``config.regressor``;
            the paper compares the two in Sec. 5.3).
        source: the registration inputs' data: "registration" (scans of the fine frames,
            registered) or "simulation" (the template's true places); default ``config.source``.
    """
    from learn.deepwrinkles.sequences import PreparedSequence
    from sim.geometry.normal_geometry import deform_to_normals

    fps = float(np.asarray(sequence.get("fps", 30.0)))
    body = method.body(str(sequence.get("body/model", "default")))
    prep = PreparedSequence(sequence, body, fps, method.config.resolution, device="cpu")
    was_training = model.training
    model.eval()
    try:
        global_shape = global_shapes(method, model, prep, lr_input, components, device, regressor, source)
        lr = prep.maps.lr(global_shape, prep.rig.skinned())
        hr = generate(method, model, lr, prep.maps.mask, device)
    finally:
        model.train(was_training)
    base, base_normals = prep.maps.surface(global_shape)
    normals = prep.maps.decode(hr, global_shape)
    faces = prep.maps.faces
    verts = np.stack([deform_to_normals(b, faces, n) for b, n in zip(base, normals, strict=True)])
    extras = {"lr_maps": lr, "normal_maps": hr, "global_shape": global_shape, "global_surface": base,
              "global_normals": base_normals, "detail_normals": normals}
    metrics = {}
    if "fine/vertices" in sequence:
        extras["hr_truth"] = prep.maps.hr(np.asarray(sequence["fine/vertices"], np.float32), global_shape)
        metrics = map_metrics(hr, extras["hr_truth"], prep.maps.mask, method.config.temporal_kind)
    return Prediction(vertices=verts.astype(np.float32), extras=extras, metrics=metrics)
