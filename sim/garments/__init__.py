"""Garments: the ``Garment`` type, sewing patterns drafted from the body's measurements and sewn on it
(``make_garment`` over the designs), import, materials."""

from sim.garments.io import load_garment
from sim.garments.materials import MATERIALS, Material, get_material
from sim.garments.templates import TEMPLATES, make_garment
from sim.garments.types import Garment

__all__ = ["Garment", "MATERIALS", "Material", "TEMPLATES", "get_material", "load_garment", "make_garment"]
