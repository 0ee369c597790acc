"""Rerun views of traced paths, of the shot candidate rays, of diffracting wedges and of
diffusely scattering tiles."""

from __future__ import annotations

import numpy as np
import rerun as rr

from ..errors import MmwsimError
from ..recording import Entity, Recording, colorize, log_colorbar, log_legend
from .paths import Interaction, PathKind, Paths
from .tracer import Tracer

__all__ = [
    "RAY_CLASSES",
    "log_paths",
    "log_candidates",
    "log_wedges",
    "log_path_context",
    "log_diffuse_tiles",
    "path_classes",
]

# What a path is drawn as: its kind, and among specular reflections its order.
RAY_CLASSES: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("line of sight", (245, 245, 245)),
    ("1 reflection", (60, 200, 80)),
    ("2 reflections", (250, 200, 40)),
    ("3 reflections", (240, 110, 40)),
    ("4+ reflections", (225, 50, 70)),
    ("diffraction", (40, 190, 250)),
    ("diffuse", (190, 90, 230)),
)
_CLASS_COLORS = np.array([c for _, c in RAY_CLASSES], dtype=np.uint8)
_DIFFRACTION, _DIFFUSE = 5, 6
_WEDGE_RGB = (95, 120, 140)
_TILE_CMAP = "plasma"


def path_classes(paths: Paths) -> np.ndarray:
    """(n_paths,) int index into :data:`RAY_CLASSES` of each path.

    Line of sight and specular reflections by order (four and more share one class);
    any path with a diffraction is a diffraction, any ending in diffuse scattering a diffuse one.
    """
    kind = paths.kind()
    out = np.minimum(paths.order.astype(np.int64), 4)
    out[kind == PathKind.DIFFRACTED] = _DIFFRACTION
    out[kind == PathKind.DIFFUSE] = _DIFFUSE
    return out


def log_paths(rec: Recording, paths: Paths, receivers: np.ndarray | None = None) -> int:
    """Paths of chosen receivers as line strips coloured by kind and reflection order (one
    batched call), with their key in the scene legend.

    Labels (receiver, kind, delay, gain) show on hover only: with many strips they would pile up.

    Parameters
    ----------
    rec : Recording
    paths : Paths
    receivers : (n,) int, optional
        Receiver indices to show; all by default.

    Returns
    -------
    int
        Number of strips logged.
    """
    sel = np.ones(paths.n_paths, bool) if receivers is None else np.isin(paths.rx_index, receivers)
    idx = np.flatnonzero(sel)
    if not len(idx):
        return 0
    # Vertices of all strips at once: tx, the interaction points, rx, then split by path.
    k = paths.order[idx].astype(np.int64)
    pts = np.concatenate(
        [
            np.broadcast_to(paths.tx, (len(idx), 1, 3)),
            np.nan_to_num(paths.points[idx]),
            paths.rx[paths.rx_index[idx]][:, None, :],
        ],
        axis=1,
    )  # (n, K + 2, 3); the rows between a path's last point and rx are padding
    keep = np.arange(pts.shape[1])[None, :] <= k[:, None]
    keep[:, -1] = True
    flat = pts[keep].astype(np.float32)
    strips = np.split(flat, np.cumsum(k + 2)[:-1])
    cls = path_classes(paths)[idx]
    gain = paths.gain_db()[idx]
    rec.log(
        Entity.RAY_PATHS,
        rr.LineStrips3D(
            strips,
            colors=_CLASS_COLORS[cls],
            radii=rr.Radius.ui_points(1.5),  # visible at any zoom, above the candidate rays
            labels=[
                f"rx {r}: {RAY_CLASSES[c][0]}, {1e9 * d:.2f} ns, {g:.1f} dB"
                for r, c, d, g in zip(paths.rx_index[idx], cls, paths.delay[idx], gain, strict=True)
            ],
            show_labels=False,
        ),
        static=True,
    )
    present = sorted(set(cls.tolist()))
    log_legend(rec, "scene", "rays", "paths (hover: delay, gain)", [RAY_CLASSES[c] for c in present])
    return len(strips)


def log_candidates(rec: Recording, tracer: Tracer) -> int:
    """An evenly spread sample of the rays shot from the transmitter, as line strips."""
    # Rays that leave the scene were drawn 1 km long; ended where they leave its box instead,
    # so they do not push the scene to a speck in the view.
    lo, hi = tracer.scene.extent
    pad = 0.05 * (hi - lo).max()
    strips = [_clip_last_leg(p, lo - pad, hi + pad).astype(np.float32) for p in tracer.shot.sample]
    if strips:
        rec.log(
            Entity.RAY_CANDIDATES,
            rr.LineStrips3D(strips, colors=[(120, 160, 255, 28)], radii=rr.Radius.ui_points(0.5)),
            static=True,
        )
        log_legend(rec, "scene", "candidates", "search", [("candidate rays (sample)", (120, 160, 255))])
    return len(strips)


def _clip_last_leg(strip: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``strip`` (k, 3) with its last point pulled back to where the last leg leaves the box [lo, hi]."""
    if len(strip) < 2:
        return strip
    a, b = strip[-2], strip[-1]
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        exit_t = np.where(d > 0, (hi - a) / d, np.where(d < 0, (lo - a) / d, np.inf))
    t = float(np.clip(exit_t.min(), 0.0, 1.0))
    out = strip.copy()
    out[-1] = a + t * d
    return out


def log_path_context(rec: Recording, paths: Paths, wedges=None, tx_power_dbm: float = 30.0) -> None:
    """What the recorded ``paths`` interact with beyond faces: the scene's wedges (:func:`log_wedges`),
    those the diffracted paths use highlighted, and the diffuse tiles (:func:`log_diffuse_tiles`)
    with the power each sends to its receiver (isotropic antennas, ``tx_power_dbm``)."""
    if wedges is not None and wedges.count:
        used = np.zeros(wedges.count, bool)
        at = wedges.locate(paths.points[paths.types == Interaction.DIFFRACTION])
        used[at[at >= 0]] = True
        log_wedges(rec, wedges.segments(), used)
    diffuse = np.flatnonzero(paths.kind() == PathKind.DIFFUSE)
    if len(diffuse):
        last = paths.order[diffuse].astype(np.int64) - 1
        power = np.sum(np.abs(paths.jones[diffuse]) ** 2, axis=(1, 2)) / 2.0
        with np.errstate(divide="ignore"):
            dbm = tx_power_dbm + 10.0 * np.log10(power)
        ok = np.isfinite(dbm)
        log_diffuse_tiles(rec, paths.points[diffuse, last][ok], dbm[ok])


def log_wedges(rec: Recording, segments: np.ndarray, used: np.ndarray) -> int:
    """The scene's diffracting edges at ``world/scene/wedges`` (static), the used ones highlighted
    in the colour of diffracted paths.

    Parameters
    ----------
    rec : Recording
    segments : (n, 2, 3) float
        End points of each edge, metres.
    used : (n,) bool
        Edges that some recorded path diffracts at.

    Returns
    -------
    int
        Number of edges logged.
    """
    seg = np.asarray(segments, dtype=np.float64)
    use = np.asarray(used)
    if seg.ndim != 3 or seg.shape[1:] != (2, 3):
        raise MmwsimError(f"wedges: expected segments of shape (n, 2, 3), got {seg.shape}")
    if use.shape != (len(seg),):
        raise MmwsimError(f"wedges: expected {len(seg)} 'used' flags, got shape {use.shape}")
    if not np.isfinite(seg).all():
        raise MmwsimError("wedges: segment end points must be finite")
    if not len(seg):
        return 0
    use = use.astype(bool)
    colours = np.where(use[:, None], _CLASS_COLORS[_DIFFRACTION], np.array(_WEDGE_RGB, dtype=np.uint8))
    rec.log(
        Entity.WEDGES,
        rr.LineStrips3D(
            seg.astype(np.float32),
            colors=colours,
            radii=np.where(use, 0.35, 0.12).astype(np.float32),
            labels=np.where(use, "diffracting edge (used)", "diffracting edge").tolist(),
            show_labels=False,
        ),
        static=True,
    )
    log_legend(
        rec,
        "scene",
        "wedges",
        f"wedges ({int(use.sum())} of {len(seg)} used)",
        [("diffracting edge", _WEDGE_RGB), ("used by a path", RAY_CLASSES[_DIFFRACTION][1])],
    )
    return len(seg)


def log_diffuse_tiles(rec: Recording, centres: np.ndarray, power_dbm: np.ndarray, radius: float = 0.6) -> int:
    """Surface tiles that scatter into a recorded receiver, as points coloured by the power they
    contribute (static), at ``world/rays/diffuse_tiles``, with a colour bar in the scene legend.

    Parameters
    ----------
    rec : Recording
    centres : (n, 3) float
        Tile centres, metres.
    power_dbm : (n,) float
        Power each tile scatters into the receiver, dBm; -inf for none.
    radius : float
        Drawn point radius, metres.

    Returns
    -------
    int
        Number of tiles logged.
    """
    c = np.asarray(centres, dtype=np.float64)
    p = np.asarray(power_dbm, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise MmwsimError(f"diffuse tiles: expected centres of shape (n, 3), got {c.shape}")
    if p.shape != (len(c),):
        raise MmwsimError(f"diffuse tiles: expected {len(c)} powers, got shape {p.shape}")
    if not np.isfinite(c).all() or np.isnan(p).any() or np.isposinf(p).any():
        raise MmwsimError("diffuse tiles: centres must be finite and powers finite or -inf")
    if not len(c):
        return 0
    finite = p[np.isfinite(p)]
    hi = float(np.ceil(finite.max() / 10.0) * 10.0) if len(finite) else 0.0
    lo = hi - 40.0  # four decades of power: weaker tiles share the darkest colour
    rec.log(
        Entity.DIFFUSE_TILES,
        rr.Points3D(
            c.astype(np.float32),
            colors=colorize(p, _TILE_CMAP, lo, hi),
            radii=float(radius),
            labels=[f"{v:.1f} dBm" for v in p],
            show_labels=False,
        ),
        static=True,
    )
    log_colorbar(rec, "scene", "diffuse_tiles", "diffuse tiles, dBm", _TILE_CMAP, lo, hi)
    return len(c)
