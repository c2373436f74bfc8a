"""DeepWrinkles' prediction of one sequence (the inference path of ``learn.methods.deepwrinkles``):
body motion -> subspace coefficients -> global shape -> LR maps -> HR maps -> fine geometry."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from learn.methods.base import Prediction


@torch.no_grad()
def coefficients(method, model, controls: np.ndarray, device: torch.device) -> np.ndarray:
    """Subspace coefficients (T, k) of a sequence's control vectors (T, C): the LSTM's last output
    of the window ending at each frame, or the linear map (``config.regressor``)."""
    from learn.deepwrinkles.regression import LinearPoseToShape, windows

    s = method.state
    ctl = (controls - s["control_mean"].numpy()) / s["control_std"].numpy()
    if method.config.regressor == "linear":
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


@torch.no_grad()
def predict(method, model, sequence: Mapping[str, np.ndarray], *, device: torch.device) -> Prediction:
    """A whole sequence (``Method.predict_sequence``): fine vertices from Guo et al.'s Eq. 10 on
    the global shape's fine surface, with ``extras``: ``normal_maps`` (HR, T x H x W x 3),
    ``lr_maps`` and ``global_shape`` (template positions, T x Vc x 3)."""
    from learn.deepwrinkles.sequences import PreparedSequence
    from sim.geometry.normal_geometry import deform_to_normals

    fps = float(np.asarray(sequence.get("fps", 30.0)))
    body = method.body(str(sequence.get("body/model", "default")))
    prep = PreparedSequence(sequence, body, fps, method.config.resolution, device="cpu")
    was_training = model.training
    model.eval()
    try:
        lam = coefficients(method, model, prep.controls, device)
        global_shape = prep.posed(method.subspace().decode(lam))
        lr = prep.maps.lr(global_shape, prep.skinned())
        hr = generate(method, model, lr, prep.maps.mask, device)
    finally:
        model.train(was_training)
    base, _ = prep.maps.surface(global_shape)
    normals = prep.maps.decode(hr, global_shape)
    faces = prep.maps.faces
    verts = np.stack([deform_to_normals(b, faces, n) for b, n in zip(base, normals, strict=True)])
    return Prediction(
        vertices=verts.astype(np.float32),
        extras={"normal_maps": hr, "lr_maps": lr, "global_shape": global_shape},
    )
