"""Tracks of drivers smoothed along the street route they drive.

The hidden-Markov smoother scores each step's acceleration on a lattice, so a vehicle that holds a
speed along a street and round its corners is read as one that keeps changing speed and heading
wherever the lattice and the corner's chord do not line up. A driver on a known street map has
two degrees of freedom instead: how far along its route it is, and how fast it goes. So for a
tracked user faster than the place table's speed whose every tracked position lies on the map's
streets, :func:`route_track` builds the route through the streets it was tracked on and runs a
forward-backward pass over (arc length, speed) on a fine grid along that route: the speed is
kept from step to step or, with the measured probability of a change, drawn again from the
measured speeds; each step weighs its arc lengths by the fingerprint likelihood of the candidate
grid point there. The track is the posterior mean position at every step, mixed per user with
the pass of drivers who keep speeds of their own (any speed at first, changed by the
differences between the measured speeds) by how well each explains its steps. Routes turn back
at dead ends, as the street network's drivers do there. A track that keeps to one side of its
route's centre line is a driver in a lane: it is smoothed along lines beside the centre line, as
far to that side as the track and nearer and farther, each weighed by how well it explains the
steps. A driver whose first or last step the smoother lost, a few metres along the street, is
weighed again with wider windows at those steps and relocated where that moves one; one whose end
step it carried straight on through a junction is weighed along each other street leaving it too.
A route track is kept only where it moves no position far from the smoother's track
(:data:`ROUTE_GATE`) and its steps' grid points are not much less likely than the track's
(:data:`ROUTE_EVIDENCE`): a user who passes near a street without driving along it keeps the
smoother's track.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from mmwsim._threads import batch_map

if TYPE_CHECKING:
    from mmwsim.trajectories import StreetNetwork

__all__ = ["ROUTE_BINS", "route_track", "speed_changes", "street_routes"]

ROUTE_BINS = 20
"""Bins of the arc length (and of the speed per step) per grid spacing: 5 cm on a 1 m grid."""
ROUTE_WINDOW = 2.5
"""Grid spacings either side of a tracked position's arc length that the pass weighs."""
ROUTE_END_WINDOW = 6.0
"""Grid spacings either side of the first and the last tracked position that a second pass weighs
(:func:`_relocate_ends`). On `runs/tnm8` (`default.zarr`, 6 dB), the first 1000 vehicles of each
split, three draws, against one pass: seen area -4.4 / -5.0 / -4.1 % at 4 / 6 / 8 spacings, held
out -0.9 / -0.8 / -0.4 %. The kernels' cost grows with the window, so the second pass is only
for drivers :data:`ROUTE_END_GAP` picks."""
ROUTE_END_GAP = 3.0
"""Log-likelihood: the second pass weighs only the drivers with a position in an end step's wider
window no more than this less likely than the likeliest within its window. On the draws above
every driver it relocated had one within 1.3; at 3 it weighs 15 % of them, with the same tracks
as weighing all."""
ROUTE_RELOCATE = 1.0
"""Grid spacings: the second pass's track is taken where it moves the first or the last position
farther than this from the first pass's. Taken for every driver, 96 of the 1000 held-out ones
ended more than 1 cm worse against 27 better (aliases in the wider window pull the mean); on the
draws above, 0.5 / 1 / 2 spacings gave -6.2 / -6.2 / -3.9 % seen and -0.8 / -1.2 / -1.8 % held
out."""
ROUTE_REACH = 4.0
"""Metres: every tracked position of a user smoothed along a route lies this near a street. A
driver's first or last tracked step (one side's evidence only) can stray 3 to 4 m off it. On one
`default.zarr` network (`runs/tnm8d`, 6 dB, 7 steps), 3 m against 4 m: our seen-area vehicles
0.1066 / 0.0991 m (1000), held out 0.1152 / 0.1118 m (1000); `foreign_motion.py` (300 each)
`lanes` vehicles 0.7058 / 0.7011, ours at 7.5 m/s 0.2772 / 0.2682, and the vehicles off the
streets `smooth` 0.8558 / 0.8632, `events` 0.8694 / 0.8714. 5 m and more: ours 0.0991, `lanes`
0.6918, `smooth` and `events` 0.88 and 0.89."""
ROUTE_EXTEND = 20.0
"""Metres the route runs on straight past the first and the last street it was tracked on."""
ROUTE_FLOOR = 0.01
"""Share of a flat density over all speeds up to :data:`ROUTE_FASTER` times the fastest measured
in the speed prior, for drivers who change to a speed the training users did not keep (drivers
who keep speeds of their own are :data:`ROUTE_OTHER`'s). On one `default.zarr` network, vehicles
seen / held out: 0.1124 / 0.1107 m at 0.1, 0.1092 / 0.1065 at 0.01, 0.1090 / 0.1062 at 0.003; ours
at 7.5 and 9.5 m/s 0.279 and 0.234 m at 0.1, 0.277 and 0.231 at 0.01."""
ROUTE_FASTER = 1.5
"""The speeds the pass weighs reach this many times the fastest measured one."""
ROUTE_OTHER = 0.2
"""Prior probability that a user drives at speeds of its own: each user's track is the posterior
over the measured speeds and over speeds of its own (:data:`ROUTE_REDRAW`), weighed by how well
each explains its steps (measured with the second version's chord speeds and flat share of 0.1:
our own vehicles at 7.5 and 9.5 m/s instead of 8.3 0.2948 and 0.2782 m without, 0.2867 and
0.2455 m with; ours at their own speeds 0.1215 and 0.1225 m on the seen area)."""
ROUTE_REDRAW = 0.3
"""Share of the speed changes of a driver at speeds of its own that draw any speed (a stop, a
start, a change unlike the training drivers'); the others change its speed by a difference
between two measured speeds (:func:`speed_changes`), as the training drivers change theirs. Our
street vehicles at 6 / 7.5 / 9.5 / 12 m/s instead of 8.3 (`benchmarks/foreign_motion.py`'s, 500
each, 6 dB) on an 8-minute `default.zarr` network: 0.324 / 0.271 / 0.236 / 0.306 m with any speed
drawn at every change (share 1), 0.310 / 0.245 / 0.203 / 0.284 m with this share (0.1 and 0.5
within 0.003 m); our own vehicles 0.096 m (held out 0.118 m) either way. On the demo's model (2 m
grid, 300 each): 0.587 / 0.538 / 0.424 / 0.504 m against 0.560 / 0.513 / 0.393 / 0.471 m, our
own 0.163 / 0.164 m (held out 0.196 / 0.200 m)."""
ROUTE_CHANGES = 0.2
"""Speed differences less likely than this share of the likeliest are left to
:data:`ROUTE_REDRAW`'s draws. Our drivers change by 3 m/s at a time: at 0.2 those two differences
are kept (of the 10 above 0.01, which track alike to 0.004 m on the demo), and the route pass
takes 0.39 to 0.41 s per 1000 seven-step sequences on `default.zarr` against 0.44 to 0.49 s for
the ten (this kernel's calls 0.27 to 0.28 s against 0.35 to 0.37 s)."""
ROUTE_DETOUR = 60.0
"""Metres: the longest way between two streets a track passes that the route fills in."""
ROUTE_GATE = 4.0
"""Metres a position may move from the smoother's track; a route track that moves one farther is
not kept (a route that does not fit the driver: one tracked onto the wrong street). On one
`default.zarr` network no gate and 4 m are alike (seen-area vehicles 0.1225 m), 1.5 m gives back
an eighth of the gain (0.1391 m); on the demo's held-out street one wrong route is 9.4 m off without
a gate."""
ROUTE_EVIDENCE = 20.0
"""Nats: a route track whose steps' grid points are this much less likely, summed over the steps,
than the smoother's track's (each step's candidate nearest it, :func:`_candidate_loglik`) is
not kept. A user off the streets whose track passes within :data:`ROUTE_REACH` of one for seven
steps (the `events` and `smooth` vehicles of `benchmarks/foreign_motion.py`, 2 to 3 % of them) was
put on the street, where its fingerprints do not place it: those users went from 2.0 to 2.8 and
3.1 m (two draws). On `runs/tn-match-tracking` of the README (1000 per set, 6 dB, 7 steps), no
gate / 40 / 20 / 10 / 5 nats: `smooth` vehicles 0.951 / 0.926 / 0.923 / 0.920 / 0.920 m, `events` vehicles (two draws)
0.814 and 0.799 / 0.797 and 0.788 / 0.792 and 0.783 / 0.792 and 0.781 / 0.792 and 0.778 m,
`lanes` (two draws) 0.674 and 0.695 / 0.657 and 0.669 / 0.626 and 0.636 / 0.627 and 0.631 /
0.628 and 0.635 m; our own seen-area and held-out vehicles 0.0805 and 0.1057 m down to 20 nats,
0.0809 and 0.1057 at 10, 0.0812 and 0.1091 at 5; ours at 7.5 m/s 0.2228 m down to 40 nats, 0.2239
at 20, 0.2304 at 5."""
ROUTE_SIDE = 0.3
"""Grid spacings: a track whose mean signed distance from its route's centre line is larger
keeps to a lane beside it, and is smoothed along lines beside the centre line
(:data:`ROUTE_LANES`). The smoother's tracks of lane drivers lie nearer the centre line than
they do, as the map's lanes pull them: at 0.3 instead of 0.5, `benchmarks/foreign_motion.py`'s
`lanes` vehicles (1 to 2.5 m right of the centre line) go from 1.106 to 1.001 m on the demo's
model (2 m grid, 500) and from 0.708 to 0.696 m on an 8-minute `default.zarr` network (1000),
our own vehicles unchanged (demo 0.164 / 0.200 m seen / held out, `default.zarr` 0.094 / 0.116
to 0.117 m); at 0.25 the demo's `lanes` 0.949 m (300) but our own 0.098 m on `default.zarr`
(500, 0.096 at 0.5); at 0.15 our own demo vehicles 0.187 m (300, 0.164)."""
ROUTE_LANES = np.linspace(-0.8, 0.8, 9)
"""Grid spacings from a lane driver's mean distance to its route's centre line: the lines along
which its track is weighed (each by how well it explains the steps)."""
ROUTE_BRANCHES = True
"""Whether a driver's route is also weighed leaving by each other street at a junction that its
first or its last two steps may pass (:func:`_end_branches`), each such route weighed as its own line.
The smoother's track of a driver who turned at a junction in its last step (or had turned into its
street in its first) often runs on straight through it, and the route built from that track then
misses the street the driver is on. On `pt67`'s network (`default.zarr`, 6 dB, 7 steps, the first
1000 vehicles of each split, three draws; with end steps off the streets routed by the others,
:func:`_street_nodes`): seen area -4.3 to -6.4 %, held out -0.9 to -2.9 %, validation -1.7 to
-2.8 %. The route pass then takes 2.0 to 2.5 s per 1000 vehicles instead of 1.1 to 1.4 s (the
same draws, 2 threads)."""
_CHUNK = 64  # users per pass (chunk x steps x window positions and likelihoods)
_BACK = 10.0  # cost per metre a track's arc length runs back (beyond the slack), in metres of distance
_BACK_SLACK = 0.2  # typical steps an arc length may run back unpunished (a stopped user's jitter)
_NEAR = 1.0  # metres farther than its nearest piece of the route a position may be put on
_TIE = 0.01  # cost per metre an arc length's growth differs from the typical step: breaks ties only
_MITRE_COS = -0.5  # corners sharper than 120 degrees are joined by a cross-over, not mitred
_TIE_BAND = 1e-6  # grid spacings from halfway between grid points that count as halfway


def _route_nodes(net: StreetNetwork, seq: list[int], track: np.ndarray) -> list[int] | None:
    """Nodes of the route through the edges ``seq`` (in the order the track meets them)."""
    E = net.edges
    a, b = (int(x) for x in E[seq[0]])
    if len(seq) == 1:
        if (track[-1] - track[0]) @ (net.nodes[b] - net.nodes[a]) < 0:
            a, b = b, a
        return [a, b]

    def ways(node: int) -> tuple[np.ndarray, np.ndarray]:
        return net.ways_from(node, ROUTE_DETOUR)  # the network keeps its last results

    if ways(a)[0][E[seq[1]]].min() < ways(b)[0][E[seq[1]]].min():  # leave by the end nearer the next
        a, b = b, a
    nodes = [a, b]
    for x in seq[1:]:
        c = nodes[-1]
        dist, pred = ways(c)
        p, q = (int(y) for y in E[x])
        if dist[p] > dist[q]:
            p, q = q, p
        if not dist[p] <= ROUTE_DETOUR:
            return None
        way = []
        while p != c:
            way.append(p)
            p = int(pred[p])
        nodes += way[::-1] + [q]
    i = 0
    while i + 2 < len(nodes):  # a street touched at a junction is no detour: x, y, x -> x
        # nor is a dead end the track never came near: a driver turns at one only where it came
        # within ROUTE_EXTEND of it, as at the route's ends
        if nodes[i] == nodes[i + 2] and (
            net.degree[nodes[i + 1]] != 1
            or np.linalg.norm(track - net.nodes[nodes[i + 1]], axis=1).min() >= ROUTE_EXTEND
        ):
            del nodes[i + 1 : i + 3]
            i = max(i - 1, 0)
        else:
            i += 1
    return nodes if len(nodes) >= 2 and len(set(nodes)) == len(nodes) - _folds(net, nodes) else None


def _folds(net: StreetNetwork, nodes: list[int]) -> int:
    """How often the route ``nodes`` turns back at a dead end (x, dead end, x)."""
    return sum(nodes[i] == nodes[i + 2] and net.degree[nodes[i + 1]] == 1 for i in range(len(nodes) - 2))


def _turn_at_dead_ends(net: StreetNetwork, nodes: list[int], track: np.ndarray) -> list[int]:
    """``nodes`` turned back at a dead end it starts or ends at that the track comes within
    :data:`ROUTE_EXTEND` of, as the street network's drivers do at a dead end."""
    near = [np.linalg.norm(track - net.nodes[nodes[k]], axis=1).min() < ROUTE_EXTEND for k in (0, -1)]
    if net.degree[nodes[-1]] == 1 and near[1]:
        nodes = nodes + [nodes[-2]]
    if net.degree[nodes[0]] == 1 and near[0]:
        nodes = [nodes[1]] + nodes
    return nodes


def street_routes(
    net: StreetNetwork, tracks: np.ndarray, reach: float = ROUTE_REACH
) -> list[np.ndarray | None]:
    """The route each track drives along the street map, or None where it leaves the streets.

    Parameters
    ----------
    net : mmwsim.trajectories.StreetNetwork
    tracks : (B, T, 2) float, metres
    reach : float
        Metres every tracked position must lie from a street.

    Returns
    -------
    list of B ``(R, 2)`` float64 route vertices in metres (the streets' nodes in the order the
    track drives them, turning back at a dead end that the track comes within
    :data:`ROUTE_EXTEND` of, as the network's drivers do there; the
    first and last pieces run on straight by :data:`ROUTE_EXTEND`), or None where a position is
    farther than ``reach`` from every street, the streets it passes are not joined within
    :data:`ROUTE_DETOUR`, or the route would pass a node twice other than at a dead end (a U-turn
    on a street).
    """
    return [None if n is None else _vertices(net, n) for n in _street_nodes(net, tracks, reach)[0]]


def _street_nodes(
    net: StreetNetwork, tracks: np.ndarray, reach: float = ROUTE_REACH
) -> tuple[list[list[int] | None], np.ndarray]:
    """The nodes of each track's route (see :func:`street_routes`), or None; and ``(B, 2)``
    whether its first and last step were left out of it.

    A track whose first or last position alone lies farther than ``reach`` from every street
    (the smoother lost that end step: one side's evidence only) gets the route of its other
    positions, along which the route pass weighs the lost step too. On the draws of
    :data:`ROUTE_BRANCHES`, with no branches, seen area -0.8, 0 and -3.0 %, held out 0 %,
    validation 0, 0 and -1.9 %."""
    tracks = np.asarray(tracks, dtype=np.float64)
    edge, dist = net.nearest_edges(tracks)
    T = tracks.shape[1]
    lost = dist[:, [0, -1]] > reach if T > 3 else np.zeros((len(tracks), 2), dtype=bool)
    out: list[list[int] | None] = []
    # One route per user: a few graph steps each, from the edges the vectorised search found.
    for b in range(len(tracks)):
        lo, hi = int(lost[b, 0]), T - int(lost[b, 1])
        if not dist[b, lo:hi].max() <= reach:
            out.append(None)
            continue
        e = edge[b, lo:hi]
        seq = [int(e[0])] + [int(x) for x, y in zip(e[1:], e[:-1], strict=True) if x != y]
        nodes = _route_nodes(net, seq, tracks[b, lo:hi])
        out.append(None if nodes is None else _turn_at_dead_ends(net, nodes, tracks[b, lo:hi]))
    return out, lost


def _vertices(net: StreetNetwork, nodes: list[int]) -> np.ndarray:
    """The route's vertices ``(R, 2)`` metres through ``nodes``, run on straight by
    :data:`ROUTE_EXTEND` past both ends."""
    P = net.nodes[nodes]
    ends = P[[0, -1]] - P[[1, -2]]
    ends /= np.linalg.norm(ends, axis=1, keepdims=True)
    return np.vstack([P[0] + ROUTE_EXTEND * ends[0], P, P[-1] + ROUTE_EXTEND * ends[1]])


def _end_branches(net: StreetNetwork, nodes: list[int], arc: np.ndarray, reach: float) -> list[list[int]]:
    """Routes that leave the route ``nodes`` by another street at a junction that the track's
    first or last two steps may pass (:data:`ROUTE_BRANCHES`).

    ``arc (T,)`` are the track's arc lengths along :func:`_vertices` of ``nodes``; a junction
    counts for the last steps where its arc length lies after the third last step's and at most
    ``reach`` metres past the last step's (for the first steps alike, mirrored). Each such
    junction gives one route per street that leaves it other than the route's own two: the route
    up to the junction and on along that street (or that street and on from the junction), as
    the network's drivers take any onward street at a junction with equal probability."""
    if len(arc) < 3:
        return []
    P = net.nodes[nodes]
    at = np.concatenate(
        [[ROUTE_EXTEND], ROUTE_EXTEND + np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]
    )
    out = []
    for j, node in enumerate(nodes):
        late = arc[-3] < at[j] <= arc[-1] + reach
        early = arc[0] - reach <= at[j] < arc[2]
        if not (late or early):
            continue
        own = {nodes[k] for k in (j - 1, j + 1) if 0 <= k < len(nodes)}
        for m in net.neighbours[node]:
            m = int(m)
            if m < 0 or m in own:
                continue
            ways = ([[*nodes[: j + 1], m]] if late else []) + ([[m, *nodes[j:]]] if early else [])
            # a branch onto a street the route already drives is a loop: not a driver's way
            out += [alt for alt in ways if len(set(alt)) == len(alt) - _folds(net, alt)]
    return out


def _along(route: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Positions ``(..., 2)`` at arc lengths ``s (...)`` along ``route (R, 2)`` (run on straight
    past its ends)."""
    s = np.asarray(s, dtype=np.float64)
    return _along_flat(np.ascontiguousarray(route, dtype=np.float64), s.ravel()).reshape(*s.shape, 2)


@numba.njit(cache=True, nogil=True)
def _along_flat(route: np.ndarray, s: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`_along` of a flat ``s (n,)``: compiled, as it runs once per line weighed."""
    R = route.shape[0]
    arc = np.zeros(R)
    for r in range(1, R):
        arc[r] = arc[r - 1] + np.hypot(route[r, 0] - route[r - 1, 0], route[r, 1] - route[r - 1, 1])
    out = np.empty((len(s), 2))
    for n in range(len(s)):
        i = min(max(np.searchsorted(arc, s[n], side="right") - 1, 0), R - 2)
        f = (s[n] - arc[i]) / max(arc[i + 1] - arc[i], 1e-12)
        for c in range(2):
            out[n, c] = route[i, c] + f * (route[i + 1, c] - route[i, c])
    return out


def _offset(route: np.ndarray, left: float) -> np.ndarray:
    """The line ``left`` metres to the left of ``route (R, 2)`` (right where negative), as its
    vertices ``(R', 2)``: corners mitred, and where the route turns back (or nearly), the two
    pieces' ends joined, as a driver in a lane crosses over to the other."""
    if left == 0.0:
        return route
    u = np.diff(route, axis=0)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    n = np.stack([-u[:, 1], u[:, 0]], axis=1)  # each piece's left normal
    a, b, corner = n[:-1], n[1:], route[1:-1]
    cos = (a * b).sum(1)
    sharp = cos <= _MITRE_COS
    mitre = corner + left * (a + b) / np.where(sharp, 1.0, 1.0 + cos)[:, None]
    # each corner's one mitred vertex, or the two ends of its pieces where it is sharp
    pair = np.where(sharp[:, None, None], np.stack([corner + left * a, corner + left * b], 1), mitre[:, None])
    inner = pair[np.stack([np.ones_like(sharp), sharp], 1)]
    return np.vstack([route[0] + left * n[0], inner, route[-1] + left * n[-1]])


def _arc_of(route: np.ndarray, x: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Arc length along ``route (R, 2)`` of each ``x (T, 2)`` of a track, and the signed distance
    of ``x`` to the left of the route there.

    Each position is put on its nearest piece of the route, or one as near within :data:`_NEAR`:
    where the route turns back at a dead end, both legs are as near, and the piece that keeps the
    arc length growing by about the track's typical ``step`` (metres) is taken (a Viterbi pass
    over the pieces, :func:`_pieces`).
    """
    route = np.ascontiguousarray(route, dtype=np.float64)
    return _arc_kernel(route, np.ascontiguousarray(x, dtype=np.float64), float(step))


@numba.njit(cache=True, nogil=True)
def _arc_kernel(
    route: np.ndarray, x: np.ndarray, step: float
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """:func:`_arc_of`, compiled: it runs once per line weighed (the feet on every piece as
    :func:`mmwsim.trajectories.segment_feet` finds them, operation for operation)."""
    P, T = len(route) - 1, len(x)
    ab = np.empty((P, 2))
    length, start = np.empty(P), np.empty(P)
    done = 0.0
    for p in range(P):
        ab[p, 0], ab[p, 1] = route[p + 1, 0] - route[p, 0], route[p + 1, 1] - route[p, 1]
        length[p] = np.sqrt(ab[p, 0] * ab[p, 0] + ab[p, 1] * ab[p, 1])
        start[p] = done
        done += length[p]
    arc, d = np.empty((T, P)), np.empty((T, P))
    for k in range(T):
        nearest = np.inf
        for p in range(P):
            wx, wy = x[k, 0] - route[p, 0], x[k, 1] - route[p, 1]
            t = (wx * ab[p, 0] + wy * ab[p, 1]) / max(ab[p, 0] * ab[p, 0] + ab[p, 1] * ab[p, 1], 1e-18)
            t = min(max(t, 0.0), 1.0)
            fx, fy = x[k, 0] - (route[p, 0] + t * ab[p, 0]), x[k, 1] - (route[p, 1] + t * ab[p, 1])
            d[k, p] = np.sqrt(fx * fx + fy * fy)
            arc[k, p] = start[p] + t * length[p]
            nearest = min(nearest, d[k, p])
        for p in range(P):  # only the pieces it lies on
            if not d[k, p] <= nearest + _NEAR:
                d[k, p] = np.inf
    piece = _pieces(arc, d, step)
    along, side = np.empty(T), np.empty(T)
    for k in range(T):
        i = piece[k]
        wx, wy = x[k, 0] - route[i, 0], x[k, 1] - route[i, 1]
        n = max(length[i], 1e-12)
        along[k] = arc[k, i]
        side[k] = ab[i, 0] / n * wy - ab[i, 1] / n * wx
    return along, side


@numba.njit(cache=True, nogil=True)
def _pieces(arc: np.ndarray, dist: np.ndarray, step: float) -> np.ndarray:  # pragma: no cover - compiled
    """The piece ``(T,)`` each step of :func:`_arc_of` goes on, from the arc lengths ``(T, P)``
    of its feet on every piece and its distances ``(T, P)`` to them (inf: not on that piece).
    Compiled, as it runs once per line weighed; ties go to the first piece."""
    T, P = arc.shape
    cost, nxt = dist[0].copy(), np.empty(P)
    came = np.zeros((T, P), dtype=np.int64)
    for k in range(1, T):
        for to in range(P):
            best, arg = np.inf, 0
            for p in range(P):
                move = arc[k, to] - arc[k - 1, p]
                c = cost[p] + _BACK * max(-move - _BACK_SLACK * step, 0.0) + _TIE * abs(move - step)
                if c < best:
                    best, arg = c, p
            came[k, to], nxt[to] = arg, best + dist[k, to]
        cost[:] = nxt
    piece = np.empty(T, dtype=np.int64)
    piece[T - 1] = np.argmin(cost)
    for k in range(T - 1, 0, -1):
        piece[k - 1] = came[k, piece[k]]
    return piece


def _candidate_loglik(xy: np.ndarray, lp: np.ndarray, pos: np.ndarray, spacing: float) -> np.ndarray:
    """Log-likelihood of the grid points nearest ``pos (n, T, S, 2)`` from each step's candidates
    ``xy (n, T, K, 2)`` with ``lp (n, T, K)``; a point that is no candidate gets its step's
    lowest candidate's (the candidates are a step's most likely points). A position halfway
    between grid points (a street between two rows of receivers) gets the likelier of them: which
    one a user there reads is the grid's rounding, not the street's."""
    ref = xy.reshape(-1, 2)[0]  # any candidate is one of the grid's points
    cand = np.rint((xy - ref) / spacing).astype(np.int64)
    u = (pos - ref) / spacing
    near = np.stack([np.floor(u + 0.5 - _TIE_BAND), np.floor(u + 0.5 + _TIE_BAND)]).astype(np.int64)
    return _lookup(cand, np.asarray(lp, np.float64), near)


@numba.njit(cache=True, nogil=True)
def _lookup(cand: np.ndarray, lp: np.ndarray, near: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`_candidate_loglik`'s search, per step: the candidates' grid indices ``cand (n, T,
    K, 2)`` sorted once (stably: of a point listed twice, the first), then each of the grid
    points ``near (2, n, T, S, 2)`` (the rows and columns either side of a halfway position)
    found by bisection. Compiled: numpy's sort and search over the whole block cost a fifth of
    the route pass."""
    n, T, K = lp.shape
    S = near.shape[3]
    best = np.empty((n, T, S))
    keys = np.empty(K, dtype=np.int64)
    for u in range(n):
        for t in range(T):
            lo_i, lo_j = cand[u, t, 0, 0], cand[u, t, 0, 1]
            hi_j = lo_j
            floor = lp[u, t, 0]
            for k in range(K):
                lo_i, lo_j = min(lo_i, cand[u, t, k, 0]), min(lo_j, cand[u, t, k, 1])
                hi_j = max(hi_j, cand[u, t, k, 1])
                floor = min(floor, lp[u, t, k])
            span = hi_j - lo_j + 1
            for k in range(K):
                keys[k] = (cand[u, t, k, 0] - lo_i) * span + (cand[u, t, k, 1] - lo_j)
            order = np.argsort(keys, kind="mergesort")
            sorted_keys = keys[order]
            for s in range(S):
                top = -np.inf
                for a in range(2):  # the two rows (the same one unless halfway) ...
                    i = near[a, u, t, s, 0]
                    for b in range(2):  # ... by the two columns
                        j = near[b, u, t, s, 1]
                        v = floor
                        if 0 <= j - lo_j < span:  # a column no candidate has is no candidate
                            want = (i - lo_i) * span + (j - lo_j)
                            m = np.searchsorted(sorted_keys, want)
                            if m < K and sorted_keys[m] == want:
                                v = lp[u, t, order[m]]
                        top = max(top, v)
                best[u, t, s] = top
    return best


@numba.njit(cache=True, nogil=True)
def _bands(lik: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:  # pragma: no cover - compiled
    """Each step's band of ``lik (T, S)``, its first and last bin with a likelihood, into ``lo``
    and ``hi (T,)`` (``S`` and ``-1`` where none has one). The route's kernels visit the bands
    only: a window wider at the end steps than between them (:func:`_relocate_ends`) is zero
    outside the narrow one there."""
    T, S = lik.shape
    for t in range(T):
        lo[t], hi[t] = S, -1
        for i in range(S):
            if lik[t, i] > 0.0:
                lo[t] = min(lo[t], i)
                hi[t] = i


@numba.njit(cache=True, nogil=True)
def _forward_backward(
    lik: np.ndarray, d: np.ndarray, prior: np.ndarray, change: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Posterior over the window's arc bins ``(n, T, S)`` of users at arc bin ``centre_t + i`` (the
    window ``i`` in ``0..S-1``) moving ``j`` bins per step (``prior (V,)``, kept with probability
    ``1 - change``); ``lik (n, T, S)`` the steps' likelihoods, ``d (n, T-1)`` the windows' shifts.
    Also ``(n,)`` whether any way through the windows is possible at all (not where the track
    runs back along its route farther than a window) and ``(n,)`` the log-likelihood of the steps
    under this motion (up to a constant of the window's size).

    Compiled, as numpy's gathers over the whole (users, bins, speeds) block cost ten times as
    much. Only the speeds that keep a user within the windows at some step (``d_t - S < j <
    d_t + S``, about half of them for a fast driver) are carried: a user drawing any other speed
    leaves the windows with its next step, so those speeds enter the evidence in closed form and
    no posterior (at the last step their share is the same at every bin). A user at bin ``i``
    moves in from, and on to, only the ``S`` speeds that keep it within the windows, so per
    step it touches about ``S^2`` (bin, speed) pairs, each speed's as one contiguous row."""
    n, T, S = lik.shape
    V = len(prior)
    post = np.zeros((n, T, S))
    alive = np.ones(n, dtype=np.bool_)
    evidence = np.zeros(n)
    # alpha_t(speed jlo + w, bin i) = redrawn[t, i] prior[jlo + w] + kept[t, w, i]. A user keeping
    # speed jlo + w from step t - 1 to t moves by shift = jlo + w - d[t - 1] bins: kept[t, w] is
    # kept[t - 1, w] shifted (a contiguous row, as beta's rows are a step back), defined only at
    # the bins a user arrives at from within the window before (its "reach", never read outside)
    redrawn = np.empty((T, S))
    kept = np.empty((T, V, S))
    beta = np.empty((V, S))
    arrived = np.empty(S)
    again = np.empty(S)
    p_all = prior.sum()
    lo_b = np.empty(T, dtype=np.int64)  # each step's band (_bands)
    hi_b = np.empty(T, dtype=np.int64)
    for u in range(n):
        lo_d, hi_d = d[u, 0], d[u, 0]
        for t in range(1, T - 1):
            lo_d, hi_d = min(lo_d, d[u, t]), max(hi_d, d[u, t])
        jlo, jhi = max(0, lo_d - (S - 1)), min(V - 1, hi_d + (S - 1))
        W = max(jhi - jlo + 1, 0)
        # every loop below visits the steps' bands only, and what it leaves out would be zero
        # (the rows it reads later are zeroed outside what it writes)
        _bands(lik[u], lo_b, hi_b)
        p_in = 0.0
        for w in range(W):
            p_in += prior[jlo + w]
        tot = 0.0
        for i in range(S):
            redrawn[0, i] = lik[u, 0, i]  # the first step's speed is drawn from the prior
            tot += lik[u, 0, i] * p_all
        for t in range(T):
            if t > 0:
                arrived[:] = 0.0
                for w in range(W):
                    shift = jlo + w - d[u, t - 1]
                    before = jlo + w - d[u, t - 2] if t > 1 else 0  # row w's reach at t - 1
                    r0, r1 = max(0, shift), min(S - 1, shift + S - 1)
                    i0 = max(r0, lo_b[t], shift + lo_b[t - 1])
                    i1 = min(r1, hi_b[t], shift + hi_b[t - 1])
                    for i in range(r0, min(i0, r1 + 1)):
                        kept[t, w, i] = 0.0
                    for i in range(max(i1 + 1, r0), r1 + 1):
                        kept[t, w, i] = 0.0
                    for i in range(i0, i1 + 1):
                        a = redrawn[t - 1, i - shift] * prior[jlo + w]
                        if t > 1 and 0 <= i - shift - before < S:
                            a += kept[t - 1, w, i - shift]
                        arrived[i] += a
                        kept[t, w, i] = (1.0 - change) * a * lik[u, t, i]
                tot = 0.0
                for i in range(S):
                    redrawn[t, i] = change * arrived[i] * lik[u, t, i]
                    tot += (1.0 - change + change * p_all) * arrived[i] * lik[u, t, i]
            if tot <= 0.0:
                alive[u] = False
                break
            evidence[u] += np.log(tot)
            inv = 1.0 / tot  # a product per bin, not a division
            redrawn[t] *= inv
            if t > 0:
                for w in range(W):
                    shift = jlo + w - d[u, t - 1]
                    i0 = max(0, shift, lo_b[t], shift + lo_b[t - 1])
                    i1 = min(S - 1, shift + S - 1, hi_b[t], shift + hi_b[t - 1])
                    for i in range(i0, i1 + 1):
                        kept[t, w, i] *= inv
        if not alive[u]:
            continue
        for t in range(T - 1, -1, -1):
            if t < T - 1:
                # beta_t(w, i) = lik_t+1(i + shift) ((1 - c) beta_t+1(w, i + shift) + again(i + shift)),
                # defined where i + shift lies in the window; beta_T-1 is 1 everywhere
                if t == T - 2:
                    again[:] = change * p_in
                else:
                    again[:] = 0.0
                    for w in range(W):
                        later = jlo + w - d[u, t + 1]
                        k0 = max(0, -later, lo_b[t + 1], lo_b[t + 2] - later)
                        k1 = min(S - 1, S - 1 - later, hi_b[t + 1], hi_b[t + 2] - later)
                        for k in range(k0, k1 + 1):
                            again[k] += prior[jlo + w] * beta[w, k]
                    again[:] *= change
                top = 0.0
                for w in range(W):
                    shift = jlo + w - d[u, t]
                    later = jlo + w - d[u, t + 1] if t < T - 2 else 0
                    r0, r1 = max(0, -shift), min(S - 1, S - 1 - shift)
                    i0, i1 = max(r0, lo_b[t + 1] - shift), min(r1, hi_b[t + 1] - shift)
                    for m in range(i1 - i0 + 1):
                        # in place: each bin read (i + shift) before it is written
                        i = i0 + m if shift >= 0 else i1 - m
                        k = i + shift
                        b = 1.0
                        if t < T - 2:  # zero where the speed leaves the window a step later still
                            b = beta[w, k] if 0 <= k + later < S else 0.0
                        beta[w, i] = lik[u, t + 1, k] * ((1.0 - change) * b + again[k])
                        top = max(top, beta[w, i])
                    for i in range(r0, min(i0, r1 + 1)):  # outside the next step's band, after it is read
                        beta[w, i] = 0.0
                    for i in range(max(i1 + 1, r0), r1 + 1):
                        beta[w, i] = 0.0
                inv = 1.0 / max(top, 1e-300)
                for w in range(W):
                    shift = jlo + w - d[u, t]
                    for i in range(
                        max(0, -shift, lo_b[t + 1] - shift),
                        min(S - 1, S - 1 - shift, hi_b[t + 1] - shift) + 1,
                    ):
                        beta[w, i] *= inv
            if t == T - 1:  # beta is 1 at every speed
                for i in range(S):
                    post[u, t, i] = redrawn[t, i] * p_in
                for w in range(W):
                    reach = jlo + w - d[u, t - 1]
                    for i in range(max(0, reach), min(S - 1, reach + S - 1) + 1):
                        post[u, t, i] += kept[t, w, i]
            else:
                for w in range(W):
                    shift = jlo + w - d[u, t]
                    reach = jlo + w - d[u, t - 1] if t > 0 else 0
                    i0 = max(0, -shift, lo_b[t], lo_b[t + 1] - shift)
                    i1 = min(S - 1, S - 1 - shift, hi_b[t], hi_b[t + 1] - shift)
                    for i in range(i0, i1 + 1):
                        a = redrawn[t, i] * prior[jlo + w]
                        if t > 0 and 0 <= i - reach < S:
                            a += kept[t, w, i]
                        post[u, t, i] += a * beta[w, i]
            tot = 0.0
            for i in range(S):
                tot += post[u, t, i]
            post[u, t] /= max(tot, 1e-300)
    return post, alive, evidence


def speed_changes(speeds: np.ndarray, rel: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The speed changes of the training drivers, for a driver at speeds of its own: the
    differences between two speeds drawn from ``speeds (V,)`` (probabilities of ``j`` arc bins per
    step), those as likely as ``rel`` (default :data:`ROUTE_CHANGES`) times the likeliest.

    Returns
    -------
    deltas : (D,) int64
        Changes in arc bins per step (never 0); none where all measured drivers kept one speed.
    prob : (D,) float64
        Their probabilities, summing to 1.
    """
    p = np.asarray(speeds, dtype=np.float64)
    p = p / p.sum()
    diff = np.correlate(p, p, "full")  # diff[V - 1 + k]: probability that two speeds differ by k
    diff[len(p) - 1] = 0.0  # a change changes
    if not diff.max() > 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    keep = np.flatnonzero(diff >= (ROUTE_CHANGES if rel is None else rel) * diff.max())
    return (keep - (len(p) - 1)).astype(np.int64), diff[keep] / diff[keep].sum()


@numba.njit(cache=True, nogil=True)
def _forward_backward_changes(
    lik: np.ndarray,
    d: np.ndarray,
    prior: np.ndarray,
    change: float,
    deltas: np.ndarray,
    prob: np.ndarray,
    redraw: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """:func:`_forward_backward` of a driver whose speed, where it changes, moves by ``deltas
    (D,)`` bins with probabilities ``(1 - redraw) prob (D,)`` or is drawn again from ``prior``
    with probability ``redraw``: speeds of its own, changed as the training drivers change
    theirs. The first speed is drawn from ``prior``.

    A change from speed ``w`` reaches other speeds than one from ``w'``, so this pass carries
    every (speed, bin) pair of the window's reachable speeds (``S`` bins by about ``2 S`` speeds
    per step, each touching ``D + 2`` others), not the redrawn column and contiguous rows that
    make :func:`_forward_backward` cheap; it runs for the drivers at speeds of their own only."""
    n, T, S = lik.shape
    V, D = len(prior), len(deltas)
    post = np.zeros((n, T, S))
    alive = np.ones(n, dtype=np.bool_)
    evidence = np.zeros(n)
    first = np.empty(S)
    anyw = np.empty(S)  # the mass over all speeds at each bin (the redraws' source)
    came = np.empty(S)
    lo = np.empty(n, dtype=np.int64)  # each user's slowest reachable speed, bins per step
    ws = np.empty(n, dtype=np.int64)  # and how many speeds from it are reachable
    for u in range(n):
        lo_d, hi_d = d[u, 0], d[u, 0]
        for t in range(1, T - 1):
            lo_d, hi_d = min(lo_d, d[u, t]), max(hi_d, d[u, t])
        lo[u] = max(0, lo_d - (S - 1))
        ws[u] = max(min(V - 1, hi_d + (S - 1)) - lo[u] + 1, 0)
    # alpha[t, w, i]: at bin i of step t's window, having moved jlo + w bins from step t - 1;
    # beta[w, i]: the later steps' likelihood after bin i of step t, having moved jlo + w bins;
    # ahead[w, i]: the next step's likelihood times beta, per speed moved into it
    alpha_all = np.empty((T, max(ws.max(), 1), S))
    beta_all = np.empty((max(ws.max(), 1), S))
    ahead_all = np.empty((max(ws.max(), 1), S))
    redrawn = np.empty(S)
    lo_b = np.empty(T, dtype=np.int64)  # each step's band (_bands)
    hi_b = np.empty(T, dtype=np.int64)
    for u in range(n):
        jlo, W = lo[u], ws[u]
        alpha, beta, ahead = alpha_all[:, :W], beta_all[:W], ahead_all[:W]
        _bands(lik[u], lo_b, hi_b)
        tot = 0.0
        for i in range(S):
            first[i] = lik[u, 0, i]
            tot += first[i]
        if tot <= 0.0 or W == 0:
            alive[u] = False
            continue
        evidence[u] += np.log(tot)
        first /= tot
        for t in range(1, T):
            if t > 1:
                anyw[:] = 0.0
                for w in range(W):
                    reach = jlo + w - d[u, t - 2]  # alpha[t - 1, w] is zero outside its reach
                    for i in range(max(0, reach, lo_b[t - 1]), min(S, S + reach, hi_b[t - 1] + 1)):
                        anyw[i] += alpha[t - 1, w, i]
            alpha[t] = 0.0
            tot = 0.0
            for w in range(W):
                # the mass arriving at speed w, per bin of step t - 1, a row at a time (loops, not
                # array expressions: numba makes a temporary array for each of those), at the
                # bins from which speed w stays within step t's window only
                shift = jlo + w - d[u, t - 1]
                # and within both steps' bands
                i0 = max(0, -shift, lo_b[t - 1], lo_b[t] - shift)
                i1 = min(S, S - shift, hi_b[t - 1] + 1, hi_b[t] + 1 - shift)
                if t == 1:
                    for i in range(i0, i1):
                        came[i] = prior[jlo + w] * first[i]
                else:
                    c = change * redraw * prior[jlo + w]
                    for i in range(i0, i1):
                        came[i] = (1.0 - change) * alpha[t - 1, w, i] + c * anyw[i]
                    for k in range(D):
                        was = w - deltas[k]
                        if 0 <= was < W:
                            c = change * (1.0 - redraw) * prob[k]
                            for i in range(i0, i1):
                                came[i] += c * alpha[t - 1, was, i]
                for i in range(i0 + shift, i1 + shift):
                    a = came[i - shift] * lik[u, t, i]
                    alpha[t, w, i] = a
                    tot += a
            if tot <= 0.0:
                alive[u] = False
                break
            evidence[u] += np.log(tot)
            inv = 1.0 / tot  # a product per bin, not a division (a fifth of the kernel's time)
            for w in range(W):
                reach = jlo + w - d[u, t - 1]
                for i in range(max(0, reach, lo_b[t]), min(S, S + reach, hi_b[t] + 1)):
                    alpha[t, w, i] *= inv
        if not alive[u]:
            continue
        # every loop visits a speed's reach only: alpha[t, w] and ahead[w] are zero outside it,
        # and beta[w] is read only within alpha[t - 1, w]'s (half the (speed, bin) pairs)
        beta[:] = 1.0
        for t in range(T - 1, 0, -1):
            for w in range(W):
                reach = jlo + w - d[u, t - 1]
                for i in range(max(0, reach, lo_b[t]), min(S, S + reach, hi_b[t] + 1)):
                    post[u, t, i] += alpha[t, w, i] * beta[w, i]
            for w in range(W):
                shift = jlo + w - d[u, t - 1]
                ahead[w] = 0.0
                for i in range(max(0, -shift, lo_b[t] - shift), min(S, S - shift, hi_b[t] + 1 - shift)):
                    ahead[w, i] = lik[u, t, i + shift] * beta[w, i + shift]
            if t == 1:
                break
            redrawn[:] = 0.0
            for w in range(W):
                shift = jlo + w - d[u, t - 1]
                for i in range(max(0, -shift, lo_b[t] - shift), min(S, S - shift, hi_b[t] + 1 - shift)):
                    redrawn[i] += prior[jlo + w] * ahead[w, i]
            c = change * redraw
            top = 0.0
            for w in range(W):
                reach = jlo + w - d[u, t - 2]
                i0, i1 = max(0, reach, lo_b[t - 1]), min(S, S + reach, hi_b[t - 1] + 1)
                for i in range(i0, i1):
                    beta[w, i] = (1.0 - change) * ahead[w, i] + c * redrawn[i]
                for k in range(D):
                    to = w + deltas[k]
                    if 0 <= to < W:
                        ck = change * (1.0 - redraw) * prob[k]
                        for i in range(i0, i1):
                            beta[w, i] += ck * ahead[to, i]
                for i in range(i0, i1):
                    top = max(top, beta[w, i])
            inv = 1.0 / max(top, 1e-300)
            for w in range(W):
                reach = jlo + w - d[u, t - 2]
                for i in range(max(0, reach, lo_b[t - 1]), min(S, S + reach, hi_b[t - 1] + 1)):
                    beta[w, i] *= inv
        for w in range(W):  # the first step: its speed drawn from the prior
            shift = jlo + w - d[u, 0]
            for i in range(max(0, -shift), min(S, S - shift)):
                post[u, 0, i] += prior[jlo + w] * ahead[w, i]
        for i in range(S):
            post[u, 0, i] *= first[i]
        for t in range(T):
            post[u, t] /= max(post[u, t].sum(), 1e-300)
    return post, alive, evidence


def _window_loglik(
    part: list,
    idx: np.ndarray,
    xy: np.ndarray,
    lp: np.ndarray,
    offsets: np.ndarray,
    spacing: float,
    steps: slice | list = slice(None),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For ``part`` ((user, line, arc lengths, branch) of :func:`route_track`) of users ``idx`` at
    ``steps``: each tracked arc length on the bins ``(n, S)``, the positions ``offsets`` metres
    either side along the line ``(n, S, W, 2)`` and their log-likelihood ``(n, S, W)``."""
    h = spacing / ROUTE_BINS
    centre = np.stack([np.rint(arc[steps] / h) * h for _, _, arc, _ in part])
    pos = np.stack([_along(r, centre[k][:, None] + offsets) for k, (_, r, _, _) in enumerate(part)])
    at = np.asarray(xy[idx][:, steps], np.float64), np.asarray(lp[idx][:, steps], np.float64)
    return centre, pos, _candidate_loglik(*at, pos, spacing)


def _end_gaps(
    lines: list, xy: np.ndarray, lp: np.ndarray, spacing: float, half: int, end: int, B: int
) -> np.ndarray:
    """``(B,)`` per user, the most by which a position along its ``lines`` at the first or the
    last step, within ``end`` arc bins of the tracked one and outside ``half``, is likelier than
    the likeliest within ``half`` (log-likelihood; -inf for users without lines)."""
    bins = np.arange(-end, end + 1)
    outside = np.abs(bins) > half
    user = np.array([line[0] for line in lines], dtype=np.int64)
    gap = np.full(B, -np.inf)
    for c in range(0, len(lines), _CHUNK):
        idx = user[c : c + _CHUNK]
        ll = _window_loglik(
            lines[c : c + _CHUNK], idx, xy, lp, bins * (spacing / ROUTE_BINS), spacing, [0, -1]
        )[2]
        np.maximum.at(gap, idx, (ll[..., outside].max(-1) - ll[..., ~outside].max(-1)).max(-1))
    return gap


def _smooth_lines(
    lines: list,
    xy: np.ndarray,
    lp: np.ndarray,
    passes: tuple,
    B: int,
    T: int,
    spacing: float,
    half: int,
    end: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Each user's track along its ``lines`` ((user, line, arc lengths, branch) of :func:`route_track`),
    every line and motion of ``passes`` weighed by how well it explains the user's steps:
    ``(B, T, 2)`` metres and ``(B,)`` whether any line explains them. Each step weighs ``half``
    arc bins either side of its tracked arc length, the first and the last ``end`` (``half``
    when None)."""
    h = spacing / ROUTE_BINS
    wide = half if end is None else max(half, end)
    bins = np.arange(-wide, wide + 1)
    offsets, outside = bins * h, np.abs(bins) > half
    user = np.array([line[0] for line in lines], dtype=np.int64)
    tracks = np.zeros((len(lines), 2, T, 2))  # per line: under the measured speeds and speeds of its own
    logw = np.full((len(lines), 2), -np.inf)
    for c in range(0, len(lines), _CHUNK):
        part = lines[c : c + _CHUNK]
        centre, pos, ll = _window_loglik(part, user[c : c + _CHUNK], xy, lp, offsets, spacing)
        ll[:, 1:-1, outside] = -np.inf  # the steps between keep the narrow window
        top = ll.max(2, keepdims=True)
        lik = np.exp(ll - top)
        d = np.rint(np.diff(centre, axis=1) / h).astype(np.int64)
        for m, (kernel, motion, share) in enumerate(passes):
            # a branch is weighed under the measured speeds only: a driver at speeds of its own
            # drives them on its route too, and their pass is the dearer (the same tracks to 0.3 %)
            rows = np.flatnonzero([m == 0 or not line[3] for line in part]) + c
            if not len(rows):
                continue
            post, alive, ev = batch_map(kernel, 2, lik[rows - c], d[rows - c], *motion)
            tracks[rows, m] = (post[..., None] * pos[rows - c]).sum(2)
            # every line of a user on one scale: each step's window's top put back
            logw[rows, m] = np.where(alive, ev + top[rows - c, :, 0].sum(1) + np.log(share), -np.inf)
    # each user's track: every line and motion weighed by how well it explains the user's steps
    best = np.full(B, -np.inf)
    np.maximum.at(best, user, logw.max(1))
    w = np.exp(logw - np.where(np.isfinite(best), best, 0.0)[user, None])  # (lines, 2)
    total, track = np.zeros(B), np.zeros((B, T, 2))
    np.add.at(total, user, w.sum(1))
    np.add.at(track, user, np.einsum("lm,lmtc->ltc", w, tracks))
    ok = total > 0
    track[ok] /= total[ok, None, None]
    return track, ok


def _relocate_ends(
    track: np.ndarray,
    ok: np.ndarray,
    lines: list,
    xy: np.ndarray,
    lp: np.ndarray,
    passes: tuple,
    spacing: float,
    half: int,
) -> np.ndarray:
    """Drivers lost at the first or the last step: the smoother tracked it 3 to 7 m off (one
    side's evidence only), outside the window :func:`_smooth_lines` weighs there. Their ``lines``
    are weighed again with :data:`ROUTE_END_WINDOW` at both end steps, for the drivers with a
    position there about as likely as inside the window (:data:`ROUTE_END_GAP`), and ``track (B,
    T, 2)`` takes that track in place where it moves an end step farther than
    :data:`ROUTE_RELOCATE`; where it moves one less, the narrow window's mean stands, as a wider
    one lets aliases pull it. Returns ``(B,)`` the drivers relocated."""
    B, T = track.shape[:2]
    take = np.zeros(B, dtype=bool)
    end = int(round(ROUTE_END_WINDOW * ROUTE_BINS))
    if end <= half or T < 3 or not lines:
        return take
    # which drivers to weigh again is read on their own routes: the branches' windows at the end
    # steps reach into other streets, where some position is always likelier (read on them too,
    # it took three times the drivers, for tracks within 0.8 %)
    near = _end_gaps([line for line in lines if not line[3]], xy, lp, spacing, half, end, B) > -ROUTE_END_GAP
    lines = [line for line in lines if near[line[0]]]
    if not lines:
        return take
    wide, wide_ok = _smooth_lines(lines, xy, lp, passes, B, T, spacing, half, end)
    moved = np.linalg.norm(wide[:, [0, -1]] - track[:, [0, -1]], axis=-1).max(1)
    take = ok & wide_ok & (moved > ROUTE_RELOCATE * spacing)
    track[take] = wide[take]
    return take


def route_track(
    tracked: np.ndarray,
    xy: np.ndarray,
    lp: np.ndarray,
    net: StreetNetwork,
    speeds: np.ndarray,
    change: float,
    spacing: float,
    min_speed: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Tracks of drivers smoothed along their street routes (see the module's text).

    Parameters
    ----------
    tracked : (B, T, 2) float, metres
        The smoother's (or network's) track.
    xy : (B, T, K, 2) float, metres
        Every step's candidate grid points.
    lp : (B, T, K) float
        Their log-likelihoods (any per-step offset).
    net : mmwsim.trajectories.StreetNetwork
    speeds : (V,) float
        Probabilities of moving ``j`` arc bins (``spacing / ROUTE_BINS`` metres) per step,
        ``j = 0..V-1``, as measured on the training users faster than ``min_speed``.
    change : float
        Probability that such a user's speed changes from one step to the next.
    spacing : float
        The grid's spacing, metres.
    min_speed : float
        Metres per step: users whose median tracked step is slower are left as they are.

    Returns
    -------
    track : (B, T, 2) float64, metres
        ``tracked`` with every user smoothed along a route replaced.
    on : (B,) bool
        The users smoothed along a route.
    """
    tracked = np.asarray(tracked, dtype=np.float64)
    out, on = tracked.copy(), np.zeros(len(tracked), dtype=bool)
    B, T = tracked.shape[:2]
    if B == 0 or T < 2:
        return out, on
    half = int(round(ROUTE_WINDOW * ROUTE_BINS))
    prior = np.asarray(speeds, dtype=np.float64)
    prior = np.r_[prior / prior.sum(), np.zeros(int(round((ROUTE_FASTER - 1) * len(prior))))]
    flat = np.full(len(prior), 1.0 / len(prior))
    deltas, prob = speed_changes(prior)
    redraw = ROUTE_REDRAW if len(deltas) else 1.0  # no measured change: every change a draw
    prior = (1 - ROUTE_FLOOR) * prior + ROUTE_FLOOR * flat
    passes = (  # (kernel, its motion arguments, prior share): measured speeds, speeds of its own
        (_forward_backward, (prior, change), 1 - ROUTE_OTHER),
        (_forward_backward_changes, (flat, change, deltas, prob, redraw), ROUTE_OTHER),
    )
    steps = np.linalg.norm(np.diff(tracked, axis=1), axis=-1)
    typical = np.median(steps, axis=1)
    fast = np.flatnonzero(typical > min_speed)
    routes, lost = _street_nodes(net, tracked[fast])
    lines = []  # (user, a line it may drive along, its track's arc lengths there, whether a branch)
    centred = np.zeros(B, dtype=bool)
    for b, nodes in zip(fast, routes, strict=True):
        if nodes is None:
            continue
        r = _vertices(net, nodes)
        step = float(typical[b])
        arc, side = _arc_of(r, tracked[b], step)
        lane = float(np.mean(side))
        # a track that keeps to one side of the centre line is a driver in a lane beside it: the
        # lines as far to that side as the track, and nearer and farther, are weighed
        centred[b] = abs(lane) <= ROUTE_SIDE * spacing
        shifts = [0.0] if centred[b] else lane + ROUTE_LANES * spacing
        for shift in shifts:
            line = _offset(r, float(shift))
            lines.append((b, line, _arc_of(line, tracked[b], step)[0] if shift else arc, False))
        if centred[b] and ROUTE_BRANCHES:
            for alt in _end_branches(net, nodes, arc, ROUTE_END_WINDOW * spacing):
                line = _vertices(net, alt)
                lines.append((b, line, _arc_of(line, tracked[b], step)[0], True))
    track, ok = _smooth_lines(lines, xy, lp, passes, B, T, spacing, half)
    centre_lines = [line for line in lines if centred[line[0]]]  # not lane drivers
    take = _relocate_ends(track, ok, centre_lines, xy, lp, passes, spacing, half)
    away = np.linalg.norm(track - tracked, axis=-1)
    away[take, 0] = away[take, -1] = 0.0  # a relocated end step is meant to move
    # and so is an end step off the streets, left out of the route
    away[fast[lost[:, 0]], 0] = away[fast[lost[:, 1]], -1] = 0.0
    keep = ok & (away.max(1) <= ROUTE_GATE)
    if keep.any():  # and the route's steps must read the fingerprints about as well as the track's
        rows = np.flatnonzero(keep)
        both = np.stack([track[rows], tracked[rows]], 2)  # (n, T, 2: route, track, 2)
        ll = _candidate_loglik(xy[rows], lp[rows], both, spacing)
        keep[rows] = (ll[..., 1] - ll[..., 0]).sum(1) <= ROUTE_EVIDENCE
    out[keep], on[keep] = track[keep], True
    return out, on
