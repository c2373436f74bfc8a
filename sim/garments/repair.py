"""Repairs of a garment file's triangle mesh, and the checks that refuse what no repair fixes.

A cloth solver needs triangles with area: a sliver (a vertex on, or within a hair of, the
opposite edge) or a needle (two vertices a hair apart) has a rest shape whose inverse is huge,
so its forces blow the simulation up, whatever the substeps. ``repair_mesh`` turns such faces
into good ones where that keeps the surface, in this order:

1. positions within ``MERGE_TOL`` merged (exporters split vertices along UV seams);
2. edges shorter than ``SHORT_EDGE`` of the median edge collapsed (their ends merged);
3. faces that collapsed to an edge or a point, and faces given twice, dropped;
4. slivers (height under ``MIN_HEIGHT_RATIO`` of the longest edge) whose longest edge is
   shared with one other face: that edge flipped (the two faces become two with area; across
   a UV seam the sliver's vertex gets a UV in the other face's chart);
5. slivers whose removal opens no hole (an extra face on a non-manifold edge, a flat face
   along the border) dropped;

and ``check_face_heights`` refuses, in one line naming the file, the slivers left (e.g. two
flat faces back to back, a quad squashed onto its diagonal): removing them would open a crack,
so the mesh needs fixing in the modelling tool. Arrays are points (V, 3) [m], faces (F, 3) and
uv_faces (F, 3) int64.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError

MERGE_TOL = 1e-6
"""Vertices closer than 1 µm are one vertex (exporters split them along UV seams) [m]."""
SHORT_EDGE = 0.01
"""An edge shorter than 1 % of the mesh's median edge is collapsed: a needle that thin holds no
cloth detail and its stiffness has no usable scale [-]."""
MIN_HEIGHT_RATIO = 0.005
"""A face whose height is under 0.5 % of its longest edge (2 area / longest², 0.87 for an
equilateral triangle, 0.26 for the worst face of any template) is a sliver: repaired or
refused. On a 3 cm skirt walking, one face at 0.0009 fails the gates at 4, 7 and 8 substeps
(edge strain 1.2, self-intersections), one at 0.000003 explodes; at 0.0026 it passes [-]."""
TINY_COMPONENT = 0.05
"""Components with fewer than 5 % of the faces are stray pieces and are dropped."""


@dataclass
class RepairedMesh:
    """A mesh after ``repair_mesh``: the arrays and what was done, as counts."""

    points: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    uv_faces: np.ndarray
    repairs: dict[str, int] = field(default_factory=dict)


def height_ratios(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Each face's height over its longest edge, 2 area / longest² (0 for a flat face), (F,)."""
    tri = points[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    longest = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2).max(axis=1)
    return np.divide(area2, longest ** 2, out=np.zeros_like(area2), where=longest > 0)


def _face_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = points[faces]
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def edge_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unique undirected edges (E, 2) and how many faces hold each (E,)."""
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0, return_counts=True)


def merge_duplicates(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions within ``MERGE_TOL`` merged into their first occurrence, in reading order (UV
    seams stay: uv_faces keep their own indices)."""
    key = np.round(points / MERGE_TOL).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return points[first[order]], rank[inv.reshape(-1)][faces]


def collapse_short_edges(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """Faces with the ends of every edge shorter than ``SHORT_EDGE`` of the median edge merged
    into the lowest-numbered vertex of each group (positions are kept: the unused ones go when
    the mesh is compacted).

    Returns:
        (faces, number of edges collapsed).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges, _ = edge_counts(faces)
    edges = edges[edges[:, 0] != edges[:, 1]]  # a face's repeated vertex is no edge
    length = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)
    short = edges[length < SHORT_EDGE * np.median(length)]
    if len(short) == 0:
        return faces, 0
    n = len(points)
    graph = coo_matrix((np.ones(len(short)), (short[:, 0], short[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    lowest = np.full(label.max() + 1, n, np.int64)
    np.minimum.at(lowest, label, np.arange(n))
    return lowest[label][faces], len(short)


def drop_collapsed_and_twice(faces: np.ndarray,
                             uv_faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Faces with a repeated vertex (collapsed to an edge or a point) and faces given twice (the
    same three vertices, either winding: an exporter's double, which would read as non-manifold
    edges) dropped.

    Returns:
        (faces, uv_faces, collapsed dropped, doubles dropped).
    """
    same = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    faces, uv_faces = faces[~same], uv_faces[~same]
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    keep = np.zeros(len(faces), bool)
    keep[first] = True
    return faces[keep], uv_faces[keep], int(same.sum()), int((~keep).sum())


def _edge_faces(faces: np.ndarray) -> dict[tuple[int, int], list[int]]:
    out: dict[tuple[int, int], list[int]] = {}
    for f, tri in enumerate(faces.tolist()):
        for k in range(3):
            a, b = tri[k], tri[(k + 1) % 3]
            out.setdefault((min(a, b), max(a, b)), []).append(f)
    return out


def _corner(face: np.ndarray, vertex: int) -> int:
    return int(np.flatnonzero(face == vertex)[0])


def _flip(points: np.ndarray, faces: np.ndarray, uv_faces: np.ndarray, uvs: list, f: int, g: int,
          m: int, c: int) -> bool:
    """Flip the edge shared by sliver ``f`` (its other vertex ``m``) and face ``g`` (its other
    vertex ``c``) in place when the two new faces are no slivers and face the same way as ``g``;
    whether it was flipped."""
    fa, ga = faces[f], faces[g]
    # g's winding gives the new faces': g = (p, q, c), the quad p -> m -> q -> c
    k = _corner(ga, c)
    p, q = int(ga[(k + 1) % 3]), int(ga[(k + 2) % 3])
    new = np.array([[p, m, c], [m, q, c]], np.int64)
    if min(height_ratios(points, new)) < MIN_HEIGHT_RATIO:
        return False
    n_g = _face_normals(points, faces[[g]])[0]
    if np.any(_face_normals(points, new) @ n_g <= 0.0):
        return False
    # the new faces live in g's UV chart; m's UV there is where m projects onto p-q
    ug = uv_faces[g]
    up, uq, uc = int(ug[(k + 1) % 3]), int(ug[(k + 2) % 3]), int(ug[k])
    uf = uv_faces[f]
    if int(uf[_corner(fa, p)]) == up and int(uf[_corner(fa, q)]) == uq:
        um = int(uf[_corner(fa, m)])  # one chart on both sides: m keeps its UV
    else:
        d = points[q] - points[p]
        t = float(np.clip(np.dot(points[m] - points[p], d) / max(np.dot(d, d), 1e-30), 0.0, 1.0))
        uvs.append((1.0 - t) * np.asarray(uvs[up]) + t * np.asarray(uvs[uq]))
        um = len(uvs) - 1
    faces[f], faces[g] = new
    uv_faces[f], uv_faces[g] = [up, um, uc], [um, uq, uc]
    return True


def flip_slivers(points: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
                 uv_faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Slivers (``MIN_HEIGHT_RATIO``) whose longest edge is shared with exactly one other face:
    that edge flipped where the two new faces are no slivers (``_flip``) and their new edge
    joins two vertices not joined yet.

    Returns:
        (faces, uvs, uv_faces, edges flipped).
    """
    faces, uv_faces = faces.copy(), uv_faces.copy()
    uv_list = list(uvs)
    flipped = 0
    for _ in range(4):  # a sliver beside a flipped pair is tried again with its new neighbour
        bad = np.flatnonzero(height_ratios(points, faces) < MIN_HEIGHT_RATIO)
        if len(bad) == 0:
            break
        edge_faces = _edge_faces(faces)
        touched: set[int] = set()
        done = 0
        for f in bad.tolist():
            tri = points[faces[f]]
            k = int(np.argmax(np.linalg.norm(tri - np.roll(tri, -1, axis=0), axis=1)))
            a, b = int(faces[f, k]), int(faces[f, (k + 1) % 3])
            owners = edge_faces[(min(a, b), max(a, b))]
            if len(owners) != 2 or touched & set(owners):
                continue
            g = owners[0] if owners[1] == f else owners[1]
            m = int(next(v for v in faces[f].tolist() if v not in (a, b)))
            c = int(next(v for v in faces[g].tolist() if v not in (a, b)))
            if (min(m, c), max(m, c)) in edge_faces:
                continue  # m and c already joined: the flip would make that edge non-manifold
            if not _flip(points, faces, uv_faces, uv_list, f, g, m, c):
                continue
            touched.update(owners)
            edge_faces[(min(m, c), max(m, c))] = owners
            del edge_faces[(min(a, b), max(a, b))]
            done += 1
        flipped += done
        if done == 0:
            break
    return faces, np.asarray(uv_list, np.float64).reshape(-1, 2), uv_faces, flipped


def drop_loose_slivers(points: np.ndarray, faces: np.ndarray,
                       uv_faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Slivers whose removal opens no hole dropped: those whose edges that would become border
    are no longer than the border edges they take away (an extra face over a non-manifold
    edge, a flat face along the border).

    Returns:
        (faces, uv_faces, number dropped).
    """
    bad = np.flatnonzero(height_ratios(points, faces) < MIN_HEIGHT_RATIO)
    if len(bad) == 0:
        return faces, uv_faces, 0
    edge_faces = _edge_faces(faces)
    drop = []
    for f in bad.tolist():
        tri = faces[f].tolist()
        change = 0.0
        longest = 0.0
        for k in range(3):
            a, b = tri[k], tri[(k + 1) % 3]
            length = float(np.linalg.norm(points[a] - points[b]))
            longest = max(longest, length)
            count = len(edge_faces[(min(a, b), max(a, b))])
            change += length if count == 2 else -length if count == 1 else 0.0
        if change <= 1e-3 * longest:
            drop.append(f)
    keep = np.ones(len(faces), bool)
    keep[drop] = False
    return faces[keep], uv_faces[keep], len(drop)


def check_face_heights(points: np.ndarray, faces: np.ndarray, path: Path) -> None:
    """Refuse a mesh that still has slivers (``MIN_HEIGHT_RATIO``), naming the worst."""
    ratio = height_ratios(points, faces)
    bad = ratio < MIN_HEIGHT_RATIO
    if not bad.any():
        return
    k = int(np.argmin(ratio))
    x, y, z = points[faces[k]].mean(axis=0)
    raise WrinklesInputError(
        f"{int(bad.sum())} degenerate triangle(s) (height under {100 * MIN_HEIGHT_RATIO:g} % of the "
        f"longest edge) that no repair fixes without opening a crack, e.g. face {k} at ({x:.4g}, "
        f"{y:.4g}, {z:.4g}); the simulation would blow up there: fix the mesh in the modelling tool "
        "(merge the vertex that lies on the opposite edge, or remesh)", path=path)


def check_manifold(points: np.ndarray, faces: np.ndarray, path: Path) -> np.ndarray:
    """The mesh's unique edges (E, 2); refused when one is in more than two faces."""
    edges, counts = edge_counts(faces)
    bad = counts > 2
    if bad.any():
        a, b = edges[bad][0]
        x, y, z = 0.5 * (points[a] + points[b])
        raise WrinklesInputError(f"{int(bad.sum())} non-manifold edges (in more than 2 faces), "
                                 f"e.g. the edge at ({x:.4g}, {y:.4g}, {z:.4g})", path=path)
    return edges


def drop_tiny_pieces(n: int, faces: np.ndarray, uv_faces: np.ndarray, edges: np.ndarray):
    """Connected pieces with fewer than ``TINY_COMPONENT`` of the faces dropped.

    Returns:
        (faces, uv_faces, repair counts ``tiny_piece_faces_dropped``, ``tiny_pieces_dropped``).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    adj = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    face_label = label[faces[:, 0]]
    sizes = np.bincount(face_label)
    keep = sizes[face_label] >= TINY_COMPONENT * len(faces)
    counts = {"tiny_piece_faces_dropped": int((~keep).sum()),
              "tiny_pieces_dropped": int(len(np.unique(face_label[~keep])))}
    return faces[keep], uv_faces[keep], counts


def repair_mesh(points: np.ndarray, faces: np.ndarray, uvs: np.ndarray, uv_faces: np.ndarray,
                path: Path) -> RepairedMesh:
    """The repairs of the module doc, then the checks (slivers left, non-manifold edges), then
    stray pieces dropped and the vertices and UVs no face uses removed.

    Returns:
        The repaired mesh; ``repairs`` counts merged vertices, collapsed short edges, dropped
        collapsed faces, faces given twice, flipped edges, dropped slivers, stray pieces and
        their faces, and removed unused vertices (zero counts left out).

    Raises:
        WrinklesInputError: slivers left, non-manifold edges, or nothing left.
    """
    n_read = len(points)
    points, faces = merge_duplicates(points, faces)
    merged = n_read - len(points)
    faces, collapsed = collapse_short_edges(points, faces)
    faces, uv_faces, n_collapsed, n_twice = drop_collapsed_and_twice(faces, uv_faces)
    if len(faces) == 0:
        raise WrinklesInputError("every face is degenerate (zero area)", path=path)
    faces, uvs, uv_faces, flipped = flip_slivers(points, faces, uvs, uv_faces)
    faces, uv_faces, loose = drop_loose_slivers(points, faces, uv_faces)
    check_face_heights(points, faces, path)
    edges = check_manifold(points, faces, path)
    faces, uv_faces, tiny = drop_tiny_pieces(len(points), faces, uv_faces, edges)
    used = np.unique(faces)
    remap = np.full(len(points), -1, np.int64)
    remap[used] = np.arange(len(used))
    used_uv = np.unique(uv_faces)
    remap_uv = np.full(len(uvs), -1, np.int64)
    remap_uv[used_uv] = np.arange(len(used_uv))
    repairs = {"merged_vertices": merged, "short_edges_collapsed": collapsed,
               "collapsed_faces_dropped": n_collapsed, "duplicate_faces_dropped": n_twice,
               "sliver_edges_flipped": flipped, "slivers_dropped": loose, **tiny,
               "unused_vertices_removed": len(points) - len(used)}
    return RepairedMesh(points[used], remap[faces], uvs[used_uv], remap_uv[uv_faces],
                        {k: int(v) for k, v in repairs.items() if v})
