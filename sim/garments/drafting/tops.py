"""Tops drafted from body measurements: t-shirt, long sleeve, tank top, dress.

The bodice block as pattern books draft it (e.g. Aldrich, *Metric Pattern Cutting*, the
"easy-fitting" jersey and shirt blocks): a front and a back panel from the hem up the side seam to
the underarm, the armhole curving up to the shoulder point, the shoulder line sloping up to the
side neck point and the neckline (round: a scoop, V: two straight lines to a point on the centre
front; the back neck is 2 cm deep). Widths are a quarter of each girth plus a quarter of its
ease; heights are the body's landmarks. A set-in sleeve is a tube whose cap (the crown over the
shoulder) is as long as the armhole it is sewn into plus the cap ease; its height is solved for
that length.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.garments.drafting.body_frame import (
    SMPL,
    ShoulderTape,
    limb_cylinder,
    limb_radius,
    torso_cylinder,
    torso_section,
)
from sim.garments.drafting.hood import hood_panels
from sim.garments.parameters import check_parameter, choice, parameter, parameter_specs
from sim.garments.pattern import Edge, Panel, Pattern, Placement, Seam, parameter_at_length, split_edge

FITS = {"tight": 0, "regular": 1, "loose": 2}
"""Fit names and their column in ``EASE``."""
EASE = {
    "chest": (0.03, 0.10, 0.20), "waist": (0.04, 0.14, 0.26), "hip": (0.04, 0.10, 0.20),
    "bicep": (0.03, 0.08, 0.14), "wrist": (0.05, 0.08, 0.12), "armhole_drop": (0.03, 0.05, 0.07),
    "shoulder": (0.0, 0.01, 0.03),
}
"""Ease [m] per girth (added to the whole girth) and per placement, by fit (tight, regular,
loose): Aldrich's jersey block takes ~4 cm at the chest, the shirt block ~10 cm, oversized
cuts 20 cm and more. The armhole drops 3 / 5 / 7 cm below the armpit and its top, the shoulder
point, stands as high as the bodice's length over the shoulder reaches (``ShoulderTape.over``): each
armhole is long enough for a sleeve cap 11-16 cm high around the upper arm plus its ease, a
shirt's set-in sleeve that hangs along the lowered arm (default body and +-2 sigma shapes). Fine
t-shirt and long sleeve on an H200 (walk / arm raise, worst strain): 0.78 / 0.39 and 0.17 / 0.65
with these caps, 0.72 / 1.36 and 0.65 / 1.69 with 6-8.4 cm caps (the shoulder point not raised).
At 1.5 / 3 / 5 cm drops the caps are flat (1 cm): sleeves that stand out from the shoulder as in
the T-pose they are sewn in and fold into the armpit when the arm comes down (coarse t-shirt,
CPU: arm raise strain 0.64 and 16 crossings against 0.19 and none at 3 / 5 / 7 cm)."""
STRAIGHT = (0.0, 0.92, 1.0)
"""The side seam's half width at waist and hip is at least this share of the chest's, by fit:
a regular tee falls nearly straight from the underarm, a tight one follows the waist."""
HOOD_GAP = 0.045
"""The hood's halves end this far [m] from the centre front along the neckline: a small opening
between them at the throat, where they would otherwise lie on each other."""
CAP_EASE = 0.01
"""A sleeve cap is this much longer than its armhole (relative): the ease sewn into the crown. A
12-17 cm cap with 3 % eased in puckers at the crown: the coarse t-shirt's sewn rest shape crossed
itself there (2 edges, rest strain 0.22 against none and 0.07 at 1 %, CPU)."""


@dataclass(frozen=True)
class TopDesign:
    """Design parameters of a top (units and ranges on each field, ``wrinkles garments --params``)."""

    fit: str = choice("regular", tuple(FITS), "ease over the body's girths (EASE)")
    hem_drop: float = parameter(0.22, "m", -0.1, 0.9, "hem below the natural waist (negative: cropped)")
    neckline: str = choice("round", ("round", "v"), "neckline shape")
    neck_depth: float = parameter(0.08, "m", 0.01, 0.3, "front neck depth below the side neck point")
    neck_width: float = parameter(0.01, "m", 0.0, 0.1, "neck width beyond the neck's, each side")
    sleeve_length: float = parameter(0.2, "m", 0.0, 0.8, "sleeve from the shoulder point, ending at the "
                                     "wrist at most (0: sleeveless)")
    strap_width: float = parameter(0.0, "m", 0.0, 0.2,
                                   "a sleeveless top's shoulder beyond the neck (0: to the shoulder point)")
    flare: float = parameter(0.0, "-", 0.0, 1.5, "the hem's extra width over the hip's, relative (dresses)")
    hood: str = choice("no", ("no", "yes"), "a two-piece hood sewn into the neckline")

    def __post_init__(self) -> None:
        for name, spec in parameter_specs(type(self)).items():
            check_parameter(name, getattr(self, name), spec, "top")


def ease(name: str, fit: str) -> float:
    return EASE[name][FITS[fit]]


def side_points(m, d: TopDesign, hem_y: float, armpit_y: float) -> list[tuple[float, float]]:
    """The side seam's corners (height above the hem, half width) from the hem up to the
    underarm: the hem, the hip and waist where the hem is below them, the underarm."""
    chest = (m.chest + ease("chest", d.fit)) / 4
    floor = STRAIGHT[FITS[d.fit]] * chest
    waist = max((m.waist + ease("waist", d.fit)) / 4, floor)
    hip = max((m.hip + ease("hip", d.fit)) / 4, floor)
    pts = []
    if hem_y < m.hip_height - 0.02:
        pts.append((m.hip_height - hem_y, hip))
    if hem_y < m.waist_height - 0.02:
        pts.append((m.waist_height - hem_y, waist))
    pts.append((armpit_y - hem_y, chest))
    if hem_y < m.hip_height - 0.02:  # below the hip the skirt part flares
        drop = m.hip_height - hem_y
        hem_hw = hip * (1.0 + d.flare) + 0.15 * drop * d.flare
    elif hem_y < m.waist_height - 0.02:  # between waist and hip: the body's width there
        t = (m.waist_height - hem_y) / max(m.waist_height - m.hip_height, 1e-6)
        hem_hw = waist + t * (hip - waist)
    else:
        hem_hw = chest
    return [(0.0, hem_hw)] + pts


def bodice_panel(name: str, m, d: TopDesign, front: bool, hem_y: float, placement: Placement,
                 over: Callable[[float, float], float]) -> Panel:
    """A front or back panel: x = 0 on the centre line, y = 0 at the hem, counter-clockwise
    seen from outside. Edge labels: hem, side, armhole, shoulder, neckline (two edges, meeting at
    the centre line). ``over(x, top_y)``: the length [m] the panel needs beyond the rise from
    chest level to reach its shoulder seam at height ``top_y``, ``x`` off the centre line
    (``over_of``); the side neck and shoulder points stand that much higher."""
    armpit_y = m.armpit_height - ease("armhole_drop", d.fit)
    side = side_points(m, d, hem_y, armpit_y)
    neck_hw = m.neck_base / (2 * np.pi) + d.neck_width
    if d.strap_width > 0:
        sp_x = neck_hw + d.strap_width
    else:
        sp_x = 0.5 * m.shoulder_width + ease("shoulder", d.fit)
    hps_body = m.neck_base_height + 0.005 - hem_y  # the side neck point's rise from the hem
    hps_y = hps_body + over(neck_hw, m.neck_base_height + 0.005)
    sp_top = m.shoulder_height + 0.012
    sp_y = sp_top + over(min(sp_x, 0.5 * m.shoulder_width), sp_top) - hem_y
    ua_y, ua_x = side[-1]
    depth = d.neck_depth if front else 0.02
    scoop = 0.018 if front else 0.008  # the armhole's hollow, deeper in front
    right = [(x, y) for y, x in side]  # hem to underarm, right half
    corners = [(-right[0][0], 0.0)] + right + [(sp_x, sp_y), (neck_hw, hps_y)]
    edges = [Edge(label="hem")] + [Edge(label="side")] * (len(right) - 1)
    armhole = Edge("cubic", ((ua_x - 0.6 * (ua_x - sp_x + scoop), ua_y),
                             (sp_x - scoop, ua_y + 0.55 * (sp_y - ua_y))), "armhole")
    edges += [armhole, Edge(label="shoulder")]
    # the neckline in halves at the centre, ``depth`` below the side neck point on the body: the
    # centre front and back go over no shoulder
    low = hps_body - depth
    drop = 0.55 * (hps_y - low)
    corners += [(0.0, low), (-neck_hw, hps_y)]
    if d.neckline == "v" and front:
        edges += [Edge(label="neckline"), Edge(label="neckline")]
    else:  # a scoop: vertical at the side neck points, level at the centre
        edges += [Edge("cubic", ((neck_hw, hps_y - drop), (0.55 * neck_hw, low)), "neckline"),
                  Edge("cubic", ((-0.55 * neck_hw, low), (-neck_hw, hps_y - drop)), "neckline")]
    corners += [(-sp_x, sp_y), (-ua_x, ua_y)] + [(-x, y) for x, y in right[-2:0:-1]]
    c1, c2 = armhole.controls
    edges += [Edge(label="shoulder"),
              Edge("cubic", ((-c2[0], c2[1]), (-c1[0], c1[1])), "armhole")]
    edges += [Edge(label="side")] * (len(right) - 1)
    return Panel(name, np.array(corners), tuple(edges), placement)


def cap_height(half_width: float, target: float) -> float:
    """Sleeve cap height [m] whose half cap (``cap_edge``) is ``target`` [m] long."""
    lo, hi = 0.01, 0.3
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        p = Panel("cap", np.array([[half_width, 0.0], [0.0, mid], [0.0, 0.0]]),
                  (cap_edge(half_width, mid), Edge(), Edge()))
        lo, hi = (mid, hi) if p.edge_length(0) < target else (lo, mid)
    return 0.5 * (lo + hi)


def cap_edge(half_width: float, height: float, base: float = 0.0, left: bool = False) -> Edge:
    """Half a sleeve cap from the underarm (±half_width, base) to the crown (0, base + height)
    (``left``: from the crown down to the left underarm): a cubic, flat at the crown."""
    c1 = (0.75 * half_width, base + 0.1 * height)
    c2 = (0.45 * half_width, base + height)
    if left:
        return Edge("cubic", ((-c2[0], c2[1]), (-c1[0], c1[1])), "sleeve_cap")
    return Edge("cubic", (c1, c2), "sleeve_cap")


def sleeve_panel(name: str, m, d: TopDesign, armhole: float, placement_of) -> Panel:
    """A set-in sleeve: cuff at y = 0, underarm seam edges 1 and 4, cap edges 2 and 3, its cap
    ``armhole`` × (1 + ``CAP_EASE``) long on each side. ``placement_of(top)`` places it with its
    crown ``top`` at the shoulder point."""
    bw = (m.bicep + ease("bicep", d.fit)) / 2
    ch = cap_height(bw, armhole * (1 + CAP_EASE))
    length = max(min(d.sleeve_length, m.arm_length), ch + 0.03)  # a cuff past the wrist grips the hand
    t = np.clip((length - ch) / max(m.arm_length, 1e-6), 0.0, 1.0)
    girth = float(np.interp(t, [0.0, 0.5, 1.0], [m.bicep, m.elbow, m.wrist]))
    cw = min(bw, (girth + ease("wrist", d.fit) + 0.03 * (1 - t)) / 2)
    base = length - ch
    corners = np.array([[-cw, 0.0], [cw, 0.0], [bw, base], [0.0, length], [-bw, base]])
    edges = (Edge(label="cuff"), Edge(label="underarm"), cap_edge(bw, ch, base),
             cap_edge(bw, ch, base, left=True), Edge(label="underarm"))
    return Panel(name, corners, edges, placement_of((0.0, length), 2 * cw))


def sleeve_placement(m, d: TopDesign, vertices: np.ndarray, mask: np.ndarray, joints: np.ndarray, limb: str):
    """``placement_of(top, cuff)`` of a sleeve on the ``limb`` ("left"/"right") arm: a cone
    around the arm's axis (shoulder to wrist joint) from the bicep's girth at the crown (``top``,
    at the shoulder point) to the cuff's girth ``cuff`` [m] at the cuff."""
    js, jw = joints[SMPL[f"{limb}_shoulder"]], joints[SMPL[f"{limb}_wrist"]]
    start = abs(np.sign(js[0]) * 0.5 * m.shoulder_width - js[0])
    arm = float(np.linalg.norm(jw - js))

    def place(top, cuff):
        cuff_at = min(start + top[1], arm)
        r_top = limb_radius(vertices, mask, js, jw, (start, start + 0.15))
        r_cuff = limb_radius(vertices, mask, js, jw, (cuff_at - 0.03, cuff_at + 0.01))
        return limb_cylinder(js, jw, start, m.bicep + ease("bicep", d.fit), r_top, top,
                             np.array([0.0, 1.0, 0.0]), bottom=(cuff, r_cuff))
    return place


def draft_top(m, vertices: np.ndarray, torso_mask: np.ndarray, arm_mask: dict, joints: np.ndarray,
              d: TopDesign, name: str, faces: np.ndarray) -> Pattern:
    """A top's pattern for a body: measurements ``m``, rest vertices, faces and joints for
    placement and for the bodice's length over the shoulders (``over_of``)."""
    hem_y = m.waist_height - d.hem_drop
    section = torso_section(vertices, torso_mask, m.chest_height)
    half = (m.chest + ease("chest", d.fit)) / 4
    hem_half = side_points(m, d, hem_y, m.armpit_height)[0][1]
    over = over_of(vertices, faces, torso_mask, m.chest_height)
    front, back = (bodice_panel(side, m, d, side == "front", hem_y,
                                torso_cylinder(section, half, side == "front", hem_y, hem_half),
                                over)
                   for side in ("front", "back"))
    k = len(side_points(m, d, hem_y, 0.0)) - 1  # side edges per side
    arm_f = k + 1
    if d.hood == "yes":  # the hood's halves start HOOD_GAP from the centre front: no overlap there
        i = arm_f + 2
        front = split_edge(front, i, parameter_at_length(front, i, front.edge_length(i) - HOOD_GAP))
        front = split_edge(front, i + 2, parameter_at_length(front, i + 2, HOOD_GAP))
    nf, nb = len(front.edges), len(back.edges)
    seams = [Seam(("front", 1 + i), ("back", nb - 1 - i)) for i in range(k)]  # side seams at +x
    seams += [Seam(("front", nf - 1 - i), ("back", 1 + i)) for i in range(k)]  # and at -x
    seams += [Seam(("front", arm_f + 1), ("back", nb - k - 2)),  # right-hand shoulders
              Seam(("front", nf - k - 2), ("back", arm_f + 1))]
    panels = [front, back]
    if d.sleeve_length > 0:
        armholes = float(np.mean([front.edge_length(arm_f), back.edge_length(arm_f)]))
        for side, limb in (("l", "left"), ("r", "right")):
            panels.append(sleeve_panel(f"sleeve_{side}", m, d, armholes,
                                       sleeve_placement(m, d, vertices, arm_mask[side], joints, limb)))
        # sleeve_l (+x arm): its edge 2 is on the back, edge 3 on the front (see limb_cylinder)
        seams += [Seam(("sleeve_l", 1), ("sleeve_l", 4)), Seam(("sleeve_r", 1), ("sleeve_r", 4)),
                  Seam(("sleeve_l", 2), ("back", nb - k - 1)), Seam(("sleeve_l", 3), ("front", arm_f)),
                  Seam(("sleeve_r", 2), ("front", nf - k - 1)), Seam(("sleeve_r", 3), ("back", arm_f))]
    if d.hood == "yes":
        hood, hood_seams = hood_panels(front.edge_length(arm_f + 2), back.edge_length(arm_f + 3), HOOD_GAP,
                                       *head_geometry(vertices, joints, m.neck_base_height))
        panels += hood
        # the left half's neck edges meet the +x halves of the necklines, the right half's the -x
        seams += hood_seams + [
            Seam(("hood_l", 0), ("front", arm_f + 2)), Seam(("hood_l", 1), ("back", arm_f + 3)),
            Seam(("hood_r", 4), ("front", arm_f + 5)), Seam(("hood_r", 3), ("back", arm_f + 2))]
    return Pattern(name, tuple(panels), tuple(seams), {"design": d.__dict__.copy()})


def over_of(vertices: np.ndarray, faces: np.ndarray, torso_mask: np.ndarray,
            chest_y: float) -> Callable[[float, float], float]:
    """``over(x, top_y)`` of both bodice panels (``bodice_panel``): the mean of the front's and
    the back's ``ShoulderTape.over``, so the two armholes stay alike for the sleeve cap and the
    seam lies where the two lengths meet over the shoulder; each (x, top_y) measured once for
    both panels."""
    tape = ShoulderTape(vertices, faces, torso_mask, chest_y)

    @functools.cache
    def over(x: float, top_y: float) -> float:
        return 0.5 * (tape.over(x, top_y, True) + tape.over(x, top_y, False))
    return over


def head_geometry(vertices: np.ndarray, joints: np.ndarray, neck_y: float):
    """(head centre (x, z), neck base height, head top height, head radius) [m] for a hood."""
    centre = joints[SMPL["head"]][[0, 2]]
    head = vertices[(vertices[:, 1] > joints[SMPL["head"]][1] - 0.05)
                    & (np.abs(vertices[:, 0] - centre[0]) < 0.15)]
    radius = float(np.linalg.norm(head[:, [0, 2]] - centre, axis=1).max())
    return centre, neck_y, float(head[:, 1].max()), radius
