"""Estimation networks: output shapes for every model and task, size of the transformer, overfitting."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from estimation import MODELS, BatchSampler, Estimator, TrainConfig, build_network, count_parameters
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
    assert net(bits, torch.zeros(5, t_out, 2)).shape == (5, t_out, 2)
    net.eval()
    assert net(bits).shape == (5, t_out, 2)
    # any input length works (tracking outputs follow it)
    assert net(bits[:, :2]).shape == (5, 2 if task == "tracking" else 3, 2)


@pytest.mark.parametrize("task,t_out", [("tracking", 4), ("forecasting", 2)])
def test_autoregressive_decoder_matches_teacher_forcing_on_its_own_outputs(task, t_out):
    torch.manual_seed(0)
    net = build_network("tn", 4, 6, task, horizon=2, decoder="autoregressive", dropout=0.0)
    net.eval()
    bits = (torch.rand(3, 4, 4, 6) < 0.3).float()
    y = net(bits)
    assert y.shape == (3, t_out, 2)
    # Feeding the model's own outputs back with the causal mask in one pass gives the same result.
    net.train()
    assert torch.allclose(net(bits, y), y, atol=1e-5)


def test_transformer_is_the_papers_size():
    net = build_network("tn", 32, 81, "tracking", 1)
    assert 5e4 <= count_parameters(net) <= 2e5
    assert len(net.transformer.encoder.layers) == 2 and len(net.transformer.decoder.layers) == 2
    assert net.transformer.encoder.layers[0].self_attn.num_heads == 2


def test_causal_models_ignore_the_future():
    """TCN, LSTM: the estimate at step t depends only on fingerprints up to t."""
    for name in ("tcn", "lstm", "gru", "rnn"):
        net = build_network(name, 4, 6, "tracking", 1, dropout=0.0).eval()
        bits = (torch.rand(2, 5, 4, 6) < 0.3).float()
        changed = bits.clone()
        changed[:, 3:] = 1 - changed[:, 3:]
        assert torch.allclose(net(bits)[:, :3], net(changed)[:, :3], atol=1e-6), name


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
        loss = torch.nn.functional.mse_loss(est(batch.bits, batch.y), target)
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
