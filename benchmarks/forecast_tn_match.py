"""How far ahead tn-match's tracks carry: forecast error 1, 2 and 3 s past the last fingerprint.

Usage: python benchmarks/forecast_tn_match.py RUN DATASET [--t-obs 4] [--horizon 3] [--max 1000] [--oracle]
       [--speed-spread 0.1]

Takes a ``tn-match`` run (trained for tracking or forecasting), tracks the first ``t_obs`` steps of
test trajectories from fingerprints with fresh 6 dB noise and extrapolates ``horizon`` steps
(:func:`estimation.extrapolate`, constant velocity), and as ``Estimator.predict`` forecasts: users
faster than the place table's speed carried on through the motion table along the lanes, and, the
default, along the streets of the data set's street map where they drive on one
(:meth:`Estimator.forecast`, ``street_forecast``). Prints, per split (seen area, held-out
region), the tracking RMSE over the observed steps and the mean distance to the true position at
each forecast step (metres) with its ratio to the tracking error and the mean per-trajectory RMSE
over the forecast steps (all users, and vehicles alone), and the same forecasts from the
true last position and velocity: what the users' own changes of motion leave unpredictable.
``--oracle`` adds the floor on the same draws: the oracle's particle filter (the generator's motion
model, the exact likelihood) tracking the observed steps and carrying its particles on
(:class:`estimation.oracle.OracleMethod`, forecasting), with its own tracking error.
``--speed-spread S`` adds the oracle that reads each user's speeds from its fingerprints, knowing
them only to within +-S (:meth:`estimation.oracle.Oracle.with_speed_spread`, particles x4).
"""

from __future__ import annotations

import time

import numpy as np
import torch
from _common import run_dataset_parser, test_draws


def main() -> None:
    from estimation import Estimator, trajectory_rmse
    from estimation.adapter import load_splits
    from estimation.smoothing.forecast import extrapolate
    from mmwsim.trajectories import KINDS

    ap = run_dataset_parser(__doc__)
    ap.add_argument("--t-obs", type=int, default=4)
    ap.add_argument("--horizon", type=int, default=3)
    ap.add_argument(
        "--oracle", action="store_true", help="also the oracle's forecast (seconds per trajectory)"
    )
    ap.add_argument(
        "--speed-spread",
        type=float,
        help="also the oracle knowing the speeds only to within +-S (with --oracle)",
    )
    args = ap.parse_args()
    if args.speed_spread is not None and not args.oracle:
        ap.error("--speed-spread needs --oracle")
    torch.set_num_threads(2)

    est = Estimator.load(args.run)
    if est.name != "tn-match":
        raise SystemExit(f"{args.run}: a {est.name} run; this benchmark reads tn-match runs")
    splits = ("validation", "test/seen", "test/holdout")
    sets, _ = load_splits(args.dataset, splits)
    est.attach(sets["validation"], args.sigma)
    print(
        f"{args.run}: trained for {est.config.task}; t_obs {args.t_obs}, horizon {args.horizon}, "
        f"{args.sigma:g} dB"
    )
    for split in splits[1:]:
        data = sets[split]
        if data.length < args.t_obs + args.horizon:
            raise SystemExit(f"{split}: {data.length}-step trajectories, need {args.t_obs + args.horizon}")
        data, bits = test_draws(data, args.max, args.sigma)
        bits = bits[:, : args.t_obs]
        t0 = time.perf_counter()
        tracked = []
        with torch.no_grad():
            for a in range(0, data.n, 256):
                xy, post, fine = est.inputs(bits[a : a + 256])
                tracked.append(est.net.eval().track(xy, post, fine))
        tracked = torch.cat(tracked)
        secs = time.perf_counter() - t0
        true = data.positions
        track_err = trajectory_rmse(tracked.numpy(), true[:, : args.t_obs]).mean()
        print(f"  {split}: {data.n} trajectories, tracking RMSE {track_err:.2f} m ({secs:.1f} s)")
        truth = torch.from_numpy(true[:, : args.t_obs])
        future = true[:, args.t_obs : args.t_obs + args.horizon]
        vehicles = data.kind == KINDS.index("vehicle")
        for name, track in (("tn-match", tracked), ("true last position and velocity", truth)):
            pred = extrapolate(track.double(), args.horizon).numpy()
            _print_steps(f"forecast from {name}", pred, future, track_err, vehicles)
            est.street_forecast = False
            lanes = est.forecast(track.double(), args.horizon).numpy()
            _print_steps("  fast users along the lanes", lanes, future, track_err, vehicles)
            est.street_forecast = True
            streets = est.forecast(track.double(), args.horizon).numpy()
            _print_steps(
                "  ... along the streets where on one (predict's)", streets, future, track_err, vehicles
            )
        if args.oracle:
            from estimation.oracle import OracleMethod

            m = OracleMethod(args.dataset).for_sigma(args.sigma, sets["validation"])
            oracles = [("oracle", m.oracle)]
            if args.speed_spread is not None:
                reading = m.oracle.with_particle_factor(4).with_speed_spread(args.speed_spread)
                oracles.append((f"oracle reading speeds +-{args.speed_spread:g}", reading))
            for name, oracle in oracles:
                t0 = time.perf_counter()
                both = oracle.track(bits, m.matcher, [args.t_obs], horizon=args.horizon)[args.t_obs]
                own = trajectory_rmse(both[:, : args.t_obs], true[:, : args.t_obs]).mean()
                print(f"    {name}: tracking RMSE {own:.2f} m ({time.perf_counter() - t0:.1f} s)")
                _print_steps(f"{name} forecast", both[:, args.t_obs :], future, track_err, vehicles)


def _print_steps(
    name: str, pred: np.ndarray, future: np.ndarray, track_err: float, vehicles: np.ndarray
) -> None:
    """Mean distance at every forecast step, and its ratio to tn-match's tracking error; the mean
    per-trajectory RMSE, of all users and of the ``vehicles`` (a mask) alone."""
    dist = np.linalg.norm(pred - future, axis=-1).mean(0)
    steps = ", ".join(f"{h + 1} s {d:.2f} m ({d / track_err:.2f}x)" for h, d in enumerate(dist))
    rmse = np.sqrt(np.square(pred - future).sum(-1).mean(-1))
    print(f"    {name}: {steps}; RMSE {rmse.mean():.2f} m (vehicles {rmse[vehicles].mean():.2f})")


if __name__ == "__main__":
    main()
