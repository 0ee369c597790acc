"""Rerun views of a data set: coverage maps (2D and draped in 3D), the transmitter's beam
patterns, and the PDPs and fingerprints of chosen receivers."""

from __future__ import annotations

import os

import numpy as np
import rerun as rr

from ..antennas import Codebook, unit_vector
from ..recording import (
    NO_DATA_RGB,
    Entity,
    Recording,
    Timeline,
    colorize,
    log_colorbar,
    log_legend,
    log_scene,
)
from ..scene import ReceiverGrid
from .store import Dataset

__all__ = [
    "record_dataset",
    "log_dataset",
    "log_beam_patterns",
    "log_fingerprint_steps",
    "beam_power_dbm",
    "default_receivers",
    "pdp_image",
    "shown_bins",
    "bits_image",
]

POWER_RANGE_DBM = (-140.0, -40.0)
"""Colour range of received power (coverage maps) and of PDP bins, dBm."""
NO_SIGNAL_DBM = -200.0
PATTERN_RANGE_DB = 30.0
"""Beam patterns are drawn down to this many dB below the codebook's peak gain."""
_POWER_CMAP, _BEAM_CMAP = "viridis", "twilight"
_BIT_ON, _BIT_OFF = (250, 215, 70), (35, 38, 52)
_GAP = 4  # pixels between a receiver's PDP and its fingerprint, and between rows


def beam_power_dbm(pdp: np.ndarray) -> np.ndarray:
    """Total received power per beam, (n, n_beams) float64 dBm, from PDPs (n, n_beams, n_bins) dBm."""
    mw = np.power(10.0, np.asarray(pdp, dtype=np.float64) / 10.0).sum(axis=-1)
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(mw)


def default_receivers(ds: Dataset, n: int = 3) -> np.ndarray:
    """``n`` valid receivers spread through the valid set (deterministic)."""
    valid = np.flatnonzero(ds.valid)
    if len(valid) == 0:
        return valid
    return valid[np.unique(np.linspace(0, len(valid) - 1, n + 2).round().astype(int)[1:-1])]


def pdp_image(pdp_dbm: np.ndarray) -> np.ndarray:
    """(n_beams, n_bins, 3) uint8: a PDP (beam x delay bin, dBm) on the power colour map."""
    return colorize(pdp_dbm, _POWER_CMAP, *POWER_RANGE_DBM)


def bits_image(bits: np.ndarray) -> np.ndarray:
    """(n_beams, n_bins, 3) uint8: a fingerprint, set bits bright."""
    return np.where(np.asarray(bits, dtype=bool)[..., None], _BIT_ON, _BIT_OFF).astype(np.uint8)


def record_dataset(
    ds: Dataset,
    path: str | os.PathLike,
    receivers: np.ndarray | None = None,
    scene=None,
    seed: int = 0,
) -> None:
    """Write a recording of ``ds`` to ``path`` (.rrd).

    Logs ``world/coverage/beam_power`` (one map per beam on the ``beam`` timeline),
    ``world/coverage/best_power`` and ``world/coverage/best_beam`` (static), and for each chosen
    receiver r ``bff/rx_<r>/pdp`` and ``bff/rx_<r>/fingerprint`` (images, beam x delay bin),
    ``bff/rx_<r>/pdp_dbm`` (the PDP as a tensor, dBm) and ``bff/rx_<r>/beam_power`` (a scalar
    per beam on the ``beam`` timeline). With a scene, also the scene and the beam patterns.
    """
    families = ("world", "coverage", "bff") if scene is not None else ("coverage", "bff")
    extent = scene.extent if scene is not None else None
    with Recording(path, "dataset", families=families, config=ds.config, extent=extent) as rec:
        log_dataset(rec, ds, receivers, scene, seed)


def log_dataset(
    rec: Recording,
    ds: Dataset,
    receivers: np.ndarray | None = None,
    scene=None,
    seed: int = 0,
) -> None:
    """Log the entities of :func:`record_dataset` into an open :class:`~mmwsim.recording.Recording`."""
    from .config import GenerateConfig
    from .tiles import make_codebook_from

    nx, ny = ds.grid.shape
    n_beams = ds.n_beams
    rx = default_receivers(ds) if receivers is None else np.asarray(receivers, dtype=np.int64)
    if scene is not None:
        log_scene(rec, scene)
        (x0, y0, _), (x1, y1, _) = scene.extent
        log_beam_patterns(
            rec,
            make_codebook_from(GenerateConfig.model_validate(ds.config)),
            np.asarray(ds.config["transmitter"], dtype=np.float64),
            0.25 * max(x1 - x0, y1 - y0),
        )
    power = np.empty((ds.n_rx, n_beams), dtype=np.float32)
    step = 8192
    for s in range(0, ds.n_rx, step):
        power[s : s + step] = beam_power_dbm(ds.pdp[s : s + step])
    signal = np.isfinite(power) & ds.valid[:, None]
    # Indoor cells are transparent (in 3D the buildings stand there); outdoor cells without
    # signal are drawn in the no-data colour.
    alpha = np.where(np.asarray(ds.outdoors), 255, 0).astype(np.uint8)

    def image(rgb: np.ndarray) -> np.ndarray:  # (n_rx, 3) -> (ny, nx, 4) with north up
        return np.concatenate([rgb, alpha[:, None]], axis=1).reshape(ny, nx, 4)[::-1]

    _log_coverage_plane(rec, ds.grid)
    lo, hi = POWER_RANGE_DBM
    for b in range(n_beams):
        rec.set_time(Timeline.BEAM, b)
        rgb = colorize(power[:, b], _POWER_CMAP, lo, hi, signal[:, b])
        rec.log(Entity.coverage("beam_power"), rr.Image(image(rgb), draw_order=1.0))
    best_power = np.where(signal, power, -np.inf).max(axis=1)
    rec.log(
        Entity.coverage("best_power"),
        rr.Image(image(colorize(best_power, _POWER_CMAP, lo, hi, signal.any(axis=1))), draw_order=0.0),
        static=True,
    )
    best = np.argmax(np.where(signal, power, -np.inf), axis=1)
    rgb = colorize(best.astype(float), _BEAM_CMAP, 0.0, float(n_beams), signal.any(axis=1))
    rec.log(Entity.coverage("best_beam"), rr.Image(image(rgb)), static=True)
    for tab in ("coverage", "scene") if scene is not None else ("coverage",):
        log_colorbar(
            rec,
            tab,
            "power",
            "received power, dBm",
            _POWER_CMAP,
            lo,
            hi,
        )
    log_colorbar(
        rec,
        "coverage",
        "best_beam",
        "best beam",
        _BEAM_CMAP,
        0.0,
        float(n_beams),
        ticks=["0", f"{n_beams // 2}", f"{n_beams - 1}"],
    )
    log_legend(rec, "coverage", "no_data", "cells", [("outdoors, no signal", NO_DATA_RGB)])

    rng = np.random.default_rng(seed)
    b0, b1 = (int(v) for v in ds.config["bins"])  # the fingerprint's delay-bin window
    pdps = np.stack([np.asarray(ds.pdp[int(r)], dtype=np.float32) for r in rx]) if len(rx) else None
    width = shown_bins(pdps[..., b0:b1]) if pdps is not None else 0
    # Receivers in up to three columns, down then across, so the images keep a readable size.
    per_column = int(np.ceil(len(rx) / (1 if len(rx) <= 3 else 2 if len(rx) <= 8 else 3))) if len(rx) else 1
    for row, r in enumerate(rx):
        name = f"rx_{int(r)}"
        bits = ds.fingerprints(np.array([r]), rng)[0]
        x, y, _ = ds.positions[int(r)]
        _log_bff_row(
            rec,
            name,
            (row // per_column, row % per_column),
            pdps[row, :, b0 : b0 + width],
            bits[:, :width],
            f"receiver {int(r)} at ({x:g}, {y:g}) m",
            static=True,
        )
        shown = np.where(np.isfinite(pdps[row]), pdps[row], NO_SIGNAL_DBM)
        rec.log(
            Entity.bff(name, "pdp_dbm"),
            rr.Tensor(shown, dim_names=["beam", "bin"], value_range=POWER_RANGE_DBM),
            static=True,
        )
        for b in range(n_beams):
            rec.set_time(Timeline.BEAM, b)
            value = float(power[int(r), b]) if np.isfinite(power[int(r), b]) else NO_SIGNAL_DBM
            rec.log(Entity.bff(name, "beam_power"), rr.Scalars(value))
    if len(rx):
        ns = 1e9 / float(ds.config["sample_rate"])
        log_colorbar(
            rec, "bff", "pdp", f"PDP, dBm: bins {b0}-{b0 + width - 1} of {ns:g} ns", _POWER_CMAP, lo, hi
        )
        log_legend(
            rec,
            "bff",
            "fingerprint",
            "fingerprint bits (right)",
            [("set", _BIT_ON), ("clear", _BIT_OFF), ("PDP bin without signal", NO_DATA_RGB)],
        )


def shown_bins(pdp: np.ndarray) -> int:
    """Delay bins worth showing of PDPs (..., n_bins): a few past the last bin with signal in any
    of them, at least 16 (late bins are empty in most scenes and would squeeze the images)."""
    signal = np.isfinite(np.asarray(pdp)).reshape(-1, pdp.shape[-1]).any(axis=0)
    last = int(np.flatnonzero(signal)[-1]) if signal.any() else 0
    return int(min(pdp.shape[-1], max(16, last + 5)))


def _log_bff_row(
    rec: Recording,
    name: str,
    slot: tuple[int, int],
    pdp: np.ndarray,
    bits: np.ndarray,
    label: str,
    static: bool,
) -> None:
    """A receiver's PDP and fingerprint side by side in slot (column, row) of the ``bff`` view,
    labelled above."""
    n_beams, n_bins = pdp.shape
    base = f"{Entity.BFF}/{name}"
    x, y = slot[0] * (2 * n_bins + 4 * _GAP), slot[1] * (n_beams + 2 * _GAP)
    rec.log(base, rr.Transform3D(translation=[float(x), float(y), 0.0]), static=True)
    rec.log(Entity.bff(name, "pdp"), rr.Image(pdp_image(pdp)), static=static)
    rec.log(
        Entity.bff(name, "fingerprint"),
        rr.Transform3D(translation=[pdp.shape[1] + _GAP, 0.0, 0.0]),
        rr.Image(bits_image(bits)),
        static=static,
    )
    rec.log(
        Entity.bff(name, "label"),
        rr.Points2D(
            [[pdp.shape[1] / 2, -0.8 * _GAP]],
            radii=0.01,
            colors=[(210, 210, 210)],
            labels=[label],
            show_labels=True,
        ),
        static=static,
    )


def log_fingerprint_steps(
    rec: Recording, name: str, pdp: np.ndarray, bits: np.ndarray, what: str = "trajectory"
) -> None:
    """PDP and fingerprint at each step of a trajectory, above the receivers' rows of the
    fingerprint view, on the ``step`` timeline.

    Parameters
    ----------
    rec : Recording
    name : str
        Entity name under ``bff`` (e.g. ``trajectory_547``).
    pdp : (n_steps, n_beams, n_bins) float
        PDP at each step over the fingerprint's delay bins, dBm (-inf or NaN: no signal).
    bits : (n_steps, n_beams, n_bins) bool or uint8
        Fingerprint given at each step.
    what : str
        Start of the label, e.g. ``"trajectory 547"``.
    """
    width = shown_bins(pdp)
    for k in range(len(pdp)):
        rec.set_time(Timeline.STEP, k)
        _log_bff_row(
            rec,
            name,
            (0, -1),
            np.asarray(pdp[k, :, :width], dtype=np.float32),
            bits[k][:, :width],
            f"{what}, step {k}: {int(np.count_nonzero(bits[k]))} bits set",
            static=False,
        )


def _log_coverage_plane(rec: Recording, grid: ReceiverGrid) -> None:
    """A pinhole looking straight down whose image plane is the receiver plane, one pixel per
    receiver: the 2D coverage images under it are draped over the scene in the 3D view.
    Its frustum is drawn transparent."""
    nx, ny = grid.shape
    (x0, y0), (x1, y1) = grid.bounds
    d = 1.0  # camera height above the receiver plane, metres
    rec.log(
        Entity.COVERAGE,
        rr.Transform3D(
            translation=[(x0 + x1) / 2, (y0 + y1) / 2, grid.height + d],
            mat3x3=np.diag([1.0, -1.0, -1.0]),  # image right = east, image down = south, looking down
        ),
        rr.Pinhole(
            focal_length=d / grid.spacing,
            width=nx,
            height=ny,
            image_plane_distance=d,
            color=(0, 0, 0, 0),
            line_width=0.0,
        ),
        static=True,
    )


def _pattern_cmap():
    """The upper part of inferno (red to pale yellow): even the lobe's faint edge stays visible."""
    import matplotlib
    from matplotlib.colors import ListedColormap

    return ListedColormap(matplotlib.colormaps["inferno"](np.linspace(0.4, 1.0, 256)))


def log_beam_patterns(
    rec: Recording,
    codebook: Codebook,
    tx: np.ndarray,
    length: float,
    step_deg: float = 2.5,
) -> None:
    """Each beam's gain pattern as a 3D lobe around the transmitter at ``world/tx/pattern``,
    one mesh per beam on the ``beam`` timeline.

    The radius in each direction grows linearly with the gain in dB from
    :data:`PATTERN_RANGE_DB` below the codebook's peak (radius 0) to the peak (``length``); the
    colour shows the same gain. Directions far below the peak collapse onto the transmitter and
    are left out of the mesh.

    Parameters
    ----------
    rec : Recording
    codebook : Codebook
    tx : (3,) float
        Transmitter position, metres.
    length : float
        Radius of the peak, metres (about a fifth of the scene keeps lobes readable).
    step_deg : float
        Angular sampling, degrees.
    """
    theta = np.radians(np.arange(0.0, 180.0 + 1e-9, step_deg))
    phi = np.radians(np.arange(-180.0, 180.0, step_deg))
    t, p = np.meshgrid(theta, phi, indexing="ij")  # (nt, np)
    gain = codebook.gain_dbi(t, p)  # (n_beams, nt, np)
    peak = float(np.max(gain))
    floor = peak - PATTERN_RANGE_DB
    frac = np.clip((np.nan_to_num(gain, neginf=floor) - floor) / PATTERN_RANGE_DB, 0.0, 1.0)
    dirs = unit_vector(t, p)  # (nt, np, 3)
    verts = np.asarray(tx, dtype=np.float64) + length * frac[..., None] * dirs  # (n_beams, nt, np, 3)
    # Normals of the surface r(theta, phi): d/dtheta x d/dphi (periodic in phi) points outwards.
    d_t = np.gradient(verts, axis=1)
    d_p = 0.5 * (np.roll(verts, -1, axis=2) - np.roll(verts, 1, axis=2))
    normals = np.cross(d_t, d_p)
    norm = np.linalg.norm(normals, axis=-1, keepdims=True)
    normals = np.where(norm > 1e-9, normals / np.where(norm > 0, norm, 1.0), dirs)
    cmap = _pattern_cmap()
    colours = colorize(gain, cmap, floor, peak)
    nt, n_phi = t.shape
    i, j = np.meshgrid(np.arange(nt - 1), np.arange(n_phi), indexing="ij")
    a, b = i * n_phi + j, (i + 1) * n_phi + j
    c, d = (i + 1) * n_phi + (j + 1) % n_phi, i * n_phi + (j + 1) % n_phi
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    for beam in range(codebook.n_beams):
        lit = frac[beam].ravel()[faces].max(axis=1) > 0
        used, inverse = np.unique(faces[lit], return_inverse=True)
        rec.set_time(Timeline.BEAM, beam)
        rec.log(
            Entity.TX_PATTERN,
            rr.Mesh3D(
                vertex_positions=verts[beam].reshape(-1, 3)[used].astype(np.float32),
                triangle_indices=inverse.reshape(-1, 3).astype(np.uint32),
                vertex_normals=normals[beam].reshape(-1, 3)[used].astype(np.float32),
                vertex_colors=colours[beam].reshape(-1, 3)[used],
            ),
        )
    log_colorbar(
        rec,
        "scene",
        "pattern",
        "beam pattern (beam timeline), dBi",
        cmap,
        floor,
        peak,
        ticks=[f"{floor:.0f}", f"{(floor + peak) / 2:.0f}", f"{peak:.1f}"],
    )
