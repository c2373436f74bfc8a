"""Command-line options the commands share: ``--device/--seed/--quiet`` of every heavy command,
and those of the commands that pose a body with a motion (``wrinkles body``, ``simulate``,
``animate``): their arguments, parsing, and loading the body and motion they name."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from sim.errors import WrinklesInputError


def add_common_arguments(p: argparse.ArgumentParser, *, seed: bool = True, device: bool = True) -> None:
    """``--device``, ``--seed``, ``--quiet``: the options every heavy command shares."""
    if device:
        p.add_argument("--device", default="auto",
                       help="Warp device: auto (cuda when present, else cpu), cpu, cuda, cuda:N "
                            "(default: %(default)s)")
    if seed:
        p.add_argument("--seed", type=int, default=0,
                       help="random seed; the same seed gives the same result on the same device "
                            "(default: %(default)s)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars")


REST_HELP = ("what a BVH file's rest pose (all rotations zero) stands for. auto: SMPL's T-pose with the "
             "file's limb directions (thighs, shins, upper arms and forearms point as in the file, so an "
             "A-pose rest or CMU's spread legs stay so), the hands continuing the forearms, the torso "
             "upright, the head level and the feet flat. tpose: SMPL's T-pose as it is. file: every bone, "
             "spine, neck, head and hands included, points as in the file (this tilts the head and bends "
             "the wrists where the skeleton places those joints differently from SMPL). BVH files only: "
             "AMASS and procedural motions are SMPL rotations already, and --rest with them is refused "
             "(default: auto)")
"""``--rest`` help, beside ``sim.motions.bvh.REST_MODES`` whose meanings it states."""


def add_motion_arguments(p: argparse.ArgumentParser) -> None:
    """``--motion``, ``--motion-param`` (alias ``--param``), ``--rest``, ``--duration``, ``--fps``."""
    p.add_argument("--motion", default="walk",
                   help="procedural motion name, or an AMASS .npz / .bvh file (default: %(default)s)")
    p.add_argument("--motion-param", "--param", dest="motion_param", action="append", default=[],
                   metavar="KEY=VALUE",
                   help="a motion parameter, e.g. --motion-param speed=1.6 (repeatable; 'wrinkles motions "
                        "--params' lists each procedural motion's parameters; for a file, the loader's "
                        "options, e.g. scale=0.01 for a BVH in centimetres); --param is the same option")
    p.add_argument("--rest", default=None, metavar="{auto,tpose,file}", help=REST_HELP)
    p.add_argument("--duration", type=float, default=None,
                   help="length of a procedural motion [s], or where to cut a file (default: the "
                        "motion's own)")
    p.add_argument("--fps", type=float, default=30.0,
                   help="output frame rate [1/s]; files are resampled to it (default: %(default)s)")


SHAPE_RANGES_HELP = ("height 0.1-0.7 (about 1.33-2.11 m; mean 0.39), weight 0-1 (0.55), muscle 0-1 (0.43), "
                     "gender 0-1 (0 male, 1 female), proportions 0-1, age 0.77-0.9 (18 to 83 years)")
"""The default body's phenotype ranges for ``--help`` (``sim.bodies.default.phenotype_ranges``,
held to it by a test; written out so that ``--help`` loads no body)."""


def add_body_arguments(p: argparse.ArgumentParser) -> None:
    """``--body``, ``--shape``."""
    p.add_argument("--body", default="default",
                   help="'default' (embedded body) or an SMPL/SMPL-H/SMPL-X model file (.npz/.pkl)")
    p.add_argument("--shape", default=None,
                   help="body shape: comma-separated betas within +-5 ('0.5,-1.2'; the first is mostly "
                        "size) or, for the default body, named phenotype values ('height=0.6,weight=0.3'): "
                        f"{SHAPE_RANGES_HELP}")


NUMBER_LIST_OPTIONS = ("--shape",)
"""Options whose value may be a comma list of numbers starting with a minus sign (betas)."""


def _is_number_list(token: str) -> bool:
    try:  # an empty item ("-1,,2") fails float() too
        [float(x) for x in token.split(",")]
    except ValueError:
        return False
    return True


def join_negative_values(argv: list[str], options: tuple[str, ...] = NUMBER_LIST_OPTIONS) -> list[str]:
    """``["--shape", "-1.2,0.5"]`` -> ``["--shape=-1.2,0.5"]``.

    argparse takes a value that starts with ``-`` for an option unless it is one plain negative
    number, so betas whose first value is negative would stop with "expected one argument". A
    value of one of ``options`` that is a comma list of numbers is joined to its option; every
    other token, and everything after ``--``, is kept as it is.
    """
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if a == "--":
            return out + list(argv[i:])
        value = argv[i + 1] if i + 1 < len(argv) else ""
        if a in options and value.startswith("-") and _is_number_list(value):
            out.append(f"{a}={value}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def parse_params(items: list[str], flag: str) -> dict[str, float | str]:
    """``["speed=1.5", "side=left"]`` -> ``{"speed": 1.5, "side": "left"}`` (numbers where they parse)."""
    out: dict[str, float | str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise WrinklesInputError(f"{flag} {item!r}: expected KEY=VALUE")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            out[key.strip()] = value.strip()
    return out


def parse_numbers(items: list[str], flag: str) -> dict[str, float]:
    """Like ``parse_params`` but every value must be a number."""
    out = {}
    for key, value in parse_params(items, flag).items():
        if not isinstance(value, float) or not np.isfinite(value):
            raise WrinklesInputError(f"{flag} {key}={value}: the value must be a finite number")
        out[key] = value
    return out


def parse_resolution(spec: str) -> str | float:
    """``--resolution``: ``coarse``, ``fine`` or an edge length in metres (one-line error otherwise)."""
    if spec in ("coarse", "fine"):
        return spec
    try:
        return float(spec)
    except ValueError:
        raise WrinklesInputError(f"--resolution {spec!r}: expected coarse, fine or an edge length in "
                                 "metres") from None


def parse_body_shape(body, spec: str | None) -> np.ndarray | None:
    """Betas from ``--shape`` for this body (phenotype names only for the default body)."""
    if spec is None:
        return None
    if body.kind == "default":
        from sim.bodies.default import parse_shape

        return parse_shape(spec)
    from sim.bodies.default import check_betas

    try:
        betas = np.array([float(x) for x in spec.split(",") if x.strip()], dtype=np.float32)
    except ValueError as e:
        raise WrinklesInputError(
            f"--shape {spec!r}: an SMPL-family body takes comma-separated betas "
            f"(named phenotypes are for the default body)") from e
    check_betas(betas, spec)
    return betas


def check_fps(fps: float) -> None:
    if not (np.isfinite(fps) and fps > 0):
        raise WrinklesInputError(f"--fps must be a positive number, got {fps}")


@dataclass(frozen=True)
class BodyAndMotion:
    """What ``--body/--shape/--motion/--motion-param/--rest/--duration/--fps`` resolve to.

    Attributes:
        body: the ``BodyModel``.
        betas: the shape used (B,): ``--shape``, else the motion's own (AMASS), else the mean.
        motion: the motion at ``--fps``.
        params: the procedural parameters (with the seed where the motion takes one), or a file
            loader's options (a BVH's ``rest`` included).
    """

    body: object
    betas: np.ndarray
    motion: object
    params: dict


def motion_params(args: argparse.Namespace) -> dict[str, float | str]:
    """``--motion-param`` items with ``--rest``, checked before anything loads.

    ``--rest`` sets a BVH file's ``rest`` option (``auto`` when not given, recorded with the
    parameters); for any other motion it is refused, as is a rest given both ways.
    """
    from pathlib import Path

    from sim.motions.bvh import REST_MODES

    params = parse_params(args.motion_param, "--motion-param")
    is_bvh = Path(str(args.motion)).suffix.lower() == ".bvh"
    if args.rest is not None:
        if args.rest not in REST_MODES:
            raise WrinklesInputError(f"--rest {args.rest!r}: expected one of {', '.join(REST_MODES)}")
        if not is_bvh:
            raise WrinklesInputError(f"--rest applies to BVH files; the motion {args.motion!r} is already in "
                                     "SMPL's rotations (zero is SMPL's T-pose)")
        if "rest" in params:
            raise WrinklesInputError("the rest pose is given twice (--rest and --motion-param rest=...); "
                                     "keep --rest")
        params["rest"] = args.rest
    elif is_bvh:
        params.setdefault("rest", "auto")
    return params


def load_body_and_motion(args: argparse.Namespace) -> BodyAndMotion:
    """Load the body and motion the shared options name (``args.seed`` seeds random motions).

    Procedural motions place the feet with the body's own joints and soles; a BVH file's rest
    alignment uses the body's own joints too, and an AMASS file's Z-up to Y-up translation the
    body's pelvis at the shape it is posed with.
    """

    from sim.bodies import load_body
    from sim.motions import MotionSkeleton, accepts_parameter, load_motion
    from sim.motions.amass import place_pelvis
    from sim.simulate import resolve_betas

    check_fps(args.fps)
    params = motion_params(args)
    body = load_body(args.body)
    shape = parse_body_shape(body, args.shape)
    if accepts_parameter(args.motion, "seed"):
        params.setdefault("seed", args.seed)
    skeleton = MotionSkeleton.from_body(body, shape)
    motion = load_motion(args.motion, fps=args.fps, duration=args.duration, skeleton=skeleton, **params)
    betas = resolve_betas(body, motion, shape)
    motion = place_pelvis(motion, body.rest_joints(betas)[body.body_joint_map[0]])
    return BodyAndMotion(body, betas, motion, params)


def toml_value(raw: str):
    """A command-line value as TOML reads it (numbers, booleans, quoted strings, lists); a bare
    word that is not TOML is taken as text (``--set``, ``--predict``)."""
    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw
