"""Guo et al. 2024 pipeline on the sample dataset (CPU, small networks): the virtual-skeleton CVAE,
the wrinkle diffusion method and its baselines, the evaluation rows, release export and
``wrinkles animate``."""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from pipelines.cli import main

SMALL_UNET = [
    "--set",
    "model.base_channels=32",
    "--set",
    "model.channel_mult=[1, 2, 2]",
    "--set",
    "model.attention_levels=[2]",
]
COARSE = [
    "--set",
    'model.garments=["t_shirt"]',
    "--set",
    "model.num_bones=12",
    "--set",
    "model.ssdr_iterations=4",
    "--set",
    "model.hidden=64",
    "--set",
    "model.ssdr_frames=40",
]


def cli(*args) -> int:
    return main([str(a) for a in args])


def train_two_steps(method: str, data, out, *extra) -> int:
    common = ["--steps", 2, "--batch-size", 2, "-q", "--device", "cpu"]
    return cli("train", method, "--data", data, "--out", out, *common, *extra)


@pytest.fixture(scope="module")
def runs(sample_dataset, tmp_path_factory):
    """A coarse (t-shirt) and a wrinkle model trained briefly on the sample."""
    root = tmp_path_factory.mktemp("wrinkle-runs")
    assert (
        cli(
            "train",
            "coarse",
            "--data",
            sample_dataset,
            "--out",
            root / "coarse",
            "--steps",
            150,
            "--batch-size",
            8,
            "-q",
            "--device",
            "cpu",
            "--set",
            "optim.lr=3e-3",
            "--set",
            "train.ema_decay=0",
            *COARSE,
        )
        == 0
    )
    assert (
        cli(
            "train",
            "wrinkles",
            "--data",
            sample_dataset,
            "--out",
            root / "wrinkles",
            "--steps",
            6,
            "--batch-size",
            4,
            "-q",
            "--device",
            "cpu",
            "--set",
            'model.garments=["t_shirt"]',
            *SMALL_UNET,
        )
        == 0
    )
    return {
        "coarse": root / "coarse" / "checkpoints" / "last.pt",
        "wrinkles": root / "wrinkles" / "checkpoints" / "last.pt",
        "root": root,
    }


# ----------------------------------------------------------------------------------- CVAE
def test_pose_condition_and_gamma():
    from learn.methods.skeleton_cvae import gamma_of, pose_condition

    c = pose_condition(np.zeros((3, 24, 3)), np.array([0.5, -1.0]), 10)
    assert c.shape == (3, 144 + 10)
    np.testing.assert_allclose(c[:, :6], [[1, 0, 0, 0, 1, 0]] * 3, atol=1e-7)  # identity, 6D columns
    np.testing.assert_allclose(c[0, 144:], [0.5, -1.0] + [0] * 8)
    rot = np.tile(np.eye(3, dtype=np.float32), (2, 5, 1, 1))
    g = gamma_of(rot, np.ones((2, 5, 3), np.float32))
    assert g.shape == (2, 45)
    np.testing.assert_allclose(g[0, :9], [1, 0, 0, 0, 1, 0, 1, 1, 1])


def test_cvae_skinning_is_exact_lbs():
    """skin(gamma) is Eq. 8: sum_k w_k (R_k r + t_k), checked against numpy for random rigid bones."""
    from scipy.spatial.transform import Rotation

    from learn.methods.skeleton_cvae import SkeletonCVAE, SkeletonCVAEConfig, gamma_of

    rng = np.random.default_rng(0)
    V, J, K = 50, 6, 3
    idx = np.stack([rng.choice(J, K, replace=False) for _ in range(V)])
    w = rng.random((V, K))
    w /= w.sum(1, keepdims=True)
    rest = rng.normal(size=(V, 3)).astype(np.float32)
    state = {
        "rest": torch.from_numpy(rest),
        "weight_idx": torch.from_numpy(idx),
        "weight_val": torch.from_numpy(w.astype(np.float32)),
        "gamma_mean": torch.zeros(J * 9),
        "gamma_std": torch.ones(J * 9),
    }
    cfg = SkeletonCVAEConfig(latent=4, hidden=16, layers=1, num_betas=2)
    net = SkeletonCVAE(cfg, state)
    R = Rotation.random(2 * J, random_state=1).as_matrix().reshape(2, J, 3, 3).astype(np.float32)
    t = rng.normal(size=(2, J, 3)).astype(np.float32)
    out = net.skin(torch.from_numpy(gamma_of(R, t))).detach().numpy()
    ref = np.einsum("vk,bvkc->bvc", w, np.einsum("bvkij,vj->bvki", R[:, idx], rest) + t[:, idx])
    np.testing.assert_allclose(out, ref, atol=1e-5)
    sub = torch.tensor([3, 7, 11])
    np.testing.assert_allclose(
        net.skin(torch.from_numpy(gamma_of(R, t)), sub).detach().numpy(), ref[:, [3, 7, 11]], atol=1e-5
    )
    # shapes of the CVAE parts
    cond = torch.zeros(5, 6 * 24 + 2)
    mu, logvar = net.encode(torch.zeros(5, J * 9), cond)
    assert mu.shape == logvar.shape == (5, 4)
    assert net.decode(torch.zeros(5, 4), cond).shape == (5, J * 9)


@pytest.mark.slow
def test_coarse_model_learns_the_base(runs, sample_dataset):
    from learn.train.checkpoint import load_checkpoint
    from learn.train.trainer import load_trained

    recs = [json.loads(line) for line in open(runs["coarse"].parent.parent / "metrics.jsonl")]
    assert recs[-1]["vertex_cm2"] < 0.5 * recs[0]["vertex_cm2"], (recs[0], recs[-1])
    ck = load_checkpoint(runs["coarse"])
    st = ck["method_state"]
    assert st["garment"] == "t_shirt" and st["weight_idx"].shape[1] == 4
    assert 0 < st["ssdr_rmse"] < 0.02  # the 12-bone skeleton fits the sample's bases to < 2 cm
    method, model, _ = load_trained(runs["coarse"])
    from learn.data import GarmentSequenceDataset

    ds = GarmentSequenceDataset(sample_dataset, "train", garments="t_shirt")
    f = ds.open_sequence(ds.sequence_ids[0])
    seq = {k: np.asarray(f[k]) for k in f.keys()}
    pred = method.predict_sequence(model, seq, device=torch.device("cpu"))
    assert pred.vertices.shape == seq["fine/base"].shape
    err = np.linalg.norm(pred.vertices - seq["fine/base"], axis=-1).mean()
    assert err < 0.03, err  # training frames, z = 0, after 150 steps (raw weights): under 3 cm
    skirt = GarmentSequenceDataset(sample_dataset, "train", garments="straight_skirt")
    g = skirt.open_sequence(skirt.sequence_ids[0])
    from sim.errors import WrinklesInputError

    with pytest.raises(WrinklesInputError, match="rigs a t_shirt"):
        method.predict_sequence(model, {k: np.asarray(g[k]) for k in g.keys()}, device=torch.device("cpu"))


@pytest.mark.slow
def test_coarse_refuses_mixed_topologies(sample_dataset, tmp_path, capsys):
    code = cli(
        "train",
        "coarse",
        "--data",
        sample_dataset,
        "--out",
        tmp_path / "r",
        "--steps",
        1,
        "-q",
        "--set",
        "model.num_bones=4",
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "different garment meshes" in err[0]
    assert not (tmp_path / "r" / "checkpoints").exists()


# ------------------------------------------------------------------------------ diffusion
def test_temporal_guidance_pulls_x0_toward_neighbours():
    from learn.diffusion.sampling import _temporal_guidance
    from learn.diffusion.scheduler import DDIMScheduler, DDPMScheduler

    s = DDIMScheduler.from_ddpm(DDPMScheduler())
    t = 600
    a = float(s.alphas_cumprod[t])
    x0 = torch.stack([torch.full((3, 4, 4), v) for v in (0.0, 1.0, 5.0)])
    eps = torch.randn(3, 3, 4, 4, generator=torch.Generator().manual_seed(0))
    x = a**0.5 * x0 + (1 - a) ** 0.5 * eps
    same = _temporal_guidance(s, x, eps, t, 0.0, None)
    torch.testing.assert_close(same, eps)
    g = _temporal_guidance(s, x, eps, t, 0.5, None)
    x0_new = (x - (1 - a) ** 0.5 * g) / a**0.5
    lam = 0.5 * t / 1000
    want = torch.tensor([0 + lam * (1 - 0), 1 + lam * (2.5 - 1), 5 + lam * (1 - 5)])
    torch.testing.assert_close(x0_new.mean((1, 2, 3)), want, atol=1e-4, rtol=1e-4)
    anchored = _temporal_guidance(s, x, eps, t, 0.5, torch.full((3, 4, 4), -2.0))
    x0_a = (x - (1 - a) ** 0.5 * anchored) / a**0.5
    assert abs(float(x0_a[0].mean()) - lam * ((-2.0 + 1.0) / 2)) < 1e-4


@pytest.mark.slow
def test_diffusion_state_items_and_prediction(runs, sample_dataset):
    from learn.train.checkpoint import load_checkpoint
    from learn.train.trainer import load_trained
    from sim.datasets.storage import read_manifest

    st = load_checkpoint(runs["wrinkles"])["method_state"]
    manifest = read_manifest(sample_dataset)["sequences"].values()
    trained = sorted({e["material"] for e in manifest if e["garment"] == "t_shirt" and e["split"] == "train"})
    assert st["materials"] == trained and st["resolution"] == 64
    assert st["wrinkle_std"].shape == (3,) and bool((st["wrinkle_std"] > 1e-5).all())
    assert bool((st["wrinkle_std"] < 0.05).all())  # metres: wrinkles are millimetres
    method, model, _ = load_trained(runs["wrinkles"])
    ds = method.train_dataset(sample_dataset)
    item = ds[(0, 0)]
    assert item["x0"].shape == (3, 64, 64) and item["cond"].shape == (2, 64, 64)
    mask = item["cond"][-1]
    assert set(mask.unique().tolist()) <= {0.0, 1.0}
    assert float(item["x0"][:, mask == 0].abs().max()) == 0.0  # nothing outside the charts
    f = ds.ds.open_sequence(ds.ds.sequence_ids[0])
    seq = {k: np.asarray(f[k]) for k in f.keys()}
    seq = {k: v[:5] if v.ndim and v.shape[0] == 18 else v for k, v in seq.items()}
    pred = method.predict_sequence(model, seq, device=torch.device("cpu"), steps=3)
    assert pred.vertices.shape == seq["fine/base"].shape and np.isfinite(pred.vertices).all()
    assert pred.extras["wrinkle_maps"].shape == (5, 64, 64, 3)
    again = method.predict_sequence(model, seq, device=torch.device("cpu"), steps=3)
    np.testing.assert_array_equal(pred.vertices, again.vertices)  # seeded


@pytest.mark.slow
@pytest.mark.parametrize("conditioning,channels", [("strain_tensor", 4), ("normal", 4)])
def test_conditioning_variants_train(sample_dataset, tmp_path, conditioning, channels):
    from learn.train.trainer import load_trained

    out = tmp_path / conditioning
    extra = ["--set", f"model.conditioning={conditioning}", "--set", 'model.garments=["straight_skirt"]']
    assert train_two_steps("wrinkles", sample_dataset, out, *extra, *SMALL_UNET) == 0
    method, model, _ = load_trained(out / "checkpoints" / "last.pt")
    assert model.config.cond_channels == channels
    assert method.train_dataset(sample_dataset)[(0, 0)]["cond"].shape[0] == channels


@pytest.mark.slow
def test_lfgd_baseline_trains_and_predicts(sample_dataset, tmp_path):
    from learn.train.trainer import load_trained

    out = tmp_path / "lfgd"
    assert train_two_steps("displacement_regressor", sample_dataset, out, *SMALL_UNET) == 0
    method, model, _ = load_trained(out / "checkpoints" / "last.pt")
    item = method.train_dataset(sample_dataset)[(0, 0)]
    assert item["cond"].shape == (7, 64, 64) and item["target"].shape == (3, 64, 64)


def check_training_items(method, sample_dataset) -> None:
    """Training items: the sequences prepared in the trainer's process, one maps operator per
    garment layout giving the items a fresh operator gives, the item's own regression window
    first and the others windows of training frames, drawn from the item's seed."""
    from learn.deepwrinkles.normal_maps import DetailMaps
    from learn.deepwrinkles.sequences import GARMENT_KEYS
    from learn.deepwrinkles.training import TrainFrames, layout_digest

    frames = method.train_dataset(sample_dataset)  # warmed: prepared here, shared with forked workers
    assert set(frames._cache) == set(frames.ds.sequence_ids)
    preps = [c[0] for c in frames._cache.values()]
    digests = [layout_digest({k: p.seq[k] for k in GARMENT_KEYS}) for p in preps]
    assert len(frames._maps) == len(set(digests))
    for a, b in zip(range(len(preps)), range(1, len(preps)), strict=False):  # one operator per layout
        assert (preps[a].maps is preps[b].maps) == (digests[a] == digests[b])
    cold = TrainFrames(method, sample_dataset)  # an operator of its own for every sequence
    cold._layout_maps = lambda prep: DetailMaps(prep.seq, 32, device="cpu")
    for key in ((3, 0), (len(frames) - 1, 0)):
        warm_item, cold_item = frames[key], cold[key]
        for k in ("lr", "hr", "hr_prev", "mask"):
            torch.testing.assert_close(warm_item[k], cold_item[k])
        for k in ("controls", "coefficients"):  # the item's own window (the others: random frames)
            torch.testing.assert_close(warm_item[k][0], cold_item[k][0])
    item = frames[(3, 0)]
    R = method.config.regression_windows
    assert item["lr"].shape == (3, 32, 32) and item["controls"].shape[:2] == (R, 3)
    sid, t = frames.ds.locate(3)  # the item's own window first, then windows of other frames
    own = frames._cache[sid]
    np.testing.assert_array_equal(item["controls"][0].numpy(), own[1][t])
    np.testing.assert_allclose(item["coefficients"][0].numpy(), own[2][t], rtol=1e-6)
    every = np.concatenate([c[1] for c in frames._cache.values()])
    assert all((every == w.numpy()).all(axis=(1, 2)).any() for w in item["controls"][1:])
    again, other = frames[(3, 0)], frames[(3, 1)]
    torch.testing.assert_close(again["controls"], item["controls"])
    assert (other["controls"][1:] - item["controls"][1:]).abs().max() > 0  # another seed, other frames


@pytest.mark.slow
def test_deepwrinkles_trains_predicts_and_is_evaluated(sample_dataset, tmp_path):
    """DeepWrinkles end to end on the sample's t-shirts (the simulation as a perfect registration,
    tiny networks, the upper body's joints as controls): the fitted subspace reproduces the
    training shapes, the prediction is on the fine topology with unit normal maps inside the UV
    charts, and ``evaluate`` gives its row."""
    from learn.train.trainer import load_trained

    out = tmp_path / "dw"
    settings = ("garments=['t_shirt']", "source='simulation'", "resolution=32", "filters=4", "hidden=16",
                "layers=1", "components=16", "control_joints='upper'")
    small = [a for kv in settings for a in ("--set", f"model.{kv}")]
    assert train_two_steps("deepwrinkles", sample_dataset, out, *small) == 0
    method, model, _ = load_trained(out / "checkpoints" / "last.pt")
    assert method.state["control_mean"].numel() == 6 * 11 + 6  # 11 upper-body joints and the root motion
    sub = method.subspace()
    assert sub.size <= 16 and 0.0 < sub.variance_kept(1) <= sub.variance_kept() <= 1.0 + 1e-9
    check_training_items(method, sample_dataset)
    from learn.data import GarmentSequenceDataset

    test = GarmentSequenceDataset(sample_dataset, "all", garments="t_shirt")
    sf = test.open_sequence(test.sequence_ids[0])
    seq = {k: np.asarray(sf[k]) for k in sf.keys()}
    pred = method.predict_sequence(model, seq, device=torch.device("cpu"))
    assert pred.vertices.shape == seq["fine/vertices"].shape and np.isfinite(pred.vertices).all()
    from learn.evaluate import SURFACE_SHADINGS, _example

    ex = _example("s", seq, pred, {})  # what closeups.png draws
    assert ex["surface"].shape == seq["fine/vertices"].shape[1:]
    assert list(ex["surface_normals"]) == [name for name, _ in SURFACE_SHADINGS]
    detail = ex["surface_normals"]["global shape + predicted HR map"]
    np.testing.assert_allclose(np.linalg.norm(detail, axis=-1), 1.0, atol=1e-4)
    assert {"lr_maps", "normal_maps"} <= set(ex["method_maps"])
    hr = pred.extras["normal_maps"]
    norms = np.linalg.norm(hr, axis=-1)
    assert hr.shape[1:] == (32, 32, 3) and (norms > 0).mean() > 0.3
    np.testing.assert_allclose(norms[norms > 0], 1.0, atol=1e-4)
    ckpt = out / "checkpoints" / "last.pt"
    from learn.train.checkpoint import load_checkpoint
    from learn.train.export import export_model

    release = export_model(ckpt, tmp_path / "dw.pt")  # the subspace's basis in float16 in the file
    assert load_checkpoint(release)["method_state"]["components"].dtype == torch.float16
    shipped, _, _ = load_trained(release)
    assert shipped.state["components"].dtype == torch.float32
    coeffs = np.random.default_rng(0).normal(size=(3, sub.size)) * sub.singular_values / np.sqrt(sub.frames)
    full = sub.decode(coeffs)
    err = np.abs(shipped.subspace().decode(coeffs) - full).max()
    assert err <= 2e-3 * np.abs(full - sub.mean).max()
    assert cli("evaluate", "--model", ckpt, "--data", sample_dataset, "--split", "all",
               "--out", tmp_path / "eval", "--no-images", "-q") == 0
    row = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert row["summary"]["ev"] > 0 and {s["garment"] for s in row["sequences"]} == {"t_shirt"}
    # the paper's Table 1 inputs: the registrations projected on 4 components ("BS 4")
    assert cli("evaluate", "--model", ckpt, "--data", sample_dataset, "--split", "all", "--max-sequences", 1,
               "--predict", "lr_input=subspace", "--predict", "components=4", "--out", tmp_path / "bs4",
               "--no-images", "-q") == 0
    retargeting_figure(ckpt, tmp_path)
    bs4 = json.loads((tmp_path / "bs4" / "metrics.json").read_text())
    assert bs4["predict_options"] == {"lr_input": "subspace", "components": 4}
    assert 0 < bs4["summary"]["nm_l2"] < bs4["summary"]["nm_l1"] < 2.0 and bs4["summary"]["nm_temporal"] >= 0


def retargeting_figure(ckpt, tmp_path) -> None:
    """tools/render_retargeting.py on a trained checkpoint: one column per body shape; a frame
    outside the motion refused (exit 2, no file)."""
    if importlib.util.find_spec("pyvista") is None:
        return
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    from render_retargeting import main as render_retargeting

    out = tmp_path / "retargeting.png"
    base = ["--model", str(ckpt), "--motion", "walk", "--duration", "0.2", "--out", str(out)]
    assert render_retargeting([*base, "--shape", "0,0", "--shape=2.5,-2.5", "--frame", "3"]) == 0
    from PIL import Image

    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape[1] > img.shape[0]  # two columns
    out.unlink()
    assert render_retargeting([*base, "--shape", "0,0", "--frame", "99"]) == 2 and not out.exists()


@pytest.mark.slow
def test_a_split_is_registered_ahead_by_worker_processes(sample_dataset, tmp_path, capsys):
    """``python -m learn.deepwrinkles.training``: the first sequence of a split registered (scan +
    registration) in a worker process into the cache that training and evaluation read."""
    from learn.data import GarmentSequenceDataset
    from learn.deepwrinkles.global_shape import cache_path
    from learn.deepwrinkles.training import main
    from learn.methods.deepwrinkles import DeepWrinklesConfig, DeepWrinklesMethod

    every = GarmentSequenceDataset(sample_dataset, "all", garments="t_shirt")
    others = [s for s in every.sequence_ids if every.entries[s]["split"] != "train"]
    split = every.entries[others[0]]["split"] if others else "train"
    ds = GarmentSequenceDataset(sample_dataset, split, garments="t_shirt")
    settings = DeepWrinklesMethod(DeepWrinklesConfig(register_every=40, garments=("t_shirt",))).settings()
    paths = {s: cache_path(every.open_sequence(s), settings) for s in every.sequence_ids}
    for p in paths.values():
        p.unlink(missing_ok=True)
    args = [str(sample_dataset), "--split", split, "--max-sequences", "1", "--every", "40"]
    args += ["--garment", "t_shirt"]
    assert main([*args, "--workers", "2"]) == 0
    first = paths[ds.sequence_ids[0]]
    assert [s for s, p in paths.items() if p.exists()] == [ds.sequence_ids[0]]
    with np.load(first) as z:
        frames = int(ds.entries[ds.sequence_ids[0]]["frames"])
        assert z["frames"].tolist() == sorted({*range(0, frames, 40), frames - 1})
        err = np.linalg.norm(z["vertices"] - z["truth"], axis=-1)
        assert np.isfinite(err).all() and np.median(err) < 0.05  # registered, not the skinned start
    assert main([str(tmp_path / "missing")]) == 2
    assert "error:" in capsys.readouterr().err
    with pytest.raises(SystemExit) as bad:
        main([*args[:3], "--max-sequences", "0"])
    assert bad.value.code == 2


# ------------------------------------------------------------------- evaluation, export, animate
@pytest.mark.slow
def test_evaluate_rows_with_the_coarse_base(runs, sample_dataset, tmp_path):
    for name, model in (("base", "base"), ("ours", runs["wrinkles"])):
        assert (
            cli(
                "evaluate",
                "--model",
                model,
                "--coarse",
                runs["coarse"],
                "--data",
                sample_dataset,
                "--split",
                "all",
                "--out",
                tmp_path / name,
                "--no-images",
                "-q",
                "--steps",
                2,
            )
            == 0
        )
    base = json.loads((tmp_path / "base" / "metrics.json").read_text())
    ours = json.loads((tmp_path / "ours" / "metrics.json").read_text())
    assert base["coarse"] and {s["garment"] for s in base["sequences"]} == {"t_shirt"}
    assert base["summary"]["ev"] > 0 and ours["summary"]["ev"] > 0
    assert ours["predict_options"]["steps"] == 2


@pytest.mark.slow
def test_export_round_trip(runs, tmp_path):
    from learn.train.export import export_model
    from learn.train.trainer import load_trained

    dst = export_model(runs["wrinkles"], tmp_path / "w.pt")
    assert dst.stat().st_size < 0.6 * runs["wrinkles"].stat().st_size  # fp16, no optimizer state
    _, a, _ = load_trained(runs["wrinkles"])
    _, b, _ = load_trained(dst)
    for (k, va), vb in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        torch.testing.assert_close(vb, va, atol=2e-3, rtol=2e-3, msg=k)
    dst = export_model(runs["coarse"], tmp_path / "c.pt")
    _, c, _ = load_trained(dst)
    torch.testing.assert_close(c.rest, load_trained(runs["coarse"])[1].rest)  # buffers stay float32


@pytest.mark.slow
def test_animate_writes_usd_and_preview(runs, sample_dataset, tmp_path, capsys):
    pytest.importorskip("pxr")
    out = tmp_path / "anim" / "t.usda"
    assert (
        cli(
            "animate",
            "--coarse",
            runs["coarse"],
            "--wrinkles",
            runs["wrinkles"],
            "--motion",
            "walk",
            "--duration",
            0.4,
            "--steps",
            2,
            "--out",
            out,
            "--sheet",
            tmp_path / "anim" / "t.png",
            "-q",
            "--shape",
            "1.0,-0.5",
        )
        == 0
    )
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(out))
    meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    names = {p.GetName() for p in meshes}
    assert "t_shirt" in names and "Body" in names
    # the hems the dataset stored (up to 3 layers) reach the animated stage as fabricLayers, face by face
    from learn.data import GarmentSequenceDataset

    ds = GarmentSequenceDataset(sample_dataset, "train",
                                keys=["fine/faces"], garments=["t_shirt"])
    layers = np.asarray(ds.open_sequence(ds.sequence_ids[0])["fine/face_layers"])
    assert layers.min() == 1.0 and 1.0 < layers.max() <= 3.0
    shirt = next(p for p in meshes if p.GetName() == "t_shirt")
    written = np.asarray(UsdGeom.PrimvarsAPI(shirt).GetPrimvar("fabricLayers").Get())
    np.testing.assert_array_equal(written, layers)
    meta = json.loads((tmp_path / "anim" / "t.animate.json").read_text())
    assert meta["ddim_steps"] == 2 and meta["betas"][:2] == [1.0, -0.5]
    assert (tmp_path / "anim" / "t.png").stat().st_size > 1000


@pytest.mark.slow
def test_animate_bad_inputs(runs, tmp_path, capsys):
    cases = [
        (["--coarse", tmp_path / "missing.pt", "--wrinkles", runs["wrinkles"]], "no such model file"),
        (["--coarse", runs["coarse"], "--wrinkles", runs["wrinkles"], "--steps", 0], "--steps"),
        (["--coarse", runs["wrinkles"], "--wrinkles", runs["wrinkles"]], "skeleton_cvae"),
        (["--garment", "trousers"], "no shipped models for trousers"),
    ]
    for extra, words in cases:
        out = tmp_path / "x" / "a.usda"
        code = cli("animate", *extra, "--motion", "walk", "--duration", 0.2, "--out", out, "-q")
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and words in err[0], (extra, err)
        assert not out.parent.exists() or not any(out.parent.iterdir())


@pytest.mark.slow
def test_pipeline_without_wrinkles_is_the_base(runs):
    from learn.animate import WrinklePipeline
    from sim.motions import procedural_motion

    m = procedural_motion("walk", duration=0.3, fps=30.0)
    base = WrinklePipeline(runs["coarse"], None)(m.poses, m.trans, np.zeros(2))
    full = WrinklePipeline(runs["coarse"], runs["wrinkles"])(m.poses, m.trans, np.zeros(2), steps=2)
    np.testing.assert_allclose(full.base, base.vertices, atol=1e-6)
    assert full.wrinkle_maps.shape[0] == len(m.poses) and base.wrinkle_maps is None
    assert Path(str(runs["coarse"])).exists()


@pytest.mark.slow
def test_pipeline_moves_the_garment_out_of_the_body(runs):
    from learn.animate import WrinklePipeline
    from sim.bodies.default import load_default_body
    from sim.motions import procedural_motion
    from sim.quality import inside_fraction

    # the walk's first lead-in frames, near the T-pose: with the arms down the skinned body passes
    # through itself at the armpits, where no point is outside both arm and torso
    # (`wrinkles body --self-crossings` shows where)
    m = procedural_motion("walk", duration=0.2, fps=30.0).extra["lead_in"]
    m = replace(m, poses=m.poses[:6], trans=m.trans[:6])
    body = load_default_body()
    frames = body.pose(np.zeros(2), m.poses, m.trans)
    pipe = WrinklePipeline(runs["coarse"], runs["wrinkles"])
    res = pipe(m.poses, m.trans, np.zeros(2), steps=2, body_vertices=frames.vertices, body_faces=frames.faces,
               clearance=0.004)
    for x in (res.base, res.vertices):
        assert inside_fraction(x, frames.vertices, frames.faces, device="cpu").max() == 0.0
    assert res.seconds["collision"] > 0
    raw = pipe(m.poses, m.trans, np.zeros(2), steps=2)
    assert "collision" not in raw.seconds
