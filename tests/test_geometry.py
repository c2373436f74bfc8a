"""Green-Lagrange strain and local frames on exact cases: rigid motions, uniaxial stretch, shear,
a numpy reference; frames of a linear map and of a cylinder, encode/decode round trips across
seams, normal offsets, rotation equivariance, degenerate frames."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.geometry.frames import (
    SurfaceFrames,
    decode_wrinkles,
    encode_wrinkles,
    local_frames,
    uv_scale,
    uv_vertex_map,
    vertex_normals,
)
from sim.geometry.primitives import uv_sphere
from sim.geometry.strain import GreenStrain, green_lagrange, strain_field, strain_norm

F32_POSITION = 3e-5
"""Strain tolerance when positions are float32 near 1-2 m: coordinates are rounded to ~1.2e-7 m,
which is ~1e-5 of a 1.8 cm edge (E ~ 2 δl / l)."""
STRAIN_ATOL = 1e-5
"""Strain tolerance on the test sheets: float32 coordinates up to ~1 m are rounded to ~6e-8 m,
~2e-6 of the shortest jittered edge (3 cm); E = ½(l²/l0² − 1) doubles that and λ² scales it."""


def sheet(n: int = 12, size: float = 0.5, *, jitter: float = 0.0, seed: int = 0):
    """An n x n vertex sheet in the XY plane, (V, 3), faces (F, 3) counter-clockwise about +Z, and
    UVs = XY / size, so metres per UV unit = size."""
    u = np.linspace(0.0, size, n)
    X, Y = np.meshgrid(u, u, indexing="ij")
    xy = np.stack([X.ravel(), Y.ravel()], 1)
    if jitter:
        rng = np.random.default_rng(seed)
        inner = (xy > 0).all(1) & (xy < size).all(1)
        xy[inner] += rng.uniform(-jitter, jitter, (inner.sum(), 2)) * size / (n - 1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    b, c, d = a + n, a + n + 1, a + 1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    v = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    return v, faces, xy / size


def rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def cylinder(n_around: int = 40, n_up: int = 12, radius: float = 0.15, height: float = 0.4):
    """An open cylinder around +Y with outward faces and a UV seam at θ = 0 (the seam column of
    vertices has two UV copies). UV: u = r θ / L, v = y / L, L = max(2π r, height)."""
    th = 2 * np.pi * np.arange(n_around) / n_around
    ys = np.linspace(0.0, height, n_up)
    T, Yg = np.meshgrid(th, ys, indexing="ij")
    v = np.stack([radius * np.cos(T).ravel(), Yg.ravel(), radius * np.sin(T).ravel()], 1)
    L = max(2 * np.pi * radius, height)
    thu = np.append(th, 2 * np.pi)  # seam: column n_around duplicates column 0 in UV only
    TU, YU = np.meshgrid(thu, ys, indexing="ij")
    uvs = np.stack([radius * TU.ravel() / L, YU.ravel() / L], 1)
    faces, uv_faces = [], []
    for i in range(n_around):
        for j in range(n_up - 1):
            i1 = (i + 1) % n_around
            a, b, c, d = i * n_up + j, i1 * n_up + j, i1 * n_up + j + 1, i * n_up + j + 1
            ua, ub, uc, ud = i * n_up + j, (i + 1) * n_up + j, (i + 1) * n_up + j + 1, i * n_up + j + 1
            # outward (+radial) normals: θ increases from +X toward +Z, so wind (a, d, c)
            faces += [[a, d, c], [a, c, b]]
            uv_faces += [[ua, ud, uc], [ua, uc, ub]]
    return v, np.array(faces, np.int32), uvs, np.array(uv_faces, np.int32)


@pytest.fixture(scope="module")
def tshirt():
    from sim.bodies import load_body
    from sim.garments import make_garment

    return make_garment("t_shirt", load_body(), resolution=0.03)


# ---------------------------------------------------------------- strain


def test_strain_is_zero_for_rigid_motions(device, tshirt):
    rng = np.random.default_rng(1)
    x = tshirt.rest_vertices
    seq = np.stack([x @ rotation(rng).T + rng.uniform(-1, 1, 3) for _ in range(4)]).astype(np.float32)
    field = strain_field(seq, x, tshirt.faces, uvs=tshirt.uvs, uv_faces=tshirt.uv_faces, device=device)
    assert field.face.shape == (4, tshirt.num_faces, 3)
    assert field.vertex_norm.shape == (4, tshirt.num_vertices)
    np.testing.assert_allclose(field.face, 0.0, atol=F32_POSITION)
    np.testing.assert_allclose(field.vertex_norm, 0.0, atol=F32_POSITION)


UNIAXIAL_CASES = [(1.3, 0.0), (0.8, 0.0), (1.2, np.pi / 2), (1.25, 0.7)]


@pytest.mark.parametrize("stretch, angle", UNIAXIAL_CASES)
def test_strain_of_uniaxial_stretch_is_exact(device, stretch, angle):
    """Stretch by λ along d = (cos α, sin α) in the sheet's plane: E = (λ² − 1)/2 d dᵀ."""
    rng = np.random.default_rng(2)
    v, f, uv = sheet(8, jitter=0.3)
    R0, R1 = rotation(rng), rotation(rng)
    rest = v @ R0.T  # the sheet anywhere in 3D; its UV axes are R0's first two columns
    d = np.array([np.cos(angle), np.sin(angle), 0.0])
    deformed = (v + (stretch - 1.0) * (v @ d)[:, None] * d) @ R0.T @ R1.T + [0.2, -0.1, 0.3]
    e = (stretch ** 2 - 1) / 2
    want = np.array([e * d[0] ** 2, e * d[1] ** 2, e * d[0] * d[1]])
    got = green_lagrange(deformed, rest, f, uvs=uv, uv_faces=f, device=device)
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), atol=STRAIN_ATOL)
    np.testing.assert_allclose(strain_norm(got), abs(e), atol=STRAIN_ATOL)
    # face frames along each face's first edge: components differ, invariants do not
    plain = green_lagrange(deformed, rest, f, device=device)
    np.testing.assert_allclose(strain_norm(plain), abs(e), atol=STRAIN_ATOL)
    np.testing.assert_allclose(plain[:, 0] + plain[:, 1], e, atol=STRAIN_ATOL)


@pytest.mark.parametrize("kind", ["simple", "pure"])
def test_strain_of_shear_is_exact(device, kind):
    """Simple shear x' = x + γ y: E = [[0, γ/2], [γ/2, γ²/2]]. Pure shear, stretch λ along
    (1, 1)/√2 and 1/λ along (1, −1)/√2: E11 = E22 = (λ² + λ⁻² − 2)/4, E12 = (λ² − λ⁻²)/4."""
    rng = np.random.default_rng(3)
    v, f, uv = sheet(8, jitter=0.3)
    R0 = rotation(rng)
    if kind == "simple":
        g = 0.3
        F2 = np.array([[1.0, g], [0.0, 1.0]])
        want = np.array([0.0, g * g / 2, g / 2])
        norm = g / 2 * np.sqrt(g * g + 2)
    else:
        lam = 1.2
        a, b = (lam + 1 / lam) / 2, (lam - 1 / lam) / 2
        F2 = np.array([[a, b], [b, a]])
        e1, e2 = (lam ** 2 - 1) / 2, (lam ** -2 - 1) / 2
        want = np.array([(e1 + e2) / 2, (e1 + e2) / 2, (e1 - e2) / 2])
        norm = np.hypot(e1, e2)
    moved = v.copy()
    moved[:, :2] = v[:, :2] @ F2.T
    deformed = moved @ rotation(rng).T
    got = green_lagrange(deformed, v @ R0.T, f, uvs=uv, uv_faces=f, device=device)
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), atol=STRAIN_ATOL)
    np.testing.assert_allclose(strain_norm(got), norm, atol=STRAIN_ATOL)


def test_strain_matches_numpy_reference(device):
    """Random curved rest sheet, random UVs, random deformation: components in the UV-aligned
    frame from a QR of ∂X/∂u (independent of the kernel's construction), norms from the frame-free
    Gram matrices, vertex averages from bincount."""
    rng = np.random.default_rng(4)
    v, f, uv = sheet(10, jitter=0.35, seed=4)
    v[:, 2] = 0.1 * np.sin(3 * v[:, 0]) * np.cos(2 * v[:, 1])
    uv = uv + rng.uniform(-0.01, 0.01, uv.shape)
    rest = (v @ rotation(rng).T).astype(np.float32)
    T = 3
    seq = (rest + 0.02 * rng.normal(size=(T,) + rest.shape)).astype(np.float32)
    got = strain_field(seq, rest, f, uvs=uv, uv_faces=f, device=device)

    X, x, q = rest.astype(np.float64)[f], seq.astype(np.float64)[:, f], uv[f]
    Q = np.stack([q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]], 2)
    Qi = np.linalg.inv(Q)
    Gr = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]], 2) @ Qi  # (F, 3, 2) ∂X/∂u
    Gd = np.stack([x[:, :, 1] - x[:, :, 0], x[:, :, 2] - x[:, :, 0]], 3) @ Qi  # (T, F, 3, 2) ∂x/∂u
    _, Rq = np.linalg.qr(Gr)
    Rq *= np.sign(np.diagonal(Rq, axis1=1, axis2=2))[:, :, None]  # positive diagonal: axes along +u1, +u2
    Ri = np.linalg.inv(Rq)
    Euv = 0.5 * (np.swapaxes(Gd, 2, 3) @ Gd - np.swapaxes(Gr, 1, 2) @ Gr)
    E = np.swapaxes(Ri, 1, 2) @ Euv @ Ri
    want = np.stack([E[..., 0, 0], E[..., 1, 1], E[..., 0, 1]], -1)
    np.testing.assert_allclose(got.face, want, atol=STRAIN_ATOL)

    ed = np.stack([x[:, :, 1] - x[:, :, 0], x[:, :, 2] - x[:, :, 0]], 3)
    er = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]], 2)
    K = np.linalg.inv(np.swapaxes(er, 1, 2) @ er) @ (np.swapaxes(ed, 2, 3) @ ed) - np.eye(2)
    norm = 0.5 * np.sqrt(np.trace(K @ K, axis1=-2, axis2=-1))
    np.testing.assert_allclose(got.face_norm, norm, atol=STRAIN_ATOL)
    plain = green_lagrange(seq, rest, f, device=device)  # edge-aligned frames: same norm
    np.testing.assert_allclose(strain_norm(plain), norm, atol=STRAIN_ATOL)

    area = 0.5 * np.linalg.norm(np.cross(er[..., 0], er[..., 1]), axis=1)
    wsum = np.bincount(f.ravel(), np.repeat(area, 3), len(rest))
    for t in range(T):
        vn = np.bincount(f.ravel(), np.repeat(area * norm[t], 3), len(rest)) / wsum
        np.testing.assert_allclose(got.vertex_norm[t], vn, atol=STRAIN_ATOL)
        for c in range(3):
            vc = np.bincount(f.ravel(), np.repeat(area * want[t, :, c], 3), len(rest)) / wsum
            np.testing.assert_allclose(got.vertex[t, :, c], vc, atol=STRAIN_ATOL)
    # one frame in, one frame out
    np.testing.assert_allclose(GreenStrain(rest, f, device=device).face_strain(seq[1]),
                               green_lagrange(seq, rest, f, device=device)[1])


def test_strain_input_errors():
    v, f, _ = sheet(4)
    with pytest.raises(WrinklesInputError, match="zero area"):
        green_lagrange(v, np.where(np.arange(len(v))[:, None] == 0, v[1], v), f, device="cpu")
    with pytest.raises(WrinklesInputError, match="shape"):
        green_lagrange(v[:, :2], v, f, device="cpu")
    with pytest.raises(WrinklesInputError, match="outside"):
        green_lagrange(v, v, f + 1, device="cpu")


# ---------------------------------------------------------------- frames


def test_uv_scale_and_vertex_map(tshirt):
    v, f, uv = sheet(6, size=0.7)
    assert uv_scale(v, f, uv, f) == pytest.approx(0.7, rel=1e-12)
    m = uv_vertex_map(tshirt.faces, tshirt.uv_faces, len(tshirt.uvs))
    assert m.shape == (len(tshirt.uvs),) and m.min() >= 0
    np.testing.assert_array_equal(m[tshirt.uv_faces], tshirt.faces)
    assert len(tshirt.uvs) > tshirt.num_vertices  # seams split UV vertices
    bad = f.copy()
    bad[0, 0] = 5  # UV vertex 0 is now a corner of 3D vertices 5 and 0
    with pytest.raises(WrinklesInputError, match="one 3D vertex"):
        uv_vertex_map(bad, f, len(uv))


def test_frames_of_a_linear_map_are_exact(device):
    """base = P X + c of a flat sheet whose UVs are X / size: t_i = P e_i, n̂ = unit(P e1 × P e2)."""
    rng = np.random.default_rng(5)
    v, f, uv = sheet(9, size=0.6, jitter=0.3)
    P = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
    base = v @ P.T + [0.3, 1.1, -0.2]
    fr = local_frames(base, f, uv, f, uv_scale(v, f, uv, f), device=device)
    assert fr.shape == (len(uv), 3, 3)
    n = np.cross(P[:, 0], P[:, 1])
    n /= np.linalg.norm(n)
    want = np.stack([P[:, 0], P[:, 1], n], 1)
    np.testing.assert_allclose(fr, np.broadcast_to(want, fr.shape), atol=1e-5)


def test_cylinder_frames_follow_the_surface(device):
    """On a seamed cylinder (40 flat facets around): t2 along +Y, t1 along increasing θ, n̂
    radial outward, with |t2| = 1 / c, c = sqrt(chord / arc) (the scale comes from the facets'
    area), and |t1| = c cos(π/40) (the mean of the chords on both sides); exact by symmetry away
    from the seam and the two boundary rows. Each seam copy sees only its own side: its frame is
    the adjacent facet's, at angle ±π/40, with |t1| = c."""
    n_around, n_up = 40, 12
    v, f, uv, uf = cylinder(n_around, n_up)
    fr = local_frames(v, f, uv, uf, uv_scale(v, f, uv, uf), device=device)
    c = np.sqrt(np.sin(np.pi / n_around) / (np.pi / n_around))

    def frame_at(angle, length):
        angle = np.asarray(angle)[:, None]
        zero = np.zeros_like(angle)
        t1 = length * np.concatenate([-np.sin(angle), zero, np.cos(angle)], 1)
        t2 = np.concatenate([zero, zero + 1.0 / c, zero], 1)
        n = np.concatenate([np.cos(angle), zero, np.sin(angle)], 1)
        return np.stack([t1, t2, n], 2)

    col, row = np.divmod(np.arange(len(uv)), n_up)
    inner = (row > 0) & (row < n_up - 1) & (col > 0) & (col < n_around)
    want = frame_at(2 * np.pi * col[inner] / n_around, c * np.cos(np.pi / n_around))
    np.testing.assert_allclose(fr[inner], want, atol=1e-5)
    np.testing.assert_allclose(fr[:, :, 1], np.broadcast_to([0.0, 1.0 / c, 0.0], (len(uv), 3)), atol=1e-5)
    seam = np.arange(n_up)  # UV column 0 and its copy, column n_around
    np.testing.assert_allclose(fr[seam], frame_at(np.full(n_up, np.pi / n_around), c), atol=1e-5)
    np.testing.assert_allclose(fr[seam + n_around * n_up], frame_at(np.full(n_up, -np.pi / n_around), c),
                               atol=1e-5)


@pytest.mark.parametrize("mesh", ["cylinder", "tshirt"])
def test_encode_decode_round_trip(device, mesh, tshirt):
    """Wrinkled over curved, seamed bases (two frames, the second bent and moved): decode(encode)
    gives the fine mesh back to float32 precision, and every UV copy of a seam vertex alone gives
    its 3D displacement."""
    rng = np.random.default_rng(6)
    if mesh == "cylinder":
        v, f, uv, uf = cylinder()
    else:
        v, f, uv, uf = tshirt.rest_vertices, tshirt.faces, tshirt.uvs, tshirt.uv_faces
    v = v.astype(np.float64)
    bent = v + 0.05 * np.sin(4 * v[:, [1, 2, 0]]) @ rotation(rng)
    base = np.stack([v, bent @ rotation(rng).T + [0.5, 0.2, -1.0]]).astype(np.float32)
    n = vertex_normals(base, f, device=device)
    wave = 0.004 * np.sin(40 * base[..., 1:2]) * np.cos(30 * base[..., 0:1])
    fine = (base + wave * n + 0.001 * rng.normal(size=base.shape)).astype(np.float32)
    frames = SurfaceFrames(len(v), f, uv, uf, uv_scale(v, f, uv, uf), device=device)
    w = frames.encode(fine, base)
    assert w.shape == (2, len(uv), 3)
    back = frames.decode(w, base)
    np.testing.assert_allclose(back, fine, atol=1e-6)
    m = uv_vertex_map(f, uf, len(uv))
    assert (np.bincount(m, minlength=len(v)) > 1).any()  # the mesh has seam copies
    # every copy alone decodes to the same displacement: frames @ w equal across copies
    fr = frames.frames(base)
    disp = np.einsum("tuij,tuj->tui", fr, w)
    np.testing.assert_allclose(disp, (fine - base)[:, m], atol=1e-6)
    # the pure functions agree with the class
    s = frames.scale
    np.testing.assert_allclose(encode_wrinkles(fine[1], base[1], f, uv, uf, s, device=device), w[1])
    np.testing.assert_allclose(decode_wrinkles(w[1], base[1], f, uv, uf, s, device=device), back[1])


def test_normal_offset_is_the_third_component(device, tshirt):
    """fine = base + h n̂ (unit area-weighted vertex normals): w̃ = (0, 0, h) wherever the vertex
    is not on a seam (a seam copy's normal is its own side's, see sim.geometry.frames)."""
    rng = np.random.default_rng(7)
    x = tshirt.rest_vertices
    frames = SurfaceFrames.from_garment(tshirt, device=device)
    h = rng.uniform(-0.01, 0.01, len(x)).astype(np.float32)
    n = frames.normals(x)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(n, vertex_normals(x, tshirt.faces, device=device))
    w = frames.encode(x + h[:, None] * n, x)
    m = uv_vertex_map(tshirt.faces, tshirt.uv_faces, len(tshirt.uvs))
    single = np.bincount(m, minlength=len(x))[m] == 1
    assert single.mean() > 0.7
    np.testing.assert_allclose(w[single, 2], h[m[single]], atol=1e-6)
    np.testing.assert_allclose(w[single, :2], 0.0, atol=1e-6)
    np.testing.assert_allclose(frames.frames(x)[single, :, 2], n[m[single]], atol=1e-6)


def test_wrinkle_field_is_rotation_invariant(device, tshirt):
    """Rotating and moving base and fine together rotates the frames: w̃ does not change."""
    rng = np.random.default_rng(8)
    x = tshirt.rest_vertices.astype(np.float64)
    fine = x + 0.003 * rng.normal(size=x.shape)
    frames = SurfaceFrames.from_garment(tshirt, device=device)
    w = frames.encode(fine, x)
    R, b = rotation(rng), np.array([0.7, -0.3, 1.2])
    w_moved = frames.encode(fine @ R.T + b, x @ R.T + b)
    np.testing.assert_allclose(w_moved, w, atol=2e-6)
    fr, fr_moved = frames.frames(x), frames.frames(x @ R.T + b)
    np.testing.assert_allclose(fr_moved, np.einsum("ij,ujk->uik", R, fr), atol=F32_POSITION)


def test_degenerate_frames_fall_back_to_orthonormal(device):
    """A base collapsed onto a line (no ∂/∂u1, no normal): every frame is the documented
    orthonormal fallback {Y, −X, Z} and the round trip stays exact."""
    v, f, uv = sheet(7, size=0.5, jitter=0.2)
    base = v * [0.0, 1.0, 0.0]
    rng = np.random.default_rng(9)
    fine = (base + 0.01 * rng.normal(size=v.shape)).astype(np.float32)
    s = uv_scale(v, f, uv, f)
    fr = local_frames(base, f, uv, f, s, device=device)
    assert np.isfinite(fr).all()
    want = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(fr, np.broadcast_to(want, fr.shape), atol=1e-6)
    w = encode_wrinkles(fine, base, f, uv, f, s, device=device)
    np.testing.assert_allclose(decode_wrinkles(w, base, f, uv, f, s, device=device), fine, atol=1e-6)


def test_frames_input_errors():
    v, f, uv = sheet(4)
    with pytest.raises(WrinklesInputError, match="scale"):
        SurfaceFrames(len(v), f, uv, f, 0.0, device="cpu")
    with pytest.raises(WrinklesInputError, match="must match"):
        SurfaceFrames(len(v), f, uv, f[:-1], 1.0, device="cpu")
    frames = SurfaceFrames(len(v), f, uv, f, 1.0, device="cpu")
    with pytest.raises(WrinklesInputError, match="same shape"):
        frames.encode(v[None].repeat(2, 0), v)
    with pytest.raises(WrinklesInputError, match="w must have shape"):
        frames.decode(np.zeros((3, 3)), v)


def test_uv_sphere_is_closed_outward_and_encloses_the_sphere_volume():
    """Every edge is shared by two faces in opposite directions (closed, consistently oriented),
    the signed volume is positive (outward) and, the vertices lying on the sphere, just under
    4/3 pi r^3 (an inscribed polyhedron: 2.1 % under at 16 x 24), and the centre moves every
    vertex by the same offset."""
    v, f = uv_sphere(0.2, center=(0.1, -0.3, 0.5))
    directed = {(int(a), int(b)) for tri in f for a, b in zip(tri, np.roll(tri, -1), strict=True)}
    assert len(directed) == 3 * len(f)
    assert all((b, a) in directed for a, b in directed)
    a, b, c = (v[f[:, k]].astype(np.float64) - (0.1, -0.3, 0.5) for k in range(3))
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    ball = 4.0 / 3.0 * np.pi * 0.2 ** 3
    assert 0.97 * ball < volume < ball
    np.testing.assert_allclose(np.linalg.norm(v - np.float32([0.1, -0.3, 0.5]), axis=1), 0.2, rtol=1e-6)
    v0, f0 = uv_sphere(0.2)
    np.testing.assert_array_equal(f, f0)
    np.testing.assert_allclose(v - v0, np.broadcast_to(np.float32([0.1, -0.3, 0.5]), v.shape), atol=1e-6)

