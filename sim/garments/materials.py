"""Cloth materials in SI units, with named presets and their sources.

Cloth is a thin shell, so every stiffness here is *per unit width* (membrane) or per unit
width and curvature (bending): stretch and shear moduli in N/m, bending stiffness in N·m
(= N·m²/m). Conversions used for the presets:

- Kawabata (KES-FB) bending rigidity B [gf·cm²/cm] → N·m: × 9.80665e-5.
- KES shear rigidity G [gf/(cm·deg)] → N/m per radian: × 0.980665 × 180/π = × 56.19.
- Plane-stress Lamé parameters of a 2D isotropic sheet from Young's modulus E [N/m] and
  Poisson ratio ν: μ = E / (2 (1 + ν)), λ = E ν / (1 − ν²). (The 3D formula
  λ = E ν / ((1 + ν)(1 − 2ν)) does *not* apply to a membrane; plane stress eliminates the
  thickness direction.) ``from_lame`` inverts these: E = 4 μ (λ + μ) / (λ + 2 μ),
  ν = λ / (λ + 2 μ).

Woven fabrics are strongly anisotropic: their in-plane shear stiffness (``shear_modulus``,
from KES G) is one to two orders of magnitude below the isotropic μ implied by E and ν. Both
are kept; a solver that models shear separately should use ``shear_modulus``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from sim.errors import WrinklesInputError

KES_BENDING_TO_NM = 9.80665e-5
"""1 gf·cm²/cm in N·m."""
KES_SHEAR_TO_N_PER_M = 0.980665 * 180.0 / 3.141592653589793
"""1 gf/(cm·deg) in N/m per radian of shear angle."""


@dataclass(frozen=True)
class Material:
    """Mechanical and contact properties of one cloth, SI units.

    Attributes:
        name: preset or user name.
        density: area density [kg/m²] (fabric weight; 1 oz/yd² = 0.0339 kg/m²).
        youngs_modulus: in-plane tensile stiffness per unit width E [N/m] (membrane
            modulus = 3D modulus × thickness).
        poisson_ratio: in-plane Poisson ratio ν [-], 0 ≤ ν < 0.5.
        shear_modulus: in-plane shear stiffness per unit width [N/m per radian of shear
            angle], from KES shear rigidity G (anisotropic cloth: ≪ E / (2 (1 + ν))).
        bending_stiffness: bending rigidity per unit width [N·m] (KES B).
        damping: stiffness-proportional (Rayleigh β) damping coefficient [s].
        friction: Coulomb friction coefficient against skin [-].
        thickness: fabric thickness [m] (KES T at 0.5 gf/cm²); collision offset.
        source: where the values come from; "estimate" marks values not measured.
    """

    name: str
    density: float
    youngs_modulus: float
    poisson_ratio: float
    shear_modulus: float
    bending_stiffness: float
    damping: float
    friction: float
    thickness: float
    source: str = ""

    def __post_init__(self) -> None:
        positive = ("density", "youngs_modulus", "shear_modulus", "bending_stiffness", "thickness")
        for f in positive:
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and v > 0.0 and v < float("inf")):
                raise WrinklesInputError(f"material {self.name!r}: {f} must be a positive number, got {v!r}")
        for f in ("damping", "friction"):
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and 0.0 <= v < float("inf")):
                raise WrinklesInputError(f"material {self.name!r}: {f} must be >= 0, got {v!r}")
        if not 0.0 <= self.poisson_ratio < 0.5:
            raise WrinklesInputError(
                f"material {self.name!r}: poisson_ratio must lie in [0, 0.5), got {self.poisson_ratio}")

    @property
    def lame_mu(self) -> float:
        """Plane-stress Lamé μ [N/m] = E / (2 (1 + ν))."""
        return lame_from_youngs(self.youngs_modulus, self.poisson_ratio)[0]

    @property
    def lame_lambda(self) -> float:
        """Plane-stress Lamé λ [N/m] = E ν / (1 − ν²)."""
        return lame_from_youngs(self.youngs_modulus, self.poisson_ratio)[1]

    @classmethod
    def from_lame(cls, name: str, *, mu: float, lam: float, **fields: float | str) -> Material:
        """Build a material from plane-stress Lamé parameters μ, λ [N/m].

        ``shear_modulus`` defaults to μ (isotropic sheet) unless given.
        """
        E, nu = youngs_from_lame(mu, lam)
        fields.setdefault("shear_modulus", mu)
        return cls(name=name, youngs_modulus=E, poisson_ratio=nu, **fields)  # type: ignore[arg-type]

    def with_(self, **changes: float | str) -> Material:
        """A copy with some fields changed (unknown names are an error)."""
        unknown = set(changes) - set(self.__dataclass_fields__)
        if unknown:
            raise WrinklesInputError(f"material {self.name!r}: unknown field(s) {sorted(unknown)}; "
                                     f"expected {', '.join(self.__dataclass_fields__)}")
        return replace(self, **changes)  # type: ignore[arg-type]


MATERIAL_UNITS: dict[str, str] = {
    "density": "kg/m²", "youngs_modulus": "N/m", "poisson_ratio": "-", "shear_modulus": "N/m",
    "bending_stiffness": "N·m", "damping": "s", "friction": "-", "thickness": "m"}
"""The unit of each numeric ``Material`` field (the others, ``name`` and ``source``, are text)."""


def lame_from_youngs(E: float, nu: float) -> tuple[float, float]:
    """Plane-stress (membrane) Lamé parameters.

    Args:
        E: Young's modulus per unit width [N/m].
        nu: Poisson ratio [-].

    Returns:
        (μ, λ) [N/m]: μ = E / (2 (1 + ν)), λ = E ν / (1 − ν²).
    """
    return E / (2.0 * (1.0 + nu)), E * nu / (1.0 - nu * nu)


def youngs_from_lame(mu: float, lam: float) -> tuple[float, float]:
    """Inverse of ``lame_from_youngs``: (E [N/m], ν) from plane-stress μ, λ [N/m]."""
    if mu <= 0 or lam < 0:
        raise WrinklesInputError(f"Lamé parameters need mu > 0 and lambda >= 0, got mu={mu}, lambda={lam}")
    return 4.0 * mu * (lam + mu) / (lam + 2.0 * mu), lam / (lam + 2.0 * mu)


_KES = ("Kawabata KES-FB bending B and shear G ranges for the fabric class (Kawabata & Niwa 1989, "
        "'Fabric performance in clothing and clothing manufacture', J. Textile Inst. 80(1); "
        "Wang, O'Brien & Ramamoorthi 2011, 'Data-driven elastic models for cloth', SIGGRAPH)")

MATERIALS: dict[str, Material] = {
    "cotton": Material(
        "cotton", density=0.15, youngs_modulus=4.0e3, poisson_ratio=0.30,
        shear_modulus=1.0 * KES_SHEAR_TO_N_PER_M, bending_stiffness=0.08 * KES_BENDING_TO_NM,
        damping=2e-3, friction=0.40, thickness=3.0e-4,
        source="150 g/m² shirting (manufacturer weights 120-180); B 0.08 gf·cm²/cm, G 1.0, T 0.3 mm: "
               + _KES + "; E, damping, friction (skin 0.3-0.5, Derler & Gerhardt 2012) are estimates"),
    "denim": Material(
        "denim", density=0.40, youngs_modulus=1.2e4, poisson_ratio=0.25,
        shear_modulus=3.0 * KES_SHEAR_TO_N_PER_M, bending_stiffness=0.6 * KES_BENDING_TO_NM,
        damping=3e-3, friction=0.45, thickness=8.0e-4,
        source="12 oz/yd² = 0.41 kg/m² denim (manufacturer); B 0.6, G 3.0, T 0.8 mm: " + _KES
               + "; Penava et al. 2014 (Textile Res. J. 84) tensile moduli of woven fabrics; "
                 "E, damping, friction are estimates"),
    "silk": Material(
        "silk", density=0.07, youngs_modulus=1.5e3, poisson_ratio=0.30,
        shear_modulus=0.4 * KES_SHEAR_TO_N_PER_M, bending_stiffness=0.02 * KES_BENDING_TO_NM,
        damping=1e-3, friction=0.25, thickness=1.2e-4,
        source="16-19 momme habotai/charmeuse, 0.07 kg/m² (manufacturer); B 0.02, G 0.4, T 0.12 mm: "
               + _KES + "; E, damping, friction are estimates"),
    "polyester": Material(
        "polyester", density=0.12, youngs_modulus=3.0e3, poisson_ratio=0.30,
        shear_modulus=0.8 * KES_SHEAR_TO_N_PER_M, bending_stiffness=0.06 * KES_BENDING_TO_NM,
        damping=1.5e-3, friction=0.30, thickness=2.0e-4,
        source="woven polyester 120 g/m² (manufacturer); B 0.06, G 0.8, T 0.2 mm: " + _KES
               + "; E, damping, friction are estimates"),
    "jersey_knit": Material(
        "jersey_knit", density=0.18, youngs_modulus=6.0e2, poisson_ratio=0.35,
        shear_modulus=0.3 * KES_SHEAR_TO_N_PER_M, bending_stiffness=0.03 * KES_BENDING_TO_NM,
        damping=2e-3, friction=0.45, thickness=5.0e-4,
        source="cotton single jersey 180 g/m² (manufacturer); knits are ~10x softer in tension "
               "than wovens (Wang et al. 2011 knit samples); B 0.03, G 0.3, T 0.5 mm: " + _KES
               + "; E, damping, friction are estimates"),
    "leather": Material(
        "leather", density=0.70, youngs_modulus=2.0e4, poisson_ratio=0.40,
        shear_modulus=6.0e3, bending_stiffness=3.0 * KES_BENDING_TO_NM,
        damping=5e-3, friction=0.50, thickness=1.0e-3,
        source="garment lambskin 0.8-1.0 mm at ~0.8 g/cm³ -> 0.7 kg/m² (tannery data); leather is "
               "near-isotropic so shear = E/(2(1+nu))-ish; all stiffness values are estimates"),
}
"""Named presets (registry). Use ``get_material``."""


def get_material(name: str | Material) -> Material:
    """Look a preset up by name (a ``Material`` passes through).

    Raises:
        WrinklesInputError: unknown name; the message lists the presets.
    """
    if isinstance(name, Material):
        return name
    try:
        return MATERIALS[str(name)]
    except KeyError:
        raise WrinklesInputError(f"unknown material {name!r}; expected one of "
                                 f"{', '.join(sorted(MATERIALS))}") from None
