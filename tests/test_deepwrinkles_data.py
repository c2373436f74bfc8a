"""DeepWrinkles' data side: pose/shape normalisation of registrations (Eq. 3, 5), their cache and
interpolation, the tangent-space LR/HR normal maps, and the training loss reaching every network."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learn.deepwrinkles import global_shape as G
from learn.deepwrinkles.registrations import RegisteredSequence, SequenceRig
from sim.rotations import axis_angle_to_matrix


def random_rig(V: int = 40, J: int = 4, T: int = 5, seed: int = 0) -> tuple[SequenceRig, np.ndarray]:
    """A rig with random weights and rigid bone transforms, and a reference rest 1 cm off."""
    rng = np.random.default_rng(seed)
    rest = rng.normal(size=(V, 3)).astype(np.float32) * 0.2
    w = rng.random((V, J)) ** 3
    w /= w.sum(1, keepdims=True)
    rot = axis_angle_to_matrix(rng.normal(size=(T * J, 3)) * 0.4).reshape(T, J, 3, 3)
    A = np.concatenate([rot, rng.normal(size=(T, J, 3, 1)) * 0.1], axis=3).astype(np.float32)
    rig = SequenceRig(
        rest=rest,
        faces=np.zeros((1, 3), np.int32),
        weights=w.astype(np.float32),
        transforms=A,
        local=rot.astype(np.float32),
    )
    return rig, rest - 0.01


def test_normalise_then_pose_returns_the_registrations():
    rig, ref = random_rig()
    rng = np.random.default_rng(1)
    posed = rig.skinned() + rng.normal(size=rig.skinned().shape).astype(np.float32) * 0.02
    reg = RegisteredSequence(frames=np.arange(5), vertices=posed, truth=posed, pairs=np.zeros(5, np.int64))
    bar = G.normalise(rig, ref, reg, 5)
    np.testing.assert_allclose(G.pose(rig, ref, bar), posed, atol=2e-5)
    # the skinned template itself normalises to the reference rest (Eq. 5: mean shape + offset)
    reg0 = RegisteredSequence(
        frames=np.arange(5), vertices=rig.skinned(), truth=posed, pairs=np.zeros(5, np.int64)
    )
    np.testing.assert_allclose(
        G.normalise(rig, ref, reg0, 5), np.broadcast_to(ref, (5, *ref.shape)), atol=2e-5
    )


def test_frames_between_registrations_are_interpolated_in_the_normalised_space():
    rig, ref = random_rig(T=7)
    rng = np.random.default_rng(2)
    frames = G.registered_frames(7, 3)
    assert frames.tolist() == [0, 3, 6]
    assert G.registered_frames(8, 3).tolist() == [0, 3, 6, 7]
    posed = rig.skinned(frames) + rng.normal(size=(3, 40, 3)).astype(np.float32) * 0.02
    reg = RegisteredSequence(frames=frames, vertices=posed, truth=posed, pairs=np.zeros(3, np.int64))
    bar = G.normalise(rig, ref, reg, 7)
    np.testing.assert_allclose(G.pose(rig, ref, bar)[frames], posed, atol=2e-5)
    np.testing.assert_allclose(bar[1], (2 * bar[0] + bar[3]) / 3, atol=1e-6)
    np.testing.assert_allclose(bar[5], (bar[3] + 2 * bar[6]) / 3, atol=1e-6)


class _File:
    def __init__(self, path):
        self.path = path


def test_registrations_are_made_once_then_read_from_the_cache(tmp_path, monkeypatch):
    import learn.deepwrinkles.registrations as R

    calls = []
    truth = np.random.default_rng(3).normal(size=(4, 6, 3)).astype(np.float32)

    def fake(seq, body, *, frames, **kw):
        calls.append(frames.tolist())
        return RegisteredSequence(
            frames=frames,
            vertices=truth[frames] + 1.0,
            truth=truth[frames],
            pairs=np.ones(len(frames), np.int64),
        )

    monkeypatch.setattr(R, "register_sequence", fake)
    (tmp_path / "sequences").mkdir()
    sf = _File(tmp_path / "sequences" / "seq-00000.safetensors")
    seq = {"fine/vertices": np.zeros((4, 6, 3), np.float32)}
    settings = G.RegistrationSettings(register_every=2)
    a = G.registrations(sf, seq, None, settings)
    b = G.registrations(sf, seq, None, settings)
    assert calls == [[0, 2, 3]]
    assert G.cache_path(sf, settings).parent == tmp_path / "derived" / "deepwrinkles"
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_allclose(a.errors(), np.full((3, 6), np.sqrt(3.0)), rtol=1e-6)
    # other settings are another file
    assert G.cache_path(sf, G.RegistrationSettings(register_every=1)) != G.cache_path(sf, settings)


@pytest.fixture(scope="module")
def tshirt_pair():
    """A t-shirt's coarse template and fine garment as a dataset sequence's arrays (rest pose)."""
    from sim.bodies import load_body
    from sim.garments import make_garment

    body = load_body()
    coarse = make_garment("t_shirt", body, resolution=0.06)
    fine = make_garment("t_shirt", body, resolution=0.03)
    seq = {
        "coarse/rest_vertices": coarse.rest_vertices,
        "coarse/faces": coarse.faces,
        "coarse/uvs": coarse.uvs,
        "coarse/uv_faces": coarse.uv_faces,
        "fine/rest_vertices": fine.rest_vertices,
        "fine/faces": fine.faces,
        "fine/uvs": fine.uvs,
        "fine/uv_faces": fine.uv_faces,
        "fine/vertices": fine.rest_vertices[None],
    }
    return seq


def test_normal_maps_are_tangent_space_and_decode_back(tshirt_pair):
    from learn.deepwrinkles.normal_maps import DetailMaps
    from learn.deepwrinkles.registrations import template_truth

    seq = tshirt_pair
    maps = DetailMaps(seq, 64, device="cpu")
    m = maps.mask
    template = template_truth(seq).evaluate(seq["fine/faces"], seq["fine/vertices"])  # (1, Vc, 3)
    flat = maps.lr(template, template)
    assert np.all(flat[0][m][:, 2] > 0.999)  # a surface against itself: +z everywhere
    fine = seq["fine/vertices"]
    hr = maps.hr(fine, template)
    z = hr[0][m][:, 2]
    assert 0.9 < z.mean() < 0.999  # the fine surface deviates from the template's, a little
    n = maps.decode(hr, template)
    ref = maps.maps.frames.normals(fine)
    angle = np.degrees(np.arccos(np.clip(np.sum(n * ref, axis=-1), -1.0, 1.0)))
    assert np.mean(angle) < 3.0, np.mean(angle)
    # tangent space: turning the garment and its template together leaves the maps unchanged
    R = axis_angle_to_matrix(np.array([[0.3, 1.1, -0.4]]))[0].astype(np.float32)
    hr_turned = maps.hr(fine @ R.T, template @ R.T)
    assert np.abs(hr_turned - hr)[0][m].max() < 2e-3


def fake_state(V: int = 30, k: int = 6, C: int = 150) -> dict[str, torch.Tensor]:
    q, _ = np.linalg.qr(np.random.default_rng(4).normal(size=(3 * V, k)))
    return {
        "mean": torch.zeros(V, 3),
        "components": torch.from_numpy(q.T.astype(np.float32)),
        "singular_values": torch.ones(k, dtype=torch.float64),
        "total_variance": torch.tensor(float(k)),
        "frames": torch.tensor(10),
        "control_mean": torch.zeros(C),
        "control_std": torch.ones(C),
        "coefficient_scale": torch.ones(k),
        "linear": torch.zeros(k, C + 1, dtype=torch.float64),
        "template_faces": torch.zeros(1, 3, dtype=torch.int64),
    }


def test_training_loss_reaches_the_regressor_and_both_cgan_networks():
    from learn.methods.deepwrinkles import DeepWrinklesConfig, DeepWrinklesMethod

    torch.manual_seed(0)
    method = DeepWrinklesMethod(
        DeepWrinklesConfig(resolution=32, filters=4, hidden=8, layers=2, components=6)
    )
    method.load_state(fake_state())
    model = method.build_model()
    B, H = 2, 32
    maps = torch.nn.functional.normalize(torch.randn(3, B, 3, H, H), dim=2)
    batch = {
        "controls": torch.randn(B, 3, 150),
        "coefficients": torch.randn(B, 3, 6),
        "lr": maps[0],
        "hr": maps[1],
        "hr_prev": maps[2],
        "mask": torch.ones(B, 1, H, H),
    }
    out = method.training_loss(model, batch, torch.Generator())
    out.loss.backward()
    for part in ("regressor", "generator", "discriminator"):
        g = [p.grad for p in getattr(model, part).parameters() if p.grad is not None]
        assert g and sum(float(x.abs().sum()) for x in g) > 0, part
    assert {"coefficients", "data", "temporal", "gan_g", "gan_d"} <= set(out.scalars)
    assert out.scalars["coefficients"] > 0.5  # an untrained LSTM against unit-variance targets
    # items with several regression windows (B, R, W, C): the LSTM's loss over all B x R windows
    R = 4
    many = {**batch, "controls": torch.randn(B, R, 3, 150), "coefficients": torch.randn(B, R, 3, 6)}
    with torch.no_grad():
        loss = method.training_loss(model, many, torch.Generator()).scalars["coefficients"]
        pred = model.regressor(many["controls"].flatten(0, 1))
    torch.testing.assert_close(loss, (pred - many["coefficients"].flatten(0, 1)).square().mean())
    # prediction's regressor: the LSTM by default, the closed-form map on request (Sec. 5.3)
    from learn.deepwrinkles.prediction import coefficients
    from learn.deepwrinkles.regression import LinearPoseToShape

    ctl = np.random.default_rng(1).normal(size=(5, 150))
    linear = coefficients(method, model, ctl, torch.device("cpu"), "linear")
    expected = LinearPoseToShape(method.state["linear"].numpy())(method.normalise_controls(ctl))
    np.testing.assert_allclose(linear, expected, atol=1e-6)
    assert np.abs(coefficients(method, model, ctl, torch.device("cpu")) - linear).max() > 1e-3


def test_bad_settings_are_refused():
    from learn.methods.deepwrinkles import DeepWrinklesConfig, DeepWrinklesMethod

    for bad in (
        {"resolution": 48},
        {"regressor": "gp"},
        {"source": "scan"},
        {"temporal_weight": -1.0},
        {"window": 0},
        {"regression_windows": 0},
        {"control_joints": "arms"},
    ):
        with pytest.raises(ValueError, match=next(iter(bad))):
            DeepWrinklesMethod.validate_config(DeepWrinklesConfig(**bad), ValueError)


def test_the_template_moves_with_the_body_shape():
    """Eq. 5 retargeting: a reference-fit template worn by another body shape keeps each vertex's
    offset from its closest point of the body surface (in that triangle's frame), so its distance
    to the new body equals its distance to the reference body."""
    from learn.deepwrinkles.registrations import sequence_rig
    from sim.bodies import load_body
    from sim.dressing import bind_to_surface

    body = load_body()
    rng = np.random.default_rng(5)
    ref = body.rest_mesh(None)
    idx = rng.choice(len(ref), 60, replace=False)
    normals = ref[idx] - ref.mean(axis=0)
    rest = (ref[idx] + 0.02 * normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)
    betas = np.zeros(body.num_betas, np.float32)
    betas[:2] = (2.5, -1.5)  # outside a dataset's usual +-2 range
    seq = {"coarse/rest_vertices": rest, "coarse/faces": np.array([[0, 1, 2]], np.int32), "body/betas": betas,
           "body/poses": np.zeros((1, 24, 3), np.float32), "body/joints": body.rest_joints(betas)[None]}
    rig = sequence_rig(seq, body)
    shaped = body.rest_mesh(betas)
    before = bind_to_surface(rest, ref, body.faces, device="cpu")
    after = bind_to_surface(rig.rest, shaped, body.faces, device="cpu")
    gap = [np.linalg.norm(b.offset, axis=1) for b in (before, after)]
    np.testing.assert_allclose(gap[1], gap[0], atol=2e-3)
    assert np.linalg.norm(rig.rest - rest, axis=1).mean() > 0.01  # the shape change moved it
    # and at the reference shape nothing moves
    mean_shape = {"body/betas": np.zeros_like(betas), "body/joints": body.rest_joints(None)[None]}
    same = sequence_rig({**seq, **mean_shape}, body)
    np.testing.assert_array_equal(same.rest, rest)


def test_map_metrics_against_a_hand_computation():
    from learn.deepwrinkles.prediction import map_metrics

    mask = np.zeros((4, 4), bool)
    mask[1:3, 1:3] = True  # 4 covered pixels
    truth = np.zeros((2, 4, 4, 3), np.float32)
    truth[..., 2] = 1.0
    hr = truth.copy()
    hr[1, 1, 1] = (0.6, 0.0, 0.8)  # one covered pixel of frame 1 differs
    hr[:, 0, 0] = (1.0, 0.0, 0.0)  # an uncovered pixel counts for nothing
    m = map_metrics(hr, truth, mask)
    n = 2 * 4 * 3
    assert m["nm_l1"] == pytest.approx((0.6 + 0.2) / n)
    assert m["nm_l2"] == pytest.approx((0.36 + 0.04) / n)
    # Eq. 4: |sum over pixels of (gen_t - gt_{t-1})| per channel, summed, over covered pixels
    assert m["nm_temporal"] == pytest.approx((0.6 + 0.2) / 4)
    assert map_metrics(truth, truth, mask)["nm_l1"] == 0.0


def test_bad_prediction_options_are_refused():
    from learn.methods.deepwrinkles import DeepWrinklesConfig, DeepWrinklesMethod
    from pipelines.evaluate_cmd import _predict_options
    from sim.errors import WrinklesInputError

    method = DeepWrinklesMethod(DeepWrinklesConfig())
    assert _predict_options(["lr_input=registration", "components=200"], method) == {
        "lr_input": "registration", "components": 200}
    assert _predict_options(["regressor=linear"], method) == {"regressor": "linear"}
    assert _predict_options(["source=registration"], method) == {"source": "registration"}
    import types

    from learn.deepwrinkles.prediction import global_shapes

    method.load_state(fake_state())
    prep = types.SimpleNamespace(seq={"sequence/path": "x.safetensors", "fine/vertices": np.zeros((1, 3, 3))})
    with pytest.raises(WrinklesInputError, match="source 'scan'"):
        global_shapes(method, None, prep, "registration", 0, torch.device("cpu"), source="scan")
    for bad in ("steps=20", "lr_input", "sequence_file=x"):
        with pytest.raises(WrinklesInputError, match="--predict"):
            _predict_options([bad], method)


def test_the_registration_cache_follows_the_garment_settings(monkeypatch):
    """Cached registrations are of the settings that made them: another garment registration
    weight is another cache file."""
    import learn.deepwrinkles.registrations as R

    before = G.RegistrationSettings().digest()
    monkeypatch.setitem(R.GARMENT_REGISTRATION_SETTINGS, "edge", R.GARMENT_REGISTRATION_SETTINGS["edge"] * 2)
    assert G.RegistrationSettings().digest() != before
