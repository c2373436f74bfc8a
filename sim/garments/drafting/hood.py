"""A two-piece hood sewn into a top's neckline (hoodies, jackets).

Each half is drafted as pattern books draft the hood block: its neck edge as long as half the
neckline it is sewn into (front half to the side neck point, then the back half), rising 3 cm
at the centre back; the back seam up to the back of the head; the crown curving over the head
to the face opening, whose height is the distance from the neck base to the top of the head
plus ease. The halves are joined by the back and crown seams; their face edges are free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.garments.pattern import Edge, Panel, Placement, Seam

HOOD_EASE = 0.06
"""Height [m] the hood stands above the head, and its depth beyond the head's."""

HOOD_HOLD = 4.0
"""The hood's ``Placement.hold`` against the bodices' 1: its neck seam meets near the hood's neck
edge, drafted round the neck, rather than on the bodices' neckline, which is placed on the
torso's cylinder up to 18 cm off the neck. Sewn on the default body (CPU): rest strain 0.058
coarse / 0.24 fine and no crossing at rest; at 1 (the mean of the sides) the coarse hood crosses
itself (2 edges), at 0 (sewn where the neckline is placed) the fine hood's throat edges stay
stretched 11 times their length and it explodes while settling."""


@dataclass(frozen=True)
class HoodPlacement(Placement):
    """A hood half's cone (``Placement``) turned at each height so that its back seam lies at
    the centre back: the seam runs straight from panel point (``seam`` x0, y0) to (x1, y1) and
    slants backwards up the panel faster than the cone widens, so on the plain cone the halves
    wrap past the centre back 6-11 cm above the neck and cross each other when sewn."""

    seam: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def place(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        r0 = 1.0 / float(self.curvature)
        r = np.maximum(r0 + float(self.radius_slope) * np.minimum(xy[:, 1] - self.origin[1], 0.0), 0.05 * r0)
        x0, y0, x1, y1 = self.seam
        seam_x = x0 + np.clip((xy[:, 1] - y0) / (y1 - y0), 0.0, 1.0) * (x1 - x0)
        side = np.sign(x1 - self.origin[0])  # +1: the seam lies along +x from the side (a left half)
        turn = seam_x - side * 0.5 * np.pi * r - self.origin[0]  # the seam a quarter turn from the side
        return super().place(xy - np.stack([turn, np.zeros_like(turn)], axis=1))


def hood_outline(front_neck: float, back_neck: float, height: float,
                 depth: float) -> tuple[np.ndarray, tuple]:
    """The left half's corners and edges, x from the face backwards and y up [m]: neck front
    (0), neck back (1), back seam (2), crown (3), face opening (4)."""
    neck = front_neck + back_neck
    corners = np.array([[0.0, 0.0], [front_neck, 0.0], [neck, 0.03],
                        [max(depth, neck) + 0.01, 0.45 * height], [0.03, height]])
    back, top = corners[3], corners[4]
    edges = (Edge(label="hood_neck"), Edge(label="hood_neck"), Edge(label="hood_back"),
             Edge("cubic", ((back[0] + 0.01, back[1] + 0.45 * height),
                            (top[0] + 0.55 * back[0], top[1] + 0.02)), "hood_crown"),
             Edge("quadratic", ((-0.02, 0.5 * height),), "hood_edge"))
    return corners, edges


def mirror_panel(name: str, corners: np.ndarray, edges: tuple, placement: Placement) -> Panel:
    """The mirror image of an outline (x -> -x), still counter-clockwise: edge i of the
    original is edge (K - 1 - i) of the mirror, traversed the other way."""
    k = len(corners)
    mc = corners * np.array([-1.0, 1.0])
    order = [0] + list(range(k - 1, 0, -1))
    out = []
    for i in range(k - 1, -1, -1):
        e = edges[i]
        # a Bezier's control points mirror and reverse; an arc mirrored and reversed bulges
        # to the same side of its direction, so its parameters stay
        ctl = e.controls if e.kind == "arc" else tuple((-c[0], c[1]) for c in e.controls[::-1])
        out.append(Edge(e.kind, ctl, e.label))
    return Panel(name, mc[order], tuple(out), placement)


def hood_panels(front_neck: float, back_neck: float, gap: float, head_centre: np.ndarray, neck_y: float,
                head_top: float, head_radius: float) -> tuple[list[Panel], list[Seam]]:
    """The two hood halves around the head and their back and crown seams.

    Args:
        front_neck, back_neck: lengths [m] of the front and back neckline halves (centre to
            side neck point) the hood is sewn into; the front one starts ``gap`` [m] from the
            centre front.
        head_centre: (x, z) of the head's vertical axis [m]; neck_y: the neck base's height;
        head_top: the top of the head's height; head_radius: the head's largest horizontal
            radius [m].
    """
    height = head_top - neck_y + HOOD_EASE
    depth = 2.0 * head_radius + HOOD_EASE
    corners, edges = hood_outline(front_neck, back_neck, height, depth)
    neck = front_neck + back_neck
    # each half on a cone around the head's axis: at the neck its neck edge runs half round from
    # the front corner (``gap`` from the centre front of a neckline of radius ``rn``) to the
    # centre back; from ear height up a cylinder clear of the head; the centre back at the back
    rn = (neck + gap) / np.pi
    r_neck = neck / (np.pi - gap / rn)
    r_head = head_radius + 0.03
    ear = 0.5 * (head_top - neck_y)
    x0 = neck - 0.5 * np.pi * r_neck
    cx, cz = float(head_centre[0]), float(head_centre[1])
    cone = dict(curvature=1.0 / r_head, radius_slope=(r_head - r_neck) / ear, hold=HOOD_HOLD)
    y = neck_y + ear
    (sx0, sy0), (sx1, sy1) = corners[2], corners[3]
    left = HoodPlacement(anchor=(cx + r_head, y, cz), u_dir=(0.0, 0.0, -1.0), origin=(x0, ear),
                         seam=(sx0, sy0, sx1, sy1), **cone)
    right = HoodPlacement(anchor=(cx - r_head, y, cz), u_dir=(0.0, 0.0, 1.0), origin=(-x0, ear),
                          seam=(-sx0, sy0, -sx1, sy1), **cone)
    panels = [Panel("hood_l", corners, edges, left), mirror_panel("hood_r", corners, edges, right)]
    seams = [Seam(("hood_l", 2), ("hood_r", 2)), Seam(("hood_l", 3), ("hood_r", 1))]
    return panels, seams
