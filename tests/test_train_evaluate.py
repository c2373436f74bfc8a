"""End to end on the sample dataset: ``wrinkles train`` a small model, resume it, ``wrinkles
evaluate`` it; DDP with 2 CPU processes (gloo) against one process; the baseline's maths."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from learn.train.checkpoint import load_checkpoint
from pipelines.cli import main

SMALL = ["--set", "model.hidden=32", "--set", "model.layers=2", "--set", "model.vertices_per_item=128",
         "--set", "train.log_every=2", "--set", "train.checkpoint_every=4", "--device", "cpu", "-q"]


def run_cli(*args) -> int:
    return main([str(a) for a in args])


@pytest.mark.slow
def test_train_resume_evaluate_end_to_end(sample_dataset, tmp_path, capsys):
    straight, split = tmp_path / "straight", tmp_path / "split"
    assert run_cli("train", "skinned_mlp", "--data", sample_dataset, "--out", straight, "--steps", 8,
                   "--batch-size", 4, *SMALL) == 0
    assert run_cli("train", "skinned_mlp", "--data", sample_dataset, "--out", split, "--steps", 5,
                   "--batch-size", 4, *SMALL) == 0
    assert run_cli("train", "skinned_mlp", "--data", sample_dataset, "--out", split, "--steps", 8,
                   "--batch-size", 4, "--resume", *SMALL) == 0
    a = load_checkpoint(straight / "checkpoints" / "last.pt")
    b = load_checkpoint(split / "checkpoints" / "last.pt")
    assert a["step"] == b["step"] == 8
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    cfg = json.loads((straight / "config.json").read_text())
    assert cfg["method"] == "skinned_mlp" and cfg["model"]["hidden"] == 32 and cfg["train"]["steps"] == 8

    capsys.readouterr()
    out = tmp_path / "eval"
    assert run_cli("evaluate", "--model", straight / "checkpoints" / "last.pt", "--data", sample_dataset,
                   "--split", "test_id", "--out", out, "--device", "cpu", "-q") == 0
    table = capsys.readouterr().out
    assert "ev " in table and "normal_fd" in table and "not Inception FID" in table
    rec = json.loads((out / "metrics.json").read_text())
    s = rec["summary"]
    assert rec["split"] == "test_id" and rec["step"] == 8 and rec["ema"] is True
    manifest = json.loads((Path(sample_dataset) / "manifest.json").read_text())
    want = sorted(k for k, e in manifest["sequences"].items() if e["split"] == "test_id")
    assert sorted(r["id"] for r in rec["sequences"]) == want and len(want) >= 2
    # a skinned garment is within centimetres of the simulation, not exact
    assert 1e-3 < s["ev"] < 0.2 and 0 < s["ecd"] < s["ev"] ** 2 * 4  # 1-4 cm at 8 steps
    assert 0 <= s["collision"] <= 1 and 0 <= s["collision_gt"] < 0.05
    assert s["normal_fd"] >= 0 and np.isfinite(s["spectrum_distance"])
    for name in ("uv_examples.png", "renders.png"):
        assert (out / name).stat().st_size > 5000


@pytest.mark.slow
def test_evaluate_bad_inputs_exit_2_without_output(sample_dataset, tmp_path, capsys):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"nope")
    out = tmp_path / "never"
    assert run_cli("evaluate", "--model", junk, "--data", sample_dataset, "--out", out, "-q") == 2
    err = capsys.readouterr().err
    assert "junk.pt: not a readable checkpoint" in err and len(err.strip().splitlines()) == 1
    assert run_cli("evaluate", "--model", junk, "--data", tmp_path / "nodata", "--out", out, "-q") == 2
    assert not out.exists()
    assert run_cli("train", "skinned_mlp", "--data", sample_dataset, "--out", out,
                   "--set", "model.hiden=3") == 2
    assert "unknown key(s) hiden in [model]" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_skinned_mlp_starts_as_pure_skinning_and_learns(sample_dataset):
    from learn.methods.skinned_mlp import SkinnedMLPConfig, SkinnedMLPMethod, skin_batch

    method = SkinnedMLPMethod(SkinnedMLPConfig(hidden=32, layers=2, vertices_per_item=64))
    ds = method.train_dataset(sample_dataset)
    batch = method.collate([ds[(i, 100 + i)] for i in range(3)])
    model = method.build_model()
    disp = model(batch["rest"], batch["pose"], batch["betas"])
    assert torch.count_nonzero(disp) == 0  # zero-initialised head: step 0 is plain LBS
    # skin_batch (one launch, per-sample bone blocks) equals the per-sample einsum
    w, A = batch["weights"], batch["transforms"]
    ref = (torch.einsum("bvj,bjrc,bvc->bvr", w, A[..., :3], batch["rest"])
           + torch.einsum("bvj,bjr->bvr", w, A[..., 3]))
    np.testing.assert_allclose(skin_batch(batch["rest"], batch["weights"], batch["transforms"]).numpy(),
                               ref.numpy(), rtol=1e-5, atol=1e-6)
    # the same (index, seed) gives the same item; another seed another vertex subset
    again = ds[(0, 100)]
    assert torch.equal(again["rest"], batch["rest"][0])
    assert not torch.equal(ds[(0, 101)]["rest"], again["rest"])
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(40):
        opt.zero_grad()
        out = method.training_loss(model, batch, torch.Generator())
        out.loss.backward()
        opt.step()
        losses.append(out.loss.item())
    assert losses[-1] < 0.5 * losses[0]


@pytest.mark.slow
def test_ddp_two_cpu_processes_match_one(sample_dataset, tmp_path):
    """torchrun with 2 gloo processes, global batch 4 (2 each) == one process with batch 4."""
    common = ["skinned_mlp", "--data", str(sample_dataset), "--steps", "3", "--batch-size", "4",
              "--set", "train.ema_decay=0", *SMALL]
    assert run_cli("train", *common, "--out", tmp_path / "one") == 0
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
           "-m", "pipelines.cli", "train", *common, "--out", str(tmp_path / "two")]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    a = load_checkpoint(tmp_path / "one" / "checkpoints" / "last.pt")["model"]
    b = load_checkpoint(tmp_path / "two" / "checkpoints" / "last.pt")["model"]
    for k in a:
        np.testing.assert_allclose(b[k].numpy(), a[k].numpy(), rtol=1e-4, atol=1e-6, err_msg=k)
    # the weights did train (the zero-initialised head moved), so the comparison means something
    assert any(float(a[k].abs().max()) > 0 for k in a if k.startswith("mlp.4"))


@pytest.mark.slow
@pytest.mark.parametrize("bad", ["fp16"])
def test_fp16_on_cpu_is_refused(sample_dataset, tmp_path, bad, capsys):
    assert run_cli("train", "skinned_mlp", "--data", sample_dataset, "--out", tmp_path / "r", "--steps", 1,
                   "--set", f"train.amp={bad}", "--device", "cpu", "-q") == 2
    assert "needs a CUDA device" in capsys.readouterr().err


def test_train_help_lists_every_registered_method():
    from learn.methods import METHODS
    from pipelines import train_cmd

    block = train_cmd.DESCRIPTION.split("Methods:")[1].split("\n\n")[0]
    listed = {line.split()[0] for line in block.splitlines() if line.strip()}
    assert listed == set(METHODS)


class _Stranger:
    """A class a checkpoint may not hold (pickling it stores a reference to code)."""


def _pickled_object_files(tmp_path: Path) -> dict[str, Path]:
    """Files a user may pass as a checkpoint that hold pickled objects or are no checkpoint."""
    import pickle

    files = {name: tmp_path / f"{name}.pt" for name in ("object", "pickle", "bytes", "truncated", "text")}
    torch.save({"format": "wrinkles-checkpoint", "model": {}, "hook": _Stranger()}, files["object"])
    files["pickle"].write_bytes(pickle.dumps({"model": _Stranger()}, protocol=4))
    files["bytes"].write_bytes(np.random.default_rng(0).bytes(1000))
    torch.save({"model": torch.zeros(3)}, files["truncated"])
    data = files["truncated"].read_bytes()
    files["truncated"].write_bytes(data[: len(data) // 2])
    files["text"].write_text("hello\n")
    return files


UNSAFE_ADVICE = ("weights_only", "allow_pickle", "unsafe", "safe_globals", "torch.load", "pickle.load",
                 "trust")


@pytest.mark.parametrize("case, says", [
    ("object", "pickled Python object (tests.test_train_evaluate._Stranger)"),
    ("pickle", "not tensors and plain containers"),
    ("bytes", "not tensors and plain containers"),
    ("truncated", "truncated or corrupted"),
    ("text", "not in PyTorch's format"),
])
def test_checkpoint_refusals_say_what_is_wrong_without_unsafe_advice(tmp_path, capsys, case, says):
    """A file that is no checkpoint, or one with pickled objects in it, is refused in one line
    (exit 2) that says what the file holds and that wrinkles never unpickles objects; torch's
    advice to load it with weights_only=False or to allow its classes is not passed on, nor its
    warnings."""
    path = _pickled_object_files(tmp_path)[case]
    out = tmp_path / "o.usdc"
    assert run_cli("animate", "--coarse", path, "--wrinkles", path, "--out", out, "--device", "cpu",
                   "-q") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"wrinkles animate: error: {path}: not a readable checkpoint: "), err
    assert says in err, err
    if case in ("object", "pickle", "bytes"):
        assert "wrinkles never loads pickled Python objects" in err, err
    for advice in UNSAFE_ADVICE:
        assert advice not in err.lower(), (advice, err)
    assert not out.exists()


@pytest.mark.slow
def test_skinned_mlp_skins_a_reference_fit_garment_from_the_shape_it_was_made_on(sample_dataset):
    """The sample's garments are made on the mean body and worn by shaped ones (``garment/betas``):
    the untrained baseline (linear blend skinning, a zero displacement) carries them from the mean
    body's rest joints and stays within centimetres of the simulation on every sequence; from the
    shaped body's rest joints the same skinning is 9-20 cm away."""
    from learn.evaluate import evaluate
    from learn.methods.skinned_mlp import SkinnedMLPConfig, SkinnedMLPMethod

    method = SkinnedMLPMethod(SkinnedMLPConfig(hidden=16, layers=1))
    torch.manual_seed(0)
    ev = evaluate(method, method.build_model().eval(), sample_dataset, "all", image_resolution=0)
    assert len(ev.sequences) >= 4 and max(s.metrics["ev"] for s in ev.sequences) < 0.06
