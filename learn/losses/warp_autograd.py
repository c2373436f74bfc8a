"""The torch <-> Warp bridge: batched Warp energies as ``torch.autograd.Function``s.

A loss term is written once as an *energy launch*: a Python function that launches Warp
kernels (``sim.losses.loss_kernels``) on warp views of position tensors (B, N, 3) and writes
the energy of every element (triangle, hinge, vertex ...) of every sample, (B, elements); the
per-sample energy (B,) is their sum, a torch reduction (deterministic, and far faster on a GPU
than atomics into one address per sample). :func:`warp_energy` runs it as an autograd node:

* forward: the tensors are wrapped zero-copy (``wp.from_torch``) and the kernels run on
  torch's current CUDA stream (``wp.stream_from_torch``), so no synchronisation is needed;
  results are torch tensors, and Warp intermediates are released inside the stream scope
  (Warp's stream-ordered allocator frees on the current stream);
* backward: the launch runs again with a recording :class:`Launcher` (intermediate arrays
  get gradients), then Warp's adjoint kernels run in reverse order (``wp.launch(...,
  adjoint=True)``), writing the gradient straight into torch tensors. Kernels whose only output
  is the energy are not re-run forward: their adjoint replays them. A single-kernel term costs
  one adjoint launch.

Only float32, contiguous position tensors reach Warp; the caller casts (a differentiable
``.to(torch.float32)``) before. Other data of a term (topology, material constants, collision
correspondences) is captured by the launch function itself as Warp arrays.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import torch

from sim.device import warp


class Launcher:
    """Launches kernels for an energy; in recording mode also keeps them for the adjoint pass.

    Args:
        device: Warp device.
        energy: the per-element energy array (B, elements) the launch writes.
        record: backward mode: intermediate arrays get gradients, launches are recorded.
        energy_grad: backward mode: the incoming gradient of ``energy`` (any strides; it is
            passed as the adjoint explicitly, so the adjoint kernels never zero it).
    """

    def __init__(self, device: Any, energy: Any, *, record: bool, energy_grad: Any = None):
        self.device = device
        self.energy = energy
        self.record = record
        self.energy_grad = energy_grad
        self._launches: list[tuple[Any, Any, list, list]] = []

    def zeros(self, shape: int | tuple[int, ...], dtype: Any) -> Any:
        """A zero-filled intermediate array (with a gradient buffer when recording)."""
        return warp().zeros(shape, dtype=dtype, device=self.device, requires_grad=self.record)

    def __call__(self, kernel: Any, dim: int | tuple[int, ...], inputs: list, outputs: list) -> None:
        """Launch ``kernel`` (``inputs`` first, ``outputs`` ``_out``-suffixed, as the kernel declares)."""
        if self.record:
            self._launches.append((kernel, dim, inputs, outputs))
            if all(o is self.energy for o in outputs):
                return  # terminal reduction: its adjoint kernel replays it
        warp().launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device)

    def backward(self) -> None:
        """Run the recorded launches' adjoints in reverse order (gradients land in ``.grad``)."""
        wp = warp()

        def adj(a):
            return self.energy_grad if a is self.energy else _adjoint(a)
        for kernel, dim, inputs, outputs in reversed(self._launches):
            wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, adj_inputs=[adj(a) for a in inputs],
                      adj_outputs=[adj(a) for a in outputs], adjoint=True, device=self.device)


EnergyLaunch = Callable[[list, Any, Launcher], None]
"""``launch(arrays, energy_out, run)``: ``arrays`` are 2D vec3 Warp views (B, N) of the position
tensors, ``energy_out`` a 2D float array (B, elements) to write, ``run`` the :class:`Launcher`."""


def _adjoint(a: Any) -> Any:
    """Adjoint argument of a kernel argument: an array's gradient buffer, else None (as ``wp.Tape``)."""
    if isinstance(a, warp().array) and a.requires_grad:
        return a.grad
    return None


_STREAMS: dict[tuple[int, int], Any] = {}


@contextlib.contextmanager
def torch_stream(device: torch.device) -> Iterator[Any]:
    """Warp device for a torch device, with torch's current CUDA stream made Warp's current one."""
    wp = warp()
    wdev = wp.device_from_torch(device)
    if device.type != "cuda":
        yield wdev
        return
    ts = torch.cuda.current_stream(device)
    key = (wdev.ordinal, ts.cuda_stream)
    stream = _STREAMS.get(key)
    if stream is None:
        stream = _STREAMS[key] = wp.stream_from_torch(ts)
    with wp.ScopedStream(stream, sync_enter=False):
        yield wdev


def vec3_view(t: torch.Tensor, *, grad: torch.Tensor | None = None) -> Any:
    """Zero-copy 2D vec3 Warp view (B, N) of a float32 contiguous tensor (B, N, 3)."""
    wp = warp()
    if grad is None:
        return wp.from_torch(t, dtype=wp.vec3, requires_grad=False)
    return wp.from_torch(t, dtype=wp.vec3, requires_grad=True, grad=wp.from_torch(grad, dtype=wp.vec3))


class WarpEnergyFunction(torch.autograd.Function):
    """Autograd node of an energy launch (use :func:`warp_energy`)."""

    @staticmethod
    def forward(ctx, launch: EnergyLaunch, num_elements: int, *tensors: torch.Tensor) -> torch.Tensor:
        wp = warp()
        device = tensors[0].device
        batch = tensors[0].shape[0]
        per_element = torch.empty((batch, num_elements), dtype=torch.float32, device=device)
        with torch_stream(device) as wdev:
            arrays = [vec3_view(t) for t in tensors]
            e = wp.from_torch(per_element, requires_grad=False)
            launch(arrays, e, Launcher(wdev, e, record=False))
        ctx.launch = launch
        ctx.num_elements = num_elements
        ctx.save_for_backward(*tensors)
        return per_element.sum(dim=1)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_energy: torch.Tensor):
        wp = warp()
        tensors = ctx.saved_tensors
        needs = ctx.needs_input_grad[2:]
        grads = [torch.zeros_like(t) if n else None for t, n in zip(tensors, needs, strict=True)]
        device = tensors[0].device
        batch = tensors[0].shape[0]
        with torch_stream(device) as wdev:
            arrays = [vec3_view(t, grad=g) for t, g in zip(tensors, grads, strict=True)]
            # d(sum)/d(element) = 1: every element of sample b receives grad_energy[b], read
            # through a stride-0 view (no copy)
            g = grad_energy.to(torch.float32).contiguous()
            g_elem = wp.from_torch(g[:, None].expand(batch, ctx.num_elements), requires_grad=False)
            scratch = torch.empty((batch, ctx.num_elements), dtype=torch.float32, device=device)
            e = wp.from_torch(scratch, requires_grad=False)
            run = Launcher(wdev, e, record=True, energy_grad=g_elem)
            ctx.launch(arrays, e, run)
            run.backward()
            del run  # Warp intermediates are freed on this (torch's) stream, after their kernels
        return (None, None, *grads)


def warp_energy(launch: EnergyLaunch, tensors: Sequence[torch.Tensor], num_elements: int) -> torch.Tensor:
    """Per-sample energy (B,) of ``launch`` on position tensors (B, N_k, 3), differentiable wrt
    every tensor that requires grad.

    Args:
        launch: the energy launch (see ``EnergyLaunch``); it writes the energy of each of
            ``num_elements`` elements (triangles, hinges, vertices ...) of each sample.
        tensors: float32 position tensors on one device, first dimension B; made contiguous here.
        num_elements: elements per sample; the energy is their sum (a torch reduction).

    Returns:
        float32 tensor (B,) on the tensors' device.
    """
    ts = [t.contiguous() for t in tensors]
    for t in ts:
        if t.dtype != torch.float32 or t.ndim != 3 or t.shape[2] != 3:
            raise ValueError(f"warp_energy: tensors must be float32 (B, N, 3), got {t.dtype} "
                             f"{tuple(t.shape)}")
        if t.device != ts[0].device or t.shape[0] != ts[0].shape[0]:
            raise ValueError("warp_energy: all tensors must share the device and the batch size")
    return WarpEnergyFunction.apply(launch, int(num_elements), *ts)
