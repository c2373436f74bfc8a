"""The body as a ``UsdSkel`` rig: a skeleton, its animation and a skinned mesh.

Layout under ``/World`` (``<Body>`` is ``write_stage``'s ``body_name``)::

    /World/<Body>Rig                    SkelRoot, time-sampled extent of the posed body
    /World/<Body>Rig/Skeleton           Skeleton: joints (SMPL names as paths), bind and rest
                                        transforms, skel:animationSource -> Animation
    /World/<Body>Rig/Animation          SkelAnimation: time-sampled joint translations and
                                        rotations, pose blend-shape weights
    /World/<Body>Rig/<Body>             Mesh: rest points, joint indices / weights primvars,
                                        skel:geomBindTransform, skel:blendShapes
    /World/<Body>Rig/<Body>/<shape>     BlendShape: the pose correctives (bodies that have them)

UsdSkel's skinning is ours (``sim.skinning.lbs``): bind transforms are the world rest
transforms (identity rotation at each rest joint), so ``inverse(bind_j) * world_j`` is the
LBS matrix ``A_j``; joint-local transforms are ``inverse(world_parent) * world_j`` of
``BodyFrames.transforms``. SMPL's pose correctives are linear in the pose feature
``f = R_j - I`` (SMPL Eq. 9), so they are blend shapes weighted by its entries. Blender
clamps shape-key weights to [0, 1] on import, so each entry becomes shapes whose weights stay
there (``pose_shapes``): a diagonal entry (in [-2, 0]) one shape of offsets ``-2 d`` weighted
``-f / 2``; an off-diagonal entry (in [-1, 1]) a ``_pos`` shape ``d`` weighted ``max(f, 0)``
and a ``_neg`` shape ``-d`` weighted ``max(-f, 0)``. Their sum is ``f d`` at every pose.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pxr import Gf, Tf, Usd, UsdGeom, UsdSkel, Vt

from sim.rotations import matrix_to_quaternion
from sim.types import BodyFrames, BodyRig

SKELETON_NAME = "Skeleton"
ANIMATION_NAME = "Animation"
#: suffix of the SkelRoot's name after the body's (``/World/BodyRig``).
RIG_SUFFIX = "Rig"
#: largest difference [m] allowed between the rig's LBS and the body frames it is written
#: with: float32 skinning of metre-scale coordinates agrees to ~1e-6 m; a rig of other shape
#: coefficients or another body model differs by millimetres or more.
RIG_MATCH_TOL = 1e-4
#: frames of the body compared with the rig's skinning before writing (spread over the clip).
RIG_CHECK_FRAMES = 3


@dataclass(frozen=True)
class SkelPose:
    """Per-frame UsdSkel animation of a body, in the skeleton's joint order.

    Attributes:
        translations: joint-local translations [m], shape (T, J, 3), float32.
        rotations: joint-local rotations as quaternions (x, y, z, w) (``Vt.QuatfArray``'s
            layout), shape (T, J, 4), float32, continuous in time (no sign flips).
        features: SMPL's pose feature ``R_j - I`` per frame, shape (T, 9 (J - 1)), float64, or
            None for a rig without pose blend shapes.
    """

    translations: np.ndarray
    rotations: np.ndarray
    features: np.ndarray | None


@dataclass(frozen=True)
class PoseShape:
    """One blend shape of the pose correctives: offsets ``sign * scale * d`` of pose-feature
    entry ``feature``'s corrective ``d``, weight ``sign * f[feature] / scale`` where that is in
    [0, 1], else 0 or 1."""

    name: str
    feature: int
    sign: float
    scale: float


# ----------------------------------------------------------------------------- numpy side


def check_rig(rig: BodyRig, body: BodyFrames) -> BodyRig:
    """``rig`` with arrays as float32 / int32, checked against ``body``'s shapes and poses.

    Raises:
        ValueError: shapes that do not fit the body, bad parents or weights, or a rig that
            does not pose as ``body`` (``rig_error`` over ``RIG_MATCH_TOL``: a rig made with
            other shape coefficients or from another body model, or frames whose body changes
            shape).
    """
    out = rig_arrays(rig, body)
    err, frame, what = rig_error(out, body)
    if err > RIG_MATCH_TOL:
        raise ValueError(f"the rig's {what} differ from the body's by {err:.3g} m at frame {frame} "
                         f"(> {RIG_MATCH_TOL} m): a rig of other shape coefficients or another "
                         "body model, or a body that changes shape?")
    return out


def rig_fits(rig: BodyRig, body: BodyFrames) -> bool:
    """Whether ``rig`` poses as ``body`` within ``RIG_MATCH_TOL`` (shapes are checked:
    ``ValueError`` as ``rig_arrays``)."""
    return rig_error(rig_arrays(rig, body), body)[0] <= RIG_MATCH_TOL


def rig_arrays(rig: BodyRig, body: BodyFrames) -> BodyRig:
    """``rig`` with arrays as float32 / int32, its shapes checked against ``body``'s
    (``ValueError`` naming what does not fit)."""
    V, J = body.vertices.shape[1], body.transforms.shape[1]
    parents = np.asarray(rig.parents, np.int32).reshape(-1)
    rest_v = np.ascontiguousarray(rig.rest_vertices, np.float32)
    rest_j = np.ascontiguousarray(rig.rest_joints, np.float32)
    idx = np.ascontiguousarray(rig.weight_indices, np.int32)
    val = np.ascontiguousarray(rig.weight_values, np.float32)
    if rest_v.shape != (V, 3) or rest_j.shape != (J, 3) or parents.shape != (J,):
        raise ValueError(f"rig has {rest_v.shape[0]} vertices / {rest_j.shape[0]} joints / "
                         f"{parents.shape[0]} parents; the body has {V} vertices, {J} joints")
    if len(rig.joint_names) != J:
        raise ValueError(f"rig has {len(rig.joint_names)} joint names for {J} joints")
    if parents[0] != -1 or np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, J)):
        raise ValueError("rig parents must have the root first and each parent before its child")
    if idx.ndim != 2 or idx.shape[0] != V or val.shape != idx.shape:
        raise ValueError(f"rig weights must have shape ({V}, K), got indices {idx.shape}, "
                         f"values {val.shape}")
    if idx.min() < 0 or idx.max() >= J or not np.isfinite(val).all():
        raise ValueError(f"rig weight indices must lie in [0, {J}) and weights be finite")
    shapes = rig.pose_blend_shapes
    if shapes is not None:
        shapes = np.ascontiguousarray(shapes, np.float32)
        if shapes.shape != (9 * (J - 1), V, 3) or not np.isfinite(shapes).all():
            raise ValueError(f"rig pose_blend_shapes must be finite with shape "
                             f"({9 * (J - 1)}, {V}, 3), got {shapes.shape}")
    return BodyRig(rest_v, body.faces, tuple(rig.joint_names), parents, rest_j, idx, val, shapes)


def local_rotations(transforms: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """Each joint's rotation relative to its parent, ``R_parent^T R_j`` (the root's own),
    from world transforms (T, J, 4, 4); returns (T, J, 3, 3) float64."""
    R = np.asarray(transforms, np.float64)[..., :3, :3]
    local = R.copy()
    child = np.arange(1, R.shape[1])
    local[:, child] = np.swapaxes(R[:, parents[child]], -1, -2) @ R[:, child]
    return local


def pose_features(local: np.ndarray) -> np.ndarray:
    """SMPL's pose feature ``R_j - I`` of the non-root joints, (T, 9 (J - 1)) (SMPL Eq. 9)."""
    T = local.shape[0]
    return (local[:, 1:] - np.eye(3)).reshape(T, -1)


def lbs_vertices(rig: BodyRig, transforms: np.ndarray) -> np.ndarray:
    """The rig skinned by world joint transforms (T, J, 4, 4): (T, V, 3) float64 [m]."""
    G = np.asarray(transforms, np.float64)
    A = G.copy()
    A[..., :3, 3] -= np.einsum("tjab,jb->tja", G[..., :3, :3], rig.rest_joints.astype(np.float64))
    v = np.broadcast_to(rig.rest_vertices.astype(np.float64), (G.shape[0], rig.num_vertices, 3))
    if rig.pose_blend_shapes is not None:
        feat = pose_features(local_rotations(G, rig.parents))
        v = v + np.einsum("tp,pvk->tvk", feat, rig.pose_blend_shapes.astype(np.float64))
    M = np.einsum("vk,tvkab->tvab", rig.weight_values.astype(np.float64),
                  A[:, rig.weight_indices])
    return np.einsum("tvab,tvb->tva", M[..., :3, :3], v) + M[..., :3, 3]


def rig_error(rig: BodyRig, body: BodyFrames) -> tuple[float, int, str]:
    """How far the rig's pose is from ``body``: (largest difference [m], its frame, ``"bones"``
    or ``"vertices"``). Bones at every frame (each joint against its parent's frame moved by
    the rig's rest offset: a body whose shape changes over the clip fails there); skinned
    vertices at ``RIG_CHECK_FRAMES`` frames spread over the clip."""
    G = np.asarray(body.transforms, np.float64)
    rest = rig.rest_joints.astype(np.float64)
    child = np.arange(1, rig.num_joints)
    par = rig.parents[child]
    offsets = rest[child] - rest[par]
    pos, rot = G[..., :3, 3], G[..., :3, :3]
    bones = pos[:, par] + np.einsum("tjab,jb->tja", rot[:, par], offsets)
    bone_err = np.abs(bones - pos[:, child]).max(axis=(1, 2)) if child.size else np.zeros(1)
    T = G.shape[0]
    frames = np.unique(np.linspace(0, T - 1, RIG_CHECK_FRAMES).round().astype(int))
    vert_err = np.abs(lbs_vertices(rig, G[frames]) - body.vertices[frames]).max(axis=(1, 2))
    if bone_err.max() >= vert_err.max():
        return float(bone_err.max()), int(np.argmax(bone_err)), "bones"
    return float(vert_err.max()), int(frames[np.argmax(vert_err)]), "vertices"


def skel_pose(rig: BodyRig, transforms: np.ndarray) -> SkelPose:
    """The animation of world joint transforms (T, J, 4, 4) as UsdSkel wants it."""
    G = np.asarray(transforms, np.float64)
    local = local_rotations(G, rig.parents)
    q = matrix_to_quaternion(local)  # (T, J, 4) as (w, x, y, z)
    # one hemisphere per joint over time, so interpolation between frames takes the short way
    flips = np.cumsum(np.sum(q[1:] * q[:-1], axis=-1) < 0, axis=0) % 2
    q[1:] *= np.where(flips[..., None] == 1, -1.0, 1.0)
    rest = rig.rest_joints.astype(np.float64)
    offsets = rest - np.where(rig.parents[:, None] >= 0, rest[np.maximum(rig.parents, 0)], 0.0)
    translations = np.broadcast_to(offsets, (G.shape[0], *offsets.shape)).copy()
    translations[:, 0] = G[:, 0, :3, 3]  # the root: its world position (rest joint + trans)
    features = None if rig.pose_blend_shapes is None else pose_features(local)
    return SkelPose(translations.astype(np.float32),
                    np.ascontiguousarray(q[..., [1, 2, 3, 0]], dtype=np.float32), features)


# ----------------------------------------------------------------------------- authoring


def joint_paths(names: tuple[str, ...], parents: np.ndarray) -> list[str]:
    """UsdSkel joint tokens: each joint's path of names from the root (``pelvis/left_hip``),
    names made valid identifiers."""
    paths: list[str] = []
    for j, p in enumerate(parents):
        name = Tf.MakeValidIdentifier(names[j])
        paths.append(name if p < 0 else f"{paths[p]}/{name}")
    if len(set(paths)) != len(paths):
        raise ValueError(f"rig joint names are not unique as USD identifiers: {names}")
    return paths


def pose_shapes(names: tuple[str, ...]) -> list[PoseShape]:
    """The blend shapes of the pose correctives, weights in [0, 1] (module docstring):
    ``pose_<joint>_<r><c>`` for a diagonal entry of a non-root joint's feature,
    ``pose_<joint>_<r><c>_pos`` / ``_neg`` for an off-diagonal one."""
    out: list[PoseShape] = []
    for j, name in enumerate(names[1:]):
        base = f"pose_{Tf.MakeValidIdentifier(name)}"
        for r in range(3):
            for c in range(3):
                p = 9 * j + 3 * r + c
                if r == c:
                    out.append(PoseShape(f"{base}_{r}{c}", p, -1.0, 2.0))
                else:
                    out += [PoseShape(f"{base}_{r}{c}_pos", p, 1.0, 1.0),
                            PoseShape(f"{base}_{r}{c}_neg", p, -1.0, 1.0)]
    return out


def pose_shape_weights(shapes: list[PoseShape], features: np.ndarray) -> np.ndarray:
    """Weights (T, S) float32 of ``shapes`` at pose features (T, P)."""
    idx = np.array([s.feature for s in shapes], np.int64)
    factor = np.array([s.sign / s.scale for s in shapes])
    return np.clip(features[:, idx] * factor, 0.0, 1.0).astype(np.float32)


def _translation_matrices(t: np.ndarray) -> Vt.Matrix4dArray:
    """Pure translations in USD's row-vector layout (translation in the last row)."""
    m = np.tile(np.eye(4), (t.shape[0], 1, 1))
    m[:, 3, :3] = t
    return Vt.Matrix4dArray.FromNumpy(m)


@dataclass(frozen=True)
class SkelPrims:
    """What ``define_skel_body`` authored; ``mesh`` is the body mesh, ``samples`` per frame
    ``(attribute, values (T, ...), Vt array type)``."""

    mesh: UsdGeom.Mesh
    samples: list[tuple[Usd.Attribute, np.ndarray, Callable]]


def define_skel_body(stage: Usd.Stage, root_path: str, mesh_name: str, rig: BodyRig,
                     body: BodyFrames, define_mesh: Callable[[str], UsdGeom.Mesh]) -> SkelPrims:
    """The SkelRoot, Skeleton, SkelAnimation and bound mesh of ``rig`` posed as ``body``.

    Args:
        stage: the stage.
        root_path: the SkelRoot's path.
        mesh_name: the body mesh's prim name under it.
        rig: checked by ``check_rig``.
        body: its frames (``transforms``, ``vertices`` for the extents).
        define_mesh: ``define_mesh(path)`` defines the mesh (topology, material).

    Returns:
        The mesh and the time samples to author.
    """
    root = UsdSkel.Root.Define(stage, root_path)
    joints = joint_paths(rig.joint_names, rig.parents)
    skel = UsdSkel.Skeleton.Define(stage, f"{root_path}/{SKELETON_NAME}")
    skel.CreateJointsAttr(Vt.TokenArray(joints))
    skel.CreateJointNamesAttr(Vt.TokenArray(list(rig.joint_names)))
    rest = rig.rest_joints.astype(np.float64)
    skel.CreateBindTransformsAttr(_translation_matrices(rest))
    parent_rest = np.where(rig.parents[:, None] >= 0, rest[np.maximum(rig.parents, 0)], 0.0)
    skel.CreateRestTransformsAttr(_translation_matrices(rest - parent_rest))
    anim = UsdSkel.Animation.Define(stage, f"{root_path}/{ANIMATION_NAME}")
    anim.CreateJointsAttr(Vt.TokenArray(joints))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1.0, 1.0, 1.0)] * len(joints)))
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets(
        [anim.GetPath()])

    mesh = define_mesh(f"{root_path}/{mesh_name}")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(rig.rest_vertices))
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(
        np.stack([rig.rest_vertices.min(0), rig.rest_vertices.max(0)])))
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    k = int(rig.weight_indices.shape[1])
    binding.CreateJointIndicesPrimvar(False, k).Set(
        Vt.IntArray.FromNumpy(rig.weight_indices.reshape(-1)))
    binding.CreateJointWeightsPrimvar(False, k).Set(
        Vt.FloatArray.FromNumpy(rig.weight_values.reshape(-1)))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))

    pose = skel_pose(rig, body.transforms)
    extents = np.stack([body.vertices.min(axis=1), body.vertices.max(axis=1)], axis=1)
    samples: list[tuple[Usd.Attribute, np.ndarray, Callable]] = [
        (anim.CreateTranslationsAttr(), pose.translations, Vt.Vec3fArray.FromNumpy),
        (anim.CreateRotationsAttr(), pose.rotations, Vt.QuatfArray.FromNumpy),
        (root.CreateExtentAttr(), extents, Vt.Vec3fArray.FromNumpy),
    ]
    if rig.pose_blend_shapes is not None:
        shapes = _define_blend_shapes(stage, mesh, binding, rig.pose_blend_shapes,
                                      rig.joint_names)
        anim.CreateBlendShapesAttr(Vt.TokenArray([s.name for s in shapes]))
        samples.append((anim.CreateBlendShapeWeightsAttr(),
                        pose_shape_weights(shapes, pose.features), Vt.FloatArray.FromNumpy))
    return SkelPrims(mesh, samples)


def _define_blend_shapes(stage: Usd.Stage, mesh: UsdGeom.Mesh, binding: UsdSkel.BindingAPI,
                         correctives: np.ndarray, joint_names: tuple[str, ...]) -> list[PoseShape]:
    """A BlendShape under the mesh per ``pose_shapes`` entry whose corrective moves a vertex
    (holding only the vertices it moves, by ``pointIndices``, where that is fewer than all);
    returns the shapes defined."""
    kept, targets = [], []
    for shape in pose_shapes(joint_names):
        d = correctives[shape.feature]
        moved = np.nonzero(np.any(d != 0.0, axis=1))[0]
        if moved.size == 0:
            continue
        offsets = (np.float32(shape.sign * shape.scale) * d).astype(np.float32)
        bs = UsdSkel.BlendShape.Define(stage, mesh.GetPath().AppendChild(shape.name))
        if moved.size < d.shape[0]:
            bs.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(offsets[moved])))
            bs.CreatePointIndicesAttr(Vt.IntArray.FromNumpy(moved.astype(np.int32)))
        else:
            bs.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(offsets))
        kept.append(shape)
        targets.append(bs.GetPath())
    binding.CreateBlendShapesAttr(Vt.TokenArray([k.name for k in kept]))
    binding.CreateBlendShapeTargetsRel().SetTargets(targets)
    return kept


# ----------------------------------------------------------------------------- reading


def skinned_points(stage: Usd.Stage, mesh_prim: Usd.Prim,
                   times: list[Usd.TimeCode]) -> tuple[np.ndarray, np.ndarray] | None:
    """A skinned mesh's points posed by UsdSkel (blend shapes, then LBS) at each time, in its
    skeleton's space, and the skeleton's joint positions there.

    Returns:
        (points (T, V, 3) float32, joints (T, J, 3) float32), or None when ``mesh_prim`` is
        not bound to a skeleton under a SkelRoot.
    """
    root = UsdSkel.Root.Find(mesh_prim)
    if not root:
        return None
    cache = UsdSkel.Cache()
    cache.Populate(root, Usd.PrimDefaultPredicate)
    skinning = cache.GetSkinningQuery(mesh_prim)
    skel_prim = UsdSkel.BindingAPI(mesh_prim).GetInheritedSkeleton()
    if not (skinning and skel_prim):
        return None
    skel_query = cache.GetSkelQuery(skel_prim)
    blend = _blend_shape_state(skinning, skel_query, mesh_prim)
    rest = UsdGeom.Mesh(mesh_prim).GetPointsAttr()
    out, joints = [], []
    for t in times:
        points = rest.Get(t)
        if blend is not None:
            query, point_indices, offsets, mapper = blend
            weights = mapper.Remap(skel_query.GetAnimQuery().ComputeBlendShapeWeights(t)) \
                if skel_query.GetAnimQuery() else Vt.FloatArray(query.GetNumBlendShapes(), 0.0)
            sub = query.ComputeSubShapeWeights(weights)
            query.ComputeDeformedPoints(sub[0], sub[1], sub[2], point_indices, offsets, points)
        xforms = skel_query.ComputeSkinningTransforms(t)
        if not skinning.ComputeSkinnedPoints(xforms, points, t):
            return None
        out.append(np.asarray(points, np.float32))
        world = np.asarray(skel_query.ComputeJointSkelTransforms(t), np.float64)
        joints.append(world.reshape(-1, 4, 4)[:, 3, :3].astype(np.float32))
    return np.stack(out), np.stack(joints)


def _blend_shape_state(skinning: UsdSkel.SkinningQuery, skel_query: UsdSkel.SkeletonQuery,
                       mesh_prim: Usd.Prim) -> tuple | None:
    """(query, point indices, sub-shape offsets, animation -> mesh weight mapper), or None
    when the mesh has no blend shapes."""
    if not skinning.HasBlendShapes():
        return None
    query = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(mesh_prim))
    mapper = skinning.GetBlendShapeMapper()
    return query, query.ComputeBlendShapePointIndices(), query.ComputeSubShapePointOffsets(), mapper


def is_skinned(prim: Usd.Prim) -> bool:
    """The prim has UsdSkel's binding with a skeleton."""
    return prim.HasAPI(UsdSkel.BindingAPI) and bool(
        UsdSkel.BindingAPI(prim).GetInheritedSkeleton())


__all__ = ["ANIMATION_NAME", "RIG_SUFFIX", "SKELETON_NAME", "PoseShape", "SkelPose", "check_rig",
           "define_skel_body", "is_skinned", "joint_paths", "lbs_vertices", "pose_shape_weights",
           "pose_shapes", "rig_arrays", "rig_error", "rig_fits", "skel_pose", "skinned_points"]
