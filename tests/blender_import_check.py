"""Import a wrinkles USD stage into Blender and compare what Blender sees with what we wrote.

Run with Blender's Python (the PyPI ``bpy`` module, see scripts/setup-blender-venv.sh), not
the project venv: it needs only ``bpy`` and ``numpy``::

    .venv-blender/bin/python tests/blender_import_check.py STAGE.usdc EXPECTED.npz

``EXPECTED.npz`` (written by tests/test_blender_import.py) holds ``fps``, ``start``, ``end``,
``names`` (Blender object names = USD prim names) and per name ``points__<name>`` (T, V, 3)
[m, Y up], ``faces__<name>`` (F, 3) and optionally ``corner_uvs__<name>`` (F, 3, 2); for a
body written as a UsdSkel rig ``skinned`` (its name), ``joints`` (the skeleton's joint names)
and ``shape_keys`` (how many pose blend shapes it has); for a garment with normal maps
``normal_map__<name>`` (H, W, 3): its first frame's image as values in [0, 1], row 0 the top,
and ``tangents__<name>`` / ``bitangents__<name>`` (F, 3, 3) [Y up]: our tangent frame's t1 and
n x t1 (``sim.geometry.frames.tangent_basis``) at each face corner at the first frame.

Checks, each within ``TOL`` [m]:
  * every named mesh object exists and carries a Mesh Sequence Cache modifier (time-sampled
    points), except the skinned body: it has an Armature modifier on an Armature object whose
    bones are the joints, a vertex group per joint, and a shape key per blend shape;
  * the scene frame range is the stage's time-code range;
  * at every frame k the evaluated, world-space vertices (the skinned body posed by its
    armature and shape keys) equal our points at time code k, converted Y up -> Z up as
    Blender does on import ((x, y, z) -> (x, -z, y));
  * two different frames really differ (the animation is not frozen on one sample);
  * loop topology and face-varying UVs (seams) equal ours;
  * a garment with normal maps: its material's Principled BSDF takes its Normal from a Normal
    Map node (tangent space) fed by an Image Texture node whose image, read as non-colour data,
    is our first frame's PNG pixel for pixel (Blender stores rows bottom first), and Blender's
    MikkTSpace tangent and bitangent (sign * normal x tangent) point along our t1 and n x t1.

Prints one line ``WRINKLES_CHECK_RESULT {json}`` and exits 0 when all checks pass, 1 if not.
Blender 4.5 does not read ``timeCodesPerSecond`` on import (the scene keeps its fps, 24);
time code k always lands on frame k, so the script records the imported fps, sets the
stage's fps and re-checks the positions, which must be unchanged.
"""

from __future__ import annotations

import json
import sys

import bpy
import numpy as np

#: position tolerance [m]: float32 points through Blender's float32 mesh and a 90 degree
#: rotation matrix (exact up to rounding) stay far below this; so does Blender's armature
#: deform of a rig (float32 bone matrices: ~1e-6 m on a walking body, Blender 4.5).
TOL = 1e-4
#: UV tolerance: float32 UVs are copied unchanged.
UV_TOL = 1e-6
#: normal-map pixel tolerance: a 16-bit PNG read into Blender's float buffer (v / 65535).
PIXEL_TOL = 1e-4
#: smallest cosine between Blender's per-corner tangent (bitangent) and ours: MikkTSpace averages
#: over the faces at a vertex and orthogonalises against Blender's normals, ours over the UV
#: vertex's faces against the area-weighted normal; a flipped or swapped axis gives <= 0.
TANGENT_COS = 0.95
MARKER = "WRINKLES_CHECK_RESULT"


def y_up_to_blender(p: np.ndarray) -> np.ndarray:
    """USD Y-up positions (..., 3) -> Blender Z-up world positions (x, -z, y)."""
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def world_vertices(name: str, frame: int) -> np.ndarray:
    """Evaluated world-space vertex positions of object ``name`` at ``frame``, (V, 3)."""
    scene = bpy.context.scene
    scene.frame_set(frame)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ob = bpy.data.objects[name].evaluated_get(depsgraph)
    mesh = ob.data
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    m = np.array(ob.matrix_world, dtype=np.float64)
    return (co.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]).astype(np.float32)


def check_topology(name: str, faces: np.ndarray, corner_uvs: np.ndarray | None) -> dict:
    """Blender's polygons / loops / UVs against our faces and per-corner UVs."""
    mesh = bpy.data.objects[name].data
    out: dict = {"polygons": len(mesh.polygons)}
    totals = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_total", totals)
    loop_verts = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", loop_verts)
    out["topology_ok"] = bool(len(mesh.polygons) == len(faces) and np.all(totals == 3)
                              and np.array_equal(loop_verts.reshape(-1, 3), faces))
    if corner_uvs is not None:
        out["uv_layers"] = [layer.name for layer in mesh.uv_layers]
        if not mesh.uv_layers:
            out["uv_max_err"] = None
        else:
            uv = np.empty(len(mesh.loops) * 2, np.float32)
            mesh.uv_layers[0].data.foreach_get("uv", uv)
            if uv.size == corner_uvs.size:
                out["uv_max_err"] = float(np.abs(uv.reshape(-1, 3, 2) - corner_uvs).max())
            else:
                out["uv_max_err"] = None
    return out


def check_skin(ob, joints: list[str], shape_keys: int, problems: list[str]) -> dict:
    """The skinned body: an Armature modifier on an Armature object whose bones are the
    joints, a vertex group per joint, ``shape_keys`` shape keys besides the basis."""
    arm_mods = [m for m in ob.modifiers if m.type == "ARMATURE"]
    arm = arm_mods[0].object if arm_mods else None
    keys = ob.data.shape_keys
    info = {"armature": None if arm is None else f"{arm.name}:{arm.type}",
            "bones": [] if arm is None or arm.type != "ARMATURE" else [b.name for b in arm.data.bones],
            "vertex_groups": sorted(g.name for g in ob.vertex_groups),
            "shape_keys": 0 if keys is None else len(keys.key_blocks) - 1,
            "animated": arm is not None and arm.animation_data is not None
            and arm.animation_data.action is not None}
    if arm is None or arm.type != "ARMATURE":
        problems.append(f"{ob.name}: no Armature modifier on an Armature object")
    elif sorted(info["bones"]) != sorted(joints):
        problems.append(f"{ob.name}: armature bones {info['bones']} are not the joints {joints}")
    if info["vertex_groups"] != sorted(joints):
        problems.append(f"{ob.name}: vertex groups {info['vertex_groups']} are not the joints")
    if info["shape_keys"] != shape_keys:
        problems.append(f"{ob.name}: {info['shape_keys']} shape keys, expected {shape_keys}")
    if not info["animated"]:
        problems.append(f"{ob.name}: the armature has no action")
    return info


def check_positions(name: str, ours: np.ndarray, start: int, end: int,
                    problems: list[str]) -> dict:
    """Evaluated world positions at every frame against ours (Blender axes), (T, V, 3)."""
    errs, frames = [], {}
    for k in range(start, end + 1):
        frames[k] = world_vertices(name, k)
        if frames[k].shape != ours[k - start].shape:
            problems.append(f"{name}: frame {k} has {frames[k].shape[0]} vertices, "
                            f"expected {ours.shape[1]}")
            break
        errs.append(float(np.abs(frames[k] - ours[k - start]).max()))
    info: dict = {"max_err_per_frame": errs}
    if len(errs) == end - start + 1:
        info["first_last_max_diff"] = float(np.abs(frames[end] - frames[start]).max())
        if max(errs) > TOL:
            problems.append(f"{name}: positions differ by {max(errs):.3g} m > {TOL}")
        if info["first_last_max_diff"] <= TOL:
            problems.append(f"{name}: frames {start} and {end} are identical in Blender")
    return info


def linked_from(socket):
    """The node feeding an input socket, or None."""
    return socket.links[0].from_node if socket.is_linked else None


def check_normal_map(ob, exp, name: str, problems: list[str]) -> dict:
    """The material's normal-map chain, its image, and Blender's tangent frame against ours."""
    mat = ob.active_material
    nodes = [] if mat is None or not mat.use_nodes else list(mat.node_tree.nodes)
    bsdf = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)
    nmap = None if bsdf is None else linked_from(bsdf.inputs["Normal"])
    tex = linked_from(nmap.inputs["Color"]) if nmap is not None and nmap.type == "NORMAL_MAP" else None
    info: dict = {"chain": [getattr(n, "type", None) for n in (tex, nmap, bsdf)]}
    if bsdf is None or nmap is None or nmap.type != "NORMAL_MAP" or tex is None or tex.type != "TEX_IMAGE":
        problems.append(f"{name}: no Image Texture -> Normal Map -> BSDF Normal chain ({info['chain']})")
        return info
    info["space"] = nmap.space
    image = tex.image
    if nmap.space != "TANGENT" or image is None:
        problems.append(f"{name}: normal map space {nmap.space}, image {image}")
        return info
    ours = exp[f"normal_map__{name}"]
    h, w = ours.shape[:2]
    info.update(image=bpy.path.abspath(image.filepath), colorspace=image.colorspace_settings.name,
                size=list(image.size), float_buffer=bool(image.is_float), source=image.source)
    if list(image.size) != [w, h]:
        problems.append(f"{name}: image size {list(image.size)}, expected {[w, h]}")
        return info
    px = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(px)
    theirs = px.reshape(h, w, 4)[::-1, :, :3]  # Blender's rows start at the bottom
    info["pixel_max_err"] = float(np.abs(theirs - ours).max())
    if info["pixel_max_err"] > PIXEL_TOL or info["colorspace"] != "Non-Color":
        problems.append(f"{name}: image pixels differ by {info['pixel_max_err']:.3g} "
                        f"(colour space {info['colorspace']})")
    info.update(check_tangents(ob, exp, name, problems))
    return info


def check_tangents(ob, exp, name: str, problems: list[str]) -> dict:
    """Blender's MikkTSpace frame at the first frame against ours, corner by corner."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mesh = ob.evaluated_get(depsgraph).to_mesh()
    mesh.calc_tangents()
    n = len(mesh.loops)
    t, normal, sign = np.empty(n * 3, np.float32), np.empty(n * 3, np.float32), np.empty(n, np.float32)
    mesh.loops.foreach_get("tangent", t)
    mesh.loops.foreach_get("normal", normal)
    mesh.loops.foreach_get("bitangent_sign", sign)
    ob.evaluated_get(depsgraph).to_mesh_clear()
    # what the Normal Map node uses: bitangent = sign * (normal x tangent); in world axes
    b = sign[:, None] * np.cross(normal.reshape(-1, 3), t.reshape(-1, 3))
    rot = np.array(ob.matrix_world, dtype=np.float64)[:3, :3]
    rot /= np.linalg.norm(rot, axis=0, keepdims=True)
    t, b = t.reshape(-1, 3) @ rot.T, b @ rot.T
    ours_t, ours_b = (y_up_to_blender(exp[f"{k}__{name}"].reshape(-1, 3)) for k in ("tangents", "bitangents"))
    cos_t = np.einsum("ij,ij->i", t, ours_t)
    cos_b = np.einsum("ij,ij->i", b, ours_b)
    info = {"tangent_cos_min": float(cos_t.min()), "bitangent_cos_min": float(cos_b.min()),
            "bitangent_signs": sorted({float(s) for s in sign})}
    if min(info["tangent_cos_min"], info["bitangent_cos_min"]) < TANGENT_COS:
        problems.append(f"{name}: Blender's tangent frame differs from ours (cosines "
                        f"{info['tangent_cos_min']:.3f}, {info['bitangent_cos_min']:.3f})")
    return info


def check_mesh(exp, name: str, start: int, end: int, problems: list[str]) -> dict | None:
    """One named mesh: how it is animated, its positions per frame, topology and UVs."""
    ob = bpy.data.objects.get(name)
    if ob is None or ob.type != "MESH":
        problems.append(f"no mesh object {name!r} after import")
        return None
    mat = ob.active_material
    info: dict = {"modifiers": [m.type for m in ob.modifiers],
                  "material": None if mat is None else mat.name}
    if "skinned" in exp and name == str(exp["skinned"]):
        info["skin"] = check_skin(ob, [str(j) for j in exp["joints"]], int(exp["shape_keys"]),
                                  problems)
    elif "MESH_SEQUENCE_CACHE" not in info["modifiers"]:
        problems.append(f"{name}: no Mesh Sequence Cache modifier")
    info.update(check_positions(name, y_up_to_blender(exp[f"points__{name}"]), start, end,
                                problems))
    corner = exp[f"corner_uvs__{name}"] if f"corner_uvs__{name}" in exp else None
    info.update(check_topology(name, exp[f"faces__{name}"], corner))
    if not info["topology_ok"]:
        problems.append(f"{name}: loop topology differs from our faces")
    if corner is not None and (info["uv_max_err"] is None or info["uv_max_err"] > UV_TOL):
        problems.append(f"{name}: UVs differ ({info['uv_max_err']})")
    if f"normal_map__{name}" in exp:
        scene = bpy.context.scene
        scene.frame_set(start)
        info["normal_map"] = check_normal_map(ob, exp, name, problems)
    return info


def main(stage_path: str, expected_path: str) -> int:
    exp = np.load(expected_path)
    names = [str(n) for n in exp["names"]]
    fps, start, end = float(exp["fps"]), int(exp["start"]), int(exp["end"])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    status = bpy.ops.wm.usd_import(filepath=stage_path)
    scene = bpy.context.scene
    res: dict = {
        "blender": bpy.app.version_string,
        "import": sorted(status),
        "objects": sorted(f"{o.name}:{o.type}" for o in bpy.data.objects),
        "frame_range": [scene.frame_start, scene.frame_end],
        "fps_imported": scene.render.fps / scene.render.fps_base,
        "meshes": {},
    }
    problems: list[str] = []
    if res["frame_range"] != [start, end]:
        problems.append(f"frame range {res['frame_range']} != [{start}, {end}]")
    for name in names:
        info = check_mesh(exp, name, start, end, problems)
        if info is not None:
            res["meshes"][name] = info
    # Blender keeps its own fps; set the stage's and make sure time code k stays on frame k.
    scene.render.fps, scene.render.fps_base = round(fps), round(fps) / fps
    res["fps_after_setting"] = scene.render.fps / scene.render.fps_base
    for name in names:
        if name in res["meshes"] and res["meshes"][name]["max_err_per_frame"]:
            k = end
            err = float(np.abs(world_vertices(name, k)
                               - y_up_to_blender(exp[f"points__{name}"][k - start])).max())
            res["meshes"][name]["max_err_after_fps_change"] = err
            if err > TOL:
                problems.append(f"{name}: frame {k} moved after setting fps to {fps}")
    res["problems"] = problems
    print(MARKER, json.dumps(res), flush=True)
    return 1 if problems else 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(main(sys.argv[1], sys.argv[2]))
