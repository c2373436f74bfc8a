"""Per-frame tangent-space normal maps of a garment: PNG images and the UsdPreviewSurface network
that applies them.

Images. A map is (H, W, 3) unit vectors in the tangent frame of the surface they shade, zero
vectors outside the UV charts (``learn.deepwrinkles.normal_maps``). It is stored as
RGB = n * 0.5 + 0.5 in a 16-bit (default) or 8-bit PNG, written here with numpy and zlib (no
image library needed; Pillow cannot write 16-bit colour PNGs). Texels outside the charts take
the normal of the nearest chart texel, so bilinear filtering and mip-mapping at a chart's border
never mix in a non-normal (a zero vector would encode as mid-grey and darken the seams); an
image without any chart is flat, (0, 0, 1). Decoding, RGB * 2 - 1, returns the map within
1 / (2^bits - 1) per component inside the charts.

Material. The garment's ``UsdPreviewSurface`` gets its ``normal`` input from a ``UsdUVTexture``
(``inputs:file`` the image, ``sourceColorSpace = "raw"``, ``scale = (2, 2, 2, 1)``,
``bias = (-1, -1, -1, 0)``: the decode above, ``wrapS = wrapT = "clamp"``) whose ``st`` comes
from a ``UsdPrimvarReader_float2`` reading the mesh's ``primvars:st``. ``inputs:file`` holds one
image per time code (frame k at ``start_time_code + k``) and, as its default value, the first
frame's: applications that read textures without time (Blender's importer) get a still
image.

Tangent-frame convention. Our frame at a texel is (t1, n x t1, n): t1 the surface's UV
u-direction dP/du made orthogonal to the unit normal n (``sim.geometry.frames.tangent_basis``).
That is the construction of MikkTSpace, which Blender's Normal Map node and most real-time
renderers use: tangent = dP/du orthogonalised against n, bitangent = sign * (n x tangent), where
sign = +1 when dP/du x dP/dv points along n, i.e. when a triangle's UVs wind counter-clockwise
like its vertices. Every garment template's UV layout does (all panels unmirrored), so
n x t1 points along +v and the green channel is +v: the OpenGL convention ("Y+") that Blender
and UsdPreviewSurface expect, no channel flip. Rows: our UV rasters put row 0 at the top,
v = 1 - (row + 0.5) / H (``sim.geometry.uv_raster``), and PNG row 0 is the top of the image,
while texture coordinates put v = 0 at the bottom (USD, Blender): the rows are written in order,
no vertical flip. A garment whose UV layout is mirrored (clockwise UV triangles) would have its
green channel read inverted there by MikkTSpace renderers.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdShade

from sim.errors import WrinklesInputError

#: bit depths a normal map is written with.
NORMAL_MAP_BITS = (8, 16)
#: suffix of the folder beside a stage that holds its normal maps: ``<stem>_normals``.
NORMALS_FOLDER_SUFFIX = "_normals"
#: primvar the texture's st reader reads (``usd_io.write`` authors the UVs under this name).
UV_PRIMVAR = "st"
#: largest accepted |n| of a normal-map texel (unit vectors, rounding allowed).
MAX_NORM = 1.01
#: zlib level of the PNGs (zlib's default): a 256 x 256 16-bit map is filtered and compressed in
#: ~50 ms on one CPU core.
PNG_LEVEL = 6

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_COLOR_TYPES = {1: 0, 2: 4, 3: 2, 4: 6}  # channels -> PNG colour type (grey, grey+alpha, RGB, RGBA)


# ----------------------------------------------------------------------------- checks


def check_normal_maps(maps: np.ndarray, n_frames: int, what: str) -> np.ndarray:
    """``maps`` as a floating (T, H, W, 3) array of unit (or zero) vectors, T = ``n_frames``.

    Raises:
        WrinklesInputError: another shape, non-finite values or vectors longer than ``MAX_NORM``,
            one line naming ``what``.
    """
    a = np.asarray(maps)
    if a.dtype.kind != "f":
        a = a.astype(np.float32)
    if a.ndim != 4 or a.shape[-1] != 3 or a.shape[0] != n_frames or min(a.shape[1:3]) < 1:
        raise WrinklesInputError(f"{what} normal_maps must have shape ({n_frames}, H, W, 3) (one map per "
                                 f"frame), got {a.shape}")
    for k, frame in enumerate(a):
        if not np.isfinite(frame).all():
            raise WrinklesInputError(f"{what} normal_maps have NaN/inf values at frame {k}")
        if np.einsum("hwc,hwc->hw", frame, frame).max() > MAX_NORM**2:
            raise WrinklesInputError(f"{what} normal_maps must hold unit vectors (0 outside the UV "
                                     f"charts); frame {k} has longer ones")
    return a


def check_bits(bits: int) -> int:
    if bits not in NORMAL_MAP_BITS:
        raise WrinklesInputError(f"normal-map bit depth must be one of {NORMAL_MAP_BITS}, got {bits!r}")
    return int(bits)


# ----------------------------------------------------------------------------- encoding


def fill_outside_charts(normals: np.ndarray) -> np.ndarray:
    """One map (H, W, 3) with its zero texels (outside the charts) set to the nearest chart
    texel's normal; an all-zero map becomes flat (0, 0, 1)."""
    from scipy.ndimage import distance_transform_edt

    n = np.asarray(normals, np.float32)
    inside = np.einsum("hwc,hwc->hw", n, n) > 0.25  # unit vectors inside, zeros outside
    if inside.all():
        return n
    if not inside.any():
        return np.broadcast_to(np.float32([0.0, 0.0, 1.0]), n.shape).copy()
    rows, cols = distance_transform_edt(~inside, return_distances=False, return_indices=True)
    return n[rows, cols]


def encode_normal_map(normals: np.ndarray, bits: int = 16) -> np.ndarray:
    """PNG pixels (H, W, 3), uint8 or uint16, of one map: RGB = n * 0.5 + 0.5 after
    ``fill_outside_charts``."""
    top = (1 << check_bits(bits)) - 1
    rgb = np.clip(fill_outside_charts(normals) * 0.5 + 0.5, 0.0, 1.0)
    return np.rint(rgb * top).astype(np.uint16 if bits == 16 else np.uint8)


def decode_normal_map(pixels: np.ndarray) -> np.ndarray:
    """The inverse of ``encode_normal_map``, as UsdUVTexture's scale and bias apply it:
    RGB / (2^bits - 1) * 2 - 1, float32 (H, W, 3)."""
    p = np.asarray(pixels)
    top = 65535.0 if p.dtype == np.uint16 else 255.0
    return (p[..., :3].astype(np.float64) / top * 2.0 - 1.0).astype(np.float32)


# ----------------------------------------------------------------------------- PNG


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _paeth(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """PNG's Paeth predictor of left ``a``, up ``b`` and up-left ``c`` (int arrays)."""
    p = a + b - c
    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
    return np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))


def _filtered(raw: np.ndarray, bpp: int) -> np.ndarray:
    """Rows (H, 1 + row bytes) each filtered with the PNG filter (None, Sub, Up, Average, Paeth)
    whose bytes, read as signed, sum smallest in magnitude (the PNG specification's heuristic)."""
    x = raw.astype(np.int16)
    left = np.zeros_like(x)
    left[:, bpp:] = x[:, :-bpp]
    up = np.zeros_like(x)
    up[1:] = x[:-1]
    upleft = np.zeros_like(x)
    upleft[1:, bpp:] = x[:-1, :-bpp]
    options = np.stack([x, x - left, x - up, x - (left + up) // 2, x - _paeth(left, up, upleft)])
    options = (options & 0xFF).astype(np.uint8)
    cost = np.abs(options.view(np.int8).astype(np.int32)).sum(axis=2)
    best = cost.argmin(axis=0)
    rows = options[best, np.arange(len(x))]
    return np.concatenate([best.astype(np.uint8)[:, None], rows], axis=1)


def png_bytes(pixels: np.ndarray, *, level: int = PNG_LEVEL) -> bytes:
    """A PNG file of ``pixels`` (H, W) or (H, W, C), C in 1-4 (grey, grey + alpha, RGB, RGBA),
    uint8 or uint16 (big-endian 16-bit samples); row 0 is the top of the image."""
    p = np.asarray(pixels)
    if p.ndim == 2:
        p = p[..., None]
    if p.ndim != 3 or p.shape[2] not in _COLOR_TYPES or min(p.shape[:2]) < 1:
        raise ValueError(f"PNG pixels must have shape (H, W) or (H, W, 1-4), got {p.shape}")
    if p.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG pixels must be uint8 or uint16, got {p.dtype}")
    h, w, c = p.shape
    depth = 8 * p.dtype.itemsize
    raw = np.ascontiguousarray(p.astype(p.dtype.newbyteorder(">"))).view(np.uint8).reshape(h, -1)
    header = struct.pack(">IIBBBBB", w, h, depth, _COLOR_TYPES[c], 0, 0, 0)
    data = zlib.compress(_filtered(raw, c * p.dtype.itemsize).tobytes(), level)
    return _PNG_SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", data) + _chunk(b"IEND", b"")


def write_png(path: str | Path, pixels: np.ndarray) -> Path:
    """Write ``png_bytes(pixels)`` to ``path``."""
    path = Path(path)
    path.write_bytes(png_bytes(pixels))
    return path


def _unfilter(kind: int, row: np.ndarray, prev: np.ndarray, bpp: int) -> np.ndarray:
    """One PNG row's bytes from its filtered bytes ``row`` and the previous decoded row."""
    if kind == 0:
        return row
    if kind == 2:
        return row + prev
    if kind == 1:  # each byte adds the one bpp before it: a running sum per byte position
        n = len(row)
        padded = np.zeros(-(-n // bpp) * bpp, np.uint64)
        padded[:n] = row
        return (np.cumsum(padded.reshape(-1, bpp), axis=0).reshape(-1)[:n] & 0xFF).astype(np.uint8)
    out = row.astype(np.int32)
    up = prev.astype(np.int32)
    if kind not in (3, 4):
        raise ValueError(f"unknown PNG filter type {kind}")
    for i in range(0, len(out), bpp):  # Average and Paeth read the decoded byte to the left
        a = out[i - bpp:i] if i else np.zeros(bpp, np.int32)
        b = up[i:i + bpp]
        c = up[i - bpp:i] if i else np.zeros(bpp, np.int32)
        pred = (a + b) // 2 if kind == 3 else _paeth(a, b, c)
        out[i:i + bpp] = (out[i:i + bpp] + pred) & 0xFF
    return out.astype(np.uint8)


def read_png(path: str | Path) -> np.ndarray:
    """Pixels (H, W, C) of a non-interlaced 8- or 16-bit grey / grey + alpha / RGB / RGBA PNG,
    uint8 or uint16, row 0 the top of the image (what ``write_png`` writes, and most PNGs).

    Raises:
        WrinklesInputError: not such a PNG (names the file).
    """
    path = Path(path)
    data = path.read_bytes()
    if not data.startswith(_PNG_SIGNATURE):
        raise WrinklesInputError("not a PNG file", path=path)
    pos, header, idat = len(_PNG_SIGNATURE), None, []
    while pos + 8 <= len(data):
        (n,), kind = struct.unpack(">I", data[pos:pos + 4]), data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + n]
        pos += 12 + n
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    channels = {v: k for k, v in _COLOR_TYPES.items()}
    if header is None or header[2] not in (8, 16) or header[3] not in channels or header[6] != 0:
        raise WrinklesInputError(f"unsupported PNG (header {header}): this reader takes 8- or 16-bit "
                                 "grey/RGB(A), not interlaced", path=path)
    w, h, depth, color = header[:4]
    size = depth // 8
    bpp = channels[color] * size
    try:
        stream = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8).reshape(h, 1 + w * bpp)
    except (zlib.error, ValueError):
        raise WrinklesInputError("corrupt PNG image data", path=path) from None
    rows = np.zeros((h, w * bpp), np.uint8)
    prev = np.zeros(w * bpp, np.uint8)
    for r in range(h):
        prev = rows[r] = _unfilter(int(stream[r, 0]), stream[r, 1:], prev, bpp)
    dtype = np.dtype(">u2") if size == 2 else np.dtype(np.uint8)
    return rows.view(dtype).reshape(h, w, channels[color]).astype(dtype.newbyteorder("="))


# ----------------------------------------------------------------------------- USD


def normal_map_files(folder: str, name: str, n_frames: int) -> list[str]:
    """Asset paths of a garment's per-frame maps, relative to the stage:
    ``./<folder>/<name>_0000.png`` ..."""
    return [f"./{folder}/{name}_{k:04d}.png" for k in range(n_frames)]


def define_normal_texture(stage: Usd.Stage, material: UsdShade.Material, surface: UsdShade.Shader,
                          first_file: str) -> Usd.Attribute:
    """The ``UsdUVTexture`` (and its st reader) feeding ``surface``'s ``normal`` input, under
    ``material`` (module docstring); returns its ``inputs:file`` attribute, whose default is
    ``first_file`` and to which the caller adds one time sample per frame."""
    root = material.GetPath()
    reader = UsdShade.Shader.Define(stage, root.AppendChild("NormalUVReader"))
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set(UV_PRIMVAR)
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, root.AppendChild("NormalTexture"))
    tex.CreateIdAttr("UsdUVTexture")
    file_input = tex.CreateInput("file", Sdf.ValueTypeNames.Asset)
    file_input.Set(Sdf.AssetPath(first_file))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2.0, 2.0, 2.0, 1.0))
    tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1.0, -1.0, -1.0, 0.0))
    for wrap in ("wrapS", "wrapT"):
        tex.CreateInput(wrap, Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surface.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    return file_input.GetAttr()


def normal_texture_files(stage: Usd.Stage, material_path: str) -> Sequence[tuple[float, str]] | None:
    """(time code, resolved image path) of every time sample of a material's normal texture
    (``define_normal_texture``), or None when the material has none."""
    surface = UsdShade.Shader.Get(stage, f"{material_path}/PreviewSurface")
    normal = surface.GetInput("normal") if surface else None
    if not normal or not normal.HasConnectedSource():
        return None
    source = normal.GetConnectedSources()[0][0].source
    attr = UsdShade.Shader(source.GetPrim()).GetInput("file").GetAttr()
    return [(t, attr.Get(t).resolvedPath) for t in attr.GetTimeSamples()]
