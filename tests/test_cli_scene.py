"""`mmwsim scene show|export|record|list` and the CLI's error contract."""

import subprocess
import sys

import pytest
import trimesh

from mmwsim.cli import main
from tests.helpers.rrd import blueprint_count, check_blueprint, entity_rows


def test_show_default(capsys):
    assert main(["scene", "show", "default"]) == 0
    out = capsys.readouterr().out
    for text in ("triangles", "concrete", "free area", "transmitter  (200, 203, 10) m", "401 x 401"):
        assert text in out


def test_show_file_with_tx_override(capsys, scene_folder):
    assert main(["scene", "show", str(scene_folder), "--tx", "60,10,8"]) == 0
    assert "transmitter  (60, 10, 8) m" in capsys.readouterr().out


@pytest.mark.parametrize("suffix", [".ply", ".glb", ".obj"])
def test_export(tmp_path, suffix, capsys):
    out = tmp_path / f"merged{suffix}"
    assert main(["scene", "export", "default", "--out", str(out)]) == 0
    mesh = trimesh.load(out, force="mesh")
    assert len(mesh.faces) == 974
    assert not list(tmp_path.glob(".*partial*"))


def test_record(tmp_path):
    rrd = tmp_path / "scene.rrd"
    assert main(["scene", "record", "default", "--rrd", str(rrd)]) == 0
    rows = entity_rows(rrd)
    assert rows["/world/scene/concrete"] == 1
    assert rows["/world/tx"] == 1 and rows["/world/rx_grid"] == 1
    assert rows["/map/footprints"] == 1 and rows["/meta/config"] == 1
    assert blueprint_count(rrd) == 1
    check_blueprint(rrd, ["Scene", "Config"])
    assert not list(tmp_path.glob(".*partial"))


def test_record_colours_materials(tmp_path, scene_folder):
    rrd = tmp_path / "tiny.rrd"
    assert main(["scene", "record", str(scene_folder), "--rrd", str(rrd)]) == 0
    rows = entity_rows(rrd)
    assert rows["/world/scene/asphalt"] == 1 and rows["/world/scene/concrete"] == 1


@pytest.mark.parametrize(
    "argv,message",
    [
        (["scene", "show", "atlantis"], "unknown scene 'atlantis'"),
        (["scene", "show", "default", "--tx", "80,70,5"], "inside a building"),
        (["scene", "show", "default", "--tx", "900,70,5"], "outside the scene"),
        (["scene", "show", "default", "--tx", "1,2"], "--tx"),
        (["scene", "show", "default", "--tx", "nan,2,3"], "--tx"),
        (["scene", "export", "default", "--out", "/nonexistent/x.ply"], "not writable"),
        (["scene", "export", "default", "--out", "x.docx"], "unsupported export format"),
        (["scene", "record", "default", "--rrd", "/nonexistent/x.rrd"], "not writable"),
    ],
)
def test_errors_exit_2_with_one_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_console_script_exit_status(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("objects = [")
    r = subprocess.run(
        [sys.executable, "-m", "mmwsim", "scene", "show", str(bad)], capture_output=True, text=True
    )
    assert r.returncode == 2
    assert r.stderr.strip().startswith("mmwsim: error:") and "malformed TOML" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    r = subprocess.run(
        [sys.executable, "-m", "mmwsim", "scene", "frobnicate"], capture_output=True, text=True
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


def test_importing_mmwsim_does_not_load_torch():
    code = "import sys, mmwsim, mmwsim.cli; mmwsim.cli.build_parser(); print('torch' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "False"
