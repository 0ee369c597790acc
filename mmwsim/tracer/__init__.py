"""Exact specular ray tracing (Embree candidates, image-method geometry)."""

from .fresnel import Surface, fresnel, slab
from .paths import POLARISATIONS, Interaction, PathKind, Paths
from .reflectors import Reflectors, group_reflectors
from .tracer import DEFAULT_RAYS, Tracer, trace

__all__ = [
    "DEFAULT_RAYS",
    "POLARISATIONS",
    "Interaction",
    "PathKind",
    "Paths",
    "Reflectors",
    "Surface",
    "Tracer",
    "fresnel",
    "group_reflectors",
    "slab",
    "trace",
]
