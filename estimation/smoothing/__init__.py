"""Smoothing of per-step fingerprint matches: Kalman (one match per step) and hidden-Markov (many
candidates per step), with the motion densities the hidden-Markov smoothers score steps by and the acceleration
memory their sampled paths are weighed by, the smoother of drivers along their street routes, and
the walkers' straight lines and walks of two lines, composed for the walkers."""

from .forecast import carry, extrapolate, forecast_tracks
from .hmm import candidate_features, cell_mean, motion_posterior, subcell_mean, velocity_posterior
from .kalman import kalman_forecast, rts_smoother
from .line import line_track
from .memory import MotionMemory
from .motion import MixtureMotion, MotionTable, snap_to_lattice, speed_scaled
from .online import CandidateFilter
from .route import route_track, street_routes
from .two_lines import two_line_track
from .walks import walk_track

__all__ = [
    "CandidateFilter",
    "MixtureMotion",
    "MotionMemory",
    "MotionTable",
    "candidate_features",
    "carry",
    "cell_mean",
    "extrapolate",
    "forecast_tracks",
    "kalman_forecast",
    "line_track",
    "motion_posterior",
    "route_track",
    "rts_smoother",
    "snap_to_lattice",
    "speed_scaled",
    "street_routes",
    "subcell_mean",
    "two_line_track",
    "velocity_posterior",
    "walk_track",
]
