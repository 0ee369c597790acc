"""Trajectory generators: geometry (no sample indoors, no segment through a building), kinematic
statistics against the configured parameters, determinism and bad parameters."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

import scenes
from mmwsim.errors import MmwsimError
from mmwsim.geometry import CoverageMask, FreeSpace
from mmwsim.materials import get_material
from mmwsim.scene import ReceiverGrid, Scene, SceneObject
from mmwsim.trajectories import MotionModel, StreetNetwork, TrajectoryError
from mmwsim.trajectories import generate_trajectories as generate
from mmwsim.trajectories.motion import PEDESTRIAN, VEHICLE
from scenes.layout import Building, building_mesh


@pytest.fixture(scope="module")
def city() -> Scene:
    return scenes.load("default")


def _open_area(size: float = 5000.0) -> Scene:
    """No buildings, a large area: kinematics unperturbed by walls."""
    grid = ReceiverGrid((0.0, 0.0), size / 100, (101, 101), 1.5)
    return Scene([], receivers=grid, name="open", bounds=np.array([[0, 0, 0], [size, size, 10.0]]))


def _segments(positions: np.ndarray) -> np.ndarray:
    a = positions[:, :-1].reshape(-1, 2)
    b = positions[:, 1:].reshape(-1, 2)
    return shapely.linestrings(np.stack([a, b], axis=1))


def _assert_clear_of_buildings(scene: Scene, positions: np.ndarray, clearance: float = 0.0) -> None:
    union = shapely.union_all(scene.footprints)
    pts = positions.reshape(-1, 2)
    assert scene.outdoors(pts).all(), "a sample lies indoors (ray-cast test)"
    assert not shapely.contains_xy(union, pts[:, 0], pts[:, 1]).any()
    lines = _segments(positions)
    assert not shapely.intersects(lines, union).any(), "a segment crosses a building"
    if clearance:
        assert shapely.distance(lines, union).min() >= clearance - 1e-6
    (x0, y0), (x1, y1) = scene.receivers.bounds
    assert pts[:, 0].min() >= x0 and pts[:, 0].max() <= x1 and pts[:, 1].min() >= y0 and pts[:, 1].max() <= y1


def test_city_trajectories_stay_outdoors(city):
    t = generate(city, {"pedestrian": 300, "hybrid": 150, "vehicle": 200, "static": 50}, 12, seed=1)
    assert t.positions.shape == (700, 12, 2)
    assert np.bincount(t.kind, minlength=4).tolist() == [50, 300, 150, 200]
    assert np.array_equal(np.sort(t.ids), np.arange(700))
    for kind, clearance in (("pedestrian", 0.5), ("hybrid", 1.0), ("vehicle", 1.5), ("static", 0.5)):
        _assert_clear_of_buildings(city, t.of_kind(kind).positions, clearance)
    static = t.of_kind("static").positions
    assert np.all(static == static[:, :1])


def test_vehicles_on_street_network(city):
    net = StreetNetwork.from_scene(city, half_width=4.0)
    union = shapely.union_all(city.footprints)
    # The centre lines keep the half width from every building and form one connected network.
    assert shapely.distance(shapely.linestrings(net.lines()), union).min() >= 4.0 - 1e-6
    assert net.total_length > 2000.0
    t = generate(city, {"vehicle": 300}, 20, seed=2, vehicles_on_streets=True)
    _assert_clear_of_buildings(city, t.positions, 1.5)
    # Every sample lies on the network (within the simplification tolerance).
    pts = shapely.points(t.positions.reshape(-1, 2))
    assert shapely.distance(pts, shapely.multilinestrings(shapely.linestrings(net.lines()))).max() < 0.5
    v = t.speeds()
    assert v.max() <= VEHICLE.max_speed + 1e-9
    moving = v[v > 0]
    # Chords at corners are a little shorter than the arc driven, never longer.
    assert 0.9 * VEHICLE.mean_speed < moving.mean() < 1.05 * VEHICLE.mean_speed


def test_ways_along_the_streets_are_the_shortest_within_their_limit():
    # A square block 0-1-2-3 with a spur 2-4: from 0, node 2 is 20 m either way round.
    nodes = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [10.0, 40.0]])
    net = StreetNetwork(nodes, np.array([[0, 1], [1, 2], [2, 3], [3, 0], [2, 4]]))
    length, pred = net.ways_from(0)
    np.testing.assert_allclose(length, [0.0, 10.0, 20.0, 10.0, 50.0])
    assert pred[4] == 2 and pred[1] == 0
    length, pred = net.ways_from(0, limit=25.0)
    assert np.isinf(length[4]) and pred[4] < 0 and length[2] == 20.0
    # the nearest edge of points beside them, and past the spur's end (its foot at the end)
    edge, dist = net.nearest_edges(np.array([[[5.0, -1.0], [11.0, 30.0], [10.0, 43.0]]]))
    assert edge.tolist() == [[0, 4, 4]] and np.allclose(dist, [[1.0, 1.0, 3.0]])


def test_segment_check_catches_thin_wall():
    """End points on both sides of a 0.5 m wall are free; the segment between them is not."""
    wall = SceneObject("wall", building_mesh([Building(49.75, 0, 50.25, 100, 20)]), get_material("concrete"))
    scene = Scene([wall], receivers=ReceiverGrid((0.0, 0.0), 1.0, (101, 101), 1.5), name="thin")
    fs = FreeSpace.from_scene(scene, clearance=0.0)
    a, b = np.array([[46.0, 50.0]]), np.array([[54.0, 50.0]])
    assert fs.points_ok(np.vstack([a, b])).all()
    assert not fs.segments_ok(a, b)[0]
    assert fs.segments_ok(a, np.array([[46.0, 58.0]]))[0]
    # Vehicles (8 m steps) in a field of thin walls never jump across one.
    walls = [Building(x, 5, x + 0.5, 95, 20) for x in (20.0, 40.0, 60.0, 80.0)]
    scene = Scene(
        [SceneObject("walls", building_mesh(walls), get_material("concrete"))],
        receivers=ReceiverGrid((0.0, 0.0), 1.0, (101, 101), 1.5),
        name="walls",
    )
    t = generate(
        scene, {"vehicle": 200, "hybrid": 100}, 10, seed=5, models={"vehicle": VEHICLE.replace(clearance=0.0)}
    )
    _assert_clear_of_buildings(scene, t.positions)


def _measured(model: MotionModel, seed: int, n: int = 3000, length: int = 7, rate: float = 1.0):
    size = 5000.0
    t = generate(
        _open_area(size), {model.kind: n}, length, seed=seed, rate_hz=rate, models={model.kind: model}
    )
    # Keep users that cannot reach the area's edge, so that no step had to avoid it.
    reach = model.max_speed * (length - 1) / rate + 1.0
    start = t.positions[:, 0]
    t = t.subset(np.all((start > reach) & (start < size - reach), axis=1))
    d = np.diff(t.positions, axis=1)
    step = np.linalg.norm(d, axis=2)
    moving = step > 1e-9
    pair = moving[:, 1:] & moving[:, :-1]  # consecutive moving steps (no restart between them)
    dstep = np.abs(np.diff(step, axis=1))[pair]
    heading = np.arctan2(d[..., 1], d[..., 0])
    dturn = np.abs(np.angle(np.exp(1j * np.diff(heading, axis=1))))[pair]
    return t, step, moving, dstep, dturn


@pytest.mark.parametrize("model", [PEDESTRIAN, VEHICLE], ids=lambda m: m.kind)
def test_measured_kinematics_match_configuration(model):
    dt = 1.0
    t, step, moving, dstep, dturn = _measured(model, seed=11)
    speed = step[moving] / dt
    assert speed.max() <= model.max_speed + 1e-9 and speed.min() >= model.speed_floor - 1e-9
    assert abs(speed.mean() - model.mean_speed) < 0.02 * model.mean_speed
    # Stops: zero-length steps, with the configured probability per second.
    stop = 1.0 - moving.mean()
    assert abs(stop - model.p_stop) < 0.01
    # Speed changes really change the speed, by exactly speed_change * dt.
    changed = dstep > 1e-9
    assert np.allclose(dstep[changed], model.speed_change * dt)
    assert abs(changed.mean() - model.p_speed / (1 - model.p_stop)) < 0.012
    # Turns: the configured direction change, with the configured probability.
    turned = dturn > 1e-9
    assert np.allclose(dturn[turned], np.radians(model.turn_rate) * dt, atol=1e-6)
    assert abs(turned.mean() - model.p_turn / (1 - model.p_stop)) < 0.012


def test_rate_scales_steps_and_probabilities():
    model = PEDESTRIAN
    t, step, moving, dstep, dturn = _measured(model, seed=3, n=1500, length=13, rate=2.0)
    assert abs(step[moving].mean() * 2.0 - model.mean_speed) < 0.03 * model.mean_speed
    assert abs((1 - moving.mean()) - model.p_stop / 2) < 0.01
    # A change of speed_change * dt in speed changes the step by that times dt.
    assert np.allclose(dstep[dstep > 1e-9], model.speed_change * 0.5 * 0.5)


def test_deterministic_and_independent_streams(city):
    a = generate(city, {"pedestrian": 50, "vehicle": 30}, 8, seed=7)
    b = generate(city, {"pedestrian": 50, "vehicle": 30}, 8, seed=7)
    c = generate(city, {"pedestrian": 50, "vehicle": 30}, 8, seed=8)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.events, b.events)
    assert not np.array_equal(a.positions, c.positions)
    # More vehicles do not change the pedestrians.
    d = generate(city, {"pedestrian": 50, "vehicle": 60}, 8, seed=7)
    assert np.array_equal(a.of_kind("pedestrian").positions, d.of_kind("pedestrian").positions)


def test_coverage_mask_restricts_every_sample(city):
    grid = city.receivers.with_spacing(4.0)
    xy = grid.positions()[:, :2]
    valid = city.outdoors(xy) & (xy[:, 0] < 200)  # pretend the east half has no coverage
    mask = CoverageMask(grid, valid)
    t = generate(city, {"pedestrian": 200, "vehicle": 100}, 10, seed=4, coverage=mask)
    assert mask(t.positions.reshape(-1, 2)).all()


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(mean_speed=-1.0), "mean_speed must be a finite number >= 0"),
        (dict(max_speed=1.0), "below mean_speed"),
        (dict(p_stop=0.7, p_turn=0.5), "must not exceed 1"),
        (dict(p_turn=1.5), "probability"),
    ],
)
def test_bad_motion_parameters(kwargs, message):
    with pytest.raises(TrajectoryError, match=message):
        PEDESTRIAN.replace(**kwargs)


def test_bad_generation_parameters(city):
    for length in (0, 2, 31):
        with pytest.raises(TrajectoryError, match="3..30"):
            generate(city, {"pedestrian": 1}, length, seed=0)
    with pytest.raises(TrajectoryError, match=">= 0"):
        generate(city, {"pedestrian": -3}, 7, seed=0)
    with pytest.raises(TrajectoryError, match="unknown trajectory kind"):
        generate(city, {"bicycle": 3}, 7, seed=0)
    with pytest.raises(TrajectoryError, match="no trajectories requested"):
        generate(city, {}, 7, seed=0)
    with pytest.raises(TrajectoryError, match="speed range"):
        generate(city, {"pedestrian": 1}, 7, seed=0, rate_hz=0.2)
    with pytest.raises(TrajectoryError, match="raise the rate"):
        generate(city, {"pedestrian": 1}, 7, seed=0, rate_hz=0.1)


def test_empty_free_area():
    block = SceneObject("block", building_mesh([Building(-10, -10, 110, 110, 30)]), get_material("concrete"))
    scene = Scene([block], receivers=ReceiverGrid((0.0, 0.0), 1.0, (101, 101), 1.5), name="solid")
    with pytest.raises(MmwsimError, match="no free area"):
        generate(scene, {"pedestrian": 5}, 7, seed=0)


def test_users_and_the_planner_avoid_the_same_obstacles():
    """One free space: a free-standing wall (kind "other") blocks users as it blocks the planner."""
    from planning import AgentSpace

    scene = scenes.load("ground_wall:distance=15")  # a wall in the plane x = 15, 30 m tall
    strip = np.array([[5.0, -50.0], [25.0, 50.0]])  # 20 m around the wall: free walkers would cross it
    fs = FreeSpace.from_scene(scene, bounds=strip)
    assert fs.obstacles and all(g.geom_type == "LineString" for g in fs.obstacles)  # the wall's slab
    crossing = fs.segments_ok(np.array([[10.0, 0.0], [10.0, 0.0]]), np.array([[20.0, 0.0], [12.0, 0.0]]))
    assert crossing.tolist() == [False, True]
    agent = AgentSpace(scene, radius=0.5)
    assert all(g.equals(h) for g, h in zip(agent.obstacles, fs.obstacles, strict=True))
    assert not agent.exact_motion_valid(10.0, 0.0, 20.0, 0.0) and agent.exact_motion_valid(
        10.0, 0.0, 12.0, 0.0
    )
    t = generate(scene, {"pedestrian": 300}, 10, seed=3, free_space_bounds=strip)
    steps = np.stack([t.positions[:, :-1], t.positions[:, 1:]], axis=2).reshape(-1, 2, 2)
    assert not np.any((steps[:, 0, 0] - 15.0) * (steps[:, 1, 0] - 15.0) < 0)  # no step crosses x = 15
