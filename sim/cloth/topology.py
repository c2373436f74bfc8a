"""Mesh topology of a cloth instance: hinges (interior edges) and the vertex colouring of the
Gauss-Seidel sweeps (``sim.cloth.coloring``), cached per mesh, and made for a batch of new
meshes in parallel processes (``mesh_topologies``).

A colouring with fewer colours than a proper one needs (``max_colors``, the CUDA layout's 3) is a
TabuCol search that runs its whole move budget: ~5 s for a 20k-vertex garment in Python, which
made the cloth model of a batch of 16 new fine garments take 99 s on an H200 host (against 3 s
once their colourings were cached). The searches of different meshes are independent, so a
batch's run side by side on the host's cores (child processes), with the same results.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from sim.cloth.coloring import compact_coloring, vertex_adjacency, wheel_bound
from sim.memo import LRU, content_key

CACHE_SIZE = 64
"""Meshes whose topology ``mesh_topology`` keeps (least recently made dropped first)."""
PARALLEL_VERTICES = 20_000
"""A batch's new meshes are coloured in parallel processes from this many vertices in all
(below, starting the processes costs more than it saves)."""

_TOPOLOGY = LRU(CACHE_SIZE)


def build_hinges(faces: np.ndarray) -> np.ndarray:
    """Interior edges as hinges ``(o0, o1, a, b)`` (layout in ``sim.cloth.energies``).

    Edges with more than two faces (non-manifold) get no hinge.
    """
    f = faces.astype(np.int64)
    a = f.reshape(-1)
    b = np.roll(f, -1, axis=1).reshape(-1)
    o = np.roll(f, -2, axis=1).reshape(-1)
    key = np.minimum(a, b) * (int(a.max(initial=0)) + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    key_s = key[order]
    hinges = []
    start = 0
    while start < len(order):
        end = start
        while end < len(order) and key_s[end] == key_s[start]:
            end += 1
        if end - start == 2:
            h0, h1 = order[start], order[start + 1]
            hinges.append((o[h0], o[h1], a[h0], b[h0]))
        start = end
    return np.asarray(hinges, dtype=np.int32).reshape(-1, 4)


def _key(vertex_count: int, faces: np.ndarray, max_colors: int) -> str:
    return content_key(int(vertex_count), np.asarray(faces, np.int32), int(max_colors))


def _compute(vertex_count: int, faces: np.ndarray, max_colors: int) -> tuple[np.ndarray, np.ndarray]:
    hinges = build_hinges(faces)
    no_hinges = np.zeros((0, 4), np.int64)
    colors = compact_coloring(vertex_adjacency(vertex_count, faces, no_hinges), max_colors=max_colors,
                              floor=wheel_bound(vertex_count, faces))
    return hinges, colors


def mesh_topology(vertex_count: int, faces: np.ndarray, max_colors: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Hinges and vertex colouring (of the triangle edges: see ``sim.cloth.model``) of a mesh,
    cached by topology (the last ``CACHE_SIZE`` meshes): a batch of one garment pattern colours
    it once (the 5k t-shirt's compact colouring takes 0.45 s, and 1024 copies of it took longer
    than their simulation)."""
    return mesh_topologies([(vertex_count, faces)], max_colors)[0]


def mesh_topologies(meshes: Sequence[tuple[int, np.ndarray]], max_colors: int = 0) -> list[tuple]:
    """``mesh_topology`` of each ``(vertex_count, faces)``: those not cached, when they have
    ``PARALLEL_VERTICES`` or more in all, computed side by side in child processes (``python -m
    sim.cloth.topology``, one per core this process may use, at most 16: plain subprocesses, so
    this works in a daemonic Dask worker and whatever the main module is). Same results as one
    at a time."""
    keys = [_key(n, f, max_colors) for n, f in meshes]
    todo = {k: m for k, m in zip(keys, meshes, strict=True) if k not in _TOPOLOGY}
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    workers = min(len(todo), cores, 16)
    if sum(n for n, _ in todo.values()) >= PARALLEL_VERTICES and workers > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers) as pool:
            made = list(pool.map(lambda m: _in_child(*m, max_colors), todo.values()))
    else:
        made = [_compute(n, f, max_colors) for n, f in todo.values()]
    found = dict(zip(todo, made, strict=True))
    out = []
    for k in keys:
        hinges, colors = found[k] if k in found else _TOPOLOGY[k]
        out.append((hinges.copy(), colors.copy()))
    for k, v in found.items():
        _TOPOLOGY.put(k, v)
    return out


def _in_child(vertex_count: int, faces: np.ndarray, max_colors: int) -> tuple[np.ndarray, np.ndarray]:
    """``_compute`` in a child process (``python -m sim.cloth.topology IN OUT``, npz files)."""
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory(prefix="wrinkles-topology-") as tmp:
        src, dst = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        np.savez(src, vertex_count=vertex_count, faces=np.asarray(faces, np.int32), max_colors=max_colors)
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
        r = subprocess.run([sys.executable, "-m", "sim.cloth.topology", src, dst], capture_output=True,
                           env=env, check=False)
        if r.returncode != 0:
            why = r.stderr.decode(errors="replace")[-2000:]
            raise RuntimeError(f"sim.cloth.topology child failed: {why}")
        with np.load(dst, allow_pickle=False) as z:
            return z["hinges"], z["colors"]


def _serve(src: str, dst: str) -> None:
    """The child's side of ``_in_child``."""
    with np.load(src, allow_pickle=False) as z:
        hinges, colors = _compute(int(z["vertex_count"]), z["faces"], int(z["max_colors"]))
    np.savez(dst, hinges=hinges, colors=colors)


if __name__ == "__main__":
    import sys

    _serve(*sys.argv[1:3])
