"""Trousers and shorts drafted from body measurements.

The trouser block as pattern books draft it (Aldrich, *Metric Pattern Cutting*, the trouser
block): per leg a front and a back panel, x = 0 on the crease line and y = 0 at the hem, drafted
with the inseam on the left (the left leg's front and the right leg's back; the others are their
mirror images). The crotch line lies the body's crotch plus ease below the waist; along it the
front is a quarter of the hip girth with ease, less ``SEAT_SHIFT``, plus the front crotch
extension (hip / 16), the back a quarter plus ``SEAT_SHIFT`` plus the back extension (hip / 10);
the crease halves the crotch line. The centre front runs straight from the waist to the hip line
and curves out to the front fork; the centre back rises higher (``BACK_RAISE``), slants in at
the waist and curves down to the back fork. Knee and hem are drafted about the crease, the front
``LEG_SHIFT`` narrower than the back each side; the back's lower leg is set out so that its
outseam is the front's moved sideways, and its fork dropped so that the inseams are equally long.
Waist suppression as for the skirt (``sim.garments.drafting.bottoms``): a dart in each panel,
the centre seams' take and the side seams; a straight waistband joins the four waist edges.

Placement (``RowPlacement``): up to the crotch line each leg's panels wrap a cone around the
leg's axis (the thigh's centre below the crotch to the leg's centre above the hem), front on
the +Z side, back on the -Z side, as wide as the two panels together, so the inseam and outseam
start closed; the two legs' cones stay ``LEG_GAP`` apart. Above it the seat is placed on the
torso: at the hip line and the waist seam each panel wraps the torso's front (back) arc from
the centre line to the side (``torso_wrap``), as the skirt does, so the centre seams and the
waist seam start closed too and the waist lands on the body's waist, where the band holds it.
A cone around the leg alone would leave the waist's side points 4-9 cm out from the body and
the held band stretched toward them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.drafting.body_frame import CLEARANCE, limb_cylinder, limb_radius, torso_section
from sim.garments.drafting.bottoms import (
    DART_SHARE,
    Outline,
    PanelRow,
    Piece,
    RowPlacement,
    band_pieces,
    band_seams,
    bottom_ease,
    check_design,
    girth_at,
    placement_rows,
    torso_wrap,
    waist_shaping,
)
from sim.garments.drafting.tops import FITS
from sim.garments.parameters import choice, parameter
from sim.garments.pattern import Edge, Pattern, Placement, Seam

FRONT_EXTENSION = 1.0 / 16.0
"""Front crotch extension beyond the centre front line, as a share of the hip girth with ease."""
BACK_EXTENSION = 1.0 / 10.0
"""Back crotch extension beyond the centre back line, as a share of the hip girth with ease."""
SEAT_SHIFT = 0.01
"""The back panel is this much wider at the hip line than a quarter, the front narrower [m]."""
LEG_SHIFT = 0.01
"""At the knee and hem the back's half width is a quarter girth plus this, the front's less [m]."""
HEM_TAPER = 0.9
"""A trouser hem's girth over the knee's (both with ease) at flare 0: Aldrich's straight
trouser block is 4-5 cm narrower at the hem than at the knee."""
CENTRE_TAKE = (0.01, 0.02)
"""How far the centre front and centre back seams slant in from the hip line to the waist [m]."""
BACK_RAISE = 0.025
"""The centre back's waist point above the side's [m]: the seat needs the longer back rise."""
TROUSER_DARTS = (0.07, 0.11)
"""Front and back dart lengths [m] below the waist."""
CROTCH_CURVE = (0.6, 0.45)
"""The crotch curve's shape: its first control point this share of the way down the centre line
from the hip line to the crotch line, its second this share of the extension in from the fork."""
LEG_CLEARANCE = 0.005
"""Least gap [m] between a leg's cone and the leg where it is placed: the thighs leave little
room between them."""
LEG_GAP = 0.004
"""Least distance [m] of a leg cone's inner side from the body's mid-plane (x = 0) at the crotch
line: the two legs start apart."""


@dataclass(frozen=True)
class PantsDesign:
    """Design parameters of trousers and shorts (units and ranges on each field)."""

    fit: str = choice("regular", tuple(FITS), "ease over the waist, hip and leg girths (BOTTOM_EASE)")
    length: float = parameter(0.95, "-", 0.1, 1.0, "the leg's length as a share of the inseam (crotch "
                              "to ankle joint): shorts ~0.2, trousers ~0.95")
    flare: float = parameter(0.0, "-", -0.3, 1.0, "the hem's girth over the knee's beyond HEM_TAPER, "
                             "relative (negative: tapered toward the ankle; shorts: over the leg's)")
    waistband: float = parameter(0.035, "m", 0.02, 0.08, "waistband height")
    waist_drop: float = parameter(0.02, "m", 0.0, 0.12, "top of the waistband below the natural waist "
                                  "(a low rise sits lower)")

    def __post_init__(self) -> None:
        check_design(self, "pants")


def leg_girth(m, y: float) -> float:
    """One leg's girth [m] at height ``y``, linear in height between the thigh (2 cm below the
    crotch), knee, calf (halfway between knee and ankle) and ankle."""
    ys = [m.ankle_height, 0.5 * (m.knee_height + m.ankle_height), m.knee_height, m.crotch_height - 0.02]
    return float(np.interp(y, ys, [m.ankle, m.calf, m.knee, m.thigh]))


@dataclass(frozen=True)
class LegLines:
    """One panel's construction [m], panel coordinates (x = 0 on the crease at the crotch line,
    y = 0 at the hem)."""

    half: float  # half the crotch line's width: crease to fork and to the outseam
    extension: float  # the crotch extension beyond the centre line
    rows: tuple  # ((y, half width, shift), ...) of the mid row and the hem, about x = shift
    crotch_y: float  # the crotch line
    fork_drop: float  # the fork below the crotch line
    hip_y: float
    waist_y: float
    side: float  # the side seam's take at the waist
    centre: tuple[float, float]  # (x, y) of the centre seam's waist point
    dart: tuple[float, float, float]  # (distance from the side's waist point, width, length)


@dataclass(frozen=True)
class PantsFrame:
    """Heights [m] the trousers are drafted at: world heights of the hem, crotch line and top
    of the waistband; panel heights (above the hem) of the mid row (the knee, or halfway up
    a shorts leg), hip line and waist seam."""

    hem_y: float
    crotch: float
    top_y: float
    mid: float
    hip: float
    waist: float
    below_knee: bool


def pants_frame(m, d: PantsDesign) -> PantsFrame:
    top_y = m.waist_height - d.waist_drop
    crotch = m.crotch_height - bottom_ease("crotch", d.fit)
    hem_y = crotch - d.length * (m.crotch_height - m.ankle_height)
    if top_y - d.waistband < m.hip_height + 0.04:
        raise WrinklesInputError(f"pants: the waist seam {top_y - d.waistband:.3f} m is within 4 cm of "
                                 f"the hip line {m.hip_height:.3f} m; lower waist_drop or the waistband")
    below = bool(hem_y < m.knee_height - 0.05)
    mid = m.knee_height - hem_y if below else 0.5 * (crotch - hem_y)
    return PantsFrame(hem_y, crotch, top_y, mid, m.hip_height - hem_y, top_y - d.waistband - hem_y, below)


def leg_widths(m, d: PantsDesign, f: PantsFrame, half: list[float]) -> tuple[list, list]:
    """(front, back) half widths about the crease at the mid row and at the hem [m]."""
    ease = bottom_ease("leg", d.fit)
    if f.below_knee:  # a little narrower than the knee (flare 0), never tighter than the leg there
        hem_g = max((m.knee + ease) * (HEM_TAPER + d.flare), leg_girth(m, f.hem_y) + 0.5 * ease)
        mids = [(m.knee + ease) / 4 - LEG_SHIFT, (m.knee + ease) / 4 + LEG_SHIFT]
    else:
        hem_g = (leg_girth(m, f.hem_y) + ease) * (1.0 + d.flare)
    hems = [hem_g / 4 - LEG_SHIFT, hem_g / 4 + LEG_SHIFT]
    if not f.below_knee:  # shorts: the mid row halfway, on the straight line to the hem
        mids = [(half[0] + hems[0]) / 2]
        mids.append(mids[0] + hems[1] - hems[0])
    return mids, hems


def leg_lines(m, d: PantsDesign, f: PantsFrame) -> tuple[LegLines, LegLines]:
    """The front and back panels' lines."""
    hip_g = max(m.hip, m.waist) + bottom_ease("hip", d.fit)
    quarter = hip_g / 4
    shaping = waist_shaping((quarter - SEAT_SHIFT, quarter + SEAT_SHIFT),
                            (girth_at(m, f.top_y) + bottom_ease("waist", d.fit)) / 4, DART_SHARE, CENTRE_TAKE)
    ext = (FRONT_EXTENSION * hip_g, BACK_EXTENSION * hip_g)
    half = [(shaping.hip[k] + ext[k]) / 2 for k in (0, 1)]
    mids, hems = leg_widths(m, d, f, half)
    crotch_y = f.crotch - f.hem_y
    shift = (half[1] - mids[1]) - (half[0] - mids[0])  # the back's outseam is the front's, moved
    rise = crotch_y - f.mid
    length = np.hypot(half[0] - mids[0], rise)
    inner = half[1] - mids[1] + shift
    drop = rise - np.sqrt(max(length ** 2 - inner ** 2, 0.0))  # equal inseams
    out = []
    for k in (0, 1):
        s = shift if k else 0.0
        side_x = half[k] - shaping.side
        waist_len = shaping.waist[k] + shaping.darts[k]
        lift = BACK_RAISE if k else 0.0
        centre = (side_x - np.sqrt(max(waist_len ** 2 - lift ** 2, 1e-8)), f.waist + lift)
        w = shaping.darts[k]
        at = side_x if k == 0 else 0.5 * waist_len  # the front dart on the crease, the back's midway
        at = float(np.clip(at, w / 2 + 0.02, waist_len - w / 2 - 0.02))
        out.append(LegLines(half[k], ext[k], ((f.mid, mids[k], s), (0.0, hems[k], s)), crotch_y,
                            drop if k else 0.0, f.hip, f.waist, shaping.side, centre,
                            (at, w, TROUSER_DARTS[k])))
    return out[0], out[1]


def leg_panel(name: str, g: LegLines, placement) -> Piece:
    """A trouser panel with its inseam on the left: hem, outseam (hem to mid row, to the hip,
    to the waist), the waist with its dart, the centre seam (waist to hip line, crotch curve to
    the fork), the inseam (fork to mid row, to the hem)."""
    (ym, mw, s), (_, hw, _) = g.rows
    fork = (-g.half, g.crotch_y - g.fork_drop)
    centre_hip = np.array([-g.half + g.extension, g.hip_y])
    down = centre_hip - np.asarray(g.centre)  # along the centre line, continued below the hip
    c1 = centre_hip + down * (CROTCH_CURVE[0] * (g.hip_y - g.crotch_y) / -down[1])
    c2 = (fork[0] + CROTCH_CURVE[1] * g.extension, fork[1])
    out = Outline()
    out.add((s - hw, 0.0), Edge(label="hem"), "hem")
    out.add((s + hw, 0.0), Edge(label="outseam"), "out")
    out.add((s + mw, ym), Edge("quadratic", ((g.half, g.crotch_y),), "outseam"), "out")
    out.add((g.half, g.hip_y), Edge("quadratic", ((g.half, 0.5 * (g.hip_y + g.waist_y)),), "outseam"), "out")
    out.add_notched((g.half - g.side, g.waist_y), g.centre, [g.dart])
    out.add(g.centre, Edge(label="crotch"), "centre")
    out.add(centre_hip, Edge("cubic", (tuple(c1), c2), "crotch"), "centre")
    out.add(fork, Edge(label="inseam"), "in")
    out.add((s - mw, ym), Edge(label="inseam"), "in")
    return out.piece(name, placement)


def leg_section_centre(vertices: np.ndarray, mask: np.ndarray, y: float) -> np.ndarray:
    """(x, y, z) [m]: the centre of the bounding box of the masked vertices within 1 cm of ``y``."""
    sel = vertices[mask & (np.abs(vertices[:, 1] - y) <= 0.01)]
    c = 0.5 * (sel.min(axis=0) + sel.max(axis=0))
    return np.array([c[0], y, c[2]])


def leg_placements(m, vertices: np.ndarray, torso_mask: np.ndarray, f: PantsFrame, sign: float,
                   lines: tuple[LegLines, LegLines]):
    """Placements of one leg's (``sign`` +1: left, -1: right) front and back panels: a cone
    around the leg's axis from the crotch line (the crotch line's widths) to the hem (the hem's),
    at least ``LEG_CLEARANCE`` off the leg, its inner side ``LEG_GAP`` off the mid-plane (the
    axis tilts out at the crotch line where the legs are close)."""
    leg = torso_mask & (vertices[:, 0] * sign > 0) & (vertices[:, 1] < m.crotch_height)
    root = leg_section_centre(vertices, leg, min(f.crotch, m.crotch_height - 0.03))
    root[1] = f.crotch
    toward = leg_section_centre(vertices, leg, max(f.hem_y + 0.03, m.ankle_height + 0.06))
    toward[1] = min(toward[1], f.crotch - 0.05)
    top = 2 * (lines[0].half + lines[1].half)
    hem = 2 * (lines[0].rows[1][1] + lines[1].rows[1][1])
    span = float(np.linalg.norm(toward - root))
    for _ in range(2):  # the inner side clear of the mid-plane (the radius grows as the axis moves)
        r = max(top / (2 * np.pi), limb_radius(vertices, leg, root, toward, (0.0, 0.1)) + LEG_CLEARANCE)
        root[0] += max(r + LEG_GAP - abs(root[0]), 0.0) * sign
    extra = LEG_CLEARANCE - CLEARANCE  # limb_cylinder adds CLEARANCE
    near_top = limb_radius(vertices, leg, root, toward, (0.0, 0.1)) + extra
    near_hem = limb_radius(vertices, leg, root, toward, (span - 0.05, span + 0.02)) + extra
    return tuple(limb_cylinder(root, toward, 0.0, top, near_top, (0.0, g.crotch_y), np.array([0.0, 0.0, z]),
                               bottom=(hem, near_hem)) for g, z in zip(lines, (1.0, -1.0), strict=True))


def seat_rows(m, vertices: np.ndarray, torso_mask: np.ndarray, f: PantsFrame, g: LegLines,
              front: bool, mirrored: bool, leg: Placement) -> RowPlacement:
    """A panel's placement: its leg's cone ``leg`` up to the crotch line, then the torso's arcs
    at the hip line and the waist seam (``torso_wrap``) from the body's centre line to its
    side."""
    sign = -1.0 if mirrored else 1.0
    rows = [PanelRow(g.crotch_y, leg, -sign * g.half, sign * g.half)]
    for world_y, y, centre, side in ((m.hip_height, g.hip_y, -g.half + g.extension, g.half),
                                     (f.hem_y + g.waist_y, g.waist_y, g.centre[0], g.half - g.side)):
        arc = torso_wrap(torso_section(vertices, torso_mask, world_y), front, y, side - centre, f.hem_y)
        arc = dataclasses.replace(arc, origin=(sign * centre, y))
        rows.append(PanelRow(y, arc, sign * centre, sign * side))
    return placement_rows(rows)


def draft_pants(m, vertices: np.ndarray, torso_mask: np.ndarray, joints: np.ndarray, d: PantsDesign,
                name: str = "pants") -> Pattern:
    """Trousers' (shorts') pattern for a body: measurements ``m``, the rest vertices and torso
    mask for placement (``joints`` is unused: the legs' axes come from the leg sections)."""
    f = pants_frame(m, d)
    lines = leg_lines(m, d, f)
    front, back = lines
    left = leg_placements(m, vertices, torso_mask, f, 1.0, lines)
    right = leg_placements(m, vertices, torso_mask, f, -1.0, lines)

    def place(g: LegLines, front_side: bool, mirrored: bool, leg: Placement) -> RowPlacement:
        return seat_rows(m, vertices, torso_mask, f, g, front_side, mirrored, leg)

    front_l = leg_panel("front_l", front, place(front, True, False, left[0]))
    back_r = leg_panel("back_r", back, place(back, False, False, right[1]))
    front_r = front_l.mirrored("front_r", place(front, True, True, right[0]))
    back_l = back_r.mirrored("back_l", place(back, False, True, left[1]))
    seams = []
    for a, b in ((front_l, back_l), (back_r, front_r)):  # unmirrored first: its edges run the other way
        for group in ("out", "in"):
            seams += [Seam(x, y) for x, y in zip(a.edges(group), b.edges(group), strict=True)]
    seams += [Seam(x, y) for x, y in zip(front_l.edges("centre"), front_r.edges("centre"), strict=True)]
    seams += [Seam(x, y) for x, y in zip(back_r.edges("centre"), back_l.edges("centre"), strict=True)]
    for p in (front_l, front_r, back_l, back_r):
        seams += p.dart_seams()
    # the waist pieces left to right seen from outside: the mirrored panels' in drafting order
    fw = front_r.edges("waist") + front_l.edges("waist")[::-1]
    bw = back_l.edges("waist") + back_r.edges("waist")[::-1]
    by_name = {pc.panel.name: pc.panel for pc in (front_l, front_r, back_l, back_r)}
    length = [[by_name[n].edge_length(i) for n, i in w] for w in (fw, bw)]
    band_f, band_b = band_pieces(vertices, torso_mask, f.top_y, d.waistband, *length)
    seams += band_seams(band_f, band_b, fw, bw)
    panels = (front_l, front_r, back_l, back_r, band_f, band_b)
    return Pattern(name, tuple(p.panel for p in panels), tuple(seams), {"design": dict(d.__dict__), "ease": {
        k: bottom_ease(k, d.fit) for k in ("waist", "hip", "leg", "crotch")}})
