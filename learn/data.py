"""Reading synthetic garment datasets for training: frame windows of sequence files, as tensors.

A dataset directory (``sim.datasets.storage``) holds ``manifest.json`` and one safetensors file
per sequence (arrays listed in ``sim.datasets.schema``). :class:`GarmentSequenceDataset` serves
*windows* of consecutive frames: item ``i`` is one sequence's frames ``start .. start + window - 1``
of the chosen per-frame arrays, plus that sequence's static arrays whole. Files are
memory-mapped, so an item reads only its window's bytes from disk (or the page cache).

Typical use::

    ds = GarmentSequenceDataset("data/tshirts", "train", window=4, stride=2)
    loader = DataLoader(ds, batch_size=8, shuffle=True, num_workers=4, collate_fn=collate_windows)

Manifest statistics (``wrinkles dataset info``) live in ``sim.datasets.info`` (no torch).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from sim.datasets.schema import (
    BODY_KEYS,
    COARSE_KEYS,
    FINE_KEYS,
    IMAGE_KEYS,
    PER_FRAME_KEYS,
    QUALITY_KEYS,
    SPLITS,
)
from sim.datasets.storage import MANIFEST, SequenceFile, file_sha256, read_manifest
from sim.errors import WrinklesInputError

ALL_SPLITS = "all"
"""``split`` value that selects every sequence of the manifest."""

SCHEMA_KEYS = (*FINE_KEYS, *IMAGE_KEYS, *COARSE_KEYS, *BODY_KEYS, *QUALITY_KEYS)
"""Every array name a sequence file may hold (``sim.datasets.schema``)."""

DEFAULT_KEYS = ("fine/vertices", "fine/base", "fine/wrinkle", "fine/strain_norm", *BODY_KEYS)
"""Arrays an item holds when ``keys`` is not given; ``images/*`` are added when every selected
sequence has images (manifest ``image_resolution`` not null)."""

_PER_FRAME = frozenset(PER_FRAME_KEYS)


def rest_betas(seq: Mapping[str, np.ndarray], num_betas: int) -> np.ndarray:
    """The body shape a sequence's garment was made on: ``garment/betas`` (a reference fit: the
    garment made on another shape than the body's), else ``body/betas``; at most ``num_betas``."""
    b = seq.get("garment/betas")
    b = seq["body/betas"] if b is None or np.asarray(b).size == 0 else b
    return np.asarray(b, np.float32).reshape(-1)[:num_betas]


def sequence_inputs(sf: SequenceFile, entry: Mapping, config: Mapping,
                    keys: Iterable[str] | None = None) -> dict[str, np.ndarray]:
    """A sequence as ``Method.predict_sequence`` reads it: its arrays (all, or those of ``keys`` it
    has), ``body/model`` (the body's name or file), ``fps``, ``sequence/path``,
    ``garment/material`` (empty when unknown) and, from the manifest entry, ``garment/betas``
    where the garment was made on another shape than the body's (a reference fit).

    Args:
        sf: the sequence file; entry: its manifest entry; config: the manifest's generator config.
        keys: array names to read (a missing one is left out); None: every one.
    """
    from sim.datasets.storage import body_model_name

    names = sf.keys() if keys is None else [k for k in keys if k in sf]
    seq = {k: np.asarray(sf[k]) for k in names}
    seq["body/model"] = np.asarray(body_model_name(sf, {"config": config}) or "default")
    seq["fps"] = np.asarray(float(config.get("fps") or 30.0))
    seq["sequence/path"] = np.asarray(str(sf.path))
    seq["garment/material"] = np.asarray(str(entry.get("material") or ""))
    if entry.get("garment_betas") is not None:
        seq["garment/betas"] = np.asarray(entry["garment_betas"], np.float32)
    return seq



class GarmentSequenceDataset(Dataset):
    """Frame windows of a synthetic garment dataset, read from memory-mapped sequence files.

    Item ``i`` is a dict:

    - each per-frame array in ``keys`` (``sim.datasets.schema.PER_FRAME_KEYS``) sliced to the
      window: shape ``(window, ...)``, e.g. ``fine/vertices`` ``(window, V, 3)`` [m]. The window
      axis is kept when ``window == 1`` (shape ``(1, V, 3)``); squeeze it yourself if you want
      single frames;
    - each static array in ``keys`` whole, e.g. ``fine/faces`` ``(F, 3)``, ``images/mask``
      ``(H, W)``, ``body/betas`` ``(B,)``;
    - ``"sequence"``: the sequence id (str), ``"start"``: the window's first frame (int).

    Floating arrays (f32 positions, f16 images) become ``dtype``; integer and bool arrays keep
    their stored dtype (``fine/faces`` int32, ``images/mask`` uint8). Every tensor is a fresh
    copy, safe to modify.

    Items are ordered by sequence id, then start frame. A sequence of ``T`` frames gives windows
    starting at ``0, stride, 2 * stride, ...`` up to ``T - window`` (frames at the end that do not
    fill a window are not served); sequences with ``T < window`` give none and are listed in
    :attr:`skipped`.

    Files are opened lazily, once per process (so each ``DataLoader`` worker opens its own):
    only the parsed headers are kept, never an open memory map, and the pickled state (what a
    spawned worker receives) holds no file state at all.

    Args:
        root: the dataset directory (holding ``manifest.json``).
        split: ``"train"``, ``"test_id"``, ``"test_ood"`` or ``"all"``.
        window: consecutive frames per item (>= 1).
        stride: frames between the starts of consecutive windows of a sequence (>= 1).
        keys: array names to load (``SCHEMA_KEYS``); default :data:`DEFAULT_KEYS` (+ images).
            A named array missing from a file is an error naming the file. A str is one name.
        garments: keep only these garment categories (manifest ``garment``, e.g. ``"t_shirt"``;
            a str is one category).
        dtype: floating dtype of the float arrays.
        verify: check each file's sha256 against the manifest when a process first opens it
            (the whole file is read once per process; :meth:`verify_files` checks all files
            once, up front, and workers then skip them).

    Raises:
        WrinklesInputError: no or unreadable manifest; a garment category not in the manifest;
            (when an item is read) a file that is unreadable, fails its checksum, lacks a key, or
            whose frame count differs from the manifest.
        ValueError: a bad ``split``, ``window``, ``stride``, ``dtype`` or a key not in the schema.
    """

    def __init__(self, root: str | os.PathLike, split: str = "train", *, window: int = 1, stride: int = 1,
                 keys: Sequence[str] | None = None, garments: str | Iterable[str] | None = None,
                 dtype: torch.dtype = torch.float32, verify: bool = False):
        self.root = Path(root)
        manifest = read_manifest(self.root)
        self.generator_config: dict = manifest.get("config") or {}
        """The manifest's generator config (body model, derive settings, ...)."""
        if split != ALL_SPLITS and split not in SPLITS:
            raise ValueError(f"split {split!r}: choose one of {', '.join((*SPLITS, ALL_SPLITS))}")
        if int(window) != window or window < 1:
            raise ValueError(f"window must be a positive integer, got {window!r}")
        if int(stride) != stride or stride < 1:
            raise ValueError(f"stride must be a positive integer, got {stride!r}")
        if not dtype.is_floating_point:
            raise ValueError(f"dtype must be a floating dtype, got {dtype}")
        self.split, self.window, self.stride = split, int(window), int(stride)
        self.dtype, self.verify = dtype, verify

        entries: dict[str, dict] = manifest.get("sequences", {})
        if isinstance(garments, str):
            garments = (garments,)
        self.garments = None if garments is None else tuple(dict.fromkeys(garments))
        if self.garments is not None:
            known = sorted({e.get("garment") for e in entries.values()} - {None})
            unknown = [g for g in self.garments if g not in known]
            if unknown:
                raise WrinklesInputError(f"no garment category {', '.join(map(repr, unknown))} "
                                         f"(has {', '.join(known) or 'none'})", path=self.root / MANIFEST)

        selected = {sid: e for sid, e in sorted(entries.items())
                    if (split == ALL_SPLITS or e.get("split") == split)
                    and (self.garments is None or e.get("garment") in self.garments)}
        self.entries: dict[str, dict] = selected
        """Manifest entries of the selected sequences (windows or not), by id."""

        if keys is None:
            images = bool(selected) and all(e.get("image_resolution") for e in selected.values())
            keys = (*DEFAULT_KEYS, *(IMAGE_KEYS if images else ()))
        else:
            keys = tuple(dict.fromkeys([keys] if isinstance(keys, str) else keys))
            bad = [k for k in keys if k not in SCHEMA_KEYS]
            if bad:
                raise ValueError(f"unknown array name(s) {', '.join(map(repr, bad))}: "
                                 f"sequence files hold {', '.join(SCHEMA_KEYS)}")
        self.keys: tuple[str, ...] = tuple(keys)

        ids, starts_per_seq, skipped = [], [], []
        for sid, e in selected.items():
            T = int(e["frames"])
            if T < self.window:
                skipped.append(sid)
                continue
            ids.append(sid)
            starts_per_seq.append((T - self.window) // self.stride + 1)
        self.sequence_ids: tuple[str, ...] = tuple(ids)
        """Ids of the sequences that give at least one window, in item order."""
        self.skipped: tuple[str, ...] = tuple(skipped)
        """Ids of the selected sequences shorter than ``window`` (they give no items)."""
        # item i belongs to sequence j where _first[j] <= i < _first[j + 1]
        self._first = np.concatenate([[0], np.cumsum(starts_per_seq, dtype=np.int64)])
        self._verified: set[str] = set()
        self._files: dict[str, SequenceFile] = {}
        self._pid = os.getpid()

    @property
    def num_skipped(self) -> int:
        """How many selected sequences are shorter than ``window``."""
        return len(self.skipped)

    def __len__(self) -> int:
        return int(self._first[-1])

    def locate(self, index: int) -> tuple[str, int]:
        """``(sequence id, start frame)`` of item ``index``, without reading anything."""
        n = len(self)
        if index < 0:
            index += n
        if not 0 <= index < n:
            raise IndexError(f"item {index} out of range for {n} windows")
        j = int(np.searchsorted(self._first, index, side="right")) - 1
        return self.sequence_ids[j], int(index - self._first[j]) * self.stride

    def __getitem__(self, index: int) -> dict:
        sid, start = self.locate(index)
        f = self.open_sequence(sid)
        item: dict = {}
        for key in self.keys:
            a = f[key]
            if key in _PER_FRAME:
                a = a[start:start + self.window]
            # copy out of the memory map, native byte order (torch reads only that)
            a = np.array(a, dtype=a.dtype.newbyteorder("="))
            t = torch.from_numpy(a)
            item[key] = t.to(self.dtype) if t.is_floating_point() else t
        item["sequence"] = sid
        item["start"] = start
        return item

    def verify_files(self) -> None:
        """Check every selected file's sha256 now (in this process); workers forked or spawned
        afterwards do not check them again.

        Raises:
            WrinklesInputError: a file is missing or differs from its manifest checksum.
        """
        for sid in self.sequence_ids:
            self._check_sha256(sid)

    def _check_sha256(self, sid: str) -> None:
        if sid in self._verified:
            return
        path = self._path(sid)
        want = self.entries[sid].get("sha256")
        try:
            got = file_sha256(path)
        except OSError as e:
            raise WrinklesInputError(f"cannot read sequence file ({e.strerror or e})", path=path) from None
        if got != want:
            raise WrinklesInputError(f"checksum mismatch: sha256 {got[:12]}..., manifest says "
                                     f"{str(want)[:12]}... (file corrupted or replaced)", path=path)
        self._verified.add(sid)

    def _path(self, sid: str) -> Path:
        return self.root / self.entries[sid]["file"]

    def open_sequence(self, sid: str) -> SequenceFile:
        """The (checked, per-process cached) sequence file of ``sid``: its keys are present and
        its per-frame arrays have the manifest's frame count."""
        if self._pid != os.getpid():  # a forked worker: reopen everything in this process
            self._files, self._pid = {}, os.getpid()
        f = self._files.get(sid)
        if f is not None:
            return f
        if self.verify:
            self._check_sha256(sid)
        f = SequenceFile(self._path(sid))
        missing = [k for k in self.keys if k not in f]
        if missing:
            raise WrinklesInputError(f"no array {', '.join(map(repr, missing))} in this sequence file "
                                     f"(has {', '.join(f.keys())})", path=f.path)
        T = int(self.entries[sid]["frames"])
        for k in self.keys:
            if k in _PER_FRAME and (not f.shape(k) or f.shape(k)[0] != T):
                raise WrinklesInputError(f"array {k!r} has shape {f.shape(k)}, the manifest says {T} frames",
                                         path=f.path)
        self._files[sid] = f
        return f

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_files"] = {}  # headers are re-read where the dataset lands (a spawned worker)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._pid = os.getpid()

    def __repr__(self) -> str:
        return (f"GarmentSequenceDataset({str(self.root)!r}, split={self.split!r}, window={self.window}, "
                f"stride={self.stride}: {len(self)} windows of {len(self.sequence_ids)} sequences, "
                f"{self.num_skipped} too short)")


def collate_windows(items: Sequence[Mapping]) -> dict:
    """Batch items of :class:`GarmentSequenceDataset` (``DataLoader(..., collate_fn=collate_windows)``).

    Items from different garments have different vertex / face / UV counts, so the default
    collate cannot stack them. Here, per key: tensors of one shape and dtype are stacked into a
    ``(batch, ...)`` tensor; otherwise the value is a list, one entry per item. ``"start"``
    becomes an int64 tensor ``(batch,)``; ``"sequence"`` a list of ids. So a batch of windows of
    one garment (or one topology) is all tensors, and a mixed batch has lists where sizes differ
    (``isinstance(batch[key], list)`` tells which).

    Raises:
        ValueError: no items, or items with different keys.
    """
    if not items:
        raise ValueError("collate_windows: no items")
    keys = list(items[0])
    for it in items[1:]:
        if set(it) != set(keys):
            raise ValueError(f"collate_windows: items with different keys ({sorted(set(keys) ^ set(it))})")
    out: dict = {}
    for k in keys:
        vals = [it[k] for it in items]
        if all(isinstance(v, torch.Tensor) for v in vals) and \
                len({(tuple(v.shape), v.dtype) for v in vals}) == 1:
            out[k] = torch.stack(vals)
        elif all(isinstance(v, int) and not isinstance(v, bool) for v in vals):
            out[k] = torch.tensor(vals, dtype=torch.int64)
        else:
            out[k] = vals
    return out
