"""SMPL / SMPL-H / SMPL-X model files: parity with ``smplx``, chumpy pickles read without
chumpy or code execution, and one-line errors for broken files.

The files are synthetic (``tests/smpl_synth.py``): official key layout and joint counts, a few
hundred vertices. ``smplx`` is a test-only reference (``pip install smplx --no-deps``); its
parity tests skip when it is absent.
"""

from __future__ import annotations

import io
import os
import pickle
import re
import sys
import zipfile

import numpy as np
import pytest

from sim.bodies import load_body
from sim.bodies.smpl_io import load_smpl_model, read_model_arrays
from sim.bodies.smpl_names import SMPLH_JOINT_NAMES, SMPLX_JOINT_NAMES
from sim.errors import WrinklesInputError
from sim.types import SMPL_JOINT_NAMES
from tests import smpl_synth

# float32 Warp kernels vs float32 torch (smplx) on O(1 m) coordinates: both round each step of
# a 20-joint chain at ~6e-8 relative, so agreement is ~1e-6 m; 1e-5 m is the required bound.
PARITY_ATOL = 1e-5
KINDS = ("smpl", "smplh", "smplx")
_MODEL_ARRAYS = ("v_template", "shapedirs", "posedirs", "j_regressor", "weights", "parents",
                 "faces", "rest_pose")


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    """One synthetic model per family, as .npz and as a chumpy-style .pkl."""
    d = tmp_path_factory.mktemp("smpl_models")
    for kind in KINDS:
        smpl_synth.write_model(d, kind, "npz")
        smpl_synth.write_model(d, kind, "pkl")
    return d


def _path(model_dir, kind: str, fmt: str) -> str:
    return os.path.join(model_dir, f"{kind.upper()}_NEUTRAL.{fmt}")


# --- smplx parity --------------------------------------------------------------------------
@pytest.fixture
def smplx_mod(monkeypatch):
    """``smplx`` with its extra-keypoint vertex ids moved into our small meshes (it indexes
    official vertex numbers up to 10k; those extra keypoints are not compared)."""
    smplx = pytest.importorskip(
        "smplx", reason="smplx not installed (test-only reference: pip install smplx --no-deps)")
    from smplx.vertex_ids import vertex_ids

    for fam in ("smplh", "smplx"):
        monkeypatch.setitem(vertex_ids, fam, {k: i for i, k in enumerate(vertex_ids[fam])})
    return smplx


def _random_motion(rng, T: int, n_joints: int, scale: float = 0.5):
    poses = (rng.normal(size=(T, n_joints, 3)) * scale).astype(np.float32)
    trans = rng.normal(scale=0.5, size=(T, 3)).astype(np.float32)
    return poses, trans


def _torch(a):
    import torch

    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))


def _check_parity(ours, out, J, what):
    v_ref = out.vertices.detach().numpy()
    j_ref = out.joints.detach().numpy()[:, :J]
    err_v = float(np.abs(ours.vertices - v_ref).max())
    err_j = float(np.abs(ours.joints - j_ref).max())
    print(f"{what}: max |dv| = {err_v:.2e} m, max |dJ| = {err_j:.2e} m")
    np.testing.assert_allclose(ours.vertices, v_ref, atol=PARITY_ATOL, rtol=0)
    np.testing.assert_allclose(ours.joints, j_ref, atol=PARITY_ATOL, rtol=0)


def test_smpl_parity_with_smplx(model_dir, smplx_mod):
    import torch
    from smplx.utils import Struct

    path = _path(model_dir, "smpl", "npz")
    body = load_smpl_model(path)
    assert body.kind == "smpl" and body.num_betas == 300
    rng = np.random.default_rng(10)
    T = 4
    poses, trans = _random_motion(rng, T, 24)
    betas = rng.normal(size=300).astype(np.float32)
    with np.load(path, allow_pickle=True) as z:  # smplx's SMPL reads only .pkl: hand it the arrays
        ref = smplx_mod.SMPL(model_path=path, data_struct=Struct(**dict(z)), num_betas=300,
                             batch_size=T)
    with torch.no_grad():
        out = ref(betas=_torch(np.tile(betas, (T, 1))), global_orient=_torch(poses[:, 0]),
                  body_pose=_torch(poses[:, 1:].reshape(T, -1)), transl=_torch(trans))
    _check_parity(body.pose(betas, poses, trans, device="cpu"), out, 24, "SMPL")


def test_smplh_parity_with_smplx(model_dir, smplx_mod):
    import torch

    path = _path(model_dir, "smplh", "npz")
    body = load_smpl_model(path, num_betas=10)  # smplx keeps 10 of the file's 16 (< 300)
    assert body.kind == "smplh" and body.num_betas == 10 and body.meta["file_num_betas"] == 16
    ref = smplx_mod.SMPLH(model_path=path, ext="npz", use_pca=False, flat_hand_mean=False,
                          num_betas=10, batch_size=3)
    rng = np.random.default_rng(11)
    T = 3
    poses, trans = _random_motion(rng, T, 52)
    betas = rng.normal(size=10).astype(np.float32)
    with torch.no_grad():
        out = ref(betas=_torch(np.tile(betas, (T, 1))), global_orient=_torch(poses[:, 0]),
                  body_pose=_torch(poses[:, 1:22].reshape(T, -1)),
                  left_hand_pose=_torch(poses[:, 22:37].reshape(T, -1)),
                  right_hand_pose=_torch(poses[:, 37:52].reshape(T, -1)), transl=_torch(trans))
    # smplx adds the mean hand pose to its hand inputs; our full poses are absolute
    _check_parity(body.pose(betas, poses + body.rest_pose, trans, device="cpu"), out, 52, "SMPL-H")

    # a 24-joint SMPL motion drives joints 0-21, the hands rest at their mean pose (smplx default)
    smpl_poses, trans = _random_motion(rng, T, 24)
    with torch.no_grad():
        out = ref(betas=_torch(np.tile(betas, (T, 1))), global_orient=_torch(smpl_poses[:, 0]),
                  body_pose=_torch(smpl_poses[:, 1:22].reshape(T, -1)),
                  left_hand_pose=torch.zeros(T, 45), right_hand_pose=torch.zeros(T, 45),
                  transl=_torch(trans))
    ours = body.pose(betas, smpl_poses, trans, device="cpu")
    _check_parity(ours, out, 52, "SMPL-H (SMPL motion)")


def test_smplx_parity_with_smplx(model_dir, smplx_mod):
    import torch

    path = _path(model_dir, "smplx", "npz")
    body = load_smpl_model(path)
    assert body.kind == "smplx" and body.num_betas == 300
    assert body.meta["expression_dirs"].shape == (body.num_vertices, 3, 100)
    T = 3
    ref = smplx_mod.SMPLX(model_path=path, ext="npz", use_pca=False, flat_hand_mean=False,
                          num_betas=300, num_expression_coeffs=100, batch_size=T)
    rng = np.random.default_rng(12)
    poses, trans = _random_motion(rng, T, 55)
    betas = rng.normal(size=300).astype(np.float32)
    with torch.no_grad():
        out = ref(betas=_torch(np.tile(betas, (T, 1))), global_orient=_torch(poses[:, 0]),
                  body_pose=_torch(poses[:, 1:22].reshape(T, -1)), jaw_pose=_torch(poses[:, 22]),
                  leye_pose=_torch(poses[:, 23]), reye_pose=_torch(poses[:, 24]),
                  left_hand_pose=_torch(poses[:, 25:40].reshape(T, -1)),
                  right_hand_pose=_torch(poses[:, 40:55].reshape(T, -1)),
                  expression=torch.zeros(T, 100), transl=_torch(trans))
    _check_parity(body.pose(betas, poses + body.rest_pose, trans, device="cpu"), out, 55, "SMPL-X")

    smpl_poses, trans = _random_motion(rng, T, 24)
    with torch.no_grad():
        out = ref(betas=_torch(np.tile(betas, (T, 1))), global_orient=_torch(smpl_poses[:, 0]),
                  body_pose=_torch(smpl_poses[:, 1:22].reshape(T, -1)),
                  **{k: torch.zeros(T, 3) for k in ("jaw_pose", "leye_pose", "reye_pose")},
                  left_hand_pose=torch.zeros(T, 45), right_hand_pose=torch.zeros(T, 45),
                  expression=torch.zeros(T, 100), transl=_torch(trans))
    ours = body.pose(betas, smpl_poses, trans, device="cpu")
    _check_parity(ours, out, 55, "SMPL-X (SMPL motion)")


# --- structure, names, both file formats ---------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
def test_chumpy_pkl_and_npz_load_identically(model_dir, kind):
    a = load_smpl_model(_path(model_dir, kind, "npz"))
    b = load_smpl_model(_path(model_dir, kind, "pkl"))
    for k in _MODEL_ARRAYS:
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert a.joint_names == b.joint_names and a.kind == b.kind == kind
    np.testing.assert_array_equal(a.body_joint_map, b.body_joint_map)


@pytest.mark.parametrize("protocol,style", [(0, "basic"), (2, "ops"), (0, "ops")])
def test_pickle_variants(tmp_path, protocol, style):
    """Protocol-0 pickles (copyreg._reconstructor) and chumpy expressions (add, Reshape,
    transpose) resolve to the same arrays; an npz whose shapedirs is a pickled chumpy object
    goes through the same restricted unpickler."""
    arrays = smpl_synth.make_model_arrays("smpl", num_betas=10, seed=3)
    ref = load_smpl_model(smpl_synth.write_npz(tmp_path / "ref.npz", arrays))
    pkl = load_smpl_model(smpl_synth.write_chumpy_pkl(tmp_path / "m.pkl", arrays,
                                                      protocol=protocol, style=style))
    obj = load_smpl_model(smpl_synth.write_npz(tmp_path / "obj.npz", arrays, compressed=True,
                                               object_members=("shapedirs",)))
    for k in _MODEL_ARRAYS:
        np.testing.assert_array_equal(getattr(pkl, k), getattr(ref, k), err_msg=k)
        np.testing.assert_array_equal(getattr(obj, k), getattr(ref, k), err_msg=k)


def _py2_str(b: bytes) -> bytes:
    """A Python-2 ``str`` in a protocol-2 pickle (SHORT_BINSTRING / BINSTRING)."""
    return b"U" + bytes([len(b)]) + b if len(b) < 256 else b"T" + len(b).to_bytes(4, "little") + b


def test_python2_opcodes():
    """The opcodes Python 2's cPickle wrote (byte strings, ``__builtin__``, NEWOBJ for chumpy),
    assembled by hand: ``{'x': ndarray, 'ch': Ch(x=<same array>, _dirty_vars=set())}``."""
    from sim.bodies.smpl_io import resolve, restricted_pickle_load

    a = np.arange(4, dtype=np.float64) * 0.5
    s = _py2_str
    data = (b"\x80\x02}q\x00(" + s(b"x")
            + b"cnumpy.core.multiarray\n_reconstruct\nq\x01cnumpy\nndarray\nq\x02K\x00\x85"
            + s(b"b")
            + b"\x87Rq\x03(K\x01K\x04\x85cnumpy\ndtype\n" + s(b"f8") + b"K\x00K\x01\x87R(K\x03"
            + s(b"<") + b"NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tb\x89" + s(a.tobytes()) + b"tb"
            + s(b"ch") + b"cchumpy.ch\nCh\n)\x81}(" + s(b"x") + b"h\x03" + s(b"_dirty_vars")
            + b"c__builtin__\nset\n]\x85Rub" + b"u.")
    d = restricted_pickle_load(io.BytesIO(data))
    np.testing.assert_array_equal(d["x"], a)
    np.testing.assert_array_equal(resolve(d["ch"]), a)


def test_no_chumpy_or_scipy_needed(model_dir):
    """Reading leaves no chumpy module behind and builds plain numpy arrays."""
    arrs = read_model_arrays(_path(model_dir, "smpl", "pkl"))
    assert "chumpy" not in sys.modules
    assert all(type(v) is np.ndarray for v in arrs.values())
    assert arrs["J_regressor"].shape == (24, arrs["v_template"].shape[0])


def test_joint_names_maps_and_rest_pose(model_dir):
    smpl, smplh, smplx_ = (load_smpl_model(_path(model_dir, k, "pkl")) for k in KINDS)
    assert smpl.joint_names == SMPL_JOINT_NAMES
    np.testing.assert_array_equal(smpl.body_joint_map, np.arange(24))
    np.testing.assert_array_equal(smpl.rest_pose, 0)
    assert smplh.joint_names == SMPLH_JOINT_NAMES and smplx_.joint_names == SMPLX_JOINT_NAMES
    for b in (smplh, smplx_):
        np.testing.assert_array_equal(b.body_joint_map, [*range(22), -1, -1])
        np.testing.assert_array_equal(b.rest_pose[:22], 0)
    np.testing.assert_array_equal(smplx_.rest_pose[22:25], 0)  # jaw and eyes
    arrs = read_model_arrays(_path(model_dir, "smplx", "npz"))
    for sl, key in ((slice(25, 40), "hands_meanl"), (slice(40, 55), "hands_meanr")):
        np.testing.assert_array_equal(smplx_.rest_pose[sl].ravel(), arrs[key].astype(np.float32))
    np.testing.assert_array_equal(smplh.parents[22:25], [20, 22, 23])
    np.testing.assert_array_equal(smplx_.parents[22:25], [15, 15, 15])
    try:  # the names are smplx's own, where it is installed
        from smplx.joint_names import JOINT_NAMES
    except ImportError:
        return
    assert SMPLX_JOINT_NAMES == tuple(JOINT_NAMES[:55])
    assert SMPLH_JOINT_NAMES == tuple(JOINT_NAMES[:22] + JOINT_NAMES[25:55])


def test_load_body_and_num_betas(model_dir):
    body = load_body(_path(model_dir, "smplx", "pkl"))
    assert body.kind == "smplx" and body.name == "SMPLX_NEUTRAL"
    small = load_smpl_model(_path(model_dir, "smplx", "npz"), num_betas=10)
    np.testing.assert_array_equal(small.shapedirs, body.shapedirs[:, :, :10])
    for bad in (0, 301, 2.5):
        with pytest.raises(WrinklesInputError, match=r"SMPLX_NEUTRAL\.npz.*num_betas"):
            load_smpl_model(_path(model_dir, "smplx", "npz"), num_betas=bad)


# --- restricted unpickler ------------------------------------------------------------------
def _evil_pickle(module: str, name: str, marker) -> bytes:
    """A protocol-0 pickle that calls ``module.name('touch <marker>')`` on an unsafe load."""
    return f"(dp0\nS'weights'\np1\nc{module}\n{name}\n(S'touch {marker}'\ntR.".encode()


@pytest.mark.parametrize("module,name", [("os", "system"), ("posix", "system"),
                                         ("subprocess", "call"), ("builtins", "eval"),
                                         ("numpy", "load"), ("copy_reg", "_reconstructor_evil")])
def test_unpickler_refuses_code(tmp_path, module, name):
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pkl"
    path.write_bytes(_evil_pickle(module, name, marker))
    with pytest.raises(WrinklesInputError, match=rf"evil\.pkl.*{module}\.{name}"):
        load_smpl_model(path)
    assert not marker.exists()


def test_unpickler_refuses_reduce_exploit(tmp_path):
    """A pickle made by ``__reduce__`` (the usual exploit) and one hidden in an npz member."""
    marker = tmp_path / "pwned"

    class Exploit:
        def __reduce__(self):
            return os.system, (f"touch {marker}",)

    path = tmp_path / "reduce.pkl"
    path.write_bytes(pickle.dumps({"v_template": Exploit()}, protocol=2))
    with pytest.raises(WrinklesInputError, match=r"reduce\.pkl.*system"):
        load_smpl_model(path)
    # a weights.npy whose object payload is the exploit
    arrays = smpl_synth.make_model_arrays("smpl", num_betas=2, verts_per_joint=1)
    npz = tmp_path / "evil.npz"
    smpl_synth.write_npz(npz, arrays)
    hdr = np.lib.format.header_data_from_array_1_0(np.empty((), dtype=object))
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, hdr)
    buf.write(pickle.dumps(Exploit(), protocol=3))
    with zipfile.ZipFile(npz) as src, zipfile.ZipFile(tmp_path / "evil2.npz", "w") as dst:
        for item in src.namelist():
            dst.writestr(item, buf.getvalue() if item == "weights.npy" else src.read(item))
    with pytest.raises(WrinklesInputError, match=r"evil2\.npz.*weights.*system"):
        load_smpl_model(tmp_path / "evil2.npz")
    assert not marker.exists()


# --- broken files --------------------------------------------------------------------------
def _broken(tmp_path, name: str, **changes) -> str:
    arrays = smpl_synth.make_model_arrays("smpl", num_betas=4, verts_per_joint=2, seed=5)
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = v(arrays) if callable(v) else v
    path = tmp_path / name
    if name.endswith(".npz"):
        return smpl_synth.write_npz(path, arrays)
    return smpl_synth.write_chumpy_pkl(path, arrays)


def _nan_template(a):
    vt = a["v_template"].copy()
    vt[3, 1] = np.nan
    return vt


@pytest.mark.parametrize("fmt", ["npz", "pkl"])
@pytest.mark.parametrize("change,match", [
    ({"weights": None}, "missing weights"),
    ({"J_regressor": lambda a: a["J_regressor"][:, :-1]}, "J_regressor must have shape"),
    ({"v_template": _nan_template}, "v_template contains NaN"),
    ({"posedirs": lambda a: a["posedirs"][:, :, :-9]}, "posedirs must have shape"),
    ({"kintree_table": lambda a: a["kintree_table"][:, :-1]}, "kintree_table"),
    ({"weights": lambda a: a["weights"][:, :16]}, "16 joints"),
    ({"f": lambda a: a["f"] + 10_000}, "f indexes vertices"),
])
def test_bad_arrays(tmp_path, fmt, change, match):
    path = _broken(tmp_path, f"broken_model.{fmt}", **change)
    with pytest.raises(WrinklesInputError, match=rf"broken_model\.{fmt}: .*{match}") as info:
        load_smpl_model(path)
    assert "\n" not in str(info.value)


def test_bad_files(tmp_path):
    good = _broken(tmp_path, "good.npz")
    data = open(good, "rb").read()
    cases = {
        "truncated.npz": data[: len(data) // 2],
        "notes.pkl": b"These are not the droids you are looking for.\n",
        "empty.pkl": b"",
        "list.pkl": pickle.dumps([1, 2, 3], protocol=2),
        "model.obj": data,
        "garbage.npz": b"PK\x03\x04" + bytes(200),
    }
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(WrinklesInputError, match=re.escape(f"{name}: ")) as info:
            load_smpl_model(tmp_path / name)
        assert "\n" not in str(info.value), name
    with pytest.raises(WrinklesInputError, match="missing.npz: no such model file"):
        load_smpl_model(tmp_path / "missing.npz")
