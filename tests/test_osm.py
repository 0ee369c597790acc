"""OpenStreetMap scenes, on small OSM files written here.

The expected geometry is computed independently of the loader: the test places footprints in
metres of the area's frame, writes their corners as latitude/longitude (7 decimals, as OSM stores
them), and projects what it wrote back with pyproj directly; shapely then gives the footprints'
union, the outdoors test and the free area that the scene must reproduce.
"""

from __future__ import annotations

import bz2
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pyproj
import pytest
import shapely
import trimesh

import scenes
from mmwsim import MmwsimError, OsmScene, OsmWarning, load_osm, load_scene
from mmwsim.cli import main
from mmwsim.dataset.config import scene_fingerprint
from mmwsim.scene.osm import DEFAULT_HEIGHT, LEVEL_HEIGHT, OsmArea
from mmwsim.scene.osm import loader as osm_loader
from mmwsim.trajectories import StreetNetwork

LAT0, LON0 = 60.17, 24.94  # the area's centre (UTM zone 35N)
SIZE = 200.0
UTM = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32635", always_xy=True)
CX, CY = UTM.transform(LON0, LAT0)
ORIGIN = np.array([CX - SIZE / 2, CY - SIZE / 2])
AREA = dict(center=f"{LAT0},{LON0}", size=f"{SIZE:g}x{SIZE:g}")

# footprints in the frame (metres) and their tags; expected (base, top) in metres
BUILDINGS = {
    "height": ([(20, 20), (40, 20), (40, 40), (20, 40)], {"height": "12"}, (0, 12)),
    "building_height": ([(60, 20), (80, 20), (80, 40), (60, 40)], {"building:height": "15 m"}, (0, 15)),
    "levels": ([(100, 20), (120, 20), (120, 40), (100, 40)], {"building:levels": "4"}, (0, 4 * LEVEL_HEIGHT)),
    "untagged": ([(140, 20), (160, 20), (160, 40), (140, 40)], {}, (0, DEFAULT_HEIGHT)),
    "raised": ([(20, 60), (40, 60), (40, 80), (20, 80)], {"min_height": "5", "height": "20"}, (5, 20)),
    "feet": (
        [(60, 60), (80, 60), (80, 80), (60, 80)],
        {"height": "40'", "building:material": "brick"},
        (0, 40 * 0.3048),
    ),
    "overlap_a": ([(150, 60), (170, 60), (170, 80), (150, 80)], {"height": "8"}, (0, 8)),
    "overlap_b": ([(160, 70), (180, 70), (180, 90), (160, 90)], {"height": "8"}, (0, 8)),
    "bowtie": ([(80, 110), (100, 130), (100, 110), (80, 130)], {"height": "10"}, (0, 10)),
    "tiny": ([(120, 110), (120.5, 110), (120.5, 110.5), (120, 110.5)], {"height": "10"}, None),
    "crossing": ([(180, 150), (230, 150), (230, 170), (180, 170)], {"height": "10"}, (0, 10)),
    "outside": ([(300, 300), (320, 300), (320, 320), (300, 320)], {"height": "10"}, None),
}
# two buildings sharing the wall x = 120 (shared OSM nodes), 10 m and 20 m
TOUCHING = {
    "low": ([(100, 60), (120, 60), (120, 80), (100, 80)], {"height": "10"}, (0, 10)),
    "high": (
        [(120, 60), (140, 60), (140, 80), (120, 80)],
        {"height": "20", "building:facade:material": "glass"},
        (0, 20),
    ),
}
COURTYARD_OUTER = [(20, 110), (60, 110), (60, 150), (20, 150)]
COURTYARD_INNER = [(30, 120), (50, 120), (50, 140), (30, 140)]
STREET = [(-10, 50), (90, 50), (210, 50)]  # residential, crosses the area
FOOTWAY = [(0, 100), (200, 100)]
TUNNEL = [(0, 190), (200, 190)]


class OsmWriter:
    """Builds an OSM XML document from footprints in frame metres; remembers what it wrote."""

    def __init__(self):
        self.nodes: dict[tuple[float, float], int] = {}
        self.lines: list[str] = []
        self.ways: list[str] = []
        self.next_way = 100

    def node(self, xy) -> int:
        xy = (float(xy[0]), float(xy[1]))
        if xy not in self.nodes:
            lon, lat = UTM.transform(ORIGIN[0] + xy[0], ORIGIN[1] + xy[1], direction="INVERSE")
            self.nodes[xy] = len(self.nodes) + 1
            self.lines.append(f'<node id="{self.nodes[xy]}" version="1" lat="{lat:.7f}" lon="{lon:.7f}"/>')
        return self.nodes[xy]

    def way(self, pts, tags: dict[str, str], closed: bool = True) -> int:
        ids = [self.node(p) for p in pts] + ([self.node(pts[0])] if closed else [])
        self.next_way += 1
        body = "".join(f'<nd ref="{i}"/>' for i in ids) + "".join(
            f'<tag k="{k}" v="{v}"/>' for k, v in tags.items()
        )
        self.ways.append(f'<way id="{self.next_way}" version="1">{body}</way>')
        return self.next_way

    def xml(self, relations: str = "") -> str:
        return (
            "<?xml version='1.0' encoding='UTF-8'?>\n<osm version=\"0.6\" generator=\"test\">\n"
            + "\n".join(self.lines + self.ways)
            + relations
            + "\n</osm>\n"
        )

    def frame(self, xy) -> tuple[float, float]:
        """Where the written node of ``xy`` lands in the frame, by pyproj directly."""
        lat, lon = (float(v) for v in self._latlon(xy))
        x, y = UTM.transform(lon, lat)
        return x - ORIGIN[0], y - ORIGIN[1]

    def _latlon(self, xy):
        lon, lat = UTM.transform(ORIGIN[0] + xy[0], ORIGIN[1] + xy[1], direction="INVERSE")
        return f"{lat:.7f}", f"{lon:.7f}"


def write_city(folder: Path, extra_tag: str = "") -> tuple[Path, OsmWriter]:
    w = OsmWriter()
    for pts, tags, _ in {**BUILDINGS, **TOUCHING}.values():
        w.way(pts, {"building": "yes", **tags, **({"note": extra_tag} if extra_tag else {})})
    outer = w.way(COURTYARD_OUTER, {})
    inner = w.way(COURTYARD_INNER, {})
    # a building cut by the extract's edge: one of its nodes is missing
    w.way([(150, 120), (160, 120), (160, 130)], {"building": "yes"})
    w.ways[-1] = w.ways[-1].replace(f'<nd ref="{w.node((150, 120))}"/><tag', '<nd ref="999999"/><tag')
    w.way(STREET, {"highway": "residential"}, closed=False)
    w.way(FOOTWAY, {"highway": "footway"}, closed=False)
    w.way(TUNNEL, {"highway": "primary", "tunnel": "yes"}, closed=False)
    rel = textwrap.dedent(
        f"""
        <relation id="900" version="1">
          <member type="way" ref="{outer}" role="outer"/><member type="way" ref="{inner}" role="inner"/>
          <tag k="type" v="multipolygon"/><tag k="building" v="yes"/><tag k="height" v="15"/>
        </relation>"""
    )
    path = folder / "city.osm"
    path.write_text(w.xml(rel))
    return path, w


def expected_footprints(w: OsmWriter, below: float | None = None) -> shapely.Geometry:
    """Union of the written footprints in the area (those with a base under ``below`` if given)."""
    polys = []
    for pts, _, heights in {**BUILDINGS, **TOUCHING}.values():
        if heights is None or (below is not None and heights[0] >= below):
            continue
        polys.append(shapely.make_valid(shapely.Polygon([w.frame(p) for p in pts])))
    polys.append(
        shapely.Polygon([w.frame(p) for p in COURTYARD_OUTER], [[w.frame(p) for p in COURTYARD_INNER]])
    )
    return shapely.union_all(polys).intersection(shapely.box(0, 0, SIZE, SIZE))


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("MMWSIM_CACHE_DIR", str(tmp_path / "cache"))


@pytest.fixture
def city(tmp_path):
    path, w = write_city(tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_osm(path, **AREA)
    return scene, w, path, caught


def _groups(scene) -> dict[str, trimesh.Trimesh]:
    """Building objects joined per merged group (building_NN and its other-material parts)."""
    parts: dict[str, list] = {}
    for o in scene.objects:
        if o.kind == "building":
            parts.setdefault("_".join(o.name.split("_")[:2]), []).append(o.mesh)
    out = {}
    for k, ms in parts.items():
        m = trimesh.util.concatenate(ms)
        m.merge_vertices()
        out[k] = m
    return out


def _group_at(scene, xy) -> trimesh.Trimesh:
    for m in _groups(scene).values():
        lo, hi = m.bounds
        if lo[0] <= xy[0] <= hi[0] and lo[1] <= xy[1] <= hi[1]:
            return m
    raise AssertionError(f"no building at {xy}")


# ---------------------------------------------------------------------- frame and projection
def test_projection_is_the_utm_zone_of_the_area():
    area = OsmArea.parse(**AREA)
    assert area.crs_name == "EPSG:32635"
    assert "UTM zone 35N" in area.crs_label
    np.testing.assert_allclose(area.origin, ORIGIN, atol=1e-6)
    # closed form: a point on the zone's central meridian (27 E) has easting 500 km and northing
    # k0 times the meridian arc from the equator
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    phi = np.linspace(0.0, np.radians(60.0), 200_001)
    m = a * (1 - e2) / (1 - e2 * np.sin(phi) ** 2) ** 1.5
    arc = float(np.sum(0.5 * (m[1:] + m[:-1]) * np.diff(phi)))
    x, y = OsmArea.parse(center="60,27", size="100x100").project(27.0, 60.0)
    assert float(x) == pytest.approx(500_000.0, abs=1e-6)
    assert float(y) == pytest.approx(0.9996 * arc, abs=1e-3)


def test_area_frame_and_vertices(city):
    scene, w, _, _ = city
    assert isinstance(scene, OsmScene)
    np.testing.assert_allclose(scene.extent[:, :2], [[0, 0], [SIZE, SIZE]], atol=1e-9)
    assert "EPSG:32635 (WGS 84 / UTM zone 35N)" in scene.summary()
    g = scene.receivers
    assert g.shape == (201, 201) and g.spacing == 1.0 and g.origin == (0.0, 0.0)
    # a corner of the 12 m building, projected by pyproj directly, is a vertex (1 cm grid)
    corner = np.array(w.frame((20, 20)))
    d = np.linalg.norm(scene.vertices[:, :2] - corner, axis=1)
    assert d.min() < 0.01
    assert np.abs(corner - (20, 20)).max() < 0.02  # 7-decimal degrees are centimetres


def test_bbox_area_holds_the_whole_box():
    area = OsmArea.parse(bbox="60.169,24.938,60.171,24.942")
    (x0, y0), (x1, y1) = area.rectangle
    lon = np.array([24.938, 24.942, 24.938, 24.942, 24.94])
    lat = np.array([60.169, 60.169, 60.171, 60.171, 60.171])
    x, y = UTM.transform(lon, lat)
    assert np.all((x >= x0 - 1e-6) & (x <= x1 + 1e-6) & (y >= y0 - 1e-6) & (y <= y1 + 1e-6))
    assert x.min() == pytest.approx(x0, abs=1e-6) and y.min() == pytest.approx(y0, abs=1e-6)
    assert 200 < x1 - x0 < 240 and 200 < y1 - y0 < 240  # 0.004 deg longitude at 60 N is about 222 m


# ---------------------------------------------------------------------- buildings
def test_heights_from_each_tag(city):
    scene, w, _, _ = city
    for name, (pts, _, heights) in {**BUILDINGS, **TOUCHING}.items():
        if heights is None or name in ("overlap_a", "overlap_b", "low", "high", "crossing"):
            continue
        c = np.mean(pts, axis=0)
        m = _group_at(scene, c)
        assert m.bounds[0, 2] == pytest.approx(heights[0], abs=2e-3), name
        assert m.bounds[1, 2] == pytest.approx(heights[1], abs=1e-9), name


def test_materials_from_tags(city):
    scene, *_ = city
    mats = {o.material.name for o in scene.objects if o.kind == "building"}
    assert mats == {"concrete", "brick", "glass"}
    ground = scene.objects[scene.object_index("ground")]
    assert ground.kind == "ground" and ground.material.name == "concrete"


def test_buildings_are_closed_with_outward_normals(city):
    scene, *_ = city
    groups = _groups(scene)
    assert len(groups) == 11  # 13 footprints in the area, two pairs merged
    for name, m in groups.items():
        assert m.is_watertight and m.is_winding_consistent, name
        assert m.volume > 0, name  # outward normals


def test_touching_buildings_merge_without_internal_faces(city):
    scene, w, _, _ = city
    m = _group_at(scene, (110, 70))
    assert m.bounds[1, 0] == pytest.approx(140, abs=0.02)  # one solid for both
    expected = shapely.Polygon([w.frame(p) for p in TOUCHING["low"][0]]).area * 10
    expected += shapely.Polygon([w.frame(p) for p in TOUCHING["high"][0]]).area * 20
    assert m.volume == pytest.approx(expected, rel=2e-3)
    # on the shared wall only the part above the low roof remains, facing the low roof
    c = m.triangles_center
    wall = np.abs(c[:, 0] - w.frame((120, 70))[0]) < 0.02
    assert wall.any() and np.all(c[wall, 2] > 10)
    assert np.all(m.face_normals[wall, 0] < -0.99)
    # the overlapping pair: one solid of the union's volume
    o = _group_at(scene, (155, 65))
    union = shapely.union_all(
        [shapely.Polygon([w.frame(p) for p in BUILDINGS[k][0]]) for k in ("overlap_a", "overlap_b")]
    )
    assert o.volume == pytest.approx(union.area * 8, rel=2e-3)


def test_multipolygon_keeps_its_courtyard(city):
    scene, w, _, _ = city
    m = _group_at(scene, (25, 115))
    assert m.is_watertight
    outer = shapely.Polygon([w.frame(p) for p in COURTYARD_OUTER], [[w.frame(p) for p in COURTYARD_INNER]])
    assert m.volume == pytest.approx(outer.area * 15, rel=2e-3)
    assert scene.outdoors(np.array([[40.0, 130.0]]))[0]  # the courtyard
    assert not scene.outdoors(np.array([[25.0, 130.0]]))[0]


def test_repaired_skipped_and_clipped_are_counted(city):
    scene, _, _, caught = city
    s = scene.osm_stats
    assert s["repaired"] == 1  # the bow-tie
    assert s["skipped"] == 1  # the 0.5 m x 0.5 m one
    assert s["clipped"] == 1 and s["in_area"] == 13
    assert s["broken"] == 1  # the one cut by the extract's edge
    msgs = [str(c.message) for c in caught if issubclass(c.category, OsmWarning)]
    assert len(msgs) == 1
    for text in ("1 building footprints repaired", "1 skipped", "1 building outlines near the area left out"):
        assert text in msgs[0]
    crossing = _group_at(scene, (190, 160))
    assert crossing.bounds[1, 0] == pytest.approx(SIZE, abs=1e-9) and crossing.is_watertight


def test_outdoors_footprints_and_free_area_match_shapely(city):
    scene, w, _, _ = city
    union = expected_footprints(w)
    got = shapely.union_all(scene.footprints)
    perimeter = union.length
    assert shapely.symmetric_difference(got, union).area < 0.01 * perimeter  # 1 cm on average
    assert scene.free_area_fraction() == pytest.approx(1 - union.area / SIZE**2, abs=2e-4)
    # outdoors at receiver height: everything but the buildings standing on the ground
    ground_level = expected_footprints(w, below=1.5)
    xy = np.random.default_rng(0).uniform(0, SIZE, (20000, 2))
    far = shapely.distance(ground_level.boundary, shapely.points(xy)) > 0.05
    truth = ~shapely.contains_xy(ground_level, xy[:, 0], xy[:, 1])
    got = scene.outdoors(xy)
    assert np.array_equal(got[far], truth[far])
    assert got[far].sum() > 1000 and (~got[far]).sum() > 1000
    # under the raised building (base 5 m) is outdoors at 1.5 m, inside at 10 m
    assert scene.outdoors(np.array([[30.0, 70.0, 1.5]]))[0]
    assert not scene.outdoors(np.array([[30.0, 70.0, 10.0]]))[0]


def test_roads_are_asphalt_strips_in_the_ground(tmp_path):
    path, _ = write_city(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OsmWarning)
        scene = load_osm(path, roads=True, **AREA)
    road = scene.objects[scene.object_index("roads")]
    ground = scene.objects[scene.object_index("ground")]
    assert road.material.name == "asphalt" and road.kind == "ground"
    assert np.all(road.mesh.vertices[:, 2] == 0) and np.all(road.mesh.face_normals[:, 2] > 0.99)
    # residential default: 6 m wide along y = 50 across the 200 m area; ground + road = the area
    assert road.mesh.area == pytest.approx(6 * SIZE, rel=0.02)
    assert road.mesh.area + ground.mesh.area == pytest.approx(SIZE**2, rel=1e-9)


def test_bz2_reads_the_same(tmp_path):
    path, _ = write_city(tmp_path)
    packed = tmp_path / "city.osm.bz2"
    packed.write_bytes(bz2.compress(path.read_bytes()))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OsmWarning)
        a, b = load_osm(path, **AREA), load_osm(packed, **AREA)
    assert scene_fingerprint(a) == scene_fingerprint(b)


# ---------------------------------------------------------------------- catalogue, cache, TOML
def test_catalogue_spec_reloads_the_same_scene(city):
    scene, _, path, _ = city
    assert scene.spec == f"osm:{path},center=60.17,24.94,size=200x200,crs=EPSG:32635"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OsmWarning)
        again = load_scene(scene.spec, transmitter=(10.0, 10.0, 5.0))
        bbox = scenes.load(f"osm:{path},bbox=60.169,24.938,60.171,24.942")
    assert scene_fingerprint(again) == scene_fingerprint(scene)
    assert again.transmitter.position == (10.0, 10.0, 5.0)
    assert bbox.area.bbox == (60.169, 24.938, 60.171, 24.942)


def test_cache_skips_parsing_and_notices_a_changed_file(tmp_path, monkeypatch):
    path, _ = write_city(tmp_path)
    calls = []
    real = osm_loader.read_osm
    monkeypatch.setattr(osm_loader, "read_osm", lambda p: calls.append(p) or real(p))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OsmWarning)
        first = load_osm(path, **AREA)
        assert len(calls) == 1 and list((tmp_path / "cache").glob("*.npz"))
        second = load_osm(path, **AREA)
        assert len(calls) == 1  # not parsed again
        assert scene_fingerprint(second) == scene_fingerprint(first)
        assert second.osm_stats == first.osm_stats and len(second.street_lines) == len(first.street_lines)
        write_city(tmp_path, extra_tag="edited")  # same geometry, other bytes
        load_osm(path, **AREA)
        assert len(calls) == 2
        load_osm(path, center="60.1701,24.94", size="200x200")  # another area
        assert len(calls) == 3


def test_cache_that_cannot_be_used_is_bypassed(tmp_path, monkeypatch):
    path, _ = write_city(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OsmWarning)
        reference = scene_fingerprint(load_osm(path, cache=False, **AREA))
        (tmp_path / "a_file").write_text("not a folder")
        monkeypatch.setenv("MMWSIM_CACHE_DIR", str(tmp_path / "a_file" / "cache"))
        assert scene_fingerprint(load_osm(path, **AREA)) == reference  # unwritable: built, not cached
        monkeypatch.setenv("MMWSIM_CACHE_DIR", str(tmp_path / "cache2"))
        load_osm(path, **AREA)
        (entry,) = (tmp_path / "cache2").glob("*.npz")
        entry.write_bytes(b"garbage")
        assert scene_fingerprint(load_osm(path, **AREA)) == reference  # unreadable entry: rebuilt
        assert entry.read_bytes()[:2] == b"PK"  # and written again


def test_toml_names_an_osm_source(tmp_path):
    path, _ = write_city(tmp_path)
    (tmp_path / "scene.toml").write_text(
        textwrap.dedent(
            """
            name = "osm-city"
            [osm]
            file = "city.osm"
            center = [60.17, 24.94]
            size = [200.0, 200.0]
            [transmitter]
            position = [90.0, 50.0, 10.0]
            """
        )
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OsmWarning)
        scene = load_scene(tmp_path / "scene.toml")
        direct = load_osm(path, **AREA, transmitter=(90.0, 50.0, 10.0))
    assert isinstance(scene, OsmScene) and scene.name == "osm-city"
    assert scene_fingerprint(scene) == scene_fingerprint(direct)
    assert scene.transmitter.position == (90.0, 50.0, 10.0)
    (tmp_path / "bad.toml").write_text(
        '[osm]\nfile = "../city.osm"\ncenter = [60.17, 24.94]\nsize = [200.0, 200.0]\n'
    )
    with pytest.raises(MmwsimError, match="leaves the scene folder"):
        load_scene(tmp_path / "bad.toml")


# ---------------------------------------------------------------------- streets
def test_highways_feed_the_street_network(city):
    scene, w, _, _ = city
    assert len(scene.street_lines) == 1  # the residential street; footway and tunnel left out
    net = StreetNetwork.from_scene(scene)
    y = w.frame((90, 50))[1]
    assert np.all(np.abs(net.nodes[:, 1] - y) < 0.5)
    assert net.total_length == pytest.approx(SIZE, rel=0.01)


# ---------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    "args,message",
    [
        (["--bbox", "60.18,24.93,60.16,24.95"], "south 60.18 is north of north"),
        (["--bbox", "60.16,24.95,60.18,24.93"], "west 24.95 is east of east"),
        (["--bbox", "60.16,24.93,60.16,24.95"], "the area is empty"),
        (["--bbox", "60.16,24.93,60.18"], "expected 4 numbers"),
        (["--bbox", "a,b,c,d"], "comma-separated numbers"),
        (["--bbox", "nan,24.93,60.18,24.95"], "finite"),
        (["--bbox", "-91,24.93,60.18,24.95"], "latitude -91"),
        (["--center", "60.17,24.94"], "needs a size"),
        (["--center", "60.17,24.94", "--size", "0x400"], "the area is empty"),
        (["--center", "60.17,24.94", "--size", "400y400"], "WIDTHxHEIGHT"),
        (["--size", "400x400"], "needs a center"),
        (["--bbox", "60.16,24.93,60.18,24.95", "--center", "60.17,24.94"], "not both"),
        ([], "needs an area"),
        (["--center", "10.0,10.0", "--size", "200x200"], "no buildings in the area"),
    ],
)
def test_cli_area_errors(tmp_path, capsys, args, message):
    path, _ = write_city(tmp_path)
    assert main(["scene", "show", str(path), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


@pytest.mark.parametrize(
    "name,content,message",
    [
        (
            "broken.osm",
            '<?xml version=\'1.0\'?><osm version="0.6"><node id="1" lat=',
            "not a readable OSM file",
        ),
        ("page.osm", "<html><body>not osm</body></html>", "not a readable OSM file"),
        ("random.osm.pbf", "this is not a protobuf file at all", "not a readable OSM file"),
        ("empty.osm", "<?xml version='1.0'?><osm version=\"0.6\"></osm>", "holds no buildings or highways"),
        (
            "entities.osm",
            '<?xml version="1.0"?><!DOCTYPE osm [<!ENTITY a "aaaa">]><osm version="0.6"></osm>',
            "XML entities are not supported",
        ),
    ],
)
def test_cli_bad_files(tmp_path, capsys, name, content, message):
    (tmp_path / name).write_text(content)
    assert (
        main(["scene", "show", str(tmp_path / name), *sum(([f"--{k}", v] for k, v in AREA.items()), [])]) == 2
    )
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_cli_area_only_for_osm_files(capsys):
    assert main(["scene", "show", "default", "--bbox", "60.16,24.93,60.18,24.95"]) == 2
    assert "apply to OSM files" in capsys.readouterr().err


def test_cli_show_and_trace(tmp_path, capsys):
    path, _ = write_city(tmp_path)
    assert main(["scene", "show", str(path), "--center", "60.17,24.94", "--size", "200x200"]) == 0
    out = capsys.readouterr().out
    assert "EPSG:32635" in out and "13 buildings in the area" in out
    argv = ["trace", str(path), *sum(([f"--{k}", v] for k, v in AREA.items()), [])]
    assert (
        main([*argv, "--tx", "90,50,10", "--rx", "10,50,1.5", "--rx", "190,10,1.5", "--max-reflections", "1"])
        == 0
    )
    out = capsys.readouterr().out
    assert "paths to 2 receivers" in out and "line of sight" in out
