"""Exact ray tracing: line of sight, reflections, edge diffraction (Embree candidates, exact geometry)."""

from .fresnel import Surface, slab
from .paths import POLARISATIONS, Interaction, PathKind, Paths
from .reflectors import Reflectors, group_reflectors
from .tracer import DEFAULT_RAYS, MIN_GAIN_DB, Tracer, trace

__all__ = [
    "DEFAULT_RAYS",
    "MIN_GAIN_DB",
    "POLARISATIONS",
    "Interaction",
    "PathKind",
    "Paths",
    "Reflectors",
    "Surface",
    "Tracer",
    "group_reflectors",
    "slab",
    "trace",
]
