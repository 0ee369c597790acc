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
"""

from __future__ import annotations

import warnings

import torch
from torch import nn

from .embedding import sinusoidal_encoding
from .motion import ACCELERATION, MixtureMotion, MotionTable

__all__ = [
    "CandidateTransformer",
    "candidate_features",
    "motion_posterior",
    "velocity_posterior",
    "STEP_SIGMAS",
    "ACCELERATION",
]

_SCALE = 32.0  # metres; relative candidate offsets are divided by this
_LOGP_FLOOR = -30.0  # log posteriors below this carry no information for the ranking
STEP_SIGMAS = (2.0, 3.0, 10.0)  # metres per step: pedestrians to vehicles


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
        self.embed = nn.Sequential(nn.Linear(2 + n_post, d), nn.ReLU(), nn.Linear(d, d))
        self.rank = nn.Embedding(self.k, d)
        layer = nn.TransformerEncoderLayer(d, heads, ff, dropout, batch_first=True)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="enable_nested_tensor is True")
            self.encoder = nn.TransformerEncoder(layer, layers)
        self.logit = nn.Linear(d, 1)
        self.offset = nn.Linear(d, 2)
        self.motion = MotionTable()  # measured on the training trajectories by estimation.train
        # Start as the constant-velocity smoother: unit weight on its posterior, the learned terms
        # at zero, so training starts from the classical answer.
        self.prior = nn.Parameter(torch.tensor([0.0] * (n_post - 1) + [1.0]))
        for lin in (self.logit, self.offset):
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)

    def forward(self, xy: torch.Tensor, post: torch.Tensor) -> torch.Tensor:
        """``xy (B, T, k, 2)`` metres and ``post (B, T, k, P)`` from :func:`candidate_features` ->
        positions ``(B, T, 2)`` metres."""
        B, T, K, _ = xy.shape
        # Anchor: coordinate-wise median of the steps' best candidates, robust to an alias far away.
        anchor = xy[:, :, 0].median(dim=1).values[:, None, None]
        feats = torch.cat([(xy - anchor) / _SCALE, post / 10.0], dim=-1)
        h = self.embed(feats) + self.rank.weight[:K] + sinusoidal_encoding(torch.arange(T), self.d)[:, None]
        h = self.encoder(h.reshape(B, T * K, self.d)).reshape(B, T, K, self.d)
        logits = self.logit(h)[..., 0] + (post * self.prior).sum(-1)
        w = torch.softmax(logits, dim=-1)  # (B, T, K)
        rel = (w[..., None] * (xy - anchor)).sum(2)
        # A small learned correction lets the estimate leave the grid points' convex hull by a little.
        corr = torch.tanh((w[..., None] * self.offset(h)).sum(2))
        return anchor[:, :, 0] + rel + corr
