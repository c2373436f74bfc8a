"""Importing user garments: OBJ, PLY, GLB and USD with UV seams; repairs; refusals.

The files are read as the commands read them (``pipelines.garment_files.load_garment_file``:
USD through ``usd_io``, the rest through ``sim.garments.load_garment``).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from pipelines.garment_files import load_garment_file
from sim.errors import WrinklesInputError
from sim.garments import load_garment


def _seamed_grid(n: int = 6):
    """A curved n x n grid (a quarter cylinder, 0.4 m) with a UV seam down the middle column.

    Returns:
        (points (V, 3), faces (F, 3), uvs (U, 2), uv_faces (F, 3)); U = V + n (the seam
        column's vertices have two UVs: the right half is shifted by 0.1 in u).
    """
    s, t = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    ang = s.ravel() * np.pi / 2
    points = np.stack([0.25 * np.cos(ang), 0.4 * t.ravel(), 0.25 * np.sin(ang)], 1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            faces += [(a, a + n + 1, a + 1), (a, a + n, a + n + 1)]
    faces = np.array(faces)
    mid = n // 2
    uvs = np.stack([s.ravel() * 0.4, t.ravel() * 0.8 + 0.1], 1)
    col = np.arange(len(points)) % n
    seam = np.flatnonzero(col == mid)
    uvs[col > mid, 0] += 0.1
    uvs = np.concatenate([uvs, uvs[seam] + [0.1, 0.0]])
    right = (col[faces] > mid).any(axis=1)  # faces right of the seam use the shifted copies
    uv_faces = faces.copy()
    remap = {int(v): len(points) + k for k, v in enumerate(seam)}
    for f in np.flatnonzero(right):
        uv_faces[f] = [remap.get(int(v), int(v)) for v in faces[f]]
    return points, faces, uvs, uv_faces


def _write_obj(path, points, faces, uvs=None, uv_faces=None):
    """An OBJ as DCC tools write it: welded positions, separate ``vt`` indices."""
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in points]
    if uvs is not None:
        lines += [f"vt {u:.9g} {v:.9g}" for u, v in uvs]
        lines += ["f " + " ".join(f"{a + 1}/{b + 1}" for a, b in zip(f, uf, strict=True))
                  for f, uf in zip(faces, uv_faces, strict=True)]
    else:
        lines += ["f " + " ".join(str(a + 1) for a in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def _split(points, faces, uvs, uv_faces):
    """Per-vertex UV layout (vertices split along seams), as PLY/GLB/trimesh carry UVs."""
    pairs, inv = np.unique(np.stack([faces.ravel(), uv_faces.ravel()], 1), axis=0, return_inverse=True)
    return points[pairs[:, 0]], inv.reshape(-1, 3), uvs[pairs[:, 1]]


def _export(path, points, faces, uvs, uv_faces):
    v, f, uv = _split(points, faces, uvs, uv_faces)
    trimesh.Trimesh(v, f, visual=trimesh.visual.TextureVisuals(uv=uv), process=False).export(path)
    return path


def _write_usd(path, points, faces, uvs, uv_faces, *, prim="/Shirt", up="Y", meters_per_unit=1.0):
    """A user's stage written with pxr directly: one mesh, indexed face-varying ``st``."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up == "Z" else UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    mesh = UsdGeom.Mesh.Define(stage, prim)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(points, np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(np.asarray(faces, np.int32).ravel().tolist()))
    if uvs is not None:
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(np.asarray(uvs, np.float32)))
        st.SetIndices(Vt.IntArray(np.asarray(uv_faces, np.int32).ravel().tolist()))
    stage.GetRootLayer().Save()
    del stage
    return path


def _check_same(g, points, faces, uvs, uv_faces):
    """Same surface, same per-corner UVs, welded (V vertices), seams kept (U UVs)."""
    assert g.num_vertices == len(points) and g.num_faces == len(faces)
    assert len(g.uvs) == len(uvs)
    # face order is kept; corners may rotate inside a face
    got = np.concatenate([g.rest_vertices[g.faces], g.uvs[g.uv_faces]], axis=2)
    want = np.concatenate([points[faces], uvs[uv_faces]], axis=2)
    for f in range(len(faces)):
        k = int(np.argmin(np.linalg.norm(got[f, :, :3] - want[f, 0, :3], axis=1)))
        np.testing.assert_allclose(np.roll(got[f], -k, axis=0), want[f], atol=1e-5)


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".glb"])
def test_trimesh_formats_keep_uv_seams(tmp_path, suffix):
    points, faces, uvs, uv_faces = _seamed_grid()
    path = tmp_path / f"grid{suffix}"
    if suffix == ".obj":
        _write_obj(path, points, faces, uvs, uv_faces)
    else:
        _export(path, points, faces, uvs, uv_faces)
    g = load_garment_file(path, material="denim")
    _check_same(g, points, faces, uvs, uv_faces)
    assert g.name == "grid" and g.category == "imported" and g.material.name == "denim"


def test_ply_with_per_corner_texcoords(tmp_path):
    """MeshLab-style PLY: welded vertices, a ``texcoord`` list per face (the seam)."""
    points, faces, uvs, uv_faces = _seamed_grid()
    head = ["ply", "format ascii 1.0", f"element vertex {len(points)}", "property float x",
            "property float y", "property float z", f"element face {len(faces)}",
            "property list uchar int vertex_indices", "property list uchar float texcoord", "end_header"]
    body = [" ".join(f"{c:.9g}" for c in p) for p in points]
    body += [f"3 {f[0]} {f[1]} {f[2]} 6 " + " ".join(f"{c:.9g}" for c in uvs[uf].ravel())
             for f, uf in zip(faces, uv_faces, strict=True)]
    path = tmp_path / "wedge.ply"
    path.write_text("\n".join(head + body) + "\n")
    g = load_garment_file(path)
    assert g.num_vertices == len(points) and g.num_faces == len(faces)
    np.testing.assert_allclose(np.sort(g.uvs[g.uv_faces].reshape(-1, 2), axis=0),
                               np.sort(uvs[uv_faces].reshape(-1, 2), axis=0), atol=1e-6)


def test_usd_written_by_write_stage(tmp_path):
    from usd_io import write_stage
    from usd_io.write import GarmentTrack

    points, faces, uvs, uv_faces = _seamed_grid()
    path = tmp_path / "skirt.usda"
    write_stage(path, body=None, fps=30.0, garments=[GarmentTrack(
        "skirt", points[None].astype(np.float32), faces.astype(np.int32), uvs, uv_faces)])
    g = load_garment_file(path)
    _check_same(g, points, faces, uvs, uv_faces)


def test_usd_from_another_tool_in_centimetres_z_up(tmp_path):
    points, faces, uvs, uv_faces = _seamed_grid()
    zup_cm = np.stack([points[:, 0], -points[:, 2], points[:, 1]], 1) * 100.0
    path = _write_usd(tmp_path / "shirt.usda", zup_cm, faces, uvs, uv_faces, up="Z", meters_per_unit=0.01)
    g = load_garment_file(path)
    _check_same(g, points, faces, uvs, uv_faces)  # back in metres, Y up


def test_repairs_duplicates_collapsed_faces_and_specks(tmp_path):
    points, faces, uvs, uv_faces = _seamed_grid()
    # triangle soup (every face has its own three vertices, as STL-like exporters write)
    soup_v = points[faces].reshape(-1, 3)
    soup_f = np.arange(len(soup_v)).reshape(-1, 3)
    soup_uv = uvs[uv_faces].reshape(-1, 2)
    # + a face collapsed onto an edge once duplicates merge, + a 1 mm speck far away
    k = len(soup_v)
    speck = np.array([[2, 2, 2], [2.001, 2, 2], [2, 2.001, 2]])
    soup_v = np.concatenate([soup_v, soup_v[[0, 1]], speck])
    soup_uv = np.concatenate([soup_uv, soup_uv[[0, 1]], np.full((3, 2), 0.99)])
    soup_f = np.concatenate([soup_f, [[k, k + 1, 0]], [[k + 2, k + 3, k + 4]]])
    path = tmp_path / "soup.obj"
    _write_obj(path, soup_v, soup_f, soup_uv, soup_f)
    g = load_garment_file(path)
    assert g.num_vertices == len(points) and g.num_faces == len(faces)
    np.testing.assert_allclose(np.sort(g.rest_vertices, axis=0), np.sort(points, axis=0), atol=1e-6)
    edges = np.sort(g.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    assert np.unique(edges, axis=0, return_counts=True)[1].max() == 2  # welded: interior edges shared
    # and it says what it did (the simulate command tells the drops and stores them all)
    from sim.garments.io import describe_drops

    assert g.repairs == {"merged_vertices": len(soup_v) - len(points) - 3, "collapsed_faces_dropped": 1,
                         "tiny_piece_faces_dropped": 1, "tiny_pieces_dropped": 1}
    assert describe_drops(g.repairs) == ("dropped 1 collapsed (zero-area) faces; dropped 1 stray piece(s) of "
                                         "1 faces (each under 5 % of the mesh)")
    assert load_garment_file(tmp_path / "soup.obj").repairs == g.repairs


def test_a_face_given_twice_is_dropped_not_called_non_manifold(tmp_path):
    """An exporter's doubled face (the same three vertices, either winding) makes its edges
    appear in three or four faces; it is a repair (dropped, counted), not a non-manifold refusal.
    A real fin (a third face on an edge) is still refused."""
    points, faces, uvs, uv_faces = _seamed_grid()
    doubled = np.concatenate([faces, faces[[3]], faces[[7]][:, ::-1]])
    doubled_uv = np.concatenate([uv_faces, uv_faces[[3]], uv_faces[[7]][:, ::-1]])
    path = tmp_path / "doubled.obj"
    _write_obj(path, points, doubled, uvs, doubled_uv)
    g = load_garment_file(path)
    assert g.num_faces == len(faces) and g.repairs.get("duplicate_faces_dropped") == 2
    from sim.garments.io import describe_drops

    assert describe_drops(g.repairs) == "dropped 2 faces given twice"
    def triangles(f):
        return np.sort(np.sort(f, axis=1), axis=0)

    np.testing.assert_array_equal(triangles(g.faces), triangles(faces))


def _refused(path, pattern, **kwargs):
    with pytest.raises(WrinklesInputError, match=pattern) as e:
        load_garment_file(path, **kwargs)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(path)), msg  # one line, naming the file
    return msg


def test_refuses_non_manifold_edge(tmp_path):
    points, faces, uvs, uv_faces = _seamed_grid()
    a, b = faces[0, 0], faces[0, 1]  # a third face on the edge a-b (a fin)
    points = np.concatenate([points, [[0.0, 0.2, -0.1]]])
    uvs = np.concatenate([uvs, [[0.5, 0.5]]])
    faces = np.concatenate([faces, [[a, b, len(points) - 1]]])
    uv_faces = np.concatenate([uv_faces, [[a, b, len(uvs) - 1]]])
    for path in (_write_obj(tmp_path / "fin.obj", points, faces, uvs, uv_faces),
                 _write_usd(tmp_path / "fin.usda", points, faces, uvs, uv_faces)):
        _refused(path, "1 non-manifold edges")


def test_refuses_missing_uvs(tmp_path):
    points, faces, uvs, uv_faces = _seamed_grid()
    for path in (_write_obj(tmp_path / "nouv.obj", points, faces),
                 _write_usd(tmp_path / "nouv.usda", points, faces, None, None),
                 trimesh.Trimesh(points, faces).export(tmp_path / "nouv.ply") and tmp_path / "nouv.ply"):
        _refused(path, "no UVs")
        g = load_garment_file(path, require_uvs=False)  # a simulation-only garment may skip them
        assert g.num_faces == len(faces)
    _refused(_write_obj(tmp_path / "flatuv.obj", points, faces, np.zeros_like(uvs), uv_faces), "collapsed")


def test_refuses_degenerate_triangle(tmp_path):
    points, faces, uvs, uv_faces = _seamed_grid()
    # a needle: the midpoint of an edge joined to both ends of that edge (a T-junction)
    a, b = faces[0, 0], faces[0, 1]
    points = np.concatenate([points, [0.5 * (points[a] + points[b])]])
    uvs = np.concatenate([uvs, [0.5 * (uvs[a] + uvs[b])]])
    faces = np.concatenate([faces, [[a, len(points) - 1, b]]])
    uv_faces = np.concatenate([uv_faces, [[a, len(uvs) - 1, b]]])
    msg = _refused(_write_obj(tmp_path / "needle.obj", points, faces, uvs, uv_faces), "degenerate triangle")
    assert f"face {len(faces) - 1}" in msg


def test_refuses_unreadable_missing_and_unknown(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n")
    _refused(bad, "bad.ply")
    _refused(tmp_path / "missing.obj", "no such file")
    (tmp_path / "x.fbx").write_text("")
    _refused(tmp_path / "x.fbx", "unsupported garment format")
    body_only = tmp_path / "empty.usda"
    from pxr import Usd

    stage = Usd.Stage.CreateNew(str(body_only))
    stage.GetRootLayer().Save()
    _refused(body_only, "no garment mesh")


def test_the_simulator_core_leaves_usd_to_the_pipelines(tmp_path):
    """``sim.garments.load_garment`` reads the trimesh formats only: a USD file is refused in one
    line that names the file and the function that reads it, and ``sim.garments`` does not load
    ``usd_io``."""
    import subprocess
    import sys
    from pathlib import Path

    points, faces, uvs, uv_faces = _seamed_grid()
    path = _write_usd(tmp_path / "shirt.usda", points, faces, uvs, uv_faces)
    with pytest.raises(WrinklesInputError, match=r"shirt.usda: .*pipelines.garment_files.load_garment_file"):
        load_garment(path)
    assert load_garment_file(path).num_faces == len(faces)
    code = "import sys, sim.garments; print('usd_io' in sys.modules, 'pxr' in sys.modules)"
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=root).stdout
    assert out.split() == ["False", "False"]


def test_imported_garment_has_no_hems_unless_asked(tmp_path):
    """A file does not say how its openings are sewn: no hems by default; ``hem_width`` lines
    every boundary loop (the grid's border) as a template's openings are, and a width outside
    its range is refused naming the file."""
    points, faces, uvs, uv_faces = _seamed_grid(11)
    path = tmp_path / "grid.obj"
    _write_obj(path, points, faces, uvs, uv_faces)
    plain = load_garment_file(path)
    assert (plain.face_layers == 1.0).all()
    hemmed = load_garment_file(path, hem_width=0.05, hem_layers=2.0)
    assert hemmed.face_layers.min() == 1.0 and hemmed.face_layers.max() == 2.0
    # the border faces are hem, the middle is not (the grid is 0.4 m tall, edges 4 cm)
    c = hemmed.rest_vertices[hemmed.faces].mean(axis=1)
    assert (hemmed.face_layers[(c[:, 1] < 0.02) | (c[:, 1] > 0.38)] > 1.5).all()
    from sim.garments.hems import distance_to_boundary

    d = distance_to_boundary(hemmed.rest_vertices, hemmed.faces)[hemmed.faces]
    middle = d.min(axis=1) >= 0.05  # every corner at least the width from the border
    assert middle.sum() > 10 and (hemmed.face_layers[middle] == 1.0).all()
    np.testing.assert_array_equal(hemmed.faces, plain.faces)
    with pytest.raises(WrinklesInputError, match="grid.obj.*hem_width"):
        load_garment_file(path, hem_width=0.5)


def test_simulate_cli_passes_hem_parameters_to_a_garment_file(tmp_path):
    import argparse

    from pipelines.simulate_cmd import load_garment_arg

    points, faces, uvs, uv_faces = _seamed_grid(11)
    path = tmp_path / "grid.obj"
    _write_obj(path, points, faces, uvs, uv_faces)

    def args(*params):
        return argparse.Namespace(garment=str(path), material="cotton", material_param=[],
                                  garment_param=list(params), resolution=None, quiet=True)

    from sim.bodies import load_body

    body = load_body()  # the 20 cm sheet lies in the rest body's box, as a garment file must
    assert (load_garment_arg(args(), body, None).face_layers == 1.0).all()
    g = load_garment_arg(args("hem_width=0.05", "hem_layers=2"), body, None)
    assert g.face_layers.min() == 1.0 and g.face_layers.max() == 2.0
    with pytest.raises(WrinklesInputError, match="--garment-param length.*hem_width and hem_layers only"):
        load_garment_arg(args("length=0.5"), body, None)
