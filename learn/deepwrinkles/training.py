"""DeepWrinkles' training data: the fitted state made before training and the training items
(see ``learn.methods.deepwrinkles``)."""

from __future__ import annotations

import os
import sys

import numpy as np
import torch

from sim.errors import WrinklesInputError

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
"""Thread pools a registration worker limits to one (many workers share the host's cores)."""
SEQUENCE_CACHE = 128
"""Prepared sequences a training process keeps (items come in random order; ~5 MB each at 6k
vertices and 60 frames)."""


def _sequences(method, root, split: str = "train"):
    from learn.data import GarmentSequenceDataset

    ds = GarmentSequenceDataset(
        root,
        split,
        keys=("fine/vertices",),
        garments=method.config.garments or None,
    )
    if len(ds.sequence_ids) == 0:
        raise WrinklesInputError(f"no {split} sequences", path=ds.root)
    return ds


def _prepared(method, ds, sid: str, *, device: str | None = None):
    from learn.deepwrinkles.sequences import KEYS, PreparedSequence, sequence_fps
    from sim.datasets.storage import body_model_name

    sf = ds.open_sequence(sid)
    missing = [k for k in KEYS if k not in sf]
    if missing:
        raise WrinklesInputError(
            f"sequence {sid} has no {missing[0]!r}: DeepWrinkles needs fine and coarse garments and the body",
            path=sf.path,
        )
    seq = {k: sf[k] for k in KEYS}
    body = method.body(body_model_name(sf, {"config": ds.generator_config}) or "default")
    return sf, PreparedSequence(
        seq, body, sequence_fps(sf, ds.generator_config), method.config.resolution, device=device
    )


def _register_in_worker(job: tuple) -> int:
    """A worker process's share of ``register_all``: one sequence's registrations into the cache;
    returns the number of frames registered."""
    from learn.deepwrinkles.global_shape import registrations
    from learn.methods.deepwrinkles import DeepWrinklesMethod

    config, root, split, sid = job
    method = DeepWrinklesMethod(config)
    ds = _sequences(method, root, split)
    sf, prep = _prepared(method, ds, sid, device="cpu")
    reg = registrations(sf, prep.seq, prep.body, method.settings(), device=None, rig=prep.rig)
    return len(reg.frames)


def register_all(method, root, *, split: str = "train", max_sequences: int | None = None,
                 progress=None) -> None:
    """Make the registrations of every sequence of ``split`` missing from the cache, in
    ``config.workers`` processes (each scans on the default Warp device). Registering a test split
    ahead lets ``wrinkles evaluate --predict lr_input=registration`` read them from the cache;
    ``max_sequences`` takes the split's first ones, as ``wrinkles evaluate --max-sequences`` does."""
    import concurrent.futures as cf
    import multiprocessing as mp

    from learn.deepwrinkles.global_shape import cache_path

    ds = _sequences(method, root, split)
    settings = method.settings()
    first = list(ds.sequence_ids)[:max_sequences]
    todo = [s for s in first if not cache_path(ds.open_sequence(s), settings).exists()]
    if not todo or method.config.workers <= 1:
        return
    jobs = [(method.config, str(root), split, s) for s in todo]
    spawn = mp.get_context("spawn")
    saved = {k: os.environ.get(k) for k in THREAD_VARIABLES}
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))  # one thread per worker, set before it starts
    try:
        with cf.ProcessPoolExecutor(min(method.config.workers, len(jobs)), mp_context=spawn) as pool:
            for n in pool.map(_register_in_worker, jobs):
                if progress is not None:
                    progress(n)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


VARIANCE_REPORT = (100, 200, 500)
"""Subspace sizes whose variance kept the fit reports (the paper's 500 and two smaller ones)."""


def subspace_report(sub) -> str:
    """One line: the subspace's size and the share of the offsets' variance kept at 100 / 200 / 500
    components (or fewer, where the registrations' rank is smaller)."""
    kept = ", ".join(f"{k}: {sub.variance_kept(min(k, sub.size)):.4f}" for k in VARIANCE_REPORT)
    return f"subspace: {sub.size} components of {sub.frames} frames; variance kept at k = {kept}"


def text_tensor(text: str) -> torch.Tensor:
    """A string as a uint8 tensor (the fitted state holds tensors only)."""
    return torch.tensor(list(text.encode()), dtype=torch.uint8)


def tensor_text(t: torch.Tensor) -> str:
    return bytes(t.to(torch.uint8).tolist()).decode()


def garment_state(sf, sid: str, ds) -> dict[str, torch.Tensor]:
    """A training sequence's garment (``STATE_GARMENT_KEYS`` as ``garment/<key>``, its category,
    material, body model and frame rate) as fitted-state tensors: a checkpoint animates without
    its dataset."""
    from learn.deepwrinkles.sequences import STATE_GARMENT_KEYS
    from sim.datasets.storage import body_model_name

    entry = ds.entries[sid]
    out = {f"garment/{k}": torch.from_numpy(np.array(sf[k])) for k in STATE_GARMENT_KEYS if k in sf}
    out["garment/category"] = text_tensor(str(entry.get("garment") or "garment"))
    out["garment/material"] = text_tensor(str(entry.get("material") or "cotton"))
    out["garment/body_model"] = text_tensor(body_model_name(sf, {"config": ds.generator_config}) or "default")
    out["garment/fps"] = torch.tensor(float(ds.generator_config.get("fps") or 30.0))
    return out


class FrameCount:
    """A progress callback that adds up the frames it is told of and shows the sum on ``bar``."""

    def __init__(self, bar):
        self.bar, self.done = bar, 0

    def __call__(self, n: int) -> None:
        self.done += n
        self.bar(self.done)


def fit_state(method, root) -> dict[str, torch.Tensor]:
    """Register the training sequences (cached), fit the subspace, the control statistics and the
    linear pose-to-shape map: the method's fitted state (module docstring of
    ``learn.methods.deepwrinkles``)."""
    from learn.deepwrinkles.global_shape import registered_frames
    from learn.deepwrinkles.regression import LinearPoseToShape
    from learn.deepwrinkles.subspace import fit_subspace
    from pipelines.progress import progress_bar

    cfg = method.config
    ds = _sequences(method, root)
    shapes, controls, template, garment = [], [], None, {}
    every = method.settings().register_every
    total = sum(len(registered_frames(int(ds.entries[s]["frames"]), every)) for s in ds.sequence_ids)
    with progress_bar(total, "registering", unit="frame") as bar:
        step = FrameCount(bar)
        register_all(method, root, progress=step)
        for sid in ds.sequence_ids:
            sf, prep = _prepared(method, ds, sid, device="cpu")
            if template is None:
                template = prep.rig.faces
                garment = garment_state(sf, sid, ds)
            elif not np.array_equal(template, prep.rig.faces):
                raise WrinklesInputError(
                    f"sequence {sid}: its template differs from the first sequence's; "
                    "DeepWrinkles needs one garment topology (a reference-fit dataset of one "
                    "category: set model.garments)",
                    path=sf.path,
                )
            prep.register(sf, method.settings(), device="cpu", progress=step)
            shapes.append(prep.normalised)
            controls.append(prep.controls)
    sub = fit_subspace(np.concatenate(shapes), cfg.components, device="cpu")
    print(subspace_report(sub), file=sys.stderr)
    th = method.select_controls(np.concatenate(controls)).astype(np.float64)
    mean, std = th.mean(0), np.maximum(th.std(0), 1e-6)
    coeffs = np.concatenate([sub.encode(s) for s in shapes])
    scale = np.maximum(coeffs.std(0), 1e-9)
    linear = LinearPoseToShape.fit((th - mean) / std, coeffs, ridge=cfg.ridge)
    f32 = torch.float32
    return {
        "mean": torch.from_numpy(sub.mean),
        "components": torch.from_numpy(sub.components),
        "singular_values": torch.from_numpy(sub.singular_values),
        "total_variance": torch.tensor(sub.total_variance),
        "frames": torch.tensor(sub.frames),
        "control_mean": torch.tensor(mean, dtype=f32),
        "control_std": torch.tensor(std, dtype=f32),
        "coefficient_scale": torch.tensor(scale, dtype=f32),
        "linear": torch.from_numpy(linear.matrix),
        "template_faces": torch.from_numpy(template.astype(np.int64)),
        **garment,
    }


class TrainFrames(torch.utils.data.Dataset):
    """Frames of the training split (module docstring of ``learn.methods.deepwrinkles``); item
    ``(index, seed)`` draws its extra regression windows from ``seed``.

    ``warm`` prepares the first ``SEQUENCE_CACHE`` sequences in the calling process: data-loader
    workers started by fork (the default on Linux) share them instead of each preparing every
    sequence again; workers started by spawn prepare their own (``__getstate__`` drops the
    cache). Sequences of one garment layout share one maps operator."""

    def __init__(self, method, root):
        self.method = method
        self.root = root
        self.ds = _sequences(method, root)
        self._cache: dict = {}
        self._maps: dict = {}

    def __len__(self) -> int:
        return len(self.ds)

    def warm(self) -> None:
        """Prepare up to ``SEQUENCE_CACHE`` sequences now (with a progress bar)."""
        from pipelines.progress import progress_bar

        sids = list(self.ds.sequence_ids)[:SEQUENCE_CACHE]
        with progress_bar(len(sids), "preparing sequences", unit="seq") as bar:
            for n, sid in enumerate(sids, 1):
                self._sequence(sid)
                bar(n)

    def _layout_maps(self, prep):
        """The maps operator of the sequence's garment layout (one per distinct layout: the first
        sequence of a layout makes it)."""
        from learn.deepwrinkles.sequences import GARMENT_KEYS

        key = layout_digest({k: prep.seq[k] for k in GARMENT_KEYS})
        if key not in self._maps:
            if len(self._maps) >= SEQUENCE_CACHE:
                self._maps.pop(next(iter(self._maps)))
            self._maps[key] = prep.maps
        return self._maps[key]

    def _sequence(self, sid: str):
        """A sequence's prepared arrays: its rig and maps, the normalised control and coefficient
        windows, the LR input's global shape, the skinned template, the fine frames."""
        from learn.deepwrinkles.regression import windows

        if sid not in self._cache:
            m = self.method
            sf, prep = _prepared(m, self.ds, sid, device="cpu")
            prep.use_maps(self._layout_maps(prep))
            prep.register(sf, m.settings(), device="cpu")
            sub = m.subspace()
            k = m.config.lr_components or sub.size
            coeffs = sub.encode(prep.normalised)
            lr_shape = prep.normalised if m.config.lr_source == "registration" else sub.decode(coeffs[:, :k])
            if len(self._cache) >= SEQUENCE_CACHE:
                self._cache.pop(next(iter(self._cache)))
            w = m.config.window
            self._cache[sid] = (
                prep,
                windows(m.normalise_controls(prep.controls), w),
                windows(coeffs / m.state["coefficient_scale"].numpy(), w),
                prep.posed(lr_shape),
                prep.rig.skinned(),
                np.asarray(prep.seq["fine/vertices"], np.float32),
            )
        return self._cache[sid]

    def regression_windows(self, sid: str, t: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """(controls (R, W, C), coefficients (R, W, k)): the windows of frame ``t`` of ``sid``
        and ``regression_windows - 1`` more of random frames of the prepared sequences (drawn
        from ``seed``)."""
        own = self._sequence(sid)
        rows = [(own[1][t], own[2][t])]
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 7919])
        cached = list(self._cache.values())
        for _ in range(self.method.config.regression_windows - 1):
            c = cached[int(rng.integers(len(cached)))]
            u = int(rng.integers(len(c[1])))
            rows.append((c[1][u], c[2][u]))
        return (np.stack([r[0] for r in rows]),
                np.stack([r[1] for r in rows]).astype(np.float32))

    def __getitem__(self, key: tuple[int, int]) -> dict:
        index, seed = key
        sid, t = self.ds.locate(index)
        prep, _, _, global_shape, skinned, fine = self._sequence(sid)
        controls, coefficients = self.regression_windows(sid, t, seed)
        prev = max(t - 1, 0)
        lr = prep.maps.lr(global_shape[[t]], skinned[[t]])[0]
        hr = prep.maps.hr(fine[[prev, t]], global_shape[[prev, t]])

        def chw(a: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1), dtype=np.float32))

        return {
            "controls": torch.from_numpy(controls),
            "coefficients": torch.from_numpy(coefficients),
            "lr": chw(lr),
            "hr": chw(hr[1]),
            "hr_prev": chw(hr[0]),
            "mask": torch.from_numpy(prep.maps.mask[None].astype(np.float32)),
        }

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_cache": {}, "_maps": {}}


def layout_digest(arrays: dict[str, np.ndarray]) -> str:
    """A digest of a garment's layout arrays (equal layouts share a maps operator)."""
    import hashlib

    h = hashlib.sha1()
    for k in sorted(arrays):
        a = np.ascontiguousarray(arrays[k])
        h.update(k.encode())
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def main(argv: list[str] | None = None) -> int:
    """``python -m learn.deepwrinkles.training DATA``: register the sequences of some splits ahead
    of training and evaluation, in worker processes (the registrations' cache beside the data)."""
    import argparse
    import time

    from learn.methods.deepwrinkles import DeepWrinklesConfig, DeepWrinklesMethod
    from pipelines.progress import progress_bar

    ap = argparse.ArgumentParser(prog="python -m learn.deepwrinkles.training", description=main.__doc__)
    ap.add_argument("data", help="dataset folder")
    ap.add_argument("--split", action="append", default=None,
                    help="split to register (repeatable; default: train and test_id)")
    ap.add_argument("--workers", type=int, default=max(2, (os.cpu_count() or 2) - 1), help="processes")
    defaults = DeepWrinklesConfig()
    ap.add_argument("--every", type=int, default=defaults.register_every,
                    help="register every k-th frame: model.register_every (default: %(default)s)")
    ap.add_argument("--source", choices=("registration", "simulation"), default=defaults.source,
                    help="the training's model.source (default: %(default)s)")
    ap.add_argument("--garment", action="append", default=None, help="garment category (repeatable)")
    ap.add_argument("--max-sequences", type=int, default=None,
                    help="only the first N sequences of each split (those evaluate --max-sequences takes)")
    args = ap.parse_args(argv)
    if args.every < 1 or (args.max_sequences is not None and args.max_sequences < 1):
        ap.error("--every and --max-sequences must be at least 1")
    method = DeepWrinklesMethod(DeepWrinklesConfig(
        workers=max(2, args.workers), register_every=args.every, source=args.source,
        garments=tuple(args.garment or ())))
    t0 = time.time()
    try:
        for split in args.split or ("train", "test_id"):
            with progress_bar(0, f"registering {split}", unit="frame") as bar:
                step = FrameCount(bar)
                register_all(method, args.data, split=split, max_sequences=args.max_sequences, progress=step)
            print(f"{split}: {step.done} frames registered, {time.time() - t0:.0f} s", file=sys.stderr)
    except WrinklesInputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
