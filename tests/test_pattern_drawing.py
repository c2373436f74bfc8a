"""Pattern drawings (sim.garments.pattern_drawing): a full-size SVG in millimetres whose paths
are the panels' outlines, checked against hand-computed extents, corners and an arc's centre
computed the way the SVG specification does (implementation notes F.6.5)."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from sim.garments.pattern import Edge, Panel, Pattern, Seam
from sim.garments.pattern_drawing import GAP_MM, draw_pattern_png, pattern_layout, pattern_svg

NS = {"s": "http://www.w3.org/2000/svg"}


def drawing_pattern() -> Pattern:
    """A 40 x 60 cm rectangle, a panel of quadratic, cubic and large-arc edges, a darted panel."""
    rect = Panel("rect", np.array([[0, 0], [0.4, 0], [0.4, 0.6], [0, 0.6]]),
                 (Edge(label="hem"), Edge(label="side"), Edge(label="waistband"), Edge()))
    # edge 2: radius 25 cm over a 30 cm chord, the large arc bulging up: centre (15, 60) cm,
    # so the panel spans x -10..40 cm and y -2.5 (the hem's depth) .. 85 cm
    curvy = Panel("curvy", np.array([[0, 0], [0.3, 0], [0.3, 0.4], [0, 0.4]]),
                  (Edge("quadratic", ((0.15, -0.05),), "hem"), Edge("cubic", ((0.35, 0.1), (0.35, 0.3))),
                   Edge("arc", ((0.25, 1.0, 1.0),), "hood"), Edge(label="side")))
    darted = Panel("darted", np.array([[0, 0], [0.2, 0], [0.2, 0.3], [0.12, 0.3], [0.1, 0.2], [0.08, 0.3],
                                       [0, 0.3]]), tuple(Edge() for _ in range(7)))
    return Pattern("drawing", (rect, curvy, darted),
                   (Seam(("rect", 1), ("curvy", 3)), Seam(("darted", 3), ("darted", 4), dart=True)))


def parse(path):
    root = ET.parse(path).getroot()
    return root, root.findall(".//s:path", NS)


def numbers(d: str) -> list[float]:
    return [float(x) for x in re.findall(r"-?\d+(?:\.\d+)?", d)]


def commands(d: str) -> list[tuple[str, list[float]]]:
    return [(m.group(1), numbers(m.group(2))) for m in re.finditer(r"([MLQCAZ])([^MLQCAZ]*)", d)]


def svg_arc_centre(p1, p2, r: float, large: int, sweep: int) -> np.ndarray:
    """Centre of an SVG arc of a circle (SVG 1.1, F.6.5.2, rx = ry, no rotation)."""
    h = (np.asarray(p1) - np.asarray(p2)) / 2
    sign = -1.0 if large == sweep else 1.0
    coef = sign * np.sqrt(max(r ** 4 - r * r * (h @ h), 0.0) / (r * r * (h @ h)))
    return coef * np.array([h[1], -h[0]]) + (np.asarray(p1) + np.asarray(p2)) / 2


def test_svg_is_full_size_in_millimetres(tmp_path):
    p = drawing_pattern()
    layout = pattern_svg(p, tmp_path / "p.svg")
    root, paths = parse(tmp_path / "p.svg")
    # extents: 400 + 500 + 200 mm wide with 30 mm gaps; the tallest panel is 875 mm
    width, height = 400 + 500 + 200 + 4 * GAP_MM, 875 + 2 * GAP_MM
    assert root.get("width").endswith("mm") and root.get("height").endswith("mm")
    np.testing.assert_allclose([float(root.get("width")[:-2]), float(root.get("height")[:-2])],
                               [width, height], atol=0.05)
    np.testing.assert_allclose(numbers(root.get("viewBox")), [0, 0, width, height], atol=0.05)
    np.testing.assert_allclose([layout.width, layout.height], [width, height], atol=0.05)
    assert len(paths) == len(p.panels) and all(x.get("class") == "panel" for x in paths)


def test_straight_edges_are_the_corners_in_millimetres(tmp_path):
    pattern_svg(drawing_pattern(), tmp_path / "p.svg")
    _, paths = parse(tmp_path / "p.svg")
    cmds = commands(paths[0].get("d"))
    assert [c for c, _ in cmds] == ["M", "L", "L", "L", "L", "Z"]
    np.testing.assert_allclose([xy for _, xy in cmds[:-1]], [[0, 0], [400, 0], [400, 600], [0, 600], [0, 0]],
                               atol=1e-9)
    cmds = commands(paths[2].get("d"))
    corners = drawing_pattern().panels[2].corners * 1000
    np.testing.assert_allclose([xy for _, xy in cmds[:-2]], corners, atol=1e-9)


def test_curves_are_svg_curves(tmp_path):
    p = drawing_pattern()
    pattern_svg(p, tmp_path / "p.svg")
    _, paths = parse(tmp_path / "p.svg")
    cmds = commands(paths[1].get("d"))
    assert [c for c, _ in cmds] == ["M", "Q", "C", "A", "L", "Z"]
    np.testing.assert_allclose(cmds[1][1], [150, -50, 300, 0], atol=1e-9)
    np.testing.assert_allclose(cmds[2][1], [350, 100, 350, 300, 300, 400], atol=1e-9)
    r, rr, rot, large, sweep, x, y = cmds[3][1]
    np.testing.assert_allclose([r, rr, rot, large, sweep, x, y], [250, 250, 0, 1, 1, 0, 400], atol=1e-9)
    centre = svg_arc_centre([300, 400], [x, y], r, int(large), int(sweep))
    np.testing.assert_allclose(centre, [150, 600], atol=1e-9)
    # the panel's arc lies on that circle and turns the way the sweep flag says (1: angle grows)
    pts = p.panels[1].edge_curve(2, 16) * 1000
    np.testing.assert_allclose(np.linalg.norm(pts - centre, axis=1), 250, atol=1e-6)
    turn = np.unwrap(np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0]))
    assert np.all(np.diff(turn) > 0)


def test_panels_side_by_side_inside_the_sheet(tmp_path):
    p = drawing_pattern()
    layout = pattern_svg(p, tmp_path / "p.svg")
    root, _ = parse(tmp_path / "p.svg")
    groups = root.findall("s:g", NS)
    assert [g.get("id") for g in groups] == ["panel-rect", "panel-curvy", "panel-darted"]
    spans = []
    for i, (g, panel) in enumerate(zip(groups, p.panels, strict=True)):
        ox, oy = numbers(g.find("s:g", NS).get("transform"))[:2]
        np.testing.assert_allclose([ox, oy], layout.offsets[i], atol=1e-4)
        xy = panel.outline(256) * 1000
        sheet = np.c_[ox + xy[:, 0], oy - xy[:, 1]]  # translate(ox oy) scale(1 -1)
        assert sheet.min() >= GAP_MM - 0.05 and sheet[:, 0].max() <= layout.width - GAP_MM + 0.05
        assert sheet[:, 1].max() <= layout.height - GAP_MM + 0.05
        spans.append((sheet[:, 0].min(), sheet[:, 0].max()))
    for (_, right), (left, _) in zip(spans, spans[1:], strict=False):
        np.testing.assert_allclose(left - right, GAP_MM, atol=0.05)


def test_seams_darts_and_labels_are_marked(tmp_path):
    p = drawing_pattern()
    layout = pattern_svg(p, tmp_path / "p.svg")
    root, _ = parse(tmp_path / "p.svg")
    texts = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert texts.count("S1 side") == 2  # seam 1 joins two edges labelled "side"
    assert texts.count("D1") == 2
    assert {"hem", "waistband", "hood", "rect", "curvy", "darted"} <= set(texts)
    # labels stand inside their panel, beside their edge
    rect_group = root.find("s:g[@id='panel-rect']", NS)
    rect_texts = {t.text: t for t in rect_group.iter("{http://www.w3.org/2000/svg}text")}
    hem_y, top_y = layout.to_sheet(0, [[0, 0], [0, 0.6]])[:, 1]
    assert top_y < float(rect_texts["waistband"].get("y")) < float(rect_texts["hem"].get("y")) < hem_y
    notches = root.findall(".//s:line[@class='notch']", NS)
    assert len(notches) == 4
    # the notch of seam 1 on the rectangle crosses its right side at mid-height
    x1, y1, x2, y2 = (float(notches[0].get(k)) for k in ("x1", "y1", "x2", "y2"))
    np.testing.assert_allclose([(x1 + x2) / 2, (y1 + y2) / 2], layout.to_sheet(0, [0.4, 0.3])[0], atol=1e-3)
    fold = root.findall(".//s:line[@class='dart-fold']", NS)
    assert len(fold) == 1  # from the dart's tip to the middle of its mouth
    got = np.reshape([float(fold[0].get(k)) for k in ("x1", "y1", "x2", "y2")], (2, 2))
    np.testing.assert_allclose(got, layout.to_sheet(2, [[0.1, 0.2], [0.1, 0.3]]), atol=1e-3)


def test_seam_allowance_adds_a_cutting_line(tmp_path):
    rect = drawing_pattern().panels[0]
    p = Pattern("rects", (rect, Panel("rect2", rect.corners, rect.edges)), ())
    plain = pattern_layout(p)
    layout = pattern_svg(p, tmp_path / "p.svg", seam_allowance=0.015)
    grown = [layout.width - plain.width, layout.height - plain.height]
    np.testing.assert_allclose(grown, [60, 30], atol=1e-6)  # 15 mm on each side of each panel
    root, _ = parse(tmp_path / "p.svg")
    cuts = root.findall(".//s:polygon[@class='cut']", NS)
    assert len(cuts) == 2
    pts = np.asarray(numbers(cuts[0].get("points"))).reshape(-1, 2)
    np.testing.assert_allclose([pts.min(axis=0), pts.max(axis=0)],
                               [[GAP_MM, GAP_MM], [GAP_MM + 430, GAP_MM + 630]], atol=1e-6)
    with pytest.raises(ValueError, match="seam_allowance"):
        pattern_svg(p, tmp_path / "q.svg", seam_allowance=-0.01)


def test_png_picture(tmp_path):
    pytest.importorskip("matplotlib")
    draw_pattern_png(drawing_pattern(), tmp_path / "p.png", width_px=800)
    head = (tmp_path / "p.png").read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(head[16:20], "big") == 800
