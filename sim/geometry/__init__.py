"""Surface geometry for datasets and learning (DESIGN.md, Layout: ``sim/`` geometry).

Green-Lagrange strain, normals and local frames, wrinkle-field encode/decode, base-surface
smoothing, and UV-image rasterisation / sample-back, as Warp kernels (``cpu`` and ``cuda``)
with numpy at the module boundary.
"""
