"""Hostile but fair inputs to every subcommand: one line, exit 2, no traceback, nothing left behind.

Most cases run the CLI in this process (``mmwsim.cli.main``) with stderr and warnings captured;
what needs a real process (kills, locks held by another process, worker processes) runs
``python -m mmwsim``. Kill points and full disks are injected with ``MMWSIM_FAULT`` (see
:mod:`mmwsim.faults`), never by timing.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from mmwsim import faults
from mmwsim.cli import main
from mmwsim.dataset import generate_dataset as generate
from mmwsim.locks import OutputLock, lock_path
from mmwsim.trajectories import read_trajectories
from tests.helpers.scenes import write_scene_folder

REPO = Path(__file__).resolve().parents[1]
# A data set that takes a fraction of a second: 5 x 5 receivers in 4 tiles over open ground.
GEN = ["ground_only", "--spacing", "25", "--max-reflections", "1", "--rays", "20000", "--tile-size", "8"]
GEN_KW = dict(spacing=25.0, max_reflections=1, n_rays=20000, tile_size=8, progress=False)
TOY = "toy:n=64,length=5"


# ---------------------------------------------------------------------- helpers
@pytest.fixture(autouse=True)
def _fresh_fault_counts():
    faults._hits.clear()
    yield
    faults._hits.clear()


def tree(root: Path) -> dict[str, bytes | None]:
    """Every path under ``root`` (hidden ones too) with the bytes of files."""
    return {
        str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))
    }


def refused(capsys, argv: list[str], *words: str) -> str:
    """Run the CLI here; it must exit 2 with one line naming ``words``, and warn nothing."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        status = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert status == 2, err
    assert len(lines) == 1 and lines[0].startswith("mmwsim: "), err
    assert not caught, [str(w.message) for w in caught]
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def cli(
    *argv, env: dict | None = None, cwd: Path | None = None, timeout: float = 120
) -> subprocess.CompletedProcess:
    """``python -m mmwsim ARGV`` in a real process."""
    full_env = {**os.environ, "PYTHONPATH": str(REPO), **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "mmwsim", *map(str, argv)],
        env=full_env,
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def one_line(proc: subprocess.CompletedProcess, *words: str) -> str:
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def start(*argv, env: dict) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "mmwsim", *map(str, argv)],
        env={**os.environ, "PYTHONPATH": str(REPO), **env},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_for(condition, timeout: float = 60.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def hanging(proc: subprocess.Popen, point: str, count: int = 1, timeout: float = 60.0) -> list[int]:
    """Wait until ``count`` processes of ``proc`` hang at fault ``point``; their process ids."""
    import select

    pids, buffer = [], ""
    deadline = time.monotonic() + timeout
    while len(pids) < count:
        left = deadline - time.monotonic()
        if left <= 0 or proc.poll() is not None:
            raise AssertionError(f"no hang at {point}: {buffer}")
        if select.select([proc.stderr], [], [], left)[0]:
            buffer += os.read(proc.stderr.fileno(), 4096).decode()
            pids = [
                int(line.rsplit("pid ", 1)[1].rstrip(")"))
                for line in buffer.splitlines()
                if f"{point}: hanging" in line
            ]
    return pids


def killed(proc: subprocess.Popen) -> None:
    """Wait for ``proc``, killed with SIGKILL (children that outlive it may hold its stderr open)."""
    proc.wait(timeout=120)
    proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory) -> Path:
    return write_scene_folder(tmp_path_factory.mktemp("scene") / "tiny")


def scene_variant(folder: Path, old: str, new: str) -> Path:
    """A copy of the tiny scene with one line of its TOML changed."""
    path = write_scene_folder(folder)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    return path


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict:
    """The bytes of the small data set, generated without interruption."""
    return tree(generate("ground_only", tmp_path_factory.mktemp("ref") / "d.zarr", **GEN_KW))


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    """A small data set with trajectory splits (read-only for the tests: copy it to change it)."""
    out = generate("ground_only", tmp_path_factory.mktemp("store") / "d.zarr", **GEN_KW)
    assert main(["trajectories", str(out), "--pedestrian", "30", "--length", "5", "--seed", "1"]) == 0
    return out


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("runs") / "lstm"
    assert main(["train", TOY, "--model", "lstm", "--epochs", "1", "--out", str(run), "--quiet"]) == 0
    return run


# ---------------------------------------------------------------------- the catalogue of issue 20
@pytest.mark.parametrize(
    "old, new, words",
    [
        ("spacing = 2.0", "spacing = inf", ("receivers.spacing", "finite")),
        ("shape = [51, 51]", "shape = [100000000, 100000000]", ("100000000 x 100000000", "PiB")),
        ("height = 1.5", "height = -5", ("height -5 m", "not above the scene")),
        ("origin = [0.0, 0.0]", "origin = [nan, 0.0]", ("receivers.origin", "finite")),
        ("position = [5.0, 5.0, 10.0]", "position = [5.0, 5.0, -10.0]", ("transmitter", "below the scene")),
    ],
)
def test_bad_receiver_grid_is_refused_by_show_and_generate(tmp_path, capsys, old, new, words):
    toml = scene_variant(tmp_path / "s", old, new)
    refused(capsys, ["scene", "show", toml], *words)
    before = tree(tmp_path)
    refused(capsys, ["generate", toml, "--out", tmp_path / "x.zarr", "--quiet"], *words)
    assert tree(tmp_path) == before  # no x.zarr.partial, no lock


def test_ply_with_a_nan_vertex_names_the_nan(tmp_path, capsys):
    ply = tmp_path / "nan.ply"
    ply.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\nnan 1 0\n0 1 0\n3 0 1 2\n"
    )
    refused(capsys, ["scene", "show", ply], "non-finite vertex")


@pytest.mark.parametrize(
    "transform",
    [
        '<scale value="nan"/>',
        '<rotate x="1" angle="inf"/>',
        '<translate x="nan"/>',
        '<matrix value="1 0 0"/>',
    ],
)
def test_xml_transform_with_non_finite_values_is_one_line_without_warnings(tmp_path, capsys, transform):
    write_scene_folder(tmp_path)
    xml = tmp_path / "scene.xml"
    xml.write_text(
        '<scene version="2.1.0"><bsdf type="itu-radio-material" id="c"><string name="type" value="concrete"/>'
        '</bsdf><shape type="ply" id="mesh-ground"><string name="filename" value="meshes/ground.ply"/>'
        f'<ref id="c"/><transform name="to_world">{transform}</transform></shape></scene>'
    )
    refused(capsys, ["scene", "show", xml], "malformed", "transform")


def test_xml_scale_nan_in_a_real_process_prints_one_line(tmp_path):
    write_scene_folder(tmp_path)
    xml = tmp_path / "scene.xml"
    xml.write_text(
        '<scene version="2.1.0"><bsdf type="itu-radio-material" id="c"><string name="type" value="concrete"/>'
        '</bsdf><shape type="ply" id="g"><string name="filename" value="meshes/ground.ply"/><ref id="c"/>'
        '<transform name="to_world"><scale value="nan"/></transform></shape></scene>'
    )
    one_line(cli("scene", "show", xml), "scale transform")


def test_trace_rays_zero_is_refused(capsys):
    refused(capsys, ["trace", "ground_only", "--rx", "10,10,1.5", "--rays", "0"], "--rays")


@pytest.mark.parametrize("rx", ["100000,100,1.5", "10,10,-1.5"])
def test_trace_receiver_outside_the_scene_is_refused_before_tracing(capsys, rx):
    refused(capsys, ["trace", "ground_only", "--rx", rx, "--rays", "1000"], "outside the scene")


def test_generate_onto_an_existing_file_with_resume(tmp_path, capsys):
    (tmp_path / "afile").write_text("mine")
    before = tree(tmp_path)
    refused(
        capsys,
        ["generate", *GEN, "--out", tmp_path / "afile", "--resume", "--quiet"],
        "not an mmwsim data set",
    )
    assert tree(tmp_path) == before


def test_generate_onto_a_full_disk_before_the_first_tile_keeps_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("MMWSIM_FAULT", "dataset.tile@1:enospc")
    refused(
        capsys, ["generate", *GEN, "--out", tmp_path / "d.zarr", "--quiet"], "d.zarr.partial", "disk is full"
    )
    assert tree(tmp_path) == {}


def test_generate_onto_a_full_disk_later_is_resumable_to_the_same_bytes(
    tmp_path, capsys, monkeypatch, reference
):
    monkeypatch.setenv("MMWSIM_FAULT", "dataset.tile@3:enospc")
    out = tmp_path / "d.zarr"
    refused(capsys, ["generate", *GEN, "--out", out, "--quiet"], "disk is full", "--resume")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.zarr.partial"]
    monkeypatch.delenv("MMWSIM_FAULT")
    assert main(["generate", *GEN, "--out", str(out), "--resume", "--quiet"]) == 0
    assert tree(out) == reference


def test_generate_creating_the_store_on_a_read_only_file_system(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("MMWSIM_FAULT", "dataset.create:erofs")
    refused(capsys, ["generate", *GEN, "--out", tmp_path / "d.zarr", "--quiet"], "read-only")
    assert tree(tmp_path) == {}


def test_trajectories_split_must_sum_to_one(capsys, store):
    before = tree(store)
    refused(
        capsys, ["trajectories", store, "--pedestrian", "5", "--split", "0.5,0.5,0.5"], "--split", "sum to 1"
    )
    assert tree(store) == before


@pytest.mark.parametrize("where", ["zarr.json", "grid/pdp/zarr.json", "trajectories/zarr.json"])
def test_garbage_metadata_is_one_line_for_trajectories_and_train(tmp_path, capsys, store, where):
    bad = tmp_path / "bad.zarr"
    shutil.copytree(store, bad)
    (bad / where).write_text("garbage")
    before = tree(tmp_path)
    if where != "trajectories/zarr.json":  # trajectories replace that group whatever it holds
        refused(capsys, ["trajectories", bad, "--pedestrian", "5"], str(bad), "not a readable")
    refused(capsys, ["train", bad, "--model", "lstm", "--out", tmp_path / "run", "--quiet"], "not a readable")
    assert tree(tmp_path) == before


def test_train_lr_nan_leaves_no_run_folder(tmp_path, capsys):
    refused(capsys, ["train", TOY, "--model", "lstm", "--out", tmp_path / "runs" / "x", "--lr", "nan"], "lr")
    assert tree(tmp_path) == {}


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--noise", "nan"], ("--noise",)),
        (["--noise", "-1"], ("--noise",)),
        (["--lengths", "0", "50"], ("--lengths",)),
        (["--lengths", "50"], ("1..5",)),
        (["--table-length", "0"], ("--table-length",)),
        (["--threads", "100000"], ("--threads",)),
    ],
)
def test_evaluate_bad_numbers_leave_no_report(tmp_path, capsys, run_folder, extra, words):
    refused(capsys, ["evaluate", run_folder, "--out", tmp_path / "reports" / "r", *extra], *words)
    assert tree(tmp_path) == {}


def test_train_on_a_read_only_file_system_leaves_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("MMWSIM_FAULT", "file.write:erofs")
    refused(capsys, ["train", TOY, "--model", "lstm", "--out", tmp_path / "run", "--quiet"], "read-only")
    assert tree(tmp_path) == {}


def test_evaluate_on_a_read_only_file_system_leaves_nothing(tmp_path, capsys, monkeypatch, run_folder):
    monkeypatch.setenv("MMWSIM_FAULT", "report.write:erofs")
    refused(capsys, ["evaluate", run_folder, "--noise", "6", "--out", tmp_path / "report"], "read-only")
    assert tree(tmp_path) == {}


def test_evaluate_out_is_an_existing_file(tmp_path, capsys, run_folder):
    (tmp_path / "report").write_text("mine")
    refused(capsys, ["evaluate", run_folder, "--out", tmp_path / "report"], "not a folder")
    assert (tmp_path / "report").read_text() == "mine" and len(tree(tmp_path)) == 1


@pytest.mark.parametrize("content", ["[1,2,3]", '{"summary": [1]}', '{"data": {"dataset": 5}}', "{"])
def test_run_json_that_is_not_a_run_description(tmp_path, capsys, run_folder, content):
    run = tmp_path / "run"
    shutil.copytree(run_folder, run)
    (run / "run.json").write_text(content)
    refused(capsys, ["evaluate", run, "--out", tmp_path / "report"], "run.json")
    assert not (tmp_path / "report").exists()


def _immutable(folder: Path) -> bool:
    """Make ``folder`` immutable (root only, ext4 and the like); False where that is not possible."""
    if shutil.which("chattr") is None or os.geteuid() != 0:
        return False
    return subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode == 0


@pytest.mark.parametrize("command", ["train", "evaluate", "generate", "trajectories"])
def test_outputs_in_an_immutable_folder(tmp_path, capsys, run_folder, command):
    folder = tmp_path / "locked"
    folder.mkdir()
    if not _immutable(folder):
        pytest.skip("chattr +i needs root and a file system that supports it")
    try:
        argv = {
            "train": ["train", TOY, "--model", "lstm", "--out", folder / "run", "--quiet"],
            "evaluate": ["evaluate", run_folder, "--out", folder / "report"],
            "generate": ["generate", *GEN, "--out", folder / "d.zarr", "--quiet"],
            "trajectories": [
                "trajectories",
                folder / "t.zarr",
                "--scene",
                "ground_only",
                "--pedestrian",
                "3",
            ],
        }[command]
        refused(capsys, argv, str(folder), "cannot write")
        assert list(folder.iterdir()) == []
    finally:
        subprocess.run(["chattr", "-i", str(folder)], check=True)


# ---------------------------------------------------------------------- one writer per output
def test_second_generate_is_refused_naming_the_first_and_a_killed_ones_lock_is_taken_over(
    tmp_path, capsys, reference
):
    out = tmp_path / "d.zarr"
    first = start("generate", *GEN, "--out", out, "--quiet", env={"MMWSIM_FAULT": "dataset.committed@1:hang"})
    try:
        marker = tmp_path / "d.zarr.partial" / ".mmwsim-progress.json"
        wait_for(lambda: marker.exists() and '"tiles_done": 1' in marker.read_text(), what="the first tile")
        line = refused(capsys, ["generate", *GEN, "--out", out, "--resume", "--quiet"], "being written by")
        assert f"process {first.pid} on " in line and "generate" in line
        refused(capsys, ["trajectories", out, "--pedestrian", "3"], "not finished")
    finally:
        first.kill()
    killed(first)
    assert lock_path(out).exists()  # left by the killed process, stale
    assert main(["generate", *GEN, "--out", str(out), "--resume", "--quiet"]) == 0
    assert tree(out) == reference
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.zarr"]


def test_lock_records_its_holder_and_is_reentrant(tmp_path):
    out = tmp_path / "run"
    with OutputLock(out, "run folder") as lock:
        holder = json.loads(lock.path.read_text())
        assert holder["pid"] == os.getpid() and holder["host"] and holder["started"]
        with OutputLock(out):  # the same process may lock again (a command around a library call)
            pass
        assert lock.held and lock.path.exists()
        code = f"from mmwsim.locks import OutputLock; OutputLock({str(out)!r}, 'run folder').acquire()"
        proc = subprocess.run(
            [sys.executable, "-c", code],
            env={**os.environ, "PYTHONPATH": str(REPO)},
            capture_output=True,
            text=True,
        )
        assert proc.returncode == 1 and f"process {os.getpid()}" in proc.stderr
    assert not lock.path.exists()


def test_stale_lock_file_of_a_dead_process_is_taken_over(tmp_path, capsys, run_folder):
    report = tmp_path / "report"
    dead = {"pid": 2**22 + 7, "host": "elsewhere", "started": "2020-01-01 00:00:00", "command": "x"}
    lock_path(report).write_text(json.dumps(dead))
    assert main(["evaluate", str(run_folder), "--noise", "6", "--out", str(report)]) == 0
    assert (report / "accuracy.md").exists() and not lock_path(report).exists()


def test_second_trainer_into_a_run_folder_is_refused(tmp_path, capsys):
    run = tmp_path / "run"
    first = start(
        "train", TOY, "--model", "lstm", "--out", run, "--quiet", env={"MMWSIM_FAULT": "train.epoch@1:hang"}
    )
    try:
        wait_for(lambda: (run / "run.json").exists(), what="the first trainer")
        line = refused(
            capsys, ["train", TOY, "--model", "lstm", "--out", run, "--resume", "--quiet"], "being written"
        )
        assert f"process {first.pid}" in line
    finally:
        first.kill()
    killed(first)


# ---------------------------------------------------------------------- no process outlives its parent
def _children(pid: int) -> list[int]:
    """Live child processes of ``pid`` (from /proc; zombies count as gone)."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2 :].split()
            if int(fields[1]) == pid and fields[0] != "Z":
                out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_worker_processes_die_with_a_killed_parent(tmp_path):
    parent = start(
        "generate",
        *GEN,
        "--workers",
        "2",
        "--out",
        tmp_path / "d.zarr",
        "--quiet",
        env={"MMWSIM_FAULT": "worker.start:hang"},
    )
    try:
        workers = hanging(parent, "worker.start", count=2)  # started, past their start-up, busy
        assert set(workers) <= set(_children(parent.pid))
    finally:
        parent.kill()
    killed(parent)
    wait_for(lambda: not any(_alive(w) for w in workers), timeout=10, what="the workers to die")


@pytest.mark.slow
def test_dask_tasks_of_a_killed_client_are_dropped(tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", dashboard_address=None
    ) as cluster:
        marker = tmp_path / "d.zarr.partial" / ".mmwsim-progress.json"
        client = start(
            "generate",
            *GEN,
            "--out",
            tmp_path / "d.zarr",
            "--quiet",
            "--scheduler",
            cluster.scheduler_address,
            env={"MMWSIM_FAULT": "dataset.committed@1:hang"},
        )
        try:
            wait_for(
                lambda: marker.exists() and '"tiles_done": 1' in marker.read_text(), what="the first tile"
            )
            assert len(cluster.scheduler.tasks) > 0  # the next tiles are queued for this client
        finally:
            client.kill()
        killed(client)
        wait_for(
            lambda: len(cluster.scheduler.tasks) == 0, timeout=20, what="the scheduler to drop the tasks"
        )


# ---------------------------------------------------------------------- kill points, then resume
@pytest.mark.parametrize(
    "point",
    [
        "dataset.create",
        "dataset.tile@1",
        "dataset.committed@2",
        "dataset.tile@4",
        "dataset.rename",
        "dataset.renamed",
    ],
)
def test_generate_killed_at_each_commit_point_resumes_to_the_same_bytes(tmp_path, reference, point):
    out = tmp_path / "d.zarr"
    assert (
        cli("generate", *GEN, "--out", out, "--quiet", env={"MMWSIM_FAULT": point}).returncode
        == -signal.SIGKILL
    )
    assert main(["generate", *GEN, "--out", str(out), "--resume", "--quiet"]) == 0
    assert tree(out) == reference
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.zarr"]  # no partial, no stale lock


def _splits(store: Path) -> dict[str, np.ndarray]:
    return {s: read_trajectories(store, s).positions for s in ("train", "validation", "test")}


@pytest.mark.slow
@pytest.mark.parametrize(
    "fault, holds",
    [
        ("trajectories.write", "old"),
        ("replace.written", "old"),
        ("replace.switched", "new"),
        ("replace.exchange:enosys,replace.between", "old"),  # file systems without an atomic exchange
        ("replace.exchange:enosys,replace.switched", "new"),
    ],
)
def test_trajectories_killed_while_replacing_hold_the_old_or_the_new_set(tmp_path, scene_file, fault, holds):
    def write(path, seed, env=None):
        argv = [
            "trajectories",
            path,
            "--scene",
            scene_file,
            "--pedestrian",
            "20",
            "--length",
            "4",
            "--seed",
            seed,
        ]
        return cli(*argv, env=env) if env else main([str(a) for a in argv])

    fresh = tmp_path / "fresh.zarr"
    assert write(fresh, 2) == 0
    new = _splits(fresh)
    store = tmp_path / "t.zarr"
    assert write(store, 1) == 0
    old = _splits(store)
    assert write(store, 2, env={"MMWSIM_FAULT": fault}).returncode == -signal.SIGKILL
    now = _splits(store)
    expected = old if holds == "old" else new
    assert all(np.array_equal(now[k], expected[k]) for k in expected)
    assert write(store, 2) == 0  # finishes or rolls back the interrupted replacement, then replaces
    assert tree(store) == tree(fresh)


@pytest.mark.slow
@pytest.mark.parametrize("point", ["train.epoch@2", "train.checkpointed@2", "file.rename@3"])
def test_train_killed_at_a_commit_point_resumes_to_the_same_weights(tmp_path, point):
    argv = ["train", TOY, "--model", "lstm", "--epochs", "3", "--quiet", "--out"]
    assert main(argv + [str(tmp_path / "whole")]) == 0
    run = tmp_path / "killed"
    assert cli(*argv, run, env={"MMWSIM_FAULT": point}).returncode == -signal.SIGKILL
    assert main(argv + [str(run), "--resume"]) == 0
    # the best weights, byte for byte (checkpoint and run.json also hold wall times)
    assert (run / "model.pt").read_bytes() == (tmp_path / "whole" / "model.pt").read_bytes()
    assert not [p.name for p in run.iterdir() if p.name.startswith(".")]


# ---------------------------------------------------------------------- cases that already passed, kept
class _Payload:
    """Unpickling this would create the file ``path``: proof that a file ran code when read."""

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        return (Path.touch, (Path(self.path),))


@pytest.mark.parametrize(
    "old, new, words",
    [
        ('name = "tiny"', 'name = "tiny', ("malformed TOML",)),
        ('name = "tiny"', 'name = "tiny"\ncolour = "red"', ("unknown key 'colour'",)),
        ('mesh = "meshes/ground.ply"', 'mesh = "../../escape.ply"', ("leaves the scene folder",)),
        ('mesh = "meshes/ground.ply"', 'mesh = "/etc/passwd"', ("must be relative",)),
        ('mesh = "meshes/ground.ply"', 'mesh = "meshes/none.ply"', ("mesh file not found",)),
        ("permittivity = 6.0", "permittivity = nan", ("permittivity", "finite")),
        ("frequency_ghz = 28.0", "frequency_ghz = inf", ("frequency_ghz", "finite")),
        ("frequency_ghz = 28.0", "frequency_ghz = -28.0", ("frequency_ghz",)),
        ('material = "concrete"', 'material = "unobtainium"', ("unobtainium",)),
    ],
)
def test_bad_scene_files(tmp_path, capsys, old, new, words):
    refused(capsys, ["scene", "show", scene_variant(tmp_path / "s", old, new)], *words)


def test_mesh_path_through_a_symlink_leaving_the_folder(tmp_path, capsys):
    toml = write_scene_folder(tmp_path / "s")
    (tmp_path / "outside.ply").write_bytes((toml.parent / "meshes" / "ground.ply").read_bytes())
    (toml.parent / "meshes" / "link.ply").symlink_to(tmp_path / "outside.ply")
    toml.write_text(toml.read_text().replace("meshes/ground.ply", "meshes/link.ply"))
    refused(capsys, ["scene", "show", toml], "leaves the scene folder")


@pytest.mark.parametrize(
    "doctype",
    [
        '<!DOCTYPE scene [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]>',
        '<!DOCTYPE scene [<!ENTITY x SYSTEM "file:///etc/passwd">]>',
    ],
)
def test_xml_entities_are_refused(tmp_path, capsys, doctype):
    xml = tmp_path / "bomb.xml"
    xml.write_text(
        f'<?xml version="1.0"?>{doctype}<scene version="2.1.0"><shape type="ply" id="x">'
        f'<string name="filename" value="{"&b;" if "ENTITY b" in doctype else "&x;"}"/></shape></scene>'
    )
    refused(capsys, ["scene", "show", xml], "unsafe XML")


def test_a_pickled_checkpoint_never_runs(tmp_path, capsys, run_folder):
    run = tmp_path / "run"
    shutil.copytree(run_folder, run)
    proof = tmp_path / "ran"
    (run / "model.pt").write_bytes(pickle.dumps(_Payload(str(proof))))
    refused(capsys, ["evaluate", run, "--out", tmp_path / "report"], "model.pt")
    assert not proof.exists() and not (tmp_path / "report").exists()


def test_a_pickled_npy_corridor_never_runs(tmp_path, capsys):
    proof = tmp_path / "ran"
    np.save(tmp_path / "c.npy", np.array([_Payload(str(proof))], dtype=object), allow_pickle=True)
    refused(
        capsys, ["plan", "ground_only", "--start", "0,0", "--goal", "10,10", "--corridor", tmp_path / "c.npy"]
    )
    assert not proof.exists()


@pytest.mark.parametrize(
    "argv, words",
    [
        (["trace", "ground_only", "--rx", "10,10,nan"], ("--rx",)),
        (["trace", "ground_only", "--rx", "10,10,1.5", "--tx", "inf,0,10"], ("--tx",)),
        (["generate", "ground_only", "--spacing", "nan"], ("--spacing",)),
        (["generate", "ground_only", "--spacing", "1e-300"], ("receivers", "too large")),
        (["generate", "default", "--tile-size", "1048576"], ("tile", "memory")),
        (["generate", "default", "--workers", "1000"], ("workers", "memory")),
        (
            ["trajectories", "missing.zarr", "--scene", "ground_only", "--pedestrian", "100000000"],
            ("memory",),
        ),
        (
            ["trajectories", "missing.zarr", "--scene", "ground_only", "--pedestrian", "3", "--rate", "nan"],
            ("rate",),
        ),
        (["train", "toy:n=1000000000000", "--model", "lstm", "--out", "r"], ("memory",)),
        (["train", TOY, "--model", "lstm", "--out", "r", "--option", "d=-5"], ("--option",)),
        (["train", TOY, "--model", "lstm", "--out", "r", "--time-limit", "nan"], ("--time-limit",)),
        (["evaluate", "knn-kalman", "--dataset", TOY, "--task", "forecasting", "--t-obs", "0"], ("--t-obs",)),
        (["plan", "ground_only", "--start", "nan,0", "--goal", "10,10"], ("--start",)),
        (["plan", "ground_only", "--start", "0,0", "--goal", "10,10", "--step", "inf"], ("step",)),
    ],
)
def test_numbers_out_of_range_everywhere(tmp_path, capsys, monkeypatch, argv, words):
    monkeypatch.chdir(tmp_path)
    refused(capsys, argv, *words)
    assert tree(tmp_path) == {}


@pytest.mark.parametrize(
    "argv",
    [
        ["scene", "export", "ground_only", "--out", "nowhere/x.ply"],
        ["scene", "record", "ground_only", "--rrd", "nowhere/x.rrd"],
        ["trace", "ground_only", "--rx", "10,10,1.5", "--json", "nowhere/x.json"],
        ["generate", *GEN, "--out", "d.zarr", "--rrd", "nowhere/x.rrd"],
        ["generate", *GEN, "--out", "nowhere/d.zarr"],
        [
            "trajectories",
            "missing.zarr",
            "--scene",
            "ground_only",
            "--pedestrian",
            "3",
            "--rrd",
            "nowhere/t.rrd",
        ],
    ],
)
def test_outputs_in_a_missing_folder_are_refused_before_any_work(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.chdir(tmp_path)
    refused(capsys, argv, "nowhere")
    assert tree(tmp_path) == {}


@pytest.mark.parametrize("folder", ["grid/valid", "grid/pdp", "trajectories/train/positions"])
def test_corrupt_chunks_are_one_line(tmp_path, capsys, store, folder):
    bad = tmp_path / "bad.zarr"
    shutil.copytree(store, bad)
    chunks = [
        p for p in (bad / folder).rglob("*") if p.is_file() and "c" in p.relative_to(bad / folder).parts
    ]
    assert chunks
    for p in chunks:
        p.write_bytes(b"not zstd")
    refused(capsys, ["train", bad, "--model", "lstm", "--out", tmp_path / "run", "--quiet"], "not a readable")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "argv, written",
    [
        (["scene", "export", "ground_only", "--out", "g.ply"], "g.ply"),
        (["trace", "ground_only", "--rx", "10,10,1.5", "--rays", "1000", "--json", "p.json"], "p.json"),
    ],
)
def test_full_disk_while_writing_a_file(tmp_path, capsys, monkeypatch, argv, written):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MMWSIM_FAULT", "file.write:enospc")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [err[-1]] and written in err[0] and "disk is full" in err[0] and not caught
    assert tree(tmp_path) == {}
