"""Drawings of a sewing pattern: a 1:1 SVG to print or cut from, and a PNG for pictures.

``pattern_svg`` writes every panel at full size in millimetres (the SVG's ``width`` and
``height`` carry ``mm``, its user unit is 1 mm), so it prints to scale and converts to PDF with
any SVG tool (``rsvg-convert -f pdf``, Inkscape, CairoSVG). Panels stand side by side in one row,
as drawn: seen from the garment's outside, y up. Each panel is one ``<path>`` of its outline
(the sewing line) in its own coordinates [mm] with lines, quadratic and cubic Béziers and arcs
(``L``, ``Q``, ``C``, ``A``), inside a ``<g>`` that places it; the seam allowance, when asked,
is a ``<polygon>`` around it (the cutting line). Every seam has a number, written beside both of
its edges with a notch across their midpoints (``S3``), so the pieces match when sewn; darts are
``D1``... with their fold line dashed; edge labels and panel names are text.
``draw_pattern_png`` draws the same layout with matplotlib (the ``preview`` extra).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.pattern import Panel, Pattern, arc_geometry

MM = 1000.0
"""Millimetres per metre: the SVG's user unit is 1 mm."""
GAP_MM = 30.0
"""Space between two panels and around the sheet [mm]."""
NOTCH_MM = 6.0
"""Length of a seam's notch across the outline [mm]."""
LABEL_MM = 7.0
"""Text height of edge labels and seam numbers [mm]; panel names are twice as tall."""
SAMPLES = 32
"""Segments per curved edge where an outline is measured or offset as a polyline."""
_INSTALL_HINT = "install the preview extra: pip install 'wrinkles[preview]'"


@dataclass(frozen=True)
class PatternLayout:
    """Where ``pattern_svg`` / ``draw_pattern_png`` put each panel on the sheet.

    Attributes:
        offsets: (P, 2) sheet position [mm] of each panel's point (0, 0), x right, y down.
        width: sheet width [mm].
        height: sheet height [mm].
    """

    offsets: np.ndarray
    width: float
    height: float

    def to_sheet(self, i: int, xy: np.ndarray) -> np.ndarray:
        """Sheet coordinates [mm] (y down) of points ``xy`` [m] of panel ``i``, shape (N, 2)."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2) * MM
        return np.stack([self.offsets[i, 0] + xy[:, 0], self.offsets[i, 1] - xy[:, 1]], axis=1)


def pattern_layout(pattern: Pattern, *, seam_allowance: float = 0.0) -> PatternLayout:
    """Panels in one row, in pattern order, ``GAP_MM`` apart, tops aligned.

    Args:
        pattern: the pattern.
        seam_allowance: width [m] of the cutting margin drawn around each panel.
    """
    if not pattern.panels:
        raise ValueError(f"pattern {pattern.name!r} has no panels to draw")
    boxes = []
    for p in pattern.panels:
        pts = cut_outline(p, seam_allowance) if seam_allowance > 0 else p.outline(8 * SAMPLES)
        boxes.append((pts.min(axis=0) * MM, pts.max(axis=0) * MM))
    top = max(hi[1] - lo[1] for lo, hi in boxes)
    offsets, x = [], GAP_MM
    for lo, hi in boxes:
        offsets.append((x - lo[0], GAP_MM + hi[1]))
        x += hi[0] - lo[0] + GAP_MM
    return PatternLayout(np.asarray(offsets, np.float64), float(x), float(top + 2 * GAP_MM))


def cut_outline(panel: Panel, seam_allowance: float) -> np.ndarray:
    """The cutting line: the outline moved ``seam_allowance`` [m] outwards, mitred corners
    (a mitre at most 3 allowances long), (P, 2) [m], counter-clockwise."""
    pts = panel.outline(4 * SAMPLES)
    keep = np.linalg.norm(pts - np.roll(pts, 1, axis=0), axis=1) > 1e-12
    pts = pts[keep]
    d_in = pts - np.roll(pts, 1, axis=0)
    d_out = np.roll(pts, -1, axis=0) - pts
    n_in = np.stack([d_in[:, 1], -d_in[:, 0]], axis=1) / np.linalg.norm(d_in, axis=1)[:, None]
    n_out = np.stack([d_out[:, 1], -d_out[:, 0]], axis=1) / np.linalg.norm(d_out, axis=1)[:, None]
    m = n_in + n_out
    m_len = np.linalg.norm(m, axis=1)
    m = np.where(m_len[:, None] > 1e-9, m / np.maximum(m_len, 1e-12)[:, None], n_out)
    cos_half = np.clip(np.sum(m * n_out, axis=1), 1.0 / 3.0, 1.0)
    return pts + (seam_allowance / cos_half)[:, None] * m


def _fmt(v: float) -> str:
    s = f"{v:.4f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def panel_path_d(panel: Panel) -> str:
    """SVG path data of a panel's outline in its own coordinates [mm] (y up, as drawn; the
    ``<g>`` around it flips y): ``M``, then ``L`` / ``Q`` / ``C`` / ``A`` per edge, ``Z``."""
    c = panel.corners * MM
    parts = [f"M {_fmt(c[0, 0])} {_fmt(c[0, 1])}"]
    for i, e in enumerate(panel.edges):
        p0, p1 = panel.edge_ends(i)
        end = f"{_fmt(p1[0] * MM)} {_fmt(p1[1] * MM)}"
        if e.kind == "line":
            parts.append(f"L {end}")
        elif e.kind in ("quadratic", "cubic"):
            ctrl = " ".join(f"{_fmt(x * MM)} {_fmt(y * MM)}" for x, y in e.controls)
            parts.append(f"{'Q' if e.kind == 'quadratic' else 'C'} {ctrl} {end}")
        else:
            # SVG's sweep flag 1 turns toward +y from +x: counter-clockwise in the panel's frame
            _, _, sweep, radius = arc_geometry(p0, p1, *e.controls[0])
            r = _fmt(radius * MM)
            parts.append(f"A {r} {r} 0 {int(abs(sweep) > np.pi)} {int(sweep > 0)} {end}")
    parts.append("Z")
    return " ".join(parts)


def _edge_marks(pattern: Pattern) -> dict[tuple[str, int], str]:
    """The mark written beside each sewn edge: ``S<k>`` for seam k, ``D<k>`` for dart k."""
    marks, n_seam, n_dart = {}, 0, 0
    for s in pattern.seams:
        if s.dart:
            n_dart += 1
            tag = f"D{n_dart}"
        else:
            n_seam += 1
            tag = f"S{n_seam}"
        marks[s.a] = marks[s.b] = tag
    return marks


def _midpoint(panel: Panel, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Arc-length midpoint [m] of edge ``i`` and the unit tangent there."""
    pts = panel.edge_curve(i, 2 * SAMPLES)
    t = pts[SAMPLES + 1] - pts[SAMPLES - 1]
    return pts[SAMPLES], t / max(float(np.linalg.norm(t)), 1e-12)


def _centroid(panel: Panel) -> np.ndarray:
    """Area centroid of a panel's outline [m], where its name is written."""
    p = panel.outline(SAMPLES)
    q = np.roll(p, -1, axis=0)
    cross = p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]
    return ((p + q) * cross[:, None]).sum(axis=0) / (3.0 * cross.sum())


def _text(parent, xy, text: str, size: float, angle: float = 0.0, **attrs) -> None:
    el = ET.SubElement(parent, "text", {"x": _fmt(xy[0]), "y": _fmt(xy[1]), "font-size": _fmt(size),
                                        "font-family": "sans-serif", "text-anchor": "middle",
                                        "dominant-baseline": "middle", **attrs})
    if angle:
        el.set("transform", f"rotate({_fmt(angle)} {_fmt(xy[0])} {_fmt(xy[1])})")
    el.text = text


def _upright(t_sheet: np.ndarray) -> float:
    """Angle [deg] of text along a sheet direction, turned so it never reads upside down."""
    a = float(np.degrees(np.arctan2(t_sheet[1], t_sheet[0])))
    return a - 180.0 if a > 90.0 else a + 180.0 if a < -90.0 else a


def _panel_marks(g, pattern: Pattern, layout: PatternLayout, i: int, marks: dict) -> None:
    """Notches, seam numbers and edge labels of panel ``i``, in sheet coordinates."""
    p = pattern.panels[i]
    for k, e in enumerate(p.edges):
        mark = marks.get((p.name, k), "")
        text = " ".join(x for x in (mark, e.label) if x)
        if not text:
            continue
        mid, t = _midpoint(p, k)
        inward = np.array([-t[1], t[0]])  # the panel is counter-clockwise: inside is on the left
        if mark:
            half = inward * NOTCH_MM / (2 * MM)
            ends = layout.to_sheet(i, [mid - half, mid + half])
            ET.SubElement(g, "line", {"class": "notch", "x1": _fmt(ends[0, 0]), "y1": _fmt(ends[0, 1]),
                                      "x2": _fmt(ends[1, 0]), "y2": _fmt(ends[1, 1]),
                                      "stroke": "#c0392b", "stroke-width": "0.6"})
        at = layout.to_sheet(i, mid + inward * (NOTCH_MM + LABEL_MM) / MM)[0]
        # a label runs along its edge: smaller on a short edge (sans-serif is ~0.6 em a letter)
        size = float(np.clip(0.9 * p.edge_length(k) * MM / (0.6 * len(text)), 2.5, LABEL_MM))
        _text(g, at, text, size, _upright(np.array([t[0], -t[1]])),
              fill="#c0392b" if mark else "#1f4e79")
    for s in pattern.darts:
        a, b = sorted((s.a[1], s.b[1]))
        if s.a[0] != p.name or not (b == a + 1 or (a == 0 and b == len(p.edges) - 1)):
            continue
        first = b if (a == 0 and b == len(p.edges) - 1) else a  # the leg that ends at the tip
        start, tip = p.edge_ends(first)
        mouth = 0.5 * (start + p.edge_ends((first + 1) % len(p.edges))[1])
        ends = layout.to_sheet(i, [tip, mouth])
        ET.SubElement(g, "line", {"class": "dart-fold", "x1": _fmt(ends[0, 0]), "y1": _fmt(ends[0, 1]),
                                  "x2": _fmt(ends[1, 0]), "y2": _fmt(ends[1, 1]), "stroke": "#555555",
                                  "stroke-width": "0.4", "stroke-dasharray": "4 2"})


def pattern_svg(pattern: Pattern, path: str | os.PathLike, *, seam_allowance: float = 0.0) -> PatternLayout:
    """Write ``pattern`` as a full-size SVG [mm] (see the module).

    Args:
        pattern: the pattern to draw.
        path: the .svg file to write.
        seam_allowance: cutting margin [m] drawn around each panel (0: none).

    Returns:
        the layout: each panel's position on the sheet and the sheet's size [mm].
    """
    if seam_allowance < 0:
        raise ValueError(f"seam_allowance must be >= 0 m, got {seam_allowance}")
    layout = pattern_layout(pattern, seam_allowance=seam_allowance)
    w, h = _fmt(layout.width), _fmt(layout.height)
    root = ET.Element("svg", {"xmlns": "http://www.w3.org/2000/svg", "version": "1.1",
                              "width": f"{w}mm", "height": f"{h}mm", "viewBox": f"0 0 {w} {h}"})
    ET.SubElement(root, "title").text = f"{pattern.name}: sewing pattern, 1:1, millimetres"
    marks = _edge_marks(pattern)
    for i, p in enumerate(pattern.panels):
        g = ET.SubElement(root, "g", {"id": f"panel-{p.name}"})
        if seam_allowance > 0:
            cut = layout.to_sheet(i, cut_outline(p, seam_allowance))
            points = " ".join(f"{_fmt(x)},{_fmt(y)}" for x, y in cut)
            ET.SubElement(g, "polygon", {"class": "cut", "points": points, "fill": "none",
                                         "stroke": "#000000", "stroke-width": "0.3"})
        ox, oy = layout.offsets[i]
        inner = ET.SubElement(g, "g", {"transform": f"translate({_fmt(ox)} {_fmt(oy)}) scale(1 -1)"})
        ET.SubElement(inner, "path", {"class": "panel", "d": panel_path_d(p), "fill": "#f3e3e6",
                                      "stroke": "#333333", "stroke-width": "0.5",
                                      "stroke-dasharray": "3 1.5" if seam_allowance > 0 else "none"})
        _panel_marks(g, pattern, layout, i, marks)
        centre = layout.to_sheet(i, _centroid(p))[0]
        _text(g, centre, p.name, 2 * LABEL_MM, fill="#222222", **{"font-weight": "bold"})
    ET.indent(root)
    ET.ElementTree(root).write(os.fspath(path), encoding="utf-8", xml_declaration=True)
    return layout


def draw_pattern_png(pattern: Pattern, path: str | os.PathLike, *, width_px: int = 1600) -> PatternLayout:
    """Draw ``pattern`` (the layout of ``pattern_svg``) as a PNG ``width_px`` wide: panels filled,
    seam numbers and panel names; for documentation pictures.

    Raises:
        WrinklesInputError: matplotlib is not installed.
    """
    try:
        from matplotlib.figure import Figure  # no pyplot: no global backend; PNGs go through Agg
    except ImportError as exc:
        raise WrinklesInputError(f"pattern pictures need matplotlib ({exc}); {_INSTALL_HINT}") from None
    layout = pattern_layout(pattern)
    dpi = 100
    fig = Figure(figsize=(width_px / dpi, width_px / dpi * layout.height / layout.width), dpi=dpi)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, layout.width)
    ax.set_ylim(layout.height, 0)
    ax.set_aspect("equal")
    ax.axis("off")
    # LABEL_MM in points at this scale, but no smaller than 7 pt: a picture of a whole pattern
    font = max(72.0 / dpi * width_px / layout.width * LABEL_MM, 7.0)
    marks = _edge_marks(pattern)
    for i, p in enumerate(pattern.panels):
        xy = layout.to_sheet(i, p.outline(SAMPLES))
        ax.fill(xy[:, 0], xy[:, 1], facecolor="#f3e3e6", edgecolor="#333333", linewidth=1.0)
        for k in range(len(p.edges)):
            if (p.name, k) in marks:
                mid, t = _midpoint(p, k)
                at = layout.to_sheet(i, mid + np.array([-t[1], t[0]]) * (NOTCH_MM + LABEL_MM) / MM)[0]
                ax.text(at[0], at[1], marks[(p.name, k)], color="#c0392b", fontsize=font,
                        ha="center", va="center")
        c = layout.to_sheet(i, _centroid(p))[0]
        ax.text(c[0], c[1], p.name, fontsize=2 * font, ha="center", va="center", weight="bold")
    fig.savefig(os.fspath(path), dpi=dpi)
    return layout
