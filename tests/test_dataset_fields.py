"""Quantized positions and derived fields of dataset sequence files (sim.datasets.quantize,
sim.datasets.fields): the decoding error bound, the derived fields against those of the exact
positions, and the cache of derived fields (made once, reused, stale when the data change)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from sim.datasets import fields as FD
from sim.datasets import storage as S
from sim.datasets.config import DeriveConfig
from sim.datasets.quantize import LEVELS, Dequantized, dequantize, quantize, quantized_arrays


def test_quantized_positions_decode_within_half_a_step():
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.6, 0.6, size=(4, 500, 3)) + np.array([3.0, 1.0, -20.0])  # far from the origin
    q, origin, step = quantize(x)
    assert q.dtype == np.int16 and origin.dtype == step.dtype == np.float32
    assert np.abs(q).max() <= LEVELS and np.abs(q).max() >= LEVELS - 1  # the grid spans the frame
    extent = (x.max(axis=1) - x.min(axis=1)).max(axis=1)
    assert np.all(step <= extent / (2 * LEVELS - 1) * (1 + 1e-6))
    err = np.abs(dequantize(q, origin, step) - x)
    # half a step, plus float32 rounding of the decoded value (|x| ~ 20 m: ulp 1.9e-6)
    assert np.all(err.max(axis=(1, 2)) <= 0.5 * step + 4e-6)
    assert err.max() < 2e-5  # a garment 1.2 m across: ~9 µm


def test_quantizing_degenerate_and_bad_frames():
    x = np.ones((2, 3, 3))  # every vertex at one point
    q, origin, step = quantize(x)
    np.testing.assert_array_equal(dequantize(q, origin, step), x.astype(np.float32))
    with pytest.raises(ValueError, match="not finite"):
        quantize(np.full((1, 2, 3), np.nan))
    with pytest.raises(ValueError, match=r"\(T, V, 3\)"):
        quantize(np.zeros((2, 3)))


def test_dequantized_view_decodes_only_the_frames_asked():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(6, 20, 3))
    parts = quantize(x)
    full = dequantize(*parts)
    view = Dequantized(*parts)
    assert view.shape == (6, 20, 3) and view.dtype == np.float32 and len(view) == 6
    for got, want in ((np.asarray(view), full), (view[2:5], full[2:5]), (view[-1], full[-1]),
                      (view[1, 3], full[1, 3]), (view[1:3, :4], full[1:3, :4])):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(view[np.array(2)], full[2])
    with pytest.raises(IndexError):
        view[6]
    for bad in ((Ellipsis, 2), None, (slice(None), None)):
        with pytest.raises(TypeError, match="frames first"):
            view[bad]


def _sheet(n: int, size: float = 1.2):
    """A flat square sheet (n x n vertices, ``size`` metres) with its UV layout = its plane."""
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    rest = np.stack([u.ravel() * size, np.zeros(n * n), v.ravel() * size], axis=1).astype(np.float32)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    uvs = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float32)
    return rest, faces, uvs


def _wrinkled(rest: np.ndarray, frames: int) -> np.ndarray:
    """Frames of the sheet folded by a large bend and wrinkled by 3 mm ripples 5 cm long."""
    x = np.repeat(rest[None].astype(np.float64), frames, axis=0)
    for t in range(frames):
        s = 1.0 + 0.1 * t
        x[t, :, 1] = 0.15 * np.sin(rest[:, 0] * s) + 0.003 * np.sin(2 * np.pi * rest[:, 2] / 0.05 + t)
    return x


def _write(path, rest, faces, uvs, x, *, image_resolution: int = 16) -> None:
    arrays = {**quantized_arrays("fine/vertices", x), "fine/rest_vertices": rest, "fine/faces": faces,
              "fine/uvs": uvs, "fine/uv_faces": faces,
              "fine/face_layers": np.ones(len(faces), np.float32)}
    cfg = {"smoothing_length": 0.04, "image_resolution": image_resolution, "coarse": False}
    S.write_sequence(path, arrays, {FD.DERIVE_META: json.dumps(cfg)})


def test_derived_fields_of_quantized_positions_match_the_exact_ones(tmp_path):
    from sim.datasets.derive import Deriver

    rest, faces, uvs = _sheet(81)  # 1.5 cm edges
    x = _wrinkled(rest, 3)
    (tmp_path / "sequences").mkdir()
    path = tmp_path / "sequences" / "seq-00000.safetensors"
    _write(path, rest, faces, uvs, x)
    f = S.SequenceFile(path)
    for k in (*FD.FINE_DERIVED, "images/wrinkle", "images/mask", "fine/vertices"):
        assert k in f, k
    assert "coarse/strain_norm" not in f and "fine/vertices_q" not in f.keys()
    garment = FD._rest_garment(f, "fine")
    exact = Deriver(garment, DeriveConfig(image_resolution=16), device="cpu")(x.astype(np.float32))
    for k in FD.FINE_DERIVED:
        assert f.shape(k) == exact[k].shape, k
    # what quantization (steps of 1.2 m / 65533 = 18 µm) costs the learners' fields: the
    # wrinkle field (3 mm ripples) to within a few micrometres, the base's strain to within ~2 %
    def rms(a):
        return float(np.sqrt(np.mean(np.square(a, dtype=np.float64))))

    w, w_exact = np.asarray(f["fine/wrinkle"]), exact["fine/wrinkle"]
    s, s_exact = np.asarray(f["fine/strain"]), exact["fine/strain"]
    assert rms(w - w_exact) < min(2e-6, 0.01 * rms(w_exact)) and np.abs(w - w_exact).max() < 2e-5
    # (measured: 1.8 % rms, 2.1 % of the largest: the reason positions are f32 unless asked)
    assert np.abs(s - s_exact).max() < 0.025 * np.abs(s_exact).max()
    assert rms(s - s_exact) < 0.025 * rms(s_exact)
    assert np.abs(np.asarray(f["fine/normals"]) - exact["fine/normals"]).max() < 5e-3
    assert f.shape("images/wrinkle") == (3, 16, 16, 3)


def test_derived_fields_are_cached_once_and_derived_again_when_the_data_change(tmp_path, monkeypatch):
    rest, faces, uvs = _sheet(12)
    (tmp_path / "sequences").mkdir()
    path = tmp_path / "sequences" / "seq-00000.safetensors"
    _write(path, rest, faces, uvs, _wrinkled(rest, 2), image_resolution=0)
    calls = []
    real = FD.derive_fields
    monkeypatch.setattr(FD, "derive_fields", lambda sf, **kw: calls.append(sf.path) or real(sf, **kw))
    base = np.array(S.SequenceFile(path)["fine/base"])
    cache = tmp_path / FD.DERIVED_DIR / path.name
    assert cache.exists() and len(calls) == 1
    np.testing.assert_array_equal(np.asarray(S.SequenceFile(path)["fine/base"]), base)
    assert len(calls) == 1
    assert "images/wrinkle" not in S.SequenceFile(path)  # no images asked for
    _write(path, rest, faces, uvs, _wrinkled(rest, 2) + [0.0, 0.1, 0.0])  # the sequence written anew
    moved = np.asarray(S.SequenceFile(path)["fine/base"])
    assert len(calls) == 2
    np.testing.assert_allclose(moved, base + [0.0, 0.1, 0.0], atol=1e-4)


def test_a_read_only_dataset_caches_under_the_user_cache(tmp_path, monkeypatch):
    rest, faces, uvs = _sheet(12)
    data = tmp_path / "data"
    (data / "sequences").mkdir(parents=True)
    path = data / "sequences" / "seq-00000.safetensors"
    _write(path, rest, faces, uvs, _wrinkled(rest, 2), image_resolution=0)
    monkeypatch.setenv("WRINKLES_CACHE", str(tmp_path / "cache"))
    real_access = os.access
    monkeypatch.setattr(FD.os, "access", lambda p, mode: False if str(p).startswith(str(data)) else
                        real_access(p, mode))
    np.asarray(S.SequenceFile(path)["fine/base"])
    assert not (data / FD.DERIVED_DIR).exists()
    assert len(list((tmp_path / "cache" / FD.DERIVED_DIR).glob("*.safetensors"))) == 1


def test_dataset_derive_fills_the_cache_of_every_sequence_once(tmp_path, capsys):
    from pipelines.cli import main

    rest, faces, uvs = _sheet(12)
    (tmp_path / "sequences").mkdir()
    entries = {}
    for k, split in enumerate(("train", "test_id", "train")):
        sid = f"seq-{k:05d}"
        _write(tmp_path / "sequences" / f"{sid}.safetensors", rest, faces, uvs, _wrinkled(rest, 2) + k,
               image_resolution=0)
        entries[sid] = {"file": f"sequences/{sid}.safetensors", "frames": 2, "split": split}
    S.atomic_write_json(tmp_path / S.MANIFEST, {"schema_version": S.SCHEMA_VERSION, "config": {},
                                                "sequences": entries, "rejected": {}})
    assert main(["dataset", "derive", str(tmp_path), "--device", "cpu", "-q", "--split", "train"]) == 0
    assert sorted(p.name for p in (tmp_path / FD.DERIVED_DIR).iterdir()) == [
        "seq-00000.safetensors", "seq-00002.safetensors"]
    assert main(["dataset", "derive", str(tmp_path), "--device", "cpu", "-q"]) == 0
    assert "derived 1 sequences, 2 were current" in capsys.readouterr().out
    cached = S.SequenceFile(tmp_path / FD.DERIVED_DIR / "seq-00001.safetensors")
    assert sorted(cached.keys()) == sorted(FD.FINE_DERIVED)  # no images at resolution 0, no coarse
    assert main(["dataset", "derive", str(tmp_path), "--split", "nope", "-q"]) == 2


def test_a_generation_keeps_its_dense_smoothers_within_the_device_budget(monkeypatch):
    """The derivers a generation keeps (one per garment mesh): at most ``DERIVERS``, and dense
    base smoothers on a GPU only while their factors fit the device's budget, the least recently
    used dropped first and the newest kept."""
    from types import SimpleNamespace

    import sim.geometry.smoothing as smoothing
    from sim.datasets import generate as G
    from sim.datasets.config import DatasetConfig

    run = G._Run(DatasetConfig(), None, None, None, "cpu", G.GenerateSummary(), print)

    def fake(nbytes):
        return SimpleNamespace(smoother=SimpleNamespace(device_bytes=nbytes))

    run.derivers.update({f"host{k}": fake(0) for k in range(G.DERIVERS + 3)})
    run._evict()
    assert list(run.derivers) == [f"host{k}" for k in range(3, G.DERIVERS + 3)]
    monkeypatch.setattr(smoothing, "dense_budget", lambda device: 10)
    run.derivers.clear()
    run.derivers.update({"a": fake(4), "b": fake(4), "c": fake(4)})
    run._evict()
    assert list(run.derivers) == ["b", "c"]
    run.derivers.update({"huge": fake(50)})
    run._evict()
    assert list(run.derivers) == ["huge"]
