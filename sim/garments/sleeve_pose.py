"""Sleeves of a pattern file turned onto the arms of our rest body.

GarmentCode and GarmentCodeData place a sleeve's panels along the arm of their body, which
stands in an A-pose: ``Sleeve`` (``assets/garment_programs/sleeves.py``) builds the panels with
the arm along their x axis, pivots them at the shoulder point and turns them down by the body's
``arm_pose_angle`` (40-45.5° on GarmentCode's bodies, ``assets/bodies/*.yaml``), so the sleeves
of GarmentCodeData's files hang about 50° below the horizontal. Our rest body stands in SMPL's
T-pose (arms along ±X). Sewn where the file puts them, a sleeve's seams are pulled 20-40 cm to
the torso and the arm and the cloth folds through itself (``tests/test_sleeve_pose.py``).

``pose_sleeves`` turns each arm's panels as one rigid piece from the sleeve's direction in the
file to the body's arm direction (about their common normal), then moves it so that the line
through the sleeve's centre along its direction is the arm's axis and the sleeve's side of the
armhole seams lies, along the arm, where the body's side does (so the armhole seams start
closed along the arm and the turn's pivot does not matter):

- arm panels: those labelled "arm" (GarmentCode's panel label of sleeves and their cuffs), or,
  in a file without panel labels, those whose name has "sleeve" in it or starts with "sl_"
  (GarmentCode's panel names ``{side}_sleeve_f``, ``sl_{side}...``); a panel's arm is the side
  (+x left, -x right) its placed outline's centre lies on.
- the sleeve's direction: the sum of the chords of the seams that join one arm's panels to each
  other (a sleeve's long seams run along the arm), oriented away from the body; with no such
  seam, from the centre of its armhole seams (those to the other panels) to its centre.
- the sleeve's centre: the mean of its panels' outline centres.
- the arm: the line fitted to the rest body's vertices between 45 % and 80 % of the arm's reach
  from the body's centre plane (upper arm and forearm, neither the shoulder nor the hand;
  its centre lies 0.3 mm from the elbow-wrist line of the default body).

A sleeve within ``TOLERANCE_DEG`` of its arm's direction is left where it is (a file made for a
T-posed body, our own patterns' sleeves).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sim.garments.pattern import Pattern, Placement

TOLERANCE_DEG = 10.0
"""Sleeves whose direction lies within this angle [deg] of the body's arm are not turned."""
ARM_SPAN = (0.45, 0.8)
"""Part of the arm's reach (|x| over the body's largest |x|) whose vertices give its axis."""


def arm_panels(pattern: Pattern) -> dict[int, list[str]]:
    """The names of the arm panels by side (+1: +x, the left arm; -1: -x, the right arm)."""
    labels = pattern.parameters.get("panel_labels") or {}
    if labels:
        names = [p.name for p in pattern.panels if labels.get(p.name) == "arm"]
    else:
        names = [p.name for p in pattern.panels
                 if "sleeve" in p.name.lower() or p.name.lower().startswith("sl_")]
    out: dict[int, list[str]] = {}
    for p in pattern.panels:
        if p.name in names:
            side = 1 if float(np.mean(p.placement.place(p.outline(4))[:, 0])) >= 0 else -1
            out.setdefault(side, []).append(p.name)
    return out


def body_arm(body_vertices: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """A point on the rest body's ``side`` arm axis and the arm's unit direction away from the
    body [m] (``ARM_SPAN``)."""
    v = np.asarray(body_vertices, np.float64)
    reach = side * v[:, 0]
    top = float(reach.max())
    p = v[(reach > ARM_SPAN[0] * top) & (reach < ARM_SPAN[1] * top)]
    centre = p.mean(axis=0)
    direction = np.linalg.eigh(np.cov((p - centre).T))[1][:, -1]
    return centre, direction * (1.0 if direction[0] * side > 0 else -1.0)


def _seam_points(pattern: Pattern, ref: tuple[str, int], n: int = 8) -> np.ndarray:
    p = pattern.panel(ref[0])
    return p.placement.place(p.edge_curve(ref[1], n))


def sleeve_axis(pattern: Pattern, names: list[str], side: int) -> dict[str, np.ndarray]:
    """Where the placements put the arm panels ``names`` [m]: "direction" (unit, away from the
    body), "centre", "hole" (the centre of their side of the armhole seams) and "partner" (of
    the other panels' side); see the module."""
    inner, hole, partner = [], [], []
    for s in pattern.seams:
        a, b = s.a[0] in names, s.b[0] in names
        if a and b:
            inner += [_seam_points(pattern, s.a, 1), _seam_points(pattern, s.b, 1)]
        elif a or b:
            hole.append(_seam_points(pattern, s.a if a else s.b))
            partner.append(_seam_points(pattern, s.b if a else s.a))
    centre = np.mean([pattern.panel(n).placement.place(pattern.panel(n).outline(8)).mean(axis=0)
                      for n in names], axis=0)
    hole_c = np.concatenate(hole).mean(axis=0) if hole else centre
    partner_c = np.concatenate(partner).mean(axis=0) if partner else hole_c
    if inner:
        chords = np.array([c[1] - c[0] for c in inner])
        direction = (chords * np.where(chords[:, 0] * side < 0, -1.0, 1.0)[:, None]).sum(axis=0)
    else:
        direction = centre - hole_c
    direction = direction / max(float(np.linalg.norm(direction)), 1e-12)
    return {"direction": direction, "centre": centre, "hole": hole_c, "partner": partner_c}


def _turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation taking unit vector ``a`` to unit vector ``b`` about their common normal."""
    k = np.cross(a, b)
    s, c = float(np.linalg.norm(k)), float(a @ b)
    if s < 1e-12:
        return np.eye(3)
    k = k / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def _moved(pl: Placement, r: np.ndarray, pivot: np.ndarray, shift: np.ndarray) -> Placement:
    anchor = pivot + r @ (np.asarray(pl.anchor, np.float64) - pivot) + shift
    return replace(pl, anchor=tuple(float(x) for x in anchor),
                   u_dir=tuple(float(x) for x in r @ np.asarray(pl.u_dir, np.float64)),
                   v_dir=tuple(float(x) for x in r @ np.asarray(pl.v_dir, np.float64)))


def pose_sleeves(pattern: Pattern, body_vertices: np.ndarray) -> Pattern:
    """``pattern`` with each arm's panels turned and moved onto the rest body's arm (the
    module); a pattern with no arm panels, or with sleeves along the arms, comes back as it is."""
    moves = {}
    for side, names in arm_panels(pattern).items():
        sl = sleeve_axis(pattern, names, side)
        point, arm = body_arm(body_vertices, side)
        if np.degrees(np.arccos(np.clip(sl["direction"] @ arm, -1.0, 1.0))) <= TOLERANCE_DEG:
            continue
        r = _turn(sl["direction"], arm)
        off = sl["centre"] - point
        across = -(off - (off @ arm) * arm)  # the centre onto the arm's axis
        along = ((sl["partner"] - sl["centre"] - r @ (sl["hole"] - sl["centre"])) @ arm) * arm
        moves.update({n: (r, sl["centre"], across + along) for n in names})
    if not moves:
        return pattern
    panels = tuple(replace(p, placement=_moved(p.placement, *moves[p.name])) if p.name in moves else p
                   for p in pattern.panels)
    return replace(pattern, panels=panels)
