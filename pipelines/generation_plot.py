"""The generation timeline of a dataset as a picture (``generation.png`` of ``wrinkles dataset
report``): accepted garment-frames and sequences made over the job's wall time, with the
throughput, and the rejections by cause. Read from the shards' timelines
(``sim.datasets.storage.read_events``) and the manifest's rejection reasons."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np


def generation_summary(events: list[dict], rejected: dict) -> dict:
    """The numbers behind the picture: sequences and frames over time, the throughput of the
    whole job (accepted garment-frames per second between the first and the last sequence
    done) and rejections counted by cause (``sim.datasets.info.rejection_kind``)."""
    from sim.datasets.info import rejection_kind

    causes: Counter = Counter()
    for r in rejected.values():
        for text in r.get("reasons", []):
            causes[rejection_kind(text)] += 1
    times = np.array([e["time"] for e in events], np.float64)
    frames = np.array([e["frames"] if e["outcome"] == "accepted" else 0 for e in events], np.int64)
    span = float(times[-1] - times[0]) if len(times) > 1 else 0.0
    return {"sequences": len(events), "accepted": int(sum(e["outcome"] == "accepted" for e in events)),
            "garment_frames": int(frames.sum()), "seconds": span,
            "garment_frames_per_s": float(frames[1:].sum() / span) if span > 0 else None,
            "rejection_causes": dict(causes.most_common())}


def plot_generation(events: list[dict], rejected: dict, path: Path, title: str) -> dict:
    """Write the timeline picture of ``events`` (time-ordered) to ``path``; returns
    ``generation_summary``."""
    from pipelines.dataset_report import _import_matplotlib_figure

    Figure = _import_matplotlib_figure()
    s = generation_summary(events, rejected)
    t0 = events[0]["time"] if events else 0.0
    minutes = np.array([(e["time"] - t0) / 60.0 for e in events])
    accepted = np.cumsum([e["outcome"] == "accepted" for e in events])
    frames = np.cumsum([e["frames"] if e["outcome"] == "accepted" else 0 for e in events])
    fig = Figure(figsize=(11, 4), dpi=100)
    ax, bx = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    ax.step(minutes, frames, where="post", color="tab:blue", label="accepted garment-frames")
    ax.set_xlabel("minutes since the first sequence done")
    ax.set_ylabel("accepted garment-frames", color="tab:blue")
    twin = ax.twinx()
    twin.step(minutes, np.arange(1, len(events) + 1), where="post", color="0.5", label="sequences made")
    twin.step(minutes, accepted, where="post", color="tab:green", label="accepted")
    twin.set_ylabel("sequences")
    rate = s["garment_frames_per_s"]
    ax.set_title("throughput" + (f": {rate:.2f} accepted garment-frames/s" if rate else ""))
    ax.set_zorder(twin.get_zorder() + 1)  # the frames' line over the counts
    ax.patch.set_visible(False)
    lines = ax.get_lines() + twin.get_lines()
    ax.legend(lines, [line.get_label() for line in lines], loc="upper left", fontsize=8)
    causes = s["rejection_causes"]
    if causes:
        names = list(causes)[::-1]
        bx.barh(names, [causes[n] for n in names], color="tab:red")
        bx.set_xlabel("failed gates and stops (a rejection can have several)")
    else:
        bx.text(0.5, 0.5, "no rejections", ha="center", va="center", transform=bx.transAxes)
        bx.set_axis_off()
    bx.set_title(f"rejections by cause: {len(rejected)} sequences rejected")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, format="png")
    return s
