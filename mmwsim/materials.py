"""Radio materials after ITU-R P.2040-3 (Table 3) and user-defined ones.

The permittivity model of ITU-R P.2040 is ``eps' = a f^b`` and ``sigma = c f^d``
with ``f`` in GHz and ``sigma`` in S/m; the complex relative permittivity is
``eps' - j sigma / (2 pi f eps0)``.
"""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass, replace

from .constants import VACUUM_PERMITTIVITY
from .errors import MaterialRangeWarning, MmwsimError

__all__ = [
    "Band",
    "Material",
    "ITU_MATERIALS",
    "SCATTERING_PATTERNS",
    "canonical_name",
    "get_material",
    "material_color",
    "material_names",
]


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


SCATTERING_PATTERNS = ("lambertian", "directive")


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
    scattering_coefficient : float
        Effective-roughness scattering coefficient S in [0, 1] (Degli-Esposti): a fraction
        S^2 of the reflected power is scattered diffusely, the specular reflection keeps
        sqrt(1 - S^2) of its field. 0 (default): a smooth surface.
    xpd_coefficient : float
        Fraction Kx in [0, 1] of the diffusely scattered power that goes into the
        cross polarisation.
    scattering_pattern : {"lambertian", "directive"}
        Angular pattern of the diffuse power.
    alpha_r : int
        Lobe exponent (>= 1) of the directive pattern; unused by the Lambertian one.
    """

    name: str
    bands: tuple[Band, ...]
    thickness: float | None = None
    source: str = "ITU-R P.2040-3 Table 3"
    scattering_coefficient: float = 0.0
    xpd_coefficient: float = 0.0
    scattering_pattern: str = "lambertian"
    alpha_r: int = 4

    def __post_init__(self) -> None:
        for key in ("scattering_coefficient", "xpd_coefficient"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise MmwsimError(f"material {self.name!r}: {key} must be a number, got {value!r}")
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise MmwsimError(f"material {self.name!r}: {key} must be in [0, 1], got {value}")
            object.__setattr__(self, key, float(value))
        if isinstance(self.scattering_pattern, str):
            object.__setattr__(self, "scattering_pattern", self.scattering_pattern.strip().lower())
        if self.scattering_pattern not in SCATTERING_PATTERNS:
            raise MmwsimError(
                f"material {self.name!r}: scattering_pattern must be 'lambertian' or 'directive', "
                f"got {self.scattering_pattern!r}"
            )
        a = self.alpha_r
        if isinstance(a, bool) or not isinstance(a, numbers.Integral) or a < 1:
            raise MmwsimError(f"material {self.name!r}: alpha_r must be an integer >= 1, got {a!r}")
        object.__setattr__(self, "alpha_r", int(a))

    @classmethod
    def custom(
        cls,
        name: str,
        relative_permittivity: float,
        conductivity: float,
        thickness: float | None = None,
        **scattering,
    ) -> Material:
        """A frequency-independent material from its permittivity and conductivity (S/m).

        ``scattering`` takes the optional keys ``scattering_coefficient``, ``xpd_coefficient``,
        ``scattering_pattern`` and ``alpha_r`` (see :class:`Material`).
        """
        if not (math.isfinite(relative_permittivity) and relative_permittivity >= 1.0):
            raise MmwsimError(
                f"material {name!r}: relative permittivity must be >= 1, got {relative_permittivity}"
            )
        if not (math.isfinite(conductivity) and conductivity >= 0.0):
            raise MmwsimError(f"material {name!r}: conductivity must be >= 0, got {conductivity}")
        band = Band(relative_permittivity, 0.0, conductivity, 0.0, 0.0, math.inf)
        mat = cls(name, (band,), _check_thickness(name, thickness), source="user-defined")
        return mat.with_scattering(**_scattering_keys(name, scattering)) if scattering else mat

    def with_thickness(self, thickness: float | None) -> Material:
        """The same material as a slab of ``thickness`` metres (``None``: half-space)."""
        return replace(self, thickness=_check_thickness(self.name, thickness))

    def with_scattering(
        self,
        S: float | None = None,
        xpd: float | None = None,
        pattern: str | None = None,
        alpha_r: int | None = None,
    ) -> Material:
        """A copy with the given diffuse-scattering parameters (``None`` keeps the current one).

        Parameters
        ----------
        S : float, optional
            Scattering coefficient in [0, 1].
        xpd : float, optional
            Cross-polarisation fraction Kx in [0, 1].
        pattern : {"lambertian", "directive"}, optional
        alpha_r : int, optional
            Directive lobe exponent, >= 1.

        Raises
        ------
        MmwsimError
            If a value is out of range, naming the material and the key.
        """
        changes = {
            k: v
            for k, v in (
                ("scattering_coefficient", S),
                ("xpd_coefficient", xpd),
                ("scattering_pattern", pattern),
                ("alpha_r", alpha_r),
            )
            if v is not None
        }
        return replace(self, **changes) if changes else self

    def band(self, frequency: float, warn: bool = True) -> Band:
        """The band used at ``frequency`` (Hz); warns when it lies outside every stated range.

        Where bands overlap (several P.2040-3 materials have rows of different measurement
        campaigns above 100 GHz), the first listed band that contains the frequency is used, as
        Sionna RT does; outside every band, the nearest one on a log-frequency scale.
        """
        if not (isinstance(frequency, numbers.Real) and math.isfinite(frequency) and frequency > 0):
            raise MmwsimError(f"frequency must be a positive, finite number of Hz, got {frequency!r}")
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


_SCATTERING_KEYS = {
    "scattering_coefficient": "S",
    "xpd_coefficient": "xpd",
    "scattering_pattern": "pattern",
    "alpha_r": "alpha_r",
}


def _scattering_keys(name: str, keys: dict) -> dict:
    unknown = sorted(set(keys) - set(_SCATTERING_KEYS))
    if unknown:
        raise MmwsimError(f"material {name!r}: unknown key {unknown[0]!r}")
    return {_SCATTERING_KEYS[k]: v for k, v in keys.items()}


def _check_thickness(name: str, thickness: float | None) -> float | None:
    if thickness is None:
        return None
    if not (math.isfinite(thickness) and thickness > 0.0):
        raise MmwsimError(f"material {name!r}: thickness must be > 0 m, got {thickness}")
    return float(thickness)


def _itu(name: str, *rows: tuple[float, float, float, float, float, float]) -> Material:
    return Material(name, tuple(Band(*r) for r in rows))


# ITU-R P.2040-3 (08/2023) Table 3, every row, as (a, b, c, d, f_min GHz, f_max GHz) with
# eps' = a f^b and sigma = c f^d (f in GHz). Transcribed from two tables that agree value for value
# and in the order of the rows: Sionna RT's radio_materials/itu.py (NVlabs/sionna-rt, which cites
# P.2040-3) and DiffeRT's em/_material.py (jeertmans/DiffeRT, which cites Table 3 of P.2040-4); the
# rows up to 100 GHz also agree with the P.2040-2 tables of Sionna 0.x and wave tracer. The order
# matters where bands overlap (see Material.band). The floorboard 220-300 GHz row really has
# c = 2.22e-17, d = 7.3413, and its 400-450 GHz row c = 49.8726, d = 0.
ITU_MATERIALS: dict[str, Material] = {
    m.name: m
    for m in (
        _itu("vacuum", (1.0, 0.0, 0.0, 0.0, 0.001, 100.0)),
        _itu("concrete", (5.24, 0.0, 0.0462, 0.7822, 1.0, 100.0), (5.17, 0.0, 0.0145, 1.0900, 110.0, 330.0)),
        _itu("brick", (3.91, 0.0, 0.0238, 0.16, 1.0, 40.0), (4.15, 0.0, 0.0006, 1.5712, 110.0, 330.0)),
        _itu(
            "plasterboard",
            (2.73, 0.0, 0.0085, 0.9395, 1.0, 100.0),
            (2.56, 0.0, 0.0001, 1.7799, 110.0, 330.0),
            (2.65, 0.0, 0.0002, 1.598, 100.0, 400.0),
        ),
        _itu(
            "wood",
            (1.99, 0.0, 0.0047, 1.0718, 0.001, 100.0),
            (1.82, 0.0, 0.0040, 1.0761, 110.0, 330.0),
            (2.1183, 0.0, 0.0055, 1.1113, 100.0, 400.0),
        ),
        _itu(
            "glass",
            (6.31, 0.0, 0.0036, 1.3394, 0.1, 100.0),
            (5.79, 0.0, 0.0004, 1.658, 220.0, 450.0),
            (6.5767, 0.0, 0.0012, 1.4697, 100.0, 400.0),
        ),
        _itu("clear_acrylic", (2.58, 0.0, 0.0001, 1.6524, 110.0, 330.0)),
        _itu(
            "ceiling_board",
            (1.48, 0.0, 0.0011, 1.0750, 1.0, 100.0),
            (1.52, 0.0, 0.0029, 1.029, 220.0, 450.0),
            (1.2567, 0.0, 0.00013, 1.454, 100.0, 400.0),
        ),
        _itu("chipboard", (2.58, 0.0, 0.0217, 0.7800, 1.0, 100.0), (2.16, 0.0, 0.0023, 1.359, 100.0, 200.0)),
        _itu(
            "plywood",
            (2.71, 0.0, 0.33, 0.0, 1.0, 40.0),
            (1.94, 0.0, 0.0067, 0.9982, 110.0, 330.0),
            (2.17, 0.0, 0.0063, 1.045, 100.0, 400.0),
        ),
        _itu(
            "marble",
            (7.074, 0.0, 0.0055, 0.9262, 1.0, 60.0),
            (7.94, 0.0, 0.0001, 1.7330, 110.0, 330.0),
            (8.62, 0.0, 0.0027, 1.15, 100.0, 400.0),
        ),
        _itu(
            "floorboard",
            (3.66, 0.0, 0.0044, 1.3515, 50.0, 100.0),
            (5.27, 0.0, 2.22e-17, 7.3413, 220.0, 300.0),
            (5.27, 0.0, 0.0003, 2.0298, 300.0, 400.0),
            (5.27, 0.0, 49.8726, 0.0, 400.0, 450.0),
            (3.1575, 0.0, 0.001675, 1.32775, 100.0, 400.0),
        ),
        _itu("vinyl_tile", (3.62, 0.0, 0.0051, 0.8422, 1.0, 40.0)),
        _itu("carpet_tile", (2.08, 0.0, 0.0009, 0.8200, 1.0, 40.0)),
        _itu("asphalt_concrete", (4.83, 0.0, 0.0108, 1.3969, 1.0, 40.0)),
        _itu("metal", (1.0, 0.0, 1e7, 0.0, 1.0, 100.0)),
        _itu("very_dry_ground", (3.0, 0.0, 0.00015, 2.52, 1.0, 10.0)),
        _itu("medium_dry_ground", (15.0, -0.1, 0.035, 1.63, 1.0, 10.0)),
        _itu("wet_ground", (30.0, -0.4, 0.15, 1.30, 1.0, 10.0)),
    )
}

# Road surface for city scenes at mmWave, kept under a name of its own (P.2040-3's asphalt_concrete,
# above, is a different entry). Measured asphalt at 28-60 GHz: eps' ~ 3.2 and a loss tangent ~ 0.03
# (constant over frequency, hence sigma proportional to f: d = 1).
ITU_MATERIALS["asphalt"] = Material(
    "asphalt",
    (Band(3.18, 0.0, 0.0054, 1.0, 10.0, 100.0),),
    source="literature (mmWave road measurements), not ITU-R P.2040",
)

# The ideal reference of the closed forms (Kouyoumjian-Pathak's wedge, image theory): reflection
# coefficients -1 (TE) and +1 (TM) exactly at every angle and frequency.
ITU_MATERIALS["perfect_conductor"] = Material(
    "perfect_conductor",
    (Band(1.0, 0.0, math.inf, 0.0, 0.0, math.inf),),
    source="ideal (infinite conductivity)",
)

_ALIASES = {"air": "vacuum", "ceilingboard": "ceiling_board", "pec": "perfect_conductor"}


def canonical_name(name: str) -> str | None:
    """The built-in name that ``name`` spells, or ``None`` if it is none.

    Case-insensitive; spaces and hyphens count as underscores; the Sionna / Mitsuba
    prefixes ``itu_`` and ``mat-itu_`` are dropped (``Asphalt concrete``,
    ``itu_asphalt_concrete`` and ``mat-itu_asphalt_concrete`` all give ``asphalt_concrete``).
    """
    key = name.strip().lower().replace("-", "_").replace(" ", "_")
    for prefix in ("mat_itu_", "itu_"):
        if key.startswith(prefix):
            key = key[len(prefix) :]
    key = _ALIASES.get(key, key)
    return key if key in ITU_MATERIALS else None


def material_names() -> list[str]:
    """Names of the built-in materials."""
    return sorted(ITU_MATERIALS)


def get_material(name: str, thickness: float | None = None) -> Material:
    """A built-in material by name (any spelling :func:`canonical_name` accepts).

    Raises
    ------
    MmwsimError
        If the name is unknown.
    """
    key = canonical_name(name)
    if key is None:
        raise MmwsimError(f"unknown material {name!r}; known: {', '.join(material_names())}")
    mat = ITU_MATERIALS[key]
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
    "asphalt_concrete": (70, 70, 75),
    "clear_acrylic": (200, 225, 235),
    "vinyl_tile": (180, 175, 165),
    "carpet_tile": (120, 90, 100),
    "vacuum": (255, 255, 255),
}


def material_color(name: str) -> tuple[int, int, int]:
    """An RGB display colour for a material name; user-defined materials get a stable hashed colour."""
    if name in _COLORS:
        return _COLORS[name]
    h = sum((i + 1) * ord(ch) for i, ch in enumerate(name))
    return (80 + h % 150, 80 + (h // 7) % 150, 80 + (h // 49) % 150)
