"""Dataset generation on a Dask cluster (sim.datasets.cluster): a local cluster of 2 CPU worker
processes makes the same bytes as one process, and a worker killed in the middle of its task
loses nothing (the scheduler runs the task again, which resumes from what was written)."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from sim.datasets import storage as S
from tests.test_datasets import _files, _generate, tiny_config

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny dataset made by one process (batch 1)."""
    tmp = tmp_path_factory.mktemp("one")
    _generate(tiny_config(tmp), tmp / "data")
    return tmp / "data"


def _config(tmp_path):
    from sim.datasets.config import load_config

    return load_config(tiny_config(tmp_path))


def test_task_count_and_worker_device():
    from sim.datasets.cluster import task_count, worker_device

    assert [task_count(n, 4) for n in (1, 4, 5, 9)] == [1, 1, 2, 3]
    assert worker_device("cpu") == "cpu"  # outside a worker, and on the CPU, as asked


@pytest.mark.slow
def test_two_workers_make_the_bytes_of_one_process(reference, tmp_path):
    from sim.datasets.cluster import generate_on_cluster

    ref_out = reference
    out = tmp_path / "cluster"
    notes = []
    s = generate_on_cluster(_config(tmp_path), out, workers=2, batch=1, device="cpu",
                            progress=lambda done, total, note=None: notes.append((done, total, note)))
    assert _files(out) == _files(ref_out)
    assert S.read_manifest(out)["sequences"] == S.read_manifest(ref_out)["sequences"]
    assert s.accepted + s.rejected == 4 and notes[-1][:2] == (4, 4) and "garment-frames/s" in notes[-1][2]
    # again without --resume: refused, nothing touched
    from sim.errors import WrinklesInputError

    with pytest.raises(WrinklesInputError, match="--resume"):
        generate_on_cluster(_config(tmp_path), out, workers=1, batch=1, device="cpu")
    assert _files(out) == _files(ref_out)
    # resumed: every task finds its sequences done
    again = generate_on_cluster(_config(tmp_path), out, workers=1, batch=1, device="cpu", resume=True)
    assert (again.accepted, again.rejected, again.skipped) == (0, 0, 4)
    assert _files(out) == _files(ref_out)


@pytest.mark.slow
def test_a_worker_killed_mid_task_loses_nothing(reference, tmp_path):
    from distributed import Client, LocalCluster

    from sim.datasets.cluster import generate_on_cluster

    ref_out = reference
    out = tmp_path / "killed"
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    watcher = Client(cluster)
    killed: list[int] = []

    def kill_one_busy_worker():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not killed:
            busy = [w for w, tasks in watcher.processing().items() if tasks]
            if busy:
                time.sleep(1.0)  # inside the task: garments sewn, simulating
                pid = watcher.run(os.getpid, workers=[busy[0]])[busy[0]]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            time.sleep(0.1)

    thread = threading.Thread(target=kill_one_busy_worker)
    thread.start()
    try:
        s = generate_on_cluster(_config(tmp_path), out, scheduler=cluster.scheduler_address, batch=1,
                                device="cpu")
    finally:
        thread.join()
        watcher.close()
        cluster.close()
    assert killed, "no worker was busy to kill"
    assert _files(out) == _files(ref_out)  # nothing lost, nothing different
    assert s.accepted + s.rejected + s.skipped + s.recovered == 4
    assert set(S.read_manifest(out)["sequences"]) == set(S.read_manifest(ref_out)["sequences"])


def test_cluster_options_are_checked_before_anything_runs(tmp_path, capsys):
    from pipelines.cli import main

    cfg = tiny_config(tmp_path)
    out = tmp_path / "never"
    for extra in (["--workers", "2", "--shard", "0/2"], ["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
                  ["--workers", "0"]):
        code = main(["dataset", "generate", "--config", str(cfg), "--out", str(out), "--device", "cpu", "-q",
                     *extra])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and "--workers" in err, (extra, err)
        assert not out.exists()
