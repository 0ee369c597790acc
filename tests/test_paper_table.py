"""benchmarks/paper_table.py on a toy data set: one protocol for every model, a resumable run
(killed mid-training, then continued), and the Markdown table and PNG plot it writes."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "paper_table.py"
TOY = "toy:n=48,length=7"


@pytest.fixture(scope="module")
def paper_table():
    if str(SCRIPT.parent) not in sys.path:  # the script imports its neighbour _common, as when run
        sys.path.insert(0, str(SCRIPT.parent))
    spec = importlib.util.spec_from_file_location("paper_table", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _args(out: Path, calibrate: bool = False) -> list[str]:
    return [
        *([] if calibrate else ["--no-calibrate"]),
        TOY,
        "--out",
        str(out),
        "--budget-minutes",
        "0.05",
        "--models",
        "conv1d",
        "gru",
        "--tasks",
        "tracking",
        "forecasting",
        "--noises",
        "6",
        "9",
        "--classical",
        "oracle",
        "knn-kalman",
    ]


def test_paper_table_resumes_and_writes_the_table(paper_table, tmp_path, capsys):
    out = tmp_path / "table"
    # Killed after the second epoch of the first run: the run keeps its checkpoint, no table yet.
    env = dict(os.environ, MMWSIM_FAULT="train.checkpointed@2:kill")
    killed = subprocess.run(
        [sys.executable, str(SCRIPT), *_args(out)], env=env, capture_output=True, text=True
    )
    assert killed.returncode != 0
    first = out / "runs" / "conv1d-tracking"
    assert (first / "checkpoint.pt").exists() and not (out / "paper_table.md").exists()

    # Rerun: the killed run continues from its checkpoint, the others train, all are evaluated.
    assert paper_table.main(_args(out)) == 0
    text = capsys.readouterr().out
    assert "conv1d-tracking: resuming after" in text and "resuming conv1d after epoch 2" in text
    runs = ("conv1d-tracking", "gru-tracking", "conv1d-forecasting", "gru-forecasting")
    for name in runs:
        assert (out / "runs" / name / "model.pt").exists()
    md = (out / "paper_table.md").read_text()
    assert "training budget 0.05 min per model" in md
    assert "wall-clock budget of 0.05 min per model" in md and "{" not in md.split("## Tracking")[0]
    tracking, rest = md.split("## Tracking", 1)[1].split("## Forecasting", 1)
    forecasting, cost = rest.split("## Cost", 1)
    for section in (tracking, forecasting):
        assert "6 dB seen veh." in section and "9 dB held-out all" in section
        assert "| conv1d |" in section and "| gru |" in section and "| knn-kalman |" in section
    for name in (*runs, "knn-kalman-tracking", "knn-kalman-forecasting"):
        assert f"| {name} |" in cost
    png = out / "error_vs_length.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000

    # A third run retrains and re-evaluates nothing.
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.pt")}
    assert paper_table.main(_args(out)) == 0
    text = capsys.readouterr().out
    assert text.count("finished before") == 4 and "evaluating" not in text and "cached" in text
    assert stamps == {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.pt")}

    # The table's tasks run one at a time in one folder: the one run before keeps its rows.
    only = _args(out)
    only[only.index("--tasks") + 1 : only.index("--noises")] = ["forecasting"]
    assert paper_table.main(only) == 0
    text = capsys.readouterr().out
    assert "[earlier] conv1d-tracking: cached" in text and "evaluating" not in text
    assert "[evaluate 2/4] conv1d-forecasting" in text  # numbered among this run's own
    assert (out / "paper_table.md").read_text() == md

    # Another protocol in the same folder is refused with one line.
    assert paper_table.main(_args(out) + ["--epoch-size", "16"]) == 2
    err = capsys.readouterr().err.strip()
    assert "another protocol" in err and "\n" not in err

    # A table at another budget in its own folder takes the classical trackers' evaluations from
    # this one (they do not depend on training) and evaluates its own runs.
    other = _args(tmp_path / "other") + ["--reuse", str(out)]
    other[other.index("--budget-minutes") + 1] = "0.03"
    other[other.index("--models") + 1 : other.index("--tasks")] = ["conv1d"]
    assert paper_table.main(other) == 0
    text = capsys.readouterr().out
    for key in ("knn-kalman-tracking", "knn-kalman-forecasting"):  # the oracle: not on toy data
        assert f"{key}: taken from {out}" in text
    assert "conv1d-tracking: evaluating" in text and "conv1d-forecasting: evaluating" in text
    # ... but not where the test draws differ
    other = _args(tmp_path / "third") + ["--reuse", str(out), "--max-test", "5", "--models", "conv1d"]
    assert paper_table.main(other) == 0
    text = capsys.readouterr().out
    assert "taken from" not in text and "knn-kalman-tracking: evaluating" in text


def test_paper_table_sizes_a_cosine_recipe_on_a_probe_epoch(paper_table, tmp_path, capsys):
    out = tmp_path / "table"
    args = [*_args(out, calibrate=True), "--no-fill-budget"]
    args[args.index("--budget-minutes") + 1] = "0.3"
    args[args.index("--tasks") + 1 : args.index("--noises")] = ["tracking"]
    args[args.index("--models") + 1 : args.index("--tasks")] = ["gru"]
    assert paper_table.main(args) == 0
    text = capsys.readouterr().out
    assert "gru-tracking: probe epochs" in text
    cal = json.loads((out / "cache" / "calibration-gru-tracking.json").read_text())
    assert len(cal["probe_seconds"]) == 2  # a warm-up epoch and a sequence epoch
    assert max(2, cal["scaled"]) <= cal["epochs"] <= 200  # extended to the budget, never shortened
    assert "fill_budget" not in json.loads((out / "protocol.json").read_text())
    assert not list((out / "cache").glob("probe-*"))  # the probe's run is gone
    info = json.loads((out / "runs" / "gru-tracking" / "run.json").read_text())
    assert info["config"]["epochs"] == cal["epochs"]
    # the probe's time counts against the budget: the run starts with what the probe left
    left = float(text.split("gru-tracking: training, ", 1)[1].split(" s left", 1)[0])
    assert left == pytest.approx(max(0.3 * 60 - sum(cal["probe_seconds"]), 0.0), abs=0.51)


def test_paper_table_fill_budget_extends_a_recipe_past_its_own_length(paper_table, tmp_path, capsys):
    from estimation.adapter import load_sets

    sets, _ = load_sets(TOY, ("train", "validation"))
    base = dict(model="gru", task="forecasting", sigma=6.0, patience=8, epoch_size=48, seed=0)
    (tmp_path / "cache").mkdir()
    from estimation.models import model_spec

    own = model_spec("gru").recipe["epochs"]
    # a budget of days holds far more toy epochs than the recipe's, however loaded the machine:
    # the cap alone bounds them
    args = (base, 1e6, 3 * own, sets, tmp_path, "gru-forecasting", "gru")
    settings, _ = paper_table._calibrated(*args, fill=True)
    assert settings["epochs"] == 3 * own
    assert f"-> {3 * own} epochs in the budget" in capsys.readouterr().out


def test_paper_table_fills_the_budget_by_default(paper_table, tmp_path, monkeypatch, capsys):
    asked = []

    def calibrated(*args, fill):
        asked.append(fill)
        return {"epochs": 2}, 0.0

    monkeypatch.setattr(paper_table, "_calibrated", calibrated)
    out = tmp_path / "table"
    args = _args(out, calibrate=True)
    args[args.index("--models") + 1 : args.index("--tasks")] = ["gru"]
    args[args.index("--tasks") + 1 : args.index("--noises")] = ["forecasting"]
    assert paper_table.main(args) == 0
    assert asked == [True]
    assert json.loads((out / "protocol.json").read_text())["fill_budget"] is True
    assert "past the recipe's own length" in (out / "paper_table.md").read_text()
    # a folder made under the default is not continued without it, nor one made before it with it
    capsys.readouterr()
    assert paper_table.main([*args, "--no-fill-budget"]) == 2
    assert "fill_budget True != None" in capsys.readouterr().err
    older = tmp_path / "older"
    assert paper_table.main([*_args(older, calibrate=True), "--no-fill-budget", "--models", "gru",
                             "--tasks", "forecasting"]) == 0  # fmt: skip
    capsys.readouterr()
    assert paper_table.main([*_args(older, calibrate=True), "--models", "gru", "--tasks", "forecasting"]) == 2
    assert "fill_budget None != True" in capsys.readouterr().err


@pytest.mark.parametrize(
    "bad",
    [
        ["--budget-minutes", "0"],
        ["--models", "lstm", "bert"],
        ["--noises", "nan"],
        ["--tasks", "planning"],
        ["--max-trajectories", "-1"],
        ["--reuse", "/nonexistent-table"],
    ],
)
def test_paper_table_bad_arguments(paper_table, tmp_path, capsys, bad):
    assert paper_table.main([TOY, "--out", str(tmp_path / "t"), *bad]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("paper_table.py: error:") and "\n" not in err
    assert not (tmp_path / "t").exists()
