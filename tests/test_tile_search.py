"""The tile-by-tile search returns exactly the dense top k (plain and guided)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from estimation import tile_search
from estimation.matching import FingerprintMatcher
from estimation.noise import fingerprint_bits
from estimation.tile_search import TILE_POINTS


def _city(seed: int = 0, kind: str = "smooth") -> tuple[np.ndarray, np.ndarray]:
    """A 1 m grid of 30 x 30 points less a 'building', a patch at 0.25 m spacing (tiles of more
    than TILE_POINTS points, cut), and PDPs with duplicated rows (ties) and a no-signal corner (a
    vague region). ``kind``: smooth in space as a city's are; ``rough``, with strong independent
    noise per point, so that a tile's bound is loose; ``blocky``, nearly constant over 4 m
    squares, so that the bounds are nearly tight and any error in them shows."""
    rng = np.random.default_rng(seed)
    g = np.arange(30.0)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    xy = xy[~((xy[:, 0] > 10) & (xy[:, 0] < 16) & (xy[:, 1] > 5) & (xy[:, 1] < 20))]
    f = np.arange(40.0, 42.0, 0.25)
    xy = np.concatenate([xy, np.stack(np.meshgrid(f, f, indexing="ij"), -1).reshape(-1, 2)])
    M, N = 8, 30
    # each bin fed by a few sources: power falls with the distance to them
    src = rng.uniform(0, 42, (M, N, 2, 2))
    at = np.floor(xy / 4) * 4 + 2 if kind == "blocky" else xy
    d = np.linalg.norm(at[:, None, None, None] - src[None], axis=-1).min(-1)
    noise = {"smooth": 2.0, "rough": 12.0, "blocky": 0.05}[kind]
    pdp = (-70.0 - 4.0 * d + rng.normal(0, noise, d.shape)).astype(np.float32)
    pdp[(xy[:, 0] > 24) & (xy[:, 1] > 24)] = -np.inf  # out of coverage
    pdp[5:9] = pdp[4]  # five points with one fingerprint
    return xy, pdp


def _dense_topk(m: FingerprintMatcher, bits: torch.Tensor, k: int, key_fn=None):
    sc = m.scores(bits).double().numpy()
    key = sc if key_fn is None else key_fn(sc)
    order = np.lexsort((np.broadcast_to(np.arange(key.shape[1]), key.shape), -key), axis=1)[:, :k]
    return np.take_along_axis(key, order, 1), order, np.sort(key, axis=1)[:, ::-1]


def _assert_same_topk(got_key, got_rows, want_key, want_rows, sorted_key, k):
    np.testing.assert_allclose(got_key, want_key, rtol=1e-5, atol=1e-3)
    # the sets agree wherever no near-tie straddles the k-th place (float32 summation order)
    clear = sorted_key[:, k - 1] - sorted_key[:, k] > 1e-3
    assert clear.mean() > 0.5
    for g, w in zip(got_rows[clear], want_rows[clear], strict=True):
        assert set(g) == set(w)


def test_tiles_cover_the_grid_once_in_pieces_of_at_most_tile_points():
    xy, pdp = _city()
    m = FingerprintMatcher(torch.from_numpy(pdp), xy, sigma=3.0, threshold=-115.0)
    t = m.tile_index()
    rows = t.rows[t.rows >= 0]
    assert np.array_equal(np.sort(rows), np.arange(len(xy)))
    assert t.rows.shape[1] == TILE_POINTS and (t.count <= TILE_POINTS).all()
    assert t.count.sum() == len(xy) and t.n_tiles < len(xy) / 4
    # every point of a tile lies within its box, and the tile's weights bound its points'
    ok = t.rows >= 0
    assert (t.xy[ok] >= t.lo[np.nonzero(ok)[0]]).all() and (t.xy[ok] <= t.hi[np.nonzero(ok)[0]]).all()
    assert (t.w_max.T[:, :, None] >= t.w).all() and (t.c_max[:, None] >= t.c).all()


@pytest.mark.parametrize("kind", ["smooth", "rough", "blocky"])
def test_candidates_are_the_dense_top_k(kind, monkeypatch):
    xy, pdp = _city(kind=kind)
    m = FingerprintMatcher(torch.from_numpy(pdp), xy, sigma=3.0, threshold=-115.0)
    rows = np.arange(0, len(xy), 5)
    bits = fingerprint_bits(torch.from_numpy(pdp[rows]), 6.0, -115.0, torch.Generator().manual_seed(1))
    for k in (1, 7, 40, 150):
        score, got = m.candidates(bits, k)
        want_key, want, sorted_key = _dense_topk(m, bits, k)
        _assert_same_topk(score.double().numpy(), got.numpy(), want_key, want, sorted_key, k)
        # pruning from one seed tile, or from all of them, finds the same points
        for seed in (0, 1, 10**6):
            s2, r2 = m.tile_index().topk(*m._ones(bits), k, seed=seed)
            assert np.array_equal(r2, got.numpy()) and np.array_equal(s2, score.numpy())
    # searched in batches of a few fingerprints, tile by tile, the result is the same
    monkeypatch.setattr(tile_search, "_BATCH", 7)
    s4, r4 = m.tile_index().topk(*m._ones(bits), 40)
    monkeypatch.undo()
    assert np.array_equal(r4, m.candidates(bits, 40)[1].numpy()) and len(bits) > 3 * 7
    # ties go to the lower row: the five points that share a fingerprint come next to each
    # other in row order
    r = m.candidates(torch.from_numpy(pdp[[6]] >= -115.0).float(), 60)[1][0].tolist()
    assert 4 in r and r[r.index(4) : r.index(4) + 5] == [4, 5, 6, 7, 8]
    # any leading shape; more than the grid's points gives the whole grid
    s3, r3 = m.candidates(bits[:6].reshape(2, 3, *bits.shape[1:]), 7)
    assert torch.equal(r3.reshape(6, 7), m.candidates(bits[:6], 7)[1]) and s3.shape == (2, 3, 7)
    assert sorted(m.candidates(bits[:1], 10 * len(xy))[1][0].tolist()) == list(range(len(xy)))
    assert m.candidates(bits[:0], 5)[1].shape == (0, 5) and m.candidates(bits[:3], 0)[1].shape == (3, 0)


@pytest.mark.parametrize("kind", ["smooth", "rough", "blocky"])
def test_guided_search_is_the_dense_top_k_of_score_plus_bonus(kind):
    xy, pdp = _city(2, kind)
    m = FingerprintMatcher(torch.from_numpy(pdp), xy, sigma=3.0, threshold=-115.0)
    rows = np.arange(3, len(xy), 11)
    bits = fingerprint_bits(torch.from_numpy(pdp[rows]), 6.0, -115.0, torch.Generator().manual_seed(3))
    # and empty fingerprints (every point of the no-signal corner alike), guided into the corner
    bits = torch.cat([bits, torch.zeros((20, *bits.shape[1:]))])
    rng = np.random.default_rng(4)
    pred = np.concatenate([rng.uniform(0, 42, (len(rows), 2)), rng.uniform(24, 30, (20, 2))])
    spread, A = rng.uniform(0.5, 4, len(pred)), 50.0
    d2 = np.square(xy[None] - pred[:, None]).sum(-1)
    bonus = np.log1p(A * np.exp(-d2 / (2 * spread[:, None] ** 2)))
    for k in (3, 20):
        score, got = m.tile_index().topk(*m._ones(bits), k, (pred, spread, A))
        want_key, want, sorted_key = _dense_topk(m, bits, k, lambda sc: sc + bonus)
        got_key = score + np.take_along_axis(bonus, got, 1)
        _assert_same_topk(got_key, got, want_key, want, sorted_key, k)
        for seed in (0, 1, 10**6):
            s2, r2 = m.tile_index().topk(*m._ones(bits), k, (pred, spread, A), seed=seed)
            assert np.array_equal(r2, got) and np.array_equal(s2, score)
    # the scores returned are the plain log-likelihoods
    dense = m.scores(bits).numpy()
    np.testing.assert_allclose(score, np.take_along_axis(dense, got, 1), rtol=1e-5, atol=1e-3)
    assert math.isfinite(float(score.min()))
