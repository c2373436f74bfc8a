"""The per-frame screen of a batch (``sim.simulate.screening.BatchScreen``) on the device
against the same tests in numpy: a non-finite, too distant, too fast vertex or a too long edge
flags its own instance and no other."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from sim.cloth import ClothModelBuilder
from sim.garments.materials import get_material
from sim.quality import unique_edges
from sim.simulate import SimulationConfig
from sim.simulate.screening import BatchScreen
from tests.test_quality import grid


def numpy_flags(x, x_prev, roots, inst, edges, rest, cfg) -> np.ndarray:
    """The screen's tests on the host."""
    with np.errstate(invalid="ignore", over="ignore"):
        bad = ~np.isfinite(x).all(axis=1)
        bad |= ~(np.linalg.norm(x - roots[inst], axis=1) <= cfg.max_distance)
        bad |= ~(np.linalg.norm(x - x_prev, axis=1) * cfg.fps <= cfg.max_speed)
        ratio = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1) / rest
    flags = np.zeros(roots.shape[0], bool)
    flags[inst[bad]] = True
    flags[inst[edges[~(ratio <= cfg.max_stretch), 0]]] = True
    return flags


def batch(device):
    """A model of six sheets (the screen reads its particle -> instance map and mesh edges), their
    checkers' rest lengths, the sheets' positions and spans."""
    v, f = grid(6, 0.3)
    e = unique_edges(f)
    rest = np.linalg.norm(v[e[:, 1]] - v[e[:, 0]], axis=1)
    n, count = len(v), 6
    builder = ClothModelBuilder()
    for _ in range(count):
        builder.add_cloth(v, f, get_material("cotton"))
    model = builder.finalize(device)
    tracks = [SimpleNamespace(span=model.instance_slice(k)) for k in range(count)]
    checkers = [SimpleNamespace(rest_len=rest) for _ in range(count)]
    x0 = np.concatenate([v + [0.0, 1.0, 0.0]] * count).astype(np.float32)
    return model, tracks, checkers, x0, n, e, rest


def test_each_fault_flags_its_own_instance(device):
    from sim.device import warp

    wp = warp()
    model, tracks, checkers, x0, n, e, rest = batch(device)
    cfg = SimulationConfig()
    screen = BatchScreen(model, checkers, cfg)
    roots = np.zeros((len(tracks), 3), np.float32)
    x = x0 + 0.01  # every vertex moves 1.7 cm in a frame: 0.5 m/s
    x[1 * n + 3, 1] = np.nan                               # 1: not finite
    x[2 * n + 7] += [0.0, 5.0, 0.0]                        # 2: 6 m from its root (and fast)
    x[3 * n:4 * n] = x0[3 * n:4 * n] + [0.0, 0.0, 1.9]     # 3: all at 57 m/s, too fast
    a, b = 4 * n + e[5]
    x[b] = x[a] + 3.5 * (x0[b] - x0[a])                   # 4: one edge 3.5x its rest length
    live = wp.array(x0, dtype=wp.vec3, device=device)
    screen.remember(live)
    live.assign(x)
    got = screen(live, roots)
    inst = np.repeat(np.arange(len(tracks)), n)
    edges = np.concatenate([e + t.span.start for t in tracks])
    want = numpy_flags(x, x0, roots, inst, edges, np.tile(rest, len(tracks)), cfg)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got, [False, True, True, True, True, False])
    # the next frame: positions remembered, nothing moved, nothing flagged but the NaN, the far vertex
    # and the stretched edge
    screen.remember(live)
    np.testing.assert_array_equal(screen(live, roots), [False, True, True, False, True, False])
