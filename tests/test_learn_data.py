"""learn.data: frame windows of a dataset on disk, exact against the arrays that were written."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from learn.data import GarmentSequenceDataset, collate_windows
from sim.datasets.info import dataset_statistics, format_statistics, manifest_statistics
from sim.datasets.schema import BODY_KEYS, IMAGE_KEYS, PER_FRAME_KEYS
from sim.datasets.storage import (
    SCHEMA_VERSION,
    atomic_write_json,
    read_manifest,
    sequence_path,
    write_sequence,
)
from sim.errors import WrinklesInputError

# id: (split, garment, material, motion, T, V, F, U, image (H, W) or None, coarse arrays?)
SPECS = {
    "seq-00000": ("train", "t_shirt", "cotton", "walk", 7, 5, 4, 6, (4, 5), True),
    "seq-00001": ("test_id", "dress", "silk", "walk", 12, 8, 6, 10, None, False),
    "seq-00002": ("test_ood", "t_shirt", "cotton", "run", 12, 6, 5, 7, (4, 5), False),
    "seq-00003": ("train", "skirt", "denim", "jump", 3, 9, 7, 11, None, False),
}


def _arrays(rng: np.random.Generator, T: int, V: int, F: int, U: int, image, coarse: bool) -> dict:
    f32 = np.float32
    a = {
        "fine/vertices": rng.normal(size=(T, V, 3)).astype(f32),
        "fine/base": rng.normal(size=(T, V, 3)).astype(f32),
        "fine/wrinkle": rng.normal(size=(T, U, 3)).astype(f32),
        "fine/strain": rng.normal(size=(T, F, 3)).astype(f32),
        "fine/strain_norm": rng.random((T, F)).astype(f32),
        "fine/normals": rng.normal(size=(T, V, 3)).astype(f32),
        "fine/rest_vertices": rng.normal(size=(V, 3)).astype(f32),
        "fine/faces": rng.integers(0, V, (F, 3)).astype(np.int32),
        "fine/uvs": rng.random((U, 2)).astype(f32),
        "fine/uv_faces": rng.integers(0, U, (F, 3)).astype(np.int32),
        "body/poses": rng.normal(size=(T, 24, 3)).astype(f32),
        "body/trans": rng.normal(size=(T, 3)).astype(f32),
        "body/joints": rng.normal(size=(T, 24, 3)).astype(f32),
        "body/betas": rng.normal(size=(10,)).astype(f32),
        "quality/edge_strain_max": rng.random(T).astype(f32),
        "quality/inside_fraction": rng.random(T).astype(f32),
        "quality/self_intersections": rng.integers(0, 5, T).astype(np.int32),
    }
    if image:
        H, W = image
        a["images/strain_norm"] = rng.random((T, H, W, 1)).astype(np.float16)
        for k in ("images/wrinkle", "images/normal_world", "images/normal_tangent"):
            a[k] = rng.normal(size=(T, H, W, 3)).astype(np.float16)
        a["images/mask"] = (rng.random((H, W)) > 0.3).astype(np.uint8)
    if coarse:
        a["coarse/vertices"] = rng.normal(size=(T, 3, 3)).astype(f32)
        a["coarse/strain_norm"] = rng.random((T, 1)).astype(f32)
        a["coarse/rest_vertices"] = rng.normal(size=(3, 3)).astype(f32)
        a["coarse/faces"] = np.array([[0, 1, 2]], np.int32)
        a["coarse/uvs"] = rng.random((3, 2)).astype(f32)
        a["coarse/uv_faces"] = np.array([[0, 1, 2]], np.int32)
    return a


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A 4-sequence dataset written with ``write_sequence`` and a manifest as the generator's.

    Returns (root, {id: arrays written}).
    """
    root = tmp_path_factory.mktemp("ds")
    (root / "sequences").mkdir()
    rng = np.random.default_rng(7)
    written, entries = {}, {}
    for index, (sid, spec) in enumerate(SPECS.items()):
        split, garment, material, motion, T, V, F, U, image, coarse = spec
        arrays = _arrays(rng, T, V, F, U, image, coarse)
        path = sequence_path(root, sid)
        sha = write_sequence(path, arrays, {"sequence": json.dumps({"id": sid})})
        written[sid] = arrays
        entries[sid] = {
            "file": f"sequences/{sid}.safetensors", "sha256": sha, "bytes": path.stat().st_size, "frames": T,
            "split": split, "index": index, "seed": 100 + index, "garment": garment, "garment_params": {},
            "material": material, "motion": motion, "betas": arrays["body/betas"].tolist(),
            "vertices": V, "faces": F, "uvs": U, "coarse_vertices": 3 if coarse else 0,
            "image_resolution": list(image) if image else None,
            "quality": {"max_edge_strain": 0.1 * (index + 1), "inside_fraction_mean": 0.01 * index,
                        "self_intersections_max": index},
        }
    manifest = {"schema_version": SCHEMA_VERSION, "config": {"seed": 0}, "sequences": entries,
                "rejected": {"seq-00004": {"index": 4, "garment": "dress", "motion": "run",
                                           "reasons": ["edge strain 0.6 > 0.3"]}}}
    atomic_write_json(root / "manifest.json", manifest)
    return root, written


def _expected_starts(T: int, window: int, stride: int) -> list[int]:
    return list(range(0, T - window + 1, stride))


@pytest.mark.parametrize("window,stride", [(1, 1), (3, 2), (5, 5), (12, 1), (13, 1)])
def test_windows_cover_each_sequence(dataset, window, stride):
    root, _ = dataset
    ds = GarmentSequenceDataset(root, "all", window=window, stride=stride, keys=["fine/vertices"])
    want = [(sid, s) for sid, spec in SPECS.items() for s in _expected_starts(spec[4], window, stride)]
    assert [ds.locate(i) for i in range(len(ds))] == want
    assert len(ds) == len(want)
    assert ds.skipped == tuple(sid for sid, spec in SPECS.items() if spec[4] < window)
    assert ds.num_skipped == len(ds.skipped)
    with pytest.raises(IndexError):
        ds[len(ds)]


def test_window_counts_by_hand(dataset):
    root, _ = dataset
    # T = 7, 12, 12, 3 with window 3, stride 2: 3 + 5 + 5 + 1 windows
    assert len(GarmentSequenceDataset(root, "all", window=3, stride=2)) == 14
    # window 8: the 7- and 3-frame sequences are skipped
    ds = GarmentSequenceDataset(root, "all", window=8, stride=4)
    assert len(ds) == 2 + 2 and ds.skipped == ("seq-00000", "seq-00003")


def test_items_equal_written_arrays(dataset):
    root, written = dataset
    keys = ["fine/vertices", "fine/wrinkle", "fine/strain_norm", "fine/faces", "fine/rest_vertices",
            "body/poses", "body/betas", "quality/self_intersections"]
    ds = GarmentSequenceDataset(root, "all", window=3, stride=2, keys=keys)
    for i in range(len(ds)):
        item = ds[i]
        sid, start = ds.locate(i)
        assert item["sequence"] == sid and item["start"] == start
        assert set(item) == {*keys, "sequence", "start"}
        for k in keys:
            ref = written[sid][k]
            if k in PER_FRAME_KEYS:
                ref = ref[start:start + 3]
            np.testing.assert_array_equal(item[k].numpy(), ref, err_msg=f"{sid} {k} start {start}")
            assert item[k].dtype == (torch.int32 if ref.dtype == np.int32 else torch.float32), k
    # negative indices count from the end
    assert ds[-1]["sequence"] == "seq-00003" and ds[-1]["start"] == 0


def test_window_one_keeps_the_window_axis(dataset):
    root, written = dataset
    ds = GarmentSequenceDataset(root, "test_id", keys=["fine/vertices", "fine/faces"])
    assert len(ds) == 12
    item = ds[5]
    assert item["fine/vertices"].shape == (1, 8, 3)
    np.testing.assert_array_equal(item["fine/vertices"][0].numpy(), written["seq-00001"]["fine/vertices"][5])
    assert item["fine/faces"].shape == (6, 3)


def test_items_are_copies(dataset):
    root, written = dataset
    ds = GarmentSequenceDataset(root, "train", keys=["fine/vertices"])
    item = ds[0]
    item["fine/vertices"] += 1.0  # writable, and does not touch the file
    np.testing.assert_array_equal(ds[0]["fine/vertices"][0].numpy(), written["seq-00000"]["fine/vertices"][0])


def test_default_keys_and_f16_images(dataset):
    root, written = dataset
    # train mixes a sequence with images and one without: no images by default
    ds = GarmentSequenceDataset(root, "train")
    assert not any(k.startswith("images/") for k in ds.keys)
    assert {"fine/vertices", "fine/base", "fine/wrinkle", "fine/strain_norm", *BODY_KEYS} == set(ds.keys)
    # t_shirts all have images: they come by default, f16 converted to the float dtype
    ds = GarmentSequenceDataset(root, "all", garments="t_shirt", window=2, stride=3, dtype=torch.float64)
    assert set(IMAGE_KEYS) <= set(ds.keys)
    item = ds[4]  # seq-00000 (7 frames) has 2 windows (0, 3), seq-00002 (12 frames) 4: (0, 3, 6, 9)
    sid, start = ds.locate(4)
    assert (sid, start) == ("seq-00002", 6) and item["start"] == 6
    img = item["images/wrinkle"]
    assert img.dtype == torch.float64 and img.shape == (2, 4, 5, 3)
    np.testing.assert_array_equal(img.numpy(), written[sid]["images/wrinkle"][6:8].astype(np.float64))
    assert item["images/mask"].dtype == torch.uint8 and item["images/mask"].shape == (4, 5)
    np.testing.assert_array_equal(item["images/mask"].numpy(), written[sid]["images/mask"])
    assert item["fine/vertices"].dtype == torch.float64


def test_split_and_garment_filters(dataset):
    root, _ = dataset
    ids = {s: GarmentSequenceDataset(root, s).sequence_ids for s in ("train", "test_id", "test_ood", "all")}
    assert ids == {"train": ("seq-00000", "seq-00003"), "test_id": ("seq-00001",), "test_ood": ("seq-00002",),
                   "all": tuple(SPECS)}
    assert GarmentSequenceDataset(root, "train", garments=["t_shirt"]).sequence_ids == ("seq-00000",)
    assert GarmentSequenceDataset(root, "all", garments=["skirt", "dress"]).sequence_ids == ("seq-00001",
                                                                                              "seq-00003")
    assert len(GarmentSequenceDataset(root, "test_id", garments="t_shirt")) == 0
    with pytest.raises(WrinklesInputError, match="manifest.json.*'hat'.*dress, skirt, t_shirt"):
        GarmentSequenceDataset(root, "train", garments=["hat"])
    with pytest.raises(ValueError, match="test_id"):
        GarmentSequenceDataset(root, "validation")
    with pytest.raises(ValueError, match="window"):
        GarmentSequenceDataset(root, window=0)


def test_collate_windows(dataset):
    root, written = dataset
    keys = ["fine/vertices", "fine/faces", "body/trans"]
    ds = GarmentSequenceDataset(root, "all", window=3, stride=4, keys=keys)
    # seq-00000: starts 0, 4; seq-00001: 0, 4, 8
    same = collate_windows([ds[0], ds[1]])
    assert same["fine/vertices"].shape == (2, 3, 5, 3) and same["fine/faces"].shape == (2, 4, 3)
    np.testing.assert_array_equal(same["fine/vertices"][1].numpy(),
                                  written["seq-00000"]["fine/vertices"][4:7])
    assert same["start"].tolist() == [0, 4] and same["sequence"] == ["seq-00000", "seq-00000"]
    mixed = collate_windows([ds[1], ds[2]])
    assert isinstance(mixed["fine/vertices"], list)
    assert [v.shape for v in mixed["fine/vertices"]] == [(3, 5, 3), (3, 8, 3)]
    assert mixed["body/trans"].shape == (2, 3, 3)  # equal shapes still stack in a mixed batch
    with pytest.raises(ValueError, match="different keys"):
        collate_windows([ds[0], {"start": 0}])


@pytest.mark.parametrize("context", [None, "spawn"])
def test_dataloader_workers_match_main_process(dataset, context):
    root, _ = dataset
    keys = ["fine/vertices", "fine/uvs", "body/joints"]
    ds = GarmentSequenceDataset(root, "all", window=2, stride=3, keys=keys, verify=True)
    ds[0]  # files opened (and verified) in the main process before the workers start
    if context == "spawn":
        # the pickled state holds no open files: a spawned worker reopens what it reads
        assert ds.__getstate__()["_files"] == {} and copy.deepcopy(ds)._files == {}

    def batches(workers: int) -> list[dict]:
        return list(DataLoader(ds, batch_size=3, num_workers=workers, collate_fn=collate_windows,
                               multiprocessing_context=context if workers else None))

    ref, par = batches(0), batches(2)
    assert len(ref) == len(par) == -(-len(ds) // 3)
    for a, b in zip(ref, par, strict=True):
        assert a.keys() == b.keys()
        for k in a:
            if isinstance(a[k], torch.Tensor):
                torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)
            elif k == "sequence":
                assert a[k] == b[k]
            else:
                for x, y in zip(a[k], b[k], strict=True):
                    torch.testing.assert_close(x, y, rtol=0, atol=0)


def test_a_forked_process_reopens_files(dataset):
    root, _ = dataset
    ds = GarmentSequenceDataset(root, "all", window=12, keys=["fine/vertices"])
    ds[0]
    assert set(ds._files) == {"seq-00001"}
    ds._pid = -1  # as seen from a forked worker: the parent's headers are dropped, not shared
    ds[1]
    assert set(ds._files) == {"seq-00002"}


def _corrupt_copy(dataset, tmp_path):
    """A copy of the dataset with one data byte of seq-00001 flipped."""
    import shutil

    root, _ = dataset
    shutil.copytree(root, tmp_path / "ds")
    path = sequence_path(tmp_path / "ds", "seq-00001")
    raw = bytearray(path.read_bytes())
    raw[-100] ^= 0x01
    path.write_bytes(bytes(raw))
    return tmp_path / "ds", path


def test_verify_detects_a_corrupted_file(dataset, tmp_path):
    root, path = _corrupt_copy(dataset, tmp_path)
    GarmentSequenceDataset(root, "test_id")[0]  # verify off: reads, none the wiser
    ds = GarmentSequenceDataset(root, "all", verify=True)
    ds[0]  # seq-00000 is intact
    assert ds.locate(7) == ("seq-00001", 0)
    with pytest.raises(WrinklesInputError, match="checksum mismatch") as err:
        ds[7]
    msg = str(err.value)
    assert msg.startswith(str(path)) and "\n" not in msg
    with pytest.raises(WrinklesInputError, match="seq-00001.safetensors: checksum"):
        GarmentSequenceDataset(root, "all", verify=True).verify_files()


def test_missing_manifest(tmp_path):
    with pytest.raises(WrinklesInputError, match="no manifest.json") as err:
        GarmentSequenceDataset(tmp_path)
    assert str(tmp_path) in str(err.value)


def test_unknown_and_missing_keys(dataset):
    root, _ = dataset
    with pytest.raises(ValueError, match="'fine/verts'"):
        GarmentSequenceDataset(root, keys=["fine/verts"])
    # coarse arrays exist only in seq-00000: seq-00003 lacks them, named in the error
    ds = GarmentSequenceDataset(root, "train", keys=["coarse/vertices"])
    assert ds[0]["coarse/vertices"].shape == (1, 3, 3)
    with pytest.raises(WrinklesInputError, match=r"seq-00003\.safetensors: no array 'coarse/vertices'"):
        ds[len(ds) - 1]
    ds = GarmentSequenceDataset(root, "test_id", keys=["images/wrinkle"])
    with pytest.raises(WrinklesInputError, match=r"seq-00001\.safetensors: no array 'images/wrinkle'"):
        ds[0]


def test_frame_count_must_match_manifest(dataset, tmp_path):
    import shutil

    root, _ = dataset
    shutil.copytree(root, tmp_path / "ds")
    m = read_manifest(tmp_path / "ds")
    m["sequences"]["seq-00001"]["frames"] = 11
    atomic_write_json(tmp_path / "ds" / "manifest.json", m)
    with pytest.raises(WrinklesInputError, match=r"seq-00001\.safetensors: array 'fine/vertices' has shape"):
        GarmentSequenceDataset(tmp_path / "ds", "test_id")[0]


def test_manifest_statistics(dataset):
    root, _ = dataset
    m = read_manifest(root)
    sizes = {sid: sequence_path(root, sid).stat().st_size for sid in SPECS}
    s = manifest_statistics(m)
    json.dumps(s)  # serialisable as it is
    assert (s["sequences"], s["frames"], s["bytes"], s["rejected"]) == (4, 34, sum(sizes.values()), 1)
    assert s["splits"] == {
        "test_id": {"sequences": 1, "frames": 12, "bytes": sizes["seq-00001"]},
        "test_ood": {"sequences": 1, "frames": 12, "bytes": sizes["seq-00002"]},
        "train": {"sequences": 2, "frames": 10, "bytes": sizes["seq-00000"] + sizes["seq-00003"]},
    }
    assert {g: v["sequences"] for g, v in s["garments"].items()} == {"dress": 1, "skirt": 1, "t_shirt": 2}
    assert {g: v["frames"] for g, v in s["materials"].items()} == {"cotton": 19, "denim": 3, "silk": 12}
    assert {g: v["sequences"] for g, v in s["motions"].items()} == {"jump": 1, "run": 1, "walk": 2}
    assert s["garment_splits"] == {"dress": {"test_id": 1}, "skirt": {"train": 1},
                                   "t_shirt": {"test_ood": 1, "train": 1}}
    assert s["image_resolutions"] == {"4x5": 2, "none": 2}
    q = s["quality"]["max_edge_strain"]
    np.testing.assert_allclose([q["mean"], q["max"], q["min"]], [0.25, 0.4, 0.1])
    assert s["quality"]["self_intersections_max"]["max"] == 3 and q["count"] == 4
    t = manifest_statistics(m, split="train")
    assert (t["sequences"], t["frames"], t["rejected"]) == (2, 10, 1)
    np.testing.assert_allclose(t["quality"]["inside_fraction_mean"]["mean"], 0.015)
    full = dataset_statistics(root)
    assert full["sequences"] == 4 and full["root"] == str(root)
    assert full["bytes_per_frame"] == full["bytes"] / full["frames"]
    text = format_statistics(full)
    assert "4 sequences (1 rejected, 80 % accepted)" in text and "t_shirt 2" in text
