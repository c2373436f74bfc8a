"""The same cloth scene through Newton's ``SolverVBD`` (PyPI ``newton``), for the side-by-side
figures of ``bench_tshirt --newton``.

Newton is an optional benchmark dependency, in no requirement of the project. This module
imports nothing from ``sim/``: a scene is a plain dict of numpy arrays, so it runs wherever Newton
and Warp run (a separate ``.venv-newton`` on a workstation, ``benchmarks/newton_pack.sh`` for a GPU
machine without network). ``newton`` is imported inside :func:`run_newton_vbd`.

    python -m benchmarks.newton_ref --device cpu      # a sheet dropped onto a sphere, with checks

Scene (``dict``; arrays are converted to float32 / int32)
-------------------------------------------------------
==========================  ===========  ==========================================================
key                         shape        meaning
==========================  ===========  ==========================================================
``garment_positions``       (V, 3)       garment vertices at body frame 0 [m]
``garment_rest_positions``  (V, 3)       rest shape [m] (membrane and bending rest state)
``garment_faces``           (F, 3)       triangles, int
``pinned``                  (P,)         pinned vertex indices (may be empty)
``pin_targets``             (T, P, 3)    pinned positions per body frame [m]; empty: pins stay put
``density``                 float        area density [kg/m²]
``mu``, ``lam``             float        plane-stress Lamé μ, λ [N/m] (what our solver uses)
``bending``                 float        bending rigidity k_b [N·m]
``damping``                 float        Rayleigh stiffness-proportional β [s]
``friction``                float        Coulomb μ against the body (and cloth-cloth) [-]
``thickness``               float        cloth/body contact offset [m]
``body_faces``              (Fb, 3)      body triangles, outward (counter-clockwise seen outside)
``body_vertices``           (T, Vb, 3)   body vertices per frame [m]
``fps``                     float        frame rate of ``body_vertices`` and of the output [1/s]
``gravity`` (optional)      (3,)         [m/s²], default (0, -9.81, 0) (Y up)
``face_layers`` (optional)  (F,)         fabric layers per face, >= 1 (default 1): a garment's
                                         hems (``Garment.face_layers``), as in our solver
==========================  ===========  ==========================================================

Output frame k (k = 0 .. frames-1) is the garment at body frame k; frame 0 is
``garment_positions``; frame k is one step of 1/fps from frame k-1 in ``substeps`` substeps of
``iterations`` VBD iterations each, with the body moving linearly from body frame k-1 to k.

How the scene is built in Newton 1.8 (read from the installed package's source)
-------------------------------------------------------------------------------
* Cloth: ``ModelBuilder(up_axis=Y, gravity=...)``; ``add_cloth_mesh`` with the **rest** vertices
  (it takes one vertex set as both rest and initial shape: triangle ``tri_poses``, edge rest
  angles and lengths come from it), ``builder.color()`` (VBD needs the particle colouring), then
  the states' ``particle_q`` are set to ``garment_positions``. Pinned vertices lose
  ``ParticleFlags.ACTIVE`` (the solver leaves them alone, as in ``example_cloth_twist``) and are
  written, with our linear-in-time interpolation of the pin targets, into both states before each
  substep.
* Body: one static (``body=-1``) triangle-mesh shape, ``newton.Mesh(points, faces)``. Newton's
  particle-vs-shape ("soft") contacts query the shape's ``wp.Mesh`` directly
  (``geometry/kernels.py:create_soft_contacts``: ``mesh_query_point_sign`` then
  ``mesh_eval_position`` / ``mesh_eval_velocity``), and ``newton.Mesh.mesh`` is documented as
  the finalized ``wp.Mesh`` whose ``velocities`` may be updated on the device to prescribe
  surface motion (used by friction); normal motion must come from moving the geometry. So per
  substep a kernel writes the lerped body vertices into ``mesh.points`` and the frame's
  per-vertex velocity into ``mesh.velocities``, then ``mesh.refit()``. (Newton has no skinned
  /deforming-collider example; ``example_cloth_h1`` is the pattern followed for a moving
  collider: move the kinematics, then ``CollisionPipeline.collide`` and ``solver.step`` every
  substep.) The shape's local AABB (``model.shape_collision_aabb_lower/upper``, which
  ``compute_shape_aabbs`` uses for meshes and which culls soft contacts) is widened once to the
  union over all frames, since Newton computes it from frame 0 only. The friction code
  (``rigid_vbd_kernels._eval_body_particle_contact``) takes the body velocity at the contact
  as ``(bx - bx_prev)/dt + contact_body_vel``; for a static shape the first term is 0 and
  ``contact_body_vel`` is the mesh velocity interpolated at the closest point: the cloth is
  dragged by the moving skin, as in our solver.
* Per substep (the order of ``example_cloth_h1``): place body (+ refit), place pins,
  ``state.clear_forces()``, ``pipeline.collide(state_0, contacts)``,
  ``solver.step(state_0, state_1, control, contacts, h)``, swap. Contacts are found from the
  substep-start cloth against the substep-end body, as in ours. With self-contact, each frame
  starts with ``solver.rebuild_bvh(state_0)`` (``example_cloth_twist``); self-contact
  detection itself runs inside ``step`` (default schedule ``PRE_POST_INIT``: before and
  right after the inertial initialisation).
* CUDA graph: one frame (all substeps, the frame index kept in a device counter so the same
  graph replays every frame, positions written into a device (T, V, 3) buffer) is captured
  with ``wp.ScopedCapture`` after one eager warm-up frame, like Newton's examples. Newton 1.8
  captures with self-contact too (``example_cloth_twist`` and ``example_cloth_franka`` capture
  ``rebuild_bvh`` + self-contact steps; Warp 1.19's CUDA LBVH ``Bvh.rebuild`` and ``Mesh.refit``
  are capture-safe). If capture raises, the run falls back to plain launches and says why in
  ``notes``. An odd ``substeps`` count is handled by copying the state back at the end of the
  frame (Newton's examples ask for an even count instead).

Parameter mapping (ours → Newton)
---------------------------------
* Mass: ``add_cloth_mesh(density=density)`` lumps ``density * area / 3`` per vertex (rest
  areas), identical to ours.
* Fabric layers (``face_layers``): a face of n layers has n times the density, the membrane
  moduli and damping, and a hinge the mean of its two faces' layers times the bending, as in
  ``sim.cloth.model.ClothModelBuilder.add_cloth``. After ``finalize`` the runner writes the
  lumped masses (``particle_mass``, ``particle_inv_mass``), each triangle's ``tri_materials``
  k_mu, k_lambda, k_damp and each hinge's bending properties scaled so (``layered_masses``,
  ``hinge_layers``).
* Membrane: ``tri_ke = mu``, ``tri_ka = lam``. **Mismatch:** Newton 1.8's VBD membrane is the
  stable Neo-Hookean membrane of Smith et al. 2018 (``evaluate_neo_hookean_membrane_force_
  hessian``: ψ = μ/2 (I_c − 2) + λ'/2 (J − α)², λ' = λ + μ, α = 1 + μ/λ'), ours the co-rotated
  linear membrane (``sim.cloth.energies.corotated_energy``). Both have the same small-strain
  Lamé moduli; they differ at large strain and under compression.
* Membrane damping: ``tri_kd = damping * mu / 2`` [N·s/m]. Newton dissipates kd·A/2·|Ċ|² with
  C = FᵀF = I + 2G, i.e. 2·kd·A·|Ġ|²; ours is Rayleigh damping of the strain rate
  (``sim.cloth.energies.viscous_stress_g``), dissipating β·A·(μ|Ġ|² + λ/2 (tr Ġ)²). Both are
  objective (rigid motion is not damped); β·μ/2 matches the shear part exactly, the λ part of
  ours has no counterpart in Newton.
* Bending: Newton's hinge energy is ½·edge_ke·|e|·(θ − θ₀)² (``evaluate_dihedral_angle_
  based_bending_force_hessian``: k = stiffness·rest_length), ours ½·k_e·(θ − θ₀)² with
  k_e = 3·k_b·|e|²/(A₁ + A₂). A scalar ``edge_ke`` therefore cannot represent a material
  k_b on an irregular mesh; we write per-edge values into ``model.edge_bending_properties``:
  ``edge_ke_i = 3·k_b·|e_i|/(A₁ + A₂)`` (exact match per hinge), 0 on boundary edges.
* Bending damping: ``edge_kd_i = damping * edge_ke_i`` (Newton's force −kd·|e|·θ̇·∇θ equals
  our −β·k_e·θ̇·∇θ for the hinge).
* Body contact: ``particle_radius = thickness``, shape ``margin = 0`` (contact distance
  radius + margin, as our ``thickness``), penalty stiffness ``model.soft_contact_ke`` and the
  shape's ``ke`` both ``contact_stiffness`` (Newton averages the two; fixed k since
  ``rigid_avbd_beta`` = 0), contact damping kd = 0 on both (ours has none; Newton's defaults
  are 10 and 100), friction ``soft_contact_mu`` = shape ``mu`` = ``friction`` (Newton takes
  the geometric mean), ``friction_epsilon`` the same 1e-2 m/s (both use eps_u = ε·h).
  Detection: ``CollisionPipeline(soft_contact_gap=body_contact_gap)``, the query distance beyond
  the contact distance.
* Self-contact: ``particle_enable_self_contact``, ``particle_self_contact_margin`` (the
  interaction distance) and ``particle_self_contact_gap`` (extra detection reach; query radius
  = margin + gap), stiffness ``soft_contact_ke`` and friction ``soft_contact_mu`` (shared with
  the body contact in Newton). **Mismatch:** Newton's DAT truncation caps each particle's
  motion between two detections at 0.5 × 0.85 × (margin + gap); with the default schedule
  (two detections per substep) cloth can follow the body at most about
  2 × 0.425 × (margin + gap) × substeps × fps [m/s]; ``notes`` reports this budget and the
  body's largest vertex speed. Ours bounds with the distance to the nearest primitive and a
  speed-dependent query radius instead.
* Integration: Newton's initial guess is x + h·v (ours adds the adaptive-gravity term of the
  VBD paper); both are implicit Euler with ``iterations`` Gauss-Seidel sweeps over colours.
"""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

import numpy as np
import warp as wp

SCENE_ARRAYS = ("garment_positions", "garment_rest_positions", "garment_faces", "body_faces", "body_vertices")
SCENE_SCALARS = ("density", "mu", "lam", "bending", "damping", "friction", "thickness", "fps")
DAT_RELAXATION = 0.85  # Newton's default dat_conservative_bound_relaxation
DETECTIONS_PER_SUBSTEP = 2  # Newton's default self-contact schedule, PRE_POST_INIT
VERTEX_CONTACT_BUFFER = 32  # Newton's per-vertex self-contact pairs (beyond are dropped)
EDGE_CONTACT_BUFFER = 64  # Newton's per-edge self-contact pairs
TIMED_FROM = 3  # output frame 1 runs eagerly (compiles), frame 2 is the graph's first launch


@wp.kernel
def _place_body_kernel(
    frames: wp.array2d(dtype=wp.vec3),
    counter: wp.array(dtype=wp.int32),
    alpha: float,
    fps: float,
    points: wp.array(dtype=wp.vec3),
    velocities: wp.array(dtype=wp.vec3),
):
    """Body vertices at fraction ``alpha`` of the step from frame ``counter-1`` to ``counter``."""
    i = wp.tid()
    f = wp.min(counter[0], frames.shape[0] - 1)
    a = frames[f - 1, i]
    b = frames[f, i]
    points[i] = a + alpha * (b - a)
    velocities[i] = (b - a) * fps


@wp.kernel
def _place_pins_kernel(
    targets: wp.array2d(dtype=wp.vec3),
    pinned: wp.array(dtype=wp.int32),
    counter: wp.array(dtype=wp.int32),
    alpha: float,
    q0: wp.array(dtype=wp.vec3),
    q1: wp.array(dtype=wp.vec3),
):
    j = wp.tid()
    f = wp.min(counter[0], targets.shape[0] - 1)
    a = targets[f - 1, j]
    p = a + alpha * (targets[f, j] - a)
    q0[pinned[j]] = p
    q1[pinned[j]] = p


@wp.kernel
def _record_kernel(q: wp.array(dtype=wp.vec3), counter: wp.array(dtype=wp.int32),
                   out: wp.array2d(dtype=wp.vec3)):
    i = wp.tid()
    out[wp.min(counter[0], out.shape[0] - 1), i] = q[i]


@wp.kernel
def _advance_kernel(counter: wp.array(dtype=wp.int32)):
    counter[0] = counter[0] + 1


def validate_scene(scene: dict) -> dict:
    """Check shapes and convert dtypes; return a new dict (float32 / int32 arrays, floats)."""
    missing = [k for k in (*SCENE_ARRAYS, *SCENE_SCALARS) if k not in scene]
    if missing:
        raise ValueError(f"newton_ref scene: missing keys {missing}")
    s = {k: float(scene[k]) for k in SCENE_SCALARS}
    x = np.ascontiguousarray(scene["garment_positions"], np.float32).reshape(-1, 3)
    rest = np.ascontiguousarray(scene["garment_rest_positions"], np.float32).reshape(-1, 3)
    f = np.ascontiguousarray(scene["garment_faces"], np.int32).reshape(-1, 3)
    bf = np.ascontiguousarray(scene["body_faces"], np.int32).reshape(-1, 3)
    bv = np.ascontiguousarray(scene["body_vertices"], np.float32)
    if bv.ndim != 3 or bv.shape[2] != 3 or bv.shape[0] < 1:
        raise ValueError(f"newton_ref scene: body_vertices must be (T, Vb, 3), got {bv.shape}")
    if rest.shape != x.shape:
        raise ValueError(f"newton_ref scene: rest {rest.shape} and positions {x.shape} differ")
    if len(f) == 0 or f.min() < 0 or f.max() >= len(x):
        raise ValueError("newton_ref scene: garment_faces must index 0..V-1")
    if len(bf) == 0 or bf.min() < 0 or bf.max() >= bv.shape[1]:
        raise ValueError("newton_ref scene: body_faces must index 0..Vb-1")
    pinned = np.ascontiguousarray(scene.get("pinned", np.zeros(0)), np.int32).reshape(-1)
    if len(pinned) and (pinned.min() < 0 or pinned.max() >= len(x)):
        raise ValueError("newton_ref scene: pinned must index 0..V-1")
    targets = np.asarray(scene.get("pin_targets", np.zeros(0)), np.float32)
    if targets.size == 0:
        targets = None
    else:
        targets = np.ascontiguousarray(targets).reshape(bv.shape[0], len(pinned), 3)
    g = np.asarray(scene.get("gravity", (0.0, -9.81, 0.0)), np.float64).reshape(3)
    if not (np.isfinite(x).all() and np.isfinite(bv).all() and all(math.isfinite(v) for v in s.values())):
        raise ValueError("newton_ref scene: non-finite input")
    if s["fps"] <= 0.0 or s["thickness"] <= 0.0 or s["density"] <= 0.0:
        raise ValueError("newton_ref scene: fps, thickness and density must be > 0")
    raw = scene.get("face_layers")
    layers = np.ascontiguousarray(np.ones(len(f)) if raw is None else raw, np.float32).reshape(-1)
    if layers.shape != (len(f),):
        raise ValueError(f"newton_ref scene: face_layers must have one value per face ({len(f)}), "
                         f"got {layers.shape[0]}")
    if not (np.isfinite(layers).all() and layers.min() >= 1.0):
        raise ValueError("newton_ref scene: face_layers must be finite and >= 1")
    s.update(garment_positions=x, garment_rest_positions=rest, garment_faces=f, body_faces=bf,
             body_vertices=bv, pinned=pinned, pin_targets=targets, gravity=tuple(float(v) for v in g),
             face_layers=layers)
    return s


def layered_masses(rest: np.ndarray, faces: np.ndarray, layers: np.ndarray, density: float) -> np.ndarray:
    """Lumped vertex masses [kg]: a third of each face's rest area times its layers times
    ``density``, float64 (V,) (``sim.cloth.model.lumped_areas`` times the density)."""
    r = np.asarray(rest, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    area = 0.5 * np.linalg.norm(np.cross(r[f[:, 1]] - r[f[:, 0]], r[f[:, 2]] - r[f[:, 0]]), axis=1)
    out = np.zeros(len(r))
    np.add.at(out, f.reshape(-1), np.repeat(density * area * np.asarray(layers, np.float64) / 3.0, 3))
    return out


def hinge_layers(faces: np.ndarray, layers: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Per Newton edge ``(o0, o1, a, b)``: the mean layers of the faces that hold the edge
    ``a``-``b`` (one face on a boundary edge), float64 (E,)."""
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    e = np.asarray(edges, np.int64).reshape(-1, 4)
    n = int(max(f.max(), e[:, 2:].max())) + 1
    ends = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    keys = np.minimum(ends[:, 0], ends[:, 1]) * n + np.maximum(ends[:, 0], ends[:, 1])
    face_layer = np.tile(np.asarray(layers, np.float64), 3)
    order = np.argsort(keys, kind="stable")
    uniq, start, count = np.unique(keys[order], return_index=True, return_counts=True)
    sums = np.add.reduceat(face_layer[order], start)
    want = np.minimum(e[:, 2], e[:, 3]) * n + np.maximum(e[:, 2], e[:, 3])
    at = np.searchsorted(uniq, want)
    if (at >= len(uniq)).any() or (uniq[np.minimum(at, len(uniq) - 1)] != want).any():
        raise ValueError("newton_ref: an edge of Newton's model is no edge of the garment's faces")
    return sums[at] / count[at]


def bending_edge_stiffness(rest: np.ndarray, edges: np.ndarray, k_b: float) -> np.ndarray:
    """Newton ``edge_ke`` per edge so that edge_ke·|e| = our k_e = 3·k_b·|e|²/(A₁+A₂).

    ``edges``: Newton's (E, 4) ``edge_indices`` (o0, o1, a, b), -1 for a missing opposite vertex.
    """
    e = np.asarray(edges, np.int64).reshape(-1, 4)
    out = np.zeros(len(e), np.float64)
    inner = (e[:, 0] >= 0) & (e[:, 1] >= 0)
    o0, o1, a, b = (rest[e[inner, k]].astype(np.float64) for k in range(4))
    area1 = 0.5 * np.linalg.norm(np.cross(a - o0, b - o0), axis=1)
    area2 = 0.5 * np.linalg.norm(np.cross(a - o1, b - o1), axis=1)
    length = np.linalg.norm(b - a, axis=1)
    denom = np.maximum(area1 + area2, 1e-20)
    out[inner] = 3.0 * k_b * length / denom
    return out


def build_model(newton, sc: dict, dev, contact_stiffness: float, body_contact_gap: float):
    """Newton's model of the scene ``sc`` (``validate_scene``) on ``dev``, with the per-edge
    bending, the fabric layers, the pins and the contact material of the module docstring:
    (model, the body's ``newton.Mesh``, per-edge ``edge_ke``, lumped masses [kg])."""
    bv = sc["body_vertices"]
    rest, faces = sc["garment_rest_positions"], sc["garment_faces"]
    mu, lam, beta = sc["mu"], sc["lam"], sc["damping"]
    builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=sc["gravity"])
    builder.add_cloth_mesh(
        pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0, 0.0, 0.0),
        vertices=rest.tolist(), indices=faces.reshape(-1).tolist(), density=sc["density"],
        tri_ke=mu, tri_ka=lam, tri_kd=beta * mu / 2.0, edge_ke=0.0, edge_kd=0.0,
        particle_radius=sc["thickness"])
    body_mesh = newton.Mesh(bv[0], sc["body_faces"].reshape(-1), compute_inertia=False)
    shape_cfg = newton.ModelBuilder.ShapeConfig(
        ke=contact_stiffness, kd=0.0, mu=sc["friction"], margin=0.0,
        has_shape_collision=False, has_particle_collision=True)
    body_shape = builder.add_shape_mesh(-1, mesh=body_mesh, cfg=shape_cfg)
    builder.color()
    model = builder.finalize(device=dev)
    if model.particle_count != len(rest) or model.tri_count != len(faces):
        raise RuntimeError(f"newton_ref: Newton's model has {model.particle_count} particles and "
                           f"{model.tri_count} triangles, the scene {len(rest)} and {len(faces)}")
    edge_ke, mass = set_layered_material(model, sc)
    pinned = sc["pinned"]
    if len(pinned):  # pinned particles are inactive, moved by the runner
        flags = model.particle_flags.numpy()
        flags[pinned] &= ~int(newton.ParticleFlags.ACTIVE)
        model.particle_flags.assign(flags)
    model.soft_contact_ke = contact_stiffness
    model.soft_contact_kd = 0.0
    model.soft_contact_mu = sc["friction"]
    # the body mesh deforms: its local AABB must cover every frame
    pad = body_contact_gap + sc["thickness"]
    lo = model.shape_collision_aabb_lower.numpy()
    hi = model.shape_collision_aabb_upper.numpy()
    lo[body_shape] = bv.reshape(-1, 3).min(axis=0) - pad
    hi[body_shape] = bv.reshape(-1, 3).max(axis=0) + pad
    model.shape_collision_aabb_lower.assign(lo)
    model.shape_collision_aabb_upper.assign(hi)
    return model, body_mesh, edge_ke, mass


def set_layered_material(model, sc: dict) -> tuple[np.ndarray, np.ndarray]:
    """Write the per-edge bending and damping, and the fabric layers' masses and membrane moduli,
    into a finalized model (module docstring): (per-edge ``edge_ke``, lumped masses [kg])."""
    rest, faces, layers = sc["garment_rest_positions"], sc["garment_faces"], sc["face_layers"]
    mu, lam, beta = sc["mu"], sc["lam"], sc["damping"]
    edges = model.edge_indices.numpy()
    edge_ke = bending_edge_stiffness(rest, edges, sc["bending"]) * hinge_layers(faces, layers, edges)
    props = model.edge_bending_properties.numpy()
    props[:, 0] = edge_ke
    props[:, 1] = beta * edge_ke
    model.edge_bending_properties.assign(props.astype(np.float32))
    mass = layered_masses(rest, faces, layers, sc["density"])
    model.particle_mass.assign(mass.astype(np.float32))
    model.particle_inv_mass.assign((1.0 / np.maximum(mass, 1e-30)).astype(np.float32))
    mats = model.tri_materials.numpy()
    mats[:, :3] = np.array([mu, lam, beta * mu / 2.0], np.float32) * layers[:, None]
    model.tri_materials.assign(mats)
    return edge_ke, mass


def frame_program(model, solver, pipeline, body_mesh, sc: dict, dev, substeps: int, self_contact: bool,
                  n_out: int):
    """``simulate()``, one output frame of ``substeps`` substeps (module docstring, "Per
    substep"), its frame index in a device counter so that a CUDA graph of it replays every
    frame; and the device buffer (n_out, V) it writes the frames into."""
    bv = sc["body_vertices"]
    fps, pinned = sc["fps"], sc["pinned"]
    h = 1.0 / (fps * substeps)
    wmesh = body_mesh.mesh  # the finalized wp.Mesh the contact kernels query
    contacts = pipeline.contacts()
    control = model.control()
    states = [model.state(), model.state()]
    for st in states:
        st.particle_q.assign(sc["garment_positions"])
        st.particle_qd.zero_()
    body_frames = wp.array(bv, dtype=wp.vec3, device=dev)
    counter = wp.array([1], dtype=wp.int32, device=dev)
    out = wp.zeros((n_out, len(sc["garment_positions"])), dtype=wp.vec3, device=dev)
    pin_idx = wp.array(pinned, dtype=wp.int32, device=dev) if len(pinned) else None
    pin_frames = (wp.array(sc["pin_targets"], dtype=wp.vec3, device=dev)
                  if (len(pinned) and sc["pin_targets"] is not None) else None)

    def simulate() -> None:
        s0, s1 = states
        if self_contact:
            solver.rebuild_bvh(s0)
        for s in range(substeps):
            alpha = (s + 1) / substeps
            wp.launch(_place_body_kernel, dim=bv.shape[1], inputs=[body_frames, counter, alpha, fps],
                      outputs=[wmesh.points, wmesh.velocities], device=dev)
            wmesh.refit()
            if pin_frames is not None:
                wp.launch(_place_pins_kernel, dim=len(pinned), inputs=[pin_frames, pin_idx, counter, alpha],
                          outputs=[s0.particle_q, s1.particle_q], device=dev)
            s0.clear_forces()
            pipeline.collide(s0, contacts)
            solver.step(s0, s1, control, contacts, h)
            s0, s1 = s1, s0
        if s0 is not states[0]:  # odd substep count: bring the result back to states[0]
            wp.copy(states[0].particle_q, s0.particle_q)
            wp.copy(states[0].particle_qd, s0.particle_qd)
        wp.launch(_record_kernel, dim=out.shape[1], inputs=[states[0].particle_q, counter], outputs=[out],
                  device=dev)
        wp.launch(_advance_kernel, dim=1, inputs=[counter], device=dev)

    return simulate, out


def play(simulate, n_out: int, use_graph: bool, dev, notes: list[str]) -> tuple[float, int, bool]:
    """Output frames 1 .. n_out-1: frame 1 eagerly, then (CUDA, ``use_graph``) a CUDA graph of one
    frame captured at frame 2 and replayed. (ms per frame over frames ``TIMED_FROM``.., NaN when
    there are none; frames timed; whether a graph ran)."""
    graph = None
    want_graph = bool(use_graph) and dev.is_cuda
    if use_graph and not dev.is_cuda:
        notes.append("use_graph ignored: CUDA graphs need a CUDA device")
    t0 = None
    for k in range(1, n_out):
        if k == TIMED_FROM:
            wp.synchronize_device(dev)
            t0 = time.perf_counter()
        if k == 1 or not want_graph:
            simulate()
            continue
        if graph is None:
            try:
                with wp.ScopedCapture(device=dev) as cap:
                    simulate()
                graph = cap.graph
            except Exception as e:  # reported in the notes: the run goes on in plain launches
                want_graph = False
                notes.append(f"graph capture failed, plain launches used: {type(e).__name__}: {e}")
                simulate()
                continue
        wp.capture_launch(graph)
    wp.synchronize_device(dev)
    timed = n_out - TIMED_FROM if n_out > TIMED_FROM else 0
    ms = 1000.0 * (time.perf_counter() - t0) / timed if timed > 0 and t0 is not None else float("nan")
    return ms, timed, graph is not None


def newton_params(sc: dict, edge_ke: np.ndarray, mass: np.ndarray, h: float, contact: dict) -> dict:
    """The Newton values the scene mapped to (module docstring), for the result."""
    mu, beta, layers = sc["mu"], sc["damping"], sc["face_layers"]
    inner = edge_ke > 0
    return {
        "tri_ke": mu, "tri_ka": sc["lam"], "tri_kd": beta * mu / 2.0,
        "edge_ke_mean": float(edge_ke[inner].mean()) if inner.any() else 0.0,
        "edge_kd_mean": float(beta * edge_ke[inner].mean()) if inner.any() else 0.0,
        "particle_radius": sc["thickness"], "soft_contact_ke": contact["contact_stiffness"],
        "soft_contact_kd": 0.0, "soft_contact_mu": sc["friction"],
        "soft_contact_gap": contact["body_contact_gap"],
        "friction_epsilon": contact["friction_epsilon"], "dt_substep": h,
        "membrane": "stable Neo-Hookean (Newton) against co-rotated linear (ours)",
        "face_layers": {"min": float(layers.min()), "max": float(layers.max()), "mean": float(layers.mean())},
        "mass_kg": float(mass.sum()),
    }


def run_newton_vbd(scene: dict, *, device: str, substeps: int, iterations: int, self_contact: bool,
                   use_graph: bool, frames: int | None = None, contact_stiffness: float = 1.0e5,
                   body_contact_gap: float = 0.05, self_contact_margin: float = 3.0e-3,
                   self_contact_gap: float = 3.0e-3, friction_epsilon: float = 1.0e-2) -> dict:
    """Simulate ``scene`` with Newton's ``SolverVBD``; see the module docstring for the mapping.

    Args:
        scene: see the module docstring.
        device: Warp device ("cpu", "cuda", "cuda:0").
        substeps, iterations: per output frame, and VBD iterations per substep.
        self_contact: Newton's particle self-contact (vertex-triangle + edge-edge, DAT).
        use_graph: capture one frame as a CUDA graph and replay it (CUDA only).
        frames: output frames including frame 0 (default: all T body frames).
        contact_stiffness: body (and self-) contact penalty [N/m] (our body contact's stiffness).
        body_contact_gap: body contact detection reach beyond the contact distance [m].
        self_contact_margin, self_contact_gap: Newton's interaction distance and extra detection
            reach [m] for self-contact.
        friction_epsilon: friction smoothing speed [m/s].

    Returns:
        ``positions`` (frames, V, 3) float32; ``ms_per_frame`` (mean over frames 3.., after one
        eager warm-up frame and the first graph launch, synchronised; NaN when fewer than 4
        frames); ``timed_frames``; ``graph`` (bool); ``newton_version``; ``warp_version``;
        ``device``; ``newton_params`` (the mapped values); ``notes`` (list of str).
    """
    import newton
    from newton.solvers import SolverVBD

    if substeps < 1 or iterations < 1:
        raise ValueError("substeps and iterations must be >= 1")
    sc = validate_scene(scene)
    bv = sc["body_vertices"]
    n_out = bv.shape[0] if frames is None else int(frames)
    if not 1 <= n_out <= bv.shape[0]:
        raise ValueError(f"frames must lie in 1..{bv.shape[0]} (body frames), got {frames}")
    notes: list[str] = []
    wp.init()
    dev = wp.get_device(device)
    with wp.ScopedDevice(dev):
        model, body_mesh, edge_ke, mass = build_model(newton, sc, dev, contact_stiffness, body_contact_gap)
        pipeline = newton.CollisionPipeline(model, soft_contact_gap=body_contact_gap)
        solver_kw: dict[str, Any] = dict(iterations=iterations, friction_epsilon=friction_epsilon)
        if self_contact:
            solver_kw.update(
                particle_enable_self_contact=True, particle_self_contact_margin=self_contact_margin,
                particle_self_contact_gap=self_contact_gap,
                particle_vertex_contact_buffer_size=VERTEX_CONTACT_BUFFER,
                particle_edge_contact_buffer_size=EDGE_CONTACT_BUFFER)
        solver = SolverVBD(model, **solver_kw)
        simulate, out = frame_program(model, solver, pipeline, body_mesh, sc, dev, substeps, self_contact,
                                      n_out)
        ms, timed, graph = play(simulate, n_out, use_graph, dev, notes)
        positions = out.numpy()
        positions[0] = sc["garment_positions"]
    fps = sc["fps"]
    speed = float(np.linalg.norm(np.diff(bv, axis=0), axis=2).max() * fps) if bv.shape[0] > 1 else 0.0
    contact = {"contact_stiffness": contact_stiffness, "body_contact_gap": body_contact_gap,
               "friction_epsilon": friction_epsilon}
    params = newton_params(sc, edge_ke, mass, 1.0 / (fps * substeps), contact)
    if self_contact:
        budget = DETECTIONS_PER_SUBSTEP * 0.5 * DAT_RELAXATION * (self_contact_margin + self_contact_gap) \
            * substeps * fps
        params.update(particle_self_contact_margin=self_contact_margin,
                      particle_self_contact_gap=self_contact_gap, self_contact_speed_budget_m_per_s=budget)
        notes.append(f"self-contact DAT caps cloth speed at about {budget:.2f} m/s "
                     f"(body's fastest vertex: {speed:.2f} m/s)")
    if not np.isfinite(positions).all():
        notes.append("non-finite positions in the result")
    return {
        "positions": positions, "ms_per_frame": ms, "timed_frames": timed, "graph": graph,
        "self_contact": bool(self_contact), "substeps": substeps, "iterations": iterations, "frames": n_out,
        "cloth_vertices": len(sc["garment_positions"]), "body_vertices": int(bv.shape[1]),
        "body_triangles": int(len(sc["body_faces"])), "body_max_vertex_speed_m_per_s": speed,
        "device": str(dev), "newton_version": newton.__version__, "warp_version": wp.config.version,
        "newton_params": params, "notes": notes,
    }


# --- a self-check: a sheet dropped onto a sphere ---------------------------------------------------

G = 9.81
DROP_FPS = 30.0
SPHERE_RADIUS = 0.2  # [m]
SHEET_HEIGHT = 0.3  # [m]: 0.1 m above the sphere's top


def drape_scene(frames: int, n: int = 10, size: float = 0.5) -> dict:
    """An ``n`` x ``n`` cotton-like sheet (``sim.garments.materials`` "cotton", a thicker contact
    offset for the coarse sheet) ``SHEET_HEIGHT`` above a static sphere, for ``frames`` frames."""
    s = np.linspace(-size / 2, size / 2, n, dtype=np.float32)
    xx, zz = np.meshgrid(s, s, indexing="ij")
    v = np.stack([xx.ravel(), np.full(n * n, SHEET_HEIGHT, np.float32), zz.ravel()], axis=1)
    f = [(i * n + j, i * n + j + 1, (i + 1) * n + j) for i in range(n - 1) for j in range(n - 1)]
    f += [((i + 1) * n + j, i * n + j + 1, (i + 1) * n + j + 1) for i in range(n - 1) for j in range(n - 1)]
    n_lat, n_lon = 16, 24
    sv = [(0.0, SPHERE_RADIUS, 0.0)]
    for i in range(1, n_lat):
        th = np.pi * i / n_lat
        sv += [(SPHERE_RADIUS * np.sin(th) * np.cos(2 * np.pi * j / n_lon), SPHERE_RADIUS * np.cos(th),
                SPHERE_RADIUS * np.sin(th) * np.sin(2 * np.pi * j / n_lon)) for j in range(n_lon)]
    sv.append((0.0, -SPHERE_RADIUS, 0.0))

    def ring(i, j):
        return 1 + (i - 1) * n_lon + j % n_lon

    sf = [(0, ring(1, j + 1), ring(1, j)) for j in range(n_lon)]
    sf += [(len(sv) - 1, ring(n_lat - 1, j), ring(n_lat - 1, j + 1)) for j in range(n_lon)]
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            a, b, c, d = ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)
            sf += [(a, b, c), (a, c, d)]
    sv = np.asarray(sv, np.float32)
    return {
        "garment_positions": v, "garment_rest_positions": v, "garment_faces": np.asarray(f, np.int32),
        "density": 0.15, "mu": 1.5e3, "lam": 6.0e2, "bending": 5e-6, "damping": 2e-3, "friction": 0.4,
        "thickness": 2e-3, "body_faces": np.asarray(sf, np.int32),
        "body_vertices": np.repeat(sv[None], frames, axis=0), "fps": DROP_FPS,
    }


def drape_figures(x: np.ndarray) -> dict:
    """What the drop should show: a free fall of g t^2 / 2 over its first 3 frames (before the
    sheet reaches the sphere), no vertex inside the sphere, the centre resting on its top, the
    edges hanging below the contact."""
    t = 3 / DROP_FPS
    drop = SHEET_HEIGHT - x[3, :, 1]
    centre = x[-1][np.argmin(np.abs(x[0, :, 0]) + np.abs(x[0, :, 2]))]
    return {"free_fall_drop_m": [float(drop.min()), float(drop.max())],
            "free_fall_expected_m": 0.5 * G * t * t,
            "min_radius_m": float(np.linalg.norm(x[-1], axis=1).min()), "centre_height_m": float(centre[1]),
            "lowest_m": float(x[-1, :, 1].min()), "finite": bool(np.isfinite(x).all())}


def drape_passes(fig: dict) -> bool:
    """Whether ``drape_figures`` show the drop they should: every vertex within 10 % of the free
    fall, none more than 2 mm inside the sphere, the centre on its top (within 2 cm above it),
    the edges 5 cm below it."""
    fall = fig["free_fall_expected_m"]
    return (fig["finite"] and all(math.isclose(d, fall, rel_tol=0.1) for d in fig["free_fall_drop_m"])
            and fig["min_radius_m"] > SPHERE_RADIUS - 2e-3
            and SPHERE_RADIUS - 2e-3 < fig["centre_height_m"] < SPHERE_RADIUS + 2e-2
            and fig["lowest_m"] < SPHERE_RADIUS - 0.05)


def main() -> None:
    from benchmarks.common import add_results_argument, machine, write_result

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=24)
    add_results_argument(ap)
    args = ap.parse_args()
    res = run_newton_vbd(drape_scene(args.frames), device=args.device, substeps=10, iterations=10,
                         self_contact=False, use_graph=args.device.startswith("cuda"))
    fig = drape_figures(res["positions"])
    fig.update(ms_per_frame=res["ms_per_frame"], graph=res["graph"])
    write_result(f"newton_drape_{args.device.split(':')[0]}", {
        "machine": machine(args.device), "newton_version": res["newton_version"],
        "sizes": {"cloth_vertices": res["cloth_vertices"], "frames": args.frames, "substeps": 10,
                  "iterations": 10}, "figures": fig}, args.results)
    raise SystemExit(0 if drape_passes(fig) else 1)


if __name__ == "__main__":
    main()
