"""What bounds one colour launch of the t-shirt's solve (CUDA): the launch itself, a grid-wide
barrier (the persistent-kernel alternative to one launch per colour), and the reductions that
give each particle its 3x3 system from its lanes.

Every figure is the time per launch of a CUDA graph of ``--rounds`` dependent launches of a tiled
kernel of the solve's size (``--blocks`` blocks of 8 particles x 16 lanes), except the barrier:
one persistent kernel of ``--rounds`` rounds (a write per block, a barrier, a check of another
block's write: errors must be 0, a second barrier), its time per barrier.

    python -m benchmarks.solve_floor --rounds 2000 --tag _s30
"""

from __future__ import annotations

import argparse
import ctypes
import time

import warp as wp

from benchmarks.common import machine, write_result

P, L = 8, 16  # the single t-shirt's solve layout: particles per block x lanes per particle
BLOCK = P * L

# the barrier of CUDA cooperative groups (grid.sync()); needs every block resident at once
_BARRIER = r"""
#if defined(__CUDA_ARCH__)
    __syncthreads();
    if (threadIdx.x == 0) {
        int* c = counter.data;
        volatile int* generation = (volatile int*)(c + 1);
        const int g = *generation;
        __threadfence();
        if (atomicAdd(c, 1) == blocks - 1) {
            c[0] = 0;
            __threadfence();
            atomicAdd(c + 1, 1);
        } else {
            while (*generation == g) {
            }
        }
        __threadfence();
    }
    __syncthreads();
#endif
"""


@wp.func_native(_BARRIER)
def grid_barrier(counter: wp.array(dtype=wp.int32), blocks: int): ...


_SHFL3 = r"""
#if defined(__CUDA_ARCH__)
    for (int o = 8; o > 0; o >>= 1)
        for (int k = 0; k < 3; ++k) v.c[k] += __shfl_xor_sync(0xffffffffu, v.c[k], o);
#endif
    return v;
"""
_SHFL33 = r"""
#if defined(__CUDA_ARCH__)
    for (int o = 8; o > 0; o >>= 1)
        for (int r = 0; r < 3; ++r)
            for (int k = 0; k < 3; ++k) m.data[r][k] += __shfl_xor_sync(0xffffffffu, m.data[r][k], o);
#endif
    return m;
"""


@wp.func_native(_SHFL3)
def shfl_sum3(v: wp.vec3) -> wp.vec3: ...


@wp.func_native(_SHFL33)
def shfl_sum33(m: wp.mat33) -> wp.mat33: ...


@wp.kernel(enable_backward=False)
def barrier_rounds(rounds: int, blocks: int, counter: wp.array(dtype=wp.int32),
                   values: wp.array(dtype=wp.int32), errors: wp.array(dtype=wp.int32)):
    b, t = wp.tid()
    for r in range(rounds):
        if t == 0:
            values[b] = r * blocks + b
        grid_barrier(counter, blocks)
        if t == 0:
            o = (b + 1 + r) % blocks
            if values[o] != r * blocks + o:
                wp.atomic_add(errors, 0, 1)
        grid_barrier(counter, blocks)


@wp.kernel(enable_backward=False)
def empty_tiled(x: wp.array(dtype=wp.vec3)):
    b, t = wp.tid()
    if t == 0 and b == 0:
        x[0] = x[0] + wp.vec3(1.0)


@wp.kernel(enable_backward=False)
def tile_reduce(x: wp.array(dtype=wp.vec3)):
    """The solve's reductions: a vec3 and a mat33 per thread summed over the lanes axis of a
    particles x lanes tile, each particle's sums extracted (``vbd_kernels.solve_color_kernel``)."""
    b, t = wp.tid()
    local = t // L
    xi = x[b * BLOCK + t]
    f = xi
    H = wp.outer(xi, xi)
    f_sum = wp.tile_sum(wp.tile_reshape(wp.tile(f, preserve_type=True), shape=(P, L)), axis=1)
    H_sum = wp.tile_sum(wp.tile_reshape(wp.tile(H, preserve_type=True), shape=(P, L)), axis=1)
    f = wp.tile_extract(f_sum, local)
    H = wp.tile_extract(H_sum, local)
    if t - local * L == 0:
        x[b * BLOCK + t] = f + H[0] * 1.0e-6


@wp.kernel(enable_backward=False)
def shuffle_reduce(x: wp.array(dtype=wp.vec3)):
    """The same sums by a butterfly of warp shuffles within each particle's 16 lanes."""
    b, t = wp.tid()
    local = t // L
    xi = x[b * BLOCK + t]
    f = shfl_sum3(xi)
    H = shfl_sum33(wp.outer(xi, xi))
    if t - local * L == 0:
        x[b * BLOCK + t] = f + H[0] * 1.0e-6


def resident_blocks(kernel, device, block_dim: int) -> int:
    """Blocks of ``kernel`` the device holds at once (driver occupancy x SMs)."""
    hooks = kernel.module.load(device, block_dim).get_kernel_hooks(kernel)
    per_sm = ctypes.c_int(0)
    fn = ctypes.CDLL("libcuda.so.1").cuOccupancyMaxActiveBlocksPerMultiprocessor
    fn.argtypes = [ctypes.POINTER(ctypes.c_int), ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t]
    if fn(ctypes.byref(per_sm), ctypes.c_void_p(hooks.forward), block_dim, int(hooks.forward_smem_bytes)):
        raise RuntimeError("occupancy query failed")
    return per_sm.value * device.sm_count


def graph_us(kernel, blocks: int, rounds: int, x, d) -> float:
    """µs per launch of a graph of ``rounds`` dependent launches of ``kernel`` (best of 3)."""
    wp.launch_tiled(kernel, dim=[blocks], block_dim=BLOCK, inputs=[x], device=d)
    with wp.ScopedCapture(device=d) as cap:
        for _ in range(rounds):
            wp.launch_tiled(kernel, dim=[blocks], block_dim=BLOCK, inputs=[x], device=d)
    best = float("inf")
    for _ in range(3):
        wp.synchronize_device(d)
        t0 = time.perf_counter()
        wp.capture_launch(cap.graph)
        wp.synchronize_device(d)
        best = min(best, time.perf_counter() - t0)
    return best / rounds * 1e6


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=2000)
    ap.add_argument("--blocks", type=int, default=283, help="blocks per launch (the 5k t-shirt: 187 + 96)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args(argv)
    wp.init()
    d = wp.get_device("cuda")
    resident = resident_blocks(barrier_rounds, d, BLOCK)
    counter = wp.zeros(2, dtype=wp.int32, device=d)
    values = wp.zeros(resident, dtype=wp.int32, device=d)
    errors = wp.zeros(1, dtype=wp.int32, device=d)
    out = {"resident_blocks": resident, "sm_count": d.sm_count, "blocks": args.blocks, "barrier": {}}
    for blocks in sorted({d.sm_count, 2 * d.sm_count, resident}):
        for _ in range(2):
            errors.zero_()
            wp.synchronize_device(d)
            t0 = time.perf_counter()
            wp.launch_tiled(barrier_rounds, dim=[blocks], block_dim=BLOCK,
                            inputs=[args.rounds, blocks, counter, values, errors], device=d)
            wp.synchronize_device(d)
            dt = time.perf_counter() - t0
        out["barrier"][str(blocks)] = {"us_per_barrier": dt / (2 * args.rounds) * 1e6,
                                       "errors": int(errors.numpy()[0]), "counter": counter.numpy().tolist()}
        print(f"barrier, {blocks} blocks: {out['barrier'][str(blocks)]}", flush=True)
    x = wp.full(args.blocks * BLOCK, wp.vec3(1.0e-3), dtype=wp.vec3, device=d)
    for name, kernel in (("empty", empty_tiled), ("tile_sum", tile_reduce), ("shuffle", shuffle_reduce)):
        out[f"{name}_us_per_launch"] = graph_us(kernel, args.blocks, args.rounds, x, d)
        print(f"{name}: {out[f'{name}_us_per_launch']:.2f} us per launch", flush=True)
    write_result(f"solve_floor{args.tag}", {"machine": machine("cuda"), "figures": out})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
