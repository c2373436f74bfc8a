"""Motions in SMPL's convention: AMASS ``.npz``, BVH (retargeted), and a procedural library.

Public entry points:

- :func:`load_motion` — one call for every source: a procedural name (``walk``) or a path to
  an ``.npz`` (AMASS SMPL / SMPL-H / SMPL-X) or ``.bvh`` file; optional ``fps`` resampling and
  ``duration``.
- :func:`procedural_motion`, :func:`list_motions`, ``PROCEDURAL_MOTIONS`` — the registry.
- :func:`load_amass`, :func:`load_bvh`, :func:`resample_motion`, :func:`trim_motion`.

All outputs are Y up, metres, poses (T, 24, 3) axis-angle [rad] in SMPL's joint order and
``trans`` (T, 3) [m] relative to standing at rest (see ``sim.motions.procedural``). A
procedural motion is in full motion from its first frame; its way in from the rest T-pose, its
lead-in, rides along as ``extra["lead_in"]`` (a simulation plays it in its prelude:
``sim.motions.blend.enter_from_rest``).
"""

from __future__ import annotations

import dataclasses
import inspect
import os
from pathlib import Path

from sim.errors import WrinklesInputError
from sim.motions import gait, procedural
from sim.motions.amass import load_amass
from sim.motions.bvh import load_bvh
from sim.motions.procedural import MotionSpec
from sim.motions.resample import resample_motion, trim_motion
from sim.motions.skeleton import MotionSkeleton
from sim.types import Motion

__all__ = [
    "PROCEDURAL_MOTIONS", "MotionSkeleton", "MotionSpec", "list_motions", "load_motion", "procedural_motion",
    "load_amass", "load_bvh", "resample_motion", "trim_motion",
]

#: name -> (params dataclass, generator, one-line description)
PROCEDURAL_MOTIONS: dict[str, MotionSpec] = {
    "walk": MotionSpec(gait.WalkParams, gait.walk,
                       "straight walk along +Z from normative gait curves (Perry, Winter)"),
    "run": MotionSpec(gait.RunParams, gait.run,
                      "straight run along +Z with a flight phase (Novacheck curves, spring-mass)"),
    "jump": MotionSpec(procedural.JumpParams, procedural.jump,
                       "countermovement vertical jump with ballistic flight and landing"),
    "squat": MotionSpec(procedural.SquatParams, procedural.squat,
                        "bodyweight squats, arms forward, balance kept over the feet"),
    "arm_raise": MotionSpec(procedural.ArmRaiseParams, procedural.arm_raise,
                            "arms raised and lowered to the side or to the front"),
    "torso_twist": MotionSpec(procedural.TorsoTwistParams, procedural.torso_twist,
                              "trunk rotation left and right about the vertical axis"),
    "random": MotionSpec(procedural.RandomParams, procedural.random_motion,
                         "smooth seeded random motion within the joint limits"),
    "rest_to_apose": MotionSpec(procedural.RestToAPoseParams, procedural.rest_to_apose,
                                "rest T-pose to A-pose, then hold"),
    "idle": MotionSpec(procedural.IdleParams, procedural.idle,
                       "standing idle: breathing, weight shift, head turns"),
    "wave": MotionSpec(procedural.WaveParams, procedural.wave,
                       "right hand raised beside the head, waving"),
}

_FILE_LOADERS = {".npz": load_amass, ".bvh": load_bvh}


def list_motions() -> list[tuple[str, str]]:
    """``(name, description)`` of every procedural motion, in registry order."""
    return [(name, spec.description) for name, spec in PROCEDURAL_MOTIONS.items()]


def _unknown(what: str, bad: list[str], allowed: list[str], where: str) -> WrinklesInputError:
    return WrinklesInputError(f"unknown {what} {', '.join(map(repr, bad))}; allowed: "
                              f"{', '.join(allowed) or 'none'}", path=where)


def procedural_motion(name: str, *, skeleton: MotionSkeleton | None = None,
                      **params) -> Motion:
    """Generate a registered procedural motion.

    Args:
        name: a key of ``PROCEDURAL_MOTIONS``.
        skeleton: the body's skeleton and foot contacts
            (``MotionSkeleton.from_body(body, betas)``) so the feet meet the floor on that
            body; None for SMPL's approximate skeleton (``MotionSkeleton.default()``).
        **params: fields of that motion's params dataclass (``duration`` [s], ``fps`` ...).

    Raises:
        WrinklesInputError: unknown name (lists the names) or parameter (lists the fields), or
            a parameter out of range.
    """
    spec = PROCEDURAL_MOTIONS.get(name)
    if spec is None:
        raise WrinklesInputError(f"unknown motion {name!r}; available: "
                                 f"{', '.join(PROCEDURAL_MOTIONS)}")
    allowed = [f.name for f in dataclasses.fields(spec.params)]
    bad = [k for k in params if k not in allowed]
    if bad:
        raise _unknown(f"parameter(s) for '{name}'", bad, allowed, f"procedural:{name}")
    try:
        p = spec.params(**params)
    except TypeError as e:  # pragma: no cover - names are checked above
        raise WrinklesInputError(str(e), path=f"procedural:{name}") from None
    return spec.generate(p, skeleton=skeleton)


def load_motion(spec: str | os.PathLike, *, fps: float | None = None,
                duration: float | None = None, skeleton: MotionSkeleton | None = None,
                **params) -> Motion:
    """Load or generate a motion.

    Args:
        spec: a procedural name (see :func:`list_motions`) or a path to an ``.npz`` (AMASS) or
            ``.bvh`` file.
        fps: frame rate [1/s]; procedural motions are generated at it, files are resampled to
            it (slerp). None keeps the default / the file's rate.
        duration: length [s]; procedural motions are generated for it (their lead-in comes
            before it), files are cut to it (error when the file is shorter). None keeps the
            default / the whole file.
        skeleton: procedural motions are built on it (see :func:`procedural_motion`); a BVH
            file's rest alignment uses its joints unless ``rest_joints`` is given; ignored for
            AMASS files.
        **params: procedural params fields, or the file loader's keyword options
            (``load_amass``: pelvis_offset, up_axis, source_fps; ``load_bvh``: joint_map,
            scale, rest, rest_joints).

    Returns:
        the ``Motion``.

    Raises:
        WrinklesInputError: unknown name, extension or parameter; bad file contents.
    """
    text = os.fspath(spec)
    if text in PROCEDURAL_MOTIONS:
        extra = {k: v for k, v in (("fps", fps), ("duration", duration)) if v is not None}
        return procedural_motion(text, skeleton=skeleton, **extra, **params)
    ext = Path(text).suffix.lower()
    if ext in _FILE_LOADERS:
        loader = _FILE_LOADERS[ext]
        allowed = [n for n, prm in inspect.signature(loader).parameters.items()
                   if prm.kind is inspect.Parameter.KEYWORD_ONLY]
        bad = [k for k in params if k not in allowed]
        if bad:
            raise _unknown(f"option(s) for {ext} files", bad, allowed, text)
        if ext == ".bvh" and skeleton is not None:
            params.setdefault("rest_joints", skeleton.rest_joints)
        motion = loader(text, **params)
        if fps is not None:
            motion = resample_motion(motion, fps)
        if duration is not None:
            motion = trim_motion(motion, duration)
        return motion
    if ext:
        raise WrinklesInputError(f"unknown motion file type '{ext}'; use .npz (AMASS) or .bvh, "
                                 f"or a procedural name: {', '.join(PROCEDURAL_MOTIONS)}",
                                 path=text)
    raise WrinklesInputError(f"unknown motion {text!r}; available: "
                             f"{', '.join(PROCEDURAL_MOTIONS)}, or a path to an .npz / .bvh file")


def motion_parameters(name: str) -> list[tuple[str, object, str]]:
    """A procedural motion's parameters as ``(name, default, description)``.

    The descriptions come from the params class's ``Attributes:`` docstring, whose entries are
    ``name [unit]`` or ``name: text``, separated by ``;``.
    """
    import dataclasses
    import re

    spec = PROCEDURAL_MOTIONS.get(name)
    if spec is None:
        raise WrinklesInputError(f"unknown motion '{name}'; available: {', '.join(PROCEDURAL_MOTIONS)}")
    cls = spec.params
    doc = " ".join((cls.__doc__ or "").split())
    doc = doc.split("Attributes:", 1)[-1]
    docs: dict[str, str] = {}
    for part in doc.split(";"):
        m = re.match(r"\s*([a-z_0-9]+)\s*:?\s*(.*)", part.strip().rstrip("."))
        if m:
            docs.setdefault(m.group(1), m.group(2).strip())
    return [(f.name, f.default, docs.get(f.name, "")) for f in dataclasses.fields(cls)]


def accepts_parameter(name: str, param: str) -> bool:
    """Whether procedural motion ``name`` has a parameter ``param`` (False for files)."""
    import dataclasses

    spec = PROCEDURAL_MOTIONS.get(name)
    return spec is not None and param in {f.name for f in dataclasses.fields(spec.params)}
