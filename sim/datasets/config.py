"""The dataset generator's config (TOML), checked completely before anything is simulated.

Every table and key is known (an unknown one is an error naming it), every range is checked,
and every user motion file is opened. A value to sample is either fixed (a number or a
string) or a range ``[lo, hi]`` (uniform). Example (``pipelines/configs/sample.toml`` is the
shipped one)::

    seed = 0
    sequences = 100          # sequences sampled (accepted + rejected)
    fps = 30.0
    seconds = 3.0            # motion length [s] of every sequence (its frames are stored; a
                             # procedural motion's lead-in from rest plays before, unstored)

    [garments]
    categories = ["t_shirt", "straight_skirt"]   # sampled uniformly
    fine_resolution = "fine"                     # edge length [m] or "coarse" / "fine"
    coarse_resolution = "coarse"
    fit = "body"             # "body": each garment built on its sequence's shape; "reference":
                             # on the mean shape (one topology per category and parameter set;
                             # the body morphs to the sequence's shape while the garment settles)
    [garments.params.t_shirt]                    # template parameters: fixed or [lo, hi]
    length = [0.38, 0.48]

    [materials]
    names = ["cotton", "jersey_knit"]

    [bodies]
    model = "default"        # or an SMPL-family model file
    betas = 4                # leading betas sampled, the rest are 0
    shape_std = 1.0          # betas ~ N(0, shape_std^2), clipped at +-shape_clip
    shape_clip = 2.5

    [motions]
    procedural = ["walk", "arm_raise"]
    files = ["~/amass/CMU"]  # AMASS .npz / .bvh files or folders (searched recursively)
    [motions.params.walk]
    speed = [1.0, 1.6]

    [split]
    test_fraction = 0.1      # in-distribution test share of the remaining sequences
    ood_motions = ["arm_raise"]   # these motions only in the out-of-distribution test
    ood_shape_norm = 2.0     # |betas| above this: out-of-distribution test
    ood_garments = []        # garment categories only in the out-of-distribution test

    [simulation]             # sim.simulate.SimulationConfig fields
    substeps = 0             # 0: automatic, 12 (14 over 10k garment vertices)
    iterations = 0           # 0: automatic, 5 sweeps per substep (8 over 10k garment vertices)
    # retry_factors = [1.6667, 2.0]  # a sequence failing a gate: again at these x substeps
                             # ([]: never; left out: automatic, [1.6667, 2.0] up to 10k garment
                             # vertices, none above: more substeps rescued 0 of 27 failing
                             # fine sequences, sim.simulate.config.FINE_RETRY_FACTORS)

    [derive]
    smoothing_length = 0.04  # base surface: wrinkles shorter than ~this [m] are removed
    image_resolution = 256   # UV images (0: none)
    coarse = true            # also simulate the coarse garment
    positions = "f32"        # stored positions: "f32" exact, "i16" half the bytes (~9 µm grid)
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sim.errors import WrinklesInputError

Range = float | str | tuple[float, float]


def _load_toml(path: Path) -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise WrinklesInputError("config file not found", path=path) from None
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise WrinklesInputError(f"not a readable TOML file ({e})", path=path) from None


@dataclass(frozen=True)
class GarmentsConfig:
    """Attributes:
        categories: template categories sampled uniformly.
        fine_resolution, coarse_resolution: "coarse", "fine" or an edge length [m].
        params: category -> template parameter -> fixed value or [lo, hi].
        fit: "body": each garment is built on its sequence's sampled shape; "reference": on
            the mean shape (betas 0), so all sequences of one category and parameter set share
            one mesh, and the body morphs from the mean shape to the sampled one during the
            settle (``sim.simulate.SimulationJob.garment_betas``). The cut keeps the clearance
            of the thickest of the config's materials, so every material shares it too.
    """

    categories: tuple[str, ...] = ("t_shirt",)
    fine_resolution: str | float = "fine"
    coarse_resolution: str | float = "coarse"
    params: dict = field(default_factory=dict)
    fit: str = "body"


GARMENT_FITS = ("body", "reference")
"""Allowed values of ``[garments] fit``."""


@dataclass(frozen=True)
class MaterialsConfig:
    """Attributes:
        names: material presets sampled uniformly.
    """

    names: tuple[str, ...] = ("cotton",)


@dataclass(frozen=True)
class BodiesConfig:
    """Attributes:
        model: "default" (the embedded body) or an SMPL-family model file (.npz / .pkl).
        betas: how many leading betas are sampled (the rest 0).
        shape_std: standard deviation of the sampled betas.
        shape_clip: |beta| limit.
    """

    model: str = "default"
    betas: int = 4
    shape_std: float = 1.0
    shape_clip: float = 2.5


@dataclass(frozen=True)
class MotionsConfig:
    """Attributes:
        procedural: procedural motion names (``wrinkles motions``).
        files: AMASS ``.npz`` / ``.bvh`` files or folders (searched recursively).
        params: procedural name -> parameter -> fixed value or [lo, hi].
    """

    procedural: tuple[str, ...] = ("walk",)
    files: tuple[str, ...] = ()
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SplitConfig:
    """Attributes:
        test_fraction: share of the in-distribution sequences kept for the test_id split.
        ood_motions: motions (procedural names or file stems) only in test_ood.
        ood_shape_norm: sequences whose |betas| exceeds this go to test_ood (inf: none).
        ood_garments: garment categories only in test_ood (a design no model trains on).
    """

    test_fraction: float = 0.1
    ood_motions: tuple[str, ...] = ()
    ood_shape_norm: float = float("inf")
    ood_garments: tuple[str, ...] = ()


POSITION_FORMATS = ("f32", "i16")
"""Allowed values of ``[derive] positions``."""


@dataclass(frozen=True)
class DeriveConfig:
    """Attributes:
        smoothing_length: base-surface smoothing length [m].
        image_resolution: UV image side [px] (0: no images).
        coarse: also simulate each sequence with the coarse garment.
        positions: how sequence files store positions: "f32" (exact) or "i16" (half the bytes,
            on a per-frame grid of the bounding box / 65533, ``sim.datasets.quantize``).
    """

    smoothing_length: float = 0.04
    image_resolution: int = 256
    coarse: bool = True
    positions: str = "f32"


@dataclass(frozen=True)
class DatasetConfig:
    """The generator config (see the module docstring for the TOML form).

    Attributes:
        seed: base seed; sequence k is sampled from ``(seed, k)`` alone, so shards agree.
        sequences: number of sequences to sample.
        fps: frame rate [1/s].
        seconds: motion length [s]: every sequence stores ``round(seconds * fps)`` frames of its
            motion, a procedural motion in full motion from the first (its lead-in from the
            rest pose, ``ramp`` seconds, plays in the simulation's prelude and is not stored).
        simulation: ``SimulationConfig`` fields (dict).
        source: the file it was read from ("" when built in code).
    """

    seed: int = 0
    sequences: int = 8
    fps: float = 30.0
    seconds: float = 2.0
    garments: GarmentsConfig = field(default_factory=GarmentsConfig)
    materials: MaterialsConfig = field(default_factory=MaterialsConfig)
    bodies: BodiesConfig = field(default_factory=BodiesConfig)
    motions: MotionsConfig = field(default_factory=MotionsConfig)
    split: SplitConfig = field(default_factory=SplitConfig)
    simulation: dict = field(default_factory=dict)
    derive: DeriveConfig = field(default_factory=DeriveConfig)
    source: str = ""

    def to_dict(self) -> dict:
        """JSON-ready dict (without ``source``), the form saved in the manifest."""
        d = dataclasses.asdict(self)
        d.pop("source")
        if not np.isfinite(d["split"]["ood_shape_norm"]):
            d["split"]["ood_shape_norm"] = None
        if d["garments"]["fit"] == "body":  # the default is left out: a manifest without the key
            d["garments"].pop("fit")         # is a "body" fit, and compares equal on --resume
        if d["derive"]["positions"] == "f32":  # likewise
            d["derive"].pop("positions")
        return _jsonable(d)

    def simulation_config(self):
        from sim.simulate import SimulationConfig

        return SimulationConfig.from_dict({**self.simulation, "fps": self.fps})


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x


_SECTIONS = {"garments": GarmentsConfig, "materials": MaterialsConfig, "bodies": BodiesConfig,
             "motions": MotionsConfig, "split": SplitConfig, "derive": DeriveConfig}


def _section(cls, d: Any, where: str, err):
    if not isinstance(d, dict):
        raise err(f"[{where}] must be a table")
    names = {f.name for f in dataclasses.fields(cls)}
    bad = sorted(set(d) - names)
    if bad:
        raise err(f"unknown key(s) {', '.join(bad)} in [{where}]; allowed: {', '.join(sorted(names))}")
    kw = {}
    for f in dataclasses.fields(cls):
        if f.name in d:
            v = d[f.name]
            kw[f.name] = tuple(v) if isinstance(v, list) and f.name not in ("params",) else v
    return cls(**kw)


def parse_config(data: dict, *, source: str | os.PathLike = "") -> DatasetConfig:
    """Build and validate a ``DatasetConfig`` from a parsed TOML dict.

    Raises:
        WrinklesInputError: the first problem, naming the file and the key.
    """
    src = os.fspath(source)

    def err(msg: str) -> WrinklesInputError:
        return WrinklesInputError(msg, path=src or "dataset config")

    top = {f.name for f in dataclasses.fields(DatasetConfig)} - {"source"}
    bad = sorted(set(data) - top)
    if bad:
        raise err(f"unknown key(s) {', '.join(bad)}; allowed: {', '.join(sorted(top))}")
    kw: dict = {k: data[k] for k in ("seed", "sequences", "fps", "seconds") if k in data}
    for name, cls in _SECTIONS.items():
        if name in data:
            kw[name] = _section(cls, data[name], name, err)
    if "simulation" in data:
        if not isinstance(data["simulation"], dict):
            raise err("[simulation] must be a table")
        kw["simulation"] = dict(data["simulation"])
    cfg = DatasetConfig(**kw, source=src)
    validate(cfg, err)
    return cfg


def load_config(path: str | os.PathLike) -> DatasetConfig:
    """Read and validate a generator config: a TOML path, or the name of a shipped config
    (``sample``: ``pipelines/configs/sample.toml``)."""
    p = Path(os.path.expanduser(os.fspath(path)))
    if not p.suffix and not p.exists():
        shipped = Path(__file__).resolve().parents[2] / "pipelines" / "configs" / f"{p.name}.toml"
        if shipped.exists():
            p = shipped
    return parse_config(_load_toml(p), source=p)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)


def _check_range(v, where: str, err) -> None:
    if isinstance(v, (list, tuple)):
        if len(v) != 2 or not all(_is_number(x) for x in v):
            raise err(f"{where} must be a number or a range [lo, hi], got {v!r}")
        if v[0] > v[1]:
            raise err(f"{where}: range [{v[0]}, {v[1]}] has lo > hi")
    elif not (_is_number(v) or isinstance(v, str)):
        raise err(f"{where} must be a number, a string or a range [lo, hi], got {v!r}")


def _ends(params: dict) -> list[dict]:
    """The parameter sets at the low and high ends of every range."""
    lo = {k: (v[0] if isinstance(v, (list, tuple)) else v) for k, v in params.items()}
    hi = {k: (v[1] if isinstance(v, (list, tuple)) else v) for k, v in params.items()}
    return [lo, hi]


def motion_files(cfg: DatasetConfig) -> list[Path]:
    """The user motion files the config names (folders expanded, sorted)."""
    out: list[Path] = []
    for entry in cfg.motions.files:
        p = Path(os.path.expanduser(entry))
        if not p.is_absolute() and cfg.source:
            p = Path(cfg.source).parent / p
        if p.is_dir():
            found = sorted(q for q in p.rglob("*") if q.suffix.lower() in (".npz", ".bvh"))
            out.extend(found)
        else:
            out.append(p)
    return out


def _is_count(v, lo: int) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= lo


def validate(cfg: DatasetConfig, err=None) -> None:
    """Check every value and open every user motion file (raises ``WrinklesInputError``)."""
    if err is None:
        def err(msg: str) -> WrinklesInputError:
            return WrinklesInputError(msg, path=cfg.source or "dataset config")

    _check_top(cfg, err)
    body = _check_garments(cfg, err)
    _check_materials(cfg, err)
    _check_bodies(cfg, body, err)
    stems = _check_motions(cfg, err)
    _check_split(cfg, stems, err)
    _check_derive(cfg, err)
    try:
        cfg.simulation_config()
    except WrinklesInputError as e:
        raise err(f"[simulation] {e}") from None
    except (TypeError, ValueError) as e:
        raise err(f"[simulation] {e}") from None


def _check_top(cfg: DatasetConfig, err) -> None:
    if not _is_count(cfg.seed, 0):
        raise err(f"seed must be an integer >= 0, got {cfg.seed!r}")
    if not _is_count(cfg.sequences, 1):
        raise err(f"sequences must be an integer >= 1, got {cfg.sequences!r}")
    for name in ("fps", "seconds"):
        v = getattr(cfg, name)
        if not (_is_number(v) and v > 0):
            raise err(f"{name} must be a positive number, got {v!r}")
    if cfg.fps > 240:
        raise err(f"fps {cfg.fps} is above 240")


def _check_garments(cfg: DatasetConfig, err):
    """``[garments]``, every category built at the ends of its ranges; the body model loaded."""
    from sim.garments.templates import TEMPLATES, resolve_resolution

    g = cfg.garments
    if not g.categories:
        raise err("[garments] categories is empty")
    for c in g.categories:
        if c not in TEMPLATES:
            raise err(f"[garments] unknown category {c!r}; available: {', '.join(TEMPLATES)}")
    if not (isinstance(g.fit, str) and g.fit in GARMENT_FITS):
        raise err(f"[garments] fit must be one of {', '.join(repr(f) for f in GARMENT_FITS)}, got {g.fit!r}")
    for name in ("fine_resolution", "coarse_resolution"):
        for c in g.categories:
            try:
                resolve_resolution(getattr(g, name), c)
            except WrinklesInputError as e:
                raise err(f"[garments] {name}: {e}") from None
    _check_garment_params(g, err)
    return _check_garments_build(cfg, err)


def _check_garment_params(g: GarmentsConfig, err) -> None:
    from sim.garments.templates import make_params

    if not isinstance(g.params, dict):
        raise err("[garments.params] must be a table of categories")
    for c, params in g.params.items():
        if c not in g.categories:
            raise err(f"[garments.params.{c}] is not one of the categories {list(g.categories)}")
        if not isinstance(params, dict):
            raise err(f"[garments.params.{c}] must be a table")
        for k, v in params.items():
            _check_range(v, f"[garments.params.{c}] {k}", err)
        for end in _ends(params):
            try:
                make_params(c, **end)
            except (WrinklesInputError, ValueError, TypeError) as e:
                raise err(f"[garments.params.{c}] {e}") from None


def _check_garments_build(cfg: DatasetConfig, err):
    """Every category at the ends of its ranges, on the mean body, at the coarse resolution: a
    combination the template cannot build fails here, not hours into a run. Returns the body."""
    from sim.bodies import load_body
    from sim.garments import make_garment

    g = cfg.garments
    try:
        body = load_body(cfg.bodies.model)
    except WrinklesInputError as e:
        raise err(f"[bodies] model: {e}") from None
    for c in g.categories:
        for end in _ends(g.params.get(c, {})):
            try:
                make_garment(c, body, None, resolution=g.coarse_resolution, **end)
            except (WrinklesInputError, ValueError, FloatingPointError) as e:
                raise err(f"[garments.params.{c}] {end}: {e}") from None
    return body


def _check_materials(cfg: DatasetConfig, err) -> None:
    from sim.garments import MATERIALS

    if not cfg.materials.names:
        raise err("[materials] names is empty")
    for m in cfg.materials.names:
        if m not in MATERIALS:
            raise err(f"[materials] unknown material {m!r}; available: {', '.join(MATERIALS)}")


def _check_bodies(cfg: DatasetConfig, body, err) -> None:
    b = cfg.bodies
    nb = int(body.num_betas) if hasattr(body, "num_betas") else 300
    if not (_is_count(b.betas, 0) and b.betas <= nb):
        raise err(f"[bodies] betas must be an integer in 0..{nb} (the body model's shape count), "
                  f"got {b.betas!r}")
    for name in ("shape_std", "shape_clip"):
        v = getattr(b, name)
        if not (_is_number(v) and v >= 0):
            raise err(f"[bodies] {name} must be a number >= 0, got {v!r}")


def _check_motions(cfg: DatasetConfig, err) -> list[str]:
    """``[motions]``, every user file opened; the files' stems."""
    from sim.motions import PROCEDURAL_MOTIONS, load_motion

    mo = cfg.motions
    if not mo.procedural and not mo.files:
        raise err("[motions] names no procedural motion and no files")
    for name in mo.procedural:
        if name not in PROCEDURAL_MOTIONS:
            raise err(f"[motions] unknown procedural motion {name!r}; available: "
                      f"{', '.join(PROCEDURAL_MOTIONS)}")
    _check_motion_params(cfg, err)
    stems = []
    for f in motion_files(cfg):
        try:
            load_motion(f, fps=cfg.fps, duration=cfg.seconds)
        except WrinklesInputError as e:
            raise err(f"[motions] files: {e}") from None
        stems.append(f.stem)
    if mo.files and not stems:
        raise err(f"[motions] files {list(mo.files)} hold no .npz or .bvh file")
    return stems


def _check_motion_params(cfg: DatasetConfig, err) -> None:
    from sim.motions import procedural_motion

    mo = cfg.motions
    if not isinstance(mo.params, dict):
        raise err("[motions.params] must be a table of motion names")
    for name, params in mo.params.items():
        if name not in mo.procedural:
            raise err(f"[motions.params.{name}] is not one of the procedural motions {list(mo.procedural)}")
        if not isinstance(params, dict):
            raise err(f"[motions.params.{name}] must be a table")
        for k, v in params.items():
            if k in ("fps", "duration"):
                raise err(f"[motions.params.{name}] {k} is set by the top-level fps / seconds")
            _check_range(v, f"[motions.params.{name}] {k}", err)
        for end in _ends(params):
            try:
                procedural_motion(name, fps=cfg.fps, duration=min(cfg.seconds, 0.5), **end)
            except (WrinklesInputError, ValueError, TypeError) as e:
                raise err(f"[motions.params.{name}] {e}") from None


def _check_split(cfg: DatasetConfig, stems: list[str], err) -> None:
    s = cfg.split
    if not (_is_number(s.test_fraction) and 0 <= s.test_fraction < 1):
        raise err(f"[split] test_fraction must be in [0, 1), got {s.test_fraction!r}")
    known = set(cfg.motions.procedural) | set(stems)
    for name in s.ood_motions:
        if name not in known:
            raise err(f"[split] ood_motions: {name!r} is not a configured motion")
    if set(known) and set(known) <= set(s.ood_motions):
        raise err("[split] ood_motions holds every motion: nothing is left to train on")
    if not (isinstance(s.ood_shape_norm, (int, float)) and s.ood_shape_norm > 0):
        raise err(f"[split] ood_shape_norm must be > 0, got {s.ood_shape_norm!r}")
    for name in s.ood_garments:
        if name not in cfg.garments.categories:
            raise err(f"[split] ood_garments: {name!r} is not a configured garment category")
    if cfg.garments.categories and set(cfg.garments.categories) <= set(s.ood_garments):
        raise err("[split] ood_garments holds every garment category: nothing is left to train on")


def _check_derive(cfg: DatasetConfig, err) -> None:
    d = cfg.derive
    if not (_is_number(d.smoothing_length) and 0 < d.smoothing_length <= 1.0):
        raise err(f"[derive] smoothing_length must be in (0, 1] m, got {d.smoothing_length!r}")
    res = d.image_resolution
    if not (_is_count(res, 0) and (res == 0 or 16 <= res <= 4096)):
        raise err(f"[derive] image_resolution must be 0 or an integer in 16..4096, got {res!r}")
    if not isinstance(d.coarse, bool):
        raise err(f"[derive] coarse must be true or false, got {d.coarse!r}")
    if d.positions not in POSITION_FORMATS:
        raise err(f"[derive] positions must be one of {', '.join(map(repr, POSITION_FORMATS))}, "
                  f"got {d.positions!r}")
