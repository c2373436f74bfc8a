"""GarmentCode sewing-pattern files: read and write the pattern specification JSON.

The format is the one of GarmentCode and GarmentCodeData (Korosteleva & Sorkine-Hornung 2023;
Korosteleva et al. 2024; the ``pygarment`` package, ``pygarment/pattern/core.py``) and of the
Garment-Pattern-Generator's ``specification.json`` (Korosteleva & Lee 2021,
``docs/template_spec_with_comments.json``)::

    {"pattern": {"panels": {NAME: {"vertices": [[x, y], ...], "edges": [EDGE, ...],
                                   "translation": [x, y, z], "rotation": [rx, ry, rz],
                                   "label": "body"}},
                 "stitches": [[{"panel": A, "edge": i}, {"panel": B, "edge": j}], ...],
                 "panel_order": [NAME, ...]},
     "properties": {"units_in_meter": 100, "curvature_coords": "relative", ...},
     "parameters": {}, "parameter_order": []}

    EDGE = {"endpoints": [v0, v1], "curvature": CURVE, "label": "lower_interface"}

How each part maps onto ``sim.garments.pattern``:

- Lengths are in file units; ``properties.units_in_meter`` of them make a metre (GarmentCodeData
  writes centimetres, 100; GarmentCode reads a file without it as centimetres, and so do we).
- A panel's edges form a directed closed loop (edge i ends where edge i + 1 starts); the start
  vertex of edge i is our corner i, so edge and stitch indices are kept.
- ``curvature``: a bare ``[x, y]`` (a quadratic Bézier control point, older files), a list of two
  points (cubic) or ``{"type": "quadratic" | "cubic", "params": [[x, y], ...]}``. With
  ``curvature_coords`` "relative" (the default) a point is in the edge's frame: ``x`` along the
  edge as a fraction of it, ``y`` along the edge turned 90° counter-clockwise (to the left of the
  edge's direction) as a fraction of its length (``pygarment/pattern/utils.py``
  ``rel_to_abs_2d``); "absolute" gives panel coordinates. ``{"type": "circle", "params":
  [radius, large_arc, right]}`` is a circular arc, radius in file units, ``right`` 1 when the arc
  bulges to the right of the edge's direction (``pygarment/garmentcode/edge.py``
  ``CircleEdge.as_radius_flag``), our ``arc`` edge.
- A 3D point of a panel is ``translation + R @ (x, y, 0)`` with ``R = Rz(rz) Ry(ry) Rx(rx)``,
  angles in degrees (Maya's "xyz" rotation order, ``pygarment/pattern/rotation.py``
  ``euler_xyz_to_R``, which GarmentCodeData's box-mesh generator places panels with; ``rotation``
  may also be a 3x3 matrix). Our ``Placement`` is flat: anchor = translation, u_dir / v_dir = the
  rotated x / y axes.
- A loop is counter-clockwise seen from the garment's outside, so a panel whose outside faces its
  ``-z`` (GarmentCode's back panels) is clockwise in its own plane. Ours are counter-clockwise in
  their plane with the outside along ``u_dir x v_dir``; such a panel is mirrored (x -> -x,
  u_dir = -(rotated x axis), relative curvature y and arc ``right`` flipped): the 3D outline, the
  edge order and directions and every index stay as in the file.
- A stitch joins the end of its first edge to the start of its second (GarmentCodeData's
  ``boxmeshgen.py``, ``Seam.swap``), our ``Seam.reverse`` True; a third entry ``"right_wrong"``
  joins start to start (the right side of one panel to the wrong side of the other),
  ``reverse`` False. A stitch between two consecutive edges of one panel, end to start around
  their shared corner, is a dart.
- Edge ``label``s become ``Edge.label``, GarmentCode's own named as ours (``our_label``);
  the openings a file does not label are named "cuff" and "hem" by where they are
  (``labelled_openings``; not in files wrinkles wrote, which keep their labels); panel
  ``label``s ("body", "arm", "leg") go to ``Pattern.parameters["panel_labels"]``;
  ``panel_order`` orders ``Pattern.panels``.
- ``properties.normalize_panel_translation`` True moves each panel's vertices by their mean and
  its translation by the same 2D offset, as GarmentCode does on loading.

Frames: GarmentCodeData places its panels around a body standing on the floor (y = 0 at the
soles); the Garment-Pattern-Generator's files and ours around the body in its own rest frame (Y
up, the pelvis near the origin, as ``BodyModel.rest_mesh``). ``place_on_body`` moves a pattern
onto a rest body: "floor" raises every panel by the height of the body's soles (a negative
number: it lowers them), "body" keeps it, "auto" takes the one of the two in which the pattern's
height span lies more inside the body's (``pattern_frame``). GarmentCodeData's bodies stand in an
A-pose, ours in a T-pose: ``place_on_body`` then turns the sleeves onto the body's arms
(``sim.garments.sleeve_pose``).

Writing emits the same format in centimetres with relative coordinates and ``{"type",
"params"}`` curvatures, every stitch as above, and ``normalized_edge_loops`` True so that
GarmentCode keeps our edge order (and so every edge index) instead of starting each loop at its
lowest-left vertex. A curved ``Placement`` (a panel wrapped on a
cylinder) is written as the plane tangent to it at the anchor; the top-level ``"wrinkles"``
section keeps what GarmentCode has no field for (placement origin, curvature and slope [m],
its ``hold``, darts, the pattern's name and parameters), so reading our own file gives the pattern back.
"""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from sim.errors import WrinklesInputError
from sim.garments.pattern import Edge, Panel, Pattern, Placement, Seam

UNITS_IN_METER = 100.0
"""File units per metre written (centimetres, as GarmentCodeData)."""
RIGHT_WRONG = "right_wrong"
"""The stitch flag that joins its two edges start to start."""
EXTENSION = "wrinkles"
"""Top-level key of what wrinkles writes beyond GarmentCode's fields (values in metres)."""
GARMENTCODE_LABELS = {"lower_interface": "waistband", "strapless_top": "waistband"}
"""GarmentCode's edge labels with another name here: the top of a skirt or trousers (the waist
seam of a dress or jumpsuit) and of a strapless top, which GarmentCodeData's simulator holds
at the body's waist and under the arms (``assets/Sim_props/default_sim_props.yaml``
``attachment_label_names``, ``pygarment/meshgen/garment.py``), are our "waistband" (held while
the sewn garment settles, ``sewing.HELD``); where such an edge is sewn to another (a dress's or
jumpsuit's waist seam) it is our "waist" (``labelled_openings``): held, the seam keeps the
stretch the closing left in it (a pencil dress's rest strain 0.53 -> 13.8 at a 4 cm edge)."""
HEM_SLOPE_DEG = 30.0
"""An opening of a file without labels for it is a hem when it runs within this angle [deg] of
the horizontal below its panel's centre (a bottom edge; side openings and slits are steeper)."""
FRAMES = ("auto", "floor", "body")
"""Frames a pattern file's panels may be placed in (``place_on_body``)."""


class _SpecError(Exception):
    """A problem in a specification, raised inside the reader and re-raised naming the file."""


# ----------------------------------------------------------------------------- rotations


def rotation_matrix(euler_deg) -> np.ndarray:
    """GarmentCode's rotation of XYZ Euler angles [deg]: ``Rz @ Ry @ Rx``, shape (3, 3)."""
    a, b, c = np.deg2rad(np.asarray(euler_deg, np.float64))
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def euler_angles(r: np.ndarray) -> list[float]:
    """XYZ Euler angles [deg] of a rotation matrix, the inverse of ``rotation_matrix``."""
    r = np.asarray(r, np.float64)
    cb = float(np.hypot(r[0, 0], r[1, 0]))
    b = np.arctan2(-r[2, 0], cb)
    if cb > 1e-9:
        a, c = np.arctan2(r[2, 1], r[2, 2]), np.arctan2(r[1, 0], r[0, 0])
    else:  # gimbal lock (ry = ±90°): put the whole turn about x
        a, c = np.arctan2(-r[1, 2], r[1, 1]), 0.0
    return [float(np.rad2deg(x)) for x in (a, b, c)]


# ----------------------------------------------------------------------------- reading


def read_garmentcode(path: str | os.PathLike) -> Pattern:
    """Read a GarmentCode / GarmentCodeData pattern specification JSON file [m].

    Raises:
        WrinklesInputError: the file is missing, not JSON, or not a pattern we can read; the
            one-line message names the file and what is wrong.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise WrinklesInputError(f"cannot read the pattern file ({exc.strerror or exc})", path=path) from None
    except UnicodeDecodeError:
        raise WrinklesInputError("is not a GarmentCode pattern: not UTF-8 text", path=path) from None
    try:
        spec = json.loads(text)
    except json.JSONDecodeError as exc:
        raise WrinklesInputError(f"is not a GarmentCode pattern: not JSON ({exc.msg} at line {exc.lineno})",
                                 path=path) from None
    name = path.stem[: -len("_specification")] if path.stem.endswith("_specification") else path.stem
    return pattern_from_spec(spec, name=name or "garmentcode", path=path)


def pattern_from_spec(spec: dict, *, name: str = "garmentcode",
                      path: str | os.PathLike | None = None) -> Pattern:
    """The ``Pattern`` [m] of a GarmentCode specification (the parsed JSON).

    Args:
        spec: the specification, ``{"pattern": ..., "properties": ...}``.
        name: the pattern's name when the specification does not carry one.
        path: the file it came from, named in error messages.

    Raises:
        WrinklesInputError: unknown or inconsistent content.
    """
    try:
        return _pattern(spec, name)
    except (_SpecError, ValueError, TypeError) as exc:  # ValueError: the pattern types' own checks
        raise WrinklesInputError(f"GarmentCode pattern: {exc}", path=path) from None


def _pattern(spec, name: str) -> Pattern:
    if not isinstance(spec, dict) or not isinstance(spec.get("pattern"), dict):
        raise _SpecError("no 'pattern' object at the top level")
    props = spec.get("properties") or {}
    if not isinstance(props, dict):
        raise _SpecError("'properties' is not an object")
    units = props.get("units_in_meter", UNITS_IN_METER)
    if isinstance(units, bool) or not isinstance(units, (int, float)) or not units > 0:
        raise _SpecError(f"properties.units_in_meter must be a positive number, got {units!r}")
    coords = props.get("curvature_coords", "relative")
    if coords not in ("relative", "absolute"):
        raise _SpecError(f"properties.curvature_coords must be 'relative' or 'absolute', got {coords!r}")
    ext = spec.get(EXTENSION) if isinstance(spec.get(EXTENSION), dict) else {}
    extra = ext.get("placements") if isinstance(ext.get("placements"), dict) else {}
    body = spec["pattern"]
    raw = body.get("panels")
    if not isinstance(raw, dict) or not raw:
        raise _SpecError("'pattern.panels' has no panels")
    panels, labels = {}, {}
    for pname in _panel_order(body, raw):
        panels[pname] = _panel(pname, raw[pname], 1.0 / float(units), coords == "relative",
                               bool(props.get("normalize_panel_translation", False)), extra.get(pname))
        if isinstance(raw[pname].get("label"), str) and raw[pname]["label"]:
            labels[pname] = raw[pname]["label"]
    seams = _seams(body.get("stitches", []), panels, ext.get("darts"))
    params = dict(ext.get("parameters") or {})
    if labels:
        params["panel_labels"] = labels
    pattern = Pattern(str(ext.get("name") or name), tuple(panels.values()), seams, params)
    return pattern if EXTENSION in spec else labelled_openings(pattern)


def _panel_order(body: dict, raw: dict) -> list[str]:
    order = body.get("panel_order")
    if order is None:
        return list(raw)
    if not isinstance(order, list):
        raise _SpecError("'pattern.panel_order' is not a list")
    listed = [n for n in order if n is not None]
    missing = [n for n in listed if n not in raw]
    if missing:
        raise _SpecError(f"panel_order names panels the file does not have: {missing}")
    if len(set(listed)) != len(listed):
        raise _SpecError("panel_order names a panel twice")
    return listed + [n for n in raw if n not in listed]


def _vec(value, n: int, what: str) -> np.ndarray:
    try:
        out = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise _SpecError(f"{what} must be {n} numbers, got {value!r}") from None
    if out.shape != (n,) or not np.all(np.isfinite(out)):
        raise _SpecError(f"{what} must be {n} finite numbers, got {value!r}")
    return out


def _rotation(value, what: str) -> np.ndarray:
    """A panel's rotation: XYZ Euler angles [deg] or a 3x3 matrix."""
    value = [0, 0, 0] if value is None else value
    try:
        arr = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is not None and arr.shape == (3, 3) and np.all(np.isfinite(arr)):
        if not np.allclose(arr @ arr.T, np.eye(3), atol=1e-6) or np.linalg.det(arr) < 0:
            raise _SpecError(f"{what} is a 3x3 matrix but not a rotation")
        return arr
    return rotation_matrix(_vec(value, 3, f"{what} (XYZ Euler angles in degrees)"))


def _panel(name: str, raw, scale: float, relative: bool, centre: bool, extra) -> Panel:
    if not isinstance(raw, dict):
        raise _SpecError(f"panel {name!r} is not an object")
    try:
        verts = np.asarray(raw.get("vertices", []), np.float64) * scale
    except (TypeError, ValueError):
        raise _SpecError(f"panel {name!r}: 'vertices' must be [x, y] pairs") from None
    if verts.ndim != 2 or verts.shape[1] != 2 or len(verts) < 2 or not np.all(np.isfinite(verts)):
        raise _SpecError(f"panel {name!r}: 'vertices' must be at least two [x, y] pairs")
    edges_raw = raw.get("edges")
    if not isinstance(edges_raw, list) or len(edges_raw) < 2:
        raise _SpecError(f"panel {name!r}: 'edges' must list the edges of its outline")
    ends = [_endpoints(name, k, e, len(verts)) for k, e in enumerate(edges_raw)]
    for k, (_, v1) in enumerate(ends):
        if ends[(k + 1) % len(ends)][0] != v1:
            raise _SpecError(f"panel {name!r}: edge {k} ends at vertex {v1} but edge "
                             f"{(k + 1) % len(ends)} starts at vertex {ends[(k + 1) % len(ends)][0]}; "
                             "the edges must form one closed loop in order")
    corners = verts[[v0 for v0, _ in ends]]
    edges = [_edge(name, k, e, corners[k], corners[(k + 1) % len(corners)], scale, relative)
             for k, e in enumerate(edges_raw)]
    r = _rotation(raw.get("rotation"), f"panel {name!r} rotation")
    anchor = _vec(raw.get("translation", [0, 0, 0]), 3, f"panel {name!r} translation") * scale
    if centre:  # GarmentCode moves the vertices to their mean and the translation by it, unrotated
        mean = np.append(verts.mean(axis=0), 0.0)
        anchor = anchor + mean - r @ mean
    extra = extra if isinstance(extra, dict) else {}
    origin = _vec(extra.get("origin", [0, 0]), 2, f"{EXTENSION}.placements.{name}.origin")
    placement = dict(anchor=anchor + r @ np.append(origin, 0.0), origin=origin,
                     curvature=float(extra.get("curvature", 0.0)),
                     radius_slope=float(extra.get("radius_slope", 0.0)), hold=float(extra.get("hold", 1.0)))
    panel = Panel(name, corners, tuple(edges), _placement(r[:, 0], r[:, 1], **placement))
    if panel.area() >= 0:
        return panel
    flip = np.array([-1.0, 1.0])
    placement["origin"] = origin * flip
    return Panel(name, corners * flip, tuple(_mirrored(e) for e in edges),
                 _placement(-r[:, 0], r[:, 1], **placement))


def _placement(u, v, *, anchor, origin, curvature: float, radius_slope: float, hold: float) -> Placement:
    return Placement(tuple(float(x) for x in anchor), tuple(float(x) for x in u), tuple(float(x) for x in v),
                     curvature, (float(origin[0]), float(origin[1])), radius_slope, hold)


def _endpoints(name: str, k: int, edge, n: int) -> tuple[int, int]:
    ends = edge.get("endpoints") if isinstance(edge, dict) else None
    if (not isinstance(ends, list) or len(ends) != 2
            or not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < n for i in ends)):
        raise _SpecError(f"panel {name!r}: edge {k} needs 'endpoints' [i, j], two of its {n} vertex "
                         f"indices, got {ends!r}")
    if ends[0] == ends[1]:
        raise _SpecError(f"panel {name!r}: edge {k} starts and ends at vertex {ends[0]}")
    return ends[0], ends[1]


def our_label(label: str) -> str:
    """Our edge label (``sim.garments.designs.ATTACHMENT_LABELS``, ``sewing.HELD``) of a
    GarmentCode edge label (``GARMENTCODE_LABELS``; "{side}_collar" -> "neckline",
    "{side}_armhole" -> "armhole"); any other label stays as it is."""
    if label in GARMENTCODE_LABELS:
        return GARMENTCODE_LABELS[label]
    if label.endswith("_collar"):
        return "neckline"
    return "armhole" if label.endswith("_armhole") else label


def labelled_openings(pattern: Pattern) -> Pattern:
    """``pattern`` with a "waistband" sewn to another edge named "waist" (the waist seam of a dress
    or jumpsuit, which hangs free while settling) and its unlabelled openings (edges in no seam)
    named as ours are: "cuff" on an
    arm panel (``sleeve_pose.arm_panels``), "hem" where the edge runs within ``HEM_SLOPE_DEG`` of
    the horizontal below the centre of its panel (where the placements put them)."""
    from sim.garments.sleeve_pose import arm_panels

    arms = {n for names in arm_panels(pattern).values() for n in names}
    free: dict[str, set[int]] = {}
    for name, i in pattern.free_edges():
        free.setdefault(name, set()).add(i)
    panels = []
    for p in pattern.panels:
        centre_y = float(p.placement.place(p.outline(8))[:, 1].mean())
        edges = [replace(e, label="waist") if e.label == "waistband" and i not in free.get(p.name, ()) else e
                 for i, e in enumerate(p.edges)]
        for i in sorted(free.get(p.name, ())):
            if edges[i].label:
                continue
            pts = p.placement.place(p.edge_curve(i, 8))
            chord = pts[-1] - pts[0]
            flat = abs(chord[1]) <= np.sin(np.deg2rad(HEM_SLOPE_DEG)) * np.linalg.norm(chord)
            label = "cuff" if p.name in arms else "hem" if flat and pts[:, 1].mean() < centre_y else ""
            edges[i] = replace(edges[i], label=label)
        panels.append(replace(p, edges=tuple(edges)))
    return replace(pattern, panels=tuple(panels))


def _edge(name: str, k: int, raw: dict, p0: np.ndarray, p1: np.ndarray, scale: float,
          relative: bool) -> Edge:
    label = raw.get("label", "")
    label = our_label(label if isinstance(label, str) else str(label))
    curve = raw.get("curvature")
    where = f"panel {name!r} edge {k}"
    if curve is None:
        return Edge("line", (), label)
    if isinstance(curve, dict):
        kind, params = curve.get("type"), curve.get("params")
        if kind == "circle":
            p = _vec(params, 3, f"{where}: circle params [radius, large_arc, right]")
            if p[0] <= 0:
                raise _SpecError(f"{where}: circle radius must be positive, got {p[0]}")
            return Edge("arc", ((p[0] * scale, float(bool(p[1])), float(bool(p[2]))),), label)
        if kind not in ("quadratic", "cubic"):
            raise _SpecError(f"{where}: unknown curvature type {kind!r} "
                             "(expected quadratic, cubic or circle)")
        points = params if kind == "cubic" or _is_nested(params) else [params]
        if not isinstance(points, list) or len(points) != (1 if kind == "quadratic" else 2):
            raise _SpecError(f"{where}: a {kind} curvature needs {1 if kind == 'quadratic' else 2} "
                             f"control points, got {params!r}")
    elif isinstance(curve, list) and _is_nested(curve) and len(curve) == 2:
        kind, points = "cubic", curve
    elif isinstance(curve, list):
        kind, points = "quadratic", [curve]
    else:
        raise _SpecError(f"{where}: unknown curvature {curve!r}")
    controls = [_control(_vec(c, 2, f"{where}: control point"), p0, p1, scale, relative) for c in points]
    return Edge(kind, tuple(controls), label)


def _is_nested(value) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, (list, tuple)) for v in value)


def _control(c: np.ndarray, p0: np.ndarray, p1: np.ndarray, scale: float, relative: bool) -> tuple:
    """A control point in panel coordinates [m] from the file's relative or absolute one."""
    if not relative:
        return tuple(c * scale)
    d = p1 - p0
    return tuple(p0 + c[0] * d + c[1] * np.array([-d[1], d[0]]))


def _mirrored(e: Edge) -> Edge:
    """The edge of the panel mirrored x -> -x (same direction, the other side bulges)."""
    if e.kind == "arc":
        radius, large, right = e.controls[0]
        return Edge("arc", ((radius, large, 1.0 - right),), e.label)
    return Edge(e.kind, tuple((-x, y) for x, y in e.controls), e.label)


def _seams(stitches, panels: dict[str, Panel], darts) -> tuple[Seam, ...]:
    if not isinstance(stitches, list):
        raise _SpecError("'pattern.stitches' is not a list")
    darts = set(darts) if isinstance(darts, list) else None
    seams = []
    for k, st in enumerate(stitches):
        if not isinstance(st, list) or not 2 <= len(st) <= 3:
            raise _SpecError(f"stitch {k} must be a list of two edges (and an optional 'right_wrong'), "
                             f"got {st!r}")
        if len(st) == 3 and st[2] != RIGHT_WRONG:
            raise _SpecError(f"stitch {k}: unknown third entry {st[2]!r} (expected {RIGHT_WRONG!r}); "
                             "only stitches of two edges are supported")
        a, b = (_side(k, s, panels) for s in st[:2])
        reverse = len(st) == 2
        dart = k in darts if darts is not None else _is_dart(a, b, reverse, panels)
        seams.append(Seam(a, b, reverse=reverse, dart=dart))
    return tuple(seams)


def _side(k: int, side, panels: dict[str, Panel]) -> tuple[str, int]:
    if not isinstance(side, dict) or "panel" not in side or "edge" not in side:
        raise _SpecError(f"stitch {k}: each side must be {{'panel': NAME, 'edge': INDEX}}, got {side!r}")
    name, edge = side["panel"], side["edge"]
    if name not in panels:
        raise _SpecError(f"stitch {k} refers to panel {name!r}, which the file does not have")
    n = len(panels[name].edges)
    if not isinstance(edge, int) or isinstance(edge, bool) or not 0 <= edge < n:
        raise _SpecError(f"stitch {k} refers to edge {edge!r} of panel {name!r}, which has edges 0..{n - 1}")
    return name, edge


def _is_dart(a: tuple[str, int], b: tuple[str, int], reverse: bool, panels: dict[str, Panel]) -> bool:
    """Two consecutive edges of one panel sewn end to start around their shared corner."""
    if a[0] != b[0] or not reverse:
        return False
    n = len(panels[a[0]].edges)
    return (a[1] + 1) % n == b[1] or (b[1] + 1) % n == a[1]


# ----------------------------------------------------------------------------- writing


def write_garmentcode(pattern: Pattern, path: str | os.PathLike, *,
                      units_in_meter: float = UNITS_IN_METER) -> None:
    """Write ``pattern`` as a GarmentCode pattern specification JSON file (see the module)."""
    text = json.dumps(pattern_to_spec(pattern, units_in_meter=units_in_meter), indent=1,
                      default=_json_default)
    Path(path).write_text(text + "\n", encoding="utf-8")


def pattern_to_spec(pattern: Pattern, *, units_in_meter: float = UNITS_IN_METER) -> dict:
    """The GarmentCode specification (a JSON-able dict) of ``pattern``, in ``units_in_meter``
    units per metre with relative curvature coordinates."""
    s = float(units_in_meter)
    labels = pattern.parameters.get("panel_labels") or {}
    panels, extra = {}, {}
    for p in pattern.panels:
        r, t = _frame(p.placement)
        spec = {"translation": (t * s).tolist(), "rotation": euler_angles(r),
                "vertices": (p.corners * s).tolist(),
                "edges": [_edge_spec(p, k, s) for k in range(len(p.edges))]}
        if labels.get(p.name):
            spec["label"] = labels[p.name]
        panels[p.name] = spec
        pl = p.placement
        if pl.curvature or pl.radius_slope or any(pl.origin) or pl.hold != 1.0:
            extra[p.name] = {"origin": [float(x) for x in pl.origin], "curvature": float(pl.curvature),
                             "radius_slope": float(pl.radius_slope), "hold": float(pl.hold)}
    stitches = [[{"panel": sm.a[0], "edge": int(sm.a[1])}, {"panel": sm.b[0], "edge": int(sm.b[1])}]
                + ([] if sm.reverse else [RIGHT_WRONG]) for sm in pattern.seams]
    return {
        "pattern": {"panels": panels, "stitches": stitches, "panel_order": [p.name for p in pattern.panels]},
        "parameters": {}, "parameter_order": [],
        "properties": {"curvature_coords": "relative", "normalize_panel_translation": False,
                       "normalized_edge_loops": True, "units_in_meter": s},
        EXTENSION: {"name": pattern.name, "parameters": pattern.parameters,
                    "darts": [k for k, sm in enumerate(pattern.seams) if sm.dart], "placements": extra},
    }


def _frame(pl: Placement) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation [m] of the plane a placement puts the panel on at its anchor
    (u_dir, then v_dir made orthogonal to it)."""
    u = np.asarray(pl.u_dir, np.float64)
    u = u / np.linalg.norm(u)
    v = np.asarray(pl.v_dir, np.float64)
    v = v - (v @ u) * u
    v = v / np.linalg.norm(v)
    r = np.stack([u, v, np.cross(u, v)], axis=1)
    return r, np.asarray(pl.anchor, np.float64) - r @ np.array([pl.origin[0], pl.origin[1], 0.0])


def _edge_spec(p: Panel, k: int, s: float) -> dict:
    n = len(p.corners)
    e = p.edges[k]
    out: dict = {"endpoints": [k, (k + 1) % n]}
    if e.kind == "arc":
        radius, large, right = e.controls[0]
        out["curvature"] = {"type": "circle", "params": [radius * s, int(bool(large)), int(bool(right))]}
    elif e.kind in ("quadratic", "cubic"):
        p0, p1 = p.edge_ends(k)
        out["curvature"] = {"type": e.kind, "params": [_relative(c, p0, p1, p.name, k) for c in e.controls]}
    if e.label:
        out["label"] = e.label
    return out


def _relative(c, p0: np.ndarray, p1: np.ndarray, name: str, k: int) -> list[float]:
    """A control point in the edge's frame (the inverse of ``_control``)."""
    d = p1 - p0
    dd = float(d @ d)
    if dd == 0.0:
        raise ValueError(f"panel {name!r} edge {k}: a curve between coincident corners has no edge frame")
    w = np.asarray(c, np.float64) - p0
    return [float(w @ d) / dd, float(d[0] * w[1] - d[1] * w[0]) / dd]


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple):
        return list(value)
    raise TypeError(f"pattern parameter {value!r} is not JSON-able")


# ----------------------------------------------------------------------------- frames


def height_span(pattern: Pattern) -> tuple[float, float]:
    """Lowest and highest y [m] of the pattern's panels where their placements put them."""
    ys = np.concatenate([p.placement.place(p.outline(8))[:, 1] for p in pattern.panels])
    return float(ys.min()), float(ys.max())


def pattern_frame(pattern: Pattern, body_vertices: np.ndarray) -> str:
    """"floor" or "body": the frame in which more of the pattern's height span lies inside the
    rest body's (``body_vertices`` (V, 3) [m]); "body" on a tie."""
    y = np.asarray(body_vertices, np.float64)[:, 1]
    lo, hi = height_span(pattern)

    def inside(shift: float) -> float:
        return max(0.0, min(hi + shift, y.max()) - max(lo + shift, y.min())) / max(hi - lo, 1e-9)

    return "floor" if inside(float(y.min())) > inside(0.0) else "body"


def place_on_body(pattern: Pattern, body_vertices: np.ndarray, frame: str = "auto") -> Pattern:
    """``pattern`` with its panels moved from the file's ``frame`` (``FRAMES``; see the module)
    into the frame of the rest body ``body_vertices`` (V, 3) [m] and its sleeves turned onto the
    body's arms (``sleeve_pose.pose_sleeves``)."""
    if frame not in FRAMES:
        raise ValueError(f"unknown pattern frame {frame!r}; expected one of {', '.join(FRAMES)}")
    from sim.garments.sleeve_pose import pose_sleeves

    if frame == "auto":
        frame = pattern_frame(pattern, body_vertices)
    if frame == "floor":
        lift = np.array([0.0, float(np.min(np.asarray(body_vertices)[:, 1])), 0.0])
        pattern = replace(pattern, panels=tuple(replace(p, placement=replace(p.placement, anchor=tuple(
            float(a) for a in np.asarray(p.placement.anchor) + lift))) for p in pattern.panels))
    return pose_sleeves(pattern, body_vertices)
