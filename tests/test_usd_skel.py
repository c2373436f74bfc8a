"""The body as a UsdSkel rig: UsdSkel's own skinning of what we write equals our LBS.

The reference is ``BodyModel.pose`` (Warp LBS, what the simulator uses); the skinned points are
UsdSkel's (``UsdSkel.Cache`` / ``SkinningQuery.ComputeSkinnedPoints``, blend shapes first
through ``BlendShapeQuery``), so a stage that another USD application poses differently from
our bodies fails here.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdSkel

from sim.bodies import load_body
from sim.motions import procedural_motion
from sim.skinning.lbs import lbs_reference
from sim.types import SMPL_JOINT_NAMES
from tests import smpl_synth
from tests.conftest import random_body
from usd_io import (
    BODY_PATH,
    SKEL_BODY_PATH,
    GarmentTrack,
    read_stage,
    validate_stage,
    validation_report,
    write_stage,
)
from usd_io.skel import lbs_vertices, pose_shapes, rig_error, rig_fits

FPS = 30.0
#: UsdSkel (double-precision transforms from float32 quaternions) against our float32 LBS.
SKIN_ATOL = 1e-5


@pytest.fixture(scope="module")
def walk():
    """The default body, shaped, walking for 8 frames: (model, betas, frames)."""
    body = load_body()
    betas = np.zeros(body.num_betas, np.float32)
    betas[:3] = [0.8, -0.5, 0.3]
    motion = procedural_motion("walk", duration=8 / FPS, fps=FPS)
    return body, betas, body.pose_motion(motion, betas, device="cpu")


def usdskel_points(path: Path, mesh_path: str) -> tuple[np.ndarray, int]:
    """UsdSkel's skinned points of the mesh at every time code, (T, V, 3), and the number of
    blend shapes it applied."""
    stage = Usd.Stage.Open(str(path))
    mesh = stage.GetPrimAtPath(mesh_path)
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root.Find(mesh), Usd.PrimDefaultPredicate)
    skinning = cache.GetSkinningQuery(mesh)
    skel = cache.GetSkelQuery(UsdSkel.BindingAPI(mesh).GetInheritedSkeleton())
    n_shapes = 0
    out = []
    for code in range(int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode()) + 1):
        t = Usd.TimeCode(code)
        points = UsdGeom.Mesh(mesh).GetPointsAttr().Get(t)
        if skinning.HasBlendShapes():
            query = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(mesh))
            n_shapes = query.GetNumBlendShapes()
            weights = skinning.GetBlendShapeMapper().Remap(
                skel.GetAnimQuery().ComputeBlendShapeWeights(t))
            sub = query.ComputeSubShapeWeights(weights)
            assert query.ComputeDeformedPoints(*sub, query.ComputeBlendShapePointIndices(),
                                               query.ComputeSubShapePointOffsets(), points)
        assert skinning.ComputeSkinnedPoints(skel.ComputeSkinningTransforms(t), points, t)
        out.append(np.asarray(points, np.float32))
    return np.stack(out), n_shapes


@pytest.mark.parametrize("suffix", [".usdc", ".usda", ".usdz"])
def test_usdskel_skins_the_default_body_as_our_lbs(tmp_path, walk, suffix):
    body, betas, frames = walk
    path = write_stage(tmp_path / f"walk{suffix}", body=frames, fps=FPS, rig=body.rig(betas))
    skinned, n_shapes = usdskel_points(path, SKEL_BODY_PATH)
    assert n_shapes == 0  # the default body has no pose correctives
    assert np.abs(frames.vertices[-1] - frames.vertices[0]).max() > 0.1  # it does walk
    np.testing.assert_allclose(skinned, frames.vertices, atol=SKIN_ATOL)
    data = read_stage(path)
    assert data.body.path == SKEL_BODY_PATH
    np.testing.assert_allclose(data.body.points, frames.vertices, atol=SKIN_ATOL)
    np.testing.assert_allclose(data.joints, frames.joints, atol=SKIN_ATOL)
    np.testing.assert_array_equal(data.body.faces, frames.faces)
    report = validation_report(path)
    assert report.errors == [] and report.warnings == []


@pytest.mark.parametrize("kind", ["smpl", "smplx"])
def test_pose_correctives_are_blend_shapes_with_weights_in_unit_range(tmp_path, kind):
    """SMPL's pose blend shapes as UsdSkel blend shapes: rotations past 90 degrees (pose-feature
    entries below -1) included; every weight stays in [0, 1], which Blender clamps to."""
    if kind == "smpl":
        body = random_body(300, seed=4)
    else:
        body = load_body(smpl_synth.write_model(tmp_path, "smplx", "npz"))
    rng = np.random.default_rng(5)
    T = 5
    poses = rng.normal(scale=1.2, size=(T, 24, 3)).astype(np.float32)
    trans = rng.normal(scale=0.5, size=(T, 3)).astype(np.float32)
    betas = rng.normal(size=4).astype(np.float32)
    frames = body.pose(betas, poses, trans, device="cpu")
    path = write_stage(tmp_path / "posed.usdc", body=frames, fps=FPS, rig=body.rig(betas))
    skinned, n_shapes = usdskel_points(path, SKEL_BODY_PATH)
    assert n_shapes == 15 * (body.num_joints - 1)  # 3 diagonal + 2 x 6 off-diagonal per joint
    np.testing.assert_allclose(skinned, frames.vertices, atol=SKIN_ATOL)
    stage = Usd.Stage.Open(str(path))  # held: a prim of a released stage is invalid
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/World/BodyRig/Animation"))
    weights = np.stack([np.asarray(anim.GetBlendShapeWeightsAttr().Get(k)) for k in range(T)])
    assert weights.min() >= 0.0 and weights.max() <= 1.0
    names = [s.name for s in pose_shapes(body.joint_names)]
    diag = weights[:, [i for i, n in enumerate(names) if not n.endswith(("_pos", "_neg"))]]
    assert diag.max() > 0.5  # a rotation past 90 degrees: R_ii - 1 < -1, weight -f / 2 > 0.5
    assert validate_stage(path) == []


def test_lbs_of_the_rig_is_the_body_models(walk):
    """``BodyModel.rig`` + ``lbs_vertices`` reproduce the numpy SMPL reference, correctives too."""
    body = random_body(200, seed=2)
    rng = np.random.default_rng(1)
    poses = rng.normal(scale=0.5, size=(3, 24, 3)).astype(np.float32)
    trans = rng.normal(size=(3, 3)).astype(np.float32)
    betas = rng.normal(size=8).astype(np.float32)
    frames = body.pose(betas, poses, trans, device="cpu")
    ref, _ = lbs_reference(body, betas, poses, trans)
    rig = body.rig(betas)
    np.testing.assert_allclose(lbs_vertices(rig, frames.transforms), ref, atol=1e-5)
    dense = np.zeros((rig.num_vertices, rig.num_joints))
    rows = np.repeat(np.arange(rig.num_vertices), rig.weight_indices.shape[1])
    np.add.at(dense, (rows, rig.weight_indices.reshape(-1)), rig.weight_values.reshape(-1))
    np.testing.assert_array_equal(dense.astype(np.float32), body.weights)
    np.testing.assert_array_equal(rig.rest_vertices, body.rest_mesh(betas))
    assert rig.pose_blend_shapes.shape == (207, rig.num_vertices, 3)
    assert load_body().rig().pose_blend_shapes is None


def test_rig_layout(tmp_path, walk):
    """What DCCs read: joint paths by SMPL names, bind = world rest, rest = local rest,
    time-sampled joint animation, the skin primvars and the SkelRoot's posed extent."""
    body, betas, frames = walk
    rig = body.rig(betas)
    stage = Usd.Stage.Open(str(write_stage(tmp_path / "walk.usdc", body=frames, fps=FPS,
                                           rig=rig)))
    assert not stage.GetPrimAtPath(BODY_PATH) and not stage.GetPrimAtPath("/World/BodyJoints")
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/World/BodyRig/Skeleton"))
    joints = list(skel.GetJointsAttr().Get())
    assert joints[:3] == ["pelvis", "pelvis/left_hip", "pelvis/right_hip"]
    assert joints[23] == "pelvis/spine1/spine2/spine3/right_collar/right_shoulder/right_elbow/" \
                        "right_wrist/right_hand"
    assert list(skel.GetJointNamesAttr().Get()) == list(SMPL_JOINT_NAMES)
    bind = np.asarray(skel.GetBindTransformsAttr().Get())
    np.testing.assert_allclose(bind[:, 3, :3], rig.rest_joints, atol=1e-7)
    np.testing.assert_array_equal(bind[:, :3, :3], np.broadcast_to(np.eye(3), (24, 3, 3)))
    rest = np.asarray(skel.GetRestTransformsAttr().Get())
    np.testing.assert_allclose(rest[4, 3, :3], rig.rest_joints[4] - rig.rest_joints[1], atol=1e-7)
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/World/BodyRig/Animation"))
    assert anim.GetRotationsAttr().GetNumTimeSamples() == frames.num_frames
    assert anim.GetTranslationsAttr().GetNumTimeSamples() == frames.num_frames
    quats = np.stack([np.asarray(anim.GetRotationsAttr().Get(k)) for k in range(frames.num_frames)])
    assert (np.sum(quats[1:] * quats[:-1], axis=-1) > 0).all()  # no sign flips between frames
    root_t = np.asarray(anim.GetTranslationsAttr().Get(3))[0]
    np.testing.assert_allclose(root_t, frames.joints[3, 0], atol=1e-6)
    mesh = stage.GetPrimAtPath(SKEL_BODY_PATH)
    binding = UsdSkel.BindingAPI(mesh)
    assert binding.GetSkeletonRel().GetTargets() == [skel.GetPath()]
    assert binding.GetJointIndicesPrimvar().GetElementSize() == rig.weight_indices.shape[1]
    assert binding.GetGeomBindTransformAttr().Get() == Gf.Matrix4d(1.0)
    np.testing.assert_array_equal(np.asarray(UsdGeom.Mesh(mesh).GetPointsAttr().Get()),
                                  rig.rest_vertices)
    ext = np.asarray(UsdGeom.Boundable(stage.GetPrimAtPath("/World/BodyRig")).GetExtentAttr().Get(5))
    np.testing.assert_array_equal(ext, [frames.vertices[5].min(0), frames.vertices[5].max(0)])


def test_points_on_request_and_without_a_rig(tmp_path, walk):
    body, betas, frames = walk
    for path, kw in ((tmp_path / "asked.usdc", {"rig": body.rig(betas), "body_as": "points"}),
                     (tmp_path / "norig.usdc", {})):
        write_stage(path, body=frames, fps=FPS, **kw)
        data = read_stage(path)
        assert data.body.path == BODY_PATH
        np.testing.assert_array_equal(data.body.points, frames.vertices)
        assert not Usd.Stage.Open(str(path)).GetPrimAtPath("/World/BodyRig")


def test_a_rig_that_is_not_the_bodys_is_refused(tmp_path, walk):
    body, betas, frames = walk
    with pytest.raises(ValueError, match=r"the rig's bones differ from the body's by 0.0\d+ m at frame"):
        write_stage(tmp_path / "a.usdc", body=frames, fps=FPS, rig=body.rig(None))
    with pytest.raises(ValueError, match=r"body_as='skel' needs the body's rig"):
        write_stage(tmp_path / "a.usdc", body=frames, fps=FPS, body_as="skel")
    with pytest.raises(ValueError, match=r"body_as must be one of"):
        write_stage(tmp_path / "a.usdc", body=frames, fps=FPS, body_as="mesh")
    other = random_body(300)
    with pytest.raises(ValueError, match=r"rig has 300 vertices"):
        write_stage(tmp_path / "a.usdc", body=frames, fps=FPS, rig=other.rig())
    assert list(tmp_path.iterdir()) == []


def test_a_body_that_changes_shape_does_not_fit_one_rig(walk):
    """Frames posed with other shape coefficients in the middle of the clip (a settle that
    morphs the body) are found at every frame, not only at the sampled ones."""
    body, betas, frames = walk
    other = body.pose(np.zeros_like(betas), np.zeros((frames.num_frames, 24, 3)), device="cpu")
    mixed = dataclasses.replace(frames, transforms=frames.transforms.copy())
    mixed.transforms[2, :, :3, 3] = other.transforms[2, :, :3, 3]  # frame 2 of 0..7: not sampled
    rig = body.rig(betas)
    assert rig_fits(rig, frames)
    assert not rig_fits(rig, mixed)
    err, frame, what = rig_error(rig, mixed)
    assert (frame, what) == (2, "bones") and err > 1e-3


def test_rig_with_garments_keeps_garments_time_sampled(tmp_path, walk):
    body, betas, frames = walk
    rng = np.random.default_rng(0)
    g = rng.normal(size=(frames.num_frames, 30, 3)).astype(np.float32)
    track = GarmentTrack("shirt", g, np.arange(30, dtype=np.int32).reshape(10, 3))
    path = write_stage(tmp_path / "dressed.usda", body=frames, fps=FPS, garments=[track],
                       rig=body.rig(betas))
    data = read_stage(path)
    assert list(data.meshes) == [SKEL_BODY_PATH, "/World/Garments/shirt"]
    np.testing.assert_array_equal(data.garments["shirt"].points, g)
    assert validate_stage(path) == []


def test_a_rig_is_smaller_than_a_point_cache(tmp_path, walk):
    body, betas, frames = walk
    skel = write_stage(tmp_path / "skel.usdc", body=frames, fps=FPS, rig=body.rig(betas))
    points = write_stage(tmp_path / "points.usdc", body=frames, fps=FPS)
    # 8 frames: the rig holds the mesh once plus its weights; the cache the mesh 8 times
    assert os.path.getsize(skel) < 0.6 * os.path.getsize(points)


def test_validation_catches_a_broken_skin(tmp_path, walk):
    body, betas, frames = walk
    path = write_stage(tmp_path / "walk.usda", body=frames, fps=FPS, rig=body.rig(betas))
    stage = Usd.Stage.Open(str(path))
    pv = UsdSkel.BindingAPI(stage.GetPrimAtPath(SKEL_BODY_PATH)).GetJointIndicesPrimvar()
    idx = np.array(pv.Get())
    idx[7] = 99
    pv.Set(idx[:-4].tolist())
    stage.Save()
    errors = [e for e in validate_stage(path) if e.startswith("wrinkles:SkelBinding")]
    assert len(errors) == 3, errors
    assert "53388 joint indices for 53392 joint weights" in errors[0]
    assert "53388 joint indices for 13348 points x 4 influences" in errors[1]
    assert "joint indices outside [0, 24)" in errors[2]
