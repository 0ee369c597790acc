"""Scene model: extent, outdoors query, footprints, free area, back-ends."""

import numpy as np
import pytest
import shapely

import scenes
from mmwsim import MmwsimError, Scene, SceneObject, get_material, load_scene
from scenes.layout import Building, building_mesh, ground_mesh


@pytest.fixture(scope="module")
def two_box_scene() -> Scene:
    concrete = get_material("concrete")
    return Scene(
        [
            SceneObject("ground", ground_mesh(0, 0, 100, 100), concrete, "ground"),
            SceneObject("a", building_mesh([Building(10, 10, 30, 20, 15.0)]), concrete),
            SceneObject("b", building_mesh([Building(40, 30, 50, 60, 25.0)]), concrete),
        ],
        name="two_boxes",
    )


def test_extent_and_triangles(two_box_scene):
    np.testing.assert_allclose(two_box_scene.extent, [[0, 0, 0], [100, 100, 25]])
    assert two_box_scene.n_triangles == 2 + 12 + 12
    assert list(np.bincount(two_box_scene.face_object)) == [2, 12, 12]


def test_outdoors_query(two_box_scene):
    pts = np.array(
        [
            [20, 15, 1.5],  # inside a
            [20, 15, 14.9],  # inside a, just under the roof
            [20, 15, 15.1],  # above a
            [45, 45, 20.0],  # inside b
            [35, 25, 1.5],  # street
            [10.0001, 15, 1.5],  # just inside a's wall
            [9.9999, 15, 1.5],  # just outside a's wall
            [0.5, 0.5, 1.5],
        ]
    )
    assert two_box_scene.outdoors(pts).tolist() == [False, False, True, False, True, False, True, True]
    # 2D points are taken at the receiver height
    assert two_box_scene.outdoors(np.array([[20.0, 15.0], [35.0, 25.0]])).tolist() == [False, True]


def test_outdoors_rejects_bad_points(two_box_scene):
    with pytest.raises(MmwsimError, match="shape"):
        two_box_scene.outdoors(np.zeros((3, 4)))
    with pytest.raises(MmwsimError, match="NaN"):
        two_box_scene.outdoors(np.array([[np.nan, 0, 0]]))


def test_outdoors_matches_footprints_on_default_scene():
    scene = scenes.load("default")
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(0, 400, 20000), rng.uniform(0, 400, 20000), np.full(20000, 1.5)])
    inside = shapely.contains_xy(shapely.union_all(scene.footprints), pts[:, 0], pts[:, 1])
    assert np.array_equal(scene.outdoors(pts), ~inside)


def test_footprints_and_free_area(two_box_scene):
    fps = two_box_scene.footprints
    assert [round(p.area, 6) for p in fps] == [200.0, 300.0]
    assert fps[0].bounds == (10.0, 10.0, 30.0, 20.0)
    assert two_box_scene.free_area_fraction() == pytest.approx(1 - 500 / 10000)


def test_backends_built_once(two_box_scene):
    assert two_box_scene.ray_caster is two_box_scene.ray_caster
    assert two_box_scene.collision_model is two_box_scene.collision_model
    # the collision model holds buildings only, not the ground
    assert two_box_scene.collision_model.n_faces == 24
    t, face = two_box_scene.ray_caster.intersect(np.array([[20.0, 5.0, 5.0]]), np.array([[0.0, 1.0, 0.0]]))
    assert t[0] == pytest.approx(5.0) and two_box_scene.face_object[face[0]] == 1


def test_collision_model_cylinder(two_box_scene):
    import fcl

    cyl = fcl.Cylinder(0.5, 2.0)
    assert two_box_scene.collision_model.collides(cyl, fcl.Transform(np.array([9.6, 15.0, 1.0])))
    assert not two_box_scene.collision_model.collides(cyl, fcl.Transform(np.array([9.4, 15.0, 1.0])))


def test_empty_and_duplicate_names():
    with pytest.raises(MmwsimError, match="empty"):
        Scene([], name="nothing")
    concrete = get_material("concrete")
    box = building_mesh([Building(0, 0, 1, 1, 1)])
    with pytest.raises(MmwsimError, match="unique"):
        Scene([SceneObject("x", box, concrete), SceneObject("x", box.copy(), concrete)])


def test_transmitter_checks(two_box_scene):
    with pytest.raises(MmwsimError, match="inside a building"):
        two_box_scene.check_transmitter((20, 15, 5))
    with pytest.raises(MmwsimError, match="outside the scene"):
        two_box_scene.check_transmitter((120, 15, 5))
    with pytest.raises(MmwsimError, match="finite"):
        two_box_scene.check_transmitter((np.nan, 15, 5))
    two_box_scene.check_transmitter((20, 15, 16))  # on the roof is fine


def test_transmitter_override_through_loader():
    with pytest.raises(MmwsimError, match="inside a building"):
        load_scene("default", transmitter=(80.0, 70.0, 5.0))
    s = load_scene("default", transmitter=(201.0, 200.0, 12.0))
    assert s.transmitter.position == (201.0, 200.0, 12.0)


def test_receiver_grid():
    g = scenes.load("default").receivers
    assert g.shape == (401, 401) and g.spacing == 1.0 and g.height == 1.5
    pos = g.positions()
    assert pos.shape == (160801, 3)
    np.testing.assert_array_equal(pos[401 * 203 + 200], [200, 203, 1.5])  # x index runs fastest
    coarse = g.with_spacing(4.0)
    assert coarse.shape == (101, 101) and coarse.bounds[1].tolist() == [400, 400]
    # the nearest grid point: off the grid at its edge, a position that is no number refused
    assert g.nearest_index(np.array([[200.4, 202.6], [-5.0, 1e6]])).tolist() == [401 * 203 + 200, 401 * 400]
    assert g.nearest_index(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(MmwsimError, match="NaN or infinite"):
        g.nearest_index(np.array([[np.nan, 3.0]]))
    with pytest.raises(MmwsimError, match=r"shape \(\.\.\., 2\)"):
        g.nearest_index(np.zeros((3, 4)))
