"""Garments: the ``Garment`` type, procedural templates fitted to a body, import, materials."""

from sim.garments.io import load_garment
from sim.garments.materials import MATERIALS, Material, get_material
from sim.garments.templates import TEMPLATES, make_garment
from sim.garments.types import Garment

__all__ = ["Garment", "MATERIALS", "Material", "TEMPLATES", "get_material", "load_garment", "make_garment"]
