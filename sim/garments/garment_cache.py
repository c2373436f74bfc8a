"""Sewn garments kept on disk: sewing a design runs the cloth solver (tens of seconds for a
coarse garment on a CPU), and the same design on the same body at the same resolution is the
same garment, so it is sewn once (``cached_garment``).

Files: ``$WRINKLES_CACHE/garments/<key>.npz`` (default ``~/.cache/wrinkles``), arrays plus a
JSON header, no pickles; written to a temporary name and renamed, so an interrupted write leaves
nothing half-written. A process sewing a garment holds a lock on ``<key>.lock`` beside it (POSIX
``flock``), so processes sharing the folder (test workers, dataset shards) sew each garment once:
the others wait and read the file. ``WRINKLES_CACHE=off`` sews every time.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from sim.garments.materials import Material
from sim.garments.types import Garment

SOURCES = ("sim/garments", "sim/cloth", "sim/bodies")
"""Packages whose code makes a sewn garment (drafting, meshing, sewing, the solver, the body):
every key holds a digest of their source, so changed code never reads an older garment."""
_MEMORY: dict[str, Garment] = {}


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-256 of the ``SOURCES`` packages' Python files (paths and contents, sorted)."""
    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha256()
    for folder in SOURCES:
        for f in sorted((root / folder).rglob("*.py")):
            h.update(str(f.relative_to(root)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def cache_dir() -> Path | None:
    """The garment cache folder, None when ``WRINKLES_CACHE=off``."""
    root = os.environ.get("WRINKLES_CACHE", "")
    if root.lower() == "off":
        return None
    return (Path(root) if root else Path.home() / ".cache" / "wrinkles") / "garments"


def cache_key(spec: dict) -> str:
    """A file-name-safe digest of a JSON-able description of how a garment is made."""
    text = json.dumps({"code": source_digest(), **spec}, sort_keys=True, default=_jsonable)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _jsonable(x):
    if isinstance(x, np.ndarray):
        return [round(float(v), 9) for v in x.ravel()]
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(f"not JSON-able: {type(x).__name__}")


def save_garment(g: Garment, path: Path) -> None:
    """Write ``g`` to ``path`` (.npz, atomically)."""
    header = {"material": dataclasses.asdict(g.material), "category": g.category, "name": g.name,
              "panel_names": list(g.panel_names), "attachments": sorted(g.attachments),
              "uv_scale": g.uv_scale}
    arrays = {"rest_vertices": g.rest_vertices, "faces": g.faces, "uvs": g.uvs, "uv_faces": g.uv_faces,
              "panel_ids": g.panel_ids, "face_layers": g.face_layers,
              **{f"attachment/{k}": v for k, v in g.attachments.items()},
              "header": np.array(json.dumps(header))}
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.npz")
    os.close(fd)
    try:
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def load_cached(path: Path) -> Garment:
    """The garment ``save_garment`` wrote to ``path``."""
    with np.load(path, allow_pickle=False) as z:
        header = json.loads(str(z["header"]))
        att = {k: z[f"attachment/{k}"] for k in header["attachments"]}
        return Garment(rest_vertices=z["rest_vertices"], faces=z["faces"], uvs=z["uvs"],
                       uv_faces=z["uv_faces"], material=Material(**header["material"]), attachments=att,
                       category=header["category"], name=header["name"], panel_ids=z["panel_ids"],
                       panel_names=tuple(header["panel_names"]), face_layers=z["face_layers"],
                       uv_scale=header["uv_scale"])


@contextmanager
def _locked(path: Path | None) -> Iterator[None]:
    """Hold an exclusive lock on ``path`` with ``.lock`` for a suffix while the block runs (no
    lock without a path, without ``fcntl`` or where the folder cannot be written)."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock, at worst two processes sew the same garment
        fcntl = None
    fd = None
    if path is not None and fcntl is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path.with_suffix(".lock"), os.O_RDWR | os.O_CREAT, 0o644)
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:  # a read-only cache folder: sew without the lock
            if fd is not None:
                os.close(fd)
            fd = None
    try:
        yield
    finally:
        if fd is not None:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)


def _read(path: Path | None) -> Garment | None:
    """The garment at ``path``, None when there is none or it cannot be read."""
    if path is None or not path.is_file():
        return None
    try:
        return load_cached(path)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def cached_garment(spec: dict, build: Callable[[], Garment]) -> Garment:
    """The garment ``spec`` describes: from memory, from the cache folder, or ``build()`` (then
    kept in both). A cache file that cannot be read is rebuilt and replaced. Building holds the
    key's lock (``_locked``): another process building the same key at the same time waits for
    this one and reads its file."""
    key = cache_key(spec)
    if key in _MEMORY:
        return _MEMORY[key]
    folder = cache_dir()
    path = None if folder is None else folder / f"{key}.npz"
    g = _read(path)
    if g is None:
        with _locked(path):
            g = _read(path)  # made by another process while this one waited for the lock
            if g is None:
                g = build()
                if path is not None:
                    try:
                        save_garment(g, path)
                    except OSError:
                        pass  # a read-only home: sew again next time
    _MEMORY[key] = g
    return g
