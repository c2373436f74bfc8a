"""The garment cache (``sim.garments.garment_cache``): a garment written and read back is the same
garment, and processes sharing the folder build a key once (the others wait for its lock)."""

from __future__ import annotations

import multiprocessing
import time

import numpy as np
import pytest

from sim.garments import garment_cache as gc
from sim.garments.materials import get_material
from sim.garments.types import Garment
from tests.test_cloth_solver import grid


def small_garment() -> Garment:
    v, f = grid(4, 5, 0.2, 0.3)
    uv = v[:, :2] * 2 + 0.5
    layers = np.linspace(1.0, 3.0, len(f)).astype(np.float32)
    return Garment(v, f, uv, f, get_material("denim"), attachments={"hem": np.array([0, 1, 2])},
                   category="sheet", name="sheet", face_layers=layers)


def test_a_saved_garment_loads_back_the_same(tmp_path):
    g = small_garment()
    gc.save_garment(g, tmp_path / "g.npz")
    back = gc.load_cached(tmp_path / "g.npz")
    for field in ("rest_vertices", "faces", "uvs", "uv_faces", "panel_ids", "face_layers"):
        np.testing.assert_array_equal(getattr(back, field), getattr(g, field), err_msg=field)
    np.testing.assert_array_equal(back.attachments["hem"], g.attachments["hem"])
    assert (back.material, back.category, back.name) == (g.material, g.category, g.name)
    assert [p.name for p in tmp_path.iterdir()] == ["g.npz"]  # no temporary file left


def _build_in_child(folder: str, log: str, out) -> None:
    import os

    os.environ["WRINKLES_CACHE"] = folder

    def build() -> Garment:
        with open(log, "a") as f:
            f.write(f"{os.getpid()}\n")
        time.sleep(0.5)  # long enough for the other process to find no file and wait for the lock
        return small_garment()

    g = gc.cached_garment({"test": "garment-cache-lock"}, build)
    out.put(g.rest_vertices.tolist())


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="no fork here")
def test_processes_sharing_the_folder_build_a_garment_once(tmp_path):
    ctx = multiprocessing.get_context("fork")
    log, out = tmp_path / "builds.txt", ctx.Queue()
    procs = [ctx.Process(target=_build_in_child, args=(str(tmp_path), str(log), out)) for _ in range(2)]
    for p in procs:
        p.start()
    got = [out.get(timeout=60) for _ in procs]
    for p in procs:
        p.join(timeout=60)
        assert p.exitcode == 0
    assert len(log.read_text().split()) == 1  # one build, the other process read its file
    for v in got:
        np.testing.assert_array_equal(np.float32(v), small_garment().rest_vertices)
    assert len(list((tmp_path / "garments").glob("*.npz"))) == 1


def test_hems_and_names_share_one_sewing(tmp_path, monkeypatch):
    """Hems only set the faces' layers after sewing: a design asked for with other hems or
    another name is sewn once, and each gets the layers of its own hems on the same mesh."""
    from sim.bodies.default import load_default_body
    from sim.garments import designs
    from sim.garments.hems import hem_face_layers
    from sim.garments.templates import make_garment

    monkeypatch.setenv("WRINKLES_CACHE", str(tmp_path))
    monkeypatch.setattr(gc, "_MEMORY", {})
    sewn = []
    real = designs.sew_patterns
    monkeypatch.setattr(designs, "sew_patterns", lambda jobs, **k: sewn.extend(jobs) or real(jobs, **k))
    body = load_default_body()
    plain = make_garment("straight_skirt", body, resolution=0.06, device="cpu")
    wide = make_garment("straight_skirt", body, resolution=0.06, device="cpu", hem_width=0.04, hem_layers=2.0)
    bare = make_garment("straight_skirt", body, resolution=0.06, device="cpu", name="skirt", hem_width=0.0)
    assert len(sewn) == 1
    np.testing.assert_array_equal(wide.rest_vertices, plain.rest_vertices)
    hems = hem_face_layers(plain.rest_vertices, plain.faces, 0.04, 2.0)
    np.testing.assert_array_equal(wide.face_layers, hems)
    assert (bare.face_layers == 1.0).all() and plain.face_layers.max() > 1.0
    assert (plain.name, bare.name) == ("straight_skirt", "skirt")
    assert len(list((tmp_path / "garments").glob("*.npz"))) == 1


def test_garments_of_a_batch_are_sewn_together_once_each(tmp_path, monkeypatch):
    """make_garments sews the garments the cache lacks in one sew_patterns batch (an order twice:
    once), and each is the garment make_garment makes alone."""
    from sim.bodies.default import load_default_body
    from sim.garments import designs
    from sim.garments.designs import GarmentRequest
    from sim.garments.templates import make_garment, make_garments

    monkeypatch.setenv("WRINKLES_CACHE", str(tmp_path))
    monkeypatch.setattr(gc, "_MEMORY", {})
    batches = []
    real = designs.sew_patterns
    monkeypatch.setattr(designs, "sew_patterns",
                        lambda jobs, **k: batches.append(len(jobs)) or real(jobs, **k))
    body = load_default_body()
    wide = np.zeros(body.num_betas, np.float32)
    wide[0] = 1.0
    orders = [GarmentRequest("straight_skirt", body, None, 0.07),
              GarmentRequest("straight_skirt", body, wide, 0.07),
              GarmentRequest("straight_skirt", body, None, 0.07, garment_name="again")]
    made = make_garments(orders, device="cpu")
    assert batches == [2] and made[2].name == "again"
    np.testing.assert_array_equal(made[0].rest_vertices, made[2].rest_vertices)
    monkeypatch.setenv("WRINKLES_CACHE", "off")
    monkeypatch.setattr(gc, "_MEMORY", {})
    alone = make_garment("straight_skirt", body, wide, resolution=0.07, device="cpu")
    assert batches == [2, 1]
    np.testing.assert_array_equal(made[1].rest_vertices, alone.rest_vertices)
    assert made[1].num_vertices != made[0].num_vertices or not np.array_equal(made[1].rest_vertices,
                                                                               made[0].rest_vertices)


def test_every_source_of_the_code_digest_exists():
    """A misspelt entry would hash nothing, and a change to that code would read old garments."""
    from pathlib import Path

    root = Path(gc.__file__).resolve().parents[2]
    for source in gc.SOURCES:
        path = root / source
        assert path.is_file() if source.endswith(".py") else any(path.rglob("*.py")), source
    assert len(gc.source_digest()) == 64
