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
    Trajectories,
    TrajectoryError,
    block_folds,
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


# ---------------------------------------------------------------- spatial block folds

AREA = (0.0, 0.0, 400.0, 400.0)


def _blocks_union(folds, f):
    return shapely.union_all([shapely.box(*r) for r in folds.blocks(f)])


def test_block_folds_cover_every_trajectory_once_and_follow_the_crossing_rule(city):
    t = generate(city, {"pedestrian": 300, "vehicle": 200, "static": 20}, 7, seed=4)
    folds = block_folds(t, 100.0, 4, bounds=AREA)
    n = len(t)
    tested = np.concatenate([folds.test(f) for f in range(4)])
    assert np.array_equal(np.sort(tested), np.arange(n))  # each trajectory tested in exactly one fold
    assert np.array_equal(folds.fold, folds.fold_at(t.positions[:, 3]))  # the middle sample's block
    for f in range(4):
        area = _blocks_union(folds, f)
        touching = np.array([shapely.LineString(p).intersects(area) for p in t.positions])
        assert np.array_equal(folds.touches[:, f], touching)
        train = folds.train(f)
        assert np.array_equal(train, np.flatnonzero(~touching))  # trains only on ones never touching
        assert not set(train) & set(folds.test(f))
        strict = folds.test(f, strict=True)
        assert set(strict) <= set(folds.test(f))
        assert all(area.covers(shapely.LineString(p)) for p in t.positions[strict])
    crossing = ~folds.inside
    assert 0 < crossing.sum() < n  # both occur: crossing ones are tested once, trained nowhere they touch
    assert (folds.touches.sum(axis=1) >= 1).all()


def test_block_folds_are_spatially_disjoint_latin_and_deterministic():
    folds = block_folds(np.zeros((0, 3, 2)), 100.0, 4, bounds=AREA)
    boxes = [[shapely.box(*r) for r in folds.blocks(f)] for f in range(4)]
    assert [len(b) for b in boxes] == [4, 4, 4, 4]
    union = [shapely.union_all(b) for b in boxes]
    for a in range(4):
        for b in range(a + 1, 4):
            assert shapely.intersection(union[a], union[b]).area == 0
    assert shapely.union_all(union).area == pytest.approx(400.0 * 400.0)
    table = folds.block_fold
    assert (np.diff(table, axis=0) != 0).all() and (np.diff(table, axis=1) != 0).all()  # no shared edge
    central = {int(table[j, i]) for j in (1, 2) for i in (1, 2)}
    assert central == {0, 1, 2, 3}  # each fold holds one block next to the centre
    # points take the fold of the block they are in, blocks half-open, the far edges closed
    pts = np.array([[50.0, 50.0], [100.0, 50.0], [399.0, 399.0], [400.0, 400.0], [-5.0, 450.0]])
    assert folds.fold_at(pts).tolist() == [table[0, 0], table[0, 1], table[3, 3], table[3, 3], table[3, 0]]

    rng = np.random.default_rng(0)
    pos = np.cumsum(rng.normal(0, 20, (200, 5, 2)), axis=1) + rng.uniform(0, 400, (200, 1, 2))
    a, b = block_folds(pos, 100.0, 4, bounds=AREA), block_folds(pos, 100.0, 4, bounds=AREA)
    assert np.array_equal(a.fold, b.fold) and np.array_equal(a.touches, b.touches)
    perm = rng.permutation(200)
    c = block_folds(pos[perm], 100.0, 4, bounds=AREA)
    assert np.array_equal(c.fold, a.fold[perm]) and np.array_equal(c.touches, a.touches[perm])


def test_block_folds_count_segments_and_borders():
    pos = np.array(
        [
            [[10.0, 10.0], [50.0, 10.0], [150.0, 10.0]],  # middle sample in block (0, 0), ends in (1, 0)
            [[95.0, 120.0], [95.0, 120.0], [120.0, 95.0]],  # its segment cuts across block (1, 1)
            [[20.0, 20.0], [30.0, 30.0], [40.0, 40.0]],  # wholly inside block (0, 0)
            [[100.0, 20.0], [100.0, 30.0], [100.0, 40.0]],  # on the border of (0, 0) and (1, 0)
        ]
    )
    folds = block_folds(pos, 100.0, 4, bounds=AREA)
    table = folds.block_fold
    f00, f10, f01, f11 = table[0, 0], table[0, 1], table[1, 0], table[1, 1]
    assert folds.fold.tolist() == [f00, f01, f00, f10]
    assert set(np.flatnonzero(folds.touches[0])) == {f00, f10}
    assert set(np.flatnonzero(folds.touches[1])) == {f01, f10, f11}  # no sample in (1, 1), a segment
    assert folds.inside.tolist() == [False, False, True, False]
    assert 0 in folds.test(f00) and 0 not in folds.test(f00, strict=True)
    assert 0 not in folds.train(f00) and 0 not in folds.train(f10) and 0 in folds.train(f11)
    assert 2 in folds.test(f00, strict=True)
    # bounds default to what generation stores
    t = Trajectories(pos, np.zeros(4), np.arange(4), np.zeros((4, 2)), attrs={"bounds": [[0, 0], [400, 400]]})
    assert np.array_equal(block_folds(t).touches, folds.touches)
    # an area that is not a multiple of the block: short last row and column, still every point in one
    odd = block_folds(pos, 150.0, 2, bounds=(0.0, 0.0, 400.0, 400.0))
    assert odd.block_fold.shape == (3, 3) and odd.blocks(0)[-1][2:] == (400.0, 400.0)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"block": 0.0}, "block side"),
        ({"block": float("nan")}, "block side"),
        ({"folds": 1}, "folds must be"),
        ({"folds": 17}, "folds must be"),
        ({"folds": 2.5}, "folds must be"),
        ({"bounds": (0, 0, -1, 5)}, "X0 < X1"),
    ],
)
def test_block_folds_bad_values(kwargs, message):
    args = {"block": 100.0, "folds": 4, "bounds": AREA} | kwargs
    with pytest.raises(TrajectoryError, match=message) as e:
        block_folds(np.zeros((2, 3, 2)), **args)
    assert len(str(e.value).splitlines()) == 1
    with pytest.raises(TrajectoryError, match="bounds"):
        block_folds(np.zeros((2, 3, 2)))
    with pytest.raises(TrajectoryError, match="fold must be"):
        block_folds(np.zeros((2, 3, 2)), bounds=AREA).test(4)
