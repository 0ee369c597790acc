"""The scene catalogue: default scene, procedural generator, canonical scenes."""

import numpy as np
import pytest

import scenes
from mmwsim import MmwsimError
from scenes.manhattan import random_plan


def test_names():
    assert {
        "default",
        "manhattan",
        "free_space",
        "ground_only",
        "ground_wall",
        "street_canyon",
        "corner_reflector",
    } <= set(scenes.names())


def test_default_scene_contract():
    s = scenes.load("default")
    np.testing.assert_allclose(s.extent[:, :2], [[0, 0], [400, 400]])
    assert s.transmitter.position == (200.0, 203.0, 10.0)
    assert s.receivers.shape == (401, 401) and s.receivers.height == 1.5
    assert s.frequency == 28e9
    assert 0.4 < s.free_area_fraction() < 0.65
    # the reference start and goal of the planning experiment lie in the street
    assert s.outdoors(np.array([[215.0, 193.0], [177.0, 46.0]])).all()
    # line of sight from the mast down the four arms of the central intersection
    tx = s.transmitter.array
    targets = np.array([[200, 30, 1.5], [200, 390, 1.5], [20, 203, 1.5], [390, 203, 1.5]], dtype=float)
    d = targets - tx
    assert not s.ray_caster.occluded(np.repeat(tx[None], 4, 0), d, np.full(4, 0.999)).any()
    heights = np.array([o.mesh.bounds[1, 2] for o in s.objects if o.kind == "building"])
    assert len(heights) > 50 and heights.min() >= 6 and heights.max() <= 150


def test_shipped_default_files_are_reproducible(tmp_path):
    scenes.write_default(tmp_path)
    shipped = scenes.default_scene_path().parent
    for name in ("scene.toml", "buildings.ply", "ground.ply"):
        assert (tmp_path / name).read_bytes() == (shipped / name).read_bytes(), name


def test_manhattan_is_deterministic_and_seeded():
    a, b, c = (
        scenes.load("manhattan:seed=4"),
        scenes.load("manhattan:seed=4"),
        scenes.load("manhattan:seed=5"),
    )
    assert a.vertices.tobytes() == b.vertices.tobytes() and a.faces.tobytes() == b.faces.tobytes()
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)
    np.testing.assert_array_equal(a.check_transmitter(a.transmitter.position), a.transmitter.position)
    inside = next(o for o in a.objects if o.kind == "building").mesh.centroid
    with pytest.raises(MmwsimError, match="inside a building"):
        a.check_transmitter(inside)


def test_manhattan_street_widths_and_heights():
    widths, heights = [], []
    for seed in range(8):
        plan = random_plan(np.random.default_rng(seed))
        widths += [b - a for a, b in plan.avenues + plan.streets]
        s = scenes.manhattan_city(seed)
        heights += [o.mesh.bounds[1, 2] for o in s.objects if o.kind == "building"]
    assert min(widths) >= 10 and max(widths) <= 30
    h = np.array(heights)
    # log-normal around the median, with a tail of towers
    assert 18 < np.median(h) < 32 and h.max() > 2 * np.median(h) and h.min() >= 6


@pytest.mark.parametrize(
    "name", ["free_space", "ground_only", "ground_wall", "street_canyon", "corner_reflector"]
)
def test_canonical_scenes(name):
    s = scenes.load(name)
    assert s.transmitter is not None and s.receivers.size > 0
    assert s.outdoors(s.receivers.positions()).all()


def test_catalogue_parameters_and_errors():
    s = scenes.load("ground_wall:distance=15")
    wall = s.objects[s.object_index("wall")]
    assert wall.mesh.bounds[0, 0] == 15
    with pytest.raises(MmwsimError, match="unexpected keyword"):
        scenes.load("ground_wall:height=3")
    with pytest.raises(MmwsimError, match="key=value"):
        scenes.load("manhattan:seed")
    with pytest.raises(MmwsimError, match="takes no parameters"):
        scenes.load("default:seed=1")
