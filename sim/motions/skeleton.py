"""The skeleton and foot contact model procedural motions are built on.

Procedural motions place the feet on the floor with forward kinematics, so they need the rest
joint positions of the body that will wear them and points on its soles. ``MotionSkeleton``
holds both:

- ``rest_joints``: SMPL's 24 joints at rest [m] (T-pose, Y up, facing +Z);
- contact points: rest positions [m] of points on the soles, each moved by linear blend
  skinning on up to ``K`` joints (``contact_joints``, ``contact_weights``), so a point's posed
  position is ``sum_k w_k (P_jk + G_jk (c - J_jk))`` with ``G, P`` the global rotations and
  positions of the joints. A point skinned to one joint is a fixed offset in that joint's frame.

``MotionSkeleton.default()`` is SMPL's approximate skeleton (``retarget.SMPL_REST_JOINTS``)
with one heel point per foot in the ankle frame and one toe point in the foot (toe-ball)
frame; motions generated without a body use it. ``MotionSkeleton.from_body(body, betas)`` takes
a body model's regressed joints and, as contacts, the support points of its foot meshes (the
vertices that can be lowest for any foot orientation within 80 degrees of level) with their
own skinning weights, so the motion's floor contact matches the skinned mesh (exactly for
bodies without pose blend shapes).

Derived quantities (``rest_floor``, the quiet-stance centre-of-mass offset) are computed once
on construction. Instances compare and hash by identity.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.motions.retarget import SMPL_REST_JOINTS, forward_kinematics
from sim.types import NUM_SMPL_JOINTS, SMPL_JOINT_NAMES, SMPL_PARENTS

_J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
_FEET = ((_J["left_ankle"], _J["left_foot"]), (_J["right_ankle"], _J["right_foot"]))

#: Default heel / toe contact offsets [m] in the ankle / foot (toe-ball) joint frames: at rest
#: roughly the heel and the tip of the sole of SMPL's neutral body.
DEFAULT_HEEL = np.array([0.0, -0.075, -0.045])
DEFAULT_TOE = np.array([0.0, -0.02, 0.045])
DEFAULT_HEEL.setflags(write=False)
DEFAULT_TOE.setflags(write=False)

_MAX_INFLUENCES = 4      # joints per contact point
_FOOT_WEIGHT = 0.5       # a foot vertex has at least this weight on its ankle + foot joints
_SOLE_BAND = 0.06        # [m] candidate foot vertices lie this close above the foot's lowest
_SUPPORT_TILT = 80.0     # [deg] foot orientations covered by the support points


@dataclass(frozen=True, eq=False)
class MotionSkeleton:
    """Rest joints and skinned foot contact points for procedural motions.

    Attributes:
        rest_joints: SMPL joint positions at rest [m], (24, 3), float64.
        contact_points: rest positions [m] of the sole contact points, (N, 3).
        contact_joints: SMPL joint indices moving each point, (N, K) int.
        contact_weights: skinning weights, (N, K), rows sum to 1 (zero-weight slots allowed).
        contact_foot: 0 (left) or 1 (right) per point, (N,).
        name: label (``default`` or the body's name).
        rest_floor: lowest contact height at rest [m] (derived): the floor procedural motions
            keep the feet on, ``trans`` being relative to standing at rest.
    """

    rest_joints: np.ndarray
    contact_points: np.ndarray
    contact_joints: np.ndarray
    contact_weights: np.ndarray
    contact_foot: np.ndarray
    name: str = "default"
    rest_floor: float = field(init=False)

    def __post_init__(self) -> None:
        J = np.array(self.rest_joints, dtype=np.float64)
        c = np.array(self.contact_points, dtype=np.float64).reshape(-1, 3)
        j = np.array(self.contact_joints, dtype=np.int64).reshape(c.shape[0], -1)
        w = np.array(self.contact_weights, dtype=np.float64).reshape(j.shape)
        foot = np.array(self.contact_foot, dtype=np.int64).reshape(c.shape[0])
        if J.shape != (NUM_SMPL_JOINTS, 3) or not np.all(np.isfinite(J)):
            raise ValueError(f"rest_joints must be finite (24, 3), got {J.shape}")
        if c.shape[0] == 0 or not np.all(np.isfinite(c)) or not np.all(np.isfinite(w)):
            raise ValueError("contact points must be a non-empty finite (N, 3) array")
        if j.min() < 0 or j.max() >= NUM_SMPL_JOINTS:
            raise ValueError("contact_joints must index SMPL's 24 joints")
        if not set(np.unique(foot)) <= {0, 1}:
            raise ValueError("contact_foot must be 0 (left) or 1 (right)")
        w = w / w.sum(axis=1, keepdims=True)
        for k, v in (("rest_joints", J), ("contact_points", c), ("contact_joints", j),
                     ("contact_weights", w), ("contact_foot", foot)):
            v.setflags(write=False)
            object.__setattr__(self, k, v)
        G, P = forward_kinematics(np.zeros((NUM_SMPL_JOINTS, 3)), rest_joints=J)
        object.__setattr__(self, "rest_floor", float(self.contact_heights(G, P).min()))

    # --- construction --------------------------------------------------------------------
    @classmethod
    def default(cls) -> MotionSkeleton:
        """SMPL's approximate skeleton with one heel and one toe point per foot (what procedural
        motions are built on when no body is given); cached."""
        global _DEFAULT
        if _DEFAULT is None:
            J = SMPL_REST_JOINTS
            pts, jts = [], []
            for a, f in _FEET:
                pts += [J[a] + DEFAULT_HEEL, J[f] + DEFAULT_TOE]
                jts += [a, f]
            _DEFAULT = cls(rest_joints=J, contact_points=np.array(pts),
                           contact_joints=np.array(jts)[:, None],
                           contact_weights=np.ones((4, 1)), contact_foot=[0, 0, 1, 1],
                           name="default")
        return _DEFAULT

    @classmethod
    def from_body(cls, body, betas: np.ndarray | None = None) -> MotionSkeleton:
        """Skeleton and sole contact points of a body model at shape ``betas``.

        Args:
            body: a ``sim.bodies.model.BodyModel`` (duck-typed: ``rest_joints``, ``rest_mesh``,
                ``weights``, ``parents``, ``body_joint_map``).
            betas: shape coefficients, None for the mean shape.

        SMPL joints the body lacks (``body_joint_map`` -1) take the default skeleton's offset
        from their parent. Contact points are, per foot, the vertices mostly skinned to its
        ankle and foot joints that are extreme in some direction within ``_SUPPORT_TILT`` of
        straight down (for the ankle-dominated and foot-dominated parts separately), with
        their skinning weights mapped to SMPL's joints (a model joint outside SMPL's 24 counts
        for its nearest mapped ancestor), the ``_MAX_INFLUENCES`` largest kept.
        """
        m = np.asarray(body.body_joint_map, dtype=np.int64).reshape(NUM_SMPL_JOINTS)
        rj = np.asarray(body.rest_joints(betas), dtype=np.float64)
        J = np.empty((NUM_SMPL_JOINTS, 3))
        for j in range(NUM_SMPL_JOINTS):  # parents first
            if m[j] >= 0:
                J[j] = rj[m[j]]
            else:
                p = SMPL_PARENTS[j]
                J[j] = SMPL_REST_JOINTS[j] if p < 0 else \
                    J[p] + SMPL_REST_JOINTS[j] - SMPL_REST_JOINTS[p]
        W = _smpl_weights(body, m)
        V = np.asarray(body.rest_mesh(betas), dtype=np.float64)
        dirs = _support_directions(_SUPPORT_TILT)
        pts, jts, wts, foot = [], [], [], []
        for side, (a, f) in enumerate(_FEET):
            sel = (W[:, a] + W[:, f]) >= _FOOT_WEIGHT
            if not sel.any():  # no foot vertices: the default offsets on this body's joints
                for jj, off in ((a, DEFAULT_HEEL), (f, DEFAULT_TOE)):
                    pts.append(J[jj] + off)
                    jts.append([jj] + [0] * (_MAX_INFLUENCES - 1))
                    wts.append([1.0] + [0.0] * (_MAX_INFLUENCES - 1))
                    foot.append(side)
                continue
            sel &= V[:, 1] <= V[sel, 1].min() + _SOLE_BAND
            idx = []
            for part in (W[:, a] >= W[:, f], W[:, a] < W[:, f]):
                ids = np.nonzero(sel & part)[0]
                if ids.size:
                    idx.append(ids[np.unique(np.argmax(V[ids] @ dirs.T, axis=0))])
            ids = np.unique(np.concatenate(idx))
            top = np.argsort(-W[ids], axis=1)[:, :_MAX_INFLUENCES]
            pts.append(V[ids])
            jts.append(top)
            wts.append(np.take_along_axis(W[ids], top, axis=1))
            foot.append(np.full(ids.size, side))
        as2 = [np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in pts]
        return cls(rest_joints=J, contact_points=np.concatenate(as2),
                   contact_joints=np.concatenate([np.atleast_2d(x) for x in jts]),
                   contact_weights=np.concatenate([np.atleast_2d(x) for x in wts]),
                   contact_foot=np.concatenate([np.atleast_1d(x) for x in foot]),
                   name=str(getattr(body, "name", "body")))

    # --- kinematics ----------------------------------------------------------------------
    def forward_kinematics(self, poses: np.ndarray, trans: np.ndarray | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
        """``retarget.forward_kinematics`` on this skeleton: (G (..., 24, 3, 3), P (..., 24, 3))."""
        return forward_kinematics(poses, trans, rest_joints=self.rest_joints)

    def contact_positions(self, G: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Posed contact points [m], (..., N, 3), from global joint rotations and positions."""
        j = self.contact_joints
        off = self.contact_points[:, None, :] - self.rest_joints[j]  # (N, K, 3)
        pos = P[..., j, :] + np.einsum("...nkab,nkb->...nka", G[..., j, :, :], off)
        return np.einsum("...nka,nk->...na", pos, self.contact_weights)

    def contact_heights(self, G: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Heights [m] of the contact points, (..., N) (cheaper than the positions)."""
        j = self.contact_joints
        off = self.contact_points[:, None, :] - self.rest_joints[j]
        y = P[..., j, 1] + np.einsum("...nkb,nkb->...nk", G[..., j, 1, :], off)
        return np.einsum("...nk,nk->...n", y, self.contact_weights)

    @property
    def num_contacts(self) -> int:
        return int(self.contact_points.shape[0])

    def __repr__(self) -> str:
        return (f"MotionSkeleton(name={self.name!r}, contacts={self.num_contacts}, "
                f"rest_floor={self.rest_floor:.4f})")


_DEFAULT: MotionSkeleton | None = None


def resolve_skeleton(skeleton: MotionSkeleton | None) -> MotionSkeleton:
    """``skeleton``, or the default one when None."""
    return MotionSkeleton.default() if skeleton is None else skeleton


def _smpl_weights(body, joint_map: np.ndarray) -> np.ndarray:
    """The body's skinning weights summed onto SMPL's 24 joints, (V, 24) float64: a model
    joint outside the map counts for its nearest mapped ancestor (the root if none)."""
    Wm = np.asarray(body.weights, dtype=np.float64)
    parents = np.asarray(body.parents, dtype=np.int64)
    to_smpl = np.full(Wm.shape[1], -1, dtype=np.int64)
    for s, mj in enumerate(joint_map):
        if mj >= 0:
            to_smpl[mj] = s
    W = np.zeros((Wm.shape[0], NUM_SMPL_JOINTS))
    for mj in range(Wm.shape[1]):
        k = mj
        while k >= 0 and to_smpl[k] < 0:
            k = parents[k]
        W[:, to_smpl[k] if k >= 0 else 0] += Wm[:, mj]
    return W


def _support_directions(tilt_deg: float, rings: int = 12, per_ring: int = 24) -> np.ndarray:
    """Unit directions within ``tilt_deg`` of straight down (-Y), (n, 3): the axis plus
    ``rings`` cones of ``per_ring`` directions."""
    out = [np.array([0.0, -1.0, 0.0])]
    for phi in np.linspace(tilt_deg, 0.0, rings, endpoint=False)[::-1] * np.pi / 180.0:
        psi = np.linspace(0.0, 2.0 * np.pi, per_ring, endpoint=False)
        out.append(np.stack([np.sin(phi) * np.cos(psi), -np.cos(phi) * np.ones_like(psi),
                             np.sin(phi) * np.sin(psi)], axis=1))
    return np.concatenate([np.atleast_2d(d) for d in out])
