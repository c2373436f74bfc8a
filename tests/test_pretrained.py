"""The shipped default models (pretrained/): they load with weights_only, fit the size budget, and
animate a garment on CPU (the README's main command, in miniature)."""

from __future__ import annotations

import numpy as np
import pytest


def test_shipped_models_fit_the_budget():
    from learn.animate import PRETRAINED, available_pretrained

    assert available_pretrained(), "pretrained/ should ship at least one garment's models"
    total = sum(p.stat().st_size for p in PRETRAINED.glob("*.pt"))
    assert total <= 50 * 2**20, f"shipped weights are {total / 2**20:.1f} MiB (budget 50 MiB)"
    assert (PRETRAINED / "MODEL_CARD.md").exists()


@pytest.mark.parametrize("category", ["t_shirt", "straight_skirt"])
def test_shipped_pipeline_animates_on_cpu(category):
    from learn.animate import WrinklePipeline, available_pretrained, pretrained_paths
    from sim.motions import procedural_motion

    if category not in available_pretrained():
        pytest.skip(f"no shipped {category} models")
    coarse, wrinkles = pretrained_paths(category)
    pipe = WrinklePipeline(coarse, wrinkles, device="cpu")
    assert pipe.category == category and pipe.coarse.name == "skeleton_cvae"
    m = procedural_motion("walk", duration=0.2, fps=30.0)
    res = pipe(m.poses[:4], m.trans[:4] + np.array([0.0, 0.0, 0.0], np.float32), np.zeros(4), steps=2)
    assert res.vertices.shape == (4, len(pipe.rest), 3) and np.isfinite(res.vertices).all()
    # wrinkles are displacements of millimetres to centimetres on the base, never metres
    d = np.linalg.norm(res.vertices - res.base, axis=-1)
    assert 0 < d.max() < 0.1
