"""tools/render_closeups.py: close-ups of bench_garments' frames files, cropped to a band of the
body's height; bad files and frames refused in one line, exit 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "render_closeups.py"


def box(lo, hi):
    """A closed box mesh: 8 corners, 12 triangles wound outward."""
    lo, hi = np.asarray(lo, np.float32), np.asarray(hi, np.float32)
    corners = [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    v = np.array(corners, np.float32)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int32)
    return v, f


def tube(radius: float, y0: float, y1: float, rings: int = 26, around: int = 24):
    """An open tube around the Y axis: (V, 3) vertices, (F, 3) faces wound outward."""
    a = np.linspace(0, 2 * np.pi, around, endpoint=False)
    y = np.linspace(y0, y1, rings)
    v = np.stack([np.repeat(radius * np.sin(a)[None], rings, 0), np.repeat(y[:, None], around, 1),
                  np.repeat(radius * np.cos(a)[None], rings, 0)], axis=2).reshape(-1, 3).astype(np.float32)
    f = []
    for r in range(rings - 1):
        for k in range(around):
            i, j = r * around + k, r * around + (k + 1) % around
            f += [[i, j, j + around], [i, j + around, i + around]]
    return v, np.array(f, np.int32)


def frames_file(path: Path) -> Path:
    body, bf = box((-0.2, 0.0, -0.1), (0.2, 1.8, 0.1))
    shirt, gf = tube(0.25, 1.0, 1.5)
    panels = (np.arange(len(gf)) % 48 >= 24).astype(np.int32)  # front and back halves
    np.savez(path, garment=np.stack([shirt, shirt + 0.01]), body=np.stack([body, body]), garment_faces=gf,
             body_faces=bf, panel_ids=panels, frames=np.array([0, 7], np.int32))
    return path


def run(*args):
    return subprocess.run([sys.executable, str(TOOL), *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT)


@pytest.mark.parametrize("make, args, message", [
    (lambda p: p.write_text("no arrays"), [], "not a frames file of bench_garments --frames-out"),
    (frames_file, ["--frame", "3"], "frame 3 is not stored (stored: [0, 7])"),
])
def test_refuses_a_bad_file_or_frame(tmp_path, make, args, message):
    src = tmp_path / "f.npz"
    make(src)
    proc = run(f"{src}:torso", *args, "--out", tmp_path / "out.png")
    assert proc.returncode == 2 and not (tmp_path / "out.png").exists()
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and str(src) in lines[0] and message in lines[0]


def test_refuses_an_unknown_region(tmp_path):
    proc = run(f"{frames_file(tmp_path / 'f.npz')}:elbows", "--out", tmp_path / "out.png")
    assert proc.returncode == 2 and "unknown region 'elbows'" in proc.stderr


def test_region_crop_is_the_garment_band(tmp_path):
    """A band narrower than the garment gives a wider-than-tall crop of the same garment; the
    whole body's picture is taller (its garment and body band span more height)."""
    sys.path.insert(0, str(TOOL.parent))
    from render_closeups import closeup, read_frames

    data, k = read_frames(frames_file(tmp_path / "f.npz"), 7)
    assert k == 1
    band = closeup(data, k, "shoulders", size=(400, 400), height=100)
    whole = closeup(data, k, "all", size=(400, 400), height=100)
    assert [im.height for im in band + whole] == [100] * 4
    assert all(b.width > w.width for b, w in zip(band, whole, strict=True))
    # the shoulders band holds garment colour, not only the body's grey
    px = np.asarray(band[0].convert("RGB"), np.float32).reshape(-1, 3)
    assert (np.abs(px - 255 * np.array([0.36, 0.55, 0.80])).max(axis=1) < 60).mean() > 0.05
