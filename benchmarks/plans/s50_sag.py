"""Session 50 scratch: where a fine pants' garment sinks in its prelude (worst_edges --save ...
--keep-prelude). Per band of rest height above / below C and of rest |x|, the mean y displacement
[mm] from frame 0 at frames 29 / 59 (the settle's and the blend's ends)."""
import sys

import numpy as np

d = np.load(sys.argv[1])
x, rest = d["x"], d["rest"]
on = np.flatnonzero(np.abs(rest[:, 0]) < 1e-6)
c = on[np.argmin(rest[on, 1])]
cy = rest[c, 1]
dy = rest[:, 1] - cy
ax = np.abs(rest[:, 0])
for f in (29, 59):
    print(f"frame {f}: C moved {(1000 * (x[f, c] - x[0, c])).round(1)} mm")
    for lo, hi in ((0.02, 0.06), (0.0, 0.02), (-0.02, 0.0), (-0.05, -0.02), (-0.1, -0.05), (-0.2, -0.1)):
        row = []
        for a0, a1 in ((0, 0.002), (0.002, 0.01), (0.01, 0.03), (0.03, 0.08), (0.08, 1)):
            m = (dy >= lo) & (dy < hi) & (ax >= a0) & (ax < a1)
            dy_mm = 1000 * (x[f, m, 1] - x[0, m, 1]).mean() if m.any() else 0.0
            row.append(f"{dy_mm:6.0f} ({m.sum():4d})" if m.any() else " " * 13)
        print(f"  y-C in [{lo:+.2f},{hi:+.2f}): " + " ".join(row))
