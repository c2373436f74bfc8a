"""Dataset generation spread over a Dask cluster (``wrinkles dataset generate --workers N`` or
``--scheduler tcp://HOST:PORT``).

The sequences are cut into tasks of one batch each: task k of T = ceil(sequences / batch) makes
shard k of T (sequences k, k + T, ...; ``sim.datasets.generate``), which a worker simulates as
one batched model and writes, file by file, atomically, into the dataset folder every worker
sees (a shared filesystem on a cluster), with its own part file. The tasks depend only on the
config and ``batch``, never on the number of workers or on which worker runs them, so the
dataset is the same bytes on 1 or 16 workers (on one kind of device). A worker that dies loses
only its task: the scheduler runs it again elsewhere, and the re-run resumes from what the task
had written (``generate(resume=True)``). ``--resume`` continues a stopped job the same way. The
driver shows one progress bar over all tasks and builds the manifest at the end.

``--workers N`` starts a local cluster of N worker processes (one thread each); with several
GPUs each worker takes GPU ``worker index mod GPUs`` (as ``dask-cuda``'s ``LocalCUDACluster``
would pin them; workers of other names use the GPU their ``CUDA_VISIBLE_DEVICES`` shows first).
A job's bytes depend on ``batch``, not on the workers; a plain run with the same ``--batch``
groups the sequences differently (consecutive ones) and makes other bytes, and a dataset started
on a cluster is continued on one (``--resume`` with ``--workers`` or ``--scheduler``).
``--scheduler`` joins an existing cluster (``dask-jobqueue`` on Slurm / PBS, ``dask-kubernetes``,
or ``dask scheduler`` + ``dask worker`` by hand). Dask is an optional
extra: ``pip install wrinkles[distributed]``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

from sim.datasets import storage as S
from sim.datasets.config import DatasetConfig
from sim.datasets.generate import GenerateSummary, finish_dataset, generate, prepare_dataset
from sim.datasets.sampling import sample_sequences, select_indices
from sim.errors import WrinklesInputError

INSTALL_HINT = "Dask is not installed: pip install 'wrinkles[distributed]' (dask[distributed])"


def task_count(sequences: int, batch: int) -> int:
    """Number of tasks (shards) of a dataset of ``sequences`` in batches of ``batch``."""
    return max(1, math.ceil(sequences / batch))


def worker_device(device: str | None) -> str:
    """The Warp device of the calling worker: ``device`` resolved, and a bare "cuda" on a
    machine of several GPUs made "cuda:i" with i = the worker's index mod the GPU count."""
    from sim.device import resolve_device, warp

    dev = resolve_device(device)
    n = warp().get_cuda_device_count()
    if dev != "cuda" or n < 2:
        return dev
    try:
        from distributed import get_worker

        name = get_worker().name
    except (ImportError, ValueError):  # not inside a worker
        return dev
    if not str(name).isdigit():  # a cluster's own naming (dask-jobqueue): it sets CUDA_VISIBLE_DEVICES
        return dev
    return f"cuda:{int(name) % n}"


def _config_dict(cfg: DatasetConfig, device: str | None) -> dict:
    """The dataset's config record as a worker makes it (its device kind sets the simulator
    defaults recorded with it)."""
    from sim.datasets.generate import config_record

    return config_record(cfg, worker_device(device))


def _run_task(cfg: DatasetConfig, out: str, shard: int, shards: int, batch: int, device: str | None,
              splits: Sequence[str] | None) -> dict:
    """One task on a worker: shard ``shard`` of ``shards``, resumed from what is written, under the
    shard's lock (a copy of the task that the scheduler started again while this one still ran
    waits, then finds the work done)."""
    import dataclasses

    from sim.garments.garment_cache import locked

    dev = worker_device(device)
    with locked(S.part_path(out, shard, shards)):
        s = generate(cfg, out, shard=shard, shards=shards, resume=True, batch=batch, device=dev,
                     splits=splits, combine=False)
    return {**dataclasses.asdict(s), "device": dev}


def _client(workers: int | None, scheduler: str | None):
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise WrinklesInputError(INSTALL_HINT) from None
    if scheduler:
        try:
            return Client(scheduler, timeout="20s")
        except OSError as e:
            raise WrinklesInputError(f"--scheduler {scheduler}: cannot connect ({e})") from None
    if not workers or workers < 1:
        raise WrinklesInputError(f"--workers must be >= 1, got {workers}")
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    try:
        return Client(cluster)
    except BaseException:
        cluster.close()
        raise


def generate_on_cluster(cfg: DatasetConfig, out: str | os.PathLike, *, workers: int | None = None,
                        scheduler: str | None = None, batch: int = 1, device: str | None = None,
                        resume: bool = False, splits: Sequence[str] | None = None,
                        progress: Callable[..., None] | None = None,
                        log: Callable[[str], None] | None = None) -> GenerateSummary:
    """Make the dataset of ``cfg`` in ``out`` on a Dask cluster (see the module docstring).

    Args:
        workers: start a local cluster of this many worker processes; or
        scheduler: the address of a running cluster's scheduler (``tcp://HOST:PORT``).
        batch: sequences per task (one batched model on a worker).
        device: each worker's Warp device ("auto", "cpu", "cuda", "cuda:N").
        resume: continue a started dataset (otherwise one is an error).
        splits: make only these splits' sequences.
        progress: ``progress(done, total, note=...)`` over sequences, as tasks finish.
        log: one line per finished task.

    Returns:
        the summed counts of every task (``seconds``: the driver's wall time).
    """
    import time

    specs = sample_sequences(cfg)
    shards = task_count(len(specs), batch)
    sizes = {k: n for k in range(shards) if (n := len(select_indices(specs, k, shards, splits)))}
    root = Path(out).resolve()  # the same folder for workers started elsewhere
    client = _client(workers, scheduler)
    try:
        cfg_dict = client.submit(_config_dict, cfg, device, pure=False).result()
        prepare_dataset(root, cfg_dict, resume, started=[S.part_path(root, k, shards) for k in sizes])
        summary, t0 = GenerateSummary(), time.perf_counter()
        tasks = {client.submit(_run_task, cfg, os.fspath(root), k, shards, batch, device, splits,
                               key=f"wrinkles-shard-{k}-of-{shards}", pure=False): k for k in sizes}
        _gather(client, tasks, summary, sizes, t0, progress, log)
    finally:
        cluster = getattr(client, "cluster", None)
        client.close()
        if cluster is not None:
            cluster.close()
    finish_dataset(root, cfg_dict)
    summary.seconds = time.perf_counter() - t0
    return summary


def _gather(client, tasks: dict, summary: GenerateSummary, sizes: dict[int, int], t0: float, progress,
            log) -> None:
    """Sum the tasks' summaries (``tasks``: future -> shard of ``sizes[shard]`` sequences) into
    ``summary`` as they finish; the first task that fails (not a worker that died: the scheduler
    runs its task again) cancels the rest and raises."""
    import time

    from distributed import as_completed

    done, total = 0, sum(sizes.values())
    for fut in as_completed(list(tasks)):
        try:
            s = fut.result()
        except BaseException:
            client.cancel(list(tasks))
            raise
        for field in ("accepted", "rejected", "skipped", "recovered", "garment_frames", "bytes"):
            setattr(summary, field, getattr(summary, field) + s[field])
        shard = tasks[fut]
        done += sizes[shard]
        rate = summary.garment_frames / max(time.perf_counter() - t0, 1e-9)
        if log is not None:
            log(f"task {shard} ({s['device']}): {s['accepted']} accepted, {s['rejected']} rejected, "
                f"{s['skipped'] + s['recovered']} already done")
        if progress is not None:
            progress(done, total, note=f"{summary.accepted} accepted, {rate:.1f} garment-frames/s")
