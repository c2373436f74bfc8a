"""Multi-process training through ``torchrun`` (DDP): process group, devices, reductions.

``torchrun --nproc_per_node N -m pipelines.cli train ...`` starts N processes with ``RANK``,
``WORLD_SIZE`` and ``LOCAL_RANK`` set; :func:`init_distributed` joins them into one process
group (NCCL on CUDA, gloo on CPU) and gives each process its device (``cuda:LOCAL_RANK``). A
plain ``python`` run is world size 1 and touches no process group.
"""

from __future__ import annotations

import gc
import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

from sim.errors import WrinklesInputError


@dataclass(frozen=True)
class DistContext:
    """Where this process stands in the run.

    Attributes:
        rank: global rank (0 .. world_size - 1).
        world_size: number of processes.
        local_rank: rank on this host.
        device: the torch device this process trains on.
    """

    rank: int
    world_size: int
    local_rank: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1


def resolve_torch_device(spec: str, local_rank: int = 0) -> torch.device:
    """``auto`` / ``cpu`` / ``cuda`` / ``cuda:N`` -> a torch device (``cuda`` takes LOCAL_RANK)."""
    if spec in ("auto", "", None):
        spec = "cuda" if torch.cuda.is_available() else "cpu"
    if spec == "cpu":
        return torch.device("cpu")
    if spec.startswith("cuda"):
        if not torch.cuda.is_available():
            raise WrinklesInputError(f"device {spec}: torch sees no CUDA device here (use cpu)")
        if spec == "cuda":
            return torch.device("cuda", local_rank)
        return torch.device(spec)
    raise WrinklesInputError(f"device {spec!r}: use auto, cpu, cuda or cuda:N")


def init_distributed(device: str = "auto") -> DistContext:
    """Join the torchrun process group when there is one; pick this process's device."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    dev = resolve_torch_device(device, local)
    if world > 1 and not dist.is_initialized():
        if dev.type == "cuda":
            torch.cuda.set_device(dev)
        dist.init_process_group(backend="nccl" if dev.type == "cuda" else "gloo")
    return DistContext(rank=rank, world_size=world, local_rank=local, device=dev)


def shutdown(ctx: DistContext, *, together: bool = True) -> None:
    """Leave the process group (if this run joined one).

    The DDP wrapper sits in a reference cycle and holds the group: collecting it first frees the
    group's worker threads while the interpreter is alive (a gloo group freed during interpreter
    finalisation aborts the process: "terminate called without an active exception"). With
    ``together`` (a run that finished on every process) a barrier first keeps one process from
    tearing down its connections while another still works; a failed run leaves at once, since
    the other processes may never reach a barrier.
    """
    if ctx.distributed and dist.is_initialized():
        gc.collect()
        if together:
            dist.barrier()
        dist.destroy_process_group()
        gc.collect()


def barrier(ctx: DistContext) -> None:
    if ctx.distributed:
        dist.barrier()


def mean_across(ctx: DistContext, values: dict[str, float]) -> dict[str, float]:
    """Average scalars over processes (identity on one process); keys must agree on every rank."""
    if not ctx.distributed or not values:
        return values
    keys = sorted(values)
    t = torch.tensor([float(values[k]) for k in keys], dtype=torch.float64,
                     device=ctx.device if ctx.device.type == "cuda" else "cpu")
    dist.all_reduce(t)
    t /= ctx.world_size
    return dict(zip(keys, t.tolist(), strict=True))


def any_across(ctx: DistContext, flag: bool) -> bool:
    """True on every process when ``flag`` is true on any (e.g. a stop request)."""
    if not ctx.distributed:
        return flag
    t = torch.tensor([1.0 if flag else 0.0], device=ctx.device if ctx.device.type == "cuda" else "cpu")
    dist.all_reduce(t)
    return bool(t.item() > 0)
