"""SMPL, SMPL-H and SMPL-X model files (``.npz`` and ``.pkl``) into a ``BodyModel``.

The official ``.pkl`` releases are Python-2 pickles holding numpy arrays, scipy sparse
matrices (``J_regressor``) and chumpy objects (``shapedirs``). They are read WITHOUT running
code from the file and without chumpy or scipy: a restricted unpickler resolves only a short
whitelist of globals (numpy array/dtype reconstruction, the csc/csr sparse classes and chumpy
classes, both as inert stubs that keep their pickled state) and refuses anything else.
``.npz`` files are read with ``allow_pickle=False``; an object member that the model needs
(e.g. a chumpy array saved by ``np.savez``) goes through the same restricted unpickler.

The family is told by the joint count (SMPL 24, SMPL-H 52, SMPL-X 55); joint names follow
the family's official order (``smpl_names``). ``rest_pose`` holds the mean hand pose
(``hands_meanl``/``hands_meanr``), so a motion that addresses only the body gives the same
result as ``smplx``'s default forward pass (``flat_hand_mean=False``).
"""

from __future__ import annotations

import io
import os
import pickle
import zipfile

import numpy as np

from sim.bodies.model import BodyModel
from sim.bodies.smpl_names import HAND_START, JOINT_NAMES, KIND_BY_JOINT_COUNT
from sim.errors import WrinklesInputError

__all__ = ["load_smpl_model", "read_model_arrays", "restricted_pickle_load"]

#: keys every SMPL-family file has (names as in the official files).
REQUIRED_KEYS = (
    "v_template", "f", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table")
#: SMPL-H / SMPL-X mean hand poses, axis-angle [rad] of 15 joints each, shape (45,).
HAND_MEAN_KEYS = ("hands_meanl", "hands_meanr")
#: SMPL-X v1.1 stores 300 shape then 100 expression columns in ``shapedirs``; files with
#: fewer than 400 columns (v1.0) hold 10 + 10. Same rule as ``smplx.SMPLX``.
SMPLX_SHAPE_DIM, SMPLX_EXPR_DIM, SMPLX_SMALL_SHAPE_DIM = 300, 100, 10
#: vertex counts of the official meshes (recorded in ``meta``; other counts are accepted).
OFFICIAL_VERTEX_COUNTS = {"smpl": 6890, "smplh": 6890, "smplx": 10475}
_MAX_CHUMPY_DEPTH = 64


class _FormatError(Exception):
    """Internal: a problem with the file, turned into WrinklesInputError with the path."""


# --- restricted unpickler ------------------------------------------------------------------
class _Stub:
    """Base of the inert classes that stand in for chumpy and scipy objects."""

    _global_name = "?"

    def __setstate__(self, state) -> None:
        self.state = state


class _ChumpyStub(_Stub):
    """A chumpy object: its pickled ``__dict__`` (``x`` for ``Ch``; ``a``, ``x1``... for ops)."""

    def value(self, depth: int = 0) -> np.ndarray:
        """Evaluate the few chumpy node types model files use, with numpy."""
        if depth > _MAX_CHUMPY_DEPTH:
            raise _FormatError("chumpy expression nested too deeply")
        st = getattr(self, "state", None)
        if not isinstance(st, dict):
            raise _FormatError(f"chumpy object {self._global_name} has no readable state")
        kind = self._global_name.rsplit(".", 1)[-1]

        def term(name: str) -> np.ndarray:
            if name not in st:
                raise _FormatError(f"chumpy object {self._global_name} lacks its term {name!r}")
            return resolve(st[name], depth + 1)

        if kind == "Ch":
            return term("x")
        binary = {"add": np.add, "subtract": np.subtract, "multiply": np.multiply,
                  "divide": np.divide}
        if kind in binary:
            return binary[kind](term("x1"), term("x2"))
        if kind == "negative":
            return -term("x")
        if kind == "Reshape":
            return term("a").reshape(st["newshape"])
        if kind == "transpose":
            return np.transpose(term("a"), axes=st.get("axes"))
        if kind == "Select":
            out = term("a").ravel()[np.asarray(st["idxs"]).ravel()]
            return out.reshape(st["preferred_shape"]) if "preferred_shape" in st else out
        if kind == "Concatenate":
            return np.concatenate([term(n) for n in st.get("dterms", ())], axis=st.get("axis", 0))
        raise _FormatError(f"chumpy object {self._global_name} cannot be evaluated without chumpy")


class _SparseStub(_Stub):
    """A scipy csc/csr matrix: its pickled ``__dict__`` (data, indices, indptr, shape)."""

    def value(self) -> np.ndarray:
        st = getattr(self, "state", None)
        if not isinstance(st, dict) or not {"data", "indices", "indptr"} <= set(st):
            raise _FormatError(f"sparse matrix {self._global_name} has no readable state")
        shape = st.get("_shape", st.get("shape"))
        try:
            rows, cols = (int(s) for s in shape)
            data = np.asarray(st["data"], dtype=np.float64).ravel()
            indices = np.asarray(st["indices"], dtype=np.int64).ravel()
            indptr = np.asarray(st["indptr"], dtype=np.int64).ravel()
        except (TypeError, ValueError) as exc:
            raise _FormatError(f"sparse matrix {self._global_name} is malformed ({exc})") from None
        csc = self._global_name.rsplit(".", 1)[-1].startswith("csc")
        outer, inner = (cols, rows) if csc else (rows, cols)
        if (indptr.shape != (outer + 1,) or indices.shape != data.shape or indptr[0] != 0
                or indptr[-1] != data.size or np.any(np.diff(indptr) < 0)
                or (indices.size and (indices.min() < 0 or indices.max() >= inner))):
            raise _FormatError(f"sparse matrix {self._global_name} has inconsistent indices")
        major = np.repeat(np.arange(outer), np.diff(indptr))
        dense = np.zeros((rows, cols), dtype=np.float64)
        if csc:
            np.add.at(dense, (indices, major), data)
        else:
            np.add.at(dense, (major, indices), data)
        return dense


_SPARSE_CLASSES = {"csc_matrix", "csr_matrix", "csc_array", "csr_array"}
_NUMPY_CORE = {"numpy.core.multiarray", "numpy._core.multiarray"}
_NUMPY_NUMERIC = {"numpy.core.numeric", "numpy._core.numeric"}


def _plain_dtype(dtype) -> np.dtype:
    dt = np.dtype(dtype)
    if dt.hasobject:
        raise _FormatError("the pickle builds a numpy scalar/buffer of object dtype")
    return dt


def _np_reconstruct(subtype, shape, dtype):
    """``numpy.core.multiarray._reconstruct``, for plain ``ndarray`` only (numpy's own
    ``__setstate__`` then fills it from the pickled bytes)."""
    if subtype is not np.ndarray:
        raise _FormatError(f"the pickle reconstructs an array of type {subtype!r}")
    if isinstance(dtype, str):
        dtype = dtype.encode("latin1")
    return np.ndarray.__new__(np.ndarray, shape, dtype)


def _np_scalar(dtype, data=b""):
    """``numpy.core.multiarray.scalar``: a numpy scalar from its raw bytes."""
    dt = _plain_dtype(dtype)
    raw = data.encode("latin1") if isinstance(data, str) else bytes(data)
    return np.frombuffer(raw, dtype=dt, count=1)[0]


def _np_frombuffer(buf, dtype, shape, order="C"):
    """``numpy.core.numeric._frombuffer`` (protocol-5 pickles of arrays)."""
    return np.frombuffer(bytes(buf), dtype=_plain_dtype(dtype)).reshape(shape, order=order).copy()


def _latin1_encode(text, encoding="latin1"):
    """``_codecs.encode``, as Python 3 writes ``bytes`` into protocol-2 pickles."""
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise _FormatError("the pickle calls _codecs.encode with unexpected arguments")
    return text.encode("latin1")


def _safe_reconstructor(cls, base, state):
    """``copyreg._reconstructor`` (protocol 0/1 objects), for the stub classes only."""
    is_stub = isinstance(cls, type) and issubclass(cls, _Stub)
    if not is_stub or base is not object or state is not None:
        raise _FormatError(f"the pickle reconstructs a {getattr(cls, '__name__', cls)!r} object")
    return object.__new__(cls)


class _RestrictedUnpickler(pickle.Unpickler):
    """``pickle.Unpickler`` whose ``find_class`` resolves only model-file types."""

    def __init__(self, file, **kwargs):
        super().__init__(file, **kwargs)
        self._stubs: dict[tuple[str, str], type] = {}

    def _stub(self, base: type, module: str, name: str) -> type:
        key = (module, name)
        if key not in self._stubs:
            self._stubs[key] = type(name, (base,), {"_global_name": f"{module}.{name}"})
        return self._stubs[key]

    def find_class(self, module: str, name: str):
        if module in _NUMPY_CORE and name == "_reconstruct":
            return _np_reconstruct
        if module in _NUMPY_CORE and name == "scalar":
            return _np_scalar
        if module in _NUMPY_NUMERIC and name == "_frombuffer":
            return _np_frombuffer
        if module == "numpy" and name in ("ndarray", "dtype"):
            return getattr(np, name)
        if module in ("copy_reg", "copyreg") and name == "_reconstructor":
            return _safe_reconstructor
        if module in ("__builtin__", "builtins") and name in ("set", "frozenset", "object"):
            return {"set": set, "frozenset": frozenset, "object": object}[name]
        if module == "_codecs" and name == "encode":
            return _latin1_encode
        if module.startswith("scipy.sparse") and name in _SPARSE_CLASSES:
            return self._stub(_SparseStub, module, name)
        if (module == "chumpy" or module.startswith("chumpy.")) and name.isidentifier():
            return self._stub(_ChumpyStub, module, name)
        raise _FormatError(
            f"refusing to unpickle the global {module}.{name}: model files may reference only "
            "numpy arrays, scipy sparse matrices and chumpy arrays (no code is run)")


def restricted_pickle_load(file) -> object:
    """Unpickle from a binary file object with the model-file whitelist (``encoding='latin1'``
    for Python-2 pickles). Raises ``_FormatError`` (internal) on anything else."""
    try:
        return _RestrictedUnpickler(file, encoding="latin1").load()
    except _FormatError:
        raise
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, KeyError,
            IndexError, UnicodeError, MemoryError, OverflowError) as exc:
        raise _FormatError(f"not a readable model pickle ({type(exc).__name__}: {exc})") from None


def resolve(obj, depth: int = 0):
    """Plain numpy value of an unpickled entry (chumpy stubs evaluated, sparse made dense)."""
    if isinstance(obj, _ChumpyStub):
        return np.asarray(obj.value(depth))
    if isinstance(obj, _SparseStub):
        return obj.value()
    if isinstance(obj, np.ndarray) and obj.dtype.hasobject and obj.shape == ():
        return resolve(obj.item(), depth + 1)  # np.savez of a single object, e.g. a chumpy Ch
    return obj


# --- file readers --------------------------------------------------------------------------
def _read_npy_member(zf: zipfile.ZipFile, member: str):
    with zf.open(member) as fh:
        data = fh.read()
    try:
        return np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)
    except ValueError as exc:
        if "allow_pickle" not in str(exc):
            raise
    fh = io.BytesIO(data)  # an object array: its payload is a pickle, read it restricted
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        np.lib.format.read_array_header_1_0(fh)
    else:
        np.lib.format.read_array_header_2_0(fh)
    return restricted_pickle_load(fh)


def _read_npz(path: str, keys: tuple[str, ...]) -> dict:
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise _FormatError(f"not a readable .npz (zip) file ({exc})") from None
    out = {}
    with zf:
        names = set(zf.namelist())
        for key in keys:
            member = key + ".npy"
            if member not in names:
                continue
            try:
                out[key] = _read_npy_member(zf, member)
            except _FormatError as exc:
                raise _FormatError(f"{key}: {exc}") from None
            except Exception as exc:  # noqa: BLE001  (zlib, CRC, header errors of a broken member)
                raise _FormatError(f"cannot read {key!r} ({type(exc).__name__}: {exc})") from None
    return out


def _read_pkl(path: str) -> dict:
    try:
        with open(path, "rb") as fh:
            obj = restricted_pickle_load(fh)
    except OSError as exc:
        raise _FormatError(f"cannot read file ({exc.strerror or exc})") from None
    if not isinstance(obj, dict):
        raise _FormatError(
            f"a model pickle holds a dict of arrays, this one holds {type(obj).__name__}")
    return {str(k): v for k, v in obj.items()}


def read_model_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of an SMPL-family file that the body model uses, as plain numpy.

    Args:
        path: ``.npz`` or ``.pkl`` model file.

    Returns:
        dict with the keys of ``REQUIRED_KEYS`` and ``HAND_MEAN_KEYS`` that the file has
        (chumpy arrays evaluated, sparse matrices dense), in the file's own dtypes.
    """
    p = os.fspath(path)
    try:
        return _read_arrays(p)
    except _FormatError as exc:
        raise WrinklesInputError(str(exc), path=p) from None


def _read_arrays(p: str) -> dict[str, np.ndarray]:
    if not os.path.isfile(p):
        raise _FormatError("no such model file")
    ext = os.path.splitext(p)[1].lower()
    keys = REQUIRED_KEYS + HAND_MEAN_KEYS
    if ext == ".npz":
        raw = _read_npz(p, keys)
    elif ext == ".pkl":
        raw = _read_pkl(p)
    else:
        raise _FormatError(
            f"unknown model file type {ext or '(no extension)'!r}: expected .npz or .pkl")
    out = {}
    for key in keys:
        if key in raw:
            try:
                out[key] = np.asarray(resolve(raw[key]))
            except _FormatError as exc:
                raise _FormatError(f"{key}: {exc}") from None
            except (ValueError, TypeError, IndexError, KeyError) as exc:  # a malformed chumpy node
                msg = f"{key}: cannot evaluate ({type(exc).__name__}: {exc})"
                raise _FormatError(msg) from None
            if out[key].dtype.hasobject:
                raise _FormatError(f"{key} is not a numeric array (holds Python objects)")
    return out


# --- model assembly ------------------------------------------------------------------------
def _float(arrs: dict, key: str, shape: tuple) -> np.ndarray:
    """arrs[key] as float32 (as BodyModel keeps it), checked against ``shape`` (None = any
    size) and for NaN / inf."""
    a = arrs[key]
    if not np.issubdtype(a.dtype, np.number):
        raise _FormatError(f"{key} must be numeric, got dtype {a.dtype}")
    fits = a.ndim == len(shape) and all(s in (None, n) for s, n in zip(shape, a.shape, strict=True))
    if not fits:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise _FormatError(f"{key} must have shape {want}, got {a.shape}")
    a = a.astype(np.float32)
    if not np.all(np.isfinite(a)):
        raise _FormatError(f"{key} contains NaN or inf")
    return a


def _assemble(arrs: dict, source: str, num_betas: int | None) -> BodyModel:
    missing = [k for k in REQUIRED_KEYS if k not in arrs]
    if missing:
        raise _FormatError(f"missing {', '.join(missing)} (an SMPL-family model file has "
                           f"{', '.join(REQUIRED_KEYS)})")
    vt = _float(arrs, "v_template", (None, 3))
    V = vt.shape[0]
    weights = _float(arrs, "weights", (V, None))
    J = weights.shape[1]
    kind = KIND_BY_JOINT_COUNT.get(J)
    if kind is None:
        raise _FormatError(f"weights has {J} joints: expected 24 (SMPL), 52 (SMPL-H) or 55 "
                           "(SMPL-X); MANO and FLAME files are not bodies")
    kt = np.asarray(arrs["kintree_table"])
    if kt.shape != (2, J) or not np.issubdtype(kt.dtype, np.number):
        raise _FormatError(f"kintree_table must have shape (2, {J}), got {kt.shape}")
    parents = kt[0].astype(np.int64)
    parents[0] = -1  # the official files store 2**32 - 1 for the root
    if np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, J)):
        raise _FormatError("kintree_table parents must list each joint's parent before the joint")
    jr = _float(arrs, "J_regressor", (J, V))
    faces = np.asarray(arrs["f"])
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise _FormatError(
            f"f must be integer triangles of shape (F, 3), got {faces.dtype} {faces.shape}")
    if faces.size and (faces.min() < 0 or faces.max() >= V):
        raise _FormatError(f"f indexes vertices outside 0..{V - 1}")
    sd = arrs["shapedirs"]
    sd = _float(arrs, "shapedirs", (V, 3) if sd.ndim == 2 else (V, 3, None))
    if sd.ndim == 2:
        sd = sd[:, :, None]
    posedirs = _float(arrs, "posedirs", (V, 3, 9 * (J - 1)))

    meta: dict = {"official_topology": V == OFFICIAL_VERTEX_COUNTS[kind]}
    if kind == "smplx":  # shape and expression columns share one array (smplx body_models.py)
        full = sd.shape[2] >= SMPLX_SHAPE_DIM + SMPLX_EXPR_DIM
        n_shape = min(SMPLX_SHAPE_DIM if full else SMPLX_SMALL_SHAPE_DIM, sd.shape[2])
        meta["expression_dirs"] = sd[:, :, n_shape:n_shape + SMPLX_EXPR_DIM].astype(np.float32)
        sd = sd[:, :, :n_shape]
    meta["file_num_betas"] = int(sd.shape[2])
    if num_betas is not None:
        if isinstance(num_betas, bool) or not isinstance(num_betas, (int, np.integer)) or not (
                1 <= num_betas <= sd.shape[2]):
            raise _FormatError(f"num_betas={num_betas!r}: the file has {sd.shape[2]} shape "
                               f"components, ask for 1..{sd.shape[2]}")
        sd = sd[:, :, : int(num_betas)]

    rest_pose = np.zeros((J, 3), np.float32)
    if kind in HAND_START:
        for side, key in zip(("left", "right"), HAND_MEAN_KEYS, strict=True):
            if key in arrs:
                start = HAND_START[kind][side]
                rest_pose[start:start + 15] = _float(arrs, key, (45,)).reshape(15, 3)
        meta["hand_mean"] = all(k in arrs for k in HAND_MEAN_KEYS)

    name = os.path.splitext(os.path.basename(source))[0]
    return BodyModel(
        v_template=vt, faces=faces.astype(np.int64), shapedirs=sd, posedirs=posedirs,
        j_regressor=jr, weights=weights, parents=parents, joint_names=JOINT_NAMES[kind],
        kind=kind, rest_pose=rest_pose, name=name, source=source, meta=meta)


def load_smpl_model(path: str | os.PathLike, *, num_betas: int | None = None) -> BodyModel:
    """Load an SMPL, SMPL-H or SMPL-X model file.

    Args:
        path: ``.npz`` or ``.pkl`` (official releases, including Python-2 pickles with chumpy
            and scipy objects, which are read without executing code).
        num_betas: keep only the first ``num_betas`` shape components (default: all of them;
            for SMPL-X the shape columns of ``shapedirs``, expressions go to
            ``meta['expression_dirs']``).

    Returns:
        BodyModel with ``kind`` ``smpl``, ``smplh`` or ``smplx``, the family's joint names,
        ``body_joint_map`` addressing joints 0-21 (SMPL's hand joints 22, 23 map to -1 for
        SMPL-H/X) and ``rest_pose`` = the mean hand pose (zeros for SMPL).

    Raises:
        WrinklesInputError: one line naming the file and what is wrong with it.
    """
    p = os.fspath(path)
    try:
        return _assemble(_read_arrays(p), p, num_betas)
    except _FormatError as exc:
        raise WrinklesInputError(str(exc), path=p) from None
