"""Skirts drafted from body measurements, and the waist pieces skirts and trousers share.

The skirt block as pattern books draft it (Aldrich, *Metric Pattern Cutting*, the close-fitting
skirt block): a front and a back panel, each from one side seam to the other, x = 0 on the centre
line and y = 0 at the hem, counter-clockwise seen from outside. Each half is a quarter of the hip
girth plus a quarter of its ease at the hip line, and a quarter of the waist girth plus a quarter
of its ease at the waist; the difference is taken up by the side seam's hip curve and one dart
each side of front and back (the back's wider and longer, ``DART_SHARE``, ``SKIRT_DARTS``). An
A-line skirt (``flare`` > 0) closes the darts by that share, the side seams taking the rest, and
widens the hem; the hem curves up at the sides to meet the slanted side seams at right angles,
so that it hangs level, and so does the waist, so that the flare falls along the whole hem. A
straight waistband (front and back halves) is sewn to the waist; its top edge ("waistband")
holds the garment while it settles.

Placement (``RowPlacement``): each panel wraps the torso's front (back) arc at the hip line,
widening as a cone to the hem, and the narrower arc at the waist seam (``torso_wrap``: two
arcs, front and back, that meet at the body's sides and stand off it equally there and at the
centre); the band wraps the same arcs at its height. Panel and band then start where they are
sewn, around the body, with their seams nearly closed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.drafting.body_frame import TorsoSection, torso_section
from sim.garments.drafting.hood import mirror_panel
from sim.garments.drafting.tops import FITS
from sim.garments.parameters import check_parameter, choice, parameter, parameter_specs
from sim.garments.pattern import Edge, Panel, Pattern, Placement, Seam

BOTTOM_EASE = {
    "waist": (0.01, 0.02, 0.04), "hip": (0.03, 0.05, 0.10), "leg": (0.04, 0.10, 0.18),
    "crotch": (0.01, 0.02, 0.035),
}
"""Ease [m] by fit (tight, regular, loose), added to a whole girth (waist, hip, leg: thigh, knee
and hem) or, for "crotch", the crotch seam's depth below the body's crotch: Aldrich's skirt and
trouser blocks take 1-2 cm at the waist and 4-6 cm at the hip; loose cuts take about double."""
DART_SHARE = (0.3, 0.5)
"""Front and back dart widths as shares of one quarter's hip-to-waist difference; the side seam
takes the rest (Aldrich's skirt block: front darts 1.5-2 cm, back darts 2.5-3 cm)."""
MAX_DART = 0.035
"""Widest dart [m]; more suppression goes to the side seams."""
MIN_DART = 0.004
"""Darts narrower than this [m] are left out (the side seams take them)."""
SKIRT_DARTS = (0.09, 0.13)
"""Front and back skirt dart lengths [m] below the waist (pattern books: 9-10 cm, 13-14 cm)."""
DART_AT = 0.45
"""A dart's centre from the centre line, as a share of the panel's half width at the waist."""
MIN_GAP = 0.004
"""Least gap [m] between a torso panel's arc and the body's side and front at the height it is
fitted at (a tight waistband's; looser panels stand off further)."""
FLARE_SLOPE = 0.35
"""Outward slant of an A-line skirt's side seam below the hip at flare 1 (metres out per metre
down)."""


def bottom_ease(name: str, fit: str) -> float:
    return BOTTOM_EASE[name][FITS[fit]]


def check_design(design, what: str) -> None:
    """Raise ``WrinklesInputError`` unless every field of ``design`` is within its ``Parameter``."""
    for name, spec in parameter_specs(type(design)).items():
        check_parameter(name, getattr(design, name), spec, what)


@dataclass(frozen=True)
class SkirtDesign:
    """Design parameters of a skirt (units and ranges on each field)."""

    fit: str = choice("regular", tuple(FITS), "ease over the waist and hip girths (BOTTOM_EASE)")
    length: float = parameter(0.55, "m", 0.3, 1.1, "from the top of the waistband to the hem")
    flare: float = parameter(0.0, "-", 0.0, 1.0, "0: straight with waist darts; 1: A-line, darts "
                             "closed and the hem widened")
    waistband: float = parameter(0.035, "m", 0.02, 0.08, "waistband height")
    waist_drop: float = parameter(0.0, "m", 0.0, 0.1, "top of the waistband below the natural waist")

    def __post_init__(self) -> None:
        check_design(self, "skirt")


def girth_at(m, y: float) -> float:
    """The body's girth [m] at height ``y``: the waist's above the waist line, the hip's below
    the hip line, linear in height between them."""
    t = np.clip((m.waist_height - y) / max(m.waist_height - m.hip_height, 1e-6), 0.0, 1.0)
    return float(m.waist + t * (m.hip - m.waist))


@dataclass(frozen=True)
class WaistShaping:
    """How a front and a back quarter go from their hip widths to their waist widths [m].

    Attributes:
        hip: (front, back) half widths at the hip line.
        waist: (front, back) half widths at the waist, darts closed.
        darts: (front, back) dart widths.
        centre: (front, back) take of the centre seam (trousers' centre front and back).
        side: take of the side seam, the same front and back so the side seams match.
    """

    hip: tuple[float, float]
    waist: tuple[float, float]
    darts: tuple[float, float]
    centre: tuple[float, float]
    side: float


def waist_shaping(hip: tuple[float, float], waist_quarter: float, dart_share: tuple[float, float],
                  centre: tuple[float, float] = (0.0, 0.0)) -> WaistShaping:
    """Share the hip-to-waist difference of a front and a back quarter (hip half widths ``hip``,
    waist a quarter girth ``waist_quarter`` [m] each on average) among darts (``dart_share``
    of a quarter's difference, at most ``MAX_DART``, none under ``MIN_DART``), centre seams
    (``centre``) and the side seam. A waist wider than the hips gets no darts and a side
    seam that slants out."""
    total = hip[0] + hip[1] - 2.0 * waist_quarter
    darts = [min(s * max(total, 0.0) / 2, MAX_DART) for s in dart_share]
    darts = [w if w >= MIN_DART else 0.0 for w in darts]
    cent = [max(c, 0.0) for c in centre]
    used = sum(darts) + sum(cent)
    if used > max(total, 0.0):
        scale = max(total, 0.0) / used
        darts, cent = [w * scale for w in darts], [c * scale for c in cent]
    side = (total - sum(darts) - sum(cent)) / 2
    waist = tuple(hip[k] - side - darts[k] - cent[k] for k in (0, 1))
    return WaistShaping(tuple(hip), waist, tuple(darts), tuple(cent), side)


@dataclass
class Outline:
    """A panel's outline while it is drafted: corners, the edge leaving each, and the indices of
    named groups of edges ("hem", "waist", "dart" legs in pairs, seams' edges...)."""

    corners: list = field(default_factory=list)
    edges: list = field(default_factory=list)
    groups: dict = field(default_factory=dict)

    def add(self, corner, edge: Edge, group: str | None = None) -> None:
        if group:
            self.groups.setdefault(group, []).append(len(self.edges))
        self.corners.append((float(corner[0]), float(corner[1])))
        self.edges.append(edge)

    def add_notched(self, right, left, darts) -> None:
        """The straight waist from corner ``right`` toward corner ``left`` (added next), with V
        darts cut into it: ``darts`` (centre's distance from ``right`` along the waist, width,
        length) [m] in order from the right. The pieces join group "waist", the legs "dart"."""
        right, left = np.asarray(right, np.float64), np.asarray(left, np.float64)
        d = (left - right) / np.linalg.norm(left - right)
        inward = np.array([-d[1], d[0]])  # the panel's inside is left of a counter-clockwise edge
        self.add(right, Edge(label="waist"), "waist")
        for at, width, length in darts:
            if width <= 0.0:
                continue
            self.add(right + (at - width / 2) * d, Edge(label="dart"), "dart")
            self.add(right + at * d + length * inward, Edge(label="dart"), "dart")
            self.add(right + (at + width / 2) * d, Edge(label="waist"), "waist")

    def piece(self, name: str, placement: Placement) -> Piece:
        return Piece(Panel(name, np.array(self.corners), tuple(self.edges), placement),
                     {k: list(v) for k, v in self.groups.items()})


@dataclass(frozen=True)
class Piece:
    """A drafted panel and its named edge groups (indices into its edges)."""

    panel: Panel
    groups: dict

    def edges(self, group: str) -> list[tuple[str, int]]:
        return [(self.panel.name, i) for i in self.groups.get(group, [])]

    def dart_seams(self) -> list[Seam]:
        legs = self.edges("dart")
        return [Seam(legs[k], legs[k + 1], dart=True) for k in range(0, len(legs), 2)]

    def mirrored(self, name: str, placement: Placement) -> Piece:
        """The mirror image (x -> -x), counter-clockwise: edge i becomes edge K - 1 - i; groups
        keep their order along the outline as drafted."""
        k = len(self.panel.edges)
        panel = mirror_panel(name, self.panel.corners, self.panel.edges, placement)
        return Piece(panel, {g: [k - 1 - i for i in idx] for g, idx in self.groups.items()})


def waistband(name: str, pieces: list[float], height: float, placement: Placement) -> Piece:
    """A straight band, x = 0 at its middle and y = 0 at its lower edge: the lower edge split
    into ``pieces`` [m] from left to right (group "waist", each sewn to one waist piece), the
    right and left ends (groups "end_r", "end_l") and the top edge labelled "waistband"."""
    total = float(sum(pieces))
    xs = -total / 2 + np.concatenate([[0.0], np.cumsum(pieces)])
    out = Outline()
    for x in xs[:-1]:
        out.add((x, 0.0), Edge(label="waist"), "waist")
    out.add((xs[-1], 0.0), Edge(label="side"), "end_r")
    out.add((xs[-1], height), Edge(label="waistband"), "top")
    out.add((xs[0], height), Edge(label="side"), "end_l")
    return out.piece(name, placement)


def band_seams(front: Piece, back: Piece, front_waist: list, back_waist: list) -> list[Seam]:
    """Seams of the front and back waistband halves: their lower pieces to the garment's waist
    edges ``front_waist`` and ``back_waist`` (left to right as seen from outside), and their
    ends to each other at the sides."""
    seams = [Seam(b, w) for b, w in zip(front.edges("waist"), front_waist, strict=True)]
    seams += [Seam(b, w) for b, w in zip(back.edges("waist"), back_waist, strict=True)]
    seams += [Seam(front.edges("end_r")[0], back.edges("end_l")[0]),
              Seam(front.edges("end_l")[0], back.edges("end_r")[0])]
    return seams


def band_pieces(vertices: np.ndarray, torso_mask: np.ndarray, top_y: float, height: float,
                front_waist: list[float], back_waist: list[float]) -> tuple[Piece, Piece]:
    """The front and back waistband halves from ``top_y`` down by ``height`` [m], their lower
    edges as long as the waist pieces they are sewn to (left to right), on the torso's arcs
    (``torso_wrap``) at the band's height."""
    section = torso_section(vertices, torso_mask, top_y - height / 2)
    out = []
    for name, front, pieces in (("band_front", True, front_waist), ("band_back", False, back_waist)):
        half = sum(pieces) / 2
        out.append(waistband(name, pieces, height, torso_wrap(section, front, 0.0, half, top_y - height)))
    return out[0], out[1]


def wrap_radius(side: float, half: float) -> tuple[float, float]:
    """Radius and axis offset [m] of a circular arc of length ``half`` from the middle of a
    panel to each side point at ``side`` [m] across: the arc that reaches the body's side, its
    axis behind the panel by the offset (negative: the axis is further from the panel's middle
    than the section's centre). A panel wider than half a turn at that radius wraps a circle
    around the centre (offset 0)."""
    if half >= side * np.pi / 2:
        return 2.0 * half / np.pi, 0.0
    lo, hi = 1e-4, np.pi / 2  # the arc's half angle: side * angle / sin(angle) = half
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if side * mid / np.sin(mid) < half else (lo, mid)
    angle = 0.5 * (lo + hi)
    radius = side / np.sin(angle)
    return radius, -radius * np.cos(angle)


def torso_wrap(section: TorsoSection, front: bool, y0: float, half0: float, hem_y: float,
               y1: float | None = None, half1: float | None = None) -> Placement:
    """Placement of a front or back panel (x = 0 on the centre line, y = 0 at height ``hem_y``)
    on an arc around the torso: at panel height ``y0`` its half width ``half0`` [m] reaches
    from the centre line to the section's side, standing as far off the body's side as off its
    front (back), at least ``MIN_GAP``. Two such arcs, front and back, follow the body's oval
    section much closer than one circle. With ``half1`` at panel height ``y1`` the arc is a
    cone's, its radius in proportion to the half width."""

    def arc(gap: float) -> tuple[float, float, float]:
        radius, offset = wrap_radius(section.half_width + gap, half0)
        return radius, offset, radius + offset - section.half_depth

    lo, hi = 0.0, 0.2  # the side gap at which the front stands off as far
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if arc(mid)[2] > mid else (lo, mid)
    radius, offset, front_gap = arc(max(0.5 * (lo + hi), MIN_GAP))
    offset += max(MIN_GAP - front_gap, 0.0)
    slope = 0.0 if half1 is None else radius * (1.0 - half1 / half0) / (y0 - y1)
    sign = 1.0 if front else -1.0
    return Placement(anchor=(section.cx, hem_y + y0, section.cz + sign * (offset + radius)),
                     u_dir=(sign, 0.0, 0.0), v_dir=(0.0, 1.0, 0.0), curvature=1.0 / radius,
                     origin=(0.0, y0), radius_slope=slope)


@dataclass(frozen=True)
class PanelRow:
    """One row of a ``RowPlacement``: at panel height ``y`` the panel's span from ``x0`` to
    ``x1`` [m] (its centre line to its side, say) is placed by ``placement``. With ``rise`` the
    row is the parabola y + rise s² across the span (s: the share of the span, 0 at x0, ±1 at
    ±x1 about x0), a curved waist, and is placed level, as it is when sewn to a straight band."""

    y: float
    placement: Placement
    x0: float
    x1: float
    rise: float = 0.0

    def height(self, x: np.ndarray) -> np.ndarray:
        """The row's panel height at panel x [m]."""
        return self.y + self.rise * ((x - self.x0) / (self.x1 - self.x0)) ** 2


def placement_rows(rows: list[PanelRow], side: tuple = ()) -> RowPlacement:
    """A ``RowPlacement`` through ``rows`` (increasing y) and the ``side`` samples (y, x1) of a
    curved side between them; its base fields are the first row's."""
    base = rows[0].placement
    return RowPlacement(**{f.name: getattr(base, f.name) for f in dataclasses.fields(Placement)},
                        rows=tuple(rows), side=tuple(side))


@dataclass(frozen=True)
class RowPlacement(Placement):
    """A placement that changes with panel height, for panels whose parts wrap different body
    parts: a skirt panel wraps the torso's arc at the hip line and the narrower arc at the
    waist; a trouser panel its leg's cone up to the crotch line and the torso's arcs above.

    Below the first row and above the last the panel is placed as those rows place it. Between
    two rows a point keeps its share ``s`` of the panel's span (the spans' x0 to x1 interpolated
    linearly in y), each row places the point at that share of its own span, and the two
    positions blend linearly in y: the centre line and the side seam run straight from row to
    row, and a panel that narrows between rows (a skirt's hip curve) does not wrap past its
    side at the narrower row. A side seam that curves between the rows gives ``side``: samples
    (y, x1) of it, from which a point's span ends at its own height, so the curve is placed
    where the rows place their sides (with the linear blend a skirt's convex hip curve wraps
    ~1 cm past the side seam on both panels, and the front and back cross there when sewn).
    Not an isometry: on the default body the placed edges of a
    straight skirt are within 1.9 % of their flat lengths for 90 % of them (up to 17 % by the
    side seams under the waist), a pair of trousers' within 5.5 % (up to ~100 % at the top of
    the crotch curve, which the blend carries from the seat to between the legs); sewing
    settles the garment on its flat rest shape.
    """

    rows: tuple = ()
    side: tuple = ()

    def place(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        heights = np.stack([r.height(xy[:, 0]) for r in self.rows])  # (rows, P)
        first, last = self.rows[0], self.rows[-1]
        out = first.placement.place(xy - np.stack([0.0 * xy[:, 0], heights[0] - first.y], axis=1))
        above = xy[:, 1] >= heights[-1]
        out[above] = last.placement.place(xy[above] - np.stack(
            [0.0 * xy[above, 0], heights[-1, above] - last.y], axis=1))
        for k in range(len(self.rows) - 1):
            sel = (xy[:, 1] >= heights[k]) & (xy[:, 1] < heights[k + 1])
            if not sel.any():
                continue
            a, b = self.rows[k], self.rows[k + 1]
            t = (xy[sel, 1] - heights[k, sel]) / (heights[k + 1, sel] - heights[k, sel])
            x0, x1 = a.x0 + t * (b.x0 - a.x0), a.x1 + t * (b.x1 - a.x1)
            if self.side:
                sy, sx = np.asarray(self.side, np.float64).T
                x1 = np.interp(xy[sel, 1], sy, sx)
            share = (xy[sel, 0] - x0) / (x1 - x0)
            lo = a.placement.place(np.stack([a.x0 + share * (a.x1 - a.x0), np.full_like(t, a.y)], axis=1))
            hi = b.placement.place(np.stack([b.x0 + share * (b.x1 - b.x0), np.full_like(t, b.y)], axis=1))
            out[sel] = (1.0 - t)[:, None] * lo + t[:, None] * hi
        return out


@dataclass(frozen=True)
class SkirtLines:
    """A skirt panel's construction [m], panel coordinates (y = 0 at the hem's centre)."""

    hem: float  # hem half width
    rise: float  # the hem's rise at the side seams over its centre
    hip: tuple[float, float]  # (half width, height) of the side seam's hip point
    waist: tuple[float, float]  # (half width at the side seam, height at the centre) of the waist
    waist_rise: float  # the waist's rise at the side seams over its centre
    side_control: tuple[float, float]  # the hip-to-waist side seam's Bézier control point


def parabola_length(half: float, rise: float) -> float:
    """Length [m] of the parabola y = rise (x / half)² from x = -half to half."""
    x = np.linspace(-half, half, 257)
    y = rise * (x / half) ** 2
    return float(np.hypot(np.diff(x), np.diff(y)).sum())


def skirt_lines(shaping: WaistShaping, flare: float, hip_y: float, waist_y: float) -> SkirtLines:
    """Where the side seam runs: straight down from the hip (flare 0) or slanting out, through
    the hip point or outside it on the line from the waist to the hem; from the hip it curves
    in to the waist (a quadratic leaving the hip along the seam below). The hem curves up toward
    the sides to meet the side seams at right angles, and so, by ``flare``'s share, does the
    waist (a parabola, as pattern books' A-line blocks once the darts are rotated into the hem),
    keeping its length."""
    hip = shaping.hip[0]
    waist = hip - shaping.side
    hem = hip + flare * FLARE_SLOPE * hip_y
    on_line = waist + (hem - waist) * (waist_y - hip_y) / waist_y
    hip_x = max(hip, on_line)
    rise = 0.0
    for _ in range(3):  # the hem meets the side seam at a right angle
        rise = hem * (hem - hip_x) / (hip_y - rise / 2)
    slope = (hip_x - hem) / (hip_y - rise / 2)  # the side seam's run per rise below the hip
    half, lift = waist, 0.0
    for _ in range(6):
        top = waist_y + lift
        ctl = (hip_x + slope * 0.5 * (top - hip_y), hip_y + 0.5 * (top - hip_y))
        # the parabola's slope 2 lift / half at the side, square to the seam's end tangent
        lift = flare * half * (ctl[0] - half) / (top - ctl[1]) / 2.0
        half *= 2.0 * waist / parabola_length(half, lift)
    top = waist_y + lift
    ctl = (hip_x + slope * 0.5 * (top - hip_y), hip_y + 0.5 * (top - hip_y))
    return SkirtLines(hem, rise, (hip_x, hip_y), (half, waist_y), lift, ctl)


def side_curve(lines: SkirtLines, samples: int = 33) -> tuple[tuple[float, float], ...]:
    """Samples (y, x) of a skirt panel's side seam from the hip point to the waist, the
    quadratic Bézier ``skirt_panel`` draws there."""
    t = np.linspace(0.0, 1.0, samples)[:, None]
    p0 = np.array(lines.hip)
    p1 = np.array(lines.side_control)
    p2 = np.array([lines.waist[0], lines.waist[1] + lines.waist_rise])
    pts = (1 - t) ** 2 * p0 + 2 * (1 - t) * t * p1 + t ** 2 * p2
    return tuple((float(y), float(x)) for x, y in pts)


def add_waist_curve(out: Outline, half: float, y: float, rise: float, darts) -> None:
    """A skirt's waist from the right side (half, y + rise) toward the left side (added next)
    along the parabola y + rise (x / half)², with V darts (centre x, width, length) [m] from the
    right. Pieces join group "waist", dart legs "dart"; each piece is the parabola's exact
    quadratic Bézier."""

    def at(x: float) -> np.ndarray:
        return np.array([x, y + rise * (x / half) ** 2])

    def piece(x1: float, x2: float) -> Edge:
        if rise <= 1e-6:
            return Edge(label="waist")
        return Edge("quadratic", (((x1 + x2) / 2, y + rise * x1 * x2 / half ** 2),), "waist")

    x = half
    for centre, width, length in darts:
        if width <= 0.0:
            continue
        right, left = at(centre + width / 2), at(centre - width / 2)
        out.add(at(x), piece(x, centre + width / 2), "waist")
        d = (left - right) / np.linalg.norm(left - right)
        out.add(right, Edge(label="dart"), "dart")
        out.add(0.5 * (right + left) + length * np.array([-d[1], d[0]]), Edge(label="dart"), "dart")
        x = centre - width / 2
    out.add(at(x), piece(x, -half), "waist")


def skirt_panel(name: str, lines: SkirtLines, dart: float, dart_length: float,
                placement: Placement) -> Piece:
    """A front or back skirt panel: hem, side seam (hem to hip, hip to waist) on the right, the
    waist with a dart each side, the side seam down the left."""
    hx, k = lines.hem, lines.rise
    (xh, yh), (xw, yw) = lines.hip, lines.waist
    top = yw + lines.waist_rise
    ctl = lines.side_control
    out = Outline()
    hem = Edge("quadratic", ((0.0, -k / 2),), "hem") if k > 1e-4 else Edge(label="hem")
    out.add((-hx, k / 2), hem, "hem")
    out.add((hx, k / 2), Edge(label="side"), "side_r")
    out.add((xh, yh), Edge("quadratic", (ctl,), "side"), "side_r")
    darts = [(DART_AT * xw, dart, dart_length), (-DART_AT * xw, dart, dart_length)]
    add_waist_curve(out, xw, yw, lines.waist_rise, darts)
    out.add((-xw, top), Edge("quadratic", ((-ctl[0], ctl[1]),), "side"), "side_l")
    out.add((-xh, yh), Edge(label="side"), "side_l")
    return out.piece(name, placement)


def draft_skirt(m, vertices: np.ndarray, torso_mask: np.ndarray, joints: np.ndarray, d: SkirtDesign,
                name: str = "skirt") -> Pattern:
    """A skirt's pattern for a body: measurements ``m``, the rest vertices and torso mask for
    placement (``joints`` is unused: a skirt hangs from the torso)."""
    top_y = m.waist_height - d.waist_drop
    hem_y = top_y - d.length
    waist_y = top_y - d.waistband
    if hem_y > m.hip_height - 0.05:
        raise WrinklesInputError(f"skirt: length {d.length:.3f} m ends above the hips; at least "
                                 f"{top_y - m.hip_height + 0.05:.3f} m on this body")
    quarter = (max(m.hip, m.waist) + bottom_ease("hip", d.fit)) / 4
    waist = (girth_at(m, top_y) + bottom_ease("waist", d.fit)) / 4
    shaping = waist_shaping((quarter, quarter), waist, tuple(s * (1.0 - d.flare) for s in DART_SHARE))
    lines = skirt_lines(shaping, d.flare, m.hip_height - hem_y, waist_y - hem_y)
    hips = torso_section(vertices, torso_mask, m.hip_height)
    waist_line = torso_section(vertices, torso_mask, waist_y)
    pieces = {}
    for k, part in enumerate(("front", "back")):
        hip = torso_wrap(hips, part == "front", lines.hip[1], lines.hip[0], hem_y, 0.0, lines.hem)
        top = torso_wrap(waist_line, part == "front", lines.waist[1], lines.waist[0], hem_y)
        place = placement_rows([PanelRow(lines.hip[1], hip, 0.0, lines.hip[0]),
                                PanelRow(lines.waist[1], top, 0.0, lines.waist[0], lines.waist_rise)],
                               side_curve(lines))
        pieces[part] = skirt_panel(part, lines, shaping.darts[k], SKIRT_DARTS[k], place)
    front, back = pieces["front"], pieces["back"]
    fw, bw = front.edges("waist")[::-1], back.edges("waist")[::-1]  # left to right
    length = [[front.panel.edge_length(i) for _, i in fw], [back.panel.edge_length(i) for _, i in bw]]
    band_f, band_b = band_pieces(vertices, torso_mask, top_y, d.waistband, *length)
    seams = [Seam(a, b) for a, b in zip(front.edges("side_r"), back.edges("side_l")[::-1], strict=True)]
    seams += [Seam(a, b) for a, b in zip(front.edges("side_l"), back.edges("side_r")[::-1], strict=True)]
    seams += front.dart_seams() + back.dart_seams() + band_seams(band_f, band_b, fw, bw)
    panels = (front.panel, back.panel, band_f.panel, band_b.panel)
    return Pattern(name, panels, tuple(seams), {"design": dict(d.__dict__), "ease": {
        "waist": bottom_ease("waist", d.fit), "hip": bottom_ease("hip", d.fit)}})
