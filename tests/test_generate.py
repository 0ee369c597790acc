"""`mmwsim generate`: resumable, executor-independent bytes, and one-line errors."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mmwsim.cli import main
from mmwsim.dataset import Dataset
from mmwsim.dataset.generate import generate
from mmwsim.dataset.store import MARKER, StoreWriter
from tests.helpers.rrd import check_blueprint

SMALL = dict(spacing=40.0, max_reflections=2, n_rays=100_000, tile_size=16, path_chunk=64, progress=False)


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = generate("default", tmp_path_factory.mktemp("ref") / "d.zarr", **SMALL)
    return tree_bytes(out)


def test_interrupted_mid_tile_and_resumed_gives_same_bytes(tmp_path, monkeypatch, reference):
    out = tmp_path / "d.zarr"
    original = StoreWriter.write
    calls = {"n": 0}

    def dying_write(self, result):
        calls["n"] += 1
        if calls["n"] == 4:
            # die in the middle of tile 3: some of its arrays written, nothing committed
            self.root["grid/pdp"][self.cfg.tile_range(result.tile)[0]] = 0.0
            self.root["grid/paths/delay"].resize((self.slots + 64,))
            raise KeyboardInterrupt
        original(self, result)

    monkeypatch.setattr(StoreWriter, "write", dying_write)
    with pytest.raises(KeyboardInterrupt):
        generate("default", out, **SMALL)
    assert not out.exists()
    assert json.loads((tmp_path / "d.zarr.partial" / MARKER).read_text())["tiles_done"] == 3
    monkeypatch.setattr(StoreWriter, "write", original)
    generate("default", out, resume=True, **SMALL)
    assert tree_bytes(out) == reference


def test_killed_process_resumes_to_same_bytes(tmp_path, reference):
    out = tmp_path / "d.zarr"
    code = (
        "from mmwsim.dataset.generate import generate; "
        f"generate('default', {str(out)!r}, spacing=40.0, max_reflections=2, n_rays=100_000, "
        "tile_size=16, path_chunk=64, progress=False)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code])
    marker = tmp_path / "d.zarr.partial" / MARKER
    deadline = time.time() + 60
    while time.time() < deadline and proc.poll() is None:
        try:
            if json.loads(marker.read_text())["tiles_done"] >= 2:
                break
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    generate("default", out, resume=True, **SMALL)
    assert tree_bytes(out) == reference


def test_two_workers_give_same_bytes(tmp_path, reference):
    out = generate("default", tmp_path / "d.zarr", workers=2, **SMALL)
    assert tree_bytes(out) == reference


def test_dask_cluster_gives_same_bytes(tmp_path, reference):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
    ) as cluster:
        out = generate("default", tmp_path / "d.zarr", scheduler=cluster.scheduler_address, **SMALL)
    assert tree_bytes(out) == reference


def one_error_line(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_cli_generates_and_resumes(tmp_path, capsys):
    out = tmp_path / "g.zarr"
    rrd = tmp_path / "g.rrd"
    argv = ["generate", "ground_only", "--out", str(out), "--max-reflections", "1", "--quiet"]
    assert main(argv + ["--spacing", "25", "--rrd", str(rrd)]) == 0
    assert "wrote" in capsys.readouterr().out and rrd.is_file()
    check_blueprint(rrd, ["Scene", "Coverage", "Fingerprints", "Config"], "beam")
    ds = Dataset.open(out)
    assert ds.grid.shape == (5, 5)
    # open ground: every receiver sees the TX, except the one 8.5 m below it, whose paths
    # arrive in bin 0, outside the fingerprint window 1..81
    assert ds.valid.sum() == 24 and not ds.valid[12]
    before = sorted(p.stat().st_mtime_ns for p in out.rglob("*"))
    assert main(argv[:-1] + ["--spacing", "25", "--resume"]) == 0  # already complete, same config
    assert sorted(p.stat().st_mtime_ns for p in out.rglob("*")) == before
    assert "already complete" in capsys.readouterr().out
    assert "already exists" in one_error_line(capsys, argv + ["--spacing", "25"])
    assert "another configuration" in one_error_line(capsys, argv + ["--spacing", "20", "--resume"])


def test_cli_bad_inputs(tmp_path, capsys):
    assert "no_such_scene" in one_error_line(
        capsys, ["generate", "no_such_scene", "--out", str(tmp_path / "x")]
    )
    line = one_error_line(capsys, ["generate", "free_space", "--out", str(tmp_path / "nope" / "x.zarr")])
    assert "not writable" in line
    assert not (tmp_path / "nope").exists()
    assert "--spacing" in one_error_line(capsys, ["generate", "free_space", "--spacing", "-1"])
    assert "--workers" in one_error_line(capsys, ["generate", "free_space", "--workers", "0"])


def test_cli_tx_for_a_scene_without_transmitter(tmp_path, monkeypatch, capsys):
    import trimesh

    import mmwsim.tracer
    from mmwsim.cli import main
    from mmwsim.dataset import Dataset
    from scenes.layout import Building, building_mesh, ground_mesh

    monkeypatch.setattr(mmwsim.tracer, "DEFAULT_RAYS", 100_000)
    mesh = tmp_path / "city.ply"
    trimesh.util.concatenate(
        [ground_mesh(0, 0, 60, 60), building_mesh([Building(20, 20, 40, 40, 10)])]
    ).export(mesh)
    out = tmp_path / "city.zarr"
    assert main(["generate", str(mesh), "--spacing", "10", "--out", str(out), "--quiet"]) == 2
    assert "has no transmitter" in capsys.readouterr().err and not out.exists()
    assert (
        main(["generate", str(mesh), "--tx", "10,10,8", "--spacing", "10", "--out", str(out), "--quiet"]) == 0
    )
    ds = Dataset.open(out)
    assert tuple(ds.config["transmitter"]) == (10.0, 10.0, 8.0)
    assert ds.valid.sum() > 0 and not ds.valid[ds.nearest(np.array([[30.0, 30.0]]))].any()
