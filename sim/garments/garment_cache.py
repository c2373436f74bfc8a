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

import contextlib
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

SOURCES = ("sim/garments", "sim/cloth", "sim/bodies", "sim/quality.py", "sim/quality_kernels.py")
"""Packages and modules whose code makes a sewn garment (drafting, meshing, sewing, the solver,
the body, the self-crossing test that decides a second settle): every key holds a digest of their
source, so changed code never reads an older garment."""
_MEMORY: dict[str, Garment] = {}


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-256 of the ``SOURCES`` Python files (a package's, sorted; paths and contents)."""
    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha256()
    for source in SOURCES:
        path = root / source
        for f in [path] if path.suffix == ".py" else sorted(path.rglob("*.py")):
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
def locked(path: Path | None) -> Iterator[None]:
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
    kept in both); ``cached_garments`` of one."""
    return cached_garments([spec], lambda todo: [build()])[0]


def cached_garments(specs: list[dict], build: Callable[[list[int]], list[Garment]]) -> list[Garment]:
    """The garments ``specs`` describe, each from memory or from the cache folder, and those in
    neither made by one call ``build(indices into specs)`` (a batch: ``sew_patterns``), then
    kept in both. Equal specs are built once. A cache file that cannot be read is rebuilt and
    replaced. Building holds the locks of the keys it builds (``locked``, taken in key order):
    another process building one of them at the same time waits and reads its file."""
    keys = [cache_key(s) for s in specs]
    folder = cache_dir()
    paths = {k: None if folder is None else folder / f"{k}.npz" for k in keys}

    def look(k: str) -> Garment | None:
        if k not in _MEMORY and (g := _read(paths[k])) is not None:
            _MEMORY[k] = g
        return _MEMORY.get(k)

    todo = sorted({k for k in keys if look(k) is None})
    if todo:
        with contextlib.ExitStack() as stack:
            for k in todo:
                stack.enter_context(locked(paths[k]))
            todo = [k for k in todo if look(k) is None]  # made by another process meanwhile
            for k, g in zip(todo, build([keys.index(k) for k in todo]) if todo else [], strict=True):
                _MEMORY[k] = g
                if paths[k] is not None:
                    try:
                        save_garment(g, paths[k])
                    except OSError:
                        pass  # a read-only home: sew again next time
    return [_MEMORY[k] for k in keys]
