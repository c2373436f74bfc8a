"""Dataset report (pipelines/dataset_report.py): pictures exist and are not blank, the numbers in
report.json are numpy's over the same data, errors leave nothing behind."""

from __future__ import annotations

import argparse
import json
import os

import numpy as np
import pytest

from pipelines import dataset_report as dr
from pipelines.preview import BODY_COLOR
from sim.datasets.storage import MANIFEST, SequenceFile, atomic_write_json, sequence_path, write_sequence
from sim.errors import WrinklesInputError

pytest.importorskip("pyvista")
pytest.importorskip("matplotlib")
Image = pytest.importorskip("PIL.Image")

T = 5
NX, NY = 10, 12      # grid sheet: 120 vertices, 198 faces
IMG = 24             # UV image resolution
TILE = (96, 96)


def _grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 0.5 m x 0.6 m sheet in the XY plane: rest vertices (V, 3), faces (F, 3), uvs (V, 2)."""
    xs, ys = np.meshgrid(np.linspace(-0.25, 0.25, NX), np.linspace(0.0, 0.6, NY))
    rest = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1).astype(np.float32)
    faces = []
    for j in range(NY - 1):
        for i in range(NX - 1):
            a = j * NX + i
            faces += [[a, a + 1, a + NX + 1], [a, a + NX + 1, a + NX]]
    uvs = np.stack([(xs.ravel() + 0.25) / 0.5, ys.ravel() / 0.6], axis=1).astype(np.float32)
    return rest, np.asarray(faces, np.int32), uvs


def _sequence(index: int, *, images: bool, height: float = 0.8) -> dict[str, np.ndarray]:
    """A waving sheet: wrinkles along z, a known strain and known quality values."""
    rng = np.random.default_rng(index)
    rest, faces, uvs = _grid()
    V, F = len(rest), len(faces)
    t = np.arange(T, dtype=np.float32)[:, None]
    wave = (0.01 * (index + 1) * np.sin(8.0 * rest[None, :, 0] + 0.7 * t)).astype(np.float32)
    base = np.broadcast_to(rest + np.float32([0.0, height, 0.0]), (T, V, 3)).copy()
    fine = base.copy()
    fine[..., 2] += wave
    wrinkle = np.zeros((T, V, 3), np.float32)
    wrinkle[..., 2] = wave
    wrinkle[..., :2] = rng.normal(0.0, 1e-3, (T, V, 2))
    strain = rng.gamma(2.0, 0.01 * (index + 1), (T, F, 3)).astype(np.float32)
    normals = np.broadcast_to(np.float32([0.0, 0.0, 1.0]), (T, V, 3)).copy()
    arrays = {
        "fine/vertices": fine, "fine/base": base, "fine/wrinkle": wrinkle, "fine/strain": strain,
        "fine/strain_norm": np.linalg.norm(strain, axis=2).astype(np.float32), "fine/normals": normals,
        "fine/rest_vertices": rest, "fine/faces": faces, "fine/uvs": uvs, "fine/uv_faces": faces,
        "body/poses": np.zeros((T, 24, 3), np.float32),
        "body/trans": np.tile(np.float32([0.0, 1.2, 0.0]), (T, 1)),
        "body/joints": np.zeros((T, 24, 3), np.float32), "body/betas": np.zeros(10, np.float32),
        "quality/edge_strain_max": (0.05 * (index + 1) + 0.01 * np.arange(T)).astype(np.float32),
        "quality/inside_fraction": np.array([0.0, 0.0, 0.002, 0.01, 0.0], np.float32) * (index + 1),
        "quality/self_intersections": np.zeros(T, np.int32),
    }
    if images:
        yy, xx = np.mgrid[0:IMG, 0:IMG]
        mask = ((xx - IMG / 2) ** 2 + (yy - IMG / 2) ** 2 < (0.4 * IMG) ** 2).astype(np.uint8)
        ramp = (xx / IMG).astype(np.float32)
        n = np.stack([np.sin(ramp), np.zeros_like(ramp), np.cos(ramp)], axis=-1)
        arrays.update({
            "images/strain_norm": np.broadcast_to(ramp[None, ..., None] * 0.1,
                                                  (T, IMG, IMG, 1)).astype(np.float16),
            "images/wrinkle": (rng.normal(0.0, 1e-3, (T, IMG, IMG, 3))).astype(np.float16),
            "images/normal_world": np.broadcast_to(n, (T, IMG, IMG, 3)).astype(np.float16),
            "images/normal_tangent": np.broadcast_to(n[..., ::-1], (T, IMG, IMG, 3)).astype(np.float16),
            "images/mask": mask,
        })
    return arrays


SPECS = [  # (garment, motion, split, images)
    ("skirt", "walk", "train", True),
    ("t_shirt", "run", "train", False),
    ("t_shirt", "squat", "test_id", False),
]


def _make_dataset(root, *, body: str = "test-body", specs=SPECS, rejected: int = 2) -> dict:
    root.mkdir(parents=True, exist_ok=True)
    entries = {}
    for i, (garment, motion, split, images) in enumerate(specs):
        sid = f"seq-{i:05d}"
        arrays = _sequence(i, images=images)
        meta = {"sequence": json.dumps({"id": sid, "split": split}),
                "body": json.dumps({"model": body, "name": body})}  # as sim.datasets.generate writes it
        path = sequence_path(root, sid)
        path.parent.mkdir(exist_ok=True)
        sha = write_sequence(path, arrays, meta)
        entries[sid] = {"file": f"sequences/{sid}.safetensors", "sha256": sha, "bytes": path.stat().st_size,
                        "frames": T, "split": split, "index": i, "seed": i, "garment": garment,
                        "motion": motion, "image_resolution": [IMG, IMG] if images else None}
    rej = {f"seq-{len(specs) + k:05d}": {"index": len(specs) + k, "garment": "skirt", "motion": "run",
                                          "reasons": ["exploded"]} for k in range(rejected)}
    manifest = {"schema_version": 1, "config": {"bodies": {"model": body}}, "sequences": entries,
                "rejected": rej}
    atomic_write_json(root / MANIFEST, manifest)
    return manifest


def _listing(path) -> list[str]:
    return sorted(os.listdir(path)) if path.exists() else []


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "data"
    _make_dataset(root)
    written = dr.write_report(root, sequences=8, frames_per_sequence=3, seed=0, tile_size=TILE)
    return root, written, json.loads((root / "report" / dr.REPORT_JSON).read_text())


@pytest.mark.slow
def test_report_writes_every_file(report):
    root, written, rep = report
    out = root / "report"
    assert written == [out / n for n in (dr.CONTACT_SHEET, dr.UV_EXAMPLES, dr.HISTOGRAMS, dr.REPORT_JSON)]
    assert _listing(out) == sorted(p.name for p in written)  # no temporaries left
    assert rep["files"] == [dr.CONTACT_SHEET, dr.UV_EXAMPLES, dr.HISTOGRAMS]
    assert rep["sequences"]["accepted"] == 3 and rep["sequences"]["rejected"] == 2


def _image(path) -> np.ndarray:
    with Image.open(path) as im:
        im.verify()
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


@pytest.mark.slow
def test_pictures_have_expected_size_and_are_not_blank(report):
    root, _, rep = report
    out = root / "report"
    sheet = _image(out / dr.CONTACT_SHEET)
    w, h = dr.contact_sheet_size(3, TILE)
    assert sheet.shape == (h, w, 3)
    assert (w, h) == (3 * TILE[0], TILE[1] + dr.CAPTION_HEIGHT + dr.LEGEND_HEIGHT)
    for k in range(3):  # every render shows something besides the background
        tile = sheet[: TILE[1], k * TILE[0]: (k + 1) * TILE[0]].astype(np.float64)
        assert tile.var() > 10.0
    assert [t["id"] for t in rep["contact_sheet"]["tiles"]] == ["seq-00000", "seq-00001", "seq-00002"]
    assert all(t["frame"] == T // 2 and not t["body"] for t in rep["contact_sheet"]["tiles"])

    uv = _image(out / dr.UV_EXAMPLES)
    w, h = dr.uv_examples_size(1)  # only seq-00000 stores images
    assert uv.shape == (h, w, 3)
    assert uv.astype(np.float64).var() > 10.0
    assert [r["id"] for r in rep["uv_examples"]["rows"]] == ["seq-00000"]

    hist = _image(out / dr.HISTOGRAMS)
    assert hist.shape == (round(dr.HISTOGRAM_FIGSIZE[1] * dr.HISTOGRAM_DPI),
                          round(dr.HISTOGRAM_FIGSIZE[0] * dr.HISTOGRAM_DPI), 3)
    assert hist.astype(np.float64).var() > 10.0


@pytest.mark.slow
def test_histogram_numbers_match_numpy(report):
    _, _, rep = report
    frames = dr.sample_frames(T, 3)
    assert frames == [0, 2, 4]
    assert rep["sequences"]["sampled_frames_by_length"] == {str(T): frames}
    seqs = [_sequence(i, images=images) for i, (*_, images) in enumerate(SPECS)]
    expected = {
        "strain_norm": np.concatenate([s["fine/strain_norm"][frames].ravel() for s in seqs]),
        "wrinkle_amplitude_mm": np.concatenate([np.abs(s["fine/wrinkle"][frames, :, 2]).ravel() * 1e3
                                                for s in seqs]),
        "penetration_percent": np.concatenate([s["quality/inside_fraction"] * np.float32(100) for s in seqs]),
        "stretch": np.concatenate([s["quality/edge_strain_max"] for s in seqs]),
    }
    hists = rep["histograms"]["quantities"]
    for key, values in expected.items():
        h = hists[key]
        values = values.astype(np.float32)
        assert h["count"] == h["values_seen"] == values.size, key
        assert sum(h["counts"]) == values.size, key
        assert len(h["counts"]) == dr.HISTOGRAM_BINS and len(h["edges"]) == dr.HISTOGRAM_BINS + 1
        assert not h["subsampled"] and h["nonfinite"] == 0
        assert h["max"] == float(values.max()), key
        assert h["min"] == float(values.min()), key
        np.testing.assert_allclose(h["mean"], values.astype(np.float64).mean(), rtol=1e-6)
        np.testing.assert_array_equal(h["counts"], np.histogram(values, bins=np.asarray(h["edges"]))[0])
    assert hists["strain_norm"]["values_seen"] == 3 * len(frames) * 2 * (NX - 1) * (NY - 1)
    assert hists["wrinkle_amplitude_mm"]["values_seen"] == 3 * len(frames) * NX * NY
    assert hists["penetration_percent"]["values_seen"] == 3 * T
    np.testing.assert_allclose(hists["penetration_percent"]["max"], 3.0, rtol=1e-6)


@pytest.mark.slow
def test_subsampled_histograms_keep_exact_extremes(tmp_path):
    root = tmp_path / "data"
    _make_dataset(root)
    dr.write_report(root, sequences=1, frames_per_sequence=5, tile_size=TILE, max_values=300)
    rep = json.loads((root / "report" / dr.REPORT_JSON).read_text())
    h = rep["histograms"]["quantities"]["strain_norm"]
    assert h["subsampled"] and h["count"] == 3 * 100 == sum(h["counts"])
    all_strain = np.concatenate([_sequence(i, images=False)["fine/strain_norm"].ravel() for i in range(3)])
    assert h["values_seen"] == all_strain.size
    assert h["max"] == float(all_strain.max())
    assert h["edges"][-1] == h["max"]
    assert len(rep["contact_sheet"]["tiles"]) == 1


def test_empty_dataset_is_an_input_error(tmp_path):
    root = tmp_path / "empty"
    _make_dataset(root, specs=[], rejected=4)
    with pytest.raises(WrinklesInputError, match="no accepted sequences") as e:
        dr.write_report(root)
    assert str(root) in str(e.value) and "\n" not in str(e.value)
    assert not (root / "report").exists()
    with pytest.raises(WrinklesInputError, match="manifest"):
        dr.write_report(tmp_path / "nothing_here")


def test_missing_sequence_file_names_it(tmp_path):
    root = tmp_path / "data"
    _make_dataset(root)
    sequence_path(root, "seq-00001").unlink()
    with pytest.raises(WrinklesInputError, match="seq-00001") as e:
        dr.write_report(root, tile_size=TILE)
    assert str(sequence_path(root, "seq-00001")) in str(e.value)
    assert not (root / "report").exists()


def test_failure_leaves_no_partial_output(tmp_path, monkeypatch):
    root = tmp_path / "data"
    _make_dataset(root)

    def boom(*args, **kwargs):
        raise RuntimeError("injected")

    # the contact sheet and UV images are already written (as temporaries) when this fails
    monkeypatch.setattr(dr, "_plot_histograms", boom)
    with pytest.raises(RuntimeError, match="injected"):
        dr.write_report(root, tile_size=TILE)
    assert not (root / "report").exists()

    # an earlier report in a directory that exists stays as it was
    out = tmp_path / "keep" / "report"
    out.mkdir(parents=True)
    (out / dr.HISTOGRAMS).write_bytes(b"old")
    with pytest.raises(RuntimeError, match="injected"):
        dr.write_report(root, out, tile_size=TILE)
    assert _listing(out) == [dr.HISTOGRAMS]
    assert (out / dr.HISTOGRAMS).read_bytes() == b"old"


@pytest.mark.slow
def test_no_images_skips_uv_examples_and_removes_a_stale_one(tmp_path):
    root = tmp_path / "data"
    _make_dataset(root, specs=[("skirt", "walk", "train", False)], rejected=0)
    out = root / "report"
    out.mkdir()
    (out / dr.UV_EXAMPLES).write_bytes(b"from an earlier report")
    written = dr.write_report(root, tile_size=TILE)
    assert [p.name for p in written] == [dr.CONTACT_SHEET, dr.HISTOGRAMS, dr.REPORT_JSON]
    assert _listing(out) == sorted(p.name for p in written)
    rep = json.loads((out / dr.REPORT_JSON).read_text())
    assert rep["uv_examples"]["file"] is None and "no sequence" in rep["uv_examples"]["skipped"]


def test_sample_sequences_spreads_over_garments_and_splits():
    def entry(i, garment, split):
        sid = f"seq-{i:05d}"
        return dr.SequenceEntry(sid, sequence_path("x", sid), garment, "walk", split, None)

    entries = [entry(i, "t_shirt", "train") for i in range(10)]
    entries += [entry(10, "t_shirt", "test_ood"), entry(11, "skirt", "train"), entry(12, "dress", "test_id")]
    two = dr.sample_sequences(entries, 2, seed=0)
    assert len({e.garment for e in two}) == 2
    three = dr.sample_sequences(entries, 3, seed=0)
    assert {e.garment for e in three} == {"t_shirt", "skirt", "dress"}
    four = dr.sample_sequences(entries, 4, seed=0)
    assert {(e.garment, e.split) for e in four} == {("t_shirt", "train"), ("t_shirt", "test_ood"),
                                                    ("skirt", "train"), ("dress", "test_id")}
    assert dr.sample_sequences(entries, 4, seed=0) == four  # seeded
    assert dr.sample_sequences(entries, 100, seed=3) == sorted(entries, key=lambda e: e.id)


def test_default_body_is_posed_into_the_render(tmp_path):
    root = tmp_path / "data"
    _make_dataset(root, body="default", specs=[("skirt", "walk", "train", False)], rejected=0)
    progress = []
    dr.write_report(root, tile_size=TILE, progress=lambda done, total: progress.append((done, total)))
    assert progress == [(1, 2), (2, 2)]
    rep = json.loads((root / "report" / dr.REPORT_JSON).read_text())
    assert rep["contact_sheet"]["tiles"][0]["body"] is True
    body_tile = _image(root / "report" / dr.CONTACT_SHEET)[: TILE[1]]
    # the clay body colour is in the render
    clay = np.asarray(BODY_COLOR, np.float64) * 255
    near = np.linalg.norm(body_tile.astype(np.float64) - clay, axis=2) < 60
    assert near.sum() > 50


@pytest.mark.slow
def test_run_report_from_arguments(tmp_path, capsys):
    root = tmp_path / "data"
    _make_dataset(root, specs=SPECS[:1], rejected=0)
    p = argparse.ArgumentParser()
    dr.add_report_arguments(p)
    args = p.parse_args([str(root), "--out", str(tmp_path / "rep"), "--sequences", "2",
                         "--frames-per-sequence", "2", "--device", "cpu"])
    assert dr.run_report(args) == 0
    assert "wrote" in capsys.readouterr().out
    assert _listing(tmp_path / "rep") == sorted(set(dr.REPORT_FILES) - {dr.GENERATION})  # no timeline
    bad = p.parse_args([str(root), "--sequences", "0", "--quiet"])
    with pytest.raises(WrinklesInputError, match="sequences"):
        dr.run_report(bad)


def test_body_model_name_sources(tmp_path):
    arrays = {"x": np.zeros(1, np.float32)}
    cases = [({"body": json.dumps({"model": "default", "name": "default"})}, {}, "default"),
             ({"body": json.dumps({"model": "/m/SMPL.npz", "name": "default"})}, {}, "/m/SMPL.npz"),
             ({"body": "default"}, {}, "default"),
             ({}, {"config": {"bodies": {"model": "default"}}}, "default"),
             ({}, {"config": {"body": "smplx"}}, "smplx"),
             ({}, {"config": {}}, None)]
    for k, (meta, manifest, expected) in enumerate(cases):
        path = tmp_path / f"{k}.safetensors"
        write_sequence(path, arrays, meta)
        assert dr.body_model_name(SequenceFile(path), manifest) == expected, meta


def test_generation_timeline_picture_and_numbers(tmp_path):
    """With the shards' timelines in parts/, the report draws generation.png and states the
    throughput (accepted garment-frames between the first and the last sequence done) and the
    rejections by cause."""
    from sim.datasets.storage import PARTS_DIR, read_events

    root = tmp_path / "data"
    m = _make_dataset(root, specs=[("skirt", "walk", "train", False)], rejected=2)
    m["rejected"]["seq-00001"]["reasons"] = ["fine: max edge strain 0.9 > 0.35",
                                             "fine: 3 self-intersection crossings at frame 2 (gate 0)"]
    m["rejected"]["seq-00002"]["reasons"] = ["fine: max edge strain 0.5 > 0.35"]
    atomic_write_json(root / MANIFEST, m)
    (root / PARTS_DIR).mkdir()
    lines = [{"id": "seq-00001", "outcome": "rejected", "frames": 0, "time": 100.0, "shard": 1},
             {"id": "seq-00000", "outcome": "accepted", "frames": 30, "time": 110.0, "shard": 0},
             {"id": "seq-00002", "outcome": "rejected", "frames": 0, "time": 120.0, "shard": 1}]
    (root / PARTS_DIR / "shard-0-of-2.events.jsonl").write_text(json.dumps(lines[1]) + "\n")
    (root / PARTS_DIR / "shard-1-of-2.events.jsonl").write_text(
        json.dumps(lines[0]) + "\n" + json.dumps(lines[2]) + "\n" + '{"id": "seq-0')  # cut short by a kill
    assert [e["id"] for e in read_events(root)] == ["seq-00001", "seq-00000", "seq-00002"]
    written = dr.write_report(root, tile_size=TILE)
    assert root / "report" / dr.GENERATION in written
    gen = json.loads((root / "report" / dr.REPORT_JSON).read_text())["generation"]
    assert gen["sequences"] == 3 and gen["accepted"] == 1 and gen["garment_frames"] == 30
    assert gen["garment_frames_per_s"] == pytest.approx(30 / 20.0)
    assert gen["rejection_causes"] == {"fine: edge strain": 2, "fine: self-intersection": 1}
    img = _image(root / "report" / dr.GENERATION)
    assert img.shape[:2] == (400, 1100) and img.std() > 10
