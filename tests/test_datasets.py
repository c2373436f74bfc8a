"""Dataset generation: config checks, sampling, storage, generate / resume / shards."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sim.datasets import storage as S
from sim.errors import WrinklesInputError

ROOT = Path(__file__).resolve().parents[1]

TINY = """\
seed = 3
sequences = 4
fps = 30.0
seconds = 0.2

[garments]
categories = ["straight_skirt", "t_shirt"]
fine_resolution = 0.06
coarse_resolution = 0.1
[garments.params.straight_skirt]
length = [0.45, 0.55]

[materials]
names = ["cotton", "silk"]

[bodies]
betas = 2

[motions]
procedural = ["walk", "arm_raise"]
[motions.params.walk]
ramp = 0.1
[motions.params.arm_raise]
ramp = 0.1

[split]
test_fraction = 0.5
ood_motions = ["arm_raise"]

[simulation]
substeps = 2
iterations = 2
settle_seconds = 0.1
blend_seconds = 0.1
self_contact = false
gates = {max_self_intersections = 1000, max_edge_strain = 5.0, max_inside_fraction = 1.0}

[derive]
smoothing_length = 0.1
image_resolution = 32
coarse = true
"""


def tiny_config(tmp_path: Path, text: str = TINY, name: str = "tiny.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _load(tmp_path, text):
    from sim.datasets.config import load_config

    return load_config(tiny_config(tmp_path, text))


# ---------------------------------------------------------------- config


@pytest.mark.parametrize("edit, message", [
    (("seed = 3", "seed = 3\ncolour = 1"), "unknown key(s) colour"),
    (("[bodies]", "[bodies]\nheight = 2"), "unknown key(s) height in [bodies]"),
    (("names = [\"cotton\", \"silk\"]", "names = [\"cotton\", \"wool\"]"), "unknown material 'wool'"),
    (("length = [0.45, 0.55]", "length = [0.55, 0.45]"), "lo > hi"),
    (("length = [0.45, 0.55]", "length = [-0.5, 0.55]"), "outside its range"),
    (("length = [0.45, 0.55]", "sleeves = 2"), "unknown parameter"),
    (("ood_motions = [\"arm_raise\"]", "ood_motions = [\"jump\"]"), "not a configured motion"),
    (("ood_motions = [\"arm_raise\"]", "ood_motions = [\"arm_raise\", \"walk\"]"),
     "nothing is left to train"),
    (("ood_motions = [\"arm_raise\"]", "ood_garments = [\"dress\"]"), "not a configured garment category"),
    (("ood_motions = [\"arm_raise\"]", "ood_garments = [\"t_shirt\", \"straight_skirt\"]"),
     "nothing is left to train"),
    (("test_fraction = 0.5", "test_fraction = 1.5"), "test_fraction"),
    (("substeps = 2", "substeps = -1"), "[simulation]"),
    (("substeps = 2", "substep = 2"), "unknown key"),
    (("image_resolution = 32", "image_resolution = 7"), "image_resolution"),
    (("sequences = 4", "sequences = 0"), "sequences must be"),
    (("categories = [\"straight_skirt\", \"t_shirt\"]", "categories = [\"cape\"]"),
     "unknown category 'cape'"),
    (("procedural = [\"walk\", \"arm_raise\"]", "procedural = [\"walk\", \"moonwalk\"]"), "moonwalk"),
])
def test_bad_config_is_refused_naming_file_and_key(tmp_path, edit, message):
    text = TINY.replace(*edit)
    assert text != TINY
    with pytest.raises(WrinklesInputError) as e:
        _load(tmp_path, text)
    msg = str(e.value)
    assert message in msg and "tiny.toml" in msg and "\n" not in msg


@pytest.mark.slow
def test_unreadable_user_motion_is_refused_before_anything_runs(tmp_path):
    bad = tmp_path / "motions"
    bad.mkdir()
    (bad / "broken.npz").write_bytes(b"not a zip file")
    text = TINY.replace('procedural = ["walk", "arm_raise"]',
                        'procedural = ["walk", "arm_raise"]\nfiles = ["motions"]')
    with pytest.raises(WrinklesInputError, match="broken.npz"):
        _load(tmp_path, text)
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "pipelines.cli", "dataset", "generate", "--config",
                        str(tmp_path / "tiny.toml"), "--out", str(out), "--device", "cpu", "-q"],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "broken.npz" in r.stderr
    assert not out.exists()


def test_not_toml_is_refused(tmp_path):
    with pytest.raises(WrinklesInputError, match="not a readable TOML"):
        _load(tmp_path, "seed = = 3")


@pytest.mark.slow
def test_shipped_sample_config_is_valid():
    from sim.datasets.config import load_config

    cfg = load_config("sample")
    assert cfg.sequences >= 4 and cfg.derive.coarse and cfg.derive.image_resolution > 0


# ---------------------------------------------------------------- sampling


def test_sampling_is_deterministic_and_index_local(tmp_path):
    from dataclasses import replace

    from sim.datasets.sampling import sample_sequences, shard_indices

    cfg = _load(tmp_path, TINY)
    a, b = sample_sequences(cfg), sample_sequences(cfg)
    assert [s.to_json() for s in a] == [s.to_json() for s in b]
    more = sample_sequences(replace(cfg, sequences=9))
    assert [s.to_json() for s in more[:4]] == [s.to_json() for s in a]  # growing keeps the first ones
    other = sample_sequences(replace(cfg, seed=4))
    assert [s.to_json() for s in other] != [s.to_json() for s in a]
    for s in more:
        lo, hi = 0.45, 0.55
        if s.category == "straight_skirt":
            assert lo <= s.garment_params["length"] <= hi
        assert s.split == "test_ood" if s.motion == "arm_raise" else s.split in ("train", "test_id")
        assert len(s.betas) == 2 and all(abs(x) <= 2.5 for x in s.betas)
    held = sample_sequences(replace(cfg, sequences=9, split=replace(cfg.split, ood_garments=("t_shirt",))))
    for s, h in zip(more, held, strict=True):  # holding a garment out moves only its sequences
        assert h.split == ("test_ood" if s.category == "t_shirt" else s.split)
        assert (h.category, h.betas, h.motion) == (s.category, s.betas, s.motion)
    assert {s.category for s in more} == {"t_shirt", "straight_skirt"}
    parts = [shard_indices(9, i, 4) for i in range(4)]
    assert sorted(sum(parts, [])) == list(range(9))


# ---------------------------------------------------------------- storage


def test_sequence_file_round_trip_and_damage(tmp_path):
    rng = np.random.default_rng(0)
    arrays = {"a/x": rng.normal(size=(5, 7, 3)).astype(np.float32), "b": np.arange(6, dtype=np.int32),
              "img": rng.normal(size=(2, 4, 4, 3)).astype(np.float16), "mask": np.ones((4, 4), np.uint8),
              "empty": np.zeros((0, 3), np.float32)}
    p = tmp_path / "s.safetensors"
    sha = S.write_sequence(p, arrays, {"k": "v"})
    assert sha == S.file_sha256(p)
    assert not list(tmp_path.glob(".*tmp*"))
    f = S.SequenceFile(p)
    assert f.keys() == sorted(arrays) and f.metadata["k"] == "v"
    # the file carries the checksum of its arrays (the bytes after the header)
    assert f.metadata["data_sha256"] == hashlib.sha256(p.read_bytes()[f.data_offset:]).hexdigest()
    for k, a in arrays.items():
        assert f[k].dtype == a.dtype and np.array_equal(np.asarray(f[k]), a)
    # same arrays, same bytes
    S.write_sequence(tmp_path / "t.safetensors", dict(reversed(list(arrays.items()))), {"k": "v"})
    assert (tmp_path / "t.safetensors").read_bytes() == p.read_bytes()
    # the layout is safetensors: 8-byte header length, JSON header, 64-byte aligned data
    raw = p.read_bytes()
    n = int.from_bytes(raw[:8], "little")
    header = json.loads(raw[8:8 + n])
    assert (8 + n) % 64 == 0 and header["a/x"]["dtype"] == "F32" and header["a/x"]["shape"] == [5, 7, 3]
    p.write_bytes(raw[:-100])  # truncated
    with pytest.raises(WrinklesInputError, match="truncated"):
        S.SequenceFile(p)


# ---------------------------------------------------------------- generate


def _generate(cfg_path: Path, out: Path, *extra: str, check: bool = True) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "pipelines.cli", "dataset", "generate", "--config",
                        str(cfg_path), "--out", str(out), "--device", "cpu", "-q", *extra],
                       capture_output=True, text=True, cwd=ROOT)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def _files(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((root / S.SEQUENCE_DIR).glob("*.safetensors"))}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """One uninterrupted generation of the tiny config."""
    tmp = tmp_path_factory.mktemp("ref")
    cfg = tiny_config(tmp)
    out = tmp / "data"
    t0 = time.perf_counter()
    _generate(cfg, out)
    return cfg, out, time.perf_counter() - t0


@pytest.mark.slow
def test_generated_dataset_holds_the_schema(reference):
    from sim.datasets.schema import BODY_KEYS, COARSE_KEYS, FINE_KEYS, IMAGE_KEYS, QUALITY_KEYS

    _, out, _ = reference
    m = S.read_manifest(out)
    assert len(m["sequences"]) + len(m["rejected"]) == 4
    assert m["sequences"], "every tiny sequence was rejected"
    for sid, e in m["sequences"].items():
        f = S.SequenceFile(out / e["file"])
        assert S.file_sha256(out / e["file"]) == e["sha256"]
        for k in (*FINE_KEYS, *IMAGE_KEYS, *COARSE_KEYS, *BODY_KEYS, *QUALITY_KEYS):
            assert k in f, (sid, k)
        # the file stores what the simulation gave; the rest is derived where it is read
        from sim.datasets.fields import DERIVED_KEYS

        assert f.has_stored("fine/vertices") and not any(f.has_stored(k) for k in DERIVED_KEYS)
        T, V = e["frames"], e["vertices"]
        assert f.shape("fine/vertices") == (T, V, 3) and f.shape("images/wrinkle") == (T, 32, 32, 3)
        layers = np.asarray(f["fine/face_layers"])  # the template's hems (up to 3 layers), the rest 1
        assert layers.shape == (f.shape("fine/faces")[0],)
        assert layers.min() == 1.0 and 1.0 < layers.max() <= 3.0
        assert f.shape("coarse/vertices")[0] == T and f.shape("body/poses") == (T, 24, 3)
        fine, base = np.asarray(f["fine/vertices"]), np.asarray(f["fine/base"])
        # the wrinkle field decodes back to the fine mesh (Guo et al. Eq. 2)
        from sim.garments import get_material
        from sim.garments.types import Garment
        from sim.geometry.frames import SurfaceFrames

        g = Garment(np.asarray(f["fine/rest_vertices"]), np.asarray(f["fine/faces"]),
                    np.asarray(f["fine/uvs"]), np.asarray(f["fine/uv_faces"]), get_material(e["material"]))
        back = SurfaceFrames.from_garment(g, device="cpu").decode(np.asarray(f["fine/wrinkle"]), base)
        assert np.abs(back - fine).max() < 1e-5
        # base is smoother than fine, and close to it
        assert 0 < np.abs(fine - base).max() < 0.05
        # the body re-posed from the stored poses/trans is where the simulation had it
        from sim.bodies.default import load_default_body

        body = load_default_body()
        posed = body.pose(np.asarray(f["body/betas"]), np.asarray(f["body/poses"]),
                          np.asarray(f["body/trans"]))
        assert np.abs(posed.joints - np.asarray(f["body/joints"])).max() < 1e-4
        # the stored frames are the motion itself, from its first frame: the arms hang or swing,
        # the T-pose (and the ramp from it, played before) is in none of them
        rot = np.degrees(np.linalg.norm(np.asarray(f["body/poses"])[:, 1:], axis=-1)).max(axis=1)
        assert rot.min() > 45.0, (sid, e["motion"], rot.min())
        prov = f.json("provenance")
        assert prov["frames"]["entry"] == "lead_in" and prov["frames"]["output"] == T == 6
        assert f.json("sequence")["split"] == e["split"]
    info = subprocess.run([sys.executable, "-m", "pipelines.cli", "dataset", "info", str(out), "--json"],
                          capture_output=True, text=True, cwd=ROOT)
    assert info.returncode == 0, info.stderr
    stats = json.loads(info.stdout)
    assert stats["sequences"] == len(m["sequences"])
    assert stats["frames"] == sum(e["frames"] for e in m["sequences"].values())
    # the dataset card: storage, gates passed, share accepted
    assert stats["schema_version"] == S.SCHEMA_VERSION and stats["positions"] == "f32"
    assert stats["gates"] == {"max_edge_strain": 5.0, "max_inside_fraction": 1.0,
                              "max_self_intersections": 1000}
    assert stats["accepted_share"] == len(m["sequences"]) / 4
    assert stats["derived_cached"] == len(m["sequences"])  # the loop above read derived fields
    # the job's timeline: one event per sequence, in time order, frames of the accepted ones
    events = S.read_events(out)
    assert sorted(e["id"] for e in events) == sorted([*m["sequences"], *m["rejected"]])
    assert sum(e["frames"] for e in events) == stats["frames"]
    assert [e["time"] for e in events] == sorted(e["time"] for e in events)


@pytest.mark.slow
def test_same_config_same_bytes(reference, tmp_path):
    cfg, out, _ = reference
    again = tmp_path / "again"
    _generate(cfg, again, "--batch", "3")  # batching does not change a sequence on one device
    assert _files(again) == _files(out)


@pytest.mark.slow
def test_sigkill_and_resume_give_the_same_dataset(tmp_path):
    cfg = tiny_config(tmp_path, TINY.replace("sequences = 4", "sequences = 12"))
    ref = tmp_path / "ref"
    t0 = time.perf_counter()
    _generate(cfg, ref)
    seconds = time.perf_counter() - t0
    out = tmp_path / "killed"
    rng = np.random.default_rng(7)
    killed = 0
    for _ in range(4):
        args = [sys.executable, "-m", "pipelines.cli", "dataset", "generate", "--config", str(cfg), "--out",
                str(out), "--device", "cpu", "-q"] + (["--resume"] if out.exists() else [])
        before = len(_files(out)) if out.exists() else 0
        target = before + int(rng.integers(1, 3))
        proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        # kill at a random point after 1-2 more sequences are complete: mid-simulation, mid-write
        # or between a file and its part-file record
        while proc.poll() is None and (not out.exists() or len(_files(out)) < target):
            time.sleep(0.01)
        time.sleep(float(rng.uniform(0.0, 0.4)))
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            killed += 1
        proc.wait()
    assert killed >= 2, f"the runs ended before they could be killed ({seconds:.1f} s uninterrupted)"
    r = _generate(cfg, out, *(["--resume"] if out.exists() else []))
    assert "accepted" in r.stdout
    assert _files(out) == _files(ref) and len(_files(ref)) > 0
    m_ref, m = S.read_manifest(ref), S.read_manifest(out)
    assert m["sequences"] == m_ref["sequences"] and m["rejected"] == m_ref["rejected"]
    assert not [p for p in out.rglob(".*tmp*")]
    # a finished dataset resumed again does nothing
    r = _generate(cfg, out, "--resume")
    assert " 0 accepted" in r.stdout


@pytest.mark.slow
def test_shards_combine_into_the_same_dataset(reference, tmp_path):
    cfg, ref, _ = reference
    out = tmp_path / "sharded"
    for i in range(2):
        _generate(cfg, out, "--shard", f"{i}/2")
    assert _files(out) == _files(ref)
    m_ref, m = S.read_manifest(ref), S.read_manifest(out)
    assert m["sequences"] == m_ref["sequences"]
    # starting a started shard again without --resume is refused; a different config too
    r = _generate(cfg, out, "--shard", "0/2", check=False)
    assert r.returncode == 2 and "--resume" in r.stderr
    other = tiny_config(tmp_path, TINY.replace("seed = 3", "seed = 4"), "other.toml")
    r = _generate(other, out, "--resume", check=False)
    assert r.returncode == 2 and "different config" in r.stderr
    # the same config without a record of the simulator defaults, or with other ones: refused
    # too, naming why, and nothing is written
    import json

    old = json.loads((out / "config.json").read_text())
    assert old["simulator"]["hems"]["layers"] == 3.0 and old["simulator"]["substeps"]["default"] == 12
    assert old["simulator"]["hems"]["rule"] == "area share"
    no_hem_rule = json.loads(json.dumps(old))
    del no_hem_rule["simulator"]["hems"]["rule"]  # hems without their area-share rule
    # begun on CUDA (3 colours), continued here on the CPU
    cuda_made = json.loads(json.dumps(old))
    assert "max_colors" not in cuda_made["simulator"]
    cuda_made["simulator"]["max_colors"] = 3
    # begun on CUDA with 3 colours and the coarse diagonal after the detection, continued on
    # CUDA with today's defaults: refused by the CUDA run's record (its "coarse_early"); a CUDA
    # run cannot be made here, so the record is compared as generate.py compares it
    from sim.simulate import simulator_defaults

    assert cuda_made["simulator"] != simulator_defaults(cuda=True)
    assert {**cuda_made["simulator"], "coarse_early": True} == simulator_defaults(cuda=True)
    # without the gait record (the cadence that keeps the hips inside their limits)
    from sim.motions.procedural import D2R

    no_gait = json.loads(json.dumps(old))
    gait = no_gait["simulator"].pop("gait")
    assert gait["cadence"] == "hip-limited" and gait["hip_extension_margin_rad"] == 1.0 * D2R
    assert gait["max_stride_frequency"] == {"walk": 1.75, "run": 2.5} and len(gait["curves_sha1"]) == 40
    # and one made with other gait curves (a key moved)
    curves = json.loads(json.dumps(old))
    curves["simulator"]["gait"]["curves_sha1"] = "0" * 40
    del old["simulator"]
    for record in (old, no_hem_rule, cuda_made, no_gait, curves):
        (out / "config.json").write_text(json.dumps(record))
        before = _files(out)
        r = _generate(cfg, out, "--resume", check=False)
        assert r.returncode == 2 and "simulator defaults" in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and _files(out) == before


@pytest.mark.slow
def test_only_the_test_splits_are_made_again(reference, tmp_path):
    """--splits test_id,test_ood makes exactly the reference's test sequences, byte for byte."""
    cfg, ref, _ = reference
    out = tmp_path / "tests_only"
    _generate(cfg, out, "--splits", "test_id,test_ood", "--batch", "2")  # other batches than ref's
    m_ref, m = S.read_manifest(ref), S.read_manifest(out)
    want = {k: e for k, e in m_ref["sequences"].items() if e["split"] != "train"}
    assert want and m["sequences"] == want
    assert {p: h for p, h in _files(ref).items() if Path(p).stem in want} == _files(out)
    r = _generate(cfg, tmp_path / "bad", "--splits", "test,train", check=False)
    assert r.returncode == 2 and "--splits" in r.stderr and not (tmp_path / "bad").exists()


def test_user_motion_folders_are_sampled(tmp_path):
    """A folder of AMASS files: every file is opened up front; sequences sample them by stem."""
    from sim.datasets.sampling import sample_sequences

    data = tmp_path / "amass" / "subject"
    data.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for name in ("jog_01", "wave_02"):
        T = 20
        np.savez(data / f"{name}.npz", poses=rng.normal(0, 0.1, (T, 156)), trans=np.zeros((T, 3)),
                 mocap_framerate=60.0, betas=np.zeros(16))
    text = TINY.replace('procedural = ["walk", "arm_raise"]', 'procedural = ["arm_raise"]\nfiles = ["amass"]')
    text = text.replace("[motions.params.walk]\nramp = 0.1\n", "")
    text = text.replace("sequences = 4", "sequences = 12")
    cfg = _load(tmp_path, text)
    specs = sample_sequences(cfg)
    assert {"jog_01", "wave_02", "arm_raise"} <= {s.motion_label for s in specs}
    for s in specs:
        if s.motion_label != "arm_raise":
            assert Path(s.motion).parent == data and s.motion_params == {}
    # a file too short for the config's seconds is refused up front
    with pytest.raises(WrinklesInputError, match="lasts only"):
        _load(tmp_path, text.replace("seconds = 0.2", "seconds = 1.0"))


@pytest.fixture
def flaky_batches(monkeypatch):
    """``simulate_batch`` whose jobs of the sequences in ``state["bad"]`` fail below
    ``state["limit"]`` substeps: they explode (``state["mode"] == "explode"``) or fail a gate
    ("gates"); every call's (jobs, substeps) goes to ``state["calls"]``."""
    import dataclasses

    import sim.simulate as simulate_mod
    from sim.quality import SimulationError

    real = simulate_mod.simulate_batch
    state = {"calls": [], "bad": set(), "limit": 4, "mode": "explode"}

    def flaky(jobs, *, config=None, failures="raise", **kw):
        state["calls"].append((len(jobs), config.substeps))
        out = real(jobs, config=config, failures=failures, **kw)
        if config.substeps < state["limit"]:
            for k, j in enumerate(jobs):
                if j.name.split()[0] in state["bad"]:
                    assert failures == "return"
                    out[k] = (SimulationError(7, "explosion: test") if state["mode"] == "explode" else
                              dataclasses.replace(out[k], failed_gates=("max edge strain 0.9 > 0.35",)))
        return out

    monkeypatch.setattr(simulate_mod, "simulate_batch", flaky)
    return state


def _two_sequence_config(tmp_path):
    from sim.datasets.config import load_config
    from sim.datasets.sampling import sample_sequences

    cfg = load_config(tiny_config(tmp_path, TINY.replace("sequences = 4", "sequences = 2")))
    return cfg, [sp.id for sp in sample_sequences(cfg)]


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["explode", "gates"])
def test_failed_sequences_are_retried_at_more_substeps(tmp_path, flaky_batches, mode):
    """A sequence whose simulation stops (explosion) or that fails a quality gate is simulated
    again at the config's retry substeps (2 -> 3 -> 4 here: 5/3 and 2 times) until it passes.
    In a batch only the failing sequences are redone (batched together), not the whole batch."""
    from sim.datasets.generate import generate

    cfg, ids = _two_sequence_config(tmp_path)
    flaky_batches.update(mode=mode, bad={ids[1]}, limit=4)
    s = generate(cfg, tmp_path / "a", batch=2, device="cpu")
    m = S.read_manifest(tmp_path / "a")
    assert s.accepted + s.rejected == 2 and not m["rejected"]
    # the batch of 2 (coarse + fine jobs: 4), then only the failing sequence at 3 and at 4
    assert flaky_batches["calls"] == [(4, 2), (2, 3), (2, 4)]
    prov = {sid: S.SequenceFile(tmp_path / "a" / e["file"]).json("provenance")
            for sid, e in m["sequences"].items()}
    assert {sid: p["config"]["substeps"] for sid, p in prov.items()} == {ids[0]: 2, ids[1]: 4}
    # the rungs it failed are in the provenance of the one that passed
    assert "failed_attempts" not in prov[ids[0]]
    assert [a["substeps"] for a in prov[ids[1]]["failed_attempts"]] == [2, 3]
    assert all(a["reasons"] for a in prov[ids[1]]["failed_attempts"])


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["explode", "gates"])
def test_a_sequence_failing_at_every_rung_is_rejected_with_its_record(tmp_path, flaky_batches, mode):
    """A sequence that fails at the last rung is rejected with its reasons, the substeps tried,
    every rung's reasons and what it takes to simulate it again."""
    from sim.datasets.generate import generate
    from sim.datasets.sampling import sample_sequences

    cfg, ids = _two_sequence_config(tmp_path)
    flaky_batches.update(mode=mode, bad=set(ids), limit=100)  # fails at every substep count
    s = generate(cfg, tmp_path / "b", batch=1, device="cpu")
    m = S.read_manifest(tmp_path / "b")
    assert s.accepted == 0 and s.rejected == 2 and flaky_batches["calls"] == [(2, 2), (2, 3), (2, 4)] * 2
    specs = {sp.id: sp for sp in sample_sequences(cfg)}
    gate = "max edge strain 0.9 > 0.35"
    for sid, r in m["rejected"].items():
        assert r["substeps"] == [2, 3, 4]
        sp = specs[sid]
        assert (r["seed"], r["betas"], r["garment_params"], r["motion_source"], r["motion_params"]) == (
            sp.seed, list(sp.betas), sp.garment_params, sp.motion, sp.motion_params)
        assert r["fit"] == cfg.garments.fit and r["vertices"] > 0 and r["split"] == sp.split
        assert r["reasons"] == (["simulation failed at frame 7: explosion: test (at 4 substeps)"]
                                if mode == "explode" else [f"fine: {gate}", f"coarse: {gate}"])
        # where the body passes through itself near the garment (a walk: nowhere), when it ran
        if mode == "explode":
            assert "body_self_crossings" not in r
            assert [a["reasons"] for a in r["attempts"]] == [
                [f"simulation failed at frame 7: explosion: test (at {n} substeps)"] for n in (2, 3, 4)]
        else:
            bc = r["body_self_crossings"]
            assert bc["frames"] > 0 and bc["frames_with_crossings"] == 0 and bc["frames_by_joint"] == {}
        # every rung's reasons, the last one's the record's own
        assert [a["substeps"] for a in r["attempts"]] == [2, 3, 4]
        assert r["attempts"][-1]["reasons"] == r["reasons"]
    lines = [json.loads(line) for line in (tmp_path / "b" / S.REJECTIONS).read_text().splitlines()]
    assert sorted(r["id"] for r in lines) == sorted(m["rejected"])
    assert all(len(r["attempts"]) == 3 for r in lines)


@pytest.mark.slow
def test_without_retries_a_failing_sequence_is_rejected_at_once(tmp_path, flaky_batches):
    from sim.datasets.config import load_config
    from sim.datasets.generate import generate
    from sim.datasets.sampling import sample_sequences

    cfg = load_config(tiny_config(tmp_path, TINY.replace("sequences = 4", "sequences = 2").replace(
        "substeps = 2", "substeps = 2\nretry_factors = []"), "no_retry.toml"))
    flaky_batches.update(mode="gates", bad={sp.id for sp in sample_sequences(cfg)}, limit=100)
    s = generate(cfg, tmp_path / "c", batch=1, device="cpu")
    assert s.rejected == 2 and flaky_batches["calls"] == [(2, 2)] * 2
