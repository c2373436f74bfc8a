"""The shared training loop: every method trains through it, so every method gets the same
seeding, checkpoints, resume, EMA, mixed precision, logs and DDP.

Run directory layout::

    RUN/config.json              resolved run config (+ data root)
    RUN/checkpoints/last.pt      latest checkpoint (atomic); step-NNNNNNN.pt numbered ones
    RUN/metrics.jsonl            logged scalars; RUN/tensorboard/ event files; RUN/curves.png

Determinism: the data order is a pure function of the seed (a stream of per-epoch permutations,
``_IndexStream``), each item's random draws come from a seed derived from its position in that
stream, and the loss's random draws from a generator seeded by (seed, step, rank). So a run
resumed from a checkpoint continues bit-exactly on CPU (tested), whatever the DataLoader workers.
On CUDA, float atomics and cuDNN algorithm choice make runs close, not bit-identical.

Interruption: SIGINT/SIGTERM set a flag; the loop finishes the current step, writes a
checkpoint and returns (``TrainSummary.interrupted``); ``--resume`` continues from it.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from learn.methods.base import Method, batch_to
from learn.train import distributed as D
from learn.train.checkpoint import check_state_dict, load_checkpoint, save_checkpoint
from learn.train.config import RESUMABLE_CHANGES, RunConfig, config_differences, config_to_dict
from learn.train.ema import ExponentialMovingAverage
from learn.train.logging import MetricLogger
from sim.datasets.storage import atomic_write_json
from sim.errors import WrinklesInputError
from sim.versions import package_versions

CHECKPOINT_DIR = "checkpoints"
LAST = "last.pt"


@dataclass
class TrainSummary:
    """What a ``fit`` call did.

    Attributes:
        run_dir: the run directory.
        start_step: step the call started from (0, or the resumed checkpoint's).
        step: steps done at the end.
        last_loss: the loss of the last step (this process).
        checkpoint: path of the last checkpoint written.
        interrupted: True when a signal stopped the run early (a checkpoint was written).
        seconds: wall time of the call.
    """

    run_dir: Path
    start_step: int
    step: int
    last_loss: float
    checkpoint: Path | None
    interrupted: bool
    seconds: float


class _IndexStream:
    """The data order: epoch e is ``permutation_e(n)`` seeded by (seed, e); the global batch of
    step s takes positions ``s*B .. s*B+B-1`` of the concatenated epochs, rank r its slice.
    Each index travels with a seed for its random draws, derived from (seed, position)."""

    def __init__(self, n: int, batch_size: int, seed: int, rank: int, world: int, start: int, stop: int):
        self.n, self.B, self.seed = n, batch_size, seed
        self.rank, self.world, self.start, self.stop = rank, world, start, stop
        self.local = batch_size // world
        self._perm: dict[int, np.ndarray] = {}

    def _order(self, epoch: int) -> np.ndarray:
        if epoch not in self._perm:
            self._perm = {epoch: np.random.default_rng([self.seed, 7919, epoch]).permutation(self.n)}
        return self._perm[epoch]

    def batch(self, step: int) -> list[tuple[int, int]]:
        first = step * self.B + self.rank * self.local
        out = []
        for pos in range(first, first + self.local):
            epoch, k = divmod(pos, self.n)
            item_seed = int(np.random.SeedSequence([self.seed, 104729, pos]).generate_state(1)[0])
            out.append((int(self._order(epoch)[k]), item_seed))
        return out

    def __iter__(self):
        for s in range(self.start, self.stop):
            yield self.batch(s)

    def __len__(self) -> int:
        return self.stop - self.start


def _lr_factor(step: int, cfg) -> float:
    """Learning-rate multiplier at ``step`` (0-based): linear warm-up, then constant or cosine."""
    o, total = cfg.optim, cfg.train.steps
    if o.warmup_steps > 0 and step < o.warmup_steps:
        return (step + 1) / o.warmup_steps
    if o.schedule == "cosine":
        span = max(1, total - o.warmup_steps)
        t = min(1.0, (step - o.warmup_steps) / span)
        return o.min_lr_ratio + (1 - o.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * t))
    return 1.0


def _amp_dtype(mode: str, device: torch.device) -> torch.dtype | None:
    if mode == "off":
        return None
    if mode == "auto":
        return torch.bfloat16 if device.type == "cuda" and torch.cuda.is_bf16_supported() else None
    if mode == "fp16":
        if device.type != "cuda":
            raise WrinklesInputError("train.amp = 'fp16' needs a CUDA device (use 'bf16' or 'off' on CPU)")
        return torch.float16
    return torch.bfloat16


class _StopFlag:
    """SIGINT/SIGTERM -> finish the step, checkpoint, return."""

    def __init__(self):
        self.raised = False
        self._old = {}

    def __enter__(self):
        def handler(signum, frame):
            self.raised = True

        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._old[sig] = signal.signal(sig, handler)
            except ValueError:  # not the main thread: leave signals alone
                pass
        return self

    def __exit__(self, *exc):
        for sig, h in self._old.items():
            signal.signal(sig, h)


class Trainer:
    """Train ``config.method`` on the dataset at ``data_root``, writing to ``run_dir``.

    Args:
        config: the resolved run config.
        data_root: dataset directory (``manifest.json``).
        run_dir: output directory of the run.
        resume: continue from ``run_dir/checkpoints/last.pt`` (start fresh when there is none).
            Without it, a ``run_dir`` that already holds checkpoints is refused.
        methods: the method registry (default ``learn.methods.METHODS``).
        progress: called on the main process after each optimizer step as
            ``progress(step, steps, note="loss 0.0123")`` (the CLI passes
            ``pipelines.progress.progress_bar``'s callback); None: nothing is shown.
    """

    def __init__(self, config: RunConfig, data_root: str | os.PathLike, run_dir: str | os.PathLike, *,
                 resume: bool = False, methods: dict | None = None,
                 progress: Callable[..., None] | None = None):
        if methods is None:
            from learn.methods import METHODS as methods
        self.config = config
        self.data_root = Path(data_root)
        self.run_dir = Path(run_dir)
        self.resume = resume
        self.progress = progress
        self.method: Method = methods[config.method](config.model)
        self.ckpt_dir = self.run_dir / CHECKPOINT_DIR
        if not resume and (self.ckpt_dir / LAST).exists():
            raise WrinklesInputError("already holds a training run; pass --resume to continue it or "
                                     "choose another output directory", path=self.run_dir)

    def config_dict(self) -> dict:
        return config_to_dict(self.config)

    # ------------------------------------------------------------------------------------------
    def fit(self) -> TrainSummary:
        """Train to ``config.train.steps`` (or until interrupted); returns a summary."""
        ctx = D.init_distributed(self.config.train.device)
        finished = False
        try:
            summary = self._fit(ctx)
            finished = True
            return summary
        finally:
            D.shutdown(ctx, together=finished)

    def _fit(self, ctx: D.DistContext) -> TrainSummary:
        t0 = time.perf_counter()
        cfg, tc = self.config, self.config.train
        if tc.batch_size % ctx.world_size:
            raise WrinklesInputError(f"train.batch_size {tc.batch_size} is not divisible by the "
                                     f"{ctx.world_size} processes")
        dev = ctx.device
        amp = _amp_dtype(tc.amp, dev)

        last = self.ckpt_dir / LAST
        resumed = load_checkpoint(last, map_location=dev) if self.resume and last.exists() else None
        # the fitted state: the checkpoint's when resuming, else fitted on the data now
        state = resumed.get("method_state", {}) if resumed else self.method.prepare(self.data_root)
        self.method.load_state(state)
        torch.manual_seed(tc.seed)
        model = self.method.build_model().to(dev)
        optimizer = torch.optim.AdamW(model.parameters(), lr=cfg.optim.lr, betas=cfg.optim.betas,
                                      weight_decay=cfg.optim.weight_decay)
        scaler = torch.amp.GradScaler("cuda", enabled=amp == torch.float16)
        ema = ExponentialMovingAverage(model, tc.ema_decay) if tc.ema_decay > 0 else None
        step = self._restore(resumed, model, optimizer, scaler, ema, dev) if resumed else 0
        start_step = step

        loader = self._loader(ctx, step)
        net = model
        if ctx.distributed:
            net = torch.nn.parallel.DistributedDataParallel(
                model, device_ids=[dev.index] if dev.type == "cuda" else None)

        if ctx.is_main:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            atomic_write_json(self.run_dir / "config.json",
                              {**self.config_dict(), "data": os.fspath(self.data_root.resolve())})
        logger = MetricLogger(self.run_dir, enabled=ctx.is_main, resume_step=step if self.resume else None)
        last_loss, ckpt_path, interrupted = float("nan"), None, False
        try:
            with _StopFlag() as stop:
                for batch in loader:
                    out, gnorm = self._step(ctx, net, model, batch, optimizer, scaler, ema, step, amp)
                    loss = out.loss
                    step += 1
                    last_loss = float(loss.detach())
                    if self.progress is not None and ctx.is_main:
                        self.progress(step, tc.steps, note=f"loss {last_loss:.4g}")
                    if step % tc.log_every == 0 or step == tc.steps:
                        scalars = {"loss": last_loss, "lr": optimizer.param_groups[0]["lr"],
                                   "grad_norm": float(gnorm)}
                        scalars.update({k: float(v.detach() if torch.is_tensor(v) else v)
                                        for k, v in out.scalars.items()})
                        logger.log(step, D.mean_across(ctx, scalars))
                    stop_now = D.any_across(ctx, stop.raised)
                    if step % tc.checkpoint_every == 0 or step == tc.steps or stop_now:
                        ckpt_path = self._save(ctx, model, optimizer, scaler, ema, step)
                        logger.flush()
                    if stop_now:
                        interrupted = step < tc.steps
                        break
        finally:
            logger.plot()
            logger.close()
        if ckpt_path is None and (self.ckpt_dir / LAST).exists():
            ckpt_path = self.ckpt_dir / LAST
        return TrainSummary(run_dir=self.run_dir, start_step=start_step, step=step, last_loss=last_loss,
                            checkpoint=ckpt_path, interrupted=interrupted, seconds=time.perf_counter() - t0)

    # ------------------------------------------------------------------------------------------
    def _loader(self, ctx: D.DistContext, step: int):
        """The training items of this process from ``step`` on (``_IndexStream``)."""
        tc = self.config.train
        dataset = self.method.train_dataset(self.data_root)
        if len(dataset) == 0:
            raise WrinklesInputError("no training items (empty train split, or sequences shorter than the "
                                     "window)", path=self.data_root)
        stream = _IndexStream(len(dataset), tc.batch_size, tc.seed, ctx.rank, ctx.world_size, step, tc.steps)
        return torch.utils.data.DataLoader(dataset, batch_sampler=stream, collate_fn=self.method.collate,
                                           num_workers=tc.num_workers, pin_memory=ctx.device.type == "cuda")

    def _step(self, ctx: D.DistContext, net, model, batch, optimizer, scaler, ema, step: int, amp):
        """One optimizer step at ``step`` (learning-rate schedule, mixed precision, gradient
        clipping, EMA); the method's loss output and the gradient norm (NaN without clipping)."""
        cfg, tc, dev = self.config, self.config.train, ctx.device
        for g in optimizer.param_groups:
            g["lr"] = cfg.optim.lr * _lr_factor(step, cfg)
        batch = batch_to(batch, dev)
        gen = torch.Generator(device=dev).manual_seed(
            int(np.random.SeedSequence([tc.seed, 15485863, step, ctx.rank]).generate_state(1)[0]))
        optimizer.zero_grad(set_to_none=True)
        ac = torch.autocast(dev.type, dtype=amp) if amp is not None else contextlib.nullcontext()
        with ac:
            out = self.method.training_loss(net, batch, gen)
        loss = out.loss
        if not torch.isfinite(loss.detach()):
            raise FloatingPointError(f"step {step}: the loss is {loss.item()} (not finite); "
                                     f"lower optim.lr or check the data")
        scaler.scale(loss).backward()
        scaler.unscale_(optimizer)
        gnorm = (torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.optim.grad_clip)
                 if cfg.optim.grad_clip > 0 else torch.tensor(float("nan")))
        scaler.step(optimizer)
        scaler.update()
        if ema is not None:
            ema.update(model)
        return out, gnorm

    def _save(self, ctx: D.DistContext, model, optimizer, scaler, ema, step: int) -> Path:
        last = self.ckpt_dir / LAST
        if ctx.is_main:
            payload = {
                "config": self.config_dict(),
                "step": step,
                "model": model.state_dict(),
                "method_state": self.method.state,
                "optimizer": optimizer.state_dict(),
                "scaler": scaler.state_dict(),
                "rng": {"torch": torch.get_rng_state()},
                "versions": package_versions("torch"),
            }
            if ctx.device.type == "cuda":
                payload["rng"]["cuda"] = torch.cuda.get_rng_state(ctx.device)
            if ema is not None:
                payload["ema"] = ema.state_dict()
            save_checkpoint(last, payload)
            numbered = self.ckpt_dir / f"step-{step:07d}.pt"
            save_checkpoint(numbered, payload)
            olds = sorted(self.ckpt_dir.glob("step-*.pt"))
            for p in olds[: max(0, len(olds) - self.config.train.keep_checkpoints)]:
                p.unlink()
        D.barrier(ctx)
        return last

    def _restore(self, ckpt: dict, model, optimizer, scaler, ema, dev) -> int:
        """Continue from ``ckpt`` (the run's last checkpoint, already read); returns its step."""
        path = self.ckpt_dir / LAST
        diffs = config_differences(ckpt["config"], self.config_dict())
        diffs = [k for k in diffs if k not in RESUMABLE_CHANGES]
        if diffs:
            raise WrinklesInputError(f"cannot resume: the config differs from the checkpoint's in "
                                     f"{', '.join(diffs)} (only {', '.join(sorted(RESUMABLE_CHANGES))} may "
                                     f"change on resume)", path=path)
        check_state_dict(model, ckpt["model"], path=path)
        model.load_state_dict(ckpt["model"])
        if "optimizer" in ckpt:
            optimizer.load_state_dict(ckpt["optimizer"])
        if "scaler" in ckpt:
            scaler.load_state_dict(ckpt["scaler"])
        if ema is not None and "ema" in ckpt:
            ema.load_state_dict(ckpt["ema"])
        rng = ckpt.get("rng", {})
        if "torch" in rng:
            torch.set_rng_state(rng["torch"].cpu())
        if "cuda" in rng and dev.type == "cuda":
            torch.cuda.set_rng_state(rng["cuda"].cpu(), dev)
        return int(ckpt["step"])


def load_trained(path: str | os.PathLike, *, device: str | torch.device = "cpu", use_ema: bool = True,
                 methods: dict | None = None):
    """Rebuild a trained method and model from a checkpoint (for evaluation and inference).

    Returns:
        ``(method, model, checkpoint_dict)``; the model is in eval mode on ``device``, holding
        the EMA weights when the checkpoint has them and ``use_ema``.

    Raises:
        WrinklesInputError: unreadable checkpoint, unknown method, config or weights that do not
            fit the method's model.
    """
    from learn.train.config import run_config_from_dict

    if methods is None:
        from learn.methods import METHODS as methods
    ckpt = load_checkpoint(path, map_location="cpu")
    cfg = run_config_from_dict(ckpt["config"], source=path, methods=methods)
    method = methods[cfg.method](cfg.model)
    method.load_state(ckpt.get("method_state", {}))
    model = method.build_model()
    check_state_dict(model, ckpt["model"], path=path)
    model.load_state_dict(ckpt["model"])
    if use_ema and "ema" in ckpt:
        ema = ExponentialMovingAverage(model, max(0.0, float(ckpt["ema"]["decay"])))
        ema.load_state_dict(ckpt["ema"])
        ema.copy_to(model)
    model.to(device).eval()
    return method, model, ckpt


def describe(summary: TrainSummary) -> str:
    """One line about a finished ``fit``."""
    state = "interrupted at" if summary.interrupted else "reached"
    return (f"{summary.run_dir}: {state} step {summary.step} (from {summary.start_step}), loss "
            f"{summary.last_loss:.4g}, {summary.seconds:.1f} s; checkpoint {summary.checkpoint}")


def dump_summary(summary: TrainSummary) -> str:
    return json.dumps({"run_dir": os.fspath(summary.run_dir), "start_step": summary.start_step,
                       "step": summary.step, "last_loss": summary.last_loss,
                       "checkpoint": None if summary.checkpoint is None else os.fspath(summary.checkpoint),
                       "interrupted": summary.interrupted, "seconds": summary.seconds})
