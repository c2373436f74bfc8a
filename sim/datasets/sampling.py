"""Sample the sequences of a dataset from its config.

Sequence ``k`` is drawn from its own generator ``numpy.random.default_rng([seed, k])``, so it
does not depend on the shard that makes it, on the order of work, or on how many sequences the
config asks for (growing ``sequences`` keeps the first ones).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.datasets.config import DatasetConfig, motion_files


def sequence_id(index: int) -> str:
    return f"seq-{index:05d}"


@dataclass(frozen=True)
class SequenceSpec:
    """One sampled sequence.

    Attributes:
        index, id: position in the dataset and its id ("seq-00012").
        seed: the sequence's own seed (simulation, random motions).
        category, garment_params: garment template and its parameters.
        material: material preset.
        betas: body shape.
        motion: procedural motion name, or a motion file path.
        motion_params: procedural parameters (empty for files).
        motion_label: the motion's name (procedural name or file stem).
        split: "train", "test_id" or "test_ood".
    """

    index: int
    id: str
    seed: int
    category: str
    garment_params: dict = field(default_factory=dict)
    material: str = "cotton"
    betas: tuple[float, ...] = ()
    motion: str = "walk"
    motion_params: dict = field(default_factory=dict)
    motion_label: str = "walk"
    split: str = "train"

    def to_json(self) -> dict:
        return json.loads(json.dumps(dataclasses.asdict(self)))


def _draw(rng: np.random.Generator, v):
    if isinstance(v, (list, tuple)):
        return float(rng.uniform(v[0], v[1]))
    return v


def sample_sequence(cfg: DatasetConfig, index: int, files: list[Path] | None = None) -> SequenceSpec:
    """The ``index``-th sequence of the dataset (deterministic)."""
    from sim.motions import PROCEDURAL_MOTIONS

    rng = np.random.default_rng([cfg.seed, index])
    seed = int(rng.integers(0, 2**31 - 1))
    g = cfg.garments
    category = g.categories[int(rng.integers(len(g.categories)))]
    params = {k: _draw(rng, v) for k, v in sorted(g.params.get(category, {}).items())}
    material = cfg.materials.names[int(rng.integers(len(cfg.materials.names)))]
    b = cfg.bodies
    betas = np.clip(rng.normal(0.0, b.shape_std, b.betas), -b.shape_clip, b.shape_clip)
    files = motion_files(cfg) if files is None else files
    choices = [*cfg.motions.procedural, *map(str, files)]
    motion = choices[int(rng.integers(len(choices)))]
    if motion in cfg.motions.procedural:
        mparams = {k: _draw(rng, v) for k, v in sorted(cfg.motions.params.get(motion, {}).items())}
        fields_ = {f.name for f in dataclasses.fields(PROCEDURAL_MOTIONS[motion].params)}
        if "seed" in fields_ and "seed" not in mparams:
            mparams["seed"] = seed % 100_000
        label = motion
    else:
        mparams = {}
        label = Path(motion).stem
    u = float(rng.random())
    s = cfg.split
    if (label in s.ood_motions or category in s.ood_garments
            or float(np.linalg.norm(betas)) > s.ood_shape_norm):
        split = "test_ood"
    else:
        split = "test_id" if u < s.test_fraction else "train"
    return SequenceSpec(index=index, id=sequence_id(index), seed=seed, category=category,
                        garment_params=params,
                        material=material, betas=tuple(float(x) for x in betas), motion=motion,
                        motion_params=mparams, motion_label=label, split=split)


def sample_sequences(cfg: DatasetConfig) -> list[SequenceSpec]:
    """Every sequence of the dataset, in index order."""
    files = motion_files(cfg)
    return [sample_sequence(cfg, k, files) for k in range(cfg.sequences)]


def shard_indices(n: int, shard: int, shards: int) -> list[int]:
    """Indices of the sequences shard ``shard`` of ``shards`` makes (round robin: every shard
    gets a mix of garments and motions)."""
    return list(range(shard, n, shards))


def select_indices(specs: list[SequenceSpec], shard: int, shards: int,
                   splits: Sequence[str] | str | None = None) -> list[int]:
    """Indices of ``specs`` that shard ``shard`` of ``shards`` makes, only those of ``splits``
    (None: every split; a sequence's split comes from the config)."""
    from sim.datasets.schema import SPLITS
    from sim.errors import WrinklesInputError

    mine = shard_indices(len(specs), shard, shards)
    if splits is None:
        return mine
    splits = (splits,) if isinstance(splits, str) else tuple(splits)
    unknown = sorted(set(splits) - set(SPLITS))
    if unknown or not splits:
        raise WrinklesInputError(f"--splits: unknown split(s) {', '.join(unknown) or '(none)'}; choose from "
                                 f"{', '.join(SPLITS)}")
    return [k for k in mine if specs[k].split in splits]
