"""GarmentCode sleeves turned onto our T-posed arms, and GarmentCode's edge labels named as ours
(sim.garments.sleeve_pose, sim.garments.garmentcode).

The specification is written here from the documented format (``pygarment``): a top in
centimetres around a body standing on the floor, as GarmentCodeData writes it, its front panels
counter-clockwise at z = 25, its back panels clockwise at z = -20, and two-panel sleeves hanging
50° below the horizontal (GarmentCode's ``Sleeve`` turns its panels down by the body's
``arm_pose_angle``), their x axis along the arm from the armhole.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim.garments.garmentcode import pattern_from_spec, place_on_body
from sim.garments.sleeve_pose import arm_panels, body_arm, pose_sleeves, sleeve_axis

ANGLE = 50.0
"""The sleeves' turn below the horizontal in the spec [deg]."""
SLEEVE = (45.0, 20.0)
"""Sleeve panel length along the arm and width across it [cm] (the armhole edge is 20 cm)."""


def _rect(x0, x1, y0, y1, ccw: bool) -> list:
    v = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    return v if ccw else [v[0], v[3], v[2], v[1]]


def _loop(vertices, labels) -> dict:
    n = len(vertices)
    return [{"endpoints": [k, (k + 1) % n], **({"label": labels[k]} if labels[k] else {})}
            for k in range(n)]


def top_spec(angle: float = ANGLE, *, labels: bool = True) -> dict:
    """A top with sleeves ``angle`` below the horizontal: torso panels 44 x 55 cm (their sides
    from 130 cm up are the armholes), sleeve panels ``SLEEVE``; a "lower_interface" hem and
    "left_collar" / "right_collar" top edges when ``labels``."""
    hem, collar = ("lower_interface", "right_collar") if labels else ("", "")
    # torso: corners ccw seen from +z: bottom, side +x (seam, armhole), top, side -x (armhole, seam)
    t = [[-22, 95], [22, 95], [22, 130], [22, 150], [-22, 150], [-22, 130]]
    panels = {
        "ftorso": {"vertices": t, "edges": _loop(t, [hem, "", "", collar, "", ""]),
                   "translation": [0, 0, 25], "rotation": [0, 0, 0], "label": "body"},
        "btorso": {"vertices": t[::-1], "edges": _loop(t[::-1], ["", collar, "", "", hem, ""]),
                   "translation": [0, 0, -20], "rotation": [0, 0, 0], "label": "body"},
    }
    length, width = SLEEVE
    for side, sign in (("left", 1), ("right", -1)):
        x1 = sign * length
        for part, z, outside in (("f", 17.5, 1), ("b", -12.5, -1)):
            v = _rect(min(0, x1), max(0, x1), -width, 0, outside > 0)
            panels[f"{side}_sleeve_{part}"] = {
                "vertices": v, "edges": _loop(v, [""] * 4), "label": "arm",
                "translation": [sign * 23, 150, z], "rotation": [0, 0, -sign * angle]}
    # ftorso edges: 0 bottom, 1 side +x, 2 armhole +x, 3 top, 4 armhole -x, 5 side -x;
    # btorso edges: 0 armhole -x, 1 top, 2 armhole +x, 3 side +x, 4 bottom, 5 side -x
    stitches = [[{"panel": "ftorso", "edge": 1}, {"panel": "btorso", "edge": 3}],
                [{"panel": "ftorso", "edge": 5}, {"panel": "btorso", "edge": 5}],
                [{"panel": "ftorso", "edge": 3}, {"panel": "btorso", "edge": 1}]]
    spec = {"pattern": {"panels": panels, "stitches": stitches},
            "properties": {"units_in_meter": 100, "curvature_coords": "relative"}}
    pattern = pattern_from_spec(spec)
    for side, sign in (("left", 1), ("right", -1)):
        f, b = pattern.panel(f"{side}_sleeve_f"), pattern.panel(f"{side}_sleeve_b")
        along = [_edge_at(f, "along_top"), _edge_at(b, "along_top")]
        under = [_edge_at(f, "along_bottom"), _edge_at(b, "along_bottom")]
        hole = [_edge_at(f, "hole"), _edge_at(b, "hole")]
        torso_hole = (2, 2) if sign > 0 else (4, 0)  # ftorso's, btorso's armhole on that side
        pairs = [((f.name, along[0]), (b.name, along[1])), ((f.name, under[0]), (b.name, under[1])),
                 ((f.name, hole[0]), ("ftorso", torso_hole[0])),
                 ((b.name, hole[1]), ("btorso", torso_hole[1]))]
        stitches += [_stitch(pattern, a, b) for a, b in pairs]
    return spec


def _stitch(pattern, a, b) -> list:
    """A stitch of edges ``a`` and ``b`` (panel, index) joining the ends that lie nearer each
    other where the file places them: end to start, or start to start ("right_wrong")."""
    ends = []
    for name, k in (a, b):
        panel = pattern.panel(name)
        ends.append(panel.placement.place(np.array(panel.edge_ends(k))))
    crossed = np.linalg.norm(ends[0][1] - ends[1][0]) + np.linalg.norm(ends[0][0] - ends[1][1])
    straight = np.linalg.norm(ends[0][0] - ends[1][0]) + np.linalg.norm(ends[0][1] - ends[1][1])
    stitch = [{"panel": a[0], "edge": a[1]}, {"panel": b[0], "edge": b[1]}]
    return stitch if crossed <= straight else stitch + ["right_wrong"]


def _edge_at(panel, which: str) -> int:
    """The index of a sleeve panel's edge by where it lies in the panel's plane: its armhole
    (x = 0), its top (y = 0) or its bottom (y = -width) edge."""
    for k in range(len(panel.edges)):
        a, b = panel.edge_ends(k)
        if which == "hole" and abs(a[0]) < 1e-9 and abs(b[0]) < 1e-9:
            return k
        if which == "along_top" and abs(a[1]) < 1e-9 and abs(b[1]) < 1e-9:
            return k
        bottom = -SLEEVE[1] / 100
        if which == "along_bottom" and abs(a[1] - bottom) < 1e-9 and abs(b[1] - bottom) < 1e-9:
            return k
    raise AssertionError(f"{panel.name} has no {which} edge")


@pytest.fixture(scope="module")
def body():
    from sim.bodies.default import load_default_body

    return load_default_body()


def _stitched_ok(spec: dict) -> None:
    """The spec's stitches join edges of equal length (the test's own geometry is right)."""
    p = pattern_from_spec(spec)
    for s in p.seams:
        np.testing.assert_allclose(p.panel(s.a[0]).edge_length(s.a[1]), p.panel(s.b[0]).edge_length(s.b[1]),
                                   atol=1e-9)


def test_sleeves_are_found_and_their_direction_is_the_spec_angle():
    spec = top_spec()
    _stitched_ok(spec)
    p = pattern_from_spec(spec)
    arms = arm_panels(p)
    assert sorted(arms[1]) == ["left_sleeve_b", "left_sleeve_f"]
    assert sorted(arms[-1]) == ["right_sleeve_b", "right_sleeve_f"]
    for side in (1, -1):
        d = sleeve_axis(p, arms[side], side)["direction"]
        t = np.deg2rad(ANGLE)
        np.testing.assert_allclose(d, [side * np.cos(t), -np.sin(t), 0.0], atol=1e-9)


def test_a_posed_sleeves_land_on_the_t_posed_arms(body):
    rest = np.asarray(body.rest_mesh(None), np.float64)
    joints = np.asarray(body.rest_joints(None), np.float64)
    names = list(body.joint_names)
    file_pattern = pattern_from_spec(top_spec())
    posed = place_on_body(file_pattern, rest, "floor")
    for side, arm in ((1, "left"), (-1, "right")):
        elbow, wrist = joints[names.index(f"{arm}_elbow")], joints[names.index(f"{arm}_wrist")]
        axis = (wrist - elbow) / np.linalg.norm(wrist - elbow)
        sl = sleeve_axis(posed, arm_panels(posed)[side], side)
        assert np.degrees(np.arccos(sl["direction"] @ axis)) < 1.0
        off = sl["centre"] - elbow
        assert np.linalg.norm(off - (off @ axis) * axis) < 0.005  # the sleeve's centre on the arm
        # along the arm, the sleeve's armhole edges lie where the torso's are (within 1 cm)
        assert abs((sl["hole"] - sl["partner"]) @ axis) < 0.01
        for part in ("f", "b"):  # each panel spans the arm: 10 cm above and below its axis
            panel = posed.panel(f"{arm}_sleeve_{part}")
            pts = panel.placement.place(panel.outline(4))
            np.testing.assert_allclose([pts[:, 1].min(), pts[:, 1].max()],
                                       [sl["centre"][1] - 0.1, sl["centre"][1] + 0.1], atol=1e-3)
    for name in ("ftorso", "btorso"):  # the torso is only moved up from the floor
        a, b = file_pattern.panel(name).placement, posed.panel(name).placement
        np.testing.assert_allclose(np.subtract(b.anchor, a.anchor), [0, rest[:, 1].min(), 0], atol=1e-9)


def test_sleeves_along_the_arms_stay_where_they_are(body):
    rest = np.asarray(body.rest_mesh(None), np.float64)
    p = pattern_from_spec(top_spec(angle=5.0))
    assert pose_sleeves(p, rest) is p
    tilted = pattern_from_spec(top_spec(angle=12.0))
    turned = pose_sleeves(tilted, rest)
    assert turned.panel("left_sleeve_f").placement != tilted.panel("left_sleeve_f").placement
    from sim.garments.designs import make_pattern

    for design in ("t_shirt", "long_sleeve"):  # our sleeves, wrapped on the arms, 1-2.3° off them
        ours = make_pattern(design, body, None)
        assert set(arm_panels(ours)) == {1, -1}
        assert pose_sleeves(ours, rest) is ours
    _, d = body_arm(rest, 1)
    np.testing.assert_allclose(d, [1, 0, 0], atol=0.01)


def test_garmentcode_labels_become_our_attachment_labels():
    p = pattern_from_spec(top_spec())
    assert sorted(p.labelled("waistband")) == [("btorso", 4), ("ftorso", 0)]
    assert sorted(p.labelled("neckline")) == [("btorso", 1), ("ftorso", 3)]
    cuffs = sorted(p.labelled("cuff"))
    assert [n for n, _ in cuffs] == ["left_sleeve_b", "left_sleeve_f", "right_sleeve_b", "right_sleeve_f"]
    for name, k in cuffs:  # the free end of each sleeve: x = ±45 cm
        a, b = p.panel(name).edge_ends(k)
        np.testing.assert_allclose(np.abs([a[0], b[0]]), 0.45, atol=1e-9)
    sewn_waist = top_spec()  # a waist sewn to another edge (a dress's) is a seam, not held
    sewn_waist["pattern"]["stitches"].append([{"panel": "ftorso", "edge": 0}, {"panel": "btorso", "edge": 4}])
    p = pattern_from_spec(sewn_waist)
    assert p.labelled("waistband") == []
    assert sorted(p.labelled("waist")) == [("btorso", 4), ("ftorso", 0)]
    unlabelled = pattern_from_spec(top_spec(labels=False))
    assert sorted(unlabelled.labelled("hem")) == [("btorso", 4), ("ftorso", 0)]
    assert unlabelled.labelled("waistband") == []


@pytest.mark.slow
def test_a_posed_sleeved_top_sews_on_the_arms(body):
    from sim.garments.designs import attachments_of
    from sim.garments.materials import get_material
    from sim.garments.sewing import sew_pattern

    rest = np.asarray(body.rest_mesh(None), np.float64)
    pattern = place_on_body(pattern_from_spec(top_spec()), rest, "auto")
    sewn = sew_pattern(pattern, rest, np.asarray(body.faces), 0.04, get_material("cotton"), device="cpu")
    assert np.all(np.isfinite(sewn.vertices))
    assert sewn.seam_gap <= 0.001
    att = attachments_of(pattern, sewn)
    assert {"waistband", "neckline", "cuffs"} <= set(att)
    # the cuffs hang around the forearm, past the elbow: the sleeve, a tube 40 cm round, hangs
    # from the top of the arm, so no point of it lies farther from the arm's axis than the
    # tube's diameter plus the arm's radius (under 5 cm); where the file puts them, 26-38 cm
    reach = 2 * SLEEVE[1] / 100 / np.pi + 0.05
    cuffs = sewn.vertices[att["cuffs"]].astype(np.float64)
    for side in (1, -1):
        point, d = body_arm(rest, side)
        c = cuffs[cuffs[:, 0] * side > 0] - point
        assert np.all(np.linalg.norm(c - (c @ d)[:, None] * d, axis=1) < reach)
        assert np.all(np.abs(cuffs[cuffs[:, 0] * side > 0][:, 0]) > 0.45)
