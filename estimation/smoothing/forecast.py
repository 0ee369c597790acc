"""Forecasting from tracked positions: the last displacement carried on, along the lanes where the
motion table knows them.

A tracker (``tn-match``, the smoothers) estimates where a user was at every observed step; the
positions after the last one follow from its last displacement (:func:`extrapolate`). Measured on
the demo's data set (2 m grid, 6 dB, ``benchmarks/forecast_tn_match.py``), the plain
constant-velocity forecast beat both the mean change of displacement per speed band that
:class:`~estimation.smoothing.motion.MotionTable` measures (2.21 against 2.09 m one second ahead:
the mean of a speed band mixes users who stop with users who cruise) and slopes fitted over more of
the track (3 steps 2.34 m, 4 steps 2.51 m: users turn). It is differentiable in the tracked
positions, so a network is trained through it.

Users fast enough for the table's place table (vehicles, which keep to lanes) are forecast by
:func:`carry` instead (:func:`forecast_tracks`): particles drawn through the measured accelerations
and weighed by the lanes, read by their geometric median, which, unlike their mean, stays with the
users who drive on rather than between them and the few who stop or turn. Where a street map is
known and such a user drives along one of its streets, :func:`follow_streets` drives its particles
along the centre lines, turning only at junctions, where the table's turns are spread over every
position.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from mmwsim.trajectories import segment_feet

from .motion import RESTART_SHARE

if TYPE_CHECKING:
    from mmwsim.trajectories import StreetNetwork

    from .motion import MotionTable

__all__ = ["carry", "extrapolate", "follow_streets", "forecast_tracks"]

CARRY_PARTICLES = 1024
"""Particles per user of :func:`carry`; 4x as many moved the default data set's forecasts by under
1 % (1000 seen-area test trajectories)."""
_MEDIAN_ITERATIONS = 20  # Weiszfeld steps of the geometric median
STREET_REACH = 4.0
"""Metres: a fast user drives along a street when it is within ``STREET_REACH |cos a|`` of its
centre line, ``a`` the angle between the street and its last displacement (a street's half width,
as the street map keeps it from the buildings, for a user moving along it; none across it); the
others are carried by the motion table."""
STREET_TURN = 2.0
"""Metres a street at right angles to a user's last displacement counts as farther away when the
nearest street is chosen: just round a corner, the displacement still runs along the street the
user left, but the user is on the new one."""
STREET_PARTICLES = 64
"""Particles per user of :func:`follow_streets`: they differ only in their choices at junctions,
drawn stratified, so 16x as many moved the default data set's vehicles' forecasts by 0.01 %."""
_STREET_CHUNK = 256  # users per chunk of the nearest-street search (users x edges arrays)
_MAX_NODES = 64  # junctions one particle may pass in one step (only a degenerate map needs more)


def extrapolate(positions: torch.Tensor, horizon: int) -> torch.Tensor:
    """Positions ``horizon`` steps past the last of ``positions``, at its last velocity.

    Parameters
    ----------
    positions : (B, T, 2) float, metres
        Tracked positions of the observed steps (one step apart); with ``T = 1`` the user is
        taken to stand.
    horizon : int
        Steps to forecast.

    Returns
    -------
    (B, horizon, 2) float, metres
        Step ``h`` is the position ``h`` steps after the last observed one.
    """
    if positions.ndim != 3 or positions.shape[-1] != 2 or positions.shape[1] < 1:
        raise ValueError(f"need positions of shape (B, T >= 1, 2), got {tuple(positions.shape)}")
    last = positions[:, -1:]
    v = last - positions[:, -2:-1] if positions.shape[1] > 1 else torch.zeros_like(last)
    steps = torch.arange(1, int(horizon) + 1, dtype=positions.dtype)[None, :, None]
    return last + steps * v


def _geometric_median(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Weighted geometric median ``(B, 2)`` of points ``x (B, n, 2)`` with weights ``w (B, n)``
    summing to one (Weiszfeld's iteration from the mean)."""
    m = (w[..., None] * x).sum(1)
    for _ in range(_MEDIAN_ITERATIONS):
        inv = w / (x - m[:, None]).norm(dim=-1).clamp(min=1e-6)
        m = (inv[..., None] * x).sum(1) / inv.sum(1, keepdim=True)
    return m


@torch.no_grad()
def carry(
    table: MotionTable, prev: torch.Tensor, last: torch.Tensor, horizon: int, particles: int = CARRY_PARTICLES
) -> torch.Tensor:
    """Where users go after positions ``prev`` and ``last``, by the motion table.

    Every user's particles start at its last displacement; each step draws an acceleration per
    particle from the table (:meth:`MotionTable.accel_sampler`), weighs the new position by the
    place table (:meth:`MotionTable.log_place_ratio`: lanes, for fast users) and resamples. The
    uniform numbers are the same for every user, so a user's forecast does not depend on the
    others in its batch, and the same inputs give the same bytes.

    Parameters
    ----------
    table : MotionTable
        Measured tables, in their own units (the sub-cell table's: grid units).
    prev, last : (B, 2) float
        The last two tracked positions, in the table's units (the place table's frame).
    horizon : int
        Steps to forecast.
    particles : int

    Returns
    -------
    (B, horizon, 2) float64
        The weighted geometric median of the particles at every step, in the table's units.
    """
    prev, last = prev.double(), last.double()
    B, n = len(last), int(particles)
    gen = torch.Generator().manual_seed(0)
    # stratified: one number in each of n equal slices of [0, 1), in a fixed shuffled order per step
    draws = [
        (torch.randperm(n, generator=gen) + torch.rand(n, generator=gen, dtype=torch.float64)) / n
        for _ in range(int(horizon))
    ]
    spokes = (torch.arange(n, dtype=torch.float64) + 0.5) / n  # systematic resampling
    v = (last - prev)[:, None].expand(B, n, 2)
    x = last[:, None].expand(B, n, 2)
    draw = table.accel_sampler()
    out = []
    for h in range(int(horizon)):
        v = v + draw(v, draws[h].expand(B, n))
        # float noise must not take a user moving along an axis into the next quarter's frame
        v = torch.where(v.abs() < 1e-9, 0.0, v)
        x = x + v
        w = torch.softmax(table.log_place_ratio(v, x).double(), dim=1)
        out.append(_geometric_median(x, w))
        idx = torch.searchsorted(w.cumsum(1), spokes.expand(B, n).contiguous()).clamp(max=n - 1)[..., None]
        v, x = v.gather(1, idx.expand(B, n, 2)), x.gather(1, idx.expand(B, n, 2))
    return torch.stack(out, 1) if out else torch.zeros(B, 0, 2, dtype=torch.float64)


def _nearest_streets(
    net: StreetNetwork, x: np.ndarray, d: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For points ``x (B, 2)`` moving by ``d (B, 2)``: the nearest edge, its distance made
    :data:`STREET_TURN` metres larger per unit of ``1 - |cos|`` of its angle to the motion; the
    share along it of the point's foot; whether the motion runs from its first node to its second;
    and whether the point drives along it (see :data:`STREET_REACH`)."""
    a, b = net.nodes[net.edges[:, 0]], net.nodes[net.edges[:, 1]]
    ab = b - a
    n2 = (ab**2).sum(-1)
    out = []
    for lo in range(0, len(x), _STREET_CHUNK):
        ds = d[lo : lo + _STREET_CHUNK, None]
        t, dist = segment_feet(x[lo : lo + _STREET_CHUNK], a, ab)
        cos = (ds * ab).sum(-1) / np.maximum(np.linalg.norm(ds, axis=-1) * np.sqrt(n2), 1e-18)
        k = np.argmin(dist + STREET_TURN * (1.0 - np.abs(cos)), axis=1)
        r = np.arange(len(k))
        c = cos[r, k]
        out.append((k, t[r, k], c > 0, dist[r, k] < STREET_REACH * np.abs(c)))
    return tuple(np.concatenate(o) for o in zip(*out, strict=True))  # type: ignore[return-value]


def _way_round(
    net: StreetNetwork, came: np.ndarray, edge: np.ndarray, prev: np.ndarray, last: np.ndarray
) -> np.ndarray:
    """Length ``(B,)`` metres of the move from ``prev`` on edge ``came`` to ``last`` on edge
    ``edge``: through the node the two edges share where they differ and share one, else (and
    never less than) the straight line."""
    chord = np.linalg.norm(last - prev, axis=1)
    a0, b0 = net.edges[came].T
    a1, b1 = net.edges[edge].T
    node = np.where((a0 == a1) | (a0 == b1), a0, np.where((b0 == a1) | (b0 == b1), b0, -1))
    node = np.where(came == edge, -1, node)
    at = net.nodes[np.maximum(node, 0)]
    way = np.linalg.norm(prev - at, axis=1) + np.linalg.norm(last - at, axis=1)
    return np.where(node >= 0, np.maximum(way, chord), chord)


def follow_streets(
    net: StreetNetwork, prev: np.ndarray, last: np.ndarray, horizon: int, particles: int = STREET_PARTICLES
) -> tuple[np.ndarray, np.ndarray]:
    """Where users driving along the streets go after positions ``prev`` and ``last``.

    Each user is put on the nearest centre line it is driving along (within
    :data:`STREET_REACH` metres, less as its last displacement turns away from the street; round a
    corner, see :data:`STREET_TURN`), in the direction of that displacement, at the same signed
    distance to its right or left (a driver keeps to a lane). Its particles keep its last
    displacement's length per step (round the node, where it and the position before lie on
    streets that meet) along the centre lines and take, at every junction, each onward street with
    equal probability (:meth:`StreetNetwork.onward`): the street map is the scene's, the choice the
    one no data tell apart.
    The uniform numbers are the same for every user, so a user's forecast does not depend on the
    others in its batch.

    Parameters
    ----------
    net : mmwsim.trajectories.StreetNetwork
        Centre lines, metres.
    prev, last : (B, 2) float
        The last two tracked positions, metres.
    horizon : int
        Steps to forecast.
    particles : int

    Returns
    -------
    forecast : (B, horizon, 2) float64
        The particles' geometric median at every step, metres (the last position where ``on`` is
        False).
    on : (B,) bool
        Users driving along a street, forecast along it.
    """
    prev, last = np.asarray(prev, dtype=np.float64), np.asarray(last, dtype=np.float64)
    B, n, H = len(last), int(particles), int(horizon)
    out = np.repeat(last[:, None], H, axis=1)
    if B == 0 or H == 0:
        return out, np.zeros(B, dtype=bool)
    d = last - prev
    edge, share, forward, on = _nearest_streets(net, last, d)  # never on for d = 0 (cos 0)
    if not on.any():
        return out, on
    # Round a corner (or a bend of the centre line) the last displacement is a chord: the speed is
    # the way round the node the two positions' streets share.
    came = _nearest_streets(net, prev[on], d[on])[0]
    speed = _way_round(net, came, edge[on], prev[on], last[on])
    e = net.edges[edge[on]]
    frm = np.where(forward[on], e[:, 0], e[:, 1])
    to = np.where(forward[on], e[:, 1], e[:, 0])
    length = net.edge_length[edge[on]]
    rem = np.where(forward[on], 1.0 - share[on], share[on]) * length
    nodes = net.nodes
    u = (nodes[to] - nodes[frm]) / np.maximum(length, 1e-12)[:, None]
    # signed distance to the left of the direction of travel, kept on every street after
    w = last[on] - nodes[frm]
    side = u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]
    m = int(on.sum())
    frm, to, rem = (np.repeat(a, n) for a in (frm, to, rem))
    speed, side = np.repeat(speed, n), np.repeat(side, n)
    steps = []
    for h in range(H):
        go = speed.copy()
        for j in range(_MAX_NODES):
            over = np.flatnonzero(go > rem)
            if not len(over):
                break
            # stratified: each onward street gets its share of every user's particles
            g = np.random.default_rng([h, j])
            draw = ((g.permutation(n) + g.random(n)) / n)[over % n]
            c = to[over]
            nxt = net.onward(c, frm[over], draw)
            go[over] -= rem[over]
            frm[over], to[over] = c, nxt
            rem[over] = np.linalg.norm(nodes[nxt] - nodes[c], axis=1)
        rem = np.maximum(rem - go, 0.0)
        span = nodes[to] - nodes[frm]
        along = span / np.maximum(np.linalg.norm(span, axis=1), 1e-12)[:, None]
        pos = nodes[to] - rem[:, None] * along + side[:, None] * np.stack([-along[:, 1], along[:, 0]], -1)
        steps.append(pos.reshape(m, n, 2))
    # the geometric median, as carry's: 1.9 % below the mean on the seen area's vehicles, the same
    # held out (forecast from tn-match's tracks, docs/estimation.md)
    clouds = torch.from_numpy(np.stack(steps, axis=1).reshape(m * H, n, 2))
    median = _geometric_median(clouds, torch.full((m * H, n), 1.0 / n, dtype=torch.float64))
    out[on] = median.numpy().reshape(m, H, 2)
    return out, on


def forecast_tracks(
    tracked: torch.Tensor,
    horizon: int,
    table: MotionTable,
    spacing: float,
    streets: StreetNetwork | None = None,
) -> torch.Tensor:
    """The forecast of tracked users: users faster than the table's place table's speed along the
    ``streets`` where they drive along one (:func:`follow_streets`), else by :func:`carry` through
    ``table``; :func:`extrapolate` for the others (and for all where the table has no place table,
    or only one step was tracked).

    Parameters
    ----------
    tracked : (B, T, 2) float, metres
    horizon : int
    table : MotionTable
        The sub-cell table (grid units), with the lanes the tracker uses.
    spacing : float
        The grid's spacing, metres (one grid unit).
    streets : mmwsim.trajectories.StreetNetwork, optional
        The street map the tracker's lanes come from, metres.

    Returns
    -------
    (B, horizon, 2), ``tracked``'s dtype, metres
    """
    out = extrapolate(tracked, horizon)
    if tracked.shape[1] < 2 or not table.has_place:
        return out
    step = (tracked[:, -1] - tracked[:, -2]).double().norm(dim=-1) / spacing
    fast = step > float(table.place_speed)
    if streets is not None and tracked.shape[1] >= 3 and float(table.restart_step) > 0:
        # Fast users who have just stopped do what the training users did next: drive on along
        # their street at the measured length (where the measured one is zero they stay).
        before = (tracked[:, -2] - tracked[:, -3]).double()
        gone = before.norm(dim=-1) / spacing
        stopped = torch.nonzero(
            (gone > float(table.place_speed)) & (step < RESTART_SHARE * float(table.place_speed))
        ).flatten()
        if len(stopped):
            last = tracked[stopped, -1].double().numpy()
            way = (before[stopped] / gone[stopped, None]).numpy() * float(table.restart_step)
            along, on = follow_streets(streets, last - way, last, horizon)
            out[stopped[on]] = torch.from_numpy(along[on]).to(out.dtype)
    rows = torch.nonzero(fast).flatten()
    if len(rows) and streets is not None:
        last2 = tracked[rows, -2:].double().numpy()
        along, on = follow_streets(streets, last2[:, 0], last2[:, 1], horizon)
        out[rows[on]] = torch.from_numpy(along[on]).to(out.dtype)
        rows = rows[~torch.from_numpy(on)]
    if len(rows):
        grid = tracked[rows].double() / spacing
        out[rows] = (carry(table, grid[:, -2], grid[:, -1], horizon) * spacing).to(out.dtype)
    return out
