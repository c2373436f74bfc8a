"""Reference-shape dressing (``sim.datasets.generate.garment_betas``,
``sim.simulate.morph_settle``; the dataset's ``[garments] fit = "reference"``): one garment mesh
built on the mean shape worn by other shapes.
Tiny CPU cases: coarse skirt (7 cm edges), few substeps, fractions of a second."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.simulate import SimulationConfig, morph_frames, morph_settle, simulate

RES = 0.07  # template edge length [m] (the sample config's coarse resolution)
# 5 x 5: at 3 x 3 the coarse system factored at the substep start leaves 5 of the skirt's 164
# vertices up to 1.06 mm inside the body at the settle's end (CPU)
FAST = dict(fps=30.0, substeps=5, iterations=5, settle_seconds=0.5, blend_seconds=0.1, device="cpu")
TARGET = np.array([1.5, -1.0], np.float32)


@pytest.fixture(scope="module")
def body():
    from sim.bodies import load_body

    return load_body()


@pytest.fixture(scope="module")
def skirt(body):
    from sim.garments import make_garment

    return make_garment("straight_skirt", body, None, resolution=RES)


def walk(body, duration: float, betas=None):
    from sim.motions import MotionSkeleton, load_motion

    return load_motion("walk", fps=30, duration=duration, skeleton=MotionSkeleton.from_body(body, betas),
                       ramp=0.2)


@pytest.fixture(scope="module")
def morphed_run(body, skirt):
    """The mean-shape skirt on the TARGET body, prelude kept."""
    cfg = SimulationConfig(**FAST, keep_prelude=True)
    motion = walk(body, 0.1, TARGET)
    res = simulate(skirt, body, motion, betas=TARGET, garment_betas=np.zeros(2), config=cfg)
    return res, cfg, motion


def test_morph_settle_interpolates_rest_meshes(body):
    from sim.motions.blend import blend_from_rest

    motion = walk(body, 0.2)
    timeline, _ = blend_from_rest(motion, 0.1, hold=0.3)
    n = 9
    ref = body.pose(body.full_betas(None), timeline.poses, timeline.trans)
    tgt = body.pose(body.full_betas(TARGET), timeline.poses, timeline.trans)
    m = morph_settle(ref, tgt, n)
    trans0 = timeline.trans[0]
    np.testing.assert_allclose(m.vertices[0], body.rest_mesh(body.full_betas(None)) + trans0, atol=1e-5)
    np.testing.assert_allclose(m.vertices[0], ref.vertices[0], atol=1e-6)
    k = morph_frames(n)
    assert 1 <= k < n  # the cloth gets the last frames of the settle on the target shape
    for t in range(k, n + 1):
        np.testing.assert_allclose(m.vertices[t], body.rest_mesh(body.full_betas(TARGET)) + trans0,
                                   atol=1e-5)
    np.testing.assert_array_equal(m.vertices[n + 1:], tgt.vertices[n + 1:])
    np.testing.assert_array_equal(m.joints[n + 1:], tgt.joints[n + 1:])
    # in between: the rest mesh of the interpolated shape (blend shapes linear in the betas)
    w = (m.vertices[2, 0] - ref.vertices[2, 0]) / (tgt.vertices[2, 0] - ref.vertices[2, 0])
    w = float(np.median(w))
    assert 0.0 < w < 1.0
    mid = body.pose(body.full_betas(w * TARGET), timeline.poses[:1], timeline.trans[:1])
    np.testing.assert_allclose(m.vertices[2], mid.vertices[0], atol=1e-5)
    np.testing.assert_allclose(m.joints[2], mid.joints[0], atol=1e-5)
    np.testing.assert_allclose(m.transforms[2], mid.transforms[0], atol=1e-5)
    # monotone, smooth: no step larger than the linear ramp's peak slope 1.5 / k
    steps = np.linalg.norm(np.diff(m.vertices[: n + 1], axis=0), axis=-1).max(axis=1)
    total = np.linalg.norm(tgt.vertices[0] - ref.vertices[0], axis=-1).max()
    assert steps.max() <= 1.5 * total / k + 1e-6
    with pytest.raises(ValueError, match="frames"):
        morph_settle(ref, tgt, ref.num_frames)


def test_same_shape_is_bit_identical(body, skirt):
    cfg = SimulationConfig(**{**FAST, "settle_seconds": 0.2})
    motion = walk(body, 0.1)
    plain = simulate(skirt, body, motion, config=cfg)
    same = simulate(skirt, body, motion, garment_betas=np.zeros(2), config=cfg)
    np.testing.assert_array_equal(same.sequence.vertices, plain.sequence.vertices)
    np.testing.assert_array_equal(same.sequence.body.vertices, plain.sequence.body.vertices)
    assert same.sequence.provenance["garment"]["betas"] == [0.0] * body.num_betas
    assert "betas" not in plain.sequence.provenance["garment"]


def test_mean_shape_garment_dressed_on_another_shape(morphed_run, body, skirt):
    res, cfg, motion = morphed_run
    seq = res.sequence
    n = cfg.settle_frames
    k = cfg.entry_frames(motion)
    assert seq.vertices.shape[1:] == (skirt.num_vertices, 3)
    assert seq.vertices.shape[0] == n + k + motion.num_frames
    assert np.isfinite(seq.vertices).all()
    # the body: the garment's (mean) rest mesh at frame 0, the target's at the end of the settle
    dy = seq.provenance["ground_offset_m"]
    off = motion.extra["lead_in"].trans[0] + np.array([0.0, dy, 0.0], np.float32)
    np.testing.assert_allclose(seq.body.vertices[0], body.rest_mesh(body.full_betas(None)) + off, atol=1e-5)
    np.testing.assert_allclose(seq.body.vertices[n], body.rest_mesh(body.full_betas(TARGET)) + off,
                               atol=1e-5)
    # grounded on the target shape at the motion's first frame
    assert abs(float(seq.body.vertices[n + k, :, 1].min())) < 1e-5
    # the garment came to rest outside the bigger body
    assert res.quality.inside_fraction[n] <= cfg.gates.max_inside_fraction
    # without the morph, the mean-shape skirt starts inside the bigger body
    plain = simulate(skirt, body, motion, betas=TARGET, config=cfg)
    assert plain.quality.inside_fraction[0] > cfg.gates.max_inside_fraction
    assert seq.provenance["garment"]["betas"] == [0.0] * body.num_betas
    assert seq.provenance["body"]["betas"][:2] == pytest.approx(TARGET.tolist())
    # the pinned waistband followed the morph: it hugs the target waist, not the mean one
    from sim.dressing import attachment_vertices, bind_to_surface

    pins = attachment_vertices(skirt.attachments, cfg.pinned)
    b = bind_to_surface(seq.vertices[0], seq.body.vertices[0], body.faces, vertices=pins, device="cpu")
    np.testing.assert_allclose(seq.vertices[n, pins], b.targets(seq.body.vertices[n]), atol=2e-3)


def test_morph_needs_a_settle(body, skirt):
    cfg = SimulationConfig(**{**FAST, "settle_seconds": 0.0})
    with pytest.raises(WrinklesInputError, match="settle"):
        simulate(skirt, body, walk(body, 0.1), betas=TARGET, garment_betas=np.zeros(2), config=cfg)


TINY = """\
seed = 1
sequences = 2
fps = 30.0
seconds = 0.1

[garments]
categories = ["straight_skirt"]
fine_resolution = 0.07
coarse_resolution = 0.1
fit = "reference"
[garments.params.straight_skirt]
length = 0.5

[materials]
names = ["cotton"]

[bodies]
betas = 2
shape_std = 1.0

[motions]
procedural = ["walk"]

[split]
test_fraction = 0.0

[simulation]
substeps = 2
iterations = 2
settle_seconds = 0.2
blend_seconds = 0.1
self_contact = false
gates = {max_self_intersections = 1000, max_edge_strain = 5.0, max_inside_fraction = 1.0}

[derive]
smoothing_length = 0.1
image_resolution = 0
coarse = false
"""


def test_reference_fit_dataset_shares_the_topology(tmp_path: Path):
    from sim.datasets import storage as S
    from sim.datasets.config import load_config
    from sim.datasets.generate import generate

    p = tmp_path / "tiny.toml"
    p.write_text(TINY)
    cfg = load_config(p)
    assert cfg.garments.fit == "reference" and cfg.to_dict()["garments"]["fit"] == "reference"
    out = tmp_path / "data"
    summary = generate(cfg, out, device="cpu", batch=2)
    assert summary.accepted == 2, summary
    m = S.read_manifest(out)
    files = [S.SequenceFile(out / e["file"]) for e in m["sequences"].values()]
    betas = [np.asarray(f["body/betas"]) for f in files]
    assert np.abs(np.subtract(betas[0], betas[1])).max() > 1e-3, betas
    np.testing.assert_array_equal(files[0]["fine/faces"], files[1]["fine/faces"])
    np.testing.assert_array_equal(files[0]["fine/rest_vertices"], files[1]["fine/rest_vertices"])
    for e, f in zip(m["sequences"].values(), files, strict=True):
        entry = json.loads(f.metadata["entry"])
        assert entry["fit"] == e["fit"] == "reference"
        assert entry["garment_betas"] == [0.0, 0.0] and entry["betas"] != [0.0, 0.0]
        assert f.shape("fine/vertices")[1] == e["vertices"]


def test_bad_fit_is_refused_naming_the_key(tmp_path: Path):
    from sim.datasets.config import load_config

    p = tmp_path / "bad.toml"
    p.write_text(TINY.replace('fit = "reference"', 'fit = "tight"'))
    with pytest.raises(WrinklesInputError, match="fit"):
        load_config(p)
    p.write_text(TINY.replace('fit = "reference"\n', ""))
    assert "fit" not in load_config(p).to_dict()["garments"]  # the default: configs made before still match
