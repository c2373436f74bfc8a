"""Importing user garments: OBJ, PLY, GLB and USD with UV seams; repairs; refusals.

The files are read as the commands read them (``pipelines.garment_files.load_garment_file``:
USD through ``usd_io``, the rest through ``sim.garments.load_garment``).
"""

from __future__ import annotations

import json

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
                         "tiny_piece_faces_dropped": 1, "tiny_pieces_dropped": 1,
                         "unused_vertices_removed": 3}
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


def _grid_vertex(i: int, j: int, n: int = 6) -> int:
    """The index of the ``_seamed_grid`` vertex in row i, column j (column 3 is the UV seam)."""
    return i * n + j


def _moved(points, vertex, a, b, t=0.5):
    """``points`` with ``vertex`` moved onto the segment a-b, at ``t`` from a."""
    out = points.copy()
    out[vertex] = (1.0 - t) * points[a] + t * points[b]
    return out


def _heights(g):
    from sim.garments.repair import height_ratios

    return height_ratios(g.rest_vertices.astype(np.float64), g.faces)


def _repairs(g) -> dict:
    """What reading ``g`` repaired, less the UV seams' split vertices merged back (every OBJ)."""
    return {k: v for k, v in g.repairs.items() if k != "merged_vertices"}


def _check_cloth(g, faces_expected):
    """A usable cloth mesh: the face count, no sliver, every edge in one or two faces, and every
    face of the UV layout with area."""
    from sim.garments.repair import MIN_HEIGHT_RATIO

    assert g.num_faces == faces_expected
    assert _heights(g).min() > MIN_HEIGHT_RATIO
    edges = np.sort(g.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    assert np.unique(edges, axis=0, return_counts=True)[1].max() == 2
    uv = g.uvs[g.uv_faces]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    assert np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).min() > 0


def test_an_extra_flat_face_on_an_edge_is_dropped(tmp_path):
    """A needle over an edge (the edge's midpoint joined to both ends, a face of no area on an
    edge that two faces hold) covers nothing: it is dropped with its vertex, and the mesh is the
    one without it."""
    points, faces, uvs, uv_faces = _seamed_grid()
    a, b = faces[0, 0], faces[0, 1]
    more = np.concatenate([points, [0.5 * (points[a] + points[b])]])
    more_uvs = np.concatenate([uvs, [0.5 * (uvs[a] + uvs[b])]])
    more_faces = np.concatenate([faces, [[a, len(points), b]]])
    more_uv_faces = np.concatenate([uv_faces, [[a, len(uvs), b]]])
    g = load_garment_file(_write_obj(tmp_path / "needle.obj", more, more_faces, more_uvs, more_uv_faces))
    assert _repairs(g) == {"slivers_dropped": 1, "unused_vertices_removed": 1}
    _check_same(g, points, faces, uvs, uv_faces)


@pytest.mark.parametrize("column", [1, 2])
def test_a_flat_triangle_inside_the_mesh_is_flipped_away(tmp_path, column):
    """A vertex moved onto the opposite edge of one of its faces (a T-junction) leaves that face
    flat: the edge is flipped, the two faces across it become two with area, and the surface
    is kept. Beside the UV seam (column 2: the flat face's long edge is the seam) the moved
    vertex gets a UV in the other side's chart, on the seam edge where it lies in 3D."""
    from sim.garments.io import describe_drops

    points, faces, uvs, uv_faces = _seamed_grid()
    v, a, b = ((_grid_vertex(2, 2), _grid_vertex(2, 1), _grid_vertex(3, 2)) if column == 1
               else (_grid_vertex(2, 2), _grid_vertex(2, 3), _grid_vertex(3, 3)))
    flat = _moved(points, v, a, b)
    g = load_garment_file(_write_obj(tmp_path / "flat.obj", flat, faces, uvs, uv_faces))
    assert _repairs(g) == {"sliver_edges_flipped": 1}
    assert describe_drops(g.repairs) == "flipped the long edge of 1 sliver triangles"
    _check_cloth(g, len(faces))
    assert len(g.uvs) == len(uvs) + (column == 2)
    if column == 2:  # the new UV: the midpoint of the seam edge in the right-hand chart
        right = [k for k, f in enumerate(faces) if {a, b} <= set(f.tolist()) and v not in f][0]
        ua, ub = (uvs[uv_faces[right][list(faces[right]).index(x)]] for x in (a, b))
        np.testing.assert_allclose(g.uvs[-1], 0.5 * (ua + ub), atol=1e-6)
    tri = g.rest_vertices[g.faces].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    given = flat[faces]
    want = 0.5 * np.linalg.norm(np.cross(given[:, 1] - given[:, 0], given[:, 2] - given[:, 0]), axis=1).sum()
    np.testing.assert_allclose(area, want, rtol=1e-3)  # the same surface (the quad is near planar)


def test_vertices_a_hair_apart_are_merged(tmp_path):
    """Three vertices 3 µm from a neighbour (over the 1 µm of exporters' duplicates, under 1 % of
    the 8 cm edges) make needles: their edges are collapsed and the faces on them dropped."""
    from sim.garments.io import describe_drops

    points, faces, uvs, uv_faces = _seamed_grid()
    moved = points.copy()
    for i, j in ((1, 1), (2, 4), (4, 2)):
        moved[_grid_vertex(i, j)] = points[_grid_vertex(i, j + 1)] + 3e-6
    g = load_garment_file(_write_obj(tmp_path / "hair.obj", moved, faces, uvs, uv_faces))
    assert _repairs(g) == {"short_edges_collapsed": 3, "collapsed_faces_dropped": 6,
                           "unused_vertices_removed": 3}
    assert describe_drops(g.repairs).startswith("collapsed 3 needle edges")
    _check_cloth(g, len(faces) - 6)


def test_refuses_flat_triangles_that_only_the_modelling_tool_can_fix(tmp_path):
    """Two flat faces back to back (both far corners of a quad moved onto its diagonal): no flip
    gives them area and dropping them would open a crack, so the file is refused in one line,
    naming the file, the count and where."""
    points, faces, uvs, uv_faces = _seamed_grid()
    a, b = _grid_vertex(2, 1), _grid_vertex(3, 2)
    squashed = _moved(_moved(points, _grid_vertex(2, 2), a, b, 1 / 3), _grid_vertex(3, 1), a, b, 2 / 3)
    msg = _refused(_write_obj(tmp_path / "squashed.obj", squashed, faces, uvs, uv_faces),
                   "2 degenerate triangle")
    assert "no repair fixes" in msg and "fix the mesh" in msg


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


# ------------------------------------------------------------------ through `wrinkles simulate`

SIM_FAST = ["--motion", "walk", "--duration", "0.2", "--settle", "0.4", "--blend", "0.1", "--substeps", "4",
            "--iterations", "4", "--device", "cpu"]


def _skirt_file_parts():
    """A 5 cm skirt fitted to the default body: (points, faces, uvs, uv_faces, boundary mask)."""
    from sim.bodies import load_body
    from sim.garments import make_garment

    g = make_garment("straight_skirt", load_body(), np.zeros(10), resolution=0.05)
    points = g.rest_vertices.astype(np.float64)
    edges = np.sort(g.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    border = np.zeros(len(points), bool)
    border[uniq[counts == 1].ravel()] = True
    return points, g.faces.astype(np.int64), g.uvs.astype(np.float64), g.uv_faces.astype(np.int64), border


def _normals(points, faces):
    tri = points[faces]
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def _flat_caps(points, faces, border, count):
    """``points`` with ``count`` interior vertices moved onto the opposite edge of one of their
    faces (T-junctions: that face flat, every other face turned by less than 90°), away from
    each other."""
    out, used, moved_count = points.copy(), set(), 0
    for f, (v, a, b) in enumerate(faces.tolist()):
        around = np.flatnonzero((faces == v).any(axis=1))
        if border[[v, a, b]].any() or used & {v, a, b}:
            continue
        moved = _moved(out, v, a, b)
        others = around[around != f]
        if (np.sum(_normals(moved, faces[others]) * _normals(out, faces[others]), axis=1) > 0).all():
            out = moved
            used |= set(faces[np.isin(faces, faces[around]).any(axis=1)].ravel().tolist())
            moved_count += 1
            if moved_count == count:
                return out
    raise AssertionError("no room for the flat faces")


@pytest.mark.slow
def test_simulate_repairs_degenerate_triangles_and_runs(tmp_path, capsys):
    """A garment file with two flat triangles (T-junctions) and a vertex 3 µm from its
    neighbour, which unrepaired turn the simulation NaN at every substep count, is repaired (the
    repair told on stderr, recorded in the quality report) and simulated."""
    from pipelines.cli import main

    points, faces, uvs, uv_faces, border = _skirt_file_parts()
    broken = _flat_caps(points, faces, border, 2)
    v = int(np.flatnonzero(~border)[-1])
    w = int(next(x for x in faces[(faces == v).any(axis=1)].ravel() if x != v))
    broken[v] = broken[w] + 3e-6
    path = _write_obj(tmp_path / "skirt.obj", broken, faces, uvs, uv_faces)
    out = tmp_path / "s.usdc"
    assert main(["simulate", "--garment", str(path), "--out", str(out), *SIM_FAST]) == 0
    err = capsys.readouterr().err
    assert "repaired: collapsed 1 needle edges" in err, err
    assert "flipped the long edge of 2 sliver triangles" in err, err
    report = json.loads((tmp_path / "s.quality.json").read_text())
    assert report["passed"] and report["garment_repairs"]["sliver_edges_flipped"] == 2


def test_simulate_refuses_unrepairable_triangles_before_simulating(tmp_path, capsys, monkeypatch):
    """Flat triangles that no repair fixes are refused when the file is read: one line naming
    the file, exit 2, no simulation started and nothing written."""
    import sim.simulate
    from pipelines.cli import main

    def no_simulation(*args, **kwargs):
        raise AssertionError("simulated a garment that should have been refused")

    monkeypatch.setattr(sim.simulate, "simulate", no_simulation)
    points, faces, uvs, uv_faces, border = _skirt_file_parts()
    # a quad squashed onto its diagonal: both far corners on the shared edge
    f = next(k for k, tri in enumerate(faces) if not border[tri].any())
    a, b, m = faces[f]
    g = next(k for k, tri in enumerate(faces) if k != f and {a, b} <= set(tri.tolist()))
    c = int(next(x for x in faces[g] if x not in (a, b)))
    squashed = _moved(_moved(points, m, a, b, 1 / 3), c, a, b, 2 / 3)
    path = _write_obj(tmp_path / "squashed.obj", squashed, faces, uvs, uv_faces)
    assert main(["simulate", "--garment", str(path), "--out", str(tmp_path / "s.usdc"), *SIM_FAST]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"wrinkles simulate: error: {path}:"), err
    assert "degenerate triangle" in err and "no repair fixes" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["squashed.obj"]
