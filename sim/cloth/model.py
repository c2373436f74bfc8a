"""Static cloth data: ``ClothModelBuilder`` (numpy) and ``ClothModel`` (Warp arrays on a device).

A model holds any number of independent cloth *instances* (garments, or the same garment in
several sequences) so that one kernel launch advances all of them.
Every particle carries its instance id; per-instance data (thickness, friction, which body
mesh it collides with) is indexed by it. Instances never interact.

Built once: rest-shape inverse ``Dm^-1`` and area per triangle, bending hinges with rest
angle and stiffness, lumped masses, vertex -> triangle / hinge adjacency (CSR) and a graph
colouring. Colours are computed per instance and merged by colour index, so an instance in a
batch is updated in exactly the same order as alone (bit-identical results).

The colouring separates the vertices of every triangle, not the two opposite vertices of a
bending hinge: the t-shirt needs 4 colours instead of 6, so every sweep is two launches
shorter. A hinge whose opposite vertices share a colour is marked in
``vertex_edge_local`` (bits 2-5: which of the hinge's vertices have this vertex's colour), and
the solve reads those from the sweep's snapshot (``sim.cloth.solve_kernel``): the weak
bending coupling between them is a Jacobi step, every other coupling Gauss-Seidel.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from sim.cloth.pattern_distance import pattern_positions
from sim.cloth.topology import mesh_topology
from sim.device import resolve_device, warp
from sim.memo import LRU, content_key, read_only
from sim.types import face_layers_array


class ClothMaterialLike(Protocol):
    """Any object with these attributes (e.g. ``sim.garments.materials.Material``).

    density [kg/m^2], mu and lam (2D Lame parameters) [N/m], bending [N m], damping
    (Rayleigh stiffness-proportional coefficient) [s], friction (Coulomb, cloth vs body) [-],
    thickness (collision distance kept from the body) [m].
    """

    density: float
    mu: float
    lam: float
    bending: float
    damping: float
    friction: float
    thickness: float


@dataclass(frozen=True)
class ClothMaterialParams:
    """Plain material parameters for the solver (units as in ``ClothMaterialLike``)."""

    density: float = 0.2
    mu: float = 500.0
    lam: float = 200.0
    bending: float = 1.0e-5
    damping: float = 1.0e-3
    friction: float = 0.3
    thickness: float = 0.004


def as_cloth_params(material: Any) -> Any:
    """Solver parameters from a ``sim.garments.Material`` (E, nu, B in SI) or anything that
    already has ``density, mu, lam, bending, damping, friction, thickness``.

    The solver's membrane is isotropic (co-rotated linear): mu, lam are the plane-stress Lame
    parameters of the material's (E, nu); its separate in-plane shear stiffness is not used.
    """
    if hasattr(material, "mu") or not hasattr(material, "lame_mu"):
        return material
    return ClothMaterialParams(
        density=float(material.density), mu=float(material.lame_mu), lam=float(material.lame_lambda),
        bending=float(material.bending_stiffness), damping=float(material.damping),
        friction=float(material.friction), thickness=float(material.thickness))


def triangle_rest_data(rest: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rest-shape ``Dm^-1`` (F, 2, 2) and area (F,) [m^2] in each triangle's own 2D frame.

    Args:
        rest: rest positions [m], (V, 3).
        faces: int (F, 3).
    """
    x = rest.astype(np.float64)
    e1 = x[faces[:, 1]] - x[faces[:, 0]]
    e2 = x[faces[:, 2]] - x[faces[:, 0]]
    n = np.cross(e1, e2)
    twice_area = np.linalg.norm(n, axis=1)
    if np.any(twice_area < 1e-14):
        bad = int(np.argmin(twice_area))
        raise ValueError(f"cloth mesh: face {bad} has zero rest area (degenerate triangle)")
    t0 = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    t1 = np.cross(n / twice_area[:, None], t0)
    dm = np.empty((len(faces), 2, 2))
    dm[:, 0, 0] = np.sum(e1 * t0, axis=1)
    dm[:, 0, 1] = np.sum(e2 * t0, axis=1)
    dm[:, 1, 0] = np.sum(e1 * t1, axis=1)
    dm[:, 1, 1] = np.sum(e2 * t1, axis=1)
    return np.linalg.inv(dm), 0.5 * twice_area


def flat_rest_data(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rest ``Dm^-1`` (F, 2, 2) and area (F,) [m^2] of triangles given by their flat corners
    (F, 3, 2) [m], counter-clockwise (the frame differs from ``triangle_rest_data``'s by a
    rotation, which the co-rotated membrane does not see)."""
    c = np.asarray(corners, np.float64)
    dm = np.stack([c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]], axis=2)  # columns e1, e2
    det = dm[:, 0, 0] * dm[:, 1, 1] - dm[:, 0, 1] * dm[:, 1, 0]
    if np.any(det < 1e-14):
        bad = int(np.argmin(det))
        raise ValueError(f"cloth mesh: face {bad} has zero or negative flat rest area (corners must be "
                         "counter-clockwise)")
    return np.linalg.inv(dm), 0.5 * det


def hinge_rest_angles(ins: _Instance) -> np.ndarray:
    """Rest dihedral angle of each hinge: of the rest shape, or 0 (flat) inside one pattern
    panel when the instance has flat rest corners."""
    angles = dihedral_angles(ins.rest, ins.hinges)
    if ins.flat is not None:
        t_a, t_b = hinge_faces(ins.faces, ins.hinges)
        angles[ins.panels[t_a] == ins.panels[t_b]] = 0.0
    return angles


def dihedral_angles(x: np.ndarray, hinges: np.ndarray) -> np.ndarray:
    """Signed dihedral angles [rad] of hinges at positions ``x`` (numpy float64 reference)."""
    x = x.astype(np.float64)
    xo0, xo1, xa, xb = (x[hinges[:, k]] for k in range(4))
    e = xb - xa
    na = np.cross(e, xo0 - xa)
    nb = np.cross(xa - xb, xo1 - xb)
    na /= np.linalg.norm(na, axis=1, keepdims=True)
    nb /= np.linalg.norm(nb, axis=1, keepdims=True)
    en = e / np.linalg.norm(e, axis=1, keepdims=True)
    return np.arctan2(np.sum(np.cross(na, nb) * en, axis=1), np.sum(na * nb, axis=1))


def _csr(num_rows: int, rows: np.ndarray, payload: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    order = np.argsort(rows, kind="stable")
    offsets = np.zeros(num_rows + 1, dtype=np.int32)
    np.add.at(offsets, rows + 1, 1)
    return (np.cumsum(offsets).astype(np.int32), *(p[order].astype(np.int32) for p in payload))


@dataclass
class _Instance:
    vertices: np.ndarray
    rest: np.ndarray
    faces: np.ndarray
    hinges: np.ndarray
    pinned: np.ndarray
    material: Any
    colors: np.ndarray
    layers: np.ndarray
    flat: np.ndarray | None = None
    panels: np.ndarray | None = None


class ClothModelBuilder:
    """Collects cloth instances (numpy) and finalises them into a ``ClothModel``.

    Args:
        gravity: gravitational acceleration [m/s^2], shared by all instances (Y up).
        max_colors: colours of each instance's vertex colouring (``compact_coloring``): 0 (default)
            as few as a proper colouring needs; fewer leaves some neighbours same-coloured, and
            the solve couples those by a Jacobi step (``vertex_tri_local``'s mask).
        contact_offset: distance [m] kept from the body on top of each material's thickness
            (``BodyContact.offset``): ``instance_thickness`` holds their sum.
    """

    def __init__(self, *, gravity: tuple[float, float, float] = (0.0, -9.81, 0.0), max_colors: int = 0,
                 contact_offset: float = 0.0):
        self.gravity = tuple(float(g) for g in gravity)
        self.contact_offset = float(contact_offset)
        if max_colors < 0 or max_colors == 1:
            raise ValueError(f"ClothModelBuilder: max_colors must be 0 (proper) or >= 2, got {max_colors}")
        self.max_colors = int(max_colors)
        self._instances: list[_Instance] = []

    def add_cloth(self, vertices: np.ndarray, faces: np.ndarray, material: ClothMaterialLike, *,
                  pinned: np.ndarray | None = None, rest_vertices: np.ndarray | None = None,
                  face_layers: np.ndarray | None = None, rest_corners: np.ndarray | None = None,
                  face_panels: np.ndarray | None = None, topology: tuple | None = None) -> int:
        """Add one cloth instance.

        Args:
            vertices: initial positions [m], (V, 3).
            faces: int (F, 3), consistently oriented.
            material: object with ``density, mu, lam, bending, damping, friction, thickness``.
            pinned: optional bool mask (V,) or index array: vertices that follow
                ``ClothControl.pin_targets`` instead of being simulated (attachments).
            rest_vertices: rest shape [m], (V, 3); defaults to ``vertices``.
            face_layers: layers of fabric per face, (F,), >= 1 (None: 1 everywhere), e.g. a
                garment's hems (``Garment.face_layers``). A face of n layers has n times the
                material's area density, membrane moduli and bending stiffness (layers that bend
                and stretch side by side, not bonded into one sheet); a hinge takes the mean of
                its two faces.
            rest_corners: each face's corners in its flat sewing-pattern panel [m], (F, 3, 2),
                counter-clockwise (a garment's ``flat_corners()``): the membrane's rest metric and
                the rest areas come from the pattern instead of ``rest_vertices``, and hinges
                inside one panel (``face_panels``) rest flat, as cloth cut from a flat bolt
                does; hinges across a seam keep ``rest_vertices``' angle.
            face_panels: panel of each face, (F,), with ``rest_corners``.
            topology: ``(hinges, colors)`` of the mesh as ``mesh_topology(V, faces,
                max_colors)`` gives them (``mesh_topologies`` makes a batch's in parallel);
                None: computed here.

        Returns:
            The instance index.
        """
        v = np.asarray(vertices, dtype=np.float32).reshape(-1, 3)
        f = np.asarray(faces, dtype=np.int32).reshape(-1, 3)
        if len(f) == 0 or f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"cloth mesh: faces must index 0..{len(v) - 1} (got {len(f)} faces)")
        material = as_cloth_params(material)
        for name in ("density", "mu", "lam", "bending", "damping", "friction", "thickness"):
            if not hasattr(material, name):
                raise ValueError(f"cloth material: missing field '{name}' (needs density, mu, lam, bending,"
                                 " damping, friction, thickness)")
        if material.density <= 0.0:
            raise ValueError(f"cloth material: density must be > 0 kg/m^2, got {material.density}")
        rest = v if rest_vertices is None else np.asarray(rest_vertices, dtype=np.float32).reshape(-1, 3)
        mask = np.zeros(len(v), dtype=bool)
        if pinned is not None:
            p = np.asarray(pinned)
            if p.dtype == bool:
                mask[:] = p
            else:
                mask[p.astype(np.int64)] = True
        layers = face_layers_array(face_layers, len(f), "cloth mesh")
        flat = panels = None
        if rest_corners is not None:
            flat = np.asarray(rest_corners, np.float64)
            panels = np.zeros(len(f), np.int64) if face_panels is None else np.asarray(face_panels, np.int64)
            if flat.shape != (len(f), 3, 2) or panels.shape != (len(f),):
                raise ValueError(f"cloth mesh: rest_corners must be ({len(f)}, 3, 2) and face_panels "
                                 f"({len(f)},), got {flat.shape} and {panels.shape}")
        hinges, colors = topology if topology is not None else mesh_topology(len(v), f, self.max_colors)
        self._instances.append(_Instance(v, rest, f, hinges, mask, material, colors, layers, flat, panels))
        return len(self._instances) - 1

    def finalize(self, device: str | None = None) -> ClothModel:
        """Upload all instances to ``device`` (None: cuda when present, else cpu)."""
        if not self._instances:
            raise ValueError("ClothModelBuilder.finalize: no cloth instances were added")
        wp = warp()
        d = resolve_device(device)
        meshes = [mesh_parts(ins) for ins in self._instances]  # each mesh's own, made once
        parts = _stack_instances(self._instances, meshes, self.contact_offset)
        n = parts.pop("particle_count")
        faces, hinges = parts["faces"], parts["hinges"]
        colors = np.concatenate([ins.colors for ins in self._instances])
        adjacency = _adjacency(self._instances, meshes, parts)
        # merge per-instance colourings by colour index (see module docstring)
        color_order = np.argsort(colors, kind="stable").astype(np.int32)
        counts = np.bincount(colors)
        color_offsets = np.concatenate([[0], np.cumsum(counts)]).astype(int).tolist()

        def arr(a, dtype):
            return wp.array(np.ascontiguousarray(a), dtype=dtype, device=d)

        return ClothModel(
            device=d, particle_count=n, tri_count=len(faces), edge_count=len(hinges),
            instance_count=len(self._instances), gravity=self.gravity,
            instance_starts=parts["instance_starts"], faces=faces, hinges=hinges, colors=colors,
            color_offsets=color_offsets,
            **{name: arr(parts[name], dtype) for name, dtype in _warp_dtypes().items()},
            **{name: arr(a, dtype) for name, (a, dtype) in adjacency.items()},
            color_vertices=arr(color_order, wp.int32),
        )


def _stack_instances(instances: list[_Instance], meshes: list[dict[str, Any]],
                     contact_offset: float = 0.0) -> dict[str, Any]:
    """The instances' per-particle, per-triangle, per-hinge and per-instance arrays (from their
    materials and their meshes' ``mesh_parts``, ``meshes``), stacked in instance order (float32 /
    int32 numpy), with ``particle_count``, ``instance_starts`` and the stacked ``faces`` and
    ``hinges`` (global vertex indices)."""
    cols: dict[str, list] = collections.defaultdict(list)
    offset = 0
    for k, (ins, mesh) in enumerate(zip(instances, meshes, strict=True)):
        m = ins.material
        nv = len(ins.vertices)
        cols["starts"].append(offset)
        dinv, a = mesh["dinv"], mesh["area"]
        cols["particle_q"].append(ins.vertices)
        cols["particle_rest"].append(ins.rest)
        cols["particle_panel"].append(mesh["panel"])
        cols["particle_flat"].append(mesh["flat"])
        cols["particle_mass"].append(m.density * mesh["lumped"])
        cols["particle_flags"].append(ins.pinned.astype(np.int32))
        cols["particle_instance"].append(np.full(nv, k, dtype=np.int32))
        cols["faces"].append(ins.faces + offset)
        cols["tri_dm_inv"].append(dinv)
        cols["tri_area"].append(a)
        cols["tri_mu"].append(m.mu * ins.layers)
        cols["tri_lam"].append(m.lam * ins.layers)
        cols["tri_damping"].append(np.full(len(a), m.damping))
        if len(ins.hinges):
            cols["hinges"].append(ins.hinges + offset)
            cols["edge_rest_angle"].append(mesh["rest_angle"])
            mean_layers, edge_len2, pair_area = mesh["hinge"]  # hinge_factors at the material's bending
            cols["edge_stiffness"].append(m.bending * mean_layers * 3.0 * edge_len2 / pair_area)
            cols["edge_damping"].append(np.full(len(ins.hinges), m.damping))
        cols["instance_thickness"].append(m.thickness + contact_offset)
        cols["instance_friction"].append(m.friction)
        offset += nv
    cat = np.concatenate
    out: dict[str, Any] = {name: cat(cols[name]).astype(np.float32) for name in (
        "particle_q", "particle_rest", "particle_mass", "tri_dm_inv", "tri_area", "tri_mu", "tri_lam",
        "tri_damping", "particle_flat")}
    out["particle_flags"] = cat(cols["particle_flags"])
    out["particle_panel"] = cat(cols["particle_panel"])
    out["particle_instance"] = cat(cols["particle_instance"])
    for name in ("edge_rest_angle", "edge_stiffness", "edge_damping"):
        out[name] = cat(cols[name]).astype(np.float32) if cols[name] else np.zeros(0, np.float32)
    for name in ("instance_thickness", "instance_friction"):
        out[name] = np.asarray(cols[name], np.float32)
    out["faces"] = cat(cols["faces"])
    out["hinges"] = cat(cols["hinges"]) if cols["hinges"] else np.zeros((0, 4), np.int32)
    out["tri_indices"] = out["faces"].astype(np.int32)
    out["edge_indices"] = out["hinges"].astype(np.int32).reshape(-1, 4)
    out["particle_count"] = offset
    out["instance_starts"] = np.asarray(cols["starts"] + [offset], dtype=np.int64)
    return out


def _adjacency(instances: list[_Instance], meshes: list[dict[str, Any]],
               parts: dict[str, Any]) -> dict[str, tuple]:
    """Vertex -> (triangle, corner), vertex -> (hinge, slot) and vertex -> (mesh edge, end) CSR
    adjacency (``local`` columns packed with the same-coloured vertices, ``local_packed``), every
    mesh edge (boundary included, for edge-edge self-contact) and the instance of every triangle
    and mesh edge, as ``ClothModel`` field -> (numpy array, Warp dtype). Instances do not share
    vertices, so each is its mesh's own adjacency (``meshes``: each instance's ``mesh_parts``)
    with its vertices, triangles, hinges and edges counted after the instances before it."""
    wp = warp()
    starts = parts["instance_starts"]
    sizes = {"vertex_tri": [len(ins.faces) for ins in instances],
             "vertex_edge": [len(ins.hinges) for ins in instances],
             "vertex_mesh_edge": [len(mesh["mesh_edges"]) for mesh in meshes]}
    out = {}
    for name, counts in sizes.items():
        stacked = _stacked_csr([mesh[name] for mesh in meshes], counts)
        for suffix, a in zip(("offsets", "ids", "local"), stacked, strict=True):
            out[f"{name}_{suffix}"] = (a, wp.int32)
    me_all = np.concatenate([mesh["mesh_edges"] + starts[k] for k, mesh in enumerate(meshes)])
    out["mesh_edge_indices"] = (me_all.astype(np.int32).reshape(-1, 2), wp.vec2i)
    out["tri_instance"] = (parts["particle_instance"][parts["faces"][:, 0]].astype(np.int32), wp.int32)
    out["mesh_edge_instance"] = (parts["particle_instance"][me_all[:, 0]].astype(np.int32), wp.int32)
    return out


def _stacked_csr(blocks: list[tuple[np.ndarray, ...]], counts: list[int]) -> tuple[np.ndarray, ...]:
    """One CSR (offsets, ids, local; int32) of the block-diagonal stack of per-instance CSRs
    ``blocks``: instance k's rows after the rows before it, its ids after the ``counts`` of
    primitives before it."""
    offsets, ids, local = [], [], []
    entries = primitives = 0
    for (o, i, loc), count in zip(blocks, counts, strict=True):
        offsets.append(np.asarray(o[:-1], np.int64) + entries)
        ids.append(np.asarray(i, np.int64) + primitives)
        local.append(loc)
        entries += len(i)
        primitives += count
    return (np.concatenate([*offsets, [entries]]).astype(np.int32), np.concatenate(ids).astype(np.int32),
            np.concatenate(local).astype(np.int32))


MESH_CACHE = 32
"""Meshes whose ``mesh_parts`` a process keeps (least recently used dropped first)."""

_MESH_PARTS = LRU(MESH_CACHE)


def mesh_parts(ins: _Instance) -> dict[str, Any]:
    """What an instance's model arrays take from its mesh alone (rest shape, faces, hinges,
    colours, fabric layers, sewing pattern), in the mesh's own indices: rest ``Dm^-1`` and areas,
    pattern positions, lumped areas, hinge rest angles and ``hinge_pieces``, and the vertex ->
    triangle / hinge / mesh-edge CSR adjacency with its mesh edges. Made once per mesh content
    (a batch of sequences of one garment adds its mesh many times: a reference-fit dataset's
    group of 32 fine and 32 coarse instances has two meshes)."""
    key = content_key(ins.rest, ins.faces, ins.hinges, ins.colors, ins.layers, ins.flat, ins.panels)
    return _MESH_PARTS.get_or_make(key, lambda: _make_mesh_parts(ins))


def _make_mesh_parts(ins: _Instance) -> dict[str, Any]:
    nv, f, h = len(ins.rest), ins.faces, ins.hinges
    dinv, a = triangle_rest_data(ins.rest, f) if ins.flat is None else flat_rest_data(ins.flat)
    panel, flat = pattern_positions(nv, f, ins.flat)
    p: dict[str, Any] = {"dinv": dinv, "area": a, "panel": panel, "flat": flat,
                         "lumped": lumped_areas(nv, f, a, ins.layers)}
    if len(h):
        p["rest_angle"] = hinge_rest_angles(ins)
        p["hinge"] = hinge_pieces(ins.rest, f, h, a, ins.layers)
    vt = _csr(nv, f.reshape(-1), [np.repeat(np.arange(len(f)), 3), np.tile(np.arange(3), len(f))])
    p["vertex_tri"] = (*vt[:2], local_packed(ins.colors, f, vt))
    ve = _csr(nv, h.reshape(-1).astype(np.int64),
              [np.repeat(np.arange(len(h)), 4), np.tile(np.arange(4), len(h))])
    p["vertex_edge"] = (*ve[:2], local_packed(ins.colors, h.reshape(-1, 4), ve))
    me = mesh_edges(f)
    p["mesh_edges"] = me
    p["vertex_mesh_edge"] = _csr(nv, me.reshape(-1).astype(np.int64),
                                 [np.repeat(np.arange(len(me)), 2), np.tile(np.arange(2), len(me))])
    for value in p.values():  # shared by every model the mesh goes into
        for a in value if isinstance(value, tuple) else (value,):
            read_only(a)
    return p


def _warp_dtypes() -> dict[str, Any]:
    """The Warp dtype of each ``ClothModel`` array ``_stack_instances`` makes."""
    wp = warp()
    return {"particle_q": wp.vec3, "particle_rest": wp.vec3, "particle_panel": wp.int32,
            "particle_flat": wp.vec3, "particle_mass": float,
            "particle_flags": wp.int32, "particle_instance": wp.int32, "tri_indices": wp.vec3i,
            "tri_dm_inv": wp.mat22, "tri_area": float, "tri_mu": float, "tri_lam": float,
            "tri_damping": float, "edge_indices": wp.vec4i, "edge_rest_angle": float, "edge_stiffness": float,
            "edge_damping": float, "instance_thickness": float, "instance_friction": float}


def local_packed(colors: np.ndarray, prims: np.ndarray, csr: tuple[np.ndarray, ...]) -> np.ndarray:
    """The packed ``local`` column of a CSR vertex -> primitive adjacency ``csr`` (offsets,
    primitive ids, slot of the vertex in the primitive) over ``prims`` (P, k) (hinges: k = 4,
    ``vertex_edge_local``; triangles: k = 3, ``vertex_tri_local``): the slot in bits 0-1, and in
    bits 2.. which of the primitive's other vertices have the vertex's colour, where the solve
    reads them from the sweep's snapshot. For a hinge only the other opposite vertex can (the
    colouring separates every triangle's vertices); a triangle's corners only with
    ``max_colors`` (a colouring with same-coloured neighbours)."""
    offsets, ids, local = csr
    if not len(ids):
        return np.asarray(local, np.int64)
    k = prims.shape[1]
    owner = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    q = prims[ids]
    same = (colors[q] == colors[owner][:, None]) & (np.arange(k)[None, :] != np.asarray(local)[:, None])
    mask = (same * (1 << np.arange(k))[None, :]).sum(axis=1)
    return np.asarray(local, np.int64) | (mask << 2)


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """Unique undirected edges ``(a, b)``, ``a < b``, of a triangle mesh, int32 (E, 2), sorted."""
    from sim.quality import unique_edges

    return unique_edges(faces)


def lumped_areas(vertex_count: int, faces: np.ndarray, areas: np.ndarray, layers: np.ndarray) -> np.ndarray:
    """Per vertex, one third of its triangles' rest areas times their fabric layers [m^2] (the
    lumped mass per unit area density), float64 (V,)."""
    out = np.zeros(vertex_count)
    np.add.at(out, np.asarray(faces).reshape(-1), np.repeat(areas * layers / 3.0, 3))
    return out


def hinge_factors(rest: np.ndarray, faces: np.ndarray, hinges: np.ndarray, areas: np.ndarray,
                  layers: np.ndarray, bending: float = 1.0) -> np.ndarray:
    """Each hinge's stiffness ``k_b n 3 |e|^2 / (A_1 + A_2)`` (rest shape; Grinspun et al. 2003),
    ``n`` the mean fabric layers of its two faces, for a bending stiffness ``bending`` [N m]
    (1: the factor of ``k_b``)."""
    mean_layers, edge_len2, pair_area = hinge_pieces(rest, faces, hinges, areas, layers)
    return bending * mean_layers * 3.0 * edge_len2 / pair_area


def hinge_pieces(rest: np.ndarray, faces: np.ndarray, hinges: np.ndarray, areas: np.ndarray,
                 layers: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per hinge, what ``hinge_factors`` takes from the mesh: the mean fabric layers of its two
    faces, its squared rest length [m^2] and the sum of its faces' rest areas [m^2]."""
    edge_len2 = np.sum((rest[hinges[:, 3]] - rest[hinges[:, 2]]) ** 2, axis=1)
    t_a, t_b = hinge_faces(faces, hinges)
    return 0.5 * (layers[t_a] + layers[t_b]), edge_len2, areas[t_a] + areas[t_b]


def hinge_faces(faces: np.ndarray, hinges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two triangles of each hinge (``build_hinges``' layout), found by their directed edges:
    the one with the directed edge a -> b, then the one with b -> a."""
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    n = int(f.max(initial=0)) + 1
    # every directed edge's key and its triangle; a manifold mesh has each directed edge once
    # (a repeated one keeps its last triangle, as a dict filled in face order would)
    keys = (f * n + np.roll(f, -1, axis=1)).reshape(-1)
    tris = np.repeat(np.arange(len(f)), 3)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    last = np.r_[sorted_keys[1:] != sorted_keys[:-1], True]
    sorted_keys, owner = sorted_keys[last], tris[order][last]
    a = np.asarray(hinges[:, 2], np.int64)
    b = np.asarray(hinges[:, 3], np.int64)

    def lookup(q: np.ndarray) -> np.ndarray:
        i = np.searchsorted(sorted_keys, q)
        if np.any(i >= len(sorted_keys)) or np.any(sorted_keys[np.minimum(i, len(sorted_keys) - 1)] != q):
            raise KeyError("hinge_faces: a hinge's directed edge is on no triangle")
        return owner[i]

    return lookup(a * n + b), lookup(b * n + a)


@dataclass
class ClothModel:
    """Static cloth data on one device (build with ``ClothModelBuilder``).

    Per particle (``particle_count``): ``particle_q`` initial positions [m], ``particle_rest``
    rest positions [m], ``particle_panel`` / ``particle_flat`` the particle's panel and (u, v,
    seam distance) [m] in its sewing pattern (``sim.cloth.pattern_distance``; panel -1 without
    one), ``particle_mass`` lumped mass [kg], ``particle_flags`` (1: pinned,
    follows ``ClothControl.pin_targets``), ``particle_instance`` instance id.
    Per triangle: ``tri_indices``, ``tri_dm_inv`` (rest ``Dm^-1``, 1/m), ``tri_area`` [m^2],
    ``tri_mu``/``tri_lam`` [N/m], ``tri_damping`` [s]. Per hinge: ``edge_indices``
    (o0, o1, a, b), ``edge_rest_angle`` [rad], ``edge_stiffness`` k_e [N m], ``edge_damping`` [s].
    Per instance: ``instance_thickness`` [m], ``instance_friction``; ``instance_starts`` (host,
    (I+1,)) slices the particle range of each instance. ``color_vertices`` lists particles by
    colour; colour ``c`` is ``color_vertices[color_offsets[c]:color_offsets[c+1]]``.
    Vertex -> triangle CSR ``vertex_tri_offsets`` / ``vertex_tri_ids`` / ``vertex_tri_local``
    (the vertex's corner in bits 0-1, same-coloured corners in bits 2-4: ``local_packed``);
    vertex -> hinge ``vertex_edge_*`` (slot and same-coloured vertices alike).
    Self-contact data: ``mesh_edge_indices`` (every undirected edge, vec2i (E,)) with vertex ->
    edge CSR ``vertex_mesh_edge_*``, ``tri_instance`` / ``mesh_edge_instance`` /
    ``particle_instance`` (BVH groups: instances never collide).
    """

    device: str
    particle_count: int
    tri_count: int
    edge_count: int
    instance_count: int
    gravity: tuple[float, float, float]
    instance_starts: np.ndarray
    faces: np.ndarray
    hinges: np.ndarray
    colors: np.ndarray
    color_offsets: list[int]
    particle_q: Any
    particle_rest: Any
    particle_panel: Any
    particle_flat: Any
    particle_mass: Any
    particle_flags: Any
    particle_instance: Any
    tri_indices: Any
    tri_dm_inv: Any
    tri_area: Any
    tri_mu: Any
    tri_lam: Any
    tri_damping: Any
    edge_indices: Any
    edge_rest_angle: Any
    edge_stiffness: Any
    edge_damping: Any
    vertex_tri_offsets: Any
    vertex_tri_ids: Any
    vertex_tri_local: Any
    vertex_edge_offsets: Any
    vertex_edge_ids: Any
    vertex_edge_local: Any
    color_vertices: Any
    instance_thickness: Any
    instance_friction: Any
    mesh_edge_indices: Any
    vertex_mesh_edge_offsets: Any
    vertex_mesh_edge_ids: Any
    vertex_mesh_edge_local: Any
    tri_instance: Any
    mesh_edge_instance: Any

    @property
    def color_count(self) -> int:
        return len(self.color_offsets) - 1

    def instance_slice(self, instance: int) -> slice:
        """Particle range of one instance."""
        return slice(int(self.instance_starts[instance]), int(self.instance_starts[instance + 1]))

    def state(self):
        """A ``ClothState`` at the initial positions, at rest."""
        from sim.cloth.state import ClothState

        return ClothState.from_model(self)

    def control(self):
        """A ``ClothControl`` with pins at the initial positions and no bodies."""
        from sim.cloth.state import ClothControl

        return ClothControl.from_model(self)
