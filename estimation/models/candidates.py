"""Transformer over fingerprint-match candidates (``tn-match``): our model, beyond the paper.

The paper's transformer (``tn``) must learn the whole map from fingerprints to positions from the
training trajectories, so it cannot place a user in a region no training trajectory visited. This
model reads the data set's grid instead: for every step the exact fingerprint likelihood
(:class:`~estimation.classical.FingerprintMatcher`) proposes its ``K`` most likely grid points, and a
transformer encoder attends over all candidates of all steps to pick the ones that form a plausible
motion. Each step's estimate is a convex combination of that step's candidates, so the model only
sees relative geometry and likelihoods: it is translation invariant and does not depend on where
the training trajectories ran.

Two classical smoothers rank the candidates and give the network its features: a random walk
(:func:`motion_posterior`), cheap enough for all ``search`` candidates, prunes them to ``k``; a
constant-velocity model (:func:`velocity_posterior`) over those ``k`` is the prior the network
starts from. Users keep their heading and speed for seconds, so the second-order model resolves
aliases a random walk cannot tell apart and averages the grid's quantisation over several steps.
Its motion statistics (:class:`~estimation.models.motion.MotionTable`) are measured on the
training trajectories and saved with the network.

A fingerprint tells only the grid cell, but the pattern in which a steady user crosses cells tells
where in them it is: a third smoother (:func:`subcell_mean`) splits the best few candidates of
every step into points of a lattice three times finer and runs the constant-velocity model there,
with a table measured on the training trajectories snapped to that lattice. Its estimate is the
network's starting point; the network moves it toward its own weighting of the candidates where it
learned to trust that.
"""

from __future__ import annotations

import warnings

import numpy as np
import torch
from torch import nn

from .embedding import sinusoidal_encoding
from .motion import ACCELERATION, SUBCELLS, MixtureMotion, MotionTable, snap_to_lattice

__all__ = [
    "CandidateTransformer",
    "candidate_features",
    "motion_posterior",
    "velocity_posterior",
    "subcell_mean",
    "STEP_SIGMAS",
    "FINE_K",
    "ACCELERATION",
]

_SCALE = 32.0  # metres; relative candidate offsets are divided by this
_LOGP_FLOOR = -30.0  # log posteriors below this carry no information for the ranking
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
    return _random_walk(_step_distances(xy), logp, step_sigma)


def _step_distances(xy: torch.Tensor) -> torch.Tensor:
    """Squared distances ``(B, T-1, K, K)`` m^2 from each step's candidates to the next step's."""
    x = xy.double()
    return torch.cdist(x[:, :-1], x[:, 1:]).square()


def _random_walk(d2: torch.Tensor, logp: torch.Tensor, step_sigma: float) -> torch.Tensor:
    """:func:`motion_posterior` from the squared step distances ``d2`` of :func:`_step_distances`.

    The sums over the previous (next) step's candidates are matrix products in linear space, each
    step rescaled by its largest log value: about twice as fast as log-sum-exp over ``(K, K)``
    tensors. A transition weight below ``exp(-708)`` (75 m at ``s = 2``) underflows to zero, and
    a candidate no earlier candidate can reach at all is floored at ``exp(-690)`` instead of
    ``-inf``, so a sequence whose steps are all that far apart degrades to per-step likelihoods.
    """
    trans = torch.exp(d2 * (-0.5 / step_sigma**2))  # (B, T-1, K, K), float64
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
    displacement before it. Costs ``O(T K^3)`` per sequence, so it runs on pruned candidates.

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
    v = xy[:, 1, None] - xy[:, 0, :, None]  # (B, K_0, K_1, 2)
    pair = [logp[:, 0, :, None] + logp[:, 1, None, :] + motion.log_first(v)]

    def triple(t: int) -> torch.Tensor:  # (B, K_t-1, K_t, K_t+1) log transition
        v = xy[:, t, None, :, None] - xy[:, t - 1, :, None, None]  # (B, K_t-1, K_t, 1, 2)
        return motion.log_accel(v, xy[:, t + 1, None, None] - xy[:, t, None, :, None] - v)

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
        post = torch.stack([logp] + [_random_walk(d2, logp, s) for s in STEP_SIGMAS], -1)
        keep = post[..., 1:].amax(-1).topk(min(k, x.shape[2]), dim=-1).indices  # (b, T, k)
        kxy = torch.gather(x, 2, keep[..., None].expand(-1, -1, -1, 2))
        kpost = torch.gather(post, 2, keep[..., None].expand(-1, -1, -1, post.shape[-1]))
        outs_xy.append(kxy)
        outs_post.append(torch.cat([kpost, velocity_posterior(kxy, kpost[..., 0], motion)[..., None]], -1))
    return torch.cat(outs_xy), torch.cat(outs_post).clamp(min=_LOGP_FLOOR)


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


class CandidateTransformer(nn.Module):
    """Candidates of every step in, positions ``(B, T, 2)`` in metres out.

    Parameters
    ----------
    search : int
        Candidates per step proposed by the matcher and smoothed (:func:`candidate_features`).
    k : int
        Candidates per step the transformer attends over.
    d, heads, layers, ff : transformer width, heads, encoder layers, feed-forward width.
    dropout : float
    """

    def __init__(
        self,
        search: int = 256,
        k: int = 48,
        d: int = 64,
        heads: int = 2,
        layers: int = 2,
        ff: int = 128,
        dropout: float = 0.01,
    ):
        super().__init__()
        if not 1 <= k <= search:
            raise ValueError(f"need 1 <= k <= search (got k={k}, search={search})")
        self.search, self.k, self.d = int(search), int(k), int(d)
        n_post = 2 + len(STEP_SIGMAS)
        self.embed = nn.Sequential(nn.Linear(4 + n_post, d), nn.ReLU(), nn.Linear(d, d))
        self.rank = nn.Embedding(self.k, d)
        layer = nn.TransformerEncoderLayer(d, heads, ff, dropout, batch_first=True)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="enable_nested_tensor is True")
            self.encoder = nn.TransformerEncoder(layer, layers)
        self.logit = nn.Linear(d, 1)
        self.offset = nn.Linear(d, 2)
        self.gate = nn.Linear(d, 1)
        # Measured on the training trajectories by estimation.train (motion.fit, fit_fine).
        self.motion = MotionTable()
        self.motion_fine = MotionTable.lattice()
        self.register_buffer("grid_step", torch.tensor(1.0))
        # Start as the classical smoother: unit weight on the constant-velocity posterior, the
        # learned terms at zero, the output the sub-cell smoother's, so training starts from it.
        self.prior = nn.Parameter(torch.tensor([0.0] * (n_post - 1) + [1.0]))
        for lin in (self.logit, self.offset, self.gate):
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)

    def fit_fine(self, positions: np.ndarray, grid_xy: np.ndarray) -> CandidateTransformer:
        """Measure the sub-cell smoother's motion table on training trajectories ``positions
        (n, L >= 3, 2)`` metres, snapped to the lattice of :func:`subcell_mean` over the grid points
        ``grid_xy (G, 2)`` metres. Returns ``self``."""
        grid_xy = np.asarray(grid_xy, dtype=np.float64)
        steps = np.diff(np.unique(grid_xy[:, 0]))
        spacing = float(steps.min()) if len(steps) else 1.0
        u = (np.asarray(positions, dtype=np.float64) - grid_xy.min(0)) / spacing
        self.motion_fine.fit(snap_to_lattice(u))
        self.grid_step.fill_(spacing)
        return self

    def smoothed(self, xy: torch.Tensor, post: torch.Tensor) -> torch.Tensor:
        """The classical estimate ``(B, T, 2)`` metres the network starts from: the sub-cell
        smoother's (:func:`subcell_mean`) once the motion tables are measured, else the cell-level
        constant-velocity posterior mean (``match-cv``)."""
        if not bool(self.motion_fine.fitted):
            return cell_mean(xy, post)
        return subcell_mean(xy, post[..., 0], post[..., -1], self.motion_fine, float(self.grid_step))

    def forward(self, xy: torch.Tensor, post: torch.Tensor, fine: torch.Tensor | None = None) -> torch.Tensor:
        """``xy (B, T, k, 2)`` metres and ``post (B, T, k, P)`` from :func:`candidate_features`, and
        the classical estimate ``fine (B, T, 2)`` metres (default :meth:`smoothed`) -> positions
        ``(B, T, 2)`` metres."""
        B, T, K, _ = xy.shape
        if fine is None:
            fine = self.smoothed(xy, post)
        # Anchor: coordinate-wise median of the steps' best candidates, robust to an alias far away.
        anchor = xy[:, :, 0].median(dim=1).values[:, None, None]
        near = (xy - fine[:, :, None]) / _SCALE
        feats = torch.cat([(xy - anchor) / _SCALE, near, post / 10.0], dim=-1)
        h = self.embed(feats) + self.rank.weight[:K] + sinusoidal_encoding(torch.arange(T), self.d)[:, None]
        h = self.encoder(h.reshape(B, T * K, self.d)).reshape(B, T, K, self.d)
        logits = self.logit(h)[..., 0] + (post * self.prior).sum(-1)
        w = torch.softmax(logits, dim=-1)  # (B, T, K)
        cells = (w[..., None] * xy).sum(2)
        # The network moves the classical estimate toward its own weighting of the candidates as
        # far as it trusts that weighting (the gate), plus a small learned correction.
        pooled = (w[..., None] * h).sum(2)
        corr = torch.tanh((w[..., None] * self.offset(h)).sum(2))
        return fine + self.gate(pooled) * (cells - fine) + corr
