"""Splits (disjoint trajectories, spatial hold-out), the zarr store, the CLI and the recording."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import trimesh

import scenes
from mmwsim.cli import main
from mmwsim.trajectories import (
    SPLITS,
    TrajectoryError,
    list_splits,
    read_trajectories,
    split,
    write_trajectories,
)
from mmwsim.trajectories import generate_trajectories as generate
from tests.helpers.rrd import entity_rows

REGION = (250.0, 250.0, 350.0, 350.0)


@pytest.fixture(scope="module")
def city():
    return scenes.load("default")


def _touches(positions: np.ndarray, region) -> np.ndarray:
    """Independent check: any segment of each trajectory meets the rectangle (one shapely line each)."""
    box = shapely.box(*region)
    return np.array([shapely.LineString(p).intersects(box) for p in positions])


def test_split_disjoint_and_complete(city):
    t = generate(city, {"pedestrian": 200, "vehicle": 100, "static": 20}, 7, seed=0)
    parts = split(t, (0.7, 0.2, 0.1), seed=3)
    ids = [set(parts[s].ids.tolist()) for s in SPLITS]
    assert all(not (a & b) for i, a in enumerate(ids) for b in ids[i + 1 :])
    assert set().union(*ids) == set(t.ids.tolist())
    assert [len(parts[s]) for s in SPLITS] == [224, 64, 32]
    for s in SPLITS:  # each split keeps the positions of its ids
        assert np.array_equal(parts[s].positions, t.positions[np.searchsorted(t.ids, parts[s].ids)])
    again = split(t, (0.7, 0.2, 0.1), seed=3)
    assert all(np.array_equal(parts[s].ids, again[s].ids) for s in SPLITS)


def test_spatial_holdout(city):
    t = generate(city, {"pedestrian": 300, "vehicle": 150}, 10, seed=1)
    parts = split(t, seed=0, holdout_region=REGION)
    for s in ("train", "validation"):
        assert not _touches(parts[s].positions, REGION).any()
        assert not parts[s].holdout.any()
    test = parts["test"]
    touching = _touches(test.positions, REGION)
    assert np.array_equal(touching, test.holdout)
    assert touching.sum() == _touches(t.positions, REGION).sum() > 10
    with pytest.raises(TrajectoryError, match="X0 < X1"):
        split(t, holdout_region=(5, 5, 1, 1))


def test_store_roundtrip_and_replace(tmp_path, city):
    t = generate(city, {"pedestrian": 30, "hybrid": 10}, 5, seed=2)
    parts = split(t, seed=1, holdout_region=REGION)
    store = tmp_path / "ds.zarr"
    write_trajectories(store, parts)
    assert list_splits(store) == list(SPLITS)
    for s in SPLITS:
        back = read_trajectories(store, s)
        for key in ("positions", "kind", "ids", "events", "holdout"):
            assert np.array_equal(getattr(back, key), getattr(parts[s], key))
        assert back.attrs["seed"] == 2 and back.attrs["split"] == s
    files = {p.relative_to(store): p.read_bytes() for p in store.rglob("*") if p.is_file()}
    write_trajectories(store, parts)  # same input, same bytes
    assert files == {p.relative_to(store): p.read_bytes() for p in store.rglob("*") if p.is_file()}
    write_trajectories(store, {"train": parts["train"]})
    assert list_splits(store) == ["train"]
    assert not [p for p in store.iterdir() if p.name.startswith(".")]
    with pytest.raises(TrajectoryError, match="no trajectory split 'test'"):
        read_trajectories(store, "test")


def test_cli_writes_splits_and_recording(tmp_path, capsys):
    store, rrd = tmp_path / "ds", tmp_path / "traj.rrd"
    argv = ["trajectories", str(store), "--scene", "default", "--pedestrian", "40", "--vehicle", "20",
            "--hybrid", "10", "--static", "5", "--length", "6", "--seed", "4", "--streets",
            "--holdout-region", "250,250,350,350", "--rrd", str(rrd)]  # fmt: skip
    assert main(argv) == 0
    assert "wrote 75 trajectories" in capsys.readouterr().out
    parts = {s: read_trajectories(store, s) for s in SPLITS}
    assert sum(len(p) for p in parts.values()) == 75
    assert np.array_equal(np.sort(np.concatenate([p.ids for p in parts.values()])), np.arange(75))
    assert not _touches(parts["train"].positions, REGION).any()
    rows = entity_rows(rrd)
    assert rows["/map/footprints"] == 1 and rows["/meta/config"] == 1
    tracks = [e for e in rows if e.startswith("/trajectories/") and e.endswith("/true")]
    assert len(tracks) == 75 and all(rows[e] == 1 and rows[f"{e}/now"] == 6 for e in tracks)
    # Same command, same arrays.
    first = read_trajectories(store, "train").positions
    assert main(argv) == 0
    assert np.array_equal(first, read_trajectories(store, "train").positions)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--length", "0"], "length must be 3..30"),
        (["--set", "pedestrian.mean_speed=-1"], "mean_speed must be a finite number >= 0"),
        (["--set", "pedestrian.speed=1"], "unknown motion parameter"),
        (["--pedestrian", "-2"], "must be an integer >= 0"),
        (["--holdout-region", "1,2,3"], "expected 4"),
        (["--holdout-region", "500,500,600,600"], "outside the area"),
        (["--split", "0,0,0"], "sum to 1"),
    ],
)
def test_cli_bad_parameters(tmp_path, capsys, extra, message):
    store = tmp_path / "ds"
    argv = ["trajectories", str(store), "--scene", "default", "--pedestrian", "3", *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not store.exists() or not (store / "trajectories").exists()


def test_cli_empty_free_area(tmp_path, capsys):
    box = trimesh.creation.box((100.0, 100.0, 30.0))
    box.apply_translation((50.0, 50.0, 15.0))
    path = tmp_path / "solid.obj"
    box.export(path)
    assert main(["trajectories", str(tmp_path / "ds"), "--scene", str(path), "--pedestrian", "3"]) == 2
    err = capsys.readouterr().err
    assert "no free area" in err and err.count("\n") == 1


def test_cli_missing_dataset(tmp_path, capsys):
    assert main(["trajectories", str(tmp_path / "nope"), "--pedestrian", "3"]) == 2
    assert "data set not found" in capsys.readouterr().err
