"""Power-delay profiles (PDP) and beamformed fingerprints (BFF)."""

from .noise import BINS, SIGMA_DB, THRESHOLD_DBM, FingerprintSampler, detection_probability, fingerprints
from .pdp import (
    N_BINS,
    RX_GAIN_DBI,
    SAMPLE_RATE,
    TX_POWER_DBM,
    beam_amplitudes,
    channel_taps,
    power_delay_profile,
    receive_pattern,
)

__all__ = [
    "BINS",
    "N_BINS",
    "RX_GAIN_DBI",
    "SAMPLE_RATE",
    "SIGMA_DB",
    "THRESHOLD_DBM",
    "TX_POWER_DBM",
    "FingerprintSampler",
    "beam_amplitudes",
    "channel_taps",
    "detection_probability",
    "fingerprints",
    "power_delay_profile",
    "receive_pattern",
]
