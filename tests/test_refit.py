"""``mmwsim refit`` / :func:`estimation.refit_motion`: a trained ``tn-match`` with its motion tables
measured again on other trajectories, the network kept."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from estimation import (
    EstimationError,
    Estimator,
    SequenceSet,
    TrainConfig,
    noisy_bits,
    refit_motion,
    train,
    trajectory_rmse,
)
from estimation.smoothing.online import ADAPTED_PRIOR
from estimation.synthetic import random_walks, toy_grid, toy_sequence_set
from mmwsim.cli import main
from mmwsim.constants import THRESHOLD_DBM

TINY = {"search": 32, "k": 8, "d": 16, "ff": 32}


def _walks(n: int, seed: int, speeds: tuple[float, float]) -> SequenceSet:
    """Users of the toy grid (the one of :func:`toy_sequence_set`) at speeds of their own (m/s)."""
    xy, pdp = toy_grid(32, 32, 1.0, 8, 12, seed=0)
    lo, hi = xy.min(0), xy.max(0)
    pos, kind = random_walks(n, 6, lo, hi, seed=seed, speeds=speeds)
    index = np.rint(pos[..., 0] - lo[0]).astype(np.int64) + 32 * np.rint(pos[..., 1] - lo[1]).astype(np.int64)
    return SequenceSet(torch.from_numpy(pdp), xy, index, pos, kind, THRESHOLD_DBM, np.stack([lo, hi]))


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny trained tn-match run, its training and validation sets."""
    torch.manual_seed(0)
    tr, va = toy_sequence_set(256, 6, seed=1), toy_sequence_set(64, 6, seed=2)
    run = tmp_path_factory.mktemp("refit") / "run"
    cfg = TrainConfig(model="tn-match", epochs=1, epoch_size=128, sigma=6.0, options=TINY)
    train(tr, va, cfg, run, progress=False, record=False, log=lambda s: None)
    info = json.loads((run / "run.json").read_text())
    info["data"] = {"dataset": "toy:n=128,length=6", "content_hash": "e" * 64}  # as a data set's run has
    (run / "run.json").write_text(json.dumps(info))
    return run, tr, va


def _tracked(run, data: SequenceSet) -> float:
    est = Estimator.load(run).attach(data)
    bits = noisy_bits(data, 6.0, torch.Generator().manual_seed(3))
    return float(trajectory_rmse(est.predict(bits).numpy(), data.positions).mean())


def test_refit_on_the_training_trajectories_is_the_trained_model(trained, tmp_path):
    """Training measures its tables exactly as a refit on its own trajectories does."""
    run, tr, _ = trained
    motion = refit_motion(run, tr, tmp_path / "same", {"dataset": "toy", "split": "train"})
    a = torch.load(run / "model.pt", weights_only=True)
    b = torch.load(tmp_path / "same" / "model.pt", weights_only=True)
    assert a.keys() == b.keys() and all(a[k] == b[k] for k in a if k != "state_dict")
    assert a["state_dict"].keys() == b["state_dict"].keys()
    assert all(torch.equal(a["state_dict"][k], b["state_dict"][k]) for k in a["state_dict"])
    info = json.loads((tmp_path / "same" / "run.json").read_text())
    assert (
        info["motion"]["trajectories"] == tr.n == motion["trajectories"]
        and info["motion"]["split"] == "train"
    )
    assert info["config"] == json.loads((run / "run.json").read_text())["config"]
    assert not (tmp_path / "same" / "checkpoint.pt").exists()  # its tables are not its training's


def test_refit_tracks_users_as_they_move(trained, tmp_path):
    """Tables measured on slow pedestrians and slow vehicles track such users better, and the
    training users worse; the network's weights stay as trained."""
    run, _, va = trained
    new = tmp_path / "slow"
    refit_motion(run, _walks(256, 5, (0.5, 2.0)), new)
    a = Estimator.load(run).net
    b = Estimator.load(new).net
    assert all(torch.equal(p, q) for p, q in zip(a.parameters(), b.parameters(), strict=True))
    assert not torch.equal(a.motion.log_accel_table, b.motion.log_accel_table)
    others = _walks(100, 6, (0.5, 2.0))
    assert _tracked(new, others) < 0.97 * _tracked(run, others)
    assert _tracked(new, va) > _tracked(run, va)


def test_refit_gives_an_older_model_the_tables_added_since(trained, tmp_path):
    """A model saved before the walkers' tables existed gains them."""
    run, tr, _ = trained
    est = Estimator.load(run)
    est.net.motion_walk = type(est.net.motion_walk)()  # unfitted, as an older version saved it
    old = tmp_path / "old"
    old.mkdir()
    est.save(old / "model.pt")
    (old / "run.json").write_text((run / "run.json").read_text())
    assert not bool(Estimator.load(old).net.motion_walk.fitted)
    refit_motion(old, tr, tmp_path / "upgraded")
    assert torch.equal(
        Estimator.load(tmp_path / "upgraded").net.motion_walk.log_accel_table,
        Estimator.load(run).net.motion_walk.log_accel_table,
    )


def test_refit_refuses_what_it_cannot_measure(trained, tmp_path):
    run, tr, _ = trained
    with pytest.raises(EstimationError, match="another data set"):
        refit_motion(run, tr, tmp_path / "a", {"content_hash": "f" * 64})
    with pytest.raises(EstimationError, match="at least 3 steps"):
        refit_motion(run, toy_sequence_set(16, 2, seed=3), tmp_path / "b")
    with pytest.raises(EstimationError, match="grid of 2 m"):
        coarse = toy_sequence_set(16, 4, seed=3)
        refit_motion(
            run, SequenceSet(coarse.grid_pdp, coarse.grid_xy * 2, coarse.index, coarse.positions * 2,
                             coarse.kind, coarse.threshold, coarse.extent * 2), tmp_path / "c",
        )  # fmt: skip
    with pytest.raises(EstimationError, match="the run itself"):
        refit_motion(run, tr, run)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "notes.txt").write_text("mine")
    with pytest.raises(EstimationError, match="not an empty folder"):
        refit_motion(run, tr, tmp_path / "full")
    assert [p.name for p in (tmp_path / "full").iterdir()] == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["full"]  # nothing else written


def test_refit_cli(trained, tmp_path, capsys):
    run, _, _ = trained
    assert main(["refit", str(run), "--out", str(tmp_path / "new"), "--split", "validation"]) == 0
    assert "32 trajectories" in capsys.readouterr().out
    assert json.loads((tmp_path / "new" / "run.json").read_text())["motion"]["split"] == "validation"
    for argv, needle in (
        (["refit", str(run), "--out", str(tmp_path / "new")], "not an empty folder"),
        (["refit", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x")], "not a training run"),
        (["refit", str(run), "--out", str(tmp_path / "x"), "--split", "nope"], "no split"),
        (["refit", str(run), "--out", str(tmp_path / "x"), "--dataset", "toy:length=2"], "at least 3 steps"),
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err
    assert not (tmp_path / "x").exists()


def test_refit_needs_a_network_with_motion_tables(tmp_path):
    tr, va = toy_sequence_set(64, 4, seed=1), toy_sequence_set(32, 4, seed=2)
    cfg = TrainConfig(model="gru", epochs=1, options={"d": 16})
    train(tr, va, cfg, tmp_path / "gru", progress=False, record=False, log=lambda s: None)
    with pytest.raises(EstimationError, match="no motion tables"):
        refit_motion(tmp_path / "gru", tr, tmp_path / "new")
    assert not (tmp_path / "new").exists()


def test_refit_on_a_read_only_file_system_leaves_nothing(trained, tmp_path, capsys, monkeypatch):
    run, _, _ = trained
    monkeypatch.setenv("MMWSIM_FAULT", "file.write:erofs")
    assert main(["refit", str(run), "--out", str(tmp_path / "runs" / "new")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "read-only" in err
    assert list(tmp_path.rglob("*")) == []


@pytest.mark.parametrize("garbage", ["run.json", "model.pt"])
def test_refit_of_a_damaged_run_is_one_line(trained, tmp_path, capsys, garbage):
    run, _, _ = trained
    bad = tmp_path / "bad"
    bad.mkdir()
    for name in ("run.json", "model.pt"):
        (bad / name).write_bytes(b"\x80garbage" if name == garbage else (run / name).read_bytes())
    assert main(["refit", str(bad), "--out", str(tmp_path / "new")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and garbage in err
    assert not (tmp_path / "new").exists()


def test_adapt_motion_learns_from_fingerprints_alone(trained, tmp_path):
    """Tables measured on the model's own tracks of unlabelled slow users, weighed beside the
    measured ones, track such users better and the training users as well; the measured tables
    and the weights stay as trained."""
    run, _, va = trained
    others, pool = _walks(100, 6, (0.5, 2.0)), _walks(256, 5, (0.5, 2.0))
    before = Estimator.load(run)
    assert not bool(before.net.motion_adapted.fitted)
    est = Estimator.load(run).attach(pool)
    est.adapt_motion(noisy_bits(pool, 6.0, torch.Generator().manual_seed(9)))
    net = est.net
    assert bool(net.motion_adapted.fitted) and bool(net.motion_adapted_fine.fitted)
    for name in ("motion", "motion_fine", "motion_kind", "motion_walk"):
        assert torch.equal(getattr(net, name).log_accel_table, getattr(before.net, name).log_accel_table)
    assert all(torch.equal(p, q) for p, q in zip(net.parameters(), before.net.parameters(), strict=True))
    # the last hypothesis, at its own prior, its paths not weighed by the memory
    alts, priors, _, skips = est._alternative_motion()
    assert alts[-1] == (net.motion_adapted, net.motion_adapted_fine)
    assert priors[-1] == ADAPTED_PRIOR and len(alts) - 1 in skips
    # taken from every other model's prior in proportion: the measured tables' odds are kept
    _, plain, _, _ = Estimator.load(run).attach(pool)._alternative_motion()
    plain = np.asarray(plain)
    assert np.allclose(priors[:-1], (1 - ADAPTED_PRIOR) * plain)
    assert np.isclose(1 - sum(priors), (1 - ADAPTED_PRIOR) * (1 - plain.sum()))
    est.save(tmp_path / "model.pt")
    assert _tracked(tmp_path / "model.pt", others) < 0.98 * _tracked(run, others)
    assert _tracked(tmp_path / "model.pt", va) < 1.01 * _tracked(run, va)
    # measuring the tables again drops an adaptation made with the old ones
    assert not bool(est.net.fit_motion(va.positions, va.grid_xy, va.index).motion_adapted.fitted)
    with pytest.raises(EstimationError, match="attach"):
        Estimator.load(run).adapt_motion(torch.zeros(4, 5, 8, 12))
    with pytest.raises(EstimationError, match="at least 3 steps"):
        Estimator.load(run).attach(pool).adapt_motion(torch.zeros(4, 2, 8, 12))
    with pytest.raises(EstimationError, match="bits"):
        Estimator.load(run).attach(pool).adapt_motion(torch.full((4, 5, 8, 12), float("nan")))


def test_refit_cli_unlabelled(trained, tmp_path, capsys):
    run, _, _ = trained
    argv = ["refit", str(run), "--out", str(tmp_path / "u"), "--unlabelled", "--max-trajectories", "40"]
    assert main(argv) == 0
    shown = capsys.readouterr()
    assert "adapted" in shown.out and "40/40" in shown.err  # the tracking's progress bar
    motion = json.loads((tmp_path / "u" / "run.json").read_text())["motion"]
    assert motion["unlabelled_noise"] == 6.0 and motion["trajectories"] == 40
    adapted, trained_net = Estimator.load(tmp_path / "u").net, Estimator.load(run).net
    assert bool(adapted.motion_adapted.fitted) and not bool(trained_net.motion_adapted.fitted)
    assert torch.equal(adapted.motion.log_accel_table, trained_net.motion.log_accel_table)
    for extra, needle in (
        (["--noise", "nan"], "--noise"),
        (["--max-trajectories", "-1"], "--max-trajectories"),
    ):
        assert main(["refit", str(run), "--out", str(tmp_path / "v"), "--unlabelled", *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err
    assert not (tmp_path / "v").exists()
    assert (
        main(
            [
                "refit",
                str(run),
                "--out",
                str(tmp_path / "q"),
                "--unlabelled",
                "--max-trajectories",
                "8",
                "--quiet",
            ]
        )
        == 0
    )
    assert capsys.readouterr().err == ""


def test_predict_shows_its_progress_when_asked(trained, capsys):
    """A bar of the sequences done, on stderr, and the same positions as without it."""
    run, _, va = trained
    est = Estimator.load(run).attach(va)
    bits = noisy_bits(va, 6.0, torch.Generator().manual_seed(3))
    quiet = est.predict(bits)
    assert capsys.readouterr().err == ""
    shown = est.predict(bits, progress=True)
    err = capsys.readouterr().err
    assert torch.equal(quiet, shown) and f"{va.n}/{va.n}" in err and "predict" in err
