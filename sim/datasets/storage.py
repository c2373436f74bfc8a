"""Dataset storage: sequence files, the manifest, atomic writes.

A dataset is a directory::

    DIR/manifest.json               schema version, generator config, one entry per sequence
    DIR/sequences/<id>.safetensors  one file per accepted sequence, written atomically
    DIR/parts/shard-<i>-of-<n>.json what one shard has done (accepted and rejected), for resume
    DIR/parts/shard-<i>-of-<n>.events.jsonl  when each of its sequences was done (the job's timeline)
    DIR/derived/<id>.safetensors    derived fields, made where they are read (sim.datasets.fields)
    DIR/rejections.jsonl            one line per rejected sequence: id and why (``attempts``: each rung;
                                    ``body_self_crossings``: the body through itself near the garment)

Sequence files use the safetensors layout (8-byte little-endian header length, a JSON header
of ``name -> {dtype, shape, data_offsets}`` plus ``__metadata__`` (str -> str), then the raw
little-endian arrays, each aligned to 64 bytes). It is not pickle: reading one executes no
code, any safetensors reader opens it, and here it is read with ``np.memmap`` so a torch
``Dataset`` touches only the frames it uses. Writers sort the names and write no timestamps,
so the same arrays give the same bytes.

Every file appears only when complete: it is written under a temporary name in the same
directory, flushed to disk, and renamed into place (``os.replace`` is atomic).
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError

SCHEMA_VERSION = 2
READABLE_VERSIONS = (1, 2)
"""Version 1 files store every field as such; version 2 files store what the simulation gives
(positions as float32 or quantized) and leave the derived fields to the reader
(``sim.datasets.schema``); both read the same."""
MANIFEST = "manifest.json"
SEQUENCE_DIR = "sequences"
PARTS_DIR = "parts"
REJECTIONS = "rejections.jsonl"
SUFFIX = ".safetensors"
_ALIGN = 64

_DTYPES = {"F16": np.float16, "F32": np.float32, "F64": np.float64, "I8": np.int8, "U8": np.uint8,
           "I16": np.int16, "I32": np.int32, "I64": np.int64, "BOOL": np.bool_}
_NAMES = {np.dtype(v).str.lstrip("<>|="): k for k, v in _DTYPES.items()}


def _dtype_name(a: np.ndarray) -> str:
    key = a.dtype.str.lstrip("<>|=")
    if key not in _NAMES:
        raise ValueError(f"dtype {a.dtype} cannot be stored")
    return _NAMES[key]


def atomic_write_bytes(path: str | os.PathLike, data: bytes | Iterable[bytes]) -> None:
    """Write ``data`` to ``path`` so that the file appears complete or not at all (the temporary
    file's name is unique to this writer: hosts sharing a folder, threads of one process)."""
    import uuid

    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}-{uuid.uuid4().hex[:12]}")
    try:
        with open(tmp, "xb") as f:
            if isinstance(data, (bytes, bytearray, memoryview)):
                f.write(data)
            else:
                for chunk in data:
                    f.write(chunk)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    try:  # make the rename itself durable
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:  # pragma: no cover - directories cannot be fsynced on some filesystems
        pass


def atomic_write_json(path: str | os.PathLike, obj) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode())


def write_sequence(path: str | os.PathLike, arrays: Mapping[str, np.ndarray],
                   metadata: Mapping[str, str] | None = None) -> str:
    """Write one sequence file atomically.

    Args:
        path: destination (``.safetensors``).
        arrays: name -> array (stored little-endian, C order; names sorted in the file).
        metadata: str -> str (e.g. JSON texts of the garment and provenance).

    Returns:
        the file's sha256 (hex).
    """
    header: dict = {}
    blobs = []
    offset = 0
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        raw = a.tobytes()
        pad = (-len(raw)) % _ALIGN
        header[name] = {"dtype": _dtype_name(a), "shape": list(a.shape),
                        "data_offsets": [offset, offset + len(raw)]}
        blobs.append(raw + b"\0" * pad)
        offset += len(raw) + pad
    data = hashlib.sha256()
    for b in blobs:
        data.update(b)
    # the arrays' own checksum, inside the file: a copy checks itself, and derived-field caches
    # (sim.datasets.fields) know which data they came from
    header["__metadata__"] = {**{str(k): str(v) for k, v in sorted((metadata or {}).items())},
                              "data_sha256": data.hexdigest()}
    text = json.dumps(header, sort_keys=True, separators=(",", ":")).encode()
    # the data starts 64-byte aligned: pad the header with spaces (allowed by the format)
    text += b" " * ((-(8 + len(text))) % _ALIGN)
    head = struct.pack("<Q", len(text)) + text
    digest = hashlib.sha256(head)
    for b in blobs:
        digest.update(b)
    atomic_write_bytes(path, [head, *blobs])
    return digest.hexdigest()


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 22), b""):
            h.update(chunk)
    return h.hexdigest()


class SequenceFile:
    """A sequence file opened for reading: arrays are memory-mapped, read-only, on demand.

    Args:
        path: a ``.safetensors`` sequence file.

    Raises:
        WrinklesInputError: not a readable sequence file (names the file and the problem).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        try:
            size = self.path.stat().st_size
            with open(self.path, "rb") as f:
                (n,) = struct.unpack("<Q", f.read(8))
                if n > size - 8 or n > 100_000_000:
                    raise ValueError("header length beyond the end of the file")
                header = json.loads(f.read(n))
        except (OSError, ValueError, struct.error) as e:
            raise WrinklesInputError(f"not a readable sequence file ({e})", path=self.path) from None
        self.metadata: dict[str, str] = header.pop("__metadata__", {}) or {}
        self._base = 8 + n
        self._entries = header
        self._names: tuple[tuple[str, ...], tuple[str, ...]] | None = None
        self._derived: SequenceFile | None = None
        for name, e in header.items():
            if e.get("dtype") not in _DTYPES or len(e.get("data_offsets", ())) != 2:
                raise WrinklesInputError(f"bad entry {name!r} in the header", path=self.path)
            lo, hi = e["data_offsets"]
            count = int(np.prod(e["shape"])) if e["shape"] else 1
            if hi - lo != count * np.dtype(_DTYPES[e["dtype"]]).itemsize or self._base + hi > size:
                raise WrinklesInputError(f"entry {name!r} does not fit the file (truncated?)", path=self.path)

    @property
    def data_offset(self) -> int:
        """Byte offset of the first array (after the header)."""
        return self._base

    def has_stored(self, name: str) -> bool:
        """Whether the file holds array ``name`` as such."""
        return name in self._entries

    def has(self, name: str) -> bool:
        """Whether ``name`` is stored, as such or quantized (``sim.datasets.quantize``)."""
        return name in self._entries or name + "_q" in self._entries

    def _virtual(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(quantized names, derivable names) of this file."""
        if self._names is None:
            from sim.datasets.fields import derivable
            from sim.datasets.quantize import SUFFIXES

            quantized = tuple(n[:-2] for n in self._entries
                              if n.endswith("_q") and all(n[:-2] + s in self._entries for s in SUFFIXES))
            self._names = (quantized, derivable(self))
        return self._names

    def keys(self) -> list[str]:
        """The names it gives: stored, quantized (read decoded) and derived (read from the cache
        of derived fields, ``sim.datasets.fields``)."""
        from sim.datasets.quantize import SUFFIXES

        quantized, derived = self._virtual()
        parts = {q + s for q in quantized for s in SUFFIXES}
        return sorted({*(n for n in self._entries if n not in parts), *quantized, *derived})

    def __contains__(self, name: str) -> bool:
        return name in self._entries or any(name in names for names in self._virtual())

    def shape(self, name: str) -> tuple[int, ...]:
        if name in self._entries:
            return tuple(self._entries[name]["shape"])
        quantized, derived = self._virtual()
        if name in quantized:
            return tuple(self._entries[name + "_q"]["shape"])
        if name in derived:
            from sim.datasets.fields import derived_shape

            return derived_shape(self, name)
        raise KeyError(f"{self.path}: no array {name!r} (has {', '.join(self.keys())})")

    def stored(self, name: str) -> np.ndarray:
        """The stored array ``name``, memory-mapped read-only (copy what you keep)."""
        if name not in self._entries:
            raise KeyError(f"{self.path}: no stored array {name!r} (has {', '.join(sorted(self._entries))})")
        e = self._entries[name]
        dt = np.dtype(_DTYPES[e["dtype"]]).newbyteorder("<")
        shape = tuple(e["shape"])
        if int(np.prod(shape)) == 0:
            return np.zeros(shape, dt)
        return np.memmap(self.path, dtype=dt, mode="r", offset=self._base + e["data_offsets"][0], shape=shape)

    def __getitem__(self, name: str):
        """Array ``name``: a stored one memory-mapped read-only (copy what you keep); a quantized
        one as a ``Dequantized`` view (slicing decodes only those frames); a derived one from the
        cache of derived fields (derived and cached on first use, on the CPU)."""
        if name in self._entries:
            return self.stored(name)
        quantized, derived = self._virtual()
        if name in quantized:
            from sim.datasets.quantize import SUFFIXES, Dequantized

            return Dequantized(*(self.stored(name + s) for s in SUFFIXES))
        if name in derived:
            if self._derived is None:
                from sim.datasets.fields import cached_fields

                self._derived = cached_fields(self, device="cpu")
            return self._derived.stored(name)
        raise KeyError(f"{self.path}: no array {name!r} (has {', '.join(self.keys())})")

    def json(self, key: str):
        """A metadata entry parsed as JSON."""
        return json.loads(self.metadata[key])


def read_manifest(root: str | os.PathLike) -> dict:
    """``DIR/manifest.json``, checked for its schema version."""
    path = Path(root) / MANIFEST
    try:
        m = json.loads(path.read_text())
    except FileNotFoundError:
        raise WrinklesInputError("no manifest.json: not a dataset directory (or generation has not "
                                 "finished a shard yet; 'wrinkles dataset combine' builds it from parts/)",
                                 path=root) from None
    except (OSError, ValueError) as e:
        raise WrinklesInputError(f"unreadable manifest ({e})", path=path) from None
    if m.get("schema_version") not in READABLE_VERSIONS:
        raise WrinklesInputError(f"schema version {m.get('schema_version')!r}, this wrinkles reads "
                                 f"{' and '.join(map(str, READABLE_VERSIONS))}", path=path)
    return m


def sequence_path(root: str | os.PathLike, seq_id: str) -> Path:
    return Path(root) / SEQUENCE_DIR / f"{seq_id}{SUFFIX}"


def part_path(root: str | os.PathLike, shard: int, shards: int) -> Path:
    return Path(root) / PARTS_DIR / f"shard-{shard}-of-{shards}.json"


def events_path(part: Path) -> Path:
    """The timeline beside a shard's part file: one JSON line per sequence done (``id``,
    ``outcome``, ``frames``, ``time`` [s since the epoch], ``shard``), appended as they finish."""
    return part.with_name(part.name.removesuffix(".json") + ".events.jsonl")


def read_events(root: str | os.PathLike) -> list[dict]:
    """Every shard's timeline events of the dataset at ``root``, in time order (a line cut short
    by a killed job is skipped)."""
    events = []
    for p in sorted((Path(root) / PARTS_DIR).glob("shard-*-of-*.events.jsonl")):
        for line in p.read_text().splitlines():
            try:
                events.append(json.loads(line))
            except ValueError:
                continue
    return sorted(events, key=lambda e: e.get("time", 0.0))


def combine_parts(root: str | os.PathLike, *, config: dict, verify: bool = False) -> dict:
    """Build ``manifest.json`` from every shard part in ``DIR/parts`` (atomically replaced).

    Args:
        root: the dataset directory.
        config: the generator config (resolved, as a dict); every part must have been made with
            the same one.
        verify: re-hash every sequence file against its recorded checksum.

    Returns:
        the manifest.
    """
    root = Path(root)
    entries: dict[str, dict] = {}
    rejected: dict[str, dict] = {}
    shards = set()
    for p in sorted((root / PARTS_DIR).glob("shard-*-of-*.json")):
        part = json.loads(p.read_text())
        if part.get("config") != config:
            raise WrinklesInputError("made with a different generator config than this one", path=p)
        shards.add(part.get("shards"))
        entries.update(part.get("sequences", {}))
        rejected.update(part.get("rejected", {}))
    if len(shards) > 1:
        raise WrinklesInputError(f"parts from different shard counts {sorted(shards)} in one dataset",
                                 path=root / PARTS_DIR)
    if verify:
        for sid, e in entries.items():
            got = file_sha256(sequence_path(root, sid))
            if got != e["sha256"]:
                raise WrinklesInputError(f"checksum mismatch ({got[:12]} != {e['sha256'][:12]})",
                                         path=sequence_path(root, sid))
    manifest = {"schema_version": SCHEMA_VERSION, "config": config,
                "sequences": dict(sorted(entries.items())), "rejected": dict(sorted(rejected.items()))}
    atomic_write_json(root / MANIFEST, manifest)
    return manifest


def body_model_name(sf: SequenceFile, manifest: dict) -> str | None:
    """The body model a sequence was simulated on (``"default"`` or a model file), or None.

    Looked up in the sequence's ``body`` metadata (``{"model": ..., "name": ...}`` as
    ``sim.datasets.generate`` writes it; ``model`` wins, a plain string is taken as is), then in
    the manifest's generator config (``config.bodies.model``, or ``config.body``).
    """
    candidates = []
    if "body" in sf.metadata:
        try:
            candidates.append(sf.json("body"))
        except ValueError:
            candidates.append(sf.metadata["body"])
    config = manifest.get("config")
    if isinstance(config, dict):
        bodies = config.get("bodies")
        candidates += [bodies.get("model") if isinstance(bodies, dict) else None, config.get("body")]
    for c in candidates:
        if isinstance(c, dict):
            c = c.get("model") or c.get("name")
        if isinstance(c, str) and c:
            return c
    return None
