"""GSNet as a method (learn.methods.gsnet, learn.gsnet.features / data) on the sample dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from learn.gsnet.features import TEMPLATE_FEATURES, material_features, template_features, vertex_uvs
from learn.methods.gsnet import GSNetConfig, GSNetMethod

TINY = GSNetConfig(width=16, node=8)


def test_vertex_uvs_take_each_vertexs_first_corner():
    faces = np.array([[0, 1, 2], [2, 1, 3]])
    uv_faces = np.array([[0, 1, 2], [4, 3, 5]])  # vertex 1 and 2 have a seam: two UV vertices each
    uvs = np.arange(12, dtype=np.float32).reshape(6, 2)
    got = vertex_uvs(faces, uvs, uv_faces, 5)
    np.testing.assert_array_equal(got, [uvs[0], uvs[1], uvs[2], uvs[5], [0, 0]])


def test_material_features_are_log_ratios_to_cotton():
    from sim.garments.materials import get_material

    np.testing.assert_array_equal(material_features("cotton"), np.zeros(3, np.float32))
    d, c = get_material("denim"), get_material("cotton")
    np.testing.assert_allclose(material_features("denim"),
                               np.log10([d.density / c.density, d.youngs_modulus / c.youngs_modulus,
                                         d.bending_stiffness / c.bending_stiffness]), rtol=1e-6)


def test_template_features_of_a_flat_square():
    rest = np.array([[0, 1, 0], [1, 1, 0], [0, 2, 0], [1, 2, 0]], np.float32)
    faces = np.array([[0, 1, 2], [2, 1, 3]])
    f = template_features(rest, faces, rest[:, :2] / 2, faces, "cotton", np.array([0, 1, 0]),
                          face_layers=np.array([1.0, 3.0]))
    assert f.shape == (4, TEMPLATE_FEATURES)
    np.testing.assert_array_equal(f[:, :3], rest - [0, 1, 0])  # relative to the root
    np.testing.assert_allclose(f[:, 3:6], np.tile([0, 0, 1], (4, 1)), atol=1e-6)  # counter-clockwise: +z
    np.testing.assert_array_equal(f[:, 6:8], rest[:, :2] / 2)
    np.testing.assert_array_equal(f[:, 11], [1, 2, 2, 3])  # mean layers of the faces around each vertex


def test_rest_pose_keeps_the_template_where_it_was_made():
    """Zero pose on the garment's own body shape: every bone transform is the identity, so the
    untrained network's prior returns the rest garment, wherever the root stands."""
    from learn.gsnet.data import garment_batch, make_template, motion_of
    from sim.bodies import load_body

    body = load_body("default")
    betas = np.array([0.8, -0.4], np.float32)
    rest = body.rest_mesh(betas)[::40] * 1.05  # a loose "garment" of body points
    faces = np.array([[i, i + 1, i + 2] for i in range(0, len(rest) - 2, 3)], np.int32)
    trans = np.array([[0.3, 1.1, -0.2], [0.3, 1.1, -0.2], [0.35, 1.1, -0.2]], np.float32)
    poses = np.zeros((3, 24, 3), np.float32)
    frames = body.pose(betas, poses, trans, device="cpu")
    seq = {"fine/rest_vertices": rest, "fine/faces": faces, "fine/uvs": np.zeros((len(rest), 2), np.float32),
           "fine/uv_faces": faces, "body/betas": betas, "body/poses": poses,
           "body/joints": frames.joints[:, :24], "body/trans": trans}
    t = make_template(seq, body, "cotton")
    a, roots = motion_of(seq, body)
    model = GSNetMethod(TINY).build_model()
    g = garment_batch([t])
    enc = model.encode(g)
    x = model.prior(enc, g, torch.from_numpy(a[2])[None]) + torch.from_numpy(roots[2])
    moved = rest + (frames.joints[2, 0] - body.rest_joints(betas)[0])
    np.testing.assert_allclose(x.detach().numpy(), moved, atol=1e-5)


def overfit_losses(root, steps: int, config: GSNetConfig = TINY) -> list[float]:
    return overfit(root, steps, config)[3]


def overfit(root, steps: int, config: GSNetConfig = TINY):
    """A network trained ``steps`` steps on one batch of 4 windows: (method, model, batch, the data
    term of every step)."""
    method = GSNetMethod(config)
    ds = method.train_dataset(root)
    batch = method.collate([ds[(i, i)] for i in range(0, len(ds), max(1, len(ds) // 4))][:4])
    torch.manual_seed(0)
    model = method.build_model()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(steps):
        out = method.training_loss(model, batch, torch.Generator().manual_seed(0))
        opt.zero_grad()
        out.loss.backward()
        opt.step()
        losses.append(float(out.scalars["data"]))
    return method, model, batch, losses


@pytest.mark.slow
def test_tiny_overfit_lowers_the_data_term(sample_dataset):
    losses = overfit_losses(sample_dataset, 100)  # 33 mm rms at step 0 (the skinning prior), 24 mm at 100
    assert losses[-1] < 0.65 * losses[0]


@pytest.mark.slow
def test_a_garment_of_new_topology_runs_through_a_trained_network(sample_dataset, tmp_path):
    """Trained on t-shirts only; a skirt (other topology, other body region) is animated too."""
    from learn.evaluate import evaluate
    from learn.train.config import RunConfig, TrainConfig
    from learn.train.trainer import Trainer

    cfg = RunConfig(method="gsnet", model=GSNetConfig(width=16, node=8, garments=("t_shirt",)),
                    train=TrainConfig(steps=30, batch_size=2, device="cpu", log_every=10,
                                      checkpoint_every=30))
    trainer = Trainer(cfg, sample_dataset, tmp_path / "run")
    trainer.fit()
    model = trainer.method.build_model()
    from learn.train.checkpoint import load_checkpoint

    model.load_state_dict(load_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")["model"])
    ev = evaluate(trainer.method, model.eval(), sample_dataset, "all", garments=("straight_skirt",),
                  image_resolution=0)
    assert ev.sequences and all(s.garment == "straight_skirt" for s in ev.sequences)
    assert np.isfinite(ev.summary["ev"]) and ev.summary["ev"] < 0.06  # the skirt follows the body
    assert ev.summary["edge_abs"] < 0.2


@pytest.mark.slow
def test_training_is_deterministic(sample_dataset):
    a, b = overfit_losses(sample_dataset, 3), overfit_losses(sample_dataset, 3)
    assert a == b


@pytest.fixture(scope="module")
def gsnet_checkpoint(sample_dataset, tmp_path_factory):
    """A GSNet trained for a few steps on the sample dataset (t-shirts and skirts)."""
    from tests.test_train_evaluate import run_cli

    out = tmp_path_factory.mktemp("gsnet-run")
    assert run_cli("train", "gsnet", "--data", sample_dataset, "--out", out, "--steps", "4",
                   "--batch-size", "2", "--set", "model.width=16", "--set", "model.node=8", "--device", "cpu",
                   "-q") == 0
    return out / "checkpoints" / "last.pt"


@pytest.mark.slow
def test_animate_a_user_garment_file_with_gsnet(gsnet_checkpoint, tmp_path):
    """A garment OBJ modelled around the rest body (``wrinkles garments --export``), a design the
    network never saw (a tank top), is animated without retraining and written as USD."""
    from tests.test_cli import run_cli

    obj = tmp_path / "tank.obj"
    proc = run_cli("garments", "--export", "tank_top", "--out", str(obj))
    assert proc.returncode == 0, proc.stderr
    usd = tmp_path / "tank.usda"
    proc = run_cli("animate", "--method", "gsnet", "--model", str(gsnet_checkpoint), "--garment", str(obj),
                   "--motion", "walk", "--duration", "0.3", "--device", "cpu", "--out", str(usd), "-q")
    assert proc.returncode == 0, proc.stderr
    from usd_io import read_stage

    stage = read_stage(usd)
    (garment,) = stage.garments.values()
    pts, body = np.asarray(garment.points), np.asarray(stage.body.points)
    assert pts.shape[0] == 9 and np.isfinite(pts).all()
    # the top stays on the body as it walks: near the skin at the first frame and the last
    from scipy.spatial import cKDTree

    for t in (0, -1):
        gap = cKDTree(body[t]).query(pts[t])[0]
        assert gap.mean() < 0.04 and gap.max() < 0.12


@pytest.mark.slow
@pytest.mark.parametrize("extra, needle", [
    (["--steps", "10"], "--steps does not apply to --method gsnet"),
    (["--model", "missing.pt"], "missing.pt: no such model file"),
    (["--resolution", "0.03", "--method", "diffusion"], "--resolution applies to --method gsnet"),
    (["--garment", "tee.obj", "--resolution", "0.03"], "--resolution applies to templates"),
    (["--garment", "cape"], "unknown garment"),
])
def test_animate_gsnet_refuses_bad_options_in_one_line(gsnet_checkpoint, tmp_path, extra, needle):
    from tests.test_cli import assert_user_error, run_cli

    args = ["animate", "--method", "gsnet", "--model", str(gsnet_checkpoint), "--garment", "t_shirt",
            "--motion", "walk", "--duration", "0.2", "--device", "cpu", "--out", str(tmp_path / "a.usdc")]
    if "--method" in extra:
        args[2] = extra[extra.index("--method") + 1]
        extra = extra[:-2]
    proc = run_cli(*args, *extra)
    assert_user_error(proc, needle)
    assert not (tmp_path / "a.usdc").exists()


@pytest.mark.slow
def test_the_harness_measures_gsnets_normal_angles(sample_dataset):
    """``normal_angle`` (GSNet Sec. 4.3's bending angle between vertex normals): the simulation
    measured against itself gives its own value, and a crumpled copy a larger one."""
    from learn.evaluate import sequence_metrics
    from sim.datasets.config import DeriveConfig
    from sim.datasets.storage import SequenceFile, read_manifest

    manifest = read_manifest(sample_dataset)
    sid, entry = next(iter(manifest["sequences"].items()))
    sf = SequenceFile(sample_dataset / entry["file"])
    gt = np.array(sf["fine/vertices"], np.float32)
    dc = DeriveConfig(image_resolution=0)
    same, _ = sequence_metrics(gt, sf, entry, None, derive_config=dc, device="cpu")
    assert same["ev"] == 0 and same["normal_angle"] == same["normal_angle_gt"] > 0
    noisy = gt + np.random.default_rng(0).normal(0, 0.02, gt.shape).astype(np.float32)
    other, _ = sequence_metrics(noisy, sf, entry, None, derive_config=dc, device="cpu")
    assert other["normal_angle"] > 1.5 * same["normal_angle"]
    assert other["normal_angle_gt"] == same["normal_angle_gt"]


@pytest.mark.slow
def test_the_physical_regression_learns_to_lift_vertices_out_of_the_body(sample_dataset):
    """Sec. 3.4: after a short overfit with the collision term, fewer of the final output's vertices
    are inside the body than of the deep skinning's (the regression moves the ones its filter marks)."""
    from dataclasses import replace

    config = replace(TINY, collision_weight=100.0, cold_start=0.0)
    method, model, batch, _ = overfit(sample_dataset, 60, config)
    g = batch["garments"]
    losses = [method.losses_of(k, t, batch["body_faces"])
              for k, t in zip(batch["keys"], batch["templates"], strict=True)]
    anchors = method._anchors(losses, g, batch["body"], 2)
    with torch.no_grad():
        skinned, final = model(g, batch["transforms"], batch["roots"], batch["history"], anchors=anchors,
                               fps=batch["fps"], eps=config.collision_eps)

    def inside(x):  # the share of vertices behind their nearest body vertex's tangent plane
        fractions = []
        for r, xr in enumerate(x):
            p, n = anchors(xr, r + 2)
            fractions.append(float(((xr - p) * n).sum(-1).lt(0).float().mean()))
        return float(np.mean(fractions))
    assert inside(final) < 0.7 * inside(skinned) and inside(skinned) > 0.01


def test_a_body_with_more_than_smpls_24_joints_is_refused():
    import types

    from learn.gsnet.data import check_body
    from sim.errors import WrinklesInputError

    smplx = types.SimpleNamespace(weights=np.zeros((10, 55)), source="models/smplx.npz", name="smplx")
    with pytest.raises(WrinklesInputError, match="24-joint SMPL bodies; this body model has 55 joints") as e:
        check_body(smplx)
    assert "models/smplx.npz" in str(e.value)
    check_body(types.SimpleNamespace(weights=np.zeros((10, 24)), source=None, name="default"))


@pytest.mark.skipif(Path(__file__).resolve().parents[1].joinpath("pretrained", "gsnet.pt").exists(),
                    reason="this checkout ships GSNet's weights")
def test_animate_gsnet_without_a_model_says_how_to_get_one(tmp_path):
    from tests.test_cli import assert_user_error, run_cli

    proc = run_cli("animate", "--method", "gsnet", "--garment", "t_shirt", "--motion", "walk",
                   "--out", str(tmp_path / "a.usdc"))
    assert_user_error(proc, "no shipped GSNet model", "wrinkles train gsnet", "--model")
    assert not (tmp_path / "a.usdc").exists()


@pytest.mark.slow
def test_a_training_item_holds_the_frames_of_its_window(sample_dataset):
    """Item = frames t-2 .. t+R-1 of one sequence: the simulated garment of all of them, the
    history (the first two, plus noise), and the posed body of the rolled-out ones, which is the
    body the evaluation poses (Warp skinning) to 1e-6 m."""
    from sim.datasets.storage import SequenceFile

    method = GSNetMethod(TINY)
    ds = method.train_dataset(sample_dataset)
    index = len(ds) - 1
    it = ds[(index, 3)]
    sid, t = ds.windows.locate(index)
    sf = SequenceFile(sample_dataset / ds.windows.entries[sid]["file"])
    r = TINY.rollout
    gt = np.asarray(sf["fine/vertices"])[t:t + r + 2]
    np.testing.assert_array_equal(it["target"], gt)
    noise = it["history"] - gt[:2]
    assert 0.5 * TINY.history_noise < noise.std() < 2 * TINY.history_noise
    body = method.body("default")
    betas = np.asarray(sf["body/betas"])[: body.num_betas]
    posed = body.pose(betas, np.asarray(sf["body/poses"])[t + 2:t + r + 2],
                      np.asarray(sf["body/trans"])[t + 2:t + r + 2], device="cpu").vertices
    np.testing.assert_allclose(it["body"], posed, atol=1e-6)
    assert it["transforms"].shape == (r + 2, 24, 3, 4) and it["roots"].shape == (r + 2, 3)
    np.testing.assert_allclose(it["roots"], np.asarray(sf["body/joints"])[t:t + r + 2, 0], atol=1e-6)


@pytest.mark.slow
def test_the_projection_takes_an_evaluated_garment_out_of_the_body(sample_dataset):
    """The margin's projection runs in the evaluated prediction: fewer vertices inside the body,
    the rest of the garment where it was."""
    from dataclasses import replace

    from learn.evaluate import evaluate

    rows = {}
    for margin in (0.0, 2e-3):
        method = GSNetMethod(replace(TINY, regression=False, projection_margin=margin))
        torch.manual_seed(0)
        model = method.build_model().eval()
        ev = evaluate(method, model, sample_dataset, "all", image_resolution=0, max_sequences=2)
        rows[margin] = ev.summary
    assert rows[0.0]["collision"] > 0.005  # the untrained network's skinning crosses the body
    assert rows[2e-3]["collision"] < 0.2 * rows[0.0]["collision"]
    assert abs(rows[2e-3]["ev"] - rows[0.0]["ev"]) < 0.002


@pytest.mark.parametrize("field, value", [("joint_topk", 25), ("cold_start", 1.5), ("width", 30),
                                          ("projection_margin", -1e-3), ("projection_margin", float("nan"))])
def test_a_bad_model_setting_is_refused_naming_it(field, value):
    from dataclasses import replace

    def err(message):
        return ValueError(message)

    with pytest.raises(ValueError, match=f"model.{field}"):
        GSNetMethod.validate_config(replace(TINY, **{field: value}), err)
