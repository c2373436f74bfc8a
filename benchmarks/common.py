"""What every benchmark shares: the machine a figure was measured on, and its JSON result file."""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
"""Where a benchmark writes ``<name>.json`` unless ``--results`` says otherwise."""


def add_results_argument(ap: argparse.ArgumentParser) -> None:
    """``--results DIR``: the folder of the JSON result (default ``benchmarks/results``)."""
    ap.add_argument("--results", type=Path, default=RESULTS,
                    help="folder of the JSON result (default: benchmarks/results)")


def machine(device: str) -> dict:
    """CPU, GPU and library versions of this process, for the result file."""
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


def command_line() -> str:
    """This process's command line as ``python -m benchmarks.NAME ARGS`` where it ran as a module."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    argv = ["-m", spec.name, *sys.argv[1:]] if spec is not None else sys.argv
    return " ".join(["python", *argv])


def write_result(name: str, result: dict, folder: Path = RESULTS) -> Path:
    """Print ``result`` with the benchmark's name, the date and the command line, and write it to
    ``folder/<name>.json``; also to ``$OUT/<name>.json`` where ``OUT`` is set (the folder a GPU
    runner brings back)."""
    result = {"benchmark": name, "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
              "command": command_line(), **result}
    text = json.dumps(result, indent=2)
    print(text)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{name}.json"]
    if os.environ.get("OUT"):
        paths.append(Path(os.environ["OUT"]) / f"{name}.json")
    for p in paths:
        tmp = p.with_suffix(".json.tmp")
        tmp.write_text(text + "\n")
        os.replace(tmp, p)
    return paths[0]
