"""Physical constants and the defaults of the physics contract (DESIGN.md)."""

SPEED_OF_LIGHT = 299_792_458.0
"""m/s, exact."""

VACUUM_PERMITTIVITY = 8.8541878128e-12
"""F/m."""

DEFAULT_FREQUENCY = 28e9
"""Hz, the carrier of the reference experiments."""
