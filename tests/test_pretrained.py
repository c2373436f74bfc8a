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


def test_shipped_deepwrinkles_animates_the_t_shirt_with_its_maps(tmp_path):
    """`wrinkles animate --method deepwrinkles` without --model takes the shipped t-shirt model:
    the garment sits on the torso of the default body and its per-frame normal maps carry
    wrinkles (tangent-space xy well away from a flat map) that follow the motion."""
    from pxr import Usd, UsdGeom

    from learn.animate import shipped_categories
    from pipelines.cli import main
    from usd_io.textures import decode_normal_map, normal_texture_files, read_png

    if "t_shirt" not in shipped_categories("deepwrinkles"):
        pytest.skip("no shipped DeepWrinkles t-shirt")
    out = tmp_path / "dw.usda"
    assert main(["animate", "--method", "deepwrinkles", "--garment", "t_shirt", "--motion", "walk",
                 "--duration", "0.3", "--out", str(out), "-q", "--device", "cpu"]) == 0
    stage = Usd.Stage.Open(str(out))
    points = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/World/Garments/t_shirt")).GetPointsAttr().Get(0))
    lo, hi = points.min(0), points.max(0)
    assert 0.8 < lo[1] < hi[1] < 1.6 and hi[0] - lo[0] < 0.8, f"garment bounds {lo} .. {hi} m (y up)"
    files = normal_texture_files(stage, "/World/Looks/t_shirtMaterial")
    maps = [decode_normal_map(read_png(f)) for _, f in files]
    assert len(maps) == 9 and maps[0].shape == (256, 256, 3)
    assert min(float(m[..., :2].std()) for m in maps) > 0.03, "the maps are nearly flat"
    assert float(np.abs(maps[-1] - maps[0]).mean()) > 0.005, "the maps do not change with the motion"
