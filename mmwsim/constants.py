"""Physical constants and the defaults of the physics contract (DESIGN.md)."""

SPEED_OF_LIGHT = 299_792_458.0
"""m/s, exact."""

VACUUM_PERMITTIVITY = 8.8541878128e-12
"""F/m."""

DEFAULT_FREQUENCY = 28e9
"""Hz, the carrier of the reference experiments."""

# Beamformed fingerprints (the physics contract's defaults; DESIGN.md)
TX_POWER_DBM = 30.0
"""Transmit power the stored PDPs are computed at, dBm."""
RX_GAIN_DBI = 10.0
"""Receive antenna gain, dBi."""
SAMPLE_RATE = 20e6
"""PDP sampling rate, Hz: 50 ns bins."""
N_BINS = 120
"""Bins per profile: 6 us at 20 MHz."""
SIGMA_DB = 6.0
"""Standard deviation of the log-normal fingerprint noise, dB."""
THRESHOLD_DBM = -115.0
"""Detection threshold on PDPs at 30 dBm / 10 dBi (= -100 dBm at 45 dBm transmit power)."""
BINS = (1, 82)
"""Fingerprint bin window [start, stop): bins 1..81, N_s = 81."""

# Tracer
DEFAULT_RAYS = 4_000_000
"""Rays shot from the transmitter for the candidate search: 8M finds the same path set on the
default scene, 2M misses a few (benchmarks/trace_grid.py)."""
