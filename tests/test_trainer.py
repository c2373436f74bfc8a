"""The shared trainer: configs, bit-exact resume, EMA, schedules, checkpoints, interruption.

Mechanics are tested on a toy least-squares method (no dataset files; known optimum); the
end-to-end path on the sample dataset lives in test_train_evaluate.py.
"""

from __future__ import annotations

import math
import os
import signal
from dataclasses import dataclass

import numpy as np
import pytest
import torch

from learn.methods.base import LossOutput, Method, Prediction
from learn.train.checkpoint import check_state_dict, load_checkpoint, save_checkpoint
from learn.train.config import (
    OptimConfig,
    RunConfig,
    TrainConfig,
    config_from_dict,
    config_to_dict,
    run_config_from_dict,
)
from learn.train.ema import ExponentialMovingAverage
from learn.train.logging import read_metrics
from learn.train.trainer import Trainer, _IndexStream, _lr_factor, load_trained
from sim.errors import WrinklesInputError

W_TRUE = torch.tensor([[0.5, -1.0, 2.0], [1.5, 0.25, -0.75]])


@dataclass(frozen=True)
class ToyConfig:
    hidden: int = 8
    """Width of the hidden layer."""
    noise: float = 0.01
    """Std of the noise added to each item's input (drawn from the item seed)."""


class _ToyData(torch.utils.data.Dataset):
    def __init__(self, n: int, noise: float):
        g = torch.Generator().manual_seed(123)
        self.x = torch.randn(n, 3, generator=g)
        self.noise = noise

    def __len__(self):
        return len(self.x)

    def __getitem__(self, key):
        i, seed = key
        rng = np.random.default_rng(seed)
        x = self.x[i] + torch.from_numpy(rng.normal(0, self.noise, 3).astype(np.float32))
        return {"x": x, "y": W_TRUE @ x}


class ToyMethod(Method):
    """y = W x through a small MLP, with dropout (so the per-step generator matters)."""

    name = "toy"
    Config = ToyConfig
    calls = 0
    stop_at = -1
    """Send SIGINT to this process at this call of the loss (-1: never)."""

    def build_model(self):
        return torch.nn.Sequential(torch.nn.Linear(3, self.config.hidden), torch.nn.Tanh(),
                                   torch.nn.Linear(self.config.hidden, 2))

    def train_dataset(self, root):
        return _ToyData(37, self.config.noise)

    def training_loss(self, model, batch, generator):
        ToyMethod.calls += 1
        if ToyMethod.calls == ToyMethod.stop_at:
            os.kill(os.getpid(), signal.SIGINT)
        keep = (torch.rand(batch["x"].shape, generator=generator) > 0.1).float()  # input dropout
        pred = model(batch["x"] * keep / 0.9)
        loss = (pred - batch["y"]).square().mean()
        return LossOutput(loss, {"mse": loss.detach()})

    def predict_sequence(self, model, sequence, *, device):
        return Prediction(vertices=np.zeros((1, 1, 3), np.float32))


METHODS = {"toy": ToyMethod}


def toy_config(schedule: str = "cosine", **train) -> RunConfig:
    t = {"steps": 12, "batch_size": 4, "log_every": 2, "checkpoint_every": 5, "device": "cpu", "seed": 3,
         "ema_decay": 0.9, **train}
    return run_config_from_dict({"method": "toy", "train": t,
                                 "optim": {"lr": 0.02, "warmup_steps": 3, "schedule": schedule}},
                                methods=METHODS)


def fit(cfg: RunConfig, run, **kw):
    return Trainer(cfg, run, run, methods=METHODS, **kw).fit()


def state(run):
    return load_checkpoint(run / "checkpoints" / "last.pt")


def assert_same_tensors(a, b):
    if isinstance(a, dict):
        assert set(a) == set(b)
        for k in a:
            assert_same_tensors(a[k], b[k])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            assert_same_tensors(x, y)
    elif torch.is_tensor(a):
        assert torch.equal(a, b)
    else:
        assert a == b


# ------------------------------------------------------------------------------------- configs


def test_config_round_trip_and_errors(tmp_path):
    cfg = run_config_from_dict({"method": "toy", "model": {"hidden": 5}, "train": {"steps": 7},
                                "optim": {"betas": [0.8, 0.9]}}, methods=METHODS)
    assert cfg.model == ToyConfig(hidden=5) and cfg.train.steps == 7 and cfg.optim.betas == (0.8, 0.9)
    again = run_config_from_dict(config_to_dict(cfg), methods=METHODS)
    assert again == cfg
    bad = [({"method": "nope"}, "method 'nope'"),
           ({"method": "toy", "train": {"stepz": 3}}, "unknown key(s) stepz in [train]"),
           ({"method": "toy", "train": {"steps": "ten"}}, "train.steps: expected an integer"),
           ({"method": "toy", "train": {"steps": 0}}, "train.steps must be >= 1"),
           ({"method": "toy", "train": {"amp": "fp8"}}, "train.amp 'fp8'"),
           ({"method": "toy", "optim": {"betas": [0.9]}}, "optim.betas: expected 2 values"),
           ({"method": "toy", "model": {"hidden": 1.5}}, "model.hidden: expected an integer"),
           ({"method": "toy", "extra": 1}, "unknown key(s) extra")]
    for data, msg in bad:
        with pytest.raises(WrinklesInputError, match=msg.replace("(", r"\(").replace(")", r"\)")
                           .replace("[", r"\[").replace("]", r"\]")):
            run_config_from_dict(data, source="my.toml", methods=METHODS)
    assert config_from_dict(TrainConfig, {"ema_decay": 0}).ema_decay == 0.0  # ints become floats


def test_lr_schedule_warmup_and_cosine():
    cfg = RunConfig(method="toy", model=ToyConfig(), train=TrainConfig(steps=11),
                    optim=OptimConfig(warmup_steps=4, schedule="cosine", min_lr_ratio=0.1))
    f = [_lr_factor(s, cfg) for s in range(11)]
    np.testing.assert_allclose(f[:4], [0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(f[4], 1.0)  # cosine starts at the peak
    np.testing.assert_allclose(f[4 + 7 // 2 + 0], 0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * 3 / 7)))
    assert all(a >= b for a, b in zip(f[4:], f[5:], strict=False))


def test_index_stream_covers_each_epoch_once_and_splits_ranks():
    n, B = 10, 4
    full = _IndexStream(n, B, seed=5, rank=0, world=1, start=0, stop=5)
    idx = [i for b in full for i, _ in b]
    assert sorted(idx[:10]) == list(range(10)) and sorted(idx[10:20]) == list(range(10))
    r0 = _IndexStream(n, B, 5, 0, 2, 0, 5)
    r1 = _IndexStream(n, B, 5, 1, 2, 0, 5)
    for s in range(5):
        assert r0.batch(s) + r1.batch(s) == full.batch(s)  # same items and item seeds, split
    late = _IndexStream(n, B, 5, 0, 1, start=3, stop=5)
    assert list(late) == [full.batch(3), full.batch(4)]


def test_ema_matches_closed_form():
    p = torch.nn.Parameter(torch.zeros(1))
    m = torch.nn.Module()
    m.p = p
    ema = ExponentialMovingAverage(m, decay=0.5)
    expect = 0.0
    for k in range(6):
        with torch.no_grad():
            p.fill_(float(k + 1))
        d = min(0.5, (1 + k) / (10 + k))
        expect = d * expect + (1 - d) * (k + 1)
        ema.update(m)
        np.testing.assert_allclose(ema.shadow["p"].item(), expect, rtol=1e-6)


# ---------------------------------------------------------------------------------- training


@pytest.mark.slow
def test_training_reduces_loss_and_logs(tmp_path):
    s = fit(toy_config(steps=60, checkpoint_every=100), tmp_path / "a")
    recs = read_metrics(tmp_path / "a")
    assert [r["step"] for r in recs] == list(range(2, 61, 2))
    assert recs[-1]["loss"] < 0.5 * recs[0]["loss"]
    assert s.step == 60 and not s.interrupted
    assert (tmp_path / "a" / "curves.png").stat().st_size > 1000
    assert any((tmp_path / "a" / "tensorboard").iterdir())
    # the learning rate followed the schedule (warm-up 3 steps, then cosine down)
    lrs = [r["lr"] for r in recs]
    np.testing.assert_allclose(lrs[0], 0.02 * 2 / 3, rtol=1e-6)  # the 2nd step: warm-up at 2/3
    assert lrs[-1] < lrs[1]


@pytest.mark.slow
def test_resume_is_bit_exact_on_cpu(tmp_path):
    # a constant schedule, so that raising train.steps on resume does not change the past steps
    # (a cosine schedule depends on the total; the SIGINT test resumes one with the same total)
    fit(toy_config("constant"), tmp_path / "straight")
    first = fit(toy_config("constant", steps=7), tmp_path / "split")
    assert first.step == 7
    s = fit(toy_config("constant", num_workers=2), tmp_path / "split", resume=True)  # workers may change
    assert (s.start_step, s.step) == (7, 12)
    a, b = state(tmp_path / "straight"), state(tmp_path / "split")
    for key in ("model", "ema", "optimizer", "step"):
        assert_same_tensors(a[key], b[key])
    # the log holds one history: steps up to 7 from the first call, then the resumed ones
    steps = [r["step"] for r in read_metrics(tmp_path / "split")]
    assert steps == sorted(steps) and steps[-1] == 12


def test_resume_refuses_changed_config_and_fresh_run_refuses_existing(tmp_path):
    fit(toy_config(steps=3), tmp_path / "r")
    with pytest.raises(WrinklesInputError, match="already holds a training run"):
        Trainer(toy_config(steps=3), tmp_path, tmp_path / "r", methods=METHODS)
    changed = run_config_from_dict({**config_to_dict(toy_config(steps=6)), "optim": {"lr": 0.5}},
                                   methods=METHODS)
    with pytest.raises(WrinklesInputError, match="cannot resume: the config differs .* optim.lr"):
        fit(changed, tmp_path / "r", resume=True)


@pytest.mark.slow
def test_sigint_finishes_step_writes_checkpoint_and_resumes(tmp_path):
    ToyMethod.calls, ToyMethod.stop_at = 0, 4
    try:
        s = fit(toy_config(), tmp_path / "i")
    finally:
        ToyMethod.stop_at = -1
    assert s.interrupted and s.step == 4
    assert state(tmp_path / "i")["step"] == 4
    s = fit(toy_config(), tmp_path / "i", resume=True)
    assert not s.interrupted and s.step == 12
    fit(toy_config(), tmp_path / "ref")
    assert_same_tensors(state(tmp_path / "i")["model"], state(tmp_path / "ref")["model"])


@pytest.mark.parametrize("device", ["cpu", "cuda"])
def test_load_state_keeps_the_fitted_state_on_the_host_in_float32(device):
    # a run resumed on a GPU reads its checkpoint there; the data loaders read the state with numpy
    if device == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    m = ToyMethod(ToyConfig())
    m.half_state = ("basis",)
    basis = torch.tensor([[0.5, -0.25], [1.0, 2.0]], dtype=torch.float16, device=device)
    m.load_state({"basis": basis, "count": torch.tensor([3], device=device), "scale": 0.5})
    assert m.state["scale"] == 0.5  # plain numbers stay as they are
    assert {v.device.type for v in m.state.values() if torch.is_tensor(v)} == {"cpu"}
    assert m.state["basis"].dtype == torch.float32 and m.state["count"].dtype == torch.int64
    np.testing.assert_array_equal(m.state["basis"].numpy(), [[0.5, -0.25], [1.0, 2.0]])


def test_non_finite_loss_stops_with_the_step(tmp_path):
    cfg = run_config_from_dict({"method": "toy", "train": {"steps": 5, "device": "cpu"},
                                "optim": {"lr": 1e30, "grad_clip": 0.0}}, methods=METHODS)
    with pytest.raises(FloatingPointError, match=r"step \d+: the loss is"):
        fit(cfg, tmp_path / "nan")


# ------------------------------------------------------------------------------- checkpoints


def test_checkpoint_mismatch_is_a_clear_error(tmp_path):
    fit(toy_config(steps=2), tmp_path / "c")
    ckpt = state(tmp_path / "c")
    wider = ToyMethod(ToyConfig(hidden=16)).build_model()
    with pytest.raises(WrinklesInputError, match=r"0.weight is \(8, 3\) in the checkpoint, \(16, 3\) here"):
        check_state_dict(wider, ckpt["model"], path="c.pt")
    other = torch.nn.Linear(3, 2)
    with pytest.raises(WrinklesInputError, match="missing 2 tensor"):
        check_state_dict(other, ckpt["model"], path="c.pt")
    method, model, _ = load_trained(tmp_path / "c" / "checkpoints" / "last.pt", methods=METHODS)
    assert isinstance(method, ToyMethod) and not model.training
    # EMA weights are what load_trained returns by default
    ema0 = ckpt["ema"]["shadow"]["0.weight"]
    assert torch.equal(model.state_dict()["0.weight"], ema0)


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned > /dev/null",))


def test_checkpoints_never_execute_code(tmp_path):
    bad = tmp_path / "evil.pt"
    torch.save({"format": "wrinkles-checkpoint", "version": 1, "config": {}, "step": 0, "model": _Evil()},
               bad)
    with pytest.raises(WrinklesInputError, match="not a readable checkpoint"):
        load_checkpoint(bad)
    (tmp_path / "junk.pt").write_bytes(b"not a zip")
    with pytest.raises(WrinklesInputError, match="junk.pt: not a readable checkpoint"):
        load_checkpoint(tmp_path / "junk.pt")
    save_checkpoint(tmp_path / "plain.pt", {"config": {}, "step": 1, "model": {}})
    torch.save({"model": {}}, tmp_path / "foreign.pt")
    with pytest.raises(WrinklesInputError, match="not a wrinkles checkpoint"):
        load_checkpoint(tmp_path / "foreign.pt")
    assert load_checkpoint(tmp_path / "plain.pt")["step"] == 1
    assert not list(tmp_path.glob(".*.tmp"))  # atomic writes leave no temporaries


def test_keeps_only_the_newest_numbered_checkpoints(tmp_path):
    fit(toy_config(steps=12, checkpoint_every=2, keep_checkpoints=2), tmp_path / "k")
    names = sorted(p.name for p in (tmp_path / "k" / "checkpoints").iterdir())
    assert names == ["last.pt", "step-0000010.pt", "step-0000012.pt"]


def test_progress_is_called_after_every_step_with_the_loss(tmp_path):
    """``progress(step, steps, note=...)`` after each optimizer step (what ``wrinkles train``
    shows as a bar or as progress lines); a resumed run counts on from its checkpoint."""
    calls = []

    def progress(done, total, *, note=None):
        calls.append((done, total, note))

    fit(toy_config(steps=6), tmp_path, progress=progress)
    assert [(d, t) for d, t, _ in calls] == [(k, 6) for k in range(1, 7)]
    assert all(n.startswith("loss ") and float(n.split()[1]) > 0 for _, _, n in calls)
    calls.clear()
    fit(toy_config(steps=8), tmp_path, resume=True, progress=progress)
    assert [d for d, _, _ in calls] == [7, 8]
