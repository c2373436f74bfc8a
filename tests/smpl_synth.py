"""Synthetic SMPL / SMPL-H / SMPL-X model files with the official STRUCTURE.

Not a human body: a few hundred vertices in clusters around a random skeleton. What is exact is
the layout the loaders see: key names, dtypes, ``kintree_table`` (root stored as 2**32 - 1),
joint counts, ``shapedirs``/``posedirs`` sizes, hand PCA components and means, SMPL-X
landmark arrays, so that ``smplx`` accepts the ``.npz`` files. ``write_chumpy_pkl`` writes a
pickle laid out like the Python-2 releases (chumpy ``Ch`` objects, ``scipy.sparse.csc``
``J_regressor``, ``numpy.core.multiarray._reconstruct`` with latin-1 string payloads) without
chumpy installed: fake ``chumpy`` modules are registered only while pickling.
"""

from __future__ import annotations

import contextlib
import io
import os
import pickle
import sys
import types

import numpy as np

from sim.bodies.smpl_names import official_parents

#: joints, pose-basis size and default shape columns per family (as the official files).
LAYOUT = {
    "smpl": {"joints": 24, "num_betas": 300},   # SMPL v1.1: 300 shape components
    "smplh": {"joints": 52, "num_betas": 16},   # AMASS SMPL-H: 16
    "smplx": {"joints": 55, "num_betas": 400},  # SMPL-X v1.1: 300 shape + 100 expression
}
ROOT_PARENT = 2**32 - 1  # how the official kintree_table stores the root's parent


def make_model_arrays(kind: str, *, num_betas: int | None = None, verts_per_joint: int = 6,
                      seed: int = 0) -> dict[str, np.ndarray]:
    """Arrays of a synthetic model of family ``kind`` (``smpl``, ``smplh``, ``smplx``).

    Returns:
        dict keyed as the official files (float64 arrays as the releases store them;
        ``J_regressor`` dense here, written sparse into pickles by ``write_chumpy_pkl``).
    """
    rng = np.random.default_rng(seed)
    parents = np.asarray(official_parents(kind), dtype=np.int64)
    J = parents.shape[0]
    B = LAYOUT[kind]["num_betas"] if num_betas is None else num_betas
    # skeleton: each joint 8-20 cm from its parent, Y up
    jpos = np.zeros((J, 3))
    for j in range(1, J):
        d = rng.normal(size=3)
        jpos[j] = jpos[parents[j]] + 0.08 * d / np.linalg.norm(d) + np.array([0.0, 0.06, 0.0])
    V = J * verts_per_joint
    owner = np.repeat(np.arange(J), verts_per_joint)
    vt = jpos[owner] + rng.normal(scale=0.04, size=(V, 3))
    # skinning: the owning joint, its parent and sometimes a random joint
    w = np.zeros((V, J))
    w[np.arange(V), owner] = rng.uniform(0.5, 1.0, V)
    par = np.maximum(parents[owner], 0)
    w[np.arange(V), par] += rng.uniform(0.0, 0.5, V)
    extra = rng.random(V) < 0.3
    n_extra = int(extra.sum())
    w[np.nonzero(extra)[0], rng.integers(0, J, n_extra)] += rng.uniform(0, 0.2, n_extra)
    w /= w.sum(axis=1, keepdims=True)
    # joint regressor: a convex combination of the joint's own vertices (rows sum to 1)
    jr = np.zeros((J, V))
    for j in range(J):
        idx = np.nonzero(owner == j)[0]
        jr[j, idx] = rng.uniform(0.1, 1.0, idx.size)
    jr /= jr.sum(axis=1, keepdims=True)
    faces = np.stack([np.arange(V - 2), np.arange(1, V - 1), np.arange(2, V)], axis=1)
    faces = faces.astype(np.uint32)  # the releases store uint32 faces
    kt = np.stack([parents, np.arange(J)]).astype(np.int64)
    kt[0, 0] = ROOT_PARENT
    out: dict[str, np.ndarray] = {
        "v_template": vt,
        "f": faces,
        "J_regressor": jr,
        "kintree_table": kt,
        "J": jr @ vt,
        "weights": w,
        "shapedirs": rng.normal(scale=0.004, size=(V, 3, B)),
        "posedirs": rng.normal(scale=0.01, size=(V, 3, 9 * (J - 1))),
        "bs_style": np.array("lbs"),
        "bs_type": np.array("lrotmin"),
    }
    if kind == "smpl":
        out["weights_prior"] = w.copy()
        out["J_regressor_prior"] = jr.copy()
        out["vert_sym_idxs"] = np.arange(V)[::-1].copy()
    if kind in ("smplh", "smplx"):
        for s in ("l", "r"):
            q, _ = np.linalg.qr(rng.normal(size=(45, 45)))
            out[f"hands_components{s}"] = q.T
            out[f"hands_mean{s}"] = rng.normal(scale=0.15, size=45)
            out[f"hands_coeffs{s}"] = rng.normal(scale=0.5, size=(8, 45))
    if kind == "smplx":
        F = faces.shape[0]
        out["lmk_faces_idx"] = rng.integers(0, F, 51).astype(np.int64)
        out["lmk_bary_coords"] = rng.dirichlet(np.ones(3), 51)
        out["dynamic_lmk_faces_idx"] = rng.integers(0, F, (79, 17)).astype(np.int64)
        out["dynamic_lmk_bary_coords"] = rng.dirichlet(np.ones(3), (79, 17))
        out["vt"] = rng.random((V, 2))
        out["ft"] = faces.astype(np.int64)
    return out


def write_npz(path: str | os.PathLike, arrays: dict, *, compressed: bool = False,
              object_members: tuple[str, ...] = ()) -> str:
    """Write ``arrays`` as an ``.npz``. ``object_members``: keys stored the way a naive
    ``np.savez`` of a chumpy model stores them (a 0-d object array holding a chumpy ``Ch``).
    SMPL-X files also get the official object-typed ``joint2num`` / ``part2num`` members."""
    arrs = dict(arrays)
    with _fake_chumpy() as ch:
        for k in object_members:
            o = np.empty((), dtype=object)
            o[()] = ch["chumpy.ch"].Ch(x=np.asarray(arrs[k]))
            arrs[k] = o
        if "lmk_faces_idx" in arrs:  # SMPL-X releases carry these dicts as object arrays
            for k in ("joint2num", "part2num"):
                o = np.empty((), dtype=object)
                o[()] = {"pelvis": 0}
                arrs[k] = o
        (np.savez_compressed if compressed else np.savez)(os.fspath(path), **arrs)
    return os.fspath(path)


# --- chumpy-style pickles --------------------------------------------------------------------
class _FakeChumpy:
    """Pickles like a chumpy object: class global ``chumpy.<module>.<Name>``, state = the
    instance ``__dict__`` with chumpy's bookkeeping (``Ch.__getstate__`` drops only
    ``_parents`` and ``_cache``)."""

    def __init__(self, **terms):
        self.__dict__.update(terms)

    def __getstate__(self):
        return dict(self.__dict__, _dirty_vars=set(), _itr=None, _make_dense=False,
                    _make_sparse=False, _depends_on_deps={})


_FAKE_MODULES = {
    "chumpy": (),
    "chumpy.ch": ("Ch",),
    "chumpy.ch_ops": ("add", "subtract", "multiply", "divide"),
    "chumpy.reordering": ("Reshape", "transpose", "Select", "Concatenate"),
}


@contextlib.contextmanager
def _fake_chumpy():
    """Register fake ``chumpy`` modules in ``sys.modules`` so pickle can name their classes;
    restore ``sys.modules`` afterwards."""
    mods = {}
    for name, classes in _FAKE_MODULES.items():
        m = types.ModuleType(name)
        for c in classes:
            setattr(m, c, type(c, (_FakeChumpy,), {"__module__": name, "__qualname__": c}))
        mods[name] = m
    saved = {k: sys.modules.get(k) for k in mods}
    sys.modules.update(mods)
    try:
        yield mods
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


class _Py2StylePickler(pickle.Pickler):
    """Writes ndarrays as Python 2 did: ``_reconstruct`` + state whose raw data is a (latin-1)
    string, which is what a Python-2 ``str`` becomes when loaded with ``encoding='latin1'``."""

    def reducer_override(self, obj):
        if type(obj) is np.ndarray and not obj.dtype.hasobject:
            fn, args, state = obj.__reduce__()
            dtype_code = args[2].decode("latin1") if isinstance(args[2], bytes) else args[2]
            return fn, (args[0], args[1], dtype_code), (*state[:4], state[4].decode("latin1"))
        return NotImplemented


def _sparse_csc(dense: np.ndarray):
    import scipy.sparse as sp  # test-only dependency (pyproject "dev"), as the releases used

    return sp.csc_matrix(dense)


def chumpy_pickle_bytes(arrays: dict, *, protocol: int = 2, style: str = "basic") -> bytes:
    """Pickle ``arrays`` like an official release.

    Args:
        arrays: from ``make_model_arrays``.
        protocol: 2 (``cPickle.dump(..., -1)`` in Python 2) or 0.
        style: ``basic``: ``shapedirs`` and ``J`` are chumpy ``Ch`` (as the releases);
            ``ops``: also chumpy expressions (``ch_ops.add``, ``reordering.Reshape`` /
            ``transpose``) for ``v_template``, ``shapedirs`` and ``posedirs``.
    """
    with _fake_chumpy() as ch:
        Ch = ch["chumpy.ch"].Ch
        d = dict(arrays)
        for k in ("J_regressor", "J_regressor_prior"):
            if k in d:
                d[k] = _sparse_csc(np.asarray(d[k]))
        for k in ("bs_style", "bs_type"):
            if k in d:
                d[k] = str(d[k])
        d["shapedirs"] = Ch(x=d["shapedirs"])
        d["J"] = Ch(x=d["J"])
        if style == "ops":
            sd = d["shapedirs"].x
            d["shapedirs"] = ch["chumpy.reordering"].Reshape(a=Ch(x=sd.ravel()), newshape=sd.shape)
            d["v_template"] = ch["chumpy.ch_ops"].add(x1=Ch(x=d["v_template"]),
                                                      x2=np.zeros_like(d["v_template"]))
            pd = d["posedirs"]
            d["posedirs"] = ch["chumpy.reordering"].transpose(
                a=Ch(x=np.ascontiguousarray(pd.transpose(2, 1, 0))), axes=(2, 1, 0))
        buf = io.BytesIO()
        _Py2StylePickler(buf, protocol=protocol).dump(d)
    data = buf.getvalue()
    # the module names of the Python-2 era releases (GLOBAL opcodes are plain text lines)
    for new, old in ((b"numpy._core.multiarray\n", b"numpy.core.multiarray\n"),
                     (b"scipy.sparse._csc\n", b"scipy.sparse.csc\n")):
        data = data.replace(b"c" + new, b"c" + old)
    return data


def write_chumpy_pkl(path: str | os.PathLike, arrays: dict, *, protocol: int = 2,
                     style: str = "basic") -> str:
    """Write ``chumpy_pickle_bytes(arrays, ...)`` to ``path``."""
    with open(path, "wb") as fh:
        fh.write(chumpy_pickle_bytes(arrays, protocol=protocol, style=style))
    return os.fspath(path)


def write_model(tmp_dir: str | os.PathLike, kind: str, fmt: str = "npz", *, seed: int = 0,
                **kwargs) -> str:
    """Write a synthetic ``kind`` model as ``<tmp_dir>/<KIND>_NEUTRAL.<fmt>``; returns the path."""
    arrays = make_model_arrays(kind, seed=seed)
    path = os.path.join(os.fspath(tmp_dir), f"{kind.upper()}_NEUTRAL.{fmt}")
    if fmt == "npz":
        return write_npz(path, arrays, **kwargs)
    return write_chumpy_pkl(path, arrays, **kwargs)
