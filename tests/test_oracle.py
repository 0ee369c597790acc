"""The oracle floor (estimation.oracle): on data drawn from its own model it beats every method."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import torch

from estimation import (
    CLASSICAL_NAMES,
    EstimationError,
    Estimator,
    TrainConfig,
    accuracy_table,
    cost_table,
    evaluate,
    method,
    noisy_bits,
    trajectory_rmse,
)
from estimation.data import SequenceSet
from estimation.evaluation import NetworkMethod
from estimation.matching import FingerprintMatcher
from estimation.oracle import Oracle, OracleMethod, _Space
from estimation.synthetic import toy_grid
from mmwsim.geometry.freespace import CoverageMask, FreeSpace
from mmwsim.scene import ReceiverGrid
from mmwsim.trajectories.generate import generate_kind
from mmwsim.trajectories.motion import KINDS, PEDESTRIAN, STATIC, VEHICLE
from mmwsim.trajectories.streets import StreetNetwork

# A 24 m x 24 m toy city: four 6 m blocks, a cross of streets between them, a smooth toy PDP on a
# 1 m grid. Slow vehicles keep 6-step drives inside it.
GRID = ReceiverGrid((0.0, 0.0), 1.0, (24, 24))
BLOCKS = [shapely.box(x, y, x + 6, y + 6) for x in (2, 15) for y in (2, 15)]
MODELS = {
    "static": STATIC,
    "pedestrian": PEDESTRIAN,
    "vehicle": VEHICLE.replace(mean_speed=3.0, max_speed=5.0, speed_change=1.0, clearance=1.0),
}
COUNTS = {"static": 8, "pedestrian": 36, "vehicle": 36}
LENGTH = 6


@pytest.fixture(scope="module")
def world():
    xy, pdp = toy_grid(24, 24, 1.0, 8, 12, seed=0)
    valid = np.ones(GRID.size, dtype=bool)
    valid[GRID.nearest_index(np.array([[5.0, 5.0], [18.0, 5.0]]))] = False  # two points without coverage
    rows = np.flatnonzero(valid)
    net = StreetNetwork.from_footprints(BLOCKS, GRID.bounds, 2.5, spur_length=3.0)

    def draw(seed: int) -> SequenceSet:
        """Trajectories from mmwsim's generator with the oracle's models, on the toy grid."""
        rng = np.random.default_rng(seed)
        pos, kind = [], []
        for k, n in COUNTS.items():
            fs = FreeSpace(BLOCKS, GRID.bounds, MODELS[k].clearance, CoverageMask(GRID, valid))
            p, _ = generate_kind(
                None, MODELS[k], n, LENGTH, rng, free_space=fs, streets=net if k == "vehicle" else None
            )
            pos.append(p)
            kind.append(np.full(n, KINDS.index(k), dtype=np.int8))
        p = np.concatenate(pos)
        row_of = np.full(GRID.size, -1)
        row_of[rows] = np.arange(len(rows))
        index = row_of[GRID.nearest_index(p)]
        assert (index >= 0).all()
        return SequenceSet(
            torch.from_numpy(pdp[rows]),
            xy[rows],
            index,
            p.astype(np.float32),
            np.concatenate(kind),
            -115.0,
            GRID.bounds,
        )

    def oracle(n_particles: int = 512, seed: int = 0) -> Oracle:
        return Oracle(
            GRID, valid, BLOCKS, GRID.bounds, MODELS, COUNTS, net, n_particles=n_particles, seed=seed
        )

    return {"test": draw(1), "validation": draw(2), "oracle": oracle, "valid": valid}


def test_oracle_beats_every_method_on_data_from_its_own_model(world):
    te, va = world["test"], world["validation"]
    cfg = TrainConfig(model="tn-match", sigma=6.0, options={"search": 32, "k": 8, "d": 16, "ff": 32})
    untrained = NetworkMethod(Estimator(cfg, va.n_beams, va.n_bins, va.normaliser()).attach(va), "tn-match")
    methods = [method("knn-kalman"), method("match-cv"), untrained, OracleMethod(world["oracle"]())]
    ev = evaluate(
        methods, {"test": te}, [6.0], va, lengths=[3, LENGTH], table_length=LENGTH, log=lambda *_: None
    )
    for length in (3, LENGTH):
        err = {r["method"]: r["mean"] for r in ev.select(length=length, kind="all")}
        assert set(err) == {"oracle", "knn-kalman", "match-cv", "tn-match"}
        others = min(v for k, v in err.items() if k != "oracle")
        assert err["oracle"] < 0.85 * others, err
    for kind in ("pedestrian", "vehicle"):
        err = {r["method"]: r["mean"] for r in ev.select(length=LENGTH, kind=kind)}
        assert err["oracle"] == min(err.values()), (kind, err)
    # evaluated last, printed first: the floor opens every table
    assert accuracy_table(ev, "test").splitlines()[2].startswith("| oracle |")
    assert cost_table(ev).splitlines()[2].startswith("| oracle |")


def test_oracle_forecast_beats_every_method_on_data_from_its_own_model(world):
    te, va = world["test"], world["validation"]
    t_obs, horizon = 4, LENGTH - 4
    task = dict(task="forecasting", t_obs=t_obs, horizon=horizon)
    cfg = TrainConfig(model="tn-match", sigma=6.0, options={"search": 32, "k": 8, "d": 16, "ff": 32}, **task)
    untrained = NetworkMethod(Estimator(cfg, va.n_beams, va.n_bins, va.normaliser()).attach(va), "tn-match")
    oracle = OracleMethod(world["oracle"](), **task)
    ev = evaluate(
        [method("knn-kalman", **task), untrained, oracle], {"test": te}, [6.0], va, log=lambda *_: None
    )
    err = {r["method"]: r["mean"] for r in ev.select(task="forecasting", kind="all")}
    assert set(err) == {"oracle", "knn-kalman", "tn-match"}
    assert err["oracle"] < 0.85 * min(err["knn-kalman"], err["tn-match"]), err
    # the forecast is the tracked filter carried on: its first step is not the last tracked one
    rows = np.flatnonzero(te.kind == KINDS.index("vehicle"))[:8]
    bits = noisy_bits(te, 6.0, torch.Generator().manual_seed(3))[rows]
    ahead = oracle.for_sigma(6.0, va).predict_lengths(bits, [t_obs])[t_obs][0]
    tracked = OracleMethod(world["oracle"]()).for_sigma(6.0, va).predict_lengths(bits, [t_obs])[t_obs][0]
    assert ahead.shape == (8, horizon, 2) and tracked.shape == (8, t_obs, 2)
    assert np.median(np.linalg.norm(ahead[:, 0] - tracked[:, -1], axis=-1)) > 1.0  # vehicles move on
    with pytest.raises(EstimationError, match="forecasting with t_obs"):
        OracleMethod(task="forecasting", t_obs=0, horizon=2)


def test_a_misspecified_oracle_loses_the_floor(world):
    te, va = world["test"], world["validation"]
    true = world["oracle"]()
    wrong = true.with_model("vehicle", mean_speed=3.5)
    assert true.motion["vehicle"].model.mean_speed == 3.0  # the original is untouched
    assert wrong.motion["vehicle"].model.mean_speed == 3.5
    assert wrong.motion["pedestrian"] is true.motion["pedestrian"]
    rows = np.flatnonzero(te.kind == KINDS.index("vehicle"))
    bits = noisy_bits(te, 6.0, torch.Generator().manual_seed(3))[rows]
    err = {}
    for name, oracle in (("true", true), ("wrong", wrong)):
        pred = OracleMethod(oracle).for_sigma(6.0, va).predict_lengths(bits, [LENGTH])[LENGTH][0]
        err[name] = trajectory_rmse(pred, te.positions[rows]).mean()
    # the vehicles' speeds are 3 +- 1 m/s steps exactly; half a metre per second off and the
    # particles no longer follow them
    assert err["wrong"] > 1.25 * err["true"], err
    with pytest.raises(EstimationError, match="no moving kind 'static'"):
        true.with_model("static", mean_speed=1.0)
    with pytest.raises(EstimationError, match="cannot change speed "):
        true.with_model("vehicle", speed=1.0, mean_speed=3.5)
    with pytest.raises(EstimationError, match="cannot change clearance"):
        true.with_model("vehicle", clearance=2.0)
    with pytest.raises(EstimationError, match="max_speed"):
        true.with_model("vehicle", mean_speed=6.0)


def test_an_oracle_that_reads_the_speeds_finds_them(world):
    te, va = world["test"], world["validation"]
    true = world["oracle"]()
    wrong = true.with_model("vehicle", mean_speed=3.5)
    reads = wrong.with_speed_spread(0.2)  # its particles' mean speeds span 2.8 to 4.2 m/s
    assert reads.motion["vehicle"].model.mean_speed == 3.5 and reads.motion["vehicle"].spread == 0.2
    assert wrong.motion["vehicle"].spread == 0.0  # the original is untouched
    assert reads.with_model("vehicle", speed_change=1.1).motion["vehicle"].spread == 0.2
    rows = np.flatnonzero(te.kind == KINDS.index("vehicle"))
    bits = noisy_bits(te, 6.0, torch.Generator().manual_seed(3))[rows]
    pred, err = {}, {}
    for name, oracle in (
        ("true", true),
        ("wrong", wrong),
        ("reads", reads),
        ("none", true.with_speed_spread(0)),
    ):
        pred[name] = OracleMethod(oracle).for_sigma(6.0, va).predict_lengths(bits, [LENGTH])[LENGTH][0]
        err[name] = trajectory_rmse(pred[name], te.positions[rows]).mean()
    # told the vehicles' speed half a metre per second off, the oracle loses them; reading each
    # vehicle's speed from its fingerprints, it finds most of the way back
    assert err["reads"] < 0.8 * err["wrong"], err
    assert err["reads"] < 1.2 * err["true"], err
    assert np.array_equal(pred["none"], pred["true"])  # no spread: the oracle itself, bit for bit
    for bad in (-0.1, 0.6, float("nan")):
        with pytest.raises(EstimationError, match="speed spread"):
            true.with_speed_spread(bad)
    with pytest.raises(EstimationError, match="no moving kind 'static'"):
        true.with_speed_spread(0.1, kinds=["static"])
    # the factor on the particle counts that a spread oracle needs (its own test of convergence)
    assert true.with_particle_factor(2.5).n_particles == {
        k: round(2.5 * n) for k, n in true.n_particles.items()
    }
    with pytest.raises(EstimationError, match="particle factor"):
        true.with_particle_factor(0.0)


def test_prefix_estimates_see_only_their_steps_and_are_seeded(world):
    te = world["test"]
    bits = noisy_bits(te, 6.0, torch.Generator().manual_seed(3))
    lik = (
        FingerprintMatcher(te.grid_pdp, te.grid_xy, 6.0, te.threshold, eps=1e-30)
        .scores(bits.reshape(-1, *bits.shape[2:]).float())
        .reshape(te.n, LENGTH, -1)
    )
    full = world["oracle"](256).smooth(lik, [3, LENGTH])
    again = world["oracle"](256).smooth(lik, [3, LENGTH])
    prefix = world["oracle"](256).smooth(lik[:, :3], [3])
    other = world["oracle"](256, seed=1).smooth(lik, [LENGTH])
    assert np.array_equal(full[LENGTH], again[LENGTH]) and np.array_equal(full[3], again[3])
    assert np.array_equal(full[3], prefix[3])  # no look-ahead: the later fingerprints change nothing
    assert not np.array_equal(full[LENGTH], other[LENGTH])
    # another seed moves the estimates by Monte-Carlo error only
    a, b = trajectory_rmse(full[LENGTH], te.positions), trajectory_rmse(other[LENGTH], te.positions)
    assert abs(a.mean() - b.mean()) < 0.25 * a.mean()


def test_fast_free_space_tests_agree_with_the_generators(world):
    """The raster shortcut answers as mmwsim's FreeSpace (shapely) does, points and segments."""
    g = world["oracle"]().grid
    space = _Space(BLOCKS, GRID.bounds, 1.0, g, 0.25)
    fs = FreeSpace(BLOCKS, GRID.bounds, 1.0, CoverageMask(GRID, world["valid"]))
    rng = np.random.default_rng(0)
    a = rng.uniform(-1.0, 24.0, (20000, 2))
    assert np.array_equal(space.points_ok(a), fs.points_ok(a))
    a = a[fs.points_ok(a)]
    h = rng.uniform(0, 2 * np.pi, len(a))
    for step in (0.0, 1.4, 5.0):
        b = a + step * np.column_stack([np.cos(h), np.sin(h)])
        assert np.array_equal(space.segments_ok(a, b, 5), fs.segments_ok(a, b))


def test_bad_input_raises_estimation_error(world):
    te = world["test"]
    oracle = world["oracle"](64)
    with pytest.raises(EstimationError, match="n_particles"):
        world["oracle"](0)
    with pytest.raises(EstimationError, match="log-likelihoods must be"):
        oracle.smooth(np.zeros((2, 3, 5)), [3])
    with pytest.raises(EstimationError, match="prefix lengths"):
        oracle.smooth(np.zeros((2, 3, oracle.grid.size)), [4])
    with pytest.raises(EstimationError, match="horizon"):
        oracle.smooth(np.zeros((2, 3, oracle.grid.size)), [2], horizon=2)
    with pytest.raises(EstimationError, match="NaN"):
        oracle.smooth(np.full((2, 3, oracle.grid.size), np.nan), [3])
    with pytest.raises(EstimationError, match="counts"):
        Oracle(GRID, world["valid"], BLOCKS, GRID.bounds, MODELS, {"hybrid": 3})
    with pytest.raises(EstimationError, match="needs the data set"):
        OracleMethod().for_sigma(6.0, te)
    with pytest.raises(EstimationError, match="for_sigma"):
        OracleMethod(oracle).predict_lengths(torch.zeros(1, 3, 8, 12), [3])
    with pytest.raises(EstimationError, match="toy"):
        OracleMethod("toy:n=64")
    with pytest.raises(EstimationError, match="not found"):
        OracleMethod("/nonexistent/data.zarr")
    wrong = FingerprintMatcher(te.grid_pdp[:10], te.grid_xy[:10], 6.0, te.threshold)
    with pytest.raises(EstimationError, match="grid"):
        oracle.track(torch.zeros(1, 3, 8, 12), wrong, [3])
    assert "oracle" in CLASSICAL_NAMES and isinstance(method("oracle"), OracleMethod)
    relabelled = OracleMethod(oracle)
    relabelled.name = "oracle x2"  # e.g. another particle count beside the default one
    assert relabelled.for_sigma(6.0, te).name == "oracle x2"


def test_cli_refuses_the_oracle_on_a_toy_data_set(tmp_path, capsys):
    from mmwsim.cli import main

    assert main(["evaluate", "oracle", "--dataset", "toy:n=64,length=5", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "toy" in err


class _Dataset:
    """What the oracle reads of a data set: grid, validity, scene, content hash and the store
    holding the generated trajectories (here a trajectory-only store, no PDPs)."""

    def __init__(self, path, grid, valid, scene):
        self.path, self.grid, self.valid, self._scene, self.content_hash = path, grid, valid, scene, "x"

    def scene(self):
        return self._scene


def test_oracle_of_a_data_set_reads_its_generator(tmp_path):
    """On the default city with a 25 m grid: the scene's buildings, the street network and the
    stored generation attributes; given each step's true cell, it places moving users better
    than the cell centres do."""
    from mmwsim.scene import load_scene
    from mmwsim.trajectories import write_trajectories
    from mmwsim.trajectories.generate import generate
    from mmwsim.trajectories.splits import split

    scene = load_scene("default")
    grid = ReceiverGrid((0.0, 0.0), 25.0, (17, 17))
    inside = shapely.intersects_xy(shapely.union_all(scene.footprints), *grid.positions()[:, :2].T)
    valid = ~inside
    counts = {"static": 2, "pedestrian": 10, "hybrid": 4, "vehicle": 10}
    t = generate(
        scene,
        counts,
        5,
        seed=3,
        coverage=CoverageMask(grid, valid),
        vehicles_on_streets=True,
        free_space_bounds=grid.bounds,
    )
    write_trajectories(tmp_path / "t.zarr", split(t, (0.0, 0.0, 1.0)))
    oracle = Oracle.from_dataset(
        _Dataset(tmp_path / "t.zarr", grid, valid, scene), n_particles=256, resolution=0.5
    )
    assert oracle.kinds == list(KINDS) and type(oracle.motion["vehicle"]).__name__ == "_StreetMotion"
    assert oracle.log_prior["pedestrian"] == pytest.approx(np.log(10 / 26))
    test = split(t, (0.0, 0.0, 1.0))["test"]
    moving = test.kind != KINDS.index("static")
    rows = oracle.grid.rows(test.positions[moving])
    lik = np.where(np.arange(oracle.grid.size) == rows[..., None], 0.0, -30.0)  # each step's true cell
    est = oracle.smooth(lik, [5])[5]
    assert np.isfinite(est).all() and oracle.dead == 0
    cells = trajectory_rmse(oracle.grid.xy[rows], test.positions[moving]).mean()
    assert trajectory_rmse(est, test.positions[moving]).mean() < 0.8 * cells


def test_oracle_of_trajectories_knows_their_own_habits(tmp_path):
    """Trajectories of other habits than the data set's (here pedestrians at 5 m/s, made with
    ``generate(..., models=...)`` and never stored) get an oracle of their own generator, which
    places them better than the oracle told the reference pedestrian's habits."""
    from mmwsim.scene import load_scene
    from mmwsim.trajectories.generate import generate

    scene = load_scene("default")
    grid = ReceiverGrid((0.0, 0.0), 4.0, (50, 50))
    valid = ~shapely.intersects_xy(shapely.union_all(scene.footprints), *grid.positions()[:, :2].T)
    fast = PEDESTRIAN.replace(mean_speed=5.0, max_speed=6.0, speed_change=0.5)
    t = generate(
        scene,
        {"pedestrian": 24},
        6,
        seed=4,
        models={"pedestrian": fast},
        coverage=CoverageMask(grid, valid),
        free_space_bounds=grid.bounds,
    )
    ds = _Dataset(tmp_path / "none.zarr", grid, valid, scene)
    own = Oracle.from_trajectories(ds, t, n_particles=256, resolution=0.5)
    assert own.kinds == ["pedestrian"] and own.motion["pedestrian"].model == fast
    assert np.allclose(own.log_prior["pedestrian"], 0.0)
    told = own.with_model("pedestrian", **{k: getattr(PEDESTRIAN, k) for k in ("mean_speed", "max_speed")})
    rows = own.grid.rows(t.positions)
    lik = np.where(np.arange(own.grid.size) == rows[..., None], 0.0, -30.0)  # each step's true cell
    err = {
        name: trajectory_rmse(o.smooth(lik, [6])[6], t.positions).mean()
        for name, o in (("own", own), ("told", told))
    }
    assert err["own"] < 0.8 * err["told"], err
    # the attrs alone serve as well; trajectories of another data set or generator are refused
    assert Oracle.from_trajectories(ds, dict(t.attrs), n_particles=256, resolution=0.5).kinds == [
        "pedestrian"
    ]
    with pytest.raises(EstimationError, match="another data set"):
        Oracle.from_trajectories(ds, {**t.attrs, "dataset": "other"})
    with pytest.raises(EstimationError, match="do not say how"):
        Oracle.from_trajectories(ds, {k: v for k, v in t.attrs.items() if k != "models"})
    with pytest.raises(EstimationError, match="made by mmwsim's generator"):
        Oracle.from_trajectories(ds, np.zeros((2, 6, 2)))
