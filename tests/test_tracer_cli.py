"""``mmwsim trace``: table, JSON, recording and one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

import scenes
from mmwsim import Entity
from mmwsim.cli import main
from mmwsim.constants import SPEED_OF_LIGHT
from mmwsim.tracer import trace
from tests.helpers.rrd import check_blueprint, entity_rows


def test_trace_cli_json_and_recording(tmp_path, capsys):
    out, rrd = tmp_path / "paths.json", tmp_path / "paths.rrd"
    args = ["trace", "street_canyon", "--tx", "0,0,10", "--rx", "30,3,1.5", "--rx", "-20,-6,1.5"]
    args += ["--max-reflections", "2", "--rays", "100000", "--json", str(out), "--rrd", str(rrd)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "receiver 1 at (30, 3, 1.5): 8 paths" in text and "wall_north > ground" in text
    doc = json.loads(out.read_text())
    assert [r["position"] for r in doc["receivers"]] == [[30.0, 3.0, 1.5], [-20.0, -6.0, 1.5]]
    first = doc["receivers"][0]["paths"]
    assert len(first) == 8
    los = first[0]
    assert los["interactions"] == []
    d = np.linalg.norm([30, 3, -8.5])
    assert los["delay_s"] == pytest.approx(d / SPEED_OF_LIGHT, rel=1e-12)
    assert los["gain_db"] == pytest.approx(20 * np.log10(SPEED_OF_LIGHT / 28e9 / (4 * np.pi * d)))
    assert los["aod"][0] == pytest.approx(np.degrees(np.arccos(-8.5 / d)))
    assert {tuple(p["interactions"]) for p in first} >= {("ground",), ("wall_north", "wall_south")}
    # The same numbers as the API.
    api = trace(scenes.load("street_canyon"), (0, 0, 10), [[30, 3, 1.5]], 2, n_rays=100000)
    np.testing.assert_allclose([p["delay_s"] for p in first], api.delay, rtol=1e-15)
    rows = {k.lstrip("/"): n for k, n in entity_rows(rrd).items()}
    assert rows[Entity.RAY_PATHS] == 1  # one batched call for all strips
    assert rows[Entity.RAY_CANDIDATES] == 1
    assert any(k.startswith(Entity.SCENE) for k in rows) and Entity.TX in rows
    check_blueprint(rrd, ["Scene", "Config"])


def test_trace_cli_many_receivers_summary(tmp_path, capsys):
    csv_file = tmp_path / "rx.csv"
    pts = scenes.load("street_canyon").receivers.positions()[:30]
    csv_file.write_text("x,y,z\n" + "\n".join(",".join(f"{v:g}" for v in p) for p in pts) + "\n")
    assert (
        main(["trace", "street_canyon", "--tx", "0,0,10", "--rx-file", str(csv_file), "--rays", "50000"]) == 0
    )
    text = capsys.readouterr().out
    assert "paths to 30 receivers" in text and "paths per receiver: mean" in text


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--rx", "20,15,1.5"], "inside a building"),
        (["--rx", "1,nan,1.5"], "finite"),
        (["--rx-file", "CSV:x,y,z\n1,2,abc\n"], "line 2"),
        (["--rx-file", "CSV:a,b,c\n1,2,3\n"], "header"),
        (["--rx", "35,25,1.5", "--json", "OUT:paths.txt"], "must end in .json"),
        (["--rx", "35,25,1.5", "--diffuse", "1.5"], "scattering coefficient from 0 to 1"),
        (["--rx", "35,25,1.5", "--diffuse", "nan"], "scattering coefficient from 0 to 1"),
    ],
)
def test_trace_cli_bad_input(tmp_path, capsys, scene_folder, extra, message):
    args = []
    for a in extra:
        if a.startswith("CSV:"):
            f = tmp_path / "rx.csv"
            f.write_text(a[4:])
            a = str(f)
        elif a.startswith("OUT:"):
            a = str(tmp_path / a[4:])
        args.append(a)
    assert main(["trace", str(scene_folder), "--tx", "35,25,10", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
    assert not list(tmp_path.glob("*.json"))


def test_trace_cli_transmitter_inside_or_outside(scene_folder, capsys):
    assert main(["trace", str(scene_folder), "--tx", "20,15,5", "--rx", "35,25,1.5"]) == 2
    assert "inside a building" in capsys.readouterr().err
    assert main(["trace", str(scene_folder), "--tx", "500,15,5", "--rx", "35,25,1.5"]) == 2
    assert "outside the scene" in capsys.readouterr().err


def test_candidate_rays_end_where_they_leave_the_scene():
    from mmwsim.tracer.record import _clip_last_leg

    lo, hi = np.zeros(3), np.array([10.0, 10.0, 5.0])
    escaping = np.array([[5.0, 5.0, 1.0], [6.0, 5.0, 1.0], [1006.0, 5.0, 501.0]])
    clipped = _clip_last_leg(escaping, lo, hi)
    assert np.allclose(clipped[:2], escaping[:2])
    assert np.allclose(clipped[-1], [10.0, 5.0, 3.0])  # the x = 10 face comes before z = 5
    inside = np.array([[1.0, 1.0, 1.0], [2.0, 3.0, 4.0]])
    assert np.array_equal(_clip_last_leg(inside, lo, hi), inside)


def test_trace_cli_diffuse_adds_diffuse_paths(tmp_path, scene_folder):
    def kinds(extra):
        out = tmp_path / "paths.json"
        args = ["trace", str(scene_folder), "--tx", "35,25,10", "--rx", "35,5,1.5", "--max-reflections", "1"]
        assert main([*args, "--rays", "50000", "--no-diffraction", "--json", str(out), *extra]) == 0
        rx = json.loads(out.read_text())["receivers"][0]["paths"]
        return [t for p in rx for t in p["interaction_types"]]

    assert "diffuse" not in kinds([])
    assert kinds(["--diffuse", "0.4"]).count("diffuse") > 10
