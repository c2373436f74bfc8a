"""Newton SolverVBD reference runner (benchmarks/newton_ref.py): physics sanity on the CPU.

Skips unless ``newton`` imports (it is an optional benchmark dependency; see
docs/BENCHMARKS.md for the separate ``.venv-newton``).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("newton")

from benchmarks.newton_ref import (  # noqa: E402
    bending_edge_stiffness,
    hinge_layers,
    layered_masses,
    run_newton_vbd,
    validate_scene,
)

G = 9.81
FPS = 30.0
RADIUS = 0.2
TOP = 0.3  # sheet height: 0.1 m above the sphere's top


def sheet(n: int = 10, size: float = 0.5, y: float = TOP):
    """n x n vertices in the plane y, centred on the y axis, faces wound with normals +y."""
    s = np.linspace(-size / 2, size / 2, n, dtype=np.float32)
    xx, zz = np.meshgrid(s, s, indexing="ij")
    v = np.stack([xx.ravel(), np.full(n * n, y, np.float32), zz.ravel()], axis=1)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            f += [(a, d, b), (b, d, c)]
    return v, np.asarray(f, np.int32)


def uv_sphere(r: float, n_lat: int = 16, n_lon: int = 24):
    """Closed, outward-facing (counter-clockwise seen from outside) UV sphere at the origin."""
    v = [(0.0, r, 0.0)]
    for i in range(1, n_lat):
        th = np.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * np.pi * j / n_lon
            v.append((r * np.sin(th) * np.cos(ph), r * np.cos(th), r * np.sin(th) * np.sin(ph)))
    v.append((0.0, -r, 0.0))
    v = np.asarray(v, np.float32)
    bottom = len(v) - 1

    def ring(i, j):
        return 1 + (i - 1) * n_lon + j % n_lon

    f = []
    for j in range(n_lon):
        f.append((0, ring(1, j + 1), ring(1, j)))
        f.append((bottom, ring(n_lat - 1, j), ring(n_lat - 1, j + 1)))
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            a, b, c, d = ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)
            f += [(a, b, c), (a, c, d)]
    f = np.asarray(f, np.int32)
    # outward: the face normal points away from the centre
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert (np.einsum("ij,ij->i", n, v[f].mean(axis=1)) > 0).all()
    return v, f


def scene(frames: int, pinned=()):
    v, f = sheet()
    sv, sf = uv_sphere(RADIUS)
    return {
        "garment_positions": v, "garment_rest_positions": v, "garment_faces": f,
        "pinned": np.asarray(pinned, np.int32), "pin_targets": np.zeros(0, np.float32),
        # cotton-like (sim.garments.materials "cotton"), thicker contact offset for a coarse sheet
        "density": 0.15, "mu": 1.5e3, "lam": 6.0e2, "bending": 5e-6, "damping": 2e-3,
        "friction": 0.4, "thickness": 2e-3,
        "body_faces": sf, "body_vertices": np.repeat(sv[None], frames, axis=0), "fps": FPS,
    }


@pytest.fixture(scope="module")
def drape():
    return run_newton_vbd(scene(24), device="cpu", substeps=10, iterations=10, self_contact=False,
                          use_graph=False)


def test_free_fall_then_rest_on_sphere(drape):
    x = drape["positions"]
    assert x.shape == (24, 100, 3) and x.dtype == np.float32
    assert np.isfinite(x).all()
    # before contact (3 frames = 0.1 s, 4.9 cm < 10 cm gap): every vertex fell ~g t^2 / 2
    t = 3 / FPS
    drop = TOP - x[3, :, 1]
    np.testing.assert_allclose(drop, 0.5 * G * t * t, rtol=0.1)
    # no sideways drift in free fall
    assert np.abs(x[3, :, [0, 2]] - x[0, :, [0, 2]]).max() < 1e-4
    # at the end: draped over the sphere, nothing inside it, the centre resting on the top
    r = np.linalg.norm(x[-1], axis=1)
    assert r.min() > RADIUS - 2e-3, r.min()
    centre = x[-1][np.argmin(np.abs(x[0, :, 0]) + np.abs(x[0, :, 2]))]
    assert RADIUS - 2e-3 < centre[1] < RADIUS + 2e-2, centre
    # the free edges hang below the contact point
    assert x[-1, :, 1].min() < RADIUS - 0.05


def test_result_fields(drape):
    assert drape["graph"] is False and drape["self_contact"] is False
    assert drape["timed_frames"] == 21 and np.isfinite(drape["ms_per_frame"])
    assert drape["newton_version"].startswith("1.")
    assert drape["cloth_vertices"] == 100


def test_pins_stay_and_self_contact_runs():
    res = run_newton_vbd(scene(6, pinned=[0, 9]), device="cpu", substeps=5, iterations=5, self_contact=True,
                         use_graph=True)
    x = res["positions"]
    assert np.isfinite(x).all()
    assert np.array_equal(x[:, [0, 9]], np.repeat(x[:1, [0, 9]], len(x), axis=0))
    assert x[-1, 50, 1] < TOP - 0.05  # the rest fell
    assert any("CUDA" in n for n in res["notes"])  # graph ignored on the CPU
    assert any("self-contact DAT" in n for n in res["notes"])


def test_moving_body_carries_the_sheet_by_friction():
    # the sheet rests on the sphere's top; the sphere then slides 0.4 m along +x at 0.6 m/s, out
    # of its frame-0 bounding box: friction against the mesh velocity must carry the sheet, and
    # the contact must follow the mesh (the shape's AABB covers all frames)
    T = 25
    shift = np.zeros((T, 1, 3), np.float32)
    shift[:, 0, 0] = np.clip(np.arange(T) - 4, 0, None) * (0.6 / FPS)
    carried = {}
    for mu in (0.0, 0.8):
        sc = scene(T)
        v, _ = sheet(y=RADIUS + 3e-3)
        sc.update(garment_positions=v, garment_rest_positions=v, friction=mu,
                  body_vertices=sc["body_vertices"] + shift)
        res = run_newton_vbd(sc, device="cpu", substeps=10, iterations=10, self_contact=False,
                             use_graph=False)
        x = res["positions"]
        assert np.isfinite(x).all()
        assert np.linalg.norm(x - shift, axis=2).min() > RADIUS - 2e-3  # never inside the moving sphere
        assert res["body_max_vertex_speed_m_per_s"] == pytest.approx(0.6, rel=1e-3)
        carried[mu] = float(x[-1, :, 0].mean() - x[0, :, 0].mean())
    assert carried[0.8] > 0.35, carried
    assert abs(carried[0.0]) < 0.1, carried


def test_bending_edge_stiffness_matches_hinge_stiffness():
    # two right triangles sharing the edge (0,0,0)-(1,0,0): k_e = 3 k_b |e|^2 / (A1 + A2)
    rest = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, -1]], np.float64)
    edges = np.array([[2, 3, 0, 1], [-1, 2, 0, 2]])
    ke = bending_edge_stiffness(rest, edges, 2.0)
    assert ke[0] * 1.0 == pytest.approx(3 * 2.0 * 1.0 / (0.5 + 0.5))
    assert ke[1] == 0.0


def test_layered_masses_match_the_cloth_model():
    # the runner's lumped masses are our model's: a third of each face's area times its layers
    from sim.cloth.model import lumped_areas

    v, f = sheet(n=6)
    rng = np.random.default_rng(3)
    layers = rng.choice([1.0, 1.5, 3.0], size=len(f))
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    np.testing.assert_allclose(layered_masses(v, f, layers, 0.2), 0.2 * lumped_areas(len(v), f, area, layers),
                               rtol=1e-6)
    # total: density x sum of area x layers
    total = layered_masses(v, f, layers, 0.2).sum()
    assert total == pytest.approx(0.2 * float((area * layers).sum()), rel=1e-6)


def test_hinge_layers_take_the_mean_of_the_edge_faces():
    # two triangles (0,1,2) at 1 layer and (1,0,3) at 3: the shared edge 0-1 has mean 2, the
    # boundary edges their one face's layers
    faces = np.array([[0, 1, 2], [1, 0, 3]])
    edges = np.array([[2, 3, 0, 1], [-1, 0, 1, 2], [-1, 1, 0, 3], [-1, 0, 3, 0]])
    np.testing.assert_allclose(hinge_layers(faces, np.array([1.0, 3.0]), edges), [2.0, 1.0, 3.0, 3.0])
    with pytest.raises(ValueError, match="no edge"):
        hinge_layers(faces, np.array([1.0, 3.0]), np.array([[0, 1, 2, 3]]))


def test_face_layers_are_validated():
    sc = scene(2)
    sc["face_layers"] = np.ones(5)
    with pytest.raises(ValueError, match="one value per face"):
        validate_scene(sc)
    sc["face_layers"] = np.full(len(sc["garment_faces"]), 0.5)
    with pytest.raises(ValueError, match=">= 1"):
        validate_scene(sc)
    sc["face_layers"] = None  # a garment without hems
    assert (validate_scene(sc)["face_layers"] == 1.0).all()


def test_two_layers_everywhere_are_the_material_doubled():
    # n layers scale the density, membrane moduli and bending alike: a sheet of 2 layers moves
    # as the sheet of the doubled material (same contact stiffness), and unlike the single layer
    # while it drapes (its mass doubles but the contact stiffness does not)
    frames = 12
    layered = scene(frames)
    layered["face_layers"] = np.full(len(layered["garment_faces"]), 2.0)
    doubled = scene(frames)
    for k in ("density", "mu", "lam", "bending"):
        doubled[k] = 2.0 * doubled[k]
    runs = [run_newton_vbd(s, device="cpu", substeps=5, iterations=5, self_contact=False, use_graph=False)
            for s in (layered, doubled, scene(frames))]
    x2, xd, x1 = (r["positions"] for r in runs)
    np.testing.assert_allclose(x2, xd, atol=2e-5)
    masses = [r["newton_params"]["mass_kg"] for r in runs]
    assert masses[0] == pytest.approx(2 * masses[2], rel=1e-5)
    assert np.abs(x2[-1] - x1[-1]).max() > 1e-4  # the contact sees twice the weight
