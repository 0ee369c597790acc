"""Training: bitwise resume, checkpoints (corrupt / foreign -> one line, exit 2), fresh noise, recording."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from estimation import (
    CHECKPOINT_FORMAT,
    BatchSampler,
    EstimationError,
    Estimator,
    TrainConfig,
    load_checkpoint,
    train,
)
from estimation.noise import fingerprint_bits
from estimation.synthetic import toy_sequence_set
from mmwsim.cli import main
from mmwsim.errors import MmwsimError
from tests.helpers.rrd import check_blueprint, entity_rows


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _sets():
    tr = toy_sequence_set(96, 6, nx=16, ny=16, n_beams=4, n_bins=8, seed=1)
    va = toy_sequence_set(32, 6, nx=16, ny=16, n_beams=4, n_bins=8, seed=2)
    return tr, va


BASE = dict(batch_size=32, sigma=6.0, patience=50)
# The paper's TCN and recipe: small and quick, so these tests are about the training loop.
CFG = dict(
    BASE,
    model="tcn",
    options={"channels": 16, "d": 16, "embedding": "factorised", "head": "regression"},
    loss="mse",
    schedule="plateau",
    warmup_epochs=0,
    min_delta=1e-3,
)


def _quiet(*a):
    pass


def test_resume_gives_the_same_weights_as_an_uninterrupted_run(tmp_path):
    tr, va = _sets()
    full = train(
        tr, va, TrainConfig(epochs=4, **CFG), tmp_path / "full", progress=False, record=False, log=_quiet
    )
    train(tr, va, TrainConfig(epochs=2, **CFG), tmp_path / "part", progress=False, record=False, log=_quiet)
    resumed = train(
        tr,
        va,
        TrainConfig(epochs=4, **CFG),
        tmp_path / "part",
        resume=True,
        progress=False,
        record=False,
        log=_quiet,
    )
    a = load_checkpoint(tmp_path / "full" / "checkpoint.pt", CHECKPOINT_FORMAT)
    b = load_checkpoint(tmp_path / "part" / "checkpoint.pt", CHECKPOINT_FORMAT)
    assert a["epoch"] == b["epoch"] == 4
    assert a["model"].keys() == b["model"].keys()
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    assert a["history"]["train_loss"] == b["history"]["train_loss"]
    assert full["best_val_loss"] == resumed["best_val_loss"]
    # the best model is loadable and predicts metres
    est = Estimator.load(tmp_path / "full")
    assert est.predict(torch.zeros(2, 3, 4, 8)).shape == (2, 3, 2)


def test_training_learns_and_records_curves(tmp_path):
    tr, va = _sets()
    s = train(tr, va, TrainConfig(epochs=3, **CFG), tmp_path / "run", progress=False, log=_quiet)
    ck = load_checkpoint(tmp_path / "run" / "checkpoint.pt", CHECKPOINT_FORMAT)
    assert ck["history"]["train_loss"][-1] < ck["history"]["train_loss"][0]
    assert s["epochs"] == 3 and s["parameters"] > 0 and math.isfinite(s["best_val_rmse"])
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["config"]["model"] == "tcn" and info["summary"]["epochs"] == 3
    rows = entity_rows(tmp_path / "run" / "training.rrd")
    assert rows["/training/tcn/loss/train"] == 3
    assert rows["/training/tcn/loss/validation"] == 3
    assert rows["/training/tcn/rmse_m/validation"] == 3
    assert rows["/training/per_epoch/loss/tcn/validation"] == 1  # bar charts: one static row
    check_blueprint(tmp_path / "run" / "training.rrd", ["Training", "Config"], "epoch")


def test_early_stopping(tmp_path):
    tr, va = _sets()
    cfg = TrainConfig(epochs=30, **(CFG | {"patience": 1}), lr=1e-9)  # no progress: stops after 2 epochs
    s = train(tr, va, cfg, tmp_path / "run", progress=False, record=False, log=_quiet)
    assert s["stopped_early"] and s["epochs"] < 30


def test_early_stopping_waits_for_a_real_improvement_and_keeps_the_best_model(tmp_path):
    """With min_delta 0.9 only a tenfold fall of the validation loss counts: training stops after
    patience epochs even while the loss still falls, and model.pt holds the best epoch."""
    tr, va = _sets()
    cfg = TrainConfig(epochs=30, **(CFG | {"patience": 2, "min_delta": 0.9}))
    s = train(tr, va, cfg, tmp_path / "run", progress=False, record=False, log=_quiet)
    assert s["stopped_early"] and s["epochs"] == 3
    saved = torch.load(tmp_path / "run" / "model.pt", weights_only=True)
    assert saved["epoch"] == s["best_epoch"] and saved["val_loss"] == pytest.approx(s["best_val_loss"])
    with pytest.raises(EstimationError, match="min_delta"):
        TrainConfig(**(CFG | {"min_delta": 1.0}))


def test_existing_checkpoint_needs_resume_and_same_settings(tmp_path):
    tr, va = _sets()
    train(tr, va, TrainConfig(epochs=1, **CFG), tmp_path / "run", progress=False, record=False, log=_quiet)
    with pytest.raises(EstimationError, match="--resume"):
        train(tr, va, TrainConfig(epochs=2, **CFG), tmp_path / "run", progress=False, log=_quiet)
    with pytest.raises(EstimationError, match="other settings"):
        train(
            tr,
            va,
            TrainConfig(epochs=2, **(CFG | {"sigma": 9.0})),
            tmp_path / "run",
            resume=True,
            progress=False,
            log=_quiet,
        )


def _write_bad(path, how):
    if how == "garbage":
        path.write_bytes(b"\x00not a checkpoint" * 10)
    elif how == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif how == "foreign":
        torch.save({"weights": torch.zeros(3)}, path)
    elif how == "pickle":  # arbitrary objects are refused by weights_only loading
        torch.save({"format": CHECKPOINT_FORMAT, "obj": np.random.default_rng(0)}, path)


@pytest.mark.parametrize("how", ["garbage", "truncated", "foreign", "pickle"])
def test_bad_checkpoint_is_one_line_error(tmp_path, how, capsys):
    tr, va = _sets()
    train(tr, va, TrainConfig(epochs=1, **CFG), tmp_path / "run", progress=False, record=False, log=_quiet)
    _write_bad(tmp_path / "run" / "checkpoint.pt", how)
    with pytest.raises(MmwsimError):
        train(tr, va, TrainConfig(epochs=2, **CFG), tmp_path / "run", resume=True, progress=False, log=_quiet)
    _write_bad(tmp_path / "run" / "model.pt", how)
    with pytest.raises(EstimationError):
        Estimator.load(tmp_path / "run")
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "run"), "--dataset", "toy:n=40,length=4"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mmwsim: error:") and "model.pt" in err


def test_model_file_of_another_network_is_refused(tmp_path):
    tr, va = _sets()
    train(tr, va, TrainConfig(epochs=1, **CFG), tmp_path / "run", progress=False, record=False, log=_quiet)
    state = torch.load(tmp_path / "run" / "model.pt", weights_only=True)
    state["config"] = TrainConfig(model="lstm").to_json()
    torch.save(state, tmp_path / "run" / "model.pt")
    with pytest.raises(EstimationError, match="does not fit"):
        Estimator.load(tmp_path / "run")


def test_fresh_noise_each_epoch_and_gaussian_tail():
    d = toy_sequence_set(64, 6, nx=16, ny=16, n_beams=4, n_bins=8, seed=1)
    s = BatchSampler(d, "tracking", 6.0, 64, (6, 6), seed=3)
    a, a2, b = next(s.epoch(0)), next(s.epoch(0)), next(s.epoch(1))
    assert torch.equal(a.bits, a2.bits)  # same epoch, same draws (what makes resume exact)
    assert not torch.equal(a.bits, b.bits)
    # P(bit) = P(N(0, sigma^2) >= thr - pdp): check on a constant PDP 3 dB below the threshold
    pdp = torch.full((200_000,), -118.0)
    frac = float(fingerprint_bits(pdp, 6.0, -115.0, torch.Generator().manual_seed(0)).mean())
    expected = 0.5 * math.erfc(3.0 / (6.0 * math.sqrt(2)))
    assert abs(frac - expected) < 4 * math.sqrt(expected * (1 - expected) / 200_000)
    assert float(fingerprint_bits(torch.tensor([-math.inf]), 6.0, -115.0, torch.Generator()).sum()) == 0


def test_forecasting_batches_and_training(tmp_path):
    tr, va = _sets()
    s = BatchSampler(tr, "forecasting", 6.0, 8, (4, 2), seed=0)
    b = next(s.epoch(0))
    assert b.bits.shape == (8, 4, 4, 8) and b.y.shape == (8, 2, 2)
    cfg = TrainConfig(epochs=1, task="forecasting", t_obs=4, horizon=2, **CFG)
    train(tr, va, cfg, tmp_path / "run", progress=False, record=False, log=_quiet)
    assert Estimator.load(tmp_path / "run").predict(b.bits).shape == (8, 2, 2)
    with pytest.raises(EstimationError, match="do not fit"):
        BatchSampler(tr, "forecasting", 6.0, 8, (5, 2), seed=0)


def test_time_limit_stops_and_resume_continues(tmp_path):
    tr, va = _sets()
    train(tr, va, TrainConfig(epochs=2, **CFG), tmp_path / "run", progress=False, record=False, log=_quiet)
    s = train(
        tr,
        va,
        TrainConfig(epochs=5, **CFG),
        tmp_path / "run",
        resume=True,
        progress=False,
        record=False,
        log=_quiet,
        time_limit=0.0,
    )
    assert s["epochs"] == 2 and not s["stopped_early"]
    s = train(
        tr,
        va,
        TrainConfig(epochs=3, **CFG),
        tmp_path / "run",
        resume=True,
        progress=False,
        record=False,
        log=_quiet,
    )
    assert s["epochs"] == 3


def test_singles_draw_every_step_of_the_epochs_trajectories_once():
    tr, _ = _sets()
    s = BatchSampler(tr, "tracking", 6.0, 32, (2, 6), seed=3, epoch_size=40)
    got = [b for b in s.singles(0, 50)]
    assert all(b.bits.shape[1:] == (1, 4, 8) and b.y.shape[1:] == (1, 2) for b in got)
    y = torch.cat([b.y[:, 0] for b in got]).numpy()
    assert len(y) == 40 * 6
    # the steps of 40 whole trajectories, each once, shuffled across trajectories
    rows = np.unique(np.concatenate([b.rows for b in got]))
    assert len(rows) == 40
    want = tr.positions[rows].reshape(-1, 2)
    assert np.array_equal(np.unique(y, axis=0), np.unique(want, axis=0))
    assert not np.array_equal(y, want)
    again = torch.cat([b.y[:, 0] for b in s.singles(0, 50)]).numpy()
    assert np.array_equal(y, again)  # same epoch, same draw


def test_warmup_epochs_train_single_steps_without_early_stopping(tmp_path):
    tr, va = _sets()
    cfg = dict(
        BASE, model="tn", patience=1, min_delta=0.99, options={"d": 16, "ff": 32, "hidden": 32, "cells": 8}
    )
    lines = []
    s = train(
        tr,
        va,
        TrainConfig(epochs=6, warmup_epochs=3, **cfg),
        tmp_path / "run",
        progress=False,
        record=False,
        log=lines.append,
    )
    # min_delta 0.99 stops at the first epoch that does not improve: not during the warm-up, and
    # not at the sequence phase's first epoch, which is its own reference
    assert s["epochs"] == 5 and s["stopped_early"]
    assert [line.split(":")[0] for line in lines[:5]] == [
        "tn warm-up 1",
        "tn warm-up 2",
        "tn warm-up 3",
        "tn epoch 4",
        "tn epoch 5",
    ]


def test_warmup_defaults_and_refusals():
    assert TrainConfig(model="tn").warmup_epochs > 0 and TrainConfig(model="tn").loss == "cells"
    assert TrainConfig(model="lstm").warmup_epochs > 0 and TrainConfig(model="lstm").loss == "cells"
    assert TrainConfig(model="tn-match").warmup_epochs == 0
    assert TrainConfig(model="tn", task="forecasting").warmup_epochs == 0
    for bad in (
        dict(model="tn-match", warmup_epochs=2),
        dict(model="tn", task="forecasting", warmup_epochs=2),
    ):
        with pytest.raises(EstimationError, match="warm-up"):
            TrainConfig(**bad)
    with pytest.raises(EstimationError, match="cell head"):
        Estimator(
            TrainConfig(model="lstm", loss="cells", options={"head": "regression"}),
            4,
            8,
            toy_sequence_set(4, 3).normaliser(),
        )


def test_learning_rate_schedules():
    from estimation.training import _epoch_lr

    cos = TrainConfig(model="tn", epochs=10, warmup_epochs=4, lr=1e-3, warmup_lr=4e-3, schedule="cosine")
    lrs = [_epoch_lr(cos, e) for e in range(10)]
    # each phase starts at its own rate and falls along half a cosine, never to zero or back up
    assert lrs[0] == pytest.approx(4e-3) and lrs[4] == pytest.approx(1e-3)
    assert lrs[2] == pytest.approx(2e-3) and lrs[7] == pytest.approx(0.5e-3)
    assert all(a > b > 0 for a, b in zip(lrs[:3], lrs[1:4], strict=True))
    assert all(a > b > 0 for a, b in zip(lrs[4:9], lrs[5:], strict=True))
    plateau = TrainConfig(
        model="lstm", epochs=10, warmup_epochs=2, lr=1e-3, warmup_lr=5e-3, schedule="plateau"
    )
    assert plateau.schedule == "plateau"
    # each phase's rate is set at its start (None: left as it is); the plateau scheduler steps only
    # after the warm-up
    assert [_epoch_lr(plateau, e) for e in range(4)] == [5e-3, None, 1e-3, None]
    assert TrainConfig(model="tn").schedule == "cosine" and TrainConfig(model="tn").warmup_lr == 3e-3
    with pytest.raises(EstimationError, match="schedule"):
        TrainConfig(model="tn", schedule="linear")


def test_warmup_holds_what_reads_across_steps():
    from estimation.training import _train_epoch

    tr, _ = _sets()
    cfg = TrainConfig(
        model="tn", epochs=4, warmup_epochs=2, options={"d": 16, "ff": 32, "hidden": 32, "cells": 8}
    )
    torch.manual_seed(0)
    est = Estimator(cfg, tr.n_beams, tr.n_bins, tr.normaliser())
    opt = torch.optim.Adam(est.net.parameters(), lr=1e-2)
    sampler = BatchSampler(tr, "tracking", 6.0, 16, (2, 6), 0)
    held = {id(p): p.detach().clone() for p in est.net.sequence_parameters()}
    embed = [p.detach().clone() for p in est.net.embed.parameters()]
    _train_epoch(est, opt, sampler, cfg, 0, progress=False)
    assert all(torch.equal(p, held[id(p)]) for p in est.net.sequence_parameters())
    assert any(not torch.equal(a, b) for a, b in zip(embed, est.net.embed.parameters(), strict=True))
    assert all(p.requires_grad for p in est.net.parameters())
    _train_epoch(est, opt, sampler, cfg, 2, progress=False)  # sequences: the attention learns
    assert any(not torch.equal(p, held[id(p)]) for p in est.net.sequence_parameters())
