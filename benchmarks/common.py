"""Shared benchmark helpers: machine description and JSON results (DESIGN.md, Performance)."""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def machine(device: str) -> dict:
    """CPU / GPU / library facts for the result file."""
    info = {
        "host_cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "device": device,
    }
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["host_cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    if device.startswith("cuda"):
        try:
            out = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total",
                                  "--format=csv,noheader"], capture_output=True, text=True, timeout=20)
            info["gpu"] = out.stdout.strip().splitlines()[0]
        except (OSError, subprocess.SubprocessError, IndexError):
            pass
    import numpy
    import warp

    info["warp"] = warp.config.version
    info["numpy"] = numpy.__version__
    return info


def write_result(name: str, result: dict) -> Path:
    """Print and write ``benchmarks/results/<name>.json`` (and $OUT/<name>.json when set)."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    argv = ["-m", spec.name, *sys.argv[1:]] if spec is not None else sys.argv
    result = {"benchmark": name, "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
              "command": " ".join(["python", *argv]), **result}
    text = json.dumps(result, indent=2)
    print(text)
    RESULTS.mkdir(exist_ok=True)
    paths = [RESULTS / f"{name}.json"]
    if os.environ.get("OUT"):
        paths.append(Path(os.environ["OUT"]) / f"{name}.json")
    for p in paths:
        tmp = p.with_suffix(".json.tmp")
        tmp.write_text(text + "\n")
        os.replace(tmp, p)
    return paths[0]


def timed_ms(wp, device: str, fn, repeats: int, graph: bool = False) -> float:
    """Milliseconds per call of ``fn`` (launches on ``device``): one warm-up call, then the mean of
    ``repeats`` calls, synchronised; ``graph`` (CUDA): the calls replay a CUDA graph of one."""
    fn()
    wp.synchronize_device(device)
    run = fn
    if graph and wp.get_device(device).is_cuda:
        with wp.ScopedCapture(device=device) as cap:
            fn()
        run = lambda: wp.capture_launch(cap.graph)  # noqa: E731
    run()
    wp.synchronize_device(device)
    t = time.perf_counter()
    for _ in range(repeats):
        run()
    wp.synchronize_device(device)
    return 1000.0 * (time.perf_counter() - t) / repeats
