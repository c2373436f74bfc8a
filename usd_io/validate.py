"""Validate a USD stage: OpenUSD's ``UsdValidation`` validators plus mesh-topology checks.

usd-core 26.x validates through the ``UsdValidation`` framework (it ships no Python
``ComplianceChecker`` for ``usdchecker``): a
``ValidationRegistry`` of validators contributed by plugins (usdGeom, usdShade, usdUtils ...),
run by a ``ValidationContext`` over a stage, returning ``ValidationError`` records typed
Error / Warn / Info.

None of the stock validators look at mesh topology, so we add ``UsdGeom.Mesh.ValidateTopology``
at every time sample of ``points`` and a range check of indexed ``primvars:st``; those issues
are reported as errors with the identifier ``wrinkles:MeshTopology``. The usdSkel validators
check only that the binding API is applied, so skinned meshes get ``wrinkles:SkelBinding``:
a valid joint hierarchy, one influence set per point with joint indices in range, and one
blend-shape target per blend-shape name.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom, UsdSkel, UsdValidation

from usd_io.read import open_stage

#: validator keywords / names skipped: none today; kept as the one place to switch a
#: validator off with the reason written beside it.
SKIPPED_VALIDATORS: frozenset[str] = frozenset()


@dataclass(frozen=True)
class ValidationReport:
    """Issues found in a stage, one line each: ``"<identifier>: <message> [at <sites>]"``.

    Attributes:
        errors: error-level issues (a stage we write must have none).
        warnings: warning-level issues.
        infos: informational notes.
    """

    errors: list[str]
    warnings: list[str]
    infos: list[str]


def _sites(error: UsdValidation.ValidationError) -> str:
    paths = []
    for site in error.GetSites():
        if site.IsProperty():
            paths.append(str(site.GetProperty().GetPath()))
        elif site.IsPrim():
            paths.append(str(site.GetPrim().GetPath()))
    return f" [at {', '.join(paths)}]" if paths else ""


def _usd_validation(stage: Usd.Stage) -> list[tuple[str, str]]:
    """Run every registered validator; returns (level, line) pairs."""
    registry = UsdValidation.ValidationRegistry()
    validators = [v for v in registry.GetOrLoadAllValidators()
                  if v.GetMetadata().name not in SKIPPED_VALIDATORS]
    context = UsdValidation.ValidationContext(validators)
    out = []
    for error in context.Validate(stage):
        if error.HasNoError():
            continue
        kind = error.GetType()
        level = ("error" if kind == UsdValidation.ValidationErrorType.Error else
                 "warning" if kind == UsdValidation.ValidationErrorType.Warn else "info")
        out.append((level, f"{error.GetIdentifier()}: {error.GetMessage()}{_sites(error)}"))
    return out


def _mesh_topology(stage: Usd.Stage) -> list[str]:
    """Face indices against the point count at every time sample; UV indices against UVs."""
    out = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        where = f"wrinkles:MeshTopology: {prim.GetPath()}"
        indices = mesh.GetFaceVertexIndicesAttr().Get()
        counts = mesh.GetFaceVertexCountsAttr().Get()
        if indices is None or counts is None:
            out.append(f"{where}: faceVertexIndices / faceVertexCounts not authored")
            continue
        attr = mesh.GetPointsAttr()
        times = attr.GetTimeSamples() or [Usd.TimeCode.Default()]
        for t in times:
            points = attr.Get(t)
            ok, reason = UsdGeom.Mesh.ValidateTopology(indices, counts,
                                                       0 if points is None else len(points))
            if not ok:
                out.append(f"{where}: at time {t}: {reason}")
                break
        st = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
        if st and st.IsIndexed():
            uv_idx = np.asarray(st.GetIndices(), dtype=np.int64)
            n_uv = len(st.Get() or [])
            if uv_idx.size and (uv_idx.min() < 0 or uv_idx.max() >= n_uv):
                out.append(f"{where}: primvars:st indices outside [0, {n_uv})")
            if (st.GetInterpolation() == UsdGeom.Tokens.faceVarying
                    and uv_idx.size != len(indices)):
                out.append(f"{where}: primvars:st has {uv_idx.size} face-varying indices for "
                           f"{len(indices)} face corners")
    return out


def _skel_bindings(stage: Usd.Stage) -> list[str]:
    """Each skinned mesh's joint influences and blend shapes against its skeleton."""
    out = []
    for prim in stage.Traverse():
        if not (prim.IsA(UsdGeom.Mesh) and prim.HasAPI(UsdSkel.BindingAPI)):
            continue
        where = f"wrinkles:SkelBinding: {prim.GetPath()}"
        binding = UsdSkel.BindingAPI(prim)
        skel = binding.GetInheritedSkeleton()
        if not skel:
            continue  # not skinned: drawn as authored
        joints = skel.GetJointsAttr().Get() or []
        ok, reason = UsdSkel.Topology(joints).Validate()
        if not ok:
            out.append(f"{where}: skeleton {skel.GetPath()}: {reason}")
            continue
        out += [f"{where}: {p}" for p in _influence_problems(binding, prim, len(joints))]
        names = binding.GetBlendShapesAttr().Get() or []
        targets = binding.GetBlendShapeTargetsRel().GetTargets()
        if len(names) != len(targets):
            out.append(f"{where}: {len(names)} skel:blendShapes for {len(targets)} "
                       "skel:blendShapeTargets")
    return out


def _influence_problems(binding: UsdSkel.BindingAPI, prim: Usd.Prim, n_joints: int) -> list[str]:
    """Joint indices / weights of a vertex-interpolated skin against the point count."""
    idx_pv, w_pv = binding.GetJointIndicesPrimvar(), binding.GetJointWeightsPrimvar()
    if not (idx_pv and idx_pv.HasAuthoredValue() and w_pv and w_pv.HasAuthoredValue()):
        return ["primvars:skel:jointIndices / jointWeights not authored"]
    idx = np.asarray(idx_pv.Get(), dtype=np.int64)
    weights = np.asarray(w_pv.Get(), dtype=np.float64)
    k = idx_pv.GetElementSize()
    n_points = len(UsdGeom.Mesh(prim).GetPointsAttr().Get() or [])
    problems = []
    if idx.size != weights.size:
        problems.append(f"{idx.size} joint indices for {weights.size} joint weights")
    if idx_pv.GetInterpolation() == UsdGeom.Tokens.vertex and idx.size != n_points * k:
        problems.append(f"{idx.size} joint indices for {n_points} points x {k} influences")
    if idx.size and (idx.min() < 0 or idx.max() >= n_joints):
        problems.append(f"joint indices outside [0, {n_joints})")
    if not np.isfinite(weights).all():
        problems.append("joint weights contain NaN or inf")
    return problems


def validation_report(path: str | os.PathLike) -> ValidationReport:
    """Validate a USD file with ``UsdValidation`` and our mesh checks.

    Args:
        path: a ``.usda`` / ``.usdc`` / ``.usd`` / ``.usdz`` file.

    Returns:
        Errors, warnings and infos, one line each.

    Raises:
        WrinklesInputError: the file is missing or not USD.
    """
    stage = open_stage(Path(path))
    found = _usd_validation(stage)
    errors = ([line for level, line in found if level == "error"] + _mesh_topology(stage)
              + _skel_bindings(stage))
    return ValidationReport(errors=errors,
                            warnings=[line for level, line in found if level == "warning"],
                            infos=[line for level, line in found if level == "info"])


def validate_stage(path: str | os.PathLike) -> list[str]:
    """Error-level issues of a USD file (empty when clean); see ``validation_report``."""
    return validation_report(path).errors
