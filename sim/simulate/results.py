"""The result of one simulated job: its ``GarmentSequence`` (output frames, body, motion and
provenance) and the quality report judged against the config's gates."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from sim.quality import QualityReport, evaluate_sequence
from sim.simulate.config import SimulationConfig
from sim.simulate.jobs import Track
from sim.types import BodyFrames, GarmentSequence
from sim.versions import package_versions


@dataclass(frozen=True)
class SimulationResult:
    """A simulated sequence with its quality report.

    Attributes:
        sequence: the garment sequence (provenance holds the resolved config).
        quality: quality statistics of every output frame.
        failed_gates: human-readable reasons the sequence fails ``config.gates`` (empty: passes).
        step_ms: wall time [ms] of each solver frame of the output (launch to device
            synchronisation; the host copy and checks excluded), shared by a batch.
    """

    sequence: GarmentSequence
    quality: QualityReport
    failed_gates: tuple[str, ...]
    step_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def passed(self) -> bool:
        return not self.failed_gates


def provenance(tr: Track, cfg: SimulationConfig, vbd, device: str, seed: int, graph: bool) -> dict:
    """What produced the sequence of ``tr``: the config and resolved ``VBDConfig`` ``vbd``, seed,
    device, whether the step ran from a CUDA graph, package versions, garment, body, motion, the
    frame counts of the timeline (``blend``: the frames from rest into the motion, its lead-in's
    where ``entry`` is ``"lead_in"``, a slerp's where it is ``"blend"``) and the garment's
    placement."""
    from sim.motions.blend import lead_in

    g = tr.job.garment
    body = tr.job.body
    out = {
        "config": cfg.to_dict(),
        "solver": vbd.to_dict(),
        "seed": int(seed),
        "device": device,
        "cuda_graph": bool(graph),
        "versions": package_versions(),
        "garment": {"name": g.name, "category": g.category, "vertices": g.num_vertices, "faces": g.num_faces,
                    "material": g.material.name, "hem_faces": int((g.face_layers > 1.0).sum()),
                    "pinned_sets": [n for n in cfg.pinned if n in g.attachments],
                    "pinned_vertices": int(tr.pinned.size)},
        "body": {"name": getattr(body, "name", "body"), "source": getattr(body, "source", ""),
                 "betas": [float(b) for b in tr.betas]},
        "motion": {"name": tr.motion.name, "source": tr.motion.source, "frames": tr.motion.num_frames},
        "frames": {"output": int(tr.out.shape[0]), "settle": tr.n_settle, "blend": tr.n_blend,
                   "entry": "blend" if lead_in(tr.motion) is None else "lead_in",
                   "prelude_kept": bool(cfg.keep_prelude), "first_output_timeline_frame": tr.first_out},
        "ground_offset_m": tr.ground_dy,
        "placement_m": [float(v) for v in tr.placement],
    }
    if tr.job.garment_betas is not None:  # the shape the garment was built on (morphed from)
        gb = tr.betas if tr.garment_betas is None else tr.garment_betas
        out["garment"]["betas"] = [float(b) for b in gb]
    return out


def finish_track(tr: Track, cfg: SimulationConfig, vbd, device: str, seed: int, graph: bool,
                 step_ms: np.ndarray) -> SimulationResult:
    """The result of a finished track: its output frames with the body and motion cut to them,
    the quality report, the gates it fails, and ``step_ms`` of the batch's solver frames (frame
    k of the output is solver step k - 1 + ``first_out``; the first is the captured one)."""
    g = tr.job.garment
    f0 = tr.first_out
    fr = tr.frames
    frames = BodyFrames(vertices=fr.vertices[f0:], joints=fr.joints[f0:], transforms=fr.transforms[f0:],
                        faces=fr.faces)
    motion = tr.motion if f0 == tr.n_settle + tr.n_blend else replace(
        tr.timeline, poses=tr.timeline.poses[f0:], trans=tr.timeline.trans[f0:])
    quality = evaluate_sequence(tr.out, g.rest_vertices, g.faces, frames.vertices, tr.job.body.faces,
                                rest_lengths=g.rest_edge_lengths(),
                                device=device)
    seq = GarmentSequence(vertices=tr.out, body=frames, garment=g, motion=motion, fps=float(cfg.fps),
                          provenance=provenance(tr, cfg, vbd, device, seed, graph))
    return SimulationResult(seq, quality, tuple(quality.failures(cfg.gates)),
                            step_ms=step_ms[max(f0, 1):tr.length - 1])
