"""The zarr data set: layout, attrs, lookups, stored paths and fingerprint sampling."""

import json

import numpy as np
import pytest

import mmwsim
from mmwsim.antennas import RotatingHorn
from mmwsim.dataset import Dataset, record_dataset
from mmwsim.dataset.generate import generate
from mmwsim.errors import MmwsimError
from mmwsim.fingerprints import power_delay_profile
from tests.helpers.rrd import check_blueprint, entity_rows

SMALL = dict(spacing=40.0, max_reflections=2, n_rays=100_000, tile_size=16, path_chunk=64, progress=False)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    return generate("default", tmp_path_factory.mktemp("ds") / "default.zarr", **SMALL)


def test_layout_and_attrs(store):
    ds = Dataset.open(store)
    assert ds.grid.shape == (11, 11) and ds.grid.spacing == 40.0
    assert ds.positions.shape == (121, 3)
    np.testing.assert_allclose(ds.positions[12], [40.0, 40.0, ds.grid.height])  # index = ix + nx iy
    assert ds.valid.dtype == bool and ds.valid.shape == (121,)
    assert ds.pdp.shape == (121, 32, 120) and ds.pdp.dtype == np.float16
    assert 20 < ds.valid.sum() < 121
    assert not (ds.valid & ~ds.outdoors).any()
    assert ds.version == mmwsim.__version__
    assert ds.config["max_reflections"] == 2 and ds.config["grid_spacing"] == 40.0
    assert len(ds.content_hash) == 64
    meta = json.loads((store / "grid" / "pdp" / "zarr.json").read_text())
    assert [c["name"] for c in meta["codecs"]] == ["bytes", "zstd"]
    assert not (store.parent / "default.zarr.partial").exists()


def test_summary_counts_valid_receivers_and_paths(store):
    """The store's summary (``n_valid``, ``n_paths``) is what its arrays hold."""
    ds = Dataset.open(store)
    info = ds.root.attrs["mmwsim"]
    assert info["complete"] is True
    assert info["n_valid"] == int(ds.valid.sum()) > 0
    assert info["n_paths"] == int(np.asarray(ds.root["grid/paths/count"][:]).sum()) > info["n_valid"]
    # valid means outdoors and detected: some noise-free PDP entry of the window at the threshold
    lo, hi = ds.config["bins"]
    detected = (np.asarray(ds.pdp[:])[:, :, lo:hi] >= ds.config["threshold_dbm"]).any(axis=(1, 2))
    np.testing.assert_array_equal(ds.valid, ds.outdoors & detected)


def test_valid_means_detected(store):
    ds = Dataset.open(store)
    pdp = ds.pdp[:].astype(np.float32)
    detected = (pdp[:, :, 1:82] >= -115.0).any(axis=(1, 2))
    np.testing.assert_array_equal(ds.valid, detected & ds.outdoors)
    # indoor receivers carry no signal at all
    assert np.isneginf(pdp[~ds.outdoors]).all()


def test_stored_paths_reproduce_the_pdp(store):
    ds = Dataset.open(store)
    idx = np.flatnonzero(ds.valid)[:10]
    paths = ds.paths(idx)
    assert paths.n_rx == 10 and paths.n_paths > 10
    again = power_delay_profile(paths, RotatingHorn(32))
    stored = ds.pdp.get_orthogonal_selection((idx,)).astype(np.float32)
    fin = np.isfinite(stored)
    np.testing.assert_array_equal(fin, np.isfinite(again))
    np.testing.assert_allclose(again[fin], stored[fin], atol=0.13)  # float16 rounding at ~100 dBm
    # another codebook needs no re-trace
    from mmwsim.antennas import PlanarArrayCodebook

    assert power_delay_profile(paths, PlanarArrayCodebook(4, 2)).shape == (10, 8, 120)


def test_nearest_and_fingerprints(store):
    ds = Dataset.open(store)
    np.testing.assert_array_equal(
        ds.nearest(np.array([[0.0, 0.0], [41.0, 19.0], [79.0, 21.0], [-9.0, 900.0]])), [0, 1, 13, 110]
    )
    idx = np.flatnonzero(ds.valid)[:5]
    rng = np.random.default_rng(0)
    a = ds.fingerprints(np.repeat(idx, 200), rng)
    b = ds.fingerprints(np.repeat(idx, 200), rng)
    assert a.shape == (1000, 32, 81) and a.dtype == np.uint8
    assert (a != b).any()
    assert a.any()


def test_open_errors_and_writable_root(store, tmp_path):
    with pytest.raises(MmwsimError, match="no data set"):
        Dataset.open(tmp_path / "missing.zarr")
    ds = Dataset.open(store, mode="r+")
    g = ds.root.require_group("trajectories/test")
    g.attrs["seed"] = 1
    assert Dataset.open(store).root["trajectories/test"].attrs["seed"] == 1
    del ds.root["trajectories"]


def test_recording(store, tmp_path):
    ds = Dataset.open(store)
    rrd = tmp_path / "ds.rrd"
    r = np.flatnonzero(ds.valid)[:2]
    record_dataset(ds, rrd, receivers=r)
    rows = entity_rows(rrd)
    assert rows["/world/coverage/beam_power"] == 32  # one image per beam
    assert rows["/world/coverage/best_beam"] == 1
    for i in r:
        assert rows[f"/bff/rx_{i}/pdp"] == 1
        assert rows[f"/bff/rx_{i}/fingerprint"] == 1
        assert rows[f"/bff/rx_{i}/beam_power"] == 32
    check_blueprint(rrd, ["Coverage", "Fingerprints", "Config"], "beam")
