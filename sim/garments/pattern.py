"""Sewing patterns: flat panels, seams, darts and labelled edges (DESIGN.md, ``Pattern``).

A panel is a closed outline in its own plane [m], x to the right and y up the garment as a
tailor draws it, counter-clockwise seen from the outside of the garment. Its outline is a list
of corners and one ``Edge`` from each corner to the next: a straight line, a quadratic or cubic
Bézier (control points in the panel's coordinates) or a circular arc (GarmentCode's
``radius, large_arc, right``). A ``Seam`` joins two edges (of two panels, or of one panel for a
dart) along their whole length; edges are split where a seam ends. Both sides of a seam are
sampled with the same number of points, so sewing matches them vertex for vertex.

Each panel carries a ``Placement``: where its flat outline goes around the rest body before
sewing (a cylinder of curvature ``curvature`` around the body part, as GarmentCodeData and
Marvelous Designer wrap panels around the torso, arms and legs).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

EDGE_KINDS = ("line", "quadratic", "cubic", "arc")
"""Curves an outline edge can be."""
DENSE = 64
"""Curved edges are measured on polylines of ``8 DENSE`` segments (a half circle to 2e-6) and
resampled at equal arc length from ``4 DENSE``."""


@dataclass(frozen=True)
class Edge:
    """One edge of a panel's outline, from corner ``i`` to corner ``i + 1`` (the last closes it).

    Attributes:
        kind: "line", "quadratic" (one control point), "cubic" (two) or "arc".
        controls: Bézier control points in panel coordinates [m], ((x, y), ...); for an arc
            ``((radius, large_arc, right),)`` as GarmentCode writes circle edges: radius [m],
            large_arc 1 for the arc over 180°, right 1 when the arc bulges to the right of the
            edge's direction.
        label: what the edge is, e.g. "neckline", "armhole", "hem", "cuff", "waistband",
            "side", "shoulder"; free edges (in no seam) are the garment's openings.
    """

    kind: str = "line"
    controls: tuple = ()
    label: str = ""

    def __post_init__(self) -> None:
        if self.kind not in EDGE_KINDS:
            raise ValueError(f"edge kind {self.kind!r} is not one of {', '.join(EDGE_KINDS)}")
        need = {"line": 0, "quadratic": 1, "cubic": 2, "arc": 1}[self.kind]
        if len(self.controls) != need:
            raise ValueError(f"a {self.kind} edge needs {need} control entries, got {len(self.controls)}")
        object.__setattr__(self, "controls", tuple(tuple(float(c) for c in p) for p in self.controls))

    def points(self, p0: np.ndarray, p1: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Points of the curve at parameters ``t`` in [0, 1], shape (len(t), 2) [m]."""
        t = np.asarray(t, np.float64)[:, None]
        p0, p1 = np.asarray(p0, np.float64), np.asarray(p1, np.float64)
        if self.kind == "line":
            return p0 + t * (p1 - p0)
        if self.kind == "quadratic":
            c = np.asarray(self.controls[0])
            return (1 - t) ** 2 * p0 + 2 * t * (1 - t) * c + t ** 2 * p1
        if self.kind == "cubic":
            c1, c2 = np.asarray(self.controls[0]), np.asarray(self.controls[1])
            return ((1 - t) ** 3 * p0 + 3 * t * (1 - t) ** 2 * c1 + 3 * t ** 2 * (1 - t) * c2
                    + t ** 3 * p1)
        centre, a0, sweep, radius = arc_geometry(p0, p1, *self.controls[0])
        a = a0 + t[:, 0] * sweep
        return centre + radius * np.stack([np.cos(a), np.sin(a)], axis=1)


def arc_geometry(p0, p1, radius: float, large_arc: float,
                 right: float) -> tuple[np.ndarray, float, float, float]:
    """Centre, start angle, signed sweep [rad] and radius of the circular arc from ``p0`` to
    ``p1`` (GarmentCode's circle edge: ``right`` = the arc bulges to the right of p0 -> p1).
    A radius below half the chord is raised to it (a half circle)."""
    p0, p1 = np.asarray(p0, np.float64), np.asarray(p1, np.float64)
    d = p1 - p0
    chord = float(np.hypot(*d))
    r = max(float(radius), 0.5 * chord)
    h = np.sqrt(max(r * r - 0.25 * chord * chord, 0.0))
    left = np.array([-d[1], d[0]]) / max(chord, 1e-12)
    # the bulge is on the right: the centre is on the left for a small arc, right for a large one
    side = 1.0 if bool(right) != bool(large_arc) else -1.0
    centre = 0.5 * (p0 + p1) + side * h * left
    a0 = float(np.arctan2(*(p0 - centre)[::-1]))
    a1 = float(np.arctan2(*(p1 - centre)[::-1]))
    sweep = (a1 - a0) % (2 * np.pi)  # counter-clockwise sweep; the other way round is sweep - 2 pi
    if h < 1e-9 * max(chord, 1e-12):  # a half circle: counter-clockwise from p0 bulges right
        sweep = np.pi if bool(right) else -np.pi
    elif (sweep > np.pi) != bool(large_arc):
        sweep -= 2 * np.pi
    return centre, a0, sweep, r


@dataclass(frozen=True)
class Placement:
    """Where a flat panel goes around the rest body before sewing.

    The panel point ``origin`` lands on ``anchor``; the panel's y axis runs along ``v_dir``;
    its x axis wraps around a cylinder of radius 1 / ``curvature`` whose axis is parallel to
    ``v_dir`` and lies behind the panel (flat when ``curvature`` is 0). The panel's outside
    faces ``u_dir x v_dir`` at the anchor. With ``radius_slope`` the cylinder becomes a cone
    below the origin (panel y under ``origin``'s), its radius changing by that much per metre
    down the panel (a sleeve narrowing to its cuff, a skirt widening to its hem); cylinders and
    cones are developable, so a panel wrapped on them is not stretched (on a cone, but for a
    small shear where its slope is large).

    ``hold`` weighs the panel's side of its seams in the point they are sewn together: 1 for
    the panels that fit the body (the meeting point is the mean of the sides), more for a piece
    placed where the seam belongs (a hood round the neck, ``HOOD_HOLD``), 0 for a piece sewn onto
    another where that one lies.
    """

    anchor: tuple[float, float, float]
    u_dir: tuple[float, float, float] = (1.0, 0.0, 0.0)
    v_dir: tuple[float, float, float] = (0.0, 1.0, 0.0)
    curvature: float = 0.0
    origin: tuple[float, float] = (0.0, 0.0)
    radius_slope: float = 0.0
    hold: float = 1.0

    def place(self, xy: np.ndarray) -> np.ndarray:
        """3D positions [m] of panel points ``xy`` (P, 2), shape (P, 3)."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        u, v = np.asarray(self.u_dir, np.float64), np.asarray(self.v_dir, np.float64)
        u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
        n = np.cross(u, v)
        d = xy[:, 0] - self.origin[0]
        along = xy[:, 1] - self.origin[1]
        anchor = np.asarray(self.anchor, np.float64)
        if abs(float(self.curvature)) < 1e-9:
            return anchor + d[:, None] * u + along[:, None] * v
        r0 = 1.0 / float(self.curvature)
        r = np.maximum(r0 + float(self.radius_slope) * np.minimum(along, 0.0), 0.05 * abs(r0))
        a = d / r
        axis = anchor - r0 * n
        return (axis + along[:, None] * v + (r * np.sin(a))[:, None] * u
                + (r * np.cos(a))[:, None] * n)


@dataclass(frozen=True)
class Panel:
    """A flat pattern piece.

    Attributes:
        name: unique within its pattern (e.g. "front", "sleeve_l").
        corners: outline corners [m], shape (K, 2), counter-clockwise seen from outside.
        edges: K edges, edge i from corner i to corner (i + 1) % K.
        placement: where it goes around the body before sewing.
    """

    name: str
    corners: np.ndarray
    edges: tuple[Edge, ...]
    placement: Placement = field(default_factory=lambda: Placement((0.0, 0.0, 0.0)))

    def __post_init__(self) -> None:
        c = np.ascontiguousarray(self.corners, np.float64)
        if c.ndim != 2 or c.shape[1] != 2 or len(c) < 2:
            raise ValueError(f"panel {self.name!r}: corners must be (K >= 2, 2), got {c.shape}")
        if len(self.edges) != len(c):
            raise ValueError(f"panel {self.name!r}: {len(c)} corners need {len(c)} edges, "
                             f"got {len(self.edges)}")
        c.setflags(write=False)
        object.__setattr__(self, "corners", c)
        object.__setattr__(self, "edges", tuple(self.edges))

    def edge_ends(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        return self.corners[i], self.corners[(i + 1) % len(self.corners)]

    def edge_curve(self, i: int, n: int) -> np.ndarray:
        """Edge ``i`` sampled at ``n`` equal arc-length segments: (n + 1, 2) points [m]."""
        p0, p1 = self.edge_ends(i)
        e = self.edges[i]
        if e.kind == "line":
            return e.points(p0, p1, np.linspace(0.0, 1.0, n + 1))
        dense = e.points(p0, p1, np.linspace(0.0, 1.0, DENSE * 4 + 1))
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        want = np.linspace(0.0, s[-1], n + 1)
        out = np.stack([np.interp(want, s, dense[:, 0]), np.interp(want, s, dense[:, 1])], axis=1)
        out[0], out[-1] = p0, p1
        return out

    def edge_length(self, i: int) -> float:
        """Arc length of edge ``i`` [m]."""
        p0, p1 = self.edge_ends(i)
        pts = self.edges[i].points(p0, p1, np.linspace(0.0, 1.0, DENSE * 8 + 1))
        return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())

    def outline(self, per_edge: int = 16) -> np.ndarray:
        """The closed outline as a polyline, ``per_edge`` segments a curved edge: (P, 2) [m]."""
        parts = [self.edge_curve(i, 1 if e.kind == "line" else per_edge)[:-1]
                 for i, e in enumerate(self.edges)]
        return np.concatenate(parts)

    def area(self) -> float:
        """Signed area of the outline [m²], positive counter-clockwise."""
        p = self.outline(32)
        return 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))


@dataclass(frozen=True)
class Seam:
    """Two edges sewn together along their whole length.

    ``a`` and ``b`` are (panel name, edge index). With ``reverse`` (the default) the start of
    ``a`` meets the end of ``b``, as on two panels both seen from outside. A seam may join two
    edges of one panel (a sleeve's underarm seam closes it into a tube); a dart (``dart`` True)
    is such a seam that closes a notch cut into the outline.
    """

    a: tuple[str, int]
    b: tuple[str, int]
    reverse: bool = True
    dart: bool = False


@dataclass(frozen=True)
class Pattern:
    """A garment's sewing pattern.

    Attributes:
        name: the design ("t_shirt", ...) or the file it was read from.
        panels: the pieces; names unique.
        seams: the seams and darts; an edge is in at most one.
        parameters: the drafting parameters and measurements it was made with (JSON-able).
    """

    name: str
    panels: tuple[Panel, ...]
    seams: tuple[Seam, ...]
    parameters: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "panels", tuple(self.panels))
        object.__setattr__(self, "seams", tuple(self.seams))
        names = [p.name for p in self.panels]
        if len(set(names)) != len(names):
            raise ValueError(f"pattern {self.name!r}: panel names repeat: {names}")
        index = {p.name: p for p in self.panels}
        used: set[tuple[str, int]] = set()
        for s in self.seams:
            for ref in (s.a, s.b):
                pn = index.get(ref[0])
                if pn is None or not 0 <= ref[1] < len(pn.edges):
                    raise ValueError(f"pattern {self.name!r}: seam refers to a missing edge {ref}")
                if ref in used:
                    raise ValueError(f"pattern {self.name!r}: edge {ref} is in two seams")
                used.add(ref)
            if s.dart and s.a[0] != s.b[0]:
                raise ValueError(f"pattern {self.name!r}: a dart joins two edges of one panel: {s}")
        for p in self.panels:
            if p.area() <= 0:
                raise ValueError(f"pattern {self.name!r}: panel {p.name!r} is not counter-clockwise")

    def panel(self, name: str) -> Panel:
        for p in self.panels:
            if p.name == name:
                return p
        raise KeyError(name)

    @property
    def darts(self) -> tuple[Seam, ...]:
        return tuple(s for s in self.seams if s.dart)

    def free_edges(self) -> list[tuple[str, int]]:
        """Edges in no seam: the garment's openings (neckline, hems, cuffs...)."""
        used = {s.a for s in self.seams} | {s.b for s in self.seams}
        return [(p.name, i) for p in self.panels for i in range(len(p.edges)) if (p.name, i) not in used]

    def labelled(self, label: str) -> list[tuple[str, int]]:
        """Edges carrying ``label``."""
        return [(p.name, i) for p in self.panels for i, e in enumerate(p.edges) if e.label == label]


def split_edge(panel: Panel, i: int, t: float) -> Panel:
    """``panel`` with edge ``i`` cut in two at curve parameter ``t`` in (0, 1): a new corner
    there, edges ``i`` and ``i + 1`` the two pieces (same kind and label; de Casteljau for
    Béziers, the split angle for arcs). Edge indices after ``i`` shift by one."""
    p0, p1 = panel.edge_ends(i)
    e = panel.edges[i]
    mid = e.points(p0, p1, np.array([t]))[0]
    if e.kind == "line":
        parts = (Edge(label=e.label), Edge(label=e.label))
    elif e.kind == "arc":
        _, _, sweep, r = arc_geometry(p0, p1, *e.controls[0])
        a, b = sweep * t, sweep * (1 - t)
        parts = tuple(Edge("arc", ((r, float(abs(s) > np.pi), e.controls[0][2]),), e.label) for s in (a, b))
    else:
        pts = [np.asarray(p0)] + [np.asarray(c) for c in e.controls] + [np.asarray(p1)]
        left, right = [pts[0]], [pts[-1]]
        while len(pts) > 1:  # de Casteljau: the first and last points of each level
            pts = [(1 - t) * a + t * b for a, b in zip(pts[:-1], pts[1:], strict=True)]
            left.append(pts[0])
            right.append(pts[-1])
        right = right[::-1]
        parts = (Edge(e.kind, tuple(map(tuple, left[1:-1])), e.label),
                 Edge(e.kind, tuple(map(tuple, right[1:-1])), e.label))
    corners = np.insert(panel.corners, i + 1, mid, axis=0)
    edges = panel.edges[:i] + parts + panel.edges[i + 1:]
    return Panel(panel.name, corners, edges, panel.placement)


def parameter_at_length(panel: Panel, i: int, length: float) -> float:
    """Curve parameter of edge ``i`` at arc length ``length`` [m] from its start."""
    p0, p1 = panel.edge_ends(i)
    t = np.linspace(0.0, 1.0, DENSE * 8 + 1)
    pts = panel.edges[i].points(p0, p1, t)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return float(np.interp(length, s, t))
