"""``mmwsim demo --tiny``: the whole chain runs and its one recording holds every stage."""

from __future__ import annotations

import json
import re
import sys
from collections import Counter

import numpy as np
import pytest
from rerun.chunk import RrdReader

from mmwsim import Dataset
from mmwsim.cli import main
from mmwsim.demo import MODEL
from mmwsim.trajectories import read_trajectories
from mmwsim.trajectories.motion import KINDS
from tests.helpers.rrd import blueprint_count, check_blueprint, entity_rows

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--tiny", "--out", str(out), "--seed", "1", "--quiet"]) == 0
    return out


def _rows_under(rows: Counter, prefix: str) -> int:
    return sum(n for path, n in rows.items() if path == prefix or path.startswith(prefix + "/"))


def _strip(path, entity: str) -> np.ndarray:
    """The one static 2D line strip logged at ``entity``, (n, 2)."""
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            strips = batch.column(batch.schema.names.index("LineStrips2D:strips")).to_pylist()
            return np.asarray(strips[0][0], dtype=np.float64)
    raise AssertionError(f"{entity} not in {path}")


def test_recording_holds_every_stage(demo, capsys):
    rrd = demo / "demo.rrd"
    rows = entity_rows(rrd)
    for family in (
        "/meta/config",
        "/world/scene",
        "/world/tx",
        "/world/rays",
        "/world/coverage",
        "/bff",
        f"/training/{MODEL}",
        "/planner/tree",
        "/planner/ellipse",
        "/planner/path",
        "/planner/cost",
        "/planner/corridor",
    ):
        assert _rows_under(rows, family) > 0, family
    ids = {path.split("/")[2] for path in rows if path.startswith("/trajectories/")} - {"map"}
    assert ids
    for ident in ids:
        assert rows[f"/trajectories/{ident}/true"] > 0 and rows[f"/trajectories/{ident}/{MODEL}"] > 0
    summary = json.loads((demo / "summary.json").read_text())
    assert rows[f"/training/{MODEL}/loss/validation"] == summary["epochs"] > 0
    # fingerprints and PDPs along the planned-along trajectory, one per step
    assert rows[f"/bff/trajectory_{summary['trajectory_id']}/fingerprint"] == 7
    timelines = set()
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        timelines.update(chunk.timeline_names)
    assert {"beam", "step", "epoch", "iteration"} <= timelines
    assert blueprint_count(rrd) == 1
    tabs = ["Scene", "Coverage", "Fingerprints", "Trajectories", "Training", "Planner", "Config"]
    check_blueprint(rrd, tabs, "beam")


def test_summary_matches_the_recording_and_the_data(demo):
    summary = json.loads((demo / "summary.json").read_text())
    rrd = demo / "demo.rrd"
    # The first trajectory shown is the one planned along: its true path is a stored held-out
    # trajectory, and the RMSE reported is that of the estimate drawn next to it.
    true = _strip(rrd, "/trajectories/test_holdout-0/true")
    estimate = _strip(rrd, f"/trajectories/test_holdout-0/{MODEL}")
    test = read_trajectories(demo / "dataset-tiny.zarr", "test")
    stored = test.positions[test.ids == summary["trajectory_id"]][0]
    assert test.holdout[test.ids == summary["trajectory_id"]][0]
    np.testing.assert_allclose(true, stored, atol=1e-4)
    rmse = np.sqrt(((estimate - true) ** 2).sum(axis=1).mean())
    assert rmse == pytest.approx(summary["rmse_m"], rel=1e-4)
    # The corridor is drawn around that estimate, and the planner's path is no shorter than the optimum.
    np.testing.assert_allclose(_strip(rrd, "/planner/corridor/trajectories"), estimate, atol=1e-4)
    assert summary["solved"]
    assert summary["optimum_m"] - 1e-6 <= summary["path_length_m"] < 1.5 * summary["optimum_m"]
    path = _strip(rrd, "/planner/optimum")
    assert np.linalg.norm(np.diff(path, axis=0), axis=1).sum() == pytest.approx(
        summary["optimum_m"], rel=1e-5
    )


def test_rerun_into_the_same_folder_resumes_with_the_same_results(demo, capsys):
    before = json.loads((demo / "summary.json").read_text())
    assert main(["demo", "--tiny", "--out", str(demo), "--seed", "1", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "reusing the finished data set" in out and "resuming tn" in out
    after = json.loads((demo / "summary.json").read_text())
    for key in ("trajectory_id", "rmse_m", "holdout_rmse_m", "path_length_m", "optimum_m", "epochs"):
        assert after[key] == before[key], key
    assert not list(demo.glob(".*partial*")) and not list(demo.glob(".*.rrd"))


@pytest.mark.parametrize(
    "args, words",
    [
        (["--seed", "-1"], "--seed"),
        (["--rrd", "demo.txt"], ".rrd"),
        (["--out", "FILE"], "not a folder"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, words):
    (tmp_path / "FILE").write_text("x")
    args = [str(tmp_path / a) if a in ("FILE", "demo.txt") else a for a in args]
    if "--out" not in args:
        args += ["--out", str(tmp_path / "out")]
    assert main(["demo", "--tiny", "--quiet", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err
    assert not (tmp_path / "out").exists()


def test_importing_the_demo_loads_neither_torch_nor_ompl():
    import subprocess
    import sys

    code = (
        "import sys, mmwsim.demo, mmwsim.cli.demo; "
        "sys.exit(1 if {'torch', 'ompl', 'estimation', 'planning'} & set(sys.modules) else 0)"
    )
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_floor_gap_benchmark_reads_the_demo(demo, capsys):
    """benchmarks/floor_gap.py: the demo's model against the oracle per kind, per event and along /
    across the motion, through the public API; a kind it does not know is refused with exit 2."""
    import importlib.util
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "floor_gap.py"
    if str(script.parent) not in sys.path:  # it imports its neighbour _common, as when run
        sys.path.insert(0, str(script.parent))
    spec = importlib.util.spec_from_file_location("floor_gap", script)
    floor_gap = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(floor_gap)
    run, data = str(demo / "runs" / f"{MODEL}-tiny"), str(demo / "dataset-tiny.zarr")
    assert floor_gap.main([run, data, "--n", "4", "--kinds", "pedestrian,vehicle"]) == 0
    out = capsys.readouterr().out
    for kind in ("pedestrian", "vehicle"):
        line = next(x for x in out.splitlines() if x.startswith(f"{kind} ("))
        ours, floor = (float(v) for v in re.findall(r"(?:tn-match|oracle) (\d+\.\d+)", line))
        # the ratio of the unrounded errors: within a rounding of the printed ones' ratio
        ratio = float(re.search(r"\((\d+\.\d+)x", line).group(1))
        assert (
            floor > 0 and abs(ratio - ours / floor) <= 0.005 + 0.0005 * (1 + ours / floor) / floor + 1e-9
        ), line
    assert "a step over 2 m off" in out and " event: " in out
    # over the kinds: their errors weighed by the test set's shares, the ratio inside its interval
    per = [
        [float(v) for v in re.findall(r"(?:tn-match|oracle) (\d+\.\d+)", x)]
        for x in out.splitlines()
        if x.startswith(("pedestrian (", "vehicle ("))
    ]
    line = next(x for x in out.splitlines() if x.startswith("the kinds at the test set's shares (4/4 users)"))
    ours, floor, ratio, lo, hi = (float(v) for v in re.findall(r"(\d+\.\d+)", line))
    test = read_trajectories(Dataset.open(data), "test")
    share = np.array(
        [(~test.holdout & (test.kind == KINDS.index(k))).sum() for k in ("pedestrian", "vehicle")]
    )
    share = share / share.sum()
    assert abs(ours - share @ [p[0] for p in per]) < 1e-3 and abs(floor - share @ [p[1] for p in per]) < 1e-3
    assert lo <= ratio <= hi
    # --skip passes over the first users: other users, other errors
    ours_of = {}
    for skip in ("0", "2"):
        assert floor_gap.main([run, data, "--n", "2", "--skip", skip, "--kinds", "pedestrian,vehicle"]) == 0
        line = next(
            x
            for x in capsys.readouterr().out.splitlines()
            if x.startswith("the kinds at") and "(2/2 users)" in x
        )
        ours_of[skip] = line.split(": ")[1].split(",")[0]
    assert ours_of["0"] != ours_of["2"]
    # a model at exactly twice the floor for every user has no spread in its ratio
    r0 = np.array([0.3, 0.5, 1.0])
    pairs = [(2 * r0, r0, 3.0), (4 * r0[:2], 2 * r0[:2], 1.0)]
    assert floor_gap._ratio_interval(pairs) == pytest.approx((2.0, 2.0))
    with pytest.raises(SystemExit) as e:
        floor_gap.main([run, data, "--kinds", "bicycle"])
    assert e.value.code == 2 and "bicycle" in capsys.readouterr().err
