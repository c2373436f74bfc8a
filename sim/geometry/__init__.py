"""Surface geometry for datasets and learning.

Green-Lagrange strain, normals and local frames, wrinkle-field encode/decode, base-surface
smoothing, and UV-image rasterisation / sample-back, as Warp kernels (``cpu`` and ``cuda``)
with numpy at the module boundary.
"""
