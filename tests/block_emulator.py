"""CPU emulation of the coarse level's CUDA snippets (``sim.cloth.coarse.block_snippets``), for
tests without a GPU.

The snippets are C++ with CUDA's block primitives. Here each is compiled by the system's C++
compiler into a function of one thread, and a block is emulated by ``threads`` OS threads with a
barrier for ``__syncthreads`` (the whole block) and one for ``__syncwarp`` (the first 32
threads, the only ones that call it). A block that does not finish in time (threads waiting at a
barrier others never reach) or whose threads cannot all start fails the run with an error
instead of hanging it. A race that the barriers do not order shows up as a wrong or run-to-run
varying result. Compiled with
``-ffp-contract=off``: every multiply and add rounds as written, so two snippets that do the same
operations in the same order give the same floats.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

_PRELUDE = r"""
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <vector>
// set when the block does not finish in time or a thread cannot start: every barrier then lets
// threads through, the block runs to its end and run() reports the failure
static std::atomic<bool> g_failed{false};
struct Barrier {  // a generation barrier on C++20 atomic waits (futexes)
    std::atomic<int> arrived{0};
    std::atomic<long> generation{0};
    int count;
    explicit Barrier(int n) : count(n) {}
    void wait() {
        const long g = generation.load();
        if (arrived.fetch_add(1) + 1 == count) {
            arrived.store(0);
            generation.fetch_add(1);
            generation.notify_all();
            return;
        }
        while (generation.load() == g && !g_failed.load())
            generation.wait(g);
    }
    void release() {  // after g_failed: wake every waiter
        generation.fetch_add(1);
        generation.notify_all();
    }
};
namespace wp {
struct vec3 {
    float c[3];
    vec3() : c{0.0f, 0.0f, 0.0f} {}
    vec3(float a, float b, float d) : c{a, b, d} {}
};
}  // namespace wp
using std::max;
using std::min;
struct Dim { unsigned x; };
static Barrier* g_block;
static Barrier* g_warp;
#define __syncthreads() g_block->wait()
#define __syncwarp() g_warp->wait()
struct Smem { struct { float* ptr; } data; };

static void body(int kind, Dim blockDim, float* shared, const wp::vec3* rhs, const float* diag,
                 const int* inst_start, const int* inst_count, const int* inst_width,
                 const long long* inst_band, const int* order, const float* band_k, const float* factor,
                 float* factor_out, wp::vec3* dx_out, int k, int lane) {
    Smem smem{{shared}};
    if (kind == 0) {
SOLVE
    } else if (kind == 1) {
FACTOR
    } else {
SUBSTITUTE
    }
}

extern "C" int run(int kind, int threads, int instances, int capacity, int timeout_ms,
                    const wp::vec3* rhs, const float* diag, const int* inst_start, const int* inst_count,
                    const int* inst_width, const long long* inst_band, const int* order,
                    const float* band_k, float* factor, wp::vec3* dx_out) {
    g_failed = false;
    for (int k = 0; k < instances && !g_failed; ++k) {
        std::vector<float> shared(capacity, 0.0f);
        Barrier block(threads), warp(32);
        g_block = &block;
        g_warp = &warp;
        std::vector<std::thread> pool;
        // a block that has not finished in time has threads waiting at a barrier others never
        // reach: fail the run instead of hanging it
        std::mutex m;
        std::condition_variable cv;
        bool done = false;
        std::thread watchdog([&] {
            std::unique_lock<std::mutex> lock(m);
            if (!cv.wait_for(lock, std::chrono::milliseconds(timeout_ms), [&] { return done; })) {
                g_failed = true;
                block.release();
                warp.release();
            }
        });
        try {
            for (int lane = 0; lane < threads; ++lane)
                pool.emplace_back(body, kind, Dim{(unsigned)threads}, shared.data(), rhs, diag, inst_start,
                                  inst_count, inst_width, inst_band, order, band_k, factor, factor, dx_out,
                                  k, lane);
        } catch (...) {
            g_failed = true;
        }
        if (g_failed) {  // a thread did not start: the others must not wait for it
            block.release();
            warp.release();
        }
        for (auto& t : pool)
            t.join();
        {
            std::lock_guard<std::mutex> lock(m);
            done = true;
        }
        cv.notify_all();
        watchdog.join();
    }
    return g_failed ? 1 : 0;
}
"""

KINDS = {"solve": 0, "factor": 1, "substitute": 2}


FLAGS = ["-std=c++20", "-O1", "-ffp-contract=off", "-shared", "-fPIC", "-pthread"]


def _cache() -> Path:
    """This user's cache of compiled snippets (not shared: a library here is loaded and run)."""
    path = Path(tempfile.gettempdir()) / f"wrinkles_block_emulator_{os.getuid()}"
    path.mkdir(mode=0o700, exist_ok=True)
    return path


def _compile(cc: str, src: str, out: Path) -> subprocess.CompletedProcess:
    """Compile ``src`` to the library ``out`` (through a private directory, then an atomic
    rename: concurrent builds of the same source do not see each other's files)."""
    with tempfile.TemporaryDirectory(dir=_cache()) as tmp:
        cpp, lib = Path(tmp) / "snippets.cpp", Path(tmp) / "snippets.so"
        cpp.write_text(src)
        done = subprocess.run([cc, *FLAGS, str(cpp), "-o", str(lib)], capture_output=True, text=True)
        if done.returncode == 0:
            lib.replace(out)
        return done


@functools.cache
def compiler() -> str | None:
    """The C++ compiler the emulation uses: g++ or clang++ where it builds the emulation's
    barrier (C++20 flags); None where there is none."""
    for name in ("g++", "clang++"):
        cc = shutil.which(name)
        probe = _PRELUDE.split("namespace wp")[0]
        if cc and _compile(cc, probe, _cache() / f"probe_{name}.so").returncode == 0:
            return cc
    return None


def build(snippets: dict[str, str]) -> ctypes.CDLL:
    """Compile ``snippets`` (``solve`` / ``factor`` / ``substitute`` texts) into one library,
    cached by source, compiler and flags."""
    cc = compiler()
    if cc is None:
        raise RuntimeError("no C++20 compiler (g++ or clang++) for the block emulation")
    src = _PRELUDE
    for name in ("solve", "factor", "substitute"):
        src = src.replace(name.upper(), snippets[name], 1)
    digest = hashlib.sha1("\0".join([src, cc, *FLAGS]).encode()).hexdigest()[:16]
    out = _cache() / f"snippets_{digest}.so"
    if not out.exists():
        done = _compile(cc, src, out)
        if done.returncode != 0:
            raise RuntimeError(f"block emulation: {cc} failed: {done.stderr.strip()[-2000:]}")
    return ctypes.CDLL(str(out))


def _ptr(a: np.ndarray) -> ctypes.c_void_p:
    return ctypes.c_void_p(a.ctypes.data)


def run(lib: ctypes.CDLL, kind: str, threads: int, capacity: int, system: dict,
        factor: np.ndarray | None = None, timeout: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    """Run snippet ``kind`` over every instance of ``system`` (``band_system``'s arrays) with
    blocks of ``threads``; returns ``(dx, factor)`` (the solution per node, and the factor
    buffer: written by ``factor``, read by ``substitute``). A block not done in ``timeout`` [s]
    raises ``RuntimeError``."""
    nodes = len(system["diag"])
    dx = np.zeros((nodes, 3), np.float32)
    fac = np.zeros_like(system["band"]) if factor is None else np.ascontiguousarray(factor, np.float32)
    arrays = [np.ascontiguousarray(system[k]) for k in
              ("rhs", "diag", "start", "count", "width", "band_start", "order", "band")]
    failed = lib.run(ctypes.c_int(KINDS[kind]), ctypes.c_int(threads), ctypes.c_int(len(system["count"])),
                     ctypes.c_int(capacity), ctypes.c_int(int(timeout * 1000)), *(_ptr(a) for a in arrays),
                     _ptr(fac), _ptr(dx))
    if failed:
        raise RuntimeError(f"block emulation of {kind!r}: a barrier timed out (some threads never reach "
                           "it) or a thread could not start")
    return dx, fac


def band_system(sizes: list[tuple[int, int]], seed: int = 0) -> dict:
    """Random symmetric positive definite band systems, one per ``(nodes, width)``, in the
    layout of ``sim.cloth.coarse`` (row ``r`` of an instance's band holds ``A[r, r - t]`` at
    ``t = 0 .. width``, the diagonal taken from ``diag``; rows in ``order``), with vec3 right-hand
    sides; ``dense`` holds each instance's matrix in row order."""
    rng = np.random.default_rng(seed)
    starts, bands, band_starts, diag, rhs, order, dense = [], [], [], [], [], [], []
    node0 = band0 = 0
    for n, b in sizes:
        w = b + 1
        a = np.zeros((n, n))
        for t in range(1, min(b, n - 1) + 1):
            off = rng.uniform(-1.0, 0.0, n - t) * (rng.random(n - t) < 0.7)
            a[np.arange(t, n), np.arange(n - t)] = off
            a[np.arange(n - t), np.arange(t, n)] = off
        a[np.arange(n), np.arange(n)] = np.abs(a).sum(1) + rng.uniform(0.05, 1.0, n)
        a = a.astype(np.float32).astype(np.float64)
        band = np.zeros((n, w), np.float32)
        for t in range(min(w, n)):
            band[t:, t] = a[np.arange(t, n), np.arange(n - t)]
        perm = rng.permutation(n)  # band row r is node perm[r]
        d = np.zeros(n, np.float32)
        d[perm] = band[:, 0]
        band[:, 0] = rng.uniform(-5, 5, n)  # the band's diagonal is not read: diag is
        r = rng.standard_normal((n, 3)).astype(np.float32)
        starts.append(node0)
        band_starts.append(band0)
        bands.append(band.ravel())
        diag.append(d)
        rhs.append(r)
        order.append(perm)  # local: the snippets read start + order[start + r]
        dense.append(a)
        node0 += n
        band0 += n * w
    return {"start": np.array(starts, np.int32), "count": np.array([s[0] for s in sizes], np.int32),
            "width": np.array([s[1] for s in sizes], np.int32), "band_start": np.array(band_starts, np.int64),
            "band": np.concatenate(bands), "diag": np.concatenate(diag), "rhs": np.concatenate(rhs),
            "order": np.concatenate(order).astype(np.int32), "dense": dense}
