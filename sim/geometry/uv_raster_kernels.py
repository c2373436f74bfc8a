"""Warp kernels for UV-image rasterisation and sample-back (see ``sim/geometry/uv_raster.py``).

Kernel arguments: inputs first, outputs with an ``_out`` suffix. Positions are in *pixel
space*: x = u·W (columns), y = (1 − v)·H (rows, row 0 at the top), so pixel (row, col) has its
centre at (col + 0.5, row + 0.5). Every kernel writes each output element from one thread and
reads no other thread's output: results are independent of scheduling (byte-identical runs).
"""

from __future__ import annotations

import warp as wp


@wp.func
def cross2(a: wp.vec2, b: wp.vec2) -> float:
    return a[0] * b[1] - a[1] * b[0]


@wp.func
def closest_on_segment(p: wp.vec2, a: wp.vec2, b: wp.vec2) -> float:
    """Parameter t in [0, 1] of the point of segment a-b closest to p."""
    d = b - a
    dd = wp.dot(d, d)
    t = float(0.0)
    if dd > 0.0:
        t = wp.clamp(wp.dot(p - a, d) / dd, 0.0, 1.0)
    return t


@wp.kernel
def coverage_kernel(
    tri: wp.array2d(dtype=wp.vec2),
    tile_start: wp.array(dtype=int),
    tile_faces: wp.array(dtype=int),
    tiles_x: int,
    tile_size: int,
    radius: float,
    inside_eps: float,
    min_weight: float,
    face_out: wp.array2d(dtype=int),
    bary_out: wp.array2d(dtype=wp.vec3),
    covered_out: wp.array2d(dtype=int),
):
    """Covering triangle and barycentrics of each pixel centre; dilation around the charts.

    tri: (F, 3) triangle corners in pixel space; tile_start (tiles + 1) / tile_faces: per tile
    of ``tile_size``² pixels, the triangles (ascending index) whose bounding box, grown by
    ``radius`` px, reaches one of the tile's pixel centres. Outputs (H, W).

    A pixel centre inside a triangle (every barycentric >= -``inside_eps``, a watertight
    tolerance for centres on shared edges) takes the lowest such triangle index and is
    covered. Otherwise the nearest triangle within ``radius`` px (ties: lowest index) gives the
    pixel its barycentrics: extrapolated (the triangle's linear function continued outward)
    when every weight is >= ``min_weight``, else those of the pixel's closest point on the
    triangle (clamped); face -1 when no triangle is that near.
    """
    r, c = wp.tid()
    p = wp.vec2(float(c) + 0.5, float(r) + 0.5)
    tile = (r // tile_size) * tiles_x + c // tile_size
    best = int(-1)
    best_d2 = radius * radius
    best_bary = wp.vec3(0.0, 0.0, 0.0)
    covered = int(0)
    for k in range(tile_start[tile], tile_start[tile + 1]):
        f = tile_faces[k]
        a = tri[f, 0]
        b = tri[f, 1]
        cc = tri[f, 2]
        area = cross2(b - a, cc - a)
        if area == 0.0:
            continue
        l0 = cross2(b - p, cc - p) / area
        l1 = cross2(cc - p, a - p) / area
        l2 = 1.0 - l0 - l1
        if l0 >= -inside_eps and l1 >= -inside_eps and l2 >= -inside_eps:
            best = f
            best_bary = wp.vec3(l0, l1, l2)
            covered = 1
            break  # lists are in ascending order: the first covering triangle is the lowest index
        # outside: closest point on the triangle's boundary (one of its three edges)
        t = closest_on_segment(p, a, b)
        q = a + t * (b - a)
        d2 = wp.length_sq(p - q)
        bary = wp.vec3(1.0 - t, t, 0.0)
        t = closest_on_segment(p, b, cc)
        q = b + t * (cc - b)
        e2 = wp.length_sq(p - q)
        if e2 < d2:
            d2 = e2
            bary = wp.vec3(0.0, 1.0 - t, t)
        t = closest_on_segment(p, cc, a)
        q = cc + t * (a - cc)
        e2 = wp.length_sq(p - q)
        if e2 < d2:
            d2 = e2
            bary = wp.vec3(t, 0.0, 1.0 - t)
        if d2 < best_d2 or (best < 0 and d2 == best_d2):
            best = f
            best_d2 = d2
            best_bary = bary
            if l0 >= min_weight and l1 >= min_weight and l2 >= min_weight:
                best_bary = wp.vec3(l0, l1, l2)
    face_out[r, c] = best
    bary_out[r, c] = best_bary
    covered_out[r, c] = covered


@wp.kernel
def interpolate_kernel(
    values: wp.array3d(dtype=float),
    corners: wp.array2d(dtype=int),
    pixel: wp.array(dtype=int),
    face: wp.array(dtype=int),
    bary: wp.array(dtype=wp.vec3),
    image_out: wp.array3d(dtype=float),
):
    """Barycentric interpolation of per-UV-vertex values into the listed pixels.

    values (T, U, C); corners = uv_faces (F, 3); pixel / face / bary (P,): flat pixel index
    (row·W + col), its triangle and barycentrics. image_out (T, H·W, C); unlisted pixels are
    left as they are.
    """
    t, k = wp.tid()
    f = face[k]
    w = bary[k]
    i0 = corners[f, 0]
    i1 = corners[f, 1]
    i2 = corners[f, 2]
    px = pixel[k]
    for ch in range(values.shape[2]):
        image_out[t, px, ch] = w[0] * values[t, i0, ch] + w[1] * values[t, i1, ch] + w[2] * values[t, i2, ch]


@wp.kernel
def face_constant_kernel(
    values: wp.array3d(dtype=float),
    pixel: wp.array(dtype=int),
    face: wp.array(dtype=int),
    image_out: wp.array3d(dtype=float),
):
    """Per-face values (T, F, C) copied into the listed pixels of image_out (T, H·W, C)."""
    t, k = wp.tid()
    f = face[k]
    px = pixel[k]
    for ch in range(values.shape[2]):
        image_out[t, px, ch] = values[t, f, ch]


@wp.kernel
def bilinear_sample_kernel(
    images: wp.array3d(dtype=float),
    height: int,
    width: int,
    points: wp.array(dtype=wp.vec2),
    point_chart: wp.array(dtype=int),
    pixel_chart: wp.array(dtype=int),
    values_out: wp.array3d(dtype=float),
):
    """Bilinear sample of images (T, H·W, C) at pixel-space points (N,) -> values_out (T, N, C).

    Taps outside the image are clamped to the border. Only taps whose pixel belongs to the
    point's chart (``pixel_chart`` (H·W,), -1 = empty; ``point_chart`` (N,)) take part, with the
    bilinear weights renormalised over them, so nothing bleeds in from empty pixels or another
    panel; a point with no such tap takes plain bilinear weights.
    """
    t, i = wp.tid()
    p = points[i]
    x = p[0] - 0.5
    y = p[1] - 0.5
    x0f = wp.floor(x)
    y0f = wp.floor(y)
    fx = x - x0f
    fy = y - y0f
    x0 = int(x0f)
    y0 = int(y0f)
    c0 = wp.clamp(x0, 0, width - 1)
    c1 = wp.clamp(x0 + 1, 0, width - 1)
    r0 = wp.clamp(y0, 0, height - 1)
    r1 = wp.clamp(y0 + 1, 0, height - 1)
    k00 = r0 * width + c0
    k01 = r0 * width + c1
    k10 = r1 * width + c0
    k11 = r1 * width + c1
    w00 = (1.0 - fx) * (1.0 - fy)
    w01 = fx * (1.0 - fy)
    w10 = (1.0 - fx) * fy
    w11 = fx * fy
    ch_i = point_chart[i]
    m00 = float(0.0)
    m01 = float(0.0)
    m10 = float(0.0)
    m11 = float(0.0)
    if pixel_chart[k00] == ch_i:
        m00 = w00
    if pixel_chart[k01] == ch_i:
        m01 = w01
    if pixel_chart[k10] == ch_i:
        m10 = w10
    if pixel_chart[k11] == ch_i:
        m11 = w11
    s = m00 + m01 + m10 + m11
    if s > 0.0:
        m00 = m00 / s
        m01 = m01 / s
        m10 = m10 / s
        m11 = m11 / s
    else:
        m00 = w00
        m01 = w01
        m10 = w10
        m11 = w11
    for ch in range(images.shape[2]):
        values_out[t, i, ch] = (m00 * images[t, k00, ch] + m01 * images[t, k01, ch]
                                + m10 * images[t, k10, ch] + m11 * images[t, k11, ch])


@wp.kernel
def average_copies_kernel(
    values: wp.array3d(dtype=float),
    copy_start: wp.array(dtype=int),
    copies: wp.array(dtype=int),
    average_out: wp.array3d(dtype=float),
):
    """Mean of each 3D vertex's UV copies: values (T, U, C), CSR copy_start (V + 1) / copies
    (UV vertex indices, ascending) -> average_out (T, V, C); 0 for a vertex with no copy."""
    t, v = wp.tid()
    k0 = copy_start[v]
    k1 = copy_start[v + 1]
    inv = float(0.0)
    if k1 > k0:
        inv = 1.0 / float(k1 - k0)
    for ch in range(values.shape[2]):
        s = float(0.0)
        for k in range(k0, k1):
            s += values[t, copies[k], ch]
        average_out[t, v, ch] = s * inv
