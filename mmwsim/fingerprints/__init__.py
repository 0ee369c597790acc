"""Power-delay profiles (PDP), the fingerprint field over positions, and beamformed fingerprints (BFF)
drawn from them under the one noise model."""

from .field import FingerprintField, GridField, TracedField
from .noise import FingerprintSampler, NoiseModel
from .pdp import beam_amplitudes, channel_taps, power_delay_profile, receive_pattern

__all__ = [
    "FingerprintField",
    "FingerprintSampler",
    "GridField",
    "NoiseModel",
    "TracedField",
    "beam_amplitudes",
    "channel_taps",
    "power_delay_profile",
    "receive_pattern",
]
