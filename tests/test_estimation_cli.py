"""``mmwsim train`` / ``mmwsim evaluate`` end to end on toy data; the data-set adapter on a fake data set."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from estimation import EstimationError, load_splits
from mmwsim.cli import main
from mmwsim.scene import ReceiverGrid
from mmwsim.trajectories import KINDS
from tests.helpers.rrd import check_blueprint, entity_rows


def test_cli_does_not_load_torch():
    """The parser reads estimation's vocabularies (estimation.names) but loads no model code."""
    code = (
        "import sys, mmwsim, mmwsim.cli; mmwsim.cli.build_parser(); "
        "sys.exit(1 if {'torch', 'estimation.models', 'estimation.training'} & set(sys.modules) else 0)"
    )
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_train_then_evaluate(tmp_path, capsys):
    n = torch.get_num_threads()
    run = tmp_path / "gru"
    args = [
        "train",
        "toy:n=64,length=5",
        "--model",
        "gru",
        "--out",
        str(run),
        "--epochs",
        "2",
        "--quiet",
        "--threads",
        "1",
        "--option",
        "d=16",
    ]
    try:
        assert main(args) == 0
        assert (run / "model.pt").exists() and (run / "training.rrd").exists()
        assert main(args) == 2  # checkpoint exists, no --resume
        assert "--resume" in capsys.readouterr().err
        assert main(args + ["--resume", "--epochs", "3"]) == 0
        out = tmp_path / "report"
        rrd = tmp_path / "eval.rrd"
        assert (
            main(
                [
                    "evaluate",
                    str(run),
                    "knn-kalman",
                    "match-cv",
                    "--noise",
                    "6",
                    "9",
                    "--out",
                    str(out),
                    "--rrd",
                    str(rrd),
                    "--threads",
                    "1",
                    "--lengths",
                    "2",
                    "4",
                ]
            )
            == 0
        )
    finally:
        torch.set_num_threads(n)
    acc = (out / "accuracy.md").read_text()
    assert "| gru | 6 |" in acc and "| knn-kalman | 9 |" in acc and "test/holdout" in acc
    assert "| match-cv | 6 |" in acc
    assert "| gru |" in (out / "cost.md").read_text()
    for split in ("test_seen", "test_holdout"):
        for noise in (6, 9):
            png = out / f"error_vs_length_{split}_{noise}dB.png"
            assert png.read_bytes()[:4] == b"\x89PNG"
    rows = entity_rows(rrd)
    assert rows["/trajectories/test_seen-0/true"] == 1
    assert rows["/trajectories/test_seen-0/gru"] == 1 and rows["/trajectories/test_seen-0/knn-kalman"] == 1
    assert rows["/trajectories/test_seen-0/gru/now"] == 5  # one point per step
    check_blueprint(rrd, ["Trajectories"], "step")


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["evaluate", "knn-kalman"], "--dataset"),
        (["evaluate", "/nonexistent/run"], "not a run folder"),
        (["train", "toy:n=64,bogus=1", "--model", "tn", "--out", "OUT"], "unknown toy option"),
        (["train", "toy", "--model", "tn", "--out", "OUT", "--option", "nonsense=3"], "--option"),
        (["evaluate", "knn-kalman", "--dataset", "toy", "--noise", "-1"], "--noise"),
    ],
)
def test_bad_input_is_one_line(tmp_path, capsys, argv, needle):
    argv = [a.replace("OUT", str(tmp_path / "run")) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err


class FakeDataset:
    """The layout of ``mmwsim.Dataset``: grid, valid mask, per-beam PDP over 120 bins (dBm, -inf = none)."""

    def __init__(self):
        self.grid = ReceiverGrid(origin=(10.0, 20.0), spacing=2.0, shape=(6, 5))
        rng = np.random.default_rng(0)
        self.pdp = rng.uniform(-140, -90, (self.grid.size, 3, 120)).astype(np.float32)
        self.pdp[:, :, 100:] = -np.inf
        self.valid = np.ones(self.grid.size, dtype=bool)
        self.valid[7] = False  # (x=12, y=22) is inside a building
        self.threshold_dbm = -110.0


def test_adapter_on_a_fake_dataset(tmp_path):
    from mmwsim.trajectories import Trajectories, write_trajectories

    ds = FakeDataset()
    pos = np.array(
        [
            [[10.2, 20.1], [12.1, 21.8], [19.9, 27.9]],  # 2nd step's nearest point is invalid
            [[14.0, 24.0], [14.0, 24.0], [14.0, 24.0]],
        ]
    )
    kinds = np.array([KINDS.index("vehicle"), KINDS.index("static")])
    t = Trajectories(pos, kinds, np.arange(2), np.zeros((2, 2)), holdout=np.array([False, True]))
    store = tmp_path / "data.zarr"
    write_trajectories(store, {"train": t, "test": t})
    sets, info = load_splits(store, ("train", "test/holdout", "test/seen"), dataset=ds)
    s = sets["train"]
    assert s.grid_pdp.shape == (ds.grid.size - 1, 3, 81) and s.grid_pdp.dtype == torch.float16
    assert s.threshold == -110.0 and info["splits"] == {"train": 2, "test/holdout": 1, "test/seen": 1}
    xy = s.grid_xy[s.index]
    assert (
        np.allclose(xy[0, 0], [10, 20]) and np.allclose(xy[0, 2], [20, 28]) and np.allclose(xy[1], [14, 24])
    )
    assert np.linalg.norm(xy[0, 1] - [12, 22]) == pytest.approx(2.0)  # nearest *valid* point
    # bins 1..81 of the stored PDP, rows of the matched points
    flat = 0 + 6 * 0
    assert np.allclose(s.grid_pdp[s.index[0, 0]].float().numpy(), ds.pdp[flat, :, 1:82], atol=0.1)
    assert [KINDS[k] for k in s.kind] == ["vehicle", "static"]
    assert np.allclose(sets["test/holdout"].positions, pos[1:]) and np.allclose(
        sets["test/seen"].positions, pos[:1]
    )
    assert np.allclose(s.extent, [[10, 20], [20, 28]])
    with pytest.raises(EstimationError, match="no trajectory split"):
        load_splits(store, ("validation",), dataset=ds)


def test_forecasting_train_and_evaluate(tmp_path, capsys):
    n = torch.get_num_threads()
    run = tmp_path / "tn-forecast"
    try:
        assert (
            main(
                [
                    "train",
                    "toy:n=48,length=6",
                    "--model",
                    "tn",
                    "--task",
                    "forecasting",
                    "--t-obs",
                    "4",
                    "--horizon",
                    "2",
                    "--out",
                    str(run),
                    "--epochs",
                    "1",
                    "--quiet",
                    "--option",
                    "d=16",
                    "--option",
                    "ff=32",
                ]
            )
            == 0
        )
        out = tmp_path / "report"
        assert (
            main(
                [
                    "evaluate",
                    str(run),
                    "knn-kalman",
                    "--task",
                    "forecasting",
                    "--t-obs",
                    "4",
                    "--horizon",
                    "2",
                    "--noise",
                    "6",
                    "--split",
                    "test",
                    "--out",
                    str(out),
                    "--threads",
                    "1",
                ]
            )
            == 0
        )
    finally:
        torch.set_num_threads(n)
    acc = (out / "accuracy.md").read_text()
    assert "Forecasting accuracy" in acc and "| tn-forecast | 6 |" in acc and "| knn-kalman | 6 |" in acc
