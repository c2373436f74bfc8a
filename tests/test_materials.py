"""Material presets and unit conversions."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import WrinklesInputError
from sim.garments.materials import (
    KES_BENDING_TO_NM,
    MATERIALS,
    Material,
    get_material,
    lame_from_youngs,
    youngs_from_lame,
)


def test_plane_stress_lame_exact():
    mu, lam = lame_from_youngs(1300.0, 0.3)
    np.testing.assert_allclose(mu, 1300.0 / 2.6)
    np.testing.assert_allclose(lam, 1300.0 * 0.3 / 0.91)
    E, nu = youngs_from_lame(mu, lam)
    np.testing.assert_allclose([E, nu], [1300.0, 0.3])


def test_from_lame_round_trip():
    m = Material.from_lame("x", mu=500.0, lam=200.0, density=0.1, bending_stiffness=1e-6,
                           damping=0.0, friction=0.3, thickness=3e-4)
    np.testing.assert_allclose([m.lame_mu, m.lame_lambda], [500.0, 200.0])
    assert m.shear_modulus == 500.0


def test_kes_conversion():
    np.testing.assert_allclose(KES_BENDING_TO_NM, 9.80665e-3 * 1e-4 / 1e-2)


def test_presets_physically_ordered():
    d, s, c, j, lt = (MATERIALS[k] for k in ("denim", "silk", "cotton", "jersey_knit", "leather"))
    assert d.density > c.density > s.density
    assert d.bending_stiffness > c.bending_stiffness > s.bending_stiffness
    assert d.youngs_modulus > c.youngs_modulus > j.youngs_modulus
    assert lt.density > d.density and lt.bending_stiffness > d.bending_stiffness
    assert d.thickness > s.thickness
    for m in MATERIALS.values():
        assert m.source and m.shear_modulus <= m.lame_mu * 1.01


def test_get_material_errors():
    assert get_material("silk").name == "silk"
    with pytest.raises(WrinklesInputError, match="unknown material 'wool'.*cotton.*denim"):
        get_material("wool")
    with pytest.raises(WrinklesInputError, match="poisson_ratio"):
        MATERIALS["silk"].with_(poisson_ratio=0.6)
    with pytest.raises(WrinklesInputError, match="unknown field"):
        MATERIALS["silk"].with_(stiffness=1.0)
