"""Hidden-Markov smoothing of per-step fingerprint-match candidates.

Every step of a sequence has ``K`` candidate positions (the matcher's most likely grid points)
with their log likelihoods. Three smoothers turn them into posteriors given all steps:

* :func:`motion_posterior`, a random walk between candidates of consecutive steps, cheap enough
  for all of them;
* :func:`velocity_posterior`, a second-order (constant-velocity) model whose state holds position
  and velocity, ``O(T K^3)`` per sequence, so it runs on candidates pruned by the first;
* :func:`subcell_mean`, the second model on a lattice finer than the grid: a fingerprint only
  tells the grid cell, but a user moving steadily crosses cells in a pattern that tells where in
  them it is.

:func:`candidate_features` chains the first two. These dense smoothers re-run on a whole
sequence; ``match-cv`` and ``tn-match`` read the same posteriors from the online filter of
:mod:`estimation.smoothing.online`, which equals them when its beam keeps every pair (the tests
check it against these). The motion densities come from :mod:`estimation.smoothing.motion`.
"""

from __future__ import annotations

import torch

from .motion import SUBCELLS, MixtureMotion, MotionTable

__all__ = [
    "FINE_K",
    "STEP_SIGMAS",
    "candidate_features",
    "cell_mean",
    "motion_posterior",
    "subcell_mean",
    "velocity_posterior",
]

LOGP_FLOOR = -30.0  # log posteriors below this carry no information for the ranking
STEP_SIGMAS = (2.0, 3.0, 10.0)  # metres per step: pedestrians to vehicles
FINE_K = 6  # grid candidates per step that the sub-cell smoother splits


def motion_posterior(xy: torch.Tensor, logp: torch.Tensor, step_sigma: float) -> torch.Tensor:
    """Log posterior of each candidate given all steps, under a random walk between candidates.

    Forward-backward over the candidates of consecutive steps with transition weight
    ``exp(-|x_t - x_t+1|^2 / (2 s^2))``: the classical hidden-Markov smoother, which the network
    starts from and corrects.

    Parameters
    ----------
    xy : (B, T, K, 2) float, metres
    logp : (B, T, K) float
        Step-wise log likelihoods (any per-step offset).
    step_sigma : float, metres
        Scale ``s`` of one step's displacement.

    Returns
    -------
    (B, T, K) float32 log posteriors, normalised per step
    """
    return _random_walk(_rw_transitions(_step_distances(xy), step_sigma), logp)


def _step_distances(xy: torch.Tensor) -> torch.Tensor:
    """Squared distances ``(B, T-1, K, K)`` m^2 from each step's candidates to the next step's."""
    x = xy.double()
    return torch.cdist(x[:, :-1], x[:, 1:]).square()


def _rw_transitions(d2: torch.Tensor, step_sigma: float) -> torch.Tensor:
    """Random-walk transition weights ``(B, T-1, K, K)`` float64 from the squared step distances
    ``d2`` of :func:`_step_distances`."""
    return torch.exp(d2 * (-0.5 / step_sigma**2))


def _random_walk(trans: torch.Tensor, logp: torch.Tensor) -> torch.Tensor:
    """:func:`motion_posterior` from the transition weights ``trans`` of :func:`_rw_transitions`.

    The sums over the previous (next) step's candidates are matrix products in linear space, each
    step rescaled by its largest log value: about twice as fast as log-sum-exp over ``(K, K)``
    tensors. A transition weight below ``exp(-708)`` (75 m at ``s = 2``) underflows to zero, and
    a candidate no earlier candidate can reach at all is floored at ``exp(-690)`` instead of
    ``-inf``, so a sequence whose steps are all that far apart degrades to per-step likelihoods.
    """
    lp = logp.double()
    T = lp.shape[1]

    def propagate(v: torch.Tensor, t: int, forward: bool) -> torch.Tensor:
        m = v.amax(-1, keepdim=True)
        u = (v - m).exp().unsqueeze(-1)  # (B, K, 1)
        s = (trans[:, t].transpose(1, 2) if forward else trans[:, t]) @ u
        return torch.log(s.squeeze(-1).clamp(min=1e-300)) + m

    fwd = [lp[:, 0]]
    for t in range(1, T):
        fwd.append(propagate(fwd[-1], t - 1, True) + lp[:, t])
    bwd = [torch.zeros_like(lp[:, -1])]
    for t in range(T - 2, -1, -1):
        bwd.append(propagate(lp[:, t + 1] + bwd[-1], t, False))
    post = torch.stack(fwd, 1) + torch.stack(bwd[::-1], 1)
    return torch.log_softmax(post, dim=-1).float()


def velocity_posterior(
    xy: torch.Tensor, logp: torch.Tensor, motion: MixtureMotion | MotionTable | None = None
) -> torch.Tensor:
    """Log posterior of each candidate given all steps, under a second-order (velocity) motion model.

    Forward-backward over pairs of candidates of consecutive steps (the state holds position and
    velocity): the first displacement ``x_1 - x_0`` is scored by ``motion.log_first`` and every
    later change of displacement ``x_t+1 - 2 x_t + x_t-1`` by ``motion.log_accel`` given the
    displacement before it; a :class:`MotionTable` with place tables also scores every position
    by :meth:`~MotionTable.log_place_ratio` given the displacement into it (out of it at step 0).
    Costs ``O(T K^3)`` per sequence, so it runs on pruned candidates.

    Parameters
    ----------
    xy : (B, T, K, 2) float, metres
    logp : (B, T, K) float
        Step-wise log likelihoods (any per-step offset).
    motion : MixtureMotion or MotionTable, optional
        Default ``MixtureMotion()``, the hand-set model.

    Returns
    -------
    (B, T, K) float32 log posteriors, normalised per step
    """
    motion = MixtureMotion() if motion is None else motion
    T = xy.shape[1]
    if T == 1:
        return torch.log_softmax(logp, dim=-1)
    place = getattr(motion, "log_place_ratio", None)
    v = xy[:, 1, None] - xy[:, 0, :, None]  # (B, K_0, K_1, 2)
    pair = [logp[:, 0, :, None] + logp[:, 1, None, :] + motion.log_first(v)]
    if place is not None:
        pair[0] = pair[0] + place(v, xy[:, 0, :, None]) + place(v, xy[:, 1, None])

    def triple(t: int) -> torch.Tensor:  # (B, K_t-1, K_t, K_t+1) log transition
        v = xy[:, t, None, :, None] - xy[:, t - 1, :, None, None]  # (B, K_t-1, K_t, 1, 2)
        w = xy[:, t + 1, None, None] - xy[:, t, None, :, None]  # (B, 1, K_t, K_t+1, 2)
        out = motion.log_accel(v, w - v)
        return out if place is None else out + place(w, xy[:, t + 1, None, None])

    trans = [triple(t) for t in range(1, T - 1)]
    for t in range(1, T - 1):  # forward over states (x_t-1, x_t) -> (x_t, x_t+1)
        pair.append(torch.logsumexp(pair[-1][..., None] + trans[t - 1], dim=1) + logp[:, t + 1, None, :])
    back = [torch.zeros_like(pair[-1])]
    for t in range(T - 2, 0, -1):
        back.append(torch.logsumexp(trans[t - 1] + (logp[:, t + 1, None, :] + back[-1])[:, None], dim=3))
    joint = [f + b for f, b in zip(pair, back[::-1], strict=True)]  # over (x_t-1, x_t) for t = 1..T-1
    marg = [torch.logsumexp(joint[0], dim=2)] + [torch.logsumexp(j, dim=1) for j in joint]
    return torch.log_softmax(torch.stack(marg, 1), dim=-1)


@torch.no_grad()
def candidate_features(
    xy: torch.Tensor,
    score: torch.Tensor,
    k: int,
    block: int = 64,
    motion: MixtureMotion | MotionTable | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` best candidates of every step after smoothing, with their posterior features.

    Parameters
    ----------
    xy : (B, T, K, 2) float, metres
        The matcher's candidates of every step, ``K >= k``.
    score : (B, T, K) float
        Their log-likelihoods.
    k : int
        Candidates kept per step, ranked by their best :func:`motion_posterior`.
    block : int
        Sequences smoothed at once (bounds the ``(block, T, K, K)`` and ``(block, T, k, k, k)``
        transition tensors).
    motion : MixtureMotion or MotionTable, optional
        Motion model of the constant-velocity posterior (default the hand-set mixture).

    Returns
    -------
    xy : (B, T, k, 2) float32, metres
    post : (B, T, k, 2 + len(STEP_SIGMAS)) float32
        Step-wise log posterior under a flat prior, the random-walk posteriors at walking and
        driving step scales, then the constant-velocity posterior over the ``k`` kept; each
        clipped at -30.
    """
    outs_xy, outs_post = [], []
    for a in range(0, xy.shape[0], block):
        x, sc = xy[a : a + block].float(), score[a : a + block].float()
        logp = torch.log_softmax(sc, dim=-1)
        d2 = _step_distances(x)
        post = torch.stack([logp] + [_random_walk(_rw_transitions(d2, s), logp) for s in STEP_SIGMAS], -1)
        keep = post[..., 1:].amax(-1).topk(min(k, x.shape[2]), dim=-1).indices  # (b, T, k)
        kxy = torch.gather(x, 2, keep[..., None].expand(-1, -1, -1, 2))
        kpost = torch.gather(post, 2, keep[..., None].expand(-1, -1, -1, post.shape[-1]))
        outs_xy.append(kxy)
        outs_post.append(torch.cat([kpost, velocity_posterior(kxy, kpost[..., 0], motion)[..., None]], -1))
    return torch.cat(outs_xy), torch.cat(outs_post).clamp(min=LOGP_FLOOR)


@torch.no_grad()
def subcell_mean(
    xy: torch.Tensor,
    logp: torch.Tensor,
    rank: torch.Tensor,
    motion: MixtureMotion | MotionTable,
    spacing: float = 1.0,
    n_sub: int = SUBCELLS,
    k: int = FINE_K,
    block: int = 16,
) -> torch.Tensor:
    """Posterior-mean positions under the constant-velocity model on a lattice finer than the grid.

    A fingerprint only tells which grid cell a user is in, but a user moving steadily crosses the
    cells in a pattern that tells where in them it is. Each step's ``k`` best candidates (by
    ``rank``) are split into ``n_sub x n_sub`` sub-cell points sharing their cell's likelihood,
    and :func:`velocity_posterior` runs over those with ``motion``, a table measured on
    trajectories snapped to that lattice (:meth:`MotionTable.lattice`, :func:`snap_to_lattice`).

    Parameters
    ----------
    xy : (B, T, K, 2) float, metres
        Grid candidates of every step.
    logp : (B, T, K) float
        Their step-wise log likelihoods.
    rank : (B, T, K) float
        Score choosing the ``k`` candidates split (e.g. the cell-level velocity posterior).
    motion : MotionTable or MixtureMotion
        Motion model in grid units (a :meth:`MotionTable.lattice` fitted on the lattice).
    spacing : float, metres
        Grid spacing.
    n_sub, k, block : int
        Sub-cells per axis, candidates split per step, sequences smoothed at once.

    Returns
    -------
    (B, T, 2) float32 positions, metres
    """
    k = min(int(k), xy.shape[2])
    top = rank.topk(k, dim=-1).indices
    cxy = torch.gather(xy.float(), 2, top[..., None].expand(-1, -1, -1, 2)) / spacing
    clp = torch.gather(logp.float(), 2, top)
    off = (torch.arange(n_sub, dtype=torch.float32) - (n_sub - 1) / 2) / n_sub
    offs = torch.stack(torch.meshgrid(off, off, indexing="ij"), -1).reshape(-1, 2)  # (n_sub^2, 2)
    B, T = cxy.shape[:2]
    sxy = (cxy[:, :, :, None] + offs).reshape(B, T, -1, 2)
    slp = clp[..., None].expand(-1, -1, -1, len(offs)).reshape(B, T, -1)
    out = []
    for a in range(0, B, block):
        w = velocity_posterior(sxy[a : a + block], slp[a : a + block], motion).exp()
        out.append((w[..., None] * sxy[a : a + block]).sum(2))
    return (torch.cat(out) if out else cxy[:, :, 0]) * spacing


def cell_mean(xy: torch.Tensor, post: torch.Tensor) -> torch.Tensor:
    """Posterior-mean positions ``(B, T, 2)`` of :func:`candidate_features`' output under its
    constant-velocity posterior (its last feature)."""
    return (torch.softmax(post[..., -1], dim=-1)[..., None] * xy).sum(2)
