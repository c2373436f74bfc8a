"""Fields a sequence file does not store, derived from what it does and kept in a cache.

A sequence file stores what only the simulation can give (positions: float32, or int16 on a
grid, ``sim.datasets.quantize``), the garments' rest data, the body's motion and the quality
record; the fields computed from those (``DERIVED_KEYS``: base surface, wrinkle field,
strain, normals, UV images, coarse strain) cost seconds per sequence and would take seven
eighths of the bytes. They are
derived on first read (``derive_fields``, the same ``Deriver`` the generator runs) and written,
all at once, to a cache file beside the dataset (``DIR/derived/<id>.safetensors``, or under
``$WRINKLES_CACHE/derived/`` where the dataset is read-only), itself a plain safetensors file.
The cache is keyed by the sequence file's data checksum, its derivation settings and
``DERIVE_VERSION``: a sequence written anew, or a derivation that changes, makes it stale and it
is derived again. Derived on another kind of device, fields differ in float rounding: the cache
records the device kind (``device`` metadata), and whichever derivation came first is kept.
``wrinkles dataset derive`` fills the cache of a whole dataset ahead of training.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.datasets.schema import IMAGE_KEYS
from sim.errors import WrinklesInputError

DERIVE_VERSION = 1
"""Changes whenever a derived field would come out different: older caches are stale then."""
FINE_DERIVED = ("fine/base", "fine/wrinkle", "fine/strain", "fine/strain_norm", "fine/normals")
DERIVED_KEYS = (*FINE_DERIVED, *IMAGE_KEYS, "coarse/strain_norm")
DERIVED_DIR = "derived"
DERIVE_META = "derive"
"""Metadata entry of a sequence file: JSON of the ``DeriveConfig`` its derived fields use."""


@dataclass(frozen=True)
class _RestGarment:
    """The parts of a ``Garment`` the derivation reads, from a sequence file."""

    rest_vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    uv_faces: np.ndarray
    face_layers: np.ndarray

    @property
    def num_vertices(self) -> int:
        return len(self.rest_vertices)


def _rest_garment(sf, prefix: str) -> _RestGarment:
    names = ("rest_vertices", "faces", "uvs", "uv_faces")
    parts = {n: np.array(sf.stored(f"{prefix}/{n}")) for n in names}
    fl = f"{prefix}/face_layers"
    layers = np.array(sf.stored(fl)) if sf.has_stored(fl) else np.ones(len(parts["faces"]), np.float32)
    return _RestGarment(face_layers=layers, **parts)


def derive_config(sf):
    """The ``DeriveConfig`` of a sequence file (its ``derive`` metadata), None without one."""
    from sim.datasets.config import DeriveConfig

    if DERIVE_META not in sf.metadata:
        return None
    d = json.loads(sf.metadata[DERIVE_META])
    return DeriveConfig(smoothing_length=float(d["smoothing_length"]),
                        image_resolution=int(d["image_resolution"]), coarse=bool(d.get("coarse", False)))


def derivable(sf) -> tuple[str, ...]:
    """The derived keys a sequence file gives (none stored: all of them can be derived)."""
    cfg = derive_config(sf)
    if cfg is None or not sf.has("fine/vertices"):
        return ()
    keys = list(FINE_DERIVED)
    if cfg.image_resolution:
        keys += IMAGE_KEYS
    if sf.has("coarse/vertices") and sf.has_stored("coarse/faces"):
        keys.append("coarse/strain_norm")
    return tuple(k for k in keys if not sf.has_stored(k))


def derived_shape(sf, key: str) -> tuple[int, ...]:
    """The shape of derived field ``key`` of ``sf``, without deriving it."""
    T, V = sf.shape("fine/vertices")[:2]
    F, U = sf.shape("fine/faces")[0], sf.shape("fine/uvs")[0]
    res = derive_config(sf).image_resolution
    channels = {"images/strain_norm": 1, "images/wrinkle": 3, "images/normal_world": 3,
                "images/normal_tangent": 3}
    shapes = {"fine/base": (T, V, 3), "fine/normals": (T, V, 3), "fine/wrinkle": (T, U, 3),
              "fine/strain": (T, F, 3), "fine/strain_norm": (T, F), "images/mask": (res, res),
              **{k: (T, res, res, c) for k, c in channels.items()}}
    if key == "coarse/strain_norm":
        return (sf.shape("coarse/vertices")[0], sf.shape("coarse/faces")[0])
    return shapes[key]


def derive_fields(sf, *, device: str | None = None) -> dict[str, np.ndarray]:
    """Every field of ``derivable(sf)``, computed from the file's stored arrays."""
    from sim.datasets.derive import Deriver, coarse_arrays

    keys = derivable(sf)
    out: dict[str, np.ndarray] = {}
    if any(k in keys for k in (*FINE_DERIVED, *IMAGE_KEYS)):
        fine = np.asarray(sf["fine/vertices"], np.float32)
        out.update(Deriver(_rest_garment(sf, "fine"), derive_config(sf), device=device)(fine))
    if "coarse/strain_norm" in keys:
        coarse = np.asarray(sf["coarse/vertices"], np.float32)
        out.update(coarse_arrays(_rest_garment(sf, "coarse"), coarse, device=device))
    return {k: np.ascontiguousarray(out[k]) for k in keys}


def data_digest(sf) -> str:
    """sha256 of the stored arrays' bytes (the file without its header): the ``data_sha256``
    metadata entry the writer records, or computed from the file for one without it."""
    if "data_sha256" in sf.metadata:
        return sf.metadata["data_sha256"]
    h = hashlib.sha256()
    with open(sf.path, "rb") as f:
        f.seek(sf.data_offset)
        for chunk in iter(lambda: f.read(1 << 22), b""):
            h.update(chunk)
    return h.hexdigest()


def user_cache_dir() -> Path:
    """The user's cache folder: ``$WRINKLES_CACHE``, default ``~/.cache/wrinkles``."""
    return Path(os.environ.get("WRINKLES_CACHE") or Path.home() / ".cache" / "wrinkles")


def local_derived_dir(sf) -> Path | None:
    """``DIR/derived`` beside the ``sequences/`` folder of sequence file ``sf`` when the dataset
    is writable there, else None (a read-only dataset: derived files go to the user's cache)."""
    folder = sf.path.parent
    root = folder.parent if folder.name == "sequences" else folder
    local = root / DERIVED_DIR
    return local if os.access(local if local.exists() else root, os.W_OK) else None


def cache_path(sf) -> Path:
    """Where the derived fields of sequence file ``sf`` are kept: ``DIR/derived/<id>`` beside a
    dataset's ``sequences/`` folder when it is writable, else under ``$WRINKLES_CACHE/derived``
    (default ``~/.cache/wrinkles``) by data checksum."""
    from sim.datasets.storage import SUFFIX

    local = local_derived_dir(sf)
    if local is not None:
        return local / sf.path.name
    return user_cache_dir() / DERIVED_DIR / f"{_cache_key(sf)['key']}{SUFFIX}"


def _cache_key(sf) -> dict[str, str]:
    """What a current cache file of ``sf`` records: the data checksum, the derivation settings,
    the version, and their digest (``key``)."""
    record = {"source": data_digest(sf), "derive": sf.metadata.get(DERIVE_META, ""),
              "version": str(DERIVE_VERSION)}
    return {**record, "key": hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()[:32]}


def cached_fields(sf, *, device: str | None = None):
    """The ``SequenceFile`` of ``sf``'s derived fields, derived and written first where the
    cache has no current one (several processes may derive the same sequence at once: each
    writes its file atomically, and the last one stays)."""
    cached = _cached(sf)
    return cached if cached is not None else _derive_into_cache(sf, device)


def _derive_into_cache(sf, device: str | None):
    """Derive ``sf``'s fields on ``device`` and write them to its cache file; that file opened."""
    from sim.datasets.storage import SequenceFile, write_sequence
    from sim.device import resolve_device

    path = cache_path(sf)
    arrays = derive_fields(sf, device=device)
    path.parent.mkdir(parents=True, exist_ok=True)
    kind = "cuda" if resolve_device(device).startswith("cuda") else "cpu"
    write_sequence(path, arrays, {**_cache_key(sf), "device": kind})
    return SequenceFile(path)


def derive_dataset(root: str | os.PathLike, *, device: str | None = None, split: str | None = None,
                   progress=None) -> tuple[int, int]:
    """Fill the cache of derived fields of every sequence of the dataset at ``root`` (of one
    ``split``: None, all), each sequence's fields derived once. ``progress(done, total)`` after
    each. Returns ``(derived now, current already)`` (files with nothing to derive in neither)."""
    from sim.datasets.storage import SequenceFile, read_manifest

    root = Path(root)
    entries = [e for _, e in sorted(read_manifest(root)["sequences"].items())
               if split is None or e.get("split") == split]
    made = current = 0
    for k, e in enumerate(entries):
        sf = SequenceFile(root / e["file"])
        if derivable(sf):  # (a schema 1 file stores every field: nothing to derive)
            if _cached(sf) is None:
                _derive_into_cache(sf, device)
                made += 1
            else:
                current += 1
        if progress is not None:
            progress(k + 1, len(entries))
    return made, current


def _cached(sf):
    """The cache file of ``sf``'s current derived fields, opened; None where there is none."""
    from sim.datasets.storage import SequenceFile

    path = cache_path(sf)
    if not path.exists():
        return None
    try:
        cached = SequenceFile(path)
    except WrinklesInputError:  # an unreadable cache file is derived again
        return None
    current = (cached.metadata.get("key") == _cache_key(sf)["key"]
               and all(cached.has_stored(k) for k in derivable(sf)))
    return cached if current else None
