"""Recording building blocks: colours by path kind, wedges, diffuse tiles, beam lobes, the draped
coverage plane, scene meshes, timelines and the stored blueprint."""

from __future__ import annotations

import numpy as np
import pytest
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader

import scenes
from mmwsim.antennas import RotatingHorn
from mmwsim.dataset.record import _log_coverage_plane, log_beam_patterns
from mmwsim.errors import MmwsimError
from mmwsim.recording import (
    NO_DATA_RGB,
    Entity,
    Recording,
    Timeline,
    blueprint,
    colorize,
    log_scene,
    scene_colors,
)
from mmwsim.scene import ReceiverGrid, load_scene
from mmwsim.tracer import Interaction, Paths
from mmwsim.tracer.record import RAY_CLASSES, log_diffuse_tiles, log_paths, log_wedges, path_classes
from tests.helpers.rrd import check_blueprint, entity_rows, read_blueprint


def _column(path, entity: str, component: str) -> list:
    """The last row of ``component`` logged at ``entity``."""
    value = None
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            if component in batch.schema.names:
                value = batch.column(batch.schema.names.index(component)).to_pylist()[-1]
    assert value is not None, f"{component} not logged at {entity}"
    return value


def _paths(types: list[list[int]]) -> Paths:
    """One receiver, one path per row of ``types`` (interaction kinds, 0 pads), made-up geometry."""
    t = np.array(types, dtype=np.int8)
    n, k = t.shape
    order = (t > 0).sum(axis=1).astype(np.int8)
    j, i = np.meshgrid(np.arange(k), np.arange(n))
    points = np.stack([10.0 * (j + 1), i.astype(float), np.full(j.shape, 5.0)], axis=-1)
    points[t == 0] = np.nan
    return Paths(
        tx=np.array([0.0, 0.0, 10.0]),
        rx=np.array([[100.0, 0.0, 1.5]]),
        frequency=28e9,
        rx_index=np.zeros(n, dtype=np.int64),
        length=np.linspace(100.0, 150.0, n),
        jones=np.tile(np.eye(2, dtype=np.complex128) * 1e-4, (n, 1, 1)),
        aod=np.zeros((n, 2)),
        aoa=np.zeros((n, 2)),
        order=order,
        faces=np.where(t > 0, 0, -1).astype(np.int64),
        objects=np.where(t > 0, 0, -1).astype(np.int32),
        points=points,
        types=t,
    )


R, D, S = Interaction.REFLECTION, Interaction.DIFFRACTION, Interaction.DIFFUSE


def test_paths_are_coloured_by_kind_and_order(tmp_path):
    paths = _paths(
        [[0, 0, 0, 0, 0], [R, 0, 0, 0, 0], [R, R, 0, 0, 0], [R, R, R, 0, 0], [R, R, R, R, R], [R, D, 0, 0, 0],
         [R, S, 0, 0, 0]]
    )  # fmt: skip
    assert path_classes(paths).tolist() == [0, 1, 2, 3, 4, 5, 6]
    rrd = tmp_path / "p.rrd"
    with Recording(rrd, "paths", families=("world",), extent=[[0, 0, 0], [100, 100, 20]]) as rec:
        assert log_paths(rec, paths) == 7
    strips = _column(rrd, "/" + Entity.RAY_PATHS, "LineStrips3D:strips")
    # tx, the interaction points in order, rx
    assert [len(s) for s in strips] == [2, 3, 4, 5, 7, 4, 4]
    for s, i in zip(strips, range(7), strict=True):
        np.testing.assert_allclose(s[0], paths.tx)
        np.testing.assert_allclose(s[-1], paths.rx[0])
        np.testing.assert_allclose(np.reshape(s[1:-1], (-1, 3)), paths.points[i, : paths.order[i]], rtol=1e-6)
    colours = _column(rrd, "/" + Entity.RAY_PATHS, "LineStrips3D:colors")
    want = [c for _, c in RAY_CLASSES]
    assert [((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c in colours] == want
    # the legend names exactly the classes drawn
    labels = _column(rrd, "/legend/scene/rays/labels", "Points2D:labels")
    assert labels == [name for name, _ in RAY_CLASSES]


def test_wedges_read_back(tmp_path):
    seg = np.array([[[0, 0, 0], [0, 0, 20]], [[10, 0, 0], [10, 0, 20]], [[0, 10, 20], [10, 10, 20]]], float)
    used = np.array([False, True, False])
    rrd = tmp_path / "w.rrd"
    with Recording(rrd, "wedges", families=("world",), extent=[[0, 0, 0], [10, 10, 20]]) as rec:
        assert log_wedges(rec, seg, used) == 3
        with pytest.raises(MmwsimError, match=r"\(n, 2, 3\)"):
            log_wedges(rec, seg[:, 0], used)
        with pytest.raises(MmwsimError, match="3 'used' flags"):
            log_wedges(rec, seg, used[:2])
        with pytest.raises(MmwsimError, match="finite"):
            log_wedges(rec, np.where(seg == 20, np.nan, seg), used)
    assert entity_rows(rrd)["/" + Entity.WEDGES] == 1
    strips = np.array(_column(rrd, "/" + Entity.WEDGES, "LineStrips3D:strips"), dtype=float)
    np.testing.assert_allclose(strips, seg)
    radii = _column(rrd, "/" + Entity.WEDGES, "LineStrips3D:radii")
    assert radii[1] > radii[0] == radii[2]  # the used edge stands out
    colours = _column(rrd, "/" + Entity.WEDGES, "LineStrips3D:colors")
    assert colours[0] == colours[2] != colours[1]
    assert ((colours[1] >> 24) & 255, (colours[1] >> 16) & 255, (colours[1] >> 8) & 255) == RAY_CLASSES[5][1]
    check_blueprint(rrd, ["Scene"])


def test_diffuse_tiles_read_back(tmp_path):
    centres = np.array([[0, 0, 5], [5, 0, 5], [10, 0, 5], [15, 0, 5]], float)
    power = np.array([-83.0, -95.0, -np.inf, -150.0])
    rrd = tmp_path / "t.rrd"
    with Recording(rrd, "tiles", families=("world",), extent=[[0, 0, 0], [20, 20, 10]]) as rec:
        assert log_diffuse_tiles(rec, centres, power) == 4
        with pytest.raises(MmwsimError, match=r"\(n, 3\)"):
            log_diffuse_tiles(rec, centres[:, :2], power)
        with pytest.raises(MmwsimError, match="4 powers"):
            log_diffuse_tiles(rec, centres, power[:3])
        with pytest.raises(MmwsimError, match="finite"):
            log_diffuse_tiles(rec, centres, np.array([np.nan, 0, 0, 0]))
    ent = "/" + Entity.DIFFUSE_TILES
    np.testing.assert_allclose(_column(rrd, ent, "Points3D:positions"), centres)
    rgb = [((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c in _column(rrd, ent, "Points3D:colors")]
    # the colour bar spans 40 dB up to the next 10 dB above the strongest tile (-80 dBm)
    assert rgb[0] == tuple(colorize(np.array([-83.0]), "plasma", -120.0, -80.0)[0])
    assert rgb[2] == NO_DATA_RGB  # no power at all
    assert rgb[3] == tuple(colorize(np.array([-120.0]), "plasma", -120.0, -80.0)[0])  # clipped
    assert _column(rrd, ent, "Points3D:labels")[1] == "-95.0 dBm"
    ticks = _column(rrd, "/legend/scene/diffuse_tiles/ticks", "Points2D:labels")
    assert ticks == ["-120", "-100", "-80"]


def test_beam_lobes_point_along_each_beam(tmp_path):
    horn = RotatingHorn(n_beams=4, gain_dbi=20.0, azimuth0=np.radians(10.0))
    tx = np.array([50.0, 60.0, 10.0])
    rrd = tmp_path / "b.rrd"
    with Recording(rrd, "beams", families=("world",), extent=[[0, 0, 0], [100, 100, 20]]) as rec:
        log_beam_patterns(rec, horn, tx, length=30.0, step_deg=2.0)
    ent = "/" + Entity.TX_PATTERN
    assert entity_rows(rrd)[ent] == 4
    lobes = []
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        if chunk.entity_path == ent:
            batch = chunk.to_record_batch()
            lobes += batch.column(batch.schema.names.index("Mesh3D:vertex_positions")).to_pylist()
            assert chunk.timeline_names == ["beam"]
    for beam, verts in enumerate(lobes):
        v = np.asarray(verts) - tx
        far = v[np.argmax(np.linalg.norm(v, axis=1))]
        # the peak lies on the horn's boresight, at the full length
        assert np.linalg.norm(far) == pytest.approx(30.0, rel=1e-3)
        az = np.degrees(np.arctan2(far[1], far[0]))
        assert abs((az - (10.0 + 90.0 * beam) + 180) % 360 - 180) <= 1.0
        assert abs(far[2]) < 30.0 * np.sin(np.radians(1.0))


def test_coverage_plane_puts_each_pixel_on_its_receiver(tmp_path):
    grid = ReceiverGrid(origin=(-20.0, 5.0), spacing=4.0, shape=(11, 6), height=1.5)
    rrd = tmp_path / "c.rrd"
    with Recording(rrd, "plane", families=("coverage",)) as rec:
        _log_coverage_plane(rec, grid)
    ent = "/" + Entity.COVERAGE
    t = np.asarray(_column(rrd, ent, "Transform3D:translation")[0])
    m = np.asarray(_column(rrd, ent, "Transform3D:mat3x3")[0]).reshape(3, 3).T  # stored column-major
    k = np.asarray(_column(rrd, ent, "Pinhole:image_from_camera")[0]).reshape(3, 3).T
    dist = _column(rrd, ent, "Pinhole:image_plane_distance")[0]
    assert _column(rrd, ent, "Pinhole:resolution")[0] == [11, 6]
    # a pixel's centre, projected back onto the image plane, is the receiver drawn there:
    # column u is x = x0 + u * spacing, row v (north up) is y = y_max - v * spacing
    for u, v in [(0, 0), (10, 0), (3, 5)]:
        cam = np.linalg.solve(k, [u + 0.5, v + 0.5, 1.0]) * dist
        world = m @ cam + t
        np.testing.assert_allclose(world, [-20.0 + 4.0 * u, 5.0 + 4.0 * (5 - v), 1.5], atol=1e-5)


def test_scene_meshes_are_shaded_and_tell_ground_from_buildings(tmp_path, scene_folder):
    scene = load_scene(str(scene_folder))
    colours = scene_colors(scene).astype(int)
    kinds = [o.kind for o in scene.objects]
    ground, building = colours[kinds.index("ground")], colours[kinds.index("building")]
    assert ground.sum() < building.sum() - 150
    city = scenes.load("default")
    c = scene_colors(city).astype(int)
    same = [i for i, o in enumerate(city.objects) if o.kind == "building" and o.material.name == "concrete"]
    assert len({tuple(c[i]) for i in same[:10]}) == 10  # neighbours of one material still differ
    rrd = tmp_path / "s.rrd"
    with Recording(rrd, "scene", families=("world",), extent=scene.extent) as rec:
        log_scene(rec, scene)
    for name in ("asphalt",):
        ent = "/" + Entity.scene_material(name)
        pos = np.asarray(_column(rrd, ent, "Mesh3D:vertex_positions"))
        nrm = np.asarray(_column(rrd, ent, "Mesh3D:vertex_normals"))
        assert len(pos) == len(nrm) and len(pos) % 3 == 0
        np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, rtol=1e-6)
        np.testing.assert_allclose(np.abs(nrm[:, 2]), 1.0, rtol=1e-6)  # the flat ground faces up or down
    labels = _column(rrd, "/legend/scene/materials/labels", "Points2D:labels")
    assert "asphalt ground" in labels and any(label.endswith(" building") for label in labels)
    bp = check_blueprint(rrd, ["Scene"])
    (view,) = [v for v in bp.views.values() if v.kind == "3D"]
    assert view.origin == "world"


def test_a_row_carries_one_timeline(tmp_path):
    rrd = tmp_path / "t.rrd"
    with Recording(rrd, "timelines", families=("bff",)) as rec:
        rec.set_time(Timeline.BEAM, 3)
        rec.log("bff/a", rr.Scalars(1.0))
        rec.set_time(Timeline.STEP, 2)
        rec.log("bff/b", rr.Scalars(2.0))
    timelines = {c.entity_path: c.timeline_names for c in RrdReader(str(rrd)).stream().to_chunks()}
    assert timelines["/bff/a"] == ["beam"] and timelines["/bff/b"] == ["step"]  # no log_time either


def test_blueprint_tabs_and_time_panel():
    bp = blueprint(("coverage", "bff"), config=False)
    tabs = bp.root_container.contents
    assert [t.name for t in tabs] == ["Coverage", "Fingerprints"]
    assert bp.time_panel.timeline == "beam"
    assert blueprint(("planner",)).time_panel.timeline == "iteration"
    assert blueprint(("world",), extent=np.array([[0, 0, 0], [10, 10, 5]])).time_panel.timeline is None
    with pytest.raises(ValueError, match="unknown"):
        blueprint(("nonsense",))


def test_check_blueprint_refuses_what_the_viewer_shows_badly(tmp_path):
    rrd = tmp_path / "bad.rrd"
    rec = rr.RecordingStream("mmwsim", recording_id="bad")
    bad = rrb.Blueprint(
        rrb.Tabs(
            rrb.Horizontal(rrb.TensorView(name="Fingerprint", origin="bff")),  # unnamed container
            name="root",
        )
    )
    rec.save(str(rrd), default_blueprint=bad)
    rec.log("bff/a", rr.Tensor(np.zeros((2, 3))), static=True)
    rec.log("bff/b", rr.Tensor(np.ones((2, 3))), static=True)
    rec.disconnect()
    stored = read_blueprint(rrd)
    assert [v.kind for v in stored.views.values()] == ["Tensor"]
    with pytest.raises(AssertionError, match="unnamed"):
        check_blueprint(rrd, [None])
    rec = rr.RecordingStream("mmwsim", recording_id="bad2")
    rec.save(
        str(tmp_path / "bad2.rrd"),
        default_blueprint=rrb.Blueprint(rrb.Tabs(rrb.TensorView(name="F", origin="bff"), name="r")),
    )
    rec.log("bff/a", rr.Tensor(np.zeros((2, 3))), static=True)
    rec.log("bff/b", rr.Tensor(np.ones((2, 3))), static=True)
    rec.disconnect()
    with pytest.raises(AssertionError, match="selects 2 tensors"):
        check_blueprint(tmp_path / "bad2.rrd", ["F"])
    rec = rr.RecordingStream("mmwsim", recording_id="bad3")
    rec.save(
        str(tmp_path / "bad3.rrd"),
        default_blueprint=rrb.Blueprint(
            rrb.Tabs(rrb.TimeSeriesView(name="Loss", origin="training"), name="r")
        ),
    )
    rec.set_time("epoch", sequence=1)
    rec.log("training/loss", rr.Scalars(1.0))
    rec.disconnect()
    with pytest.raises(AssertionError, match="nothing static"):
        check_blueprint(tmp_path / "bad3.rrd", ["Loss"])
