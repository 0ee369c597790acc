"""Radio materials after ITU-R P.2040 (Table 3) and user-defined ones.

The permittivity model of ITU-R P.2040 is ``eps' = a f^b`` and ``sigma = c f^d``
with ``f`` in GHz and ``sigma`` in S/m; the complex relative permittivity is
``eps' - j sigma / (2 pi f eps0)``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

from .constants import VACUUM_PERMITTIVITY
from .errors import MaterialRangeWarning, MmwsimError

__all__ = ["Band", "Material", "ITU_MATERIALS", "get_material", "material_color", "material_names"]


@dataclass(frozen=True)
class Band:
    """One row of ITU-R P.2040 Table 3: parameters valid from ``f_min`` to ``f_max`` GHz."""

    a: float
    b: float
    c: float
    d: float
    f_min_ghz: float
    f_max_ghz: float

    def contains(self, f_ghz: float) -> bool:
        return self.f_min_ghz <= f_ghz <= self.f_max_ghz

    def distance(self, f_ghz: float) -> float:
        """How far ``f_ghz`` is outside the band, on a log scale (0 inside)."""
        if self.contains(f_ghz):
            return 0.0
        edge = self.f_min_ghz if f_ghz < self.f_min_ghz else self.f_max_ghz
        return abs(math.log(f_ghz / edge))


@dataclass(frozen=True)
class Material:
    """A radio material.

    Parameters
    ----------
    name : str
        Identifier, e.g. ``"concrete"``.
    bands : tuple of Band
        Frequency bands with their P.2040 parameters; a user-defined material has
        one band valid at every frequency with ``b = d = 0``.
    thickness : float or None
        Slab thickness in metres; ``None`` reflects as a half-space.
    source : str
        Where the parameters come from.
    """

    name: str
    bands: tuple[Band, ...]
    thickness: float | None = None
    source: str = "ITU-R P.2040-3 Table 3"

    @classmethod
    def custom(
        cls,
        name: str,
        relative_permittivity: float,
        conductivity: float,
        thickness: float | None = None,
    ) -> Material:
        """A frequency-independent material from its permittivity and conductivity (S/m)."""
        if not (math.isfinite(relative_permittivity) and relative_permittivity >= 1.0):
            raise MmwsimError(
                f"material {name!r}: relative permittivity must be >= 1, got {relative_permittivity}"
            )
        if not (math.isfinite(conductivity) and conductivity >= 0.0):
            raise MmwsimError(f"material {name!r}: conductivity must be >= 0, got {conductivity}")
        band = Band(relative_permittivity, 0.0, conductivity, 0.0, 0.0, math.inf)
        return cls(name, (band,), _check_thickness(name, thickness), source="user-defined")

    def with_thickness(self, thickness: float | None) -> Material:
        """The same material as a slab of ``thickness`` metres (``None``: half-space)."""
        return Material(self.name, self.bands, _check_thickness(self.name, thickness), self.source)

    def band(self, frequency: float, warn: bool = True) -> Band:
        """The band used at ``frequency`` (Hz); warns when it lies outside every stated range."""
        f_ghz = frequency / 1e9
        best = min(self.bands, key=lambda b: b.distance(f_ghz))
        if warn and not best.contains(f_ghz):
            warnings.warn(
                f"material {self.name!r} is stated for {best.f_min_ghz:g}-{best.f_max_ghz:g} GHz, "
                f"used at {f_ghz:g} GHz",
                MaterialRangeWarning,
                stacklevel=2,
            )
        return best

    def in_range(self, frequency: float) -> bool:
        """Whether ``frequency`` (Hz) lies inside one of the stated ranges."""
        return any(b.contains(frequency / 1e9) for b in self.bands)

    def relative_permittivity(self, frequency: float, warn: bool = True) -> float:
        """Real relative permittivity eps' at ``frequency`` (Hz)."""
        b = self.band(frequency, warn)
        return b.a * (frequency / 1e9) ** b.b

    def conductivity(self, frequency: float, warn: bool = True) -> float:
        """Conductivity sigma in S/m at ``frequency`` (Hz)."""
        b = self.band(frequency, warn)
        return b.c * (frequency / 1e9) ** b.d

    def complex_permittivity(self, frequency: float, warn: bool = True) -> complex:
        """Complex relative permittivity ``eps' - j sigma / (2 pi f eps0)`` at ``frequency`` (Hz)."""
        eps = self.relative_permittivity(frequency, warn)
        sigma = self.conductivity(frequency, warn)
        return complex(eps, -sigma / (2.0 * math.pi * frequency * VACUUM_PERMITTIVITY))


def _check_thickness(name: str, thickness: float | None) -> float | None:
    if thickness is None:
        return None
    if not (math.isfinite(thickness) and thickness > 0.0):
        raise MmwsimError(f"material {name!r}: thickness must be > 0 m, got {thickness}")
    return float(thickness)


def _itu(name: str, *rows: tuple[float, float, float, float, float, float]) -> Material:
    return Material(name, tuple(Band(*r) for r in rows))


# (a, b, c, d, f_min GHz, f_max GHz), ITU-R P.2040-3 Table 3.
ITU_MATERIALS: dict[str, Material] = {
    m.name: m
    for m in (
        _itu("vacuum", (1.0, 0.0, 0.0, 0.0, 0.001, 100.0)),
        _itu("concrete", (5.24, 0.0, 0.0462, 0.7822, 1.0, 100.0)),
        _itu("brick", (3.91, 0.0, 0.0238, 0.16, 1.0, 40.0)),
        _itu("plasterboard", (2.73, 0.0, 0.0085, 0.9395, 1.0, 100.0)),
        _itu("wood", (1.99, 0.0, 0.0047, 1.0718, 0.001, 100.0)),
        _itu("glass", (6.31, 0.0, 0.0036, 1.3394, 0.1, 100.0), (5.79, 0.0, 0.0004, 1.658, 220.0, 450.0)),
        _itu(
            "ceiling_board",
            (1.48, 0.0, 0.0011, 1.0750, 1.0, 100.0),
            (1.52, 0.0, 0.0029, 1.029, 220.0, 450.0),
        ),
        _itu("chipboard", (2.58, 0.0, 0.0217, 0.7800, 1.0, 100.0)),
        _itu("plywood", (2.71, 0.0, 0.33, 0.0, 1.0, 40.0)),
        _itu("marble", (7.074, 0.0, 0.0055, 0.9262, 1.0, 60.0)),
        _itu("floorboard", (3.66, 0.0, 0.0044, 1.3515, 50.0, 100.0)),
        _itu("metal", (1.0, 0.0, 1e7, 0.0, 1.0, 100.0)),
        _itu("very_dry_ground", (3.0, 0.0, 0.00015, 2.52, 1.0, 10.0)),
        _itu("medium_dry_ground", (15.0, -0.1, 0.035, 1.63, 1.0, 10.0)),
        _itu("wet_ground", (30.0, -0.4, 0.15, 1.30, 1.0, 10.0)),
    )
}

# Road surface for city scenes at mmWave, where P.2040 gives no ground above 10 GHz.
# Measured asphalt at 28-60 GHz: eps' ~ 3.2 and a loss tangent ~ 0.03 (constant over
# frequency, hence sigma proportional to f: d = 1).
ITU_MATERIALS["asphalt"] = Material(
    "asphalt",
    (Band(3.18, 0.0, 0.0054, 1.0, 10.0, 100.0),),
    source="literature (mmWave road measurements), not ITU-R P.2040",
)

_ALIASES = {"air": "vacuum", "asphalt_concrete": "asphalt", "ceilingboard": "ceiling_board"}


def material_names() -> list[str]:
    """Names of the built-in materials."""
    return sorted(ITU_MATERIALS)


def get_material(name: str, thickness: float | None = None) -> Material:
    """A built-in material by name.

    Accepts the Sionna / Mitsuba spellings ``itu_concrete`` and ``mat-itu_concrete``
    as well as ``concrete``; case-insensitive.

    Raises
    ------
    MmwsimError
        If the name is unknown.
    """
    key = name.strip().lower().replace("-", "_").replace(" ", "_")
    for prefix in ("mat_itu_", "itu_"):
        if key.startswith(prefix):
            key = key[len(prefix) :]
    key = _ALIASES.get(key, key)
    try:
        mat = ITU_MATERIALS[key]
    except KeyError:
        raise MmwsimError(f"unknown material {name!r}; known: {', '.join(material_names())}") from None
    return mat.with_thickness(thickness) if thickness is not None else mat


# Display colours (RGB 0-255) for recordings and exported meshes.
_COLORS = {
    "concrete": (150, 150, 150),
    "brick": (170, 74, 50),
    "plasterboard": (220, 215, 200),
    "wood": (133, 94, 66),
    "glass": (120, 170, 220),
    "ceiling_board": (200, 200, 170),
    "chipboard": (190, 150, 110),
    "plywood": (160, 120, 80),
    "marble": (225, 220, 205),
    "floorboard": (140, 100, 60),
    "metal": (90, 90, 110),
    "very_dry_ground": (190, 160, 120),
    "medium_dry_ground": (150, 120, 80),
    "wet_ground": (100, 80, 60),
    "asphalt": (60, 60, 65),
    "vacuum": (255, 255, 255),
}


def material_color(name: str) -> tuple[int, int, int]:
    """An RGB display colour for a material name; user-defined materials get a stable hashed colour."""
    if name in _COLORS:
        return _COLORS[name]
    h = sum((i + 1) * ord(ch) for i, ch in enumerate(name))
    return (80 + h % 150, 80 + (h // 7) % 150, 80 + (h // 49) % 150)
