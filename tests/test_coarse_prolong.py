"""The coarse correction's prolongation (``transfer_kernels.prolong_kernel``) limits the move of
each particle of a garment on a body: off the body to half the contact margin's room, on it to
the whole room and no deeper into it than the thickness shell; without a body it is ``P dx``."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cloth import ClothMaterialParams, ClothModelBuilder
from sim.cloth.coarse.transfer_kernels import prolong_kernel
from sim.cloth.config import BodyContact
from sim.device import warp
from tests.conftest import DEVICES
from tests.test_cloth_solver import grid
from tests.test_coarse import coarse_level


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("body", [True, False])
def test_a_large_coarse_move_is_limited_by_the_contact_margins_room(device, body):
    from sim.cloth.self_contact import disabled_data

    wp = warp()
    v, f = grid(9, 9, 0.2, 0.2)
    b = ClothModelBuilder()
    b.add_cloth(v, f, ClothMaterialParams(), pinned=np.arange(0))
    m = b.finalize(device)
    level, arrays = coarse_level(m, spacing=2)
    n = m.particle_count
    x = np.asarray(v, np.float32)
    thickness = float(m.instance_thickness.numpy()[0])
    margin = BodyContact().margin
    # every other particle on the body (a plane under it along +z, 1 mm below), the rest off it;
    # without a body none has a contact
    active = (np.arange(n) % 2).astype(np.int32) * int(body)
    arrays["point"].assign(x - np.array([0.0, 0.0, 0.001], np.float32))
    arrays["normal"].assign(np.tile(np.array([0.0, 0.0, 1.0], np.float32), (n, 1)))
    arrays["active"].assign(active)
    move = np.array([0.08, 0.0, -0.06])  # 10 cm, partly into the body
    level.dx.assign(np.tile(move, (level.dx.shape[0], 1)).astype(np.float32))
    xw = wp.array(x, dtype=wp.vec3, device=device)
    snap = wp.zeros_like(xw)
    bodies = wp.array([1 if body else 0], dtype=wp.uint64, device=device)
    point, normal, act = level._contact
    wp.launch(prolong_kernel, dim=n, inputs=[level.dx, *level._p, point, normal, act, m.particle_flags,
                                              m.particle_instance, m.instance_thickness, bodies, margin,
                                              disabled_data(device)], outputs=[xw, snap], device=device)
    d = xw.numpy() - x
    np.testing.assert_array_equal(xw.numpy(), snap.numpy())
    if not body:  # the rows of P sum to one: a uniform coarse move moves every particle by it
        np.testing.assert_allclose(d, np.tile(move, (n, 1)), atol=1e-6)
        return
    room = margin - thickness
    off, on = active == 0, active == 1
    np.testing.assert_allclose(np.linalg.norm(d[off], axis=1), 0.5 * room, rtol=1e-5)
    # on the body: the move along the plane and into it scaled to the room, then lifted back to the
    # thickness shell's floor (the particle is 1 mm off the plane, over the 0.3 mm shell)
    scaled = move * room / np.linalg.norm(move)
    floor = min(0.001, thickness) - 0.001
    np.testing.assert_allclose(d[on][:, 0], scaled[0], rtol=1e-5)
    np.testing.assert_allclose(d[on][:, 2], max(scaled[2], floor), atol=1e-6)
