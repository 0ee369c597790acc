"""Planning: free space and exact checks, exact shortest path, OMPL planners, corridor, CLI, recording."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import shapely

import scenes
from mmwsim.cli import EXIT_NO_SOLUTION, EXIT_USAGE, main
from mmwsim.materials import get_material
from mmwsim.scene import Scene, SceneObject
from planning import (
    AgentSpace,
    Corridor,
    PlanningError,
    load_corridor,
    plan,
    save_corridor,
    shortest_path,
)
from scenes.canonical import wall
from scenes.layout import Building, building_mesh, ground_mesh
from tests.helpers.rrd import check_blueprint, entity_rows

R = 0.5


def wall_scene() -> Scene:
    """100 m x 100 m ground, a zero-thickness 10 m tall wall from (0, -20) to (0, 20), a closed
    building (30..40, -40..-30) and a box 'other' obstacle."""
    mat = get_material("concrete")
    return Scene(
        [
            SceneObject("ground", ground_mesh(-50.0, -50.0, 50.0, 50.0), mat, "ground"),
            SceneObject("wall", wall(0.0, -20.0, 0.0, 20.0, 10.0), mat, "other"),
            SceneObject("house", building_mesh([Building(30, -40, 40, -30, 12.0)]), mat, "building"),
        ],
        name="wall",
    )


@pytest.fixture(scope="module")
def walled() -> AgentSpace:
    return AgentSpace(wall_scene(), radius=R, resolution=0.25)


@pytest.fixture(scope="module")
def open_space() -> AgentSpace:
    return AgentSpace(scenes.free_space(), radius=R, resolution=0.5)


def detour_length(d_end: float, r: float) -> float:
    """Closed form: around a wall end at distance d_end from start and goal placed symmetrically
    at right angles, two tangents to the disc of radius r and the arc between them."""
    return 2 * math.sqrt(d_end**2 - r**2) + r * (math.pi / 2 + 2 * math.asin(r / d_end))


# ---------------------------------------------------------------------- free space
def test_swept_volume_is_exact_at_the_wall_end(walled):
    # A step passing the wall's end (0, 20) clears it only if it stays r away from it.
    assert not walled.motion_valid(-3.0, 20.4, 3.0, 20.4)
    assert walled.motion_valid(-3.0, 20.6, 3.0, 20.6)
    assert not walled.exact_motion_valid(-3.0, 20.4, 3.0, 20.4)
    assert walled.exact_motion_valid(-3.0, 20.6, 3.0, 20.6)
    # Both ends far from the thin wall, the step between them crosses it: no sampling can miss it.
    assert walled.state_valid(-2.5, 0.0) and walled.state_valid(2.5, 0.0)
    assert not walled.motion_valid(-2.5, 0.0, 2.5, 0.0)
    # FCL sees surfaces only: a step wholly inside the building is still rejected.
    assert not walled.motion_valid(33.0, -35.0, 37.0, -35.0)
    assert not walled.state_valid(35.0, -35.0)


def test_certificate_agrees_with_exact_fcl_tests(walled):
    rng = np.random.default_rng(1)
    a = rng.uniform(-50, 50, size=(3000, 2))
    b = a + rng.uniform(-6, 6, size=a.shape)
    fast = [walled.motion_valid(*p, *q) for p, q in zip(a, b, strict=True)]
    exact = [walled.exact_motion_valid(*p, *q) for p, q in zip(a, b, strict=True)]
    assert fast == exact
    assert 0.1 < np.mean(fast) < 0.99
    assert [walled.state_valid(*p) for p in a] == [walled.exact_state_valid(*p) for p in a]
    # Most steps are decided by the raster, without FCL.
    assert walled.stats["motions_exact"] < 0.5 * walled.stats["motions"]


def test_endpoint_errors(walled):
    with pytest.raises(PlanningError, match="outside the scene"):
        walled.check_endpoint((60.0, 0.0), "start")
    with pytest.raises(PlanningError, match="inside a building"):
        walled.check_endpoint((35.0, -35.0), "goal")
    with pytest.raises(PlanningError, match="in collision"):
        walled.check_endpoint((0.3, 5.0), "start")
    with pytest.raises(PlanningError, match="start and goal coincide"):
        plan(walled, (-10.0, 0.0), (-10.0, 0.0))
    with pytest.raises(PlanningError, match="unknown planner"):
        plan(walled, (-10.0, 0.0), (10.0, 0.0), planner="prm")
    corridor = Corridor.from_array(np.array([[-40.0, 30.0], [40.0, 30.0]]), 5.0)
    space = AgentSpace(wall_scene(), corridor=corridor, resolution=0.5)
    with pytest.raises(PlanningError, match="outside the corridor"):
        space.check_endpoint((-10.0, 0.0), "start")


# ---------------------------------------------------------------------- exact optimum
def test_optimum_closed_forms(walled, open_space):
    free = shortest_path(open_space, (-60.0, 10.0), (70.0, -20.0))
    assert len(free.path) == 2 and free.length == pytest.approx(math.hypot(130.0, 30.0), rel=1e-12)
    around = shortest_path(walled, (-20.0, 0.0), (20.0, 0.0))
    exact = detour_length(math.hypot(20.0, 20.0), R)
    # Polygonal arcs with vertices on the circle: a lower bound, tight to well under a millimetre.
    assert exact - 1e-3 < around.length <= exact + 1e-9
    assert np.all(around.path[:, 1] >= 0.0)
    # a start or goal that is no point is refused, not read as one without a path
    for start in ((math.nan, 0.0), (1.0, 2.0, 3.0), "a"):
        with pytest.raises(PlanningError, match="start must be two finite numbers"):
            shortest_path(open_space, start, (70.0, -20.0))


def test_no_path_when_goal_is_walled_in():
    mat = get_material("concrete")
    ring = [wall(*p, 5.0) for p in [(10, 10, 20, 10), (20, 10, 20, 20), (20, 20, 10, 20), (10, 20, 10, 10)]]
    objects = [SceneObject("ground", ground_mesh(0.0, 0.0, 40.0, 40.0), mat, "ground")]
    objects += [SceneObject(f"w{i}", m, mat, "other") for i, m in enumerate(ring)]
    space = AgentSpace(Scene(objects, name="pen"), resolution=0.5)
    assert shortest_path(space, (5.0, 5.0), (15.0, 15.0)) is None
    result = plan(space, (5.0, 5.0), (15.0, 15.0), planner="rrt", iterations=300, seed=1)
    assert not result.solved and result.length == math.inf and len(result.path) == 0


# ---------------------------------------------------------------------- planners
def test_straight_line_when_nothing_is_in_the_way(open_space):
    s, g = (-50.0, -20.0), (50.0, 20.0)
    d = math.hypot(100.0, 40.0)
    bit = plan(open_space, s, g, planner="bitstar", iterations=50, seed=0)
    assert bit.solved and bit.length == pytest.approx(d, rel=1e-9)
    u = (np.array(g) - s) / d
    # With a step longer than the distance the rewiring straightens the path quickly; with
    # 5 m steps Informed RRT* needs more iterations to come as close.
    for name, step, iterations, tol in [("rrtstar", 200.0, 1000, 2e-3), ("irrtstar", 200.0, 1000, 1e-3),
                                        ("irrtstar", 5.0, 3000, 5e-3)]:  # fmt: skip
        r = plan(open_space, s, g, planner=name, iterations=iterations, step=step, seed=0)
        assert r.solved and d <= r.length < (1 + tol) * d
        off = (r.path - s) @ np.array([-u[1], u[0]])
        assert np.max(np.abs(off)) < 2.0
        np.testing.assert_allclose(r.path[[0, -1]], [s, g])


def test_detour_within_two_percent_of_optimum(walled):
    s, g = (-20.0, 0.0), (20.0, 0.0)
    opt = shortest_path(walled, s, g).length
    r = plan(walled, s, g, planner="irrtstar", iterations=6000, step=5.0, seed=2)
    assert r.solved and opt - 1e-3 <= r.length < 1.02 * opt
    assert all(walled.exact_motion_valid(*p, *q) for p, q in zip(r.path[:-1], r.path[1:], strict=True))
    # The cost curve only goes down and ends at the returned path.
    c = r.cost_curve[:, 2]
    assert np.all(np.diff(c) < 0) and c[-1] == pytest.approx(r.length)
    assert np.all(np.diff(r.cost_curve[:, 0]) >= 0) and r.cost_curve[-1, 0] <= r.iterations == 6000


def test_rrt_stops_at_first_solution(walled):
    r = plan(walled, (-20.0, 0.0), (20.0, 0.0), planner="rrt", iterations=5000, seed=0)
    assert r.solved and r.iterations < 5000 and len(r.cost_curve) == 1


def test_time_budget(walled):
    r = plan(walled, (-20.0, 0.0), (20.0, 0.0), planner="aorrtc", iterations=None, time_limit=0.2, seed=0)
    assert r.solved and r.run_time < 2.0
    assert r.length >= shortest_path(walled, (-20.0, 0.0), (20.0, 0.0)).length - 1e-3


def test_corridor_respected_by_every_vertex_and_edge():
    # An L-shaped corridor: the straight line from start to goal leaves it.
    traj = np.array([[-40.0, 40.0], [-40.0, -40.0], [40.0, -40.0]])
    corridor = Corridor.from_array(traj, 4.0)
    space = AgentSpace(scenes.free_space(), corridor=corridor, resolution=0.5)
    s, g = (-40.0, 38.0), (38.0, -40.0)
    assert not corridor.covers_segment(s, g)
    opt = shortest_path(space, s, g)
    assert opt.length > math.hypot(78.0, 78.0) + 10
    for name in ("rrt", "rrtstar", "irrtstar"):
        r = plan(space, s, g, planner=name, iterations=2000, seed=5, snapshots=3)
        assert r.solved and r.length >= opt.length - 1e-3
        assert np.all(corridor.contains(r.path))
        assert all(corridor.covers_segment(p, q) for p, q in zip(r.path[:-1], r.path[1:], strict=True))
        edges = r.snapshots[-1].edges
        assert len(edges) > 10
        assert all(corridor.covers_segment(p, q) for p, q in edges)


def test_same_seed_same_path(walled):
    s, g = (-20.0, 0.0), (20.0, 0.0)
    first = plan(walled, s, g, planner="irrtstar", iterations=800, seed=3)
    other = plan(walled, s, g, planner="rrtstar", iterations=800, seed=4)
    again = plan(walled, s, g, planner="irrtstar", iterations=800, seed=3)
    assert np.array_equal(first.path, again.path) and first.length == again.length
    np.testing.assert_array_equal(first.cost_curve[:, [0, 2]], again.cost_curve[:, [0, 2]])
    assert not np.array_equal(first.path, other.path)


# ---------------------------------------------------------------------- corridor files
def test_corridor_files(tmp_path):
    trajs = np.array([[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]], [[5.0, 5.0], [6.0, 7.0], [8.0, 9.5]]])
    save_corridor(tmp_path / "c.csv", trajs)
    np.save(tmp_path / "c.npy", trajs)
    (tmp_path / "c.json").write_text(json.dumps({"trajectories": trajs.tolist()}))
    for name in ("c.csv", "c.npy", "c.json"):
        c = load_corridor(tmp_path / name, 2.0)
        assert len(c.trajectories) == 2
        np.testing.assert_array_equal(c.trajectories[1], trajs[1])
    np.save(tmp_path / "bad.npy", np.array([{"x": 1}], dtype=object))
    with pytest.raises(PlanningError, match="bad.npy"):
        load_corridor(tmp_path / "bad.npy", 2.0)
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    with pytest.raises(PlanningError, match="header must name columns x and y"):
        load_corridor(tmp_path / "bad.csv", 2.0)
    with pytest.raises(PlanningError, match="corridor width"):
        load_corridor(tmp_path / "c.csv", -1.0)
    # The polygon contains every point closer than the inner width to a polyline.
    c = load_corridor(tmp_path / "c.csv", 2.0)
    rng = np.random.default_rng(0)
    p = rng.uniform(-3, 13, size=(2000, 2))
    d = shapely.distance(shapely.MultiLineString([t for t in trajs]), shapely.points(p))
    assert np.all(c.contains(p[d < c.inner_width]))
    assert not np.any(c.contains(p[d > c.width + 1e-9]))


# ---------------------------------------------------------------------- CLI and recording
def test_cli_plan_json_and_recording(scene_folder, tmp_path, capsys):
    out, rrd = tmp_path / "plan.json", tmp_path / "plan.rrd"
    argv = [
        "plan", str(scene_folder), "--start", "5,5", "--goal", "60,80", "--iterations", "1500",
        "--seed", "1", "--json", str(out), "--rrd", str(rrd),
    ]  # fmt: skip
    assert main(argv) == 0
    doc = json.loads(out.read_text())
    assert doc["solved"] and doc["iterations"] == 1500 and doc["planner"] == "irrtstar"
    assert doc["ratio"] >= 1.0 - 1e-6 and doc["optimum"]["length_m"] <= doc["length_m"]
    assert doc["path"][0] == [5.0, 5.0] and doc["path"][-1] == [60.0, 80.0]
    rows = entity_rows(rrd)
    assert rows["/planner/tree"] >= 40
    assert rows["/planner/path"] >= 2 and rows["/planner/ellipse"] >= 1
    assert rows["/planner/cost/best"] == len(doc["cost_curve"]) and rows["/planner/cost/optimum"] == 2
    assert rows["/planner/optimum"] == 1 and rows["/planner/endpoints"] == 1 and rows["/map/footprints"] == 1
    check_blueprint(rrd, ["Planner", "Config"], "iteration")
    assert not list(tmp_path.glob(".*partial*"))


def test_cli_errors_and_no_solution(scene_folder, tmp_path, capsys):
    base = ["plan", str(scene_folder), "--goal", "60,80"]
    assert main([*base, "--start", "20,15"]) == EXIT_USAGE
    assert "start (20, 15) is inside a building" in capsys.readouterr().err
    assert main([*base, "--start=-5,5"]) == EXIT_USAGE
    assert "outside the scene" in capsys.readouterr().err
    assert main([*base, "--start", "30.2,15"]) == EXIT_USAGE
    assert "in collision" in capsys.readouterr().err
    traj = tmp_path / "t.csv"
    traj.write_text("x,y\n5,5\n5,90\n60,90\n")
    assert main([*base, "--start", "50,5", "--corridor", str(traj), "--corridor-width", "3"]) == EXIT_USAGE
    assert "outside the corridor" in capsys.readouterr().err
    out = tmp_path / "none.json"
    status = main([*base, "--start", "5,5", "--planner", "rrt", "--iterations", "3", "--json", str(out)])
    assert status == EXIT_NO_SOLUTION
    assert "no solution: RRT found no path within 3 iterations" in capsys.readouterr().err
    assert json.loads(out.read_text())["solved"] is False


def test_free_points_snap_into_the_corridor_clear_of_buildings():
    scene = scenes.load("default")
    corridor = Corridor.from_array(np.array([[200.0, 150.0], [200.0, 100.0]]), 10.0)  # on the avenue
    space = AgentSpace(scene, radius=0.5, corridor=corridor)
    np.testing.assert_array_equal(space.nearest_free_point((201.0, 120.0)), (201.0, 120.0))
    p = space.nearest_free_point((150.0, 125.0))  # inside a building west of the avenue
    assert space.exact_state_valid(*p) and space.in_corridor(*p)
    assert 190.0 <= p[0] < 190.5 and p[1] == pytest.approx(125.0, abs=0.25)
    q = space.farthest_free_point((200.0, 150.0))
    assert space.exact_state_valid(*q) and space.in_corridor(*q)
    assert np.hypot(q[0] - 200.0, q[1] - 150.0) > 59.0  # the far end of the 50 m + 10 m corridor


def test_lift_decides_which_low_objects_block():
    """The agent stands ``lift`` above the lowest point: a 0.5 m bench blocks it at the default
    0.2 m lift (map and FCL alike) and is stepped over at 1 m, the wall stays an obstacle."""
    mat = get_material("concrete")
    bench = building_mesh([Building(10.0, -2.0, 14.0, 2.0, 0.5)])
    scene = Scene(
        [
            SceneObject("ground", ground_mesh(-50.0, -50.0, 50.0, 50.0), mat, "ground"),
            SceneObject("bench", bench, mat, "other"),
            SceneObject("wall", wall(0.0, -20.0, 0.0, 20.0, 10.0), mat, "other"),
        ],
        name="bench",
    )
    low, high = AgentSpace(scene, radius=R), AgentSpace(scene, radius=R, lift=1.0)
    assert low.z0 == pytest.approx(0.2) and high.z0 == pytest.approx(1.0)
    assert not low.exact_state_valid(12.0, 0.0) and not low.state_valid(12.0, 0.0)
    assert high.exact_state_valid(12.0, 0.0) and high.state_valid(12.0, 0.0)
    assert not high.exact_motion_valid(-5.0, 0.0, 5.0, 0.0)  # the 10 m wall still blocks
    assert len(high.obstacles) < len(low.obstacles)  # the bench left the 2D map
