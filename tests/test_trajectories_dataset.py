"""End to end on a real (tiny) data set: `mmwsim generate`, then `mmwsim trajectories` into its store,
read back through `Dataset`, fingerprint-sequence batches, and `generate --resume` on a store that
holds trajectories."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import mmwsim.tracer
from mmwsim.cli import main
from mmwsim.dataset import Dataset
from mmwsim.trajectories import (
    SPLITS,
    SequenceLoader,
    TrajectoryError,
    list_splits,
    read_trajectories,
    split_attrs,
    write_trajectories,
)
from tests.helpers.rrd import check_blueprint, entity_rows

# 25 m grid over the default city, 2 reflections, few candidate rays: about a second to generate.
GENERATE = [
    "generate",
    "default",
    "--spacing",
    "25",
    "--max-reflections",
    "2",
    "--tile-size",
    "512",
    "--quiet",
]
COUNTS = ["--pedestrian", "30", "--vehicle", "10", "--hybrid", "10", "--static", "4"]
N = 54
RAYS = 100_000


def tree_bytes(root: Path, skip: str | None = None) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file() and (skip is None or p.relative_to(root).parts[0] != skip)
    }


@pytest.fixture(scope="module")
def rays():
    """The CLI traces with the tracer's default ray count; a small one keeps the test fast."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mmwsim.tracer, "DEFAULT_RAYS", RAYS)
        yield


@pytest.fixture(scope="module")
def made(tmp_path_factory, rays):
    """A data set, its bytes before trajectories, then trajectories written by the CLI."""
    folder = tmp_path_factory.mktemp("e2e")
    store, rrd = folder / "d.zarr", folder / "t.rrd"
    assert main(GENERATE + ["--out", str(store)]) == 0
    before = tree_bytes(store)
    argv = ["trajectories", str(store), *COUNTS, "--length", "7", "--seed", "1", "--rrd", str(rrd)]
    assert main(argv) == 0
    return store, rrd, before, argv


def test_trajectories_land_in_the_dataset(made):
    store, rrd, before, _ = made
    assert tree_bytes(store, skip="trajectories") == before  # the data set itself is untouched
    ds = Dataset.open(store)
    assert list_splits(ds) == list(SPLITS)
    parts = {s: read_trajectories(ds, s) for s in SPLITS}
    assert sum(len(t) for t in parts.values()) == N
    assert np.array_equal(np.sort(np.concatenate([t.ids for t in parts.values()])), np.arange(N))
    scene = ds.scene()
    spacing = ds.grid.spacing
    valid_xy = ds.positions[ds.valid, :2]
    for t in parts.values():
        assert t.positions.shape[1:] == (7, 2)
        assert t.attrs["dataset"] == ds.content_hash and t.attrs["scene"] == "default"
        pts = t.positions.reshape(-1, 2)
        # every sample lies in the cell (half a spacing either way) of a valid grid point
        cheb = np.abs(pts[:, None, :] - valid_xy[None]).max(axis=2).min(axis=1)
        assert cheb.max() <= spacing / 2 + 1e-9
        assert ds.valid[ds.nearest(t.positions)].all()
        assert scene.outdoors(pts).all()
    rows = entity_rows(rrd)
    # per trajectory: the whole track (static) and its trail and head at each of the 7 steps
    tracks = [e for e in rows if e.startswith("/trajectories/") and e.endswith("/true")]
    assert len(tracks) == N and all(rows[e] == 1 and rows[f"{e}/now"] == 7 for e in tracks)
    assert rows["/trajectories/map"] == 1
    check_blueprint(rrd, ["Trajectories", "Config"], "step")


def test_same_command_same_bytes_and_stray_partial_cleaned(made):
    store, _, _, argv = made
    first = tree_bytes(store / "trajectories")
    (store / ".trajectories.partial" / "junk").mkdir(parents=True)  # left by a killed run
    assert main(argv) == 0
    assert tree_bytes(store / "trajectories") == first
    assert not [p for p in store.iterdir() if p.name.startswith(".")]
    Dataset.open(store)


def test_fingerprint_sequence_batches(made):
    store = made[0]
    ds = Dataset.open(store)
    loader = SequenceLoader.from_dataset(ds, "train", batch_size=8, seed=5)
    assert loader.sampler is ds.sampler()  # the data set's cached fast sampler
    bits, pos = next(iter(loader))
    assert bits.shape == (8, 7, 32, 81) and bits.dtype == np.float32
    assert pos.shape == (8, 7, 2) and pos.dtype == np.float32
    assert set(np.unique(bits)) <= {0.0, 1.0} and bits.any()
    again = next(iter(loader))[0]  # next pass: fresh noise
    assert not np.array_equal(bits, again)
    replay = next(iter(SequenceLoader.from_dataset(ds, "train", batch_size=8, seed=5)))
    assert np.array_equal(replay[0], bits) and np.array_equal(replay[1], pos)
    # without noise the bits are the stored PDP rows of the nearest grid points, thresholded
    exact = SequenceLoader.from_dataset(ds, "train", batch_size=8, seed=5, sigma_db=0.0)
    bits0, pos0 = next(iter(exact))
    rows = ds.pdp.get_orthogonal_selection((ds.nearest(pos0).ravel(),)).astype(np.float32)
    want = rows[:, :, 1:82] >= ds.config["threshold_dbm"]
    assert np.array_equal(bits0.reshape(want.shape), want)
    linear = SequenceLoader.from_dataset(ds, "test", method="linear", batch_size=4)
    assert linear.sampler is None and next(iter(linear))[0].shape == (4, 7, 32, 81)


def test_traced_pdp_reproduces_the_grid(made):
    ds = Dataset.open(made[0])
    idx = np.flatnonzero(ds.valid)[:6]
    xy = ds.positions[idx, :2]
    traced = ds.traced_field().pdp_at(xy)
    stored = ds.field().pdp_at(xy)
    assert traced.shape == stored.shape == (6, 32, 81)
    fin = np.isfinite(stored)
    assert np.array_equal(fin, np.isfinite(traced))
    np.testing.assert_allclose(traced[fin], stored[fin], atol=0.13)  # float16 storage at ~100 dBm


def test_generate_resume_keeps_trajectories(made, capsys):
    store = made[0]
    everything = tree_bytes(store)
    assert main(GENERATE + ["--out", str(store), "--resume"]) == 0  # complete, same config: nothing to do
    assert tree_bytes(store) == everything
    assert main(GENERATE[:-1] + ["--out", str(store), "--resume"]) == 0  # with progress: says so
    assert "already complete" in capsys.readouterr().out
    assert main(GENERATE + ["--out", str(store)]) == 2  # no --resume: refuses to overwrite
    assert main(["generate", "default", "--spacing", "30", "--out", str(store), "--resume", "--quiet"]) == 2
    assert "another configuration" in capsys.readouterr().err
    assert tree_bytes(store) == everything
    assert read_trajectories(Dataset.open(store), "test").positions.shape[1:] == (7, 2)


def test_refusals(made, tmp_path, capsys):
    store = made[0]
    ds = Dataset.open(store)
    t = read_trajectories(ds, "train")
    t.attrs["dataset"] = "0" * 64
    with pytest.raises(TrajectoryError, match="generated for another data set"):
        write_trajectories(ds, {"train": t})
    assert list_splits(store) == list(SPLITS)
    # an unfinished data set next to the requested path: one line, nothing created
    unfinished = tmp_path / "u.zarr"
    shutil.copytree(store, tmp_path / "u.zarr.partial")
    assert main(["trajectories", str(unfinished), "--pedestrian", "3"]) == 2
    err = capsys.readouterr().err
    assert "generate --resume" in err and err.count("\n") == 1
    assert not unfinished.exists()
    # a data set's scene that is not its scene
    assert main(["trajectories", str(store), "--scene", "ground_only", "--pedestrian", "3"]) == 2
    assert "not the one this data set was generated from" in capsys.readouterr().err
    assert list_splits(store) == list(SPLITS)


def test_splits_carry_the_scenes_street_map_where_vehicles_keep_to_it(made, tmp_path):
    from estimation.adapter import GridTable, load_splits, street_lines
    from mmwsim.trajectories.streets import StreetNetwork

    # these trajectories' vehicles went anywhere (no --streets): no map
    ds = Dataset.open(made[0])
    assert split_attrs(ds, "train") == read_trajectories(ds, "train").attrs
    assert not split_attrs(ds, "train")["vehicles_on_streets"]
    assert street_lines(ds) is None and GridTable(ds).streets is None
    assert street_lines(object()) is None  # nor for data without a scene
    store = tmp_path / "d.zarr"
    shutil.copytree(made[0], store)
    shutil.rmtree(store / "trajectories")
    assert main(["trajectories", str(store), "--vehicle", "10", "--length", "5", "--streets"]) == 0
    ds = Dataset.open(store)
    sets, _ = load_splits(store, ("train", "test"), dataset=ds)
    lines = StreetNetwork.from_scene(ds.scene(), bounds=ds.grid.bounds).lines()
    for s in sets.values():
        assert np.array_equal(s.streets, lines)
        assert s.subset([0]).streets is s.streets and s.crop(1, 3).streets is s.streets
    assert np.array_equal(GridTable(ds).streets, lines)
    # the map is the one the generator's vehicles drove: their positions lie on its centre lines
    cars = read_trajectories(ds, "train").positions.reshape(-1, 2)
    a, b = lines[:, 0], lines[:, 1]
    f = np.clip(((cars[:, None] - a) * (b - a)).sum(-1) / ((b - a) ** 2).sum(-1), 0, 1)
    gap = np.linalg.norm(cars[:, None] - (a + f[..., None] * (b - a)), axis=-1).min(1)
    assert len(cars) and gap.max() < 1e-6
