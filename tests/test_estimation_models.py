"""Estimation networks: output shapes for every model and task, size of the transformer, overfitting."""

from __future__ import annotations

from itertools import product

import numpy as np
import pytest
import torch

from estimation import (
    MODELS,
    BatchSampler,
    EstimationError,
    Estimator,
    TrainConfig,
    build_network,
    count_parameters,
)
from estimation.models import BASELINE_PAPER_OPTIONS, PAPER_OPTIONS, CellHead, CellOutput
from estimation.models import positions as _position
from estimation.models.embedding import BagEmbedding
from estimation.synthetic import toy_sequence_set


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.mark.parametrize("name", [m for m, spec in MODELS.items() if not spec.reads_grid])
@pytest.mark.parametrize("task,t_out", [("tracking", 6), ("forecasting", 3)])
def test_output_shapes(name, task, t_out):
    net = build_network(name, 32, 81, task, horizon=3)
    bits = (torch.rand(5, 6, 32, 81) < 0.1).float()
    net.train()
    assert _position(net(bits, torch.zeros(5, t_out, 2))).shape == (5, t_out, 2)
    net.eval()
    assert _position(net(bits)).shape == (5, t_out, 2)
    # any input length works (tracking outputs follow it)
    assert _position(net(bits[:, :2])).shape == (5, 2 if task == "tracking" else 3, 2)


@pytest.mark.parametrize("task,t_out", [("tracking", 4), ("forecasting", 2)])
def test_autoregressive_decoder_matches_teacher_forcing_on_its_own_outputs(task, t_out):
    torch.manual_seed(0)
    net = build_network("tn", 4, 6, task, horizon=2, decoder="autoregressive", dropout=0.0)
    net.eval()
    bits = (torch.rand(3, 4, 4, 6) < 0.3).float()
    y = _position(net(bits))
    assert y.shape == (3, t_out, 2)
    # Feeding the model's own outputs back with the causal mask in one pass gives the same result.
    net.train()
    assert torch.allclose(_position(net(bits, y)), y, atol=1e-5)


@pytest.mark.parametrize("name", ["lstm", "gru", "rnn", "tcn", "conv1d"])
def test_baselines_share_tn_front_and_keep_the_papers(name):
    ours = build_network(name, 32, 81, "forecasting", 3)
    assert isinstance(ours.head, CellHead) and isinstance(ours.embed, BagEmbedding)
    paper = build_network(name, 32, 81, "forecasting", 3, **BASELINE_PAPER_OPTIONS)
    assert not isinstance(paper.head, CellHead) and not isinstance(paper.embed, BagEmbedding)
    bits = (torch.rand(5, 6, 32, 81) < 0.1).float()
    assert paper(bits).shape == (5, 3, 2) and isinstance(ours(bits), CellOutput)


def test_paper_configuration_is_the_papers_size():
    net = build_network("tn", 32, 81, "tracking", 1, **PAPER_OPTIONS)
    assert 5e4 <= count_parameters(net) <= 2e5
    assert len(net.encoder.layers) == 2 and len(net.decoder.layers) == 2
    assert net.encoder.layers[0].self_attn.num_heads == 2
    assert not isinstance(net.head, CellHead)


def test_default_transformer_starts_as_its_per_step_embedding():
    """identity_init: the untrained stack passes each step's embedding through, so the positions of
    a sequence are those of its steps read one by one (what the warm-up trains)."""
    torch.manual_seed(0)
    net = build_network("tn", 4, 6, "tracking", 1, dropout=0.0).eval()
    bits = (torch.rand(3, 5, 4, 6) < 0.3).float()
    one_by_one = torch.cat([_position(net(bits[:, t : t + 1])) for t in range(5)], 1)
    assert torch.allclose(_position(net(bits)), one_by_one, atol=1e-6)
    with torch.no_grad():  # trained attention mixes the steps
        net.encoder.layers[0].self_attn.out_proj.weight.normal_()
    assert not torch.allclose(_position(net(bits)), one_by_one, atol=1e-4)


def test_bag_embedding_is_the_dense_layer_over_set_bits():
    torch.manual_seed(0)
    emb = BagEmbedding(4, 6, 8, hidden=16, dropout=0.0)
    bits = (torch.rand(3, 2, 4, 6) < 0.3).float()
    bits[0, 0] = 0  # a fingerprint with no set bit
    dense = torch.relu(bits.flatten(-2) @ emb.rows + emb.bias)
    assert torch.allclose(emb(bits), emb.norm(emb.out(dense)), atol=1e-5)


def test_cell_head_reads_out_cells_and_scores_the_soft_target():
    head = CellHead(4, cells=4)  # cells of 0.5 in the normalised box
    h = torch.zeros(1, 4)
    with torch.no_grad():
        head.score.bias.fill_(-50.0)
        head.score.bias[1 * 4 + 2] = 50.0  # row 1, column 2: centre (0.25, -0.25)
    head.requires_grad_(False)
    out = head(h)
    assert isinstance(out, CellOutput)
    assert torch.allclose(out.position, torch.tensor([[0.25, -0.25]]), atol=1e-6)
    # the loss is smallest for a target at that centre, and grows with the distance from it
    near, _ = head.loss(out, torch.tensor([[0.25, -0.25]]))
    off, _ = head.loss(out, torch.tensor([[0.3, -0.25]]))
    far, n = head.loss(out, torch.tensor([[-0.75, 0.75]]))
    assert n == 1 and float(near) < float(off) < float(far)
    # the soft target: spread over neighbours by distance, so a uniform score costs log(16)
    with torch.no_grad():
        head.score.bias.zero_()
    total, _ = head.loss(head(h), torch.tensor([[-0.25, -0.25]]))
    position_term = (head(h).position - torch.tensor([[-0.25, -0.25]])).square().sum() / head.w**2
    assert float(total - position_term) == pytest.approx(np.log(16), abs=1e-5)
    # beyond one cell the position term grows linearly (Huber): 4.5 squared cells cost 2 sqrt(4.5) - 1
    total, _ = head.loss(head(h), torch.tensor([[0.75, 0.75]]))
    assert float(total) == pytest.approx(np.log(16) + 2 * np.sqrt(4.5) - 1, abs=1e-5)


def test_causal_models_ignore_the_future():
    """TCN, LSTM: the estimate at step t depends only on fingerprints up to t (either front)."""
    for name, options in product(("tcn", "lstm", "gru", "rnn"), ({}, BASELINE_PAPER_OPTIONS)):
        net = build_network(name, 4, 6, "tracking", 1, dropout=0.0, **options).eval()
        bits = (torch.rand(2, 5, 4, 6) < 0.3).float()
        changed = bits.clone()
        changed[:, 3:] = 1 - changed[:, 3:]
        now, later = _position(net(bits)), _position(net(changed))
        assert torch.allclose(now[:, :3], later[:, :3], atol=1e-6), name
        assert not torch.allclose(now[:, 3:], later[:, 3:], atol=1e-6), name


@pytest.mark.parametrize("name,options,steps", [("tn", {"d": 32, "ff": 64}, 200), ("lstm", {}, 250)])
def test_tiny_set_is_overfitted(name, options, steps):
    torch.manual_seed(0)
    d = toy_sequence_set(16, 4, nx=16, ny=16, n_beams=4, n_bins=8, seed=5)
    est = Estimator(
        TrainConfig(model=name, dropout=0.0, options=options), d.n_beams, d.n_bins, d.normaliser()
    )
    opt = torch.optim.Adam(est.parameters(), lr=2e-3)
    batch = next(BatchSampler(d, "tracking", 0.0, 16, (4, 4), 0, shuffle=False).epoch(0))
    target = est.normaliser.to_unit(batch.y)
    first = None
    for _ in range(steps):
        loss = torch.nn.functional.mse_loss(_position(est(batch.bits, batch.y)), target)
        first = float(loss.detach()) if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 5e-3 * first and float(loss.detach()) < 1e-3
    err = (est.predict(batch.bits) - batch.y).norm(dim=-1)
    assert float(err.mean()) < 0.5  # metres, on a 16 m grid


def test_normaliser_round_trip():
    d = toy_sequence_set(4, 3)
    n = d.normaliser()
    y = torch.from_numpy(d.positions)
    u = n.to_unit(y)
    assert float(u.abs().max()) <= 1.0 + 1e-6
    assert torch.allclose(n.to_metres(u), y, atol=1e-4)
    assert np.allclose(n.centre, d.extent.mean(0))


@pytest.mark.parametrize("threads", [1, 2])
def test_every_model_predicts_an_empty_batch_and_tracks_no_users(threads):
    from mmwsim._threads import set_threads

    d = toy_sequence_set(16, 4, nx=16, ny=16, n_beams=4, n_bins=8, seed=5)
    set_threads(threads)  # the compiled kernels' slices: none for an empty batch
    try:
        for name, task in product(MODELS, ("tracking", "forecasting")):
            options = {"search": 16, "k": 8, "d": 16, "ff": 32} if name == "tn-match" else {}
            est = Estimator(TrainConfig(model=name, task=task, options=options), 4, 8, d.normaliser())
            if est.uses_grid:  # measured tables: the sub-cell stage and the memory run too
                est.net.fit_motion(d.positions, d.grid_xy, d.index)
                est.attach(d)
            out = est.predict(np.zeros((0, 5, 4, 8), np.uint8))
            assert out.shape == (0, 5 if task == "tracking" else est.config.horizon, 2), (name, task)
            assert est.predict(np.ones((2, 5, 4, 8), np.uint8)).shape[0] == 2
            with pytest.raises(EstimationError, match="at least one step"):
                est.predict(np.zeros((2, 0, 4, 8), np.uint8))
            if name == "tn-match" and task == "tracking":
                tracker = est.tracker()
                for _ in range(5):  # past the steps where the filter pairs and weighs paths
                    assert tracker.update(np.zeros((0, 4, 8))).shape == (0, 2)
                assert tracker.track().shape == (0, 5, 2)
    finally:
        set_threads(None)


def test_a_noise_level_that_is_no_number_of_decibels_is_refused():
    d = toy_sequence_set(16, 4, nx=16, ny=16, n_beams=4, n_bins=8, seed=5)
    est = Estimator(TrainConfig(model="tn-match", options={"search": 16, "k": 8}), 4, 8, d.normaliser())
    for sigma in (float("nan"), -3.0, float("inf")):
        with pytest.raises(EstimationError, match="noise sigma must be a finite number of dB"):
            est.attach(d, sigma=sigma)
    assert est.attach(d, sigma=0.0).matcher.sigma == 0.0  # noise-free: a plain threshold
