"""How fast do a batch's sweeps go if contact costs nothing? (issue 3's batched target:
>= 20,000 garment-frames/s at 5k vertices.)

N copies of the 5k t-shirt in one ``ClothModel`` (the job's CUDA colouring, ``CUDA_COLORS``),
each figure timed as a CUDA graph of one 30 fps frame, replayed:

- ``sweeps``: the VBD sweeps of a frame (``substeps`` x ``iterations`` x colours launches) with
  the job's own energies and nothing else: each particle gathers the damped co-rotated membrane
  (``vbd_kernels.membrane_force_hessian``, with the solver's Jacobi scale where a corner shares
  its colour) and the damped hinge bending (``energies.bending_damped_vertex_force_hessian``) of
  its triangles and hinges, adds inertia and takes the 3x3 Newton step. No body contact, no
  self-contact (no detection, no pair terms, no bounds), no coarse correction, no forward /
  velocity kernels. Layouts (``--layouts``): one thread per particle (``threads``), blocks of
  particles x lanes with a tile reduction (``32x4``, ...), and ``job``: the job's own solve
  kernel (``SolverVBD.sweep``: its layout, raw loads, fast math, register cap) with contact
  off; ``block256``: one block (of 256 threads) per garment, its positions in shared memory,
  the colours separated by block barriers, one launch per substep (``floor_block_kernel``).
  All but ``job`` read a same-coloured neighbour live where the job reads its snapshot: the
  same work, a slightly different step. ``sweeps`` is the fastest layout. These are measured
  kernels, so they bound what this code reaches, not what any kernel could.
- ``stream``: the bandwidth roofline of those sweeps: the bytes of every array the sweep reads
  (each once) plus the positions it writes, per sweep, at the copy bandwidth measured in the
  same run (the better of ``wp.copy`` and a copy kernel, 1 GiB); ``stream_shared`` the same with
  the topology counted once for all copies (``FloorScene.sweep_bytes_shared``).
- ``launch``: the frame's launches with empty kernels (the graph's per-launch floor).

It prints and writes ``batch_floor_<device><tag>.json``: per batch size the figures in ms per
batched frame, their garment-frames/s, and ns per particle per sweep.

    python -m benchmarks.batch_floor --device cuda --batch 1,16,128,1024 --tag _s53
    python -m benchmarks.batch_floor --device cpu --batch 1 --vertices 1000 --rounds 2   # CPU check
"""

from __future__ import annotations

import argparse
import functools
import time
from typing import Any

import numpy as np
import warp as wp

from benchmarks.common import machine, timed_ms, write_result
from sim.cloth.energies import bending_damped_vertex_force_hessian
from sim.cloth.vbd_kernels import MEMBRANE_COROTATED, jacobi_scale, membrane_force_hessian

TARGET = 20_000.0
"""Issue 3's batched target [garment-frames/s]."""


@wp.struct
class FloorArrays:
    """What a contact-free sweep reads besides ``x``: the substep's inertial target, the
    model's per-particle, per-triangle and per-hinge data and the vertex adjacencies."""

    color_vertices: wp.array(dtype=wp.int32)
    y: wp.array(dtype=wp.vec3)
    mass: wp.array(dtype=float)
    tri_indices: wp.array(dtype=wp.vec3i)
    tri_dm_inv: wp.array(dtype=wp.mat22)
    tri_area: wp.array(dtype=float)
    tri_mu: wp.array(dtype=float)
    tri_lam: wp.array(dtype=float)
    tri_damping: wp.array(dtype=float)
    tri_strain_prev: wp.array(dtype=wp.vec3)
    edge_indices: wp.array(dtype=wp.vec4i)
    edge_rest_angle: wp.array(dtype=float)
    edge_stiffness: wp.array(dtype=float)
    edge_damping: wp.array(dtype=float)
    edge_angle_prev: wp.array(dtype=float)
    vertex_tri_offsets: wp.array(dtype=wp.int32)
    vertex_tri_ids: wp.array(dtype=wp.int32)
    vertex_tri_local: wp.array(dtype=wp.int32)
    vertex_edge_offsets: wp.array(dtype=wp.int32)
    vertex_edge_ids: wp.array(dtype=wp.int32)
    vertex_edge_local: wp.array(dtype=wp.int32)


FLOOR_ARRAYS = tuple(FloorArrays.vars)
TERMS = ("all", "membrane", "bending", "inertia")
"""What a sweep may be timed with (``FloorScene.without``, ``--terms``)."""
TOPOLOGY_ARRAYS = ("color_vertices", "tri_indices", "edge_indices", "vertex_tri_offsets", "vertex_tri_ids",
                   "vertex_tri_local", "vertex_edge_offsets", "vertex_edge_ids", "vertex_edge_local")
"""The ``FloorArrays`` that copies of one mesh share (``FloorScene.sweep_bytes_shared``)."""


@wp.func
def floor_gather(i: int, share: int, stride: int, a: FloorArrays, x: Any, base: int, inv_h: float):
    """Items ``share, share + stride, ...`` of particle ``i``'s triangles and hinges: their damped
    co-rotated membrane and damped bending force on it and Hessian blocks (the job's energies).
    Particle ``p``'s position is ``x[p - base]``: ``x`` the model's positions (``base`` 0) or one
    instance's in a shared-memory tile (``base`` its first particle)."""
    f = wp.vec3(0.0)
    H = wp.mat33(0.0)
    for k in range(a.vertex_tri_offsets[i] + share, a.vertex_tri_offsets[i + 1], stride):
        t = a.vertex_tri_ids[k]
        tri = a.tri_indices[t]
        packed = a.vertex_tri_local[k]
        fe, he = membrane_force_hessian(MEMBRANE_COROTATED, x[tri[0] - base], x[tri[1] - base],
                                        x[tri[2] - base], a.tri_dm_inv[t], a.tri_area[t], a.tri_mu[t],
                                        a.tri_lam[t], a.tri_strain_prev[t], a.tri_damping[t] * inv_h,
                                        packed & 3)
        f = f + fe
        H = H + he * jacobi_scale(packed)
    for k in range(a.vertex_edge_offsets[i] + share, a.vertex_edge_offsets[i + 1], stride):
        e = a.vertex_edge_ids[k]
        q = a.edge_indices[e]
        fb, hb = bending_damped_vertex_force_hessian(x[q[0] - base], x[q[1] - base], x[q[2] - base],
                                                     x[q[3] - base], a.edge_rest_angle[e],
                                                     a.edge_stiffness[e], a.edge_angle_prev[e],
                                                     a.edge_damping[e] * inv_h, a.vertex_edge_local[k] & 3)
        f = f + fb
        H = H + hb
    return f, H


@wp.func
def floor_newton_step(i: int, xi: wp.vec3, f: wp.vec3, H: wp.mat33, a: FloorArrays, inv_h: float) -> wp.vec3:
    """Particle ``i``'s new position: inertia added to its gathered system at ``xi``, then the
    Newton step ``xi + H^-1 f``."""
    mh = a.mass[i] * inv_h * inv_h
    f = f + mh * (a.y[i] - xi)
    H = H + mh * wp.identity(n=3, dtype=float)
    if wp.abs(wp.determinant(H)) > 1.0e-20:
        return xi + wp.inverse(H) * f
    return xi


def _floor_kernel(fn, name: str, fast_math: bool):
    """``fn`` as a kernel of its own module, named ``name`` (``_fm`` added with fast math: CUDA's
    approximate division and square roots, denormals flushed, as the job's solve kernel is
    built, ``VBDConfig.fast_math``; the CPU is unaffected)."""
    fn.__name__ = fn.__qualname__ = name + ("_fm" if fast_math else "")
    options = {"module_options": {"fast_math": True}} if fast_math else {}
    return wp.kernel(fn, enable_backward=False, module="unique", **options)


@functools.cache
def floor_sweep_kernel(fast_math: bool = False):
    """One colour of a contact-free VBD sweep, one thread per particle: particle
    ``color_vertices[begin + tid]`` takes the Newton step ``x += H^-1 f`` of the substep's
    incremental potential (inertia, damped co-rotated membrane, damped bending) in place."""

    def sweep(begin: int, a: FloorArrays, x: wp.array(dtype=wp.vec3), h: float):
        i = a.color_vertices[begin + wp.tid()]
        f, H = floor_gather(i, 0, 1, a, x, 0, 1.0 / h)
        x[i] = floor_newton_step(i, x[i], f, H, a, 1.0 / h)

    return _floor_kernel(sweep, "floor_sweep_kernel", fast_math)


@functools.cache
def floor_lanes_kernel(particles: int, lanes: int, fast_math: bool = False):
    """The same colour sweep as ``floor_sweep_kernel`` in the solver's batched layout: blocks of
    ``particles`` x ``lanes`` threads, each lane a share of its particle's triangles and hinges,
    summed over the lanes by a tile reduction, lane 0 taking the step. Launch with
    ``wp.launch_tiled(kernel, dim=[ceil(count / particles)], block_dim=particles * lanes)``
    (on the CPU 1 x 1)."""
    P, L = int(particles), int(lanes)

    def sweep(count: int, begin: int, a: FloorArrays, x: wp.array(dtype=wp.vec3), h: float):
        block, thread = wp.tid()
        local = thread // wp.static(L)
        lane = thread - local * wp.static(L)
        slot = block * wp.static(P) + local
        i = int(-1)
        f = wp.vec3(0.0)
        H = wp.mat33(0.0)
        if slot < count:
            i = a.color_vertices[begin + slot]
            f, H = floor_gather(i, lane, wp.static(L), a, x, 0, 1.0 / h)
        shape = (wp.static(P), wp.static(L))
        f_sum = wp.tile_sum(wp.tile_reshape(wp.tile(f, preserve_type=True), shape=shape), axis=1)
        H_sum = wp.tile_sum(wp.tile_reshape(wp.tile(H, preserve_type=True), shape=shape), axis=1)
        if lane == 0 and i >= 0:
            x[i] = floor_newton_step(i, x[i], wp.tile_extract(f_sum, local), wp.tile_extract(H_sum, local), a,
                                     1.0 / h)

    return _floor_kernel(sweep, f"floor_sweep_p{P}_l{L}", fast_math)


_BARRIER = r"""
#if defined(__CUDA_ARCH__)
    __syncthreads();
#endif
"""


@wp.func_native(_BARRIER)
def block_barrier(): ...


@functools.cache
def floor_block_kernel(max_vertices: int, fast_math: bool = False):
    """The contact-free sweeps of one substep with **one block per instance** (a garment): the
    block copies its instance's positions into a shared-memory tile of ``max_vertices`` (a
    compile-time size larger than every instance: 12 B each, 60 KB for the 5k t-shirt; Warp opts
    the kernel into more than 48 KB of shared memory), runs ``sweeps`` sweeps of every
    colour with block barriers between colours instead of launches, the threads striding over
    the colour's particles of this instance, each gathering from the tile, and writes the
    positions back. Launch with ``wp.launch_tiled(kernel, dim=[instances], block_dim=threads)``
    (on the CPU 1). The same step as ``floor_sweep_kernel`` swept colour by colour."""
    V = int(max_vertices)

    def sweeps(sweeps: int, colors: int, starts: wp.array(dtype=wp.int32), runs: wp.array(dtype=wp.vec2i),
               a: FloorArrays, x: wp.array(dtype=wp.vec3), h: float):
        b, t = wp.tid()
        nt = wp.block_dim()
        inv_h = 1.0 / h
        start = starts[b]
        n = starts[b + 1] - start
        spare = wp.static(V - 1)  # V > every instance's size: a slot nobody reads
        s = wp.tile_zeros(shape=wp.static(V), dtype=wp.vec3, storage="shared")
        # every thread runs every round of these loops: an element store into a shared tile ends
        # in a block barrier (Warp's tile_element_assign), so a thread out of work stores to the
        # spare slot instead of skipping it
        for base in range(0, n, nt):
            k = base + t
            value = wp.vec3(0.0)
            if k < n:
                value = x[start + k]
            s[wp.where(k < n, k, spare)] = value
        for _sweep in range(sweeps):
            for c in range(colors):
                run = runs[b * colors + c]  # this instance's particles of colour c in color_vertices
                for base in range(run[0], run[0] + run[1], nt):
                    j = base + t
                    slot = int(spare)
                    value = wp.vec3(0.0)
                    if j < run[0] + run[1]:
                        i = a.color_vertices[j]
                        f, H = floor_gather(i, 0, 1, a, s, start, inv_h)
                        slot = i - start
                        value = floor_newton_step(i, s[slot], f, H, a, inv_h)
                    s[slot] = value
                block_barrier()
        for k in range(t, n, nt):  # reads only: no barrier inside
            x[start + k] = s[k]

    return _floor_kernel(sweeps, f"floor_block_v{V}", fast_math)


@wp.kernel(enable_backward=False)
def empty_kernel(x: wp.array(dtype=wp.vec3)):
    wp.tid()


class FloorScene:
    """The arrays of one substep of ``model`` (a ``ClothModel``) of length ``h`` [s] from a
    fresh state, as ``SolverVBD.step`` sets them up: the substep starts at ``model.particle_q``
    at zero velocity; the inertial target is ``y = x + h^2 g``, which is also the sweeps' first
    guess (a fresh ``ClothState`` is falling: the adaptive guess is ``y``); the strain-rate
    damping's reference (strain and hinge angles) is taken at the substep's start."""

    def __init__(self, model, h: float, fast_math: bool = False):
        from sim.cloth.vbd_kernels import previous_deformation_kernel

        m = model
        d = m.device
        self.model = m
        self.h = float(h)
        self.fast_math = bool(fast_math)  # the plain and block kernels built with fast math
        x0 = m.particle_q.numpy()
        start = wp.array(x0, dtype=wp.vec3, device=d)
        g = np.asarray(m.gravity, np.float32)
        self.y = wp.array(x0 + (self.h * self.h) * g[None, :], dtype=wp.vec3, device=d)
        self.x = wp.clone(self.y)
        self.strain_prev = wp.zeros(m.tri_count, dtype=wp.vec3, device=d)
        self.angle_prev = wp.zeros(m.edge_count, dtype=float, device=d)
        wp.launch(previous_deformation_kernel, dim=m.tri_count + m.edge_count,
                  inputs=[start, m.tri_indices, m.tri_dm_inv, m.edge_indices, m.tri_count],
                  outputs=[self.strain_prev, self.angle_prev], device=d)
        self.colors = [(m.color_offsets[c], m.color_offsets[c + 1] - m.color_offsets[c])
                       for c in range(m.color_count)]
        own = {"y": self.y, "mass": m.particle_mass, "tri_strain_prev": self.strain_prev,
               "edge_angle_prev": self.angle_prev}
        self.arrays = FloorArrays()  # what every sweep kernel reads
        for name in FLOOR_ARRAYS:
            setattr(self.arrays, name, own[name] if name in own else getattr(m, name))
        self._jobs: dict[str, list] = {}  # job_solver's, by layout name: [solver, state, parity]
        self._runs = None  # block_sweeps' per-instance colour runs, built on first use

    @classmethod
    def tshirts(cls, garment, copies: int, device: str, substeps: int, max_colors: int,
                fast_math: bool = False) -> FloorScene:
        """``copies`` of ``garment`` at its rest shape in one model, as ``simulate_batch`` adds
        them (hems included), for a substep of a 30 fps frame of ``substeps``."""
        from sim.cloth.model import ClothModelBuilder

        b = ClothModelBuilder(max_colors=max_colors)
        for _ in range(copies):
            b.add_cloth(garment.rest_vertices, garment.faces, garment.material,
                        face_layers=garment.face_layers)
        return cls(b.finalize(device), 1.0 / (30.0 * substeps), fast_math)

    def job_solver(self, layout: str = "job"):
        """The job's own ``SolverVBD`` on this model with contact off (no bodies, no
        self-contact, no coarse correction, no air damping), its substep buffers set up by one
        step of length ``h`` from the model's positions: ``job_sweep`` then runs the job's solve
        kernel (its layout, raw loads and register cap) on them. ``layout`` "job:KEY=V+KEY=V"
        changes those ``VBDConfig`` fields (``job_overrides``), e.g. "job:max_registers=0"."""
        if layout not in self._jobs:
            import dataclasses

            from sim.cloth import SolverVBD
            from sim.simulate import SimulationConfig

            m = self.model
            cuda = wp.get_device(m.device).is_cuda
            # the job's solver settings (fast math, register cap, lanes, colours) without contact
            vertices = m.particle_count // m.instance_count
            job = SimulationConfig(device=m.device).vbd_config(vertices, cuda=cuda)
            cfg = dataclasses.replace(job, substeps=1, iterations=1, air_damping=0.0, self_contact=False,
                                      coarse_sweeps=(), coarse_prefactor=False, coarse_early=False,
                                      **job_overrides(layout))
            solver = SolverVBD(m, cfg)
            state = m.state()
            solver.step(state, state, m.control(), self.h)
            self._jobs[layout] = [solver, state, 0]
        return self._jobs[layout][:2]

    def job_sweep(self, layout: str = "job") -> None:
        """One more sweep of the job's solve kernel (``SolverVBD.sweep``) on the substep that
        ``job_solver`` set up: the sweeps alternate the solver's two snapshots as a substep's do,
        the first after the set-up step's one sweep reading snapshot 1. (A CUDA graph of an even
        number of them replays in step with its snapshots.)"""
        solver, state = self.job_solver(layout)
        entry = self._jobs[layout]
        entry[2] = 1 - entry[2]
        eps_u = solver.config.friction_epsilon * self.h
        solver.sweep(state.positions, solver._sc_data, eps_u, self.h, entry[2])

    def block_sweeps(self, threads: int, sweeps: int) -> None:
        """``sweeps`` sweeps in one launch of ``floor_block_kernel``: a block of ``threads`` per
        instance (one thread on the CPU)."""
        m = self.model
        if self._runs is None:
            starts = np.asarray(m.instance_starts, np.int64)
            cv = m.color_vertices.numpy()
            runs = np.zeros((m.instance_count, m.color_count, 2), np.int32)
            for c in range(m.color_count):  # each colour's list ascends, so instances are runs in it
                lo, hi = m.color_offsets[c], m.color_offsets[c + 1]
                first = np.searchsorted(cv[lo:hi], starts[:-1])
                runs[:, c, 0] = lo + first
                runs[:, c, 1] = np.searchsorted(cv[lo:hi], starts[1:]) - first
            self._runs = (wp.array(starts.astype(np.int32), dtype=wp.int32, device=m.device),
                          wp.array(runs.reshape(-1, 2), dtype=wp.vec2i, device=m.device),
                          -(-(int(np.diff(starts).max()) + 1) // 32) * 32)  # a spare slot
        starts_wp, runs_wp, max_vertices = self._runs
        cuda = wp.get_device(m.device).is_cuda
        wp.launch_tiled(floor_block_kernel(max_vertices, self.fast_math), dim=[m.instance_count],
                        block_dim=threads if cuda else 1,
                        inputs=[sweeps, m.color_count, starts_wp, runs_wp, self.arrays, self.x, self.h],
                        device=m.device)

    def sweep(self, layout: tuple[int, int] | None = None, arrays: FloorArrays | None = None) -> None:
        """One sweep: every colour in turn, one thread per particle (``layout`` None) or in
        blocks of ``layout`` = (particles, lanes) (``floor_lanes_kernel``), on ``arrays`` (default
        the scene's own; ``without`` leaves terms out)."""
        d = self.model.device
        arrays = self.arrays if arrays is None else arrays
        for begin, count in self.colors:
            if layout is None:
                wp.launch(floor_sweep_kernel(self.fast_math), dim=count,
                          inputs=[begin, arrays, self.x, self.h], device=d)
            else:
                P, L = layout
                wp.launch_tiled(floor_lanes_kernel(P, L, self.fast_math), dim=[-(-count // P)],
                                block_dim=P * L, inputs=[count, begin, arrays, self.x, self.h], device=d)

    def without(self, terms: str) -> FloorArrays:
        """This scene's arrays with some of the sweep's terms left out, for timing them apart:
        ``membrane`` keeps the triangles (no hinges), ``bending`` the hinges (no triangles),
        ``inertia`` neither (each particle's Newton step on its inertia alone), ``all`` both.
        A term is left out by an adjacency offset array of zeros, so its gather loop runs no
        rounds and loads nothing of it; the kernels are the same."""
        if terms not in TERMS:
            raise ValueError(f"terms {terms!r}: one of {', '.join(TERMS)}")
        a = FloorArrays()
        for name in FLOOR_ARRAYS:
            setattr(a, name, getattr(self.arrays, name))
        m = self.model
        zeros = wp.zeros(m.particle_count + 1, dtype=wp.int32, device=m.device)
        if terms in ("bending", "inertia"):
            a.vertex_tri_offsets = zeros
        if terms in ("membrane", "inertia"):
            a.vertex_edge_offsets = zeros
        return a

    def sweep_bytes(self) -> int:
        """Bytes one sweep of this model's arrays moves at the least: every array it reads once
        (the colour lists and adjacencies included) and the positions written once."""
        read = sum(getattr(self.arrays, name).capacity for name in FLOOR_ARRAYS) + self.x.capacity
        return int(read + self.x.capacity)

    def sweep_bytes_shared(self) -> int:
        """The same with the topology shared by the model's instances, which are copies of one
        mesh: the colour lists, the triangles' and hinges' vertex indices and the adjacencies
        counted once, every per-particle, per-triangle and per-hinge value (rest shape, material,
        state) once per instance. A batch of one garment pattern on different bodies could be
        laid out so; this model is not."""
        shared = sum(getattr(self.arrays, name).capacity for name in TOPOLOGY_ARRAYS)
        return int(self.sweep_bytes() - shared + shared // self.model.instance_count)


def timed_frames(fn, device: str, rounds: int, graph: bool) -> float:
    """Seconds per call of ``fn`` (one frame's launches): ``benchmarks.common.timed_ms`` over
    ``rounds`` calls, replaying a CUDA graph of one on CUDA, best of 3 such batches there."""
    return min(timed_ms(wp, device, fn, rounds, graph) for _ in range(3 if graph else 1)) / 1e3


@wp.kernel(enable_backward=False)
def copy_kernel(src: wp.array(dtype=wp.vec4), dst: wp.array(dtype=wp.vec4)):
    i = wp.tid()
    dst[i] = src[i]


def copy_bandwidth(device: str, nbytes: int, rounds: int) -> dict:
    """Device-to-device copy bandwidth [bytes/s] (read + write counted) of an ``nbytes`` array,
    by ``wp.copy`` (``memcpy``) and by a kernel (``kernel``); ``best`` is the larger. (Session 52's
    runs measured the memcpy alone: 2.77 TB/s on an H200 in a CUDA graph, where PyTorch's copy
    reaches about 4.3 TB/s on the same kind: .library/device/KINDS.md.)"""
    n = nbytes // 16
    a = wp.zeros(n, dtype=wp.vec4, device=device)
    b = wp.zeros(n, dtype=wp.vec4, device=device)
    graph = device.startswith("cuda")
    out = {"memcpy": 2.0 * n * 16 / timed_frames(lambda: wp.copy(b, a), device, rounds, graph),
           "kernel": 2.0 * n * 16 / timed_frames(
               lambda: wp.launch(copy_kernel, dim=n, inputs=[a, b], device=device), device, rounds, graph)}
    out["best"] = max(out["memcpy"], out["kernel"])
    return out


Layout = tuple[int, int] | None | str


def job_overrides(layout: str) -> dict:
    """The ``VBDConfig`` fields a "job:KEY=V+KEY=V" layout sets (integers; {} for "job").

    Raises:
        ValueError: an unknown field or a value that is not an integer."""
    from sim.cloth import VBDConfig

    _, _, spec = layout.partition(":")
    out = {}
    for part in filter(None, spec.split("+")):
        key, eq, value = part.partition("=")
        if not eq or key not in VBDConfig.__dataclass_fields__ or not value.lstrip("-").isdigit():
            raise ValueError(f"layout {layout!r}: 'job:KEY=INT+KEY=INT' with VBDConfig fields, e.g. "
                             "job:max_registers=0 or job:lanes=2+particles_per_block=64")
        out[key] = int(value)
    return out


def parse_layouts(text: str) -> list[Layout]:
    """``threads,32x4,job`` -> [None, (32, 4), "job"]: one thread per particle, blocks of
    particles x lanes (``floor_lanes_kernel``), or the job's own solve kernel with contact off
    (``FloorScene.job_sweep``), also with solver fields changed ("job:max_registers=0")."""
    out: list[Layout] = []
    for item in text.split(","):
        item = item.strip()
        if item in ("threads", "job"):
            out.append(None if item == "threads" else item)
            continue
        if item.startswith("job:"):
            job_overrides(item)
            out.append(item)
            continue
        if item.startswith("block") and item[5:].isdigit() and int(item[5:]) >= 1:
            out.append(item)
            continue
        p, sep, lanes = item.partition("x")
        if not sep or not p.isdigit() or not lanes.isdigit() or int(p) < 1 or int(lanes) < 1:
            raise ValueError(f"layout {item!r}: 'threads', 'job', 'blockTHREADS' (e.g. block256) or "
                             "PARTICLESxLANES (e.g. 32x4)")
        out.append((int(p), int(lanes)))
    return out


def layout_name(layout: Layout) -> str:
    if isinstance(layout, str):
        return layout
    return "threads" if layout is None else f"{layout[0]}x{layout[1]}"


def floors(scene: FloorScene, device: str, substeps: int, iterations: int, rounds: int, bandwidth: float,
           layouts: list[Layout], terms: tuple[str, ...] = ()) -> dict:
    """The floors of one scene, JSON-ready (module docstring): ``sweeps`` is the fastest of the
    ``layouts``, each of which is also in ``layouts``; ``stream`` at this model's bytes,
    ``stream_shared`` with the topology shared by the copies (``FloorScene.sweep_bytes_shared``),
    both at ``bandwidth`` [bytes/s]; ``terms``: the fastest plain layout (``threads`` or
    ``PxL``) again with only those terms (``FloorScene.without``)."""
    m = scene.model
    graph = device.startswith("cuda")
    sweeps = substeps * iterations

    def figures(s: float) -> dict:
        return {"ms_per_frame": 1e3 * s, "garment_frames_per_s": m.instance_count / s,
                "ns_per_particle_sweep": 1e9 * s / (sweeps * m.particle_count)}

    def launches():
        for _ in range(sweeps):
            for _begin, count in scene.colors:
                wp.launch(empty_kernel, dim=count, inputs=[scene.x], device=device)

    out = {"particles": m.particle_count, "triangles": m.tri_count, "hinges": m.edge_count,
           "colors": m.color_count, "sweeps_per_frame": sweeps,
           "launches_per_frame": sweeps * m.color_count, "bytes_per_sweep": scene.sweep_bytes(),
           "bytes_per_sweep_shared": scene.sweep_bytes_shared(), "layouts": {}}
    for layout in layouts:
        def frame(layout=layout):
            if isinstance(layout, str) and layout.startswith("block"):
                for _ in range(substeps):  # one launch per substep
                    scene.block_sweeps(int(layout[5:]), iterations)
                return
            for _ in range(sweeps):
                if isinstance(layout, str) and layout.startswith("job"):
                    scene.job_sweep(layout)
                else:
                    scene.sweep(layout)

        out["layouts"][layout_name(layout)] = figures(timed_frames(frame, device, rounds, graph))
    best = min(out["layouts"], key=lambda k: out["layouts"][k]["ms_per_frame"])
    out["sweeps"] = {**out["layouts"][best], "layout": best}
    plain = [k for k in layouts if not isinstance(k, str)]
    if terms and plain:
        fastest = min(plain, key=lambda k: out["layouts"][layout_name(k)]["ms_per_frame"])
        out["terms"] = {"layout": layout_name(fastest)}
        for term in terms:
            arrays = scene.without(term)

            def partial(arrays=arrays):
                for _ in range(sweeps):
                    scene.sweep(fastest, arrays)

            out["terms"][term] = figures(timed_frames(partial, device, rounds, graph))
    out["stream"] = figures(sweeps * scene.sweep_bytes() / bandwidth)
    out["stream_shared"] = figures(sweeps * scene.sweep_bytes_shared() / bandwidth)
    out["launch"] = figures(timed_frames(launches, device, rounds, graph))
    x = [scene.x.numpy()] + [scene.job_solver(k)[1].positions.numpy() for k in scene._jobs]
    out["finite"] = bool(all(np.isfinite(a).all() for a in x))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda", help="cuda or cpu")
    ap.add_argument("--batch", default="1,16,128,1024", help="t-shirts per model, e.g. 1,16,128,1024")
    ap.add_argument("--vertices", type=int, default=5000, help="t-shirt size (default: the issue's 5k)")
    ap.add_argument("--substeps", type=int, default=0, help="substeps per frame (0: the job's default)")
    ap.add_argument("--iterations", type=int, default=0, help="sweeps per substep (0: the job's default)")
    ap.add_argument("--rounds", type=int, default=20, help="frames per timed batch (3 batches, best)")
    ap.add_argument("--layouts", default="threads,32x4,64x2,job,block256",
                    help="sweep layouts to time: 'threads' (one per particle), PARTICLESxLANES blocks (CUDA; "
                         "the CPU runs them as 1x1), 'job' (the job's own solve kernel, contact off; "
                         "'job:KEY=INT+KEY=INT' with VBDConfig fields changed, e.g. job:max_registers=0) and "
                         "'blockTHREADS' (a block per garment, positions in shared memory, one launch per "
                         "substep)")
    ap.add_argument("--terms", default="",
                    help="also time the fastest plain layout with only some of the sweep's terms, e.g. "
                         "'membrane,bending,inertia' (inertia: neither triangles nor hinges)")
    ap.add_argument("--fast-math", action="store_true",
                    help="build the plain and block layouts' kernels with CUDA fast math, as the job's solve "
                         "kernel is (the 'job' layout always is)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args(argv)
    from benchmarks.bench_tshirt import build_garment
    from sim.bodies.default import load_default_body
    from sim.device import resolve_device
    from sim.simulate import CUDA_COLORS, default_iterations, default_substeps

    try:
        batches = [int(s) for s in args.batch.split(",")]
        if min(batches) < 1:
            raise ValueError
    except ValueError:
        ap.error(f"--batch: a comma-separated list of positive integers, got {args.batch!r}")
    try:
        layouts = parse_layouts(args.layouts)
    except ValueError as e:
        ap.error(f"--layouts: {e}")
    terms = tuple(t.strip() for t in args.terms.split(",") if t.strip())
    if any(t not in TERMS for t in terms):
        ap.error(f"--terms: a comma-separated list of {', '.join(TERMS)}, got {args.terms!r}")
    wp.init()
    device = resolve_device(args.device)
    body = load_default_body()
    garment, edge = build_garment(body, args.vertices)
    nv = len(garment.rest_vertices)
    substeps = args.substeps or default_substeps(nv)
    iterations = args.iterations or default_iterations(nv)
    colors = CUDA_COLORS if device.startswith("cuda") else 0
    if not device.startswith("cuda"):  # a CPU block is one thread
        layouts = sorted({(1, 1) if isinstance(k, tuple) else k for k in layouts}, key=layout_name)
    copy = copy_bandwidth(device, 1 << 30 if device.startswith("cuda") else 1 << 26, args.rounds)
    bandwidth = copy["best"]
    print(f"{garment.name}: {nv} vertices, {substeps} x {iterations}, "
          f"copy bandwidth {bandwidth / 1e9:.0f} GB/s (memcpy {copy['memcpy'] / 1e9:.0f})", flush=True)
    res = {"machine": machine(device), "garment": garment.name, "vertices": nv, "edge_length": edge,
           "substeps": substeps, "iterations": iterations, "max_colors": colors,
           "copy_bandwidth_gb_s": bandwidth / 1e9,
           "copy_bandwidths_gb_s": {k: v / 1e9 for k, v in copy.items()},
           "layouts": [layout_name(k) for k in layouts], "terms": list(terms), "fast_math": args.fast_math,
           "target_garment_frames_per_s": TARGET, "batches": {}}
    for n in batches:
        t0 = time.perf_counter()
        scene = FloorScene.tshirts(garment, n, device, substeps, colors, args.fast_math)
        build_s = time.perf_counter() - t0
        fig = floors(scene, device, substeps, iterations, args.rounds, bandwidth, layouts, terms)
        fig["build_s"] = build_s
        res["batches"][str(n)] = fig
        sw, st = fig["sweeps"], fig["stream"]
        print(f"batch {n}: sweeps ({sw['layout']}) {sw['ms_per_frame']:.3f} ms "
              f"({sw['garment_frames_per_s']:.0f} gf/s, "
              f"{sw['ns_per_particle_sweep']:.3f} ns), stream {st['ms_per_frame']:.3f} ms "
              f"({st['garment_frames_per_s']:.0f} gf/s), launch {fig['launch']['ms_per_frame']:.3f} ms",
              flush=True)
        del scene
    write_result(f"batch_floor_{device.split(':')[0]}{args.tag}", res)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
