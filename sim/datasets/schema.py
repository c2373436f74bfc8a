"""What a dataset sequence file gives (schema version 2; see ``sim.datasets.storage``).

A file *stores* what only the simulation gives: positions (quantized, below), the rest
garments, the body's motion and the quality record. Every other field of the tables below is
*derived* from those by the reader on first use and kept in a cache of derived fields
(``sim.datasets.fields``: ``DIR/derived/<id>.safetensors``, ``wrinkles dataset derive``);
``SequenceFile[name]`` reads stored, quantized and derived names alike. Version 1 files, which
store every field as such, read the same.

Positions ``NAME`` (``fine/vertices``, ``coarse/vertices``) are stored as float32, or, with
``[derive] positions = "i16"``, as three arrays (``sim.datasets.quantize``): ``NAME_q``
(T, V, 3) i16, ``NAME_origin`` (T, 3) f32 and ``NAME_step`` (T,) f32, with
``NAME = NAME_origin[:, None, :] + NAME_step[:, None, None] * NAME_q`` (error at most step / 2:
~9 µm on a garment 1.2 m across). The metadata entry ``data_sha256`` is the sha256 of the
arrays' bytes (the file after its header); ``derive`` is the JSON of the derivation's settings
(``DeriveConfig``: smoothing length, image resolution).

Stored: ``fine/vertices``, ``fine/rest_vertices``, ``fine/faces``, ``fine/uvs``,
``fine/uv_faces``, ``fine/face_layers``, ``coarse/vertices``, ``coarse/rest_vertices``,
``coarse/faces``, ``coarse/uvs``, ``coarse/uv_faces``, ``body/*``, ``quality/*``. Derived: the
rest (``sim.datasets.fields.DERIVED_KEYS``).

T frames; the fine garment has V vertices, F faces, U UV vertices; the coarse garment Vc, Fc,
Uc; images are H x W. Units SI, Y up, arrays little-endian.

Fine garment (the wrinkles; Guo et al. 2024, Sec. 3.1):

=========================  =================  =====  ==============================================
name                       shape              dtype  meaning
=========================  =================  =====  ==============================================
fine/vertices              (T, V, 3)          f32    simulated positions [m]
fine/base                  (T, V, 3)          f32    base surface: fine smoothed (wrinkles removed)
fine/wrinkle               (T, U, 3)          f32    fine - base in the base's local frame (Eq. 2),
                                                     per UV vertex [m]: w1, w2 along the tangents
                                                     d base / d u1, d u2 with u in metres of the
                                                     rest pattern (|t| = 1 + stretch), w3 along
                                                     the unit normal
fine/strain                (T, F, 3)          f32    Green-Lagrange strain of the base against the
                                                     rest garment, (E11, E22, E12) (Eq. 3) [-]
fine/strain_norm           (T, F)             f32    its Frobenius norm [-]
fine/normals               (T, V, 3)          f32    unit vertex normals of the fine surface
fine/rest_vertices         (V, 3)             f32    rest garment on the rest body [m]
fine/faces                 (F, 3)             i32
fine/uvs                   (U, 2)             f32    in [0, 1]^2, split along seams
fine/uv_faces              (F, 3)             i32
fine/face_layers           (F,)               f32    layers of fabric per face, >= 1 (a template's
                                                     hems: 3; ``Garment.face_layers``); a file
                                                     without it reads as 1 layer everywhere
=========================  =================  =====  ==============================================

UV images of the fine garment (pixel (row, col) centred at u = (col + .5) / W,
v = 1 - (row + .5) / H; row 0 is the top; ``sim.geometry.uv_raster``), present unless the
config turns images off:

=========================  =================  =====  ==============================================
images/strain_norm         (T, H, W, 1)       f16    base strain norm (per-vertex average)
images/wrinkle             (T, H, W, 3)       f16    wrinkle field [m]
images/normal_world        (T, H, W, 3)       f16    fine unit normals, world frame
images/normal_tangent      (T, H, W, 3)       f16    fine unit normals in the base's orthonormal
                                                     tangent frame (t1, n x t1, n)
images/mask                (H, W)             u8     1 where a UV triangle covers the pixel
=========================  =================  =====  ==============================================

Coarse garment (same body and motion, coarse resolution; for coarse-model training):

=========================  =================  =====  ==============================================
coarse/vertices            (T, Vc, 3)         f32    simulated positions [m]
coarse/strain_norm         (T, Fc)            f32    Green-Lagrange strain norm against its rest
coarse/rest_vertices       (Vc, 3)            f32
coarse/faces               (Fc, 3)            i32
coarse/uvs, coarse/uv_faces                          as for the fine garment
=========================  =================  =====  ==============================================

Body and quality:

=========================  =================  =====  ==============================================
body/poses                 (T, 24, 3)         f32    SMPL axis-angle poses
body/trans                 (T, 3)             f32    root translation [m] (as simulated: on the floor)
body/joints                (T, 24, 3)         f32    joint positions [m]
body/betas                 (B,)               f32    shape
quality/edge_strain_max    (T,)               f32    max |l/l0 - 1| of the fine garment per frame
quality/inside_fraction    (T,)               f32    fine vertices inside the body per frame
quality/self_intersections (T,)               i32    fine edge-triangle crossings per frame
=========================  =================  =====  ==============================================

Metadata (JSON strings): ``sequence`` (id, index, split, seed, garment category and
parameters, material, motion name and parameters or file, shape), ``provenance`` (generator
config, simulation config, solver settings, package versions, device), ``body`` (body model
name, faces are not stored: the body is re-posed from ``body/*`` with that model).
"""

from __future__ import annotations

SPLITS = ("train", "test_id", "test_ood")

FINE_KEYS = ("fine/vertices", "fine/base", "fine/wrinkle", "fine/strain", "fine/strain_norm", "fine/normals",
             "fine/rest_vertices", "fine/faces", "fine/uvs", "fine/uv_faces", "fine/face_layers")
IMAGE_KEYS = ("images/strain_norm", "images/wrinkle", "images/normal_world", "images/normal_tangent",
              "images/mask")
COARSE_KEYS = ("coarse/vertices", "coarse/strain_norm", "coarse/rest_vertices", "coarse/faces", "coarse/uvs",
               "coarse/uv_faces")
BODY_KEYS = ("body/poses", "body/trans", "body/joints", "body/betas")
QUALITY_KEYS = ("quality/edge_strain_max", "quality/inside_fraction", "quality/self_intersections")
PER_FRAME_KEYS = ("fine/vertices", "fine/base", "fine/wrinkle", "fine/strain", "fine/strain_norm",
                  "fine/normals",
                  "images/strain_norm", "images/wrinkle", "images/normal_world", "images/normal_tangent",
                  "coarse/vertices", "coarse/strain_norm", "body/poses", "body/trans", "body/joints",
                  *QUALITY_KEYS)
"""Arrays whose first axis is the frame (windows slice these)."""
