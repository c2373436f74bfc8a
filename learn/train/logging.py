"""Training logs: ``metrics.jsonl``, TensorBoard event files and PNG plots of the curves.

Only rank 0 of a distributed run writes. ``metrics.jsonl`` is the record of truth (one JSON
object per logged step); a resumed run first drops the lines past its checkpoint step so the
file never holds two histories. TensorBoard files go to ``<run>/tensorboard`` (``tensorboard
--logdir RUN``); when the ``tensorboard`` package is missing, a note says so and the other two
outputs are still written. ``curves.png`` plots every logged scalar against the step.
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

METRICS_FILE = "metrics.jsonl"
CURVES_FILE = "curves.png"


def read_metrics(run_dir: str | os.PathLike) -> list[dict]:
    """The logged records of a run, in order (``[]`` when none)."""
    path = Path(run_dir) / METRICS_FILE
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if line:
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:  # a line cut by a kill: ignore it
                continue
    return out


class MetricLogger:
    """Append scalars to ``metrics.jsonl`` and TensorBoard; draw ``curves.png``.

    Args:
        run_dir: the run directory.
        enabled: False on ranks other than 0 (every method is then a no-op).
        resume_step: drop records with ``step > resume_step`` (a resumed run).
        tensorboard: write TensorBoard event files when the package is installed.
    """

    def __init__(self, run_dir: str | os.PathLike, *, enabled: bool = True, resume_step: int | None = None,
                 tensorboard: bool = True):
        self.run_dir = Path(run_dir)
        self.enabled = enabled
        self.writer = None
        if not enabled:
            return
        self.run_dir.mkdir(parents=True, exist_ok=True)
        path = self.run_dir / METRICS_FILE
        if resume_step is not None and path.exists():
            kept = [r for r in read_metrics(self.run_dir) if int(r.get("step", 0)) <= resume_step]
            tmp = path.with_suffix(".tmp")
            tmp.write_text("".join(json.dumps(r) + "\n" for r in kept))
            os.replace(tmp, path)
        elif resume_step is None and path.exists():
            path.unlink()
        self._file = open(path, "a")
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError:
                print("note: the 'tensorboard' package is not installed; logging to metrics.jsonl and "
                      "curves.png only (pip install tensorboard)", file=sys.stderr)
            else:
                self.writer = SummaryWriter(log_dir=str(self.run_dir / "tensorboard"),
                                            purge_step=resume_step + 1 if resume_step is not None else None)

    def log(self, step: int, scalars: dict[str, float]) -> None:
        """Record ``scalars`` (floats) at ``step``."""
        if not self.enabled:
            return
        rec = {"step": int(step), **{k: float(v) for k, v in scalars.items()}}
        self._file.write(json.dumps(rec) + "\n")
        self._file.flush()
        if self.writer is not None:
            for k, v in scalars.items():
                self.writer.add_scalar(k, float(v), int(step))

    def flush(self) -> None:
        if self.enabled and self.writer is not None:
            self.writer.flush()

    def plot(self) -> Path | None:
        """Write ``curves.png`` (one panel per scalar; log-scale y for positive losses)."""
        if not self.enabled:
            return None
        return plot_curves(read_metrics(self.run_dir), self.run_dir / CURVES_FILE)

    def close(self) -> None:
        if not self.enabled:
            return
        self._file.close()
        if self.writer is not None:
            self.writer.close()


def plot_curves(records: list[dict], out: str | os.PathLike) -> Path | None:
    """Plot every scalar of ``records`` against ``step`` into ``out`` (PNG); None if nothing."""
    keys = sorted({k for r in records for k in r if k != "step"})
    if not records or not keys:
        return None
    try:
        import matplotlib
    except ImportError:
        print("note: matplotlib is not installed; no curves.png (metrics.jsonl has the numbers)",
              file=sys.stderr)
        return None

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(3, len(keys))
    rows = math.ceil(len(keys) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
    for ax, key in zip(axes.ravel(), keys, strict=False):
        pts = [(r["step"], r[key]) for r in records if key in r and math.isfinite(r[key])]
        if pts:
            s, v = zip(*pts, strict=True)
            ax.plot(s, v, lw=1.2)
            if key.startswith(("loss", "train/loss")) and min(v) > 0:
                ax.set_yscale("log")
        ax.set_title(key, fontsize=9)
        ax.set_xlabel("step", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(keys):]:
        ax.axis("off")
    fig.tight_layout()
    out = Path(out)
    tmp = out.with_name(f".{out.name}.tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, out)
    return out
