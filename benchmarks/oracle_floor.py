"""The oracle floor beside the trackers, on the same noise draws.

Usage: python benchmarks/oracle_floor.py DATASET [RUN] [--max 1000] [--sigma 6] [--length 7]
       [--convergence 0.25,1,4] [--misspecify vehicle.mean_speed=8.35,8.4]
       [--speed-spread 0.05,0.1] [--spread-particles 4] [--splits test/seen] [--threads 1]

The oracle (:mod:`estimation.oracle`) knows the generator's motion model and the exact fingerprint
likelihood, so its error is the floor any tracker can reach on the data set's trajectories. The
script evaluates it with knn-kalman, match-cv and, if given, a training run (e.g. tn-match) through
:func:`estimation.evaluate` (one noise draw per split shared by all) on test/seen and
test/holdout, and prints the mean per-trajectory RMSE per kind at ``--length`` steps with each
method's prediction time. ``--convergence F1,F2,...`` adds the oracle with its default particle
counts scaled by each factor (same draws), to show how far Monte-Carlo error still moves it.
``--misspecify KIND.FIELD=V1,V2`` (repeatable) adds the oracle with one field of one kind's motion
model set to each value (:meth:`estimation.oracle.Oracle.with_model`): how much of the floor rests
on knowing the generator's constants exactly. ``--speed-spread S1,S2`` adds the oracle that knows
every moving kind's speeds only to within +-S (:meth:`estimation.oracle.Oracle.with_speed_spread`:
each particle scales its kind's speeds by its own factor, so the filter reads each user's speeds
from its fingerprints): the floor of a tracker that knows how the generator moves users but not
at which speeds. Its particles spread over one more dimension, so ``--spread-particles F`` scales
their default counts by ``F`` (compare with 1 to see the Monte-Carlo error).
"""

from __future__ import annotations

import argparse
import time

import torch


def main() -> None:
    from estimation import EstimationError, cost_table, evaluate, method
    from estimation.adapter import load_splits
    from estimation.oracle import ORACLE_PARTICLES, OracleMethod
    from estimation.report import comparison_table

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("run", nargs="?", help="a training run folder (e.g. a tn-match run) to compare")
    ap.add_argument("--max", type=int, default=1000, help="trajectories per split (seeded subset)")
    ap.add_argument("--sigma", type=float, default=6.0, help="fingerprint noise, dB (default 6)")
    ap.add_argument("--length", type=int, default=7, help="steps of the table (default 7)")
    ap.add_argument("--convergence", help="factors on the oracle's particle counts, e.g. 0.25,1,4")
    ap.add_argument(
        "--misspecify",
        action="append",
        default=[],
        metavar="KIND.FIELD=V1,V2",
        help="add the oracle with a motion model field changed to each value (repeatable)",
    )
    ap.add_argument(
        "--speed-spread",
        help="add the oracle knowing every kind's speeds only to within +-S, e.g. 0.05,0.1",
    )
    ap.add_argument(
        "--spread-particles",
        type=float,
        default=1.0,
        help="factor on the particle counts of the --speed-spread oracles (default 1)",
    )
    ap.add_argument("--splits", nargs="+", default=["test/seen", "test/holdout"], help="test splits")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    changes = []
    for spec in args.misspecify:
        try:
            target, values = spec.split("=", 1)
            kind, field = target.split(".", 1)
            changes += [(kind, field, float(v)) for v in values.split(",")]
        except ValueError:
            ap.error(f"--misspecify {spec!r}: use KIND.FIELD=V1,V2, e.g. vehicle.mean_speed=8.35")

    try:
        spreads = [float(v) for v in args.speed_spread.split(",")] if args.speed_spread else []
    except ValueError:
        ap.error(f"--speed-spread {args.speed_spread!r}: use shares, e.g. 0.05,0.1")

    splits = tuple(args.splits)
    sets, _ = load_splits(args.dataset, ("validation", *splits))
    t0 = time.perf_counter()
    oracle = OracleMethod(args.dataset)
    print(
        f"oracle of {args.dataset}: built in {time.perf_counter() - t0:.1f} s, particles {ORACLE_PARTICLES}"
    )
    methods = [oracle]
    for f in [float(v) for v in args.convergence.split(",")] if args.convergence else []:
        m = OracleMethod(oracle.oracle.with_particle_factor(f))
        m.name = f"oracle x{f:g}"
        methods.append(m)
    for kind, field, value in changes:
        try:
            m = OracleMethod(oracle.oracle.with_model(kind, **{field: value}))
        except EstimationError as e:
            ap.error(str(e))
        m.name = f"oracle {kind} {field} {value:g}"
        methods.append(m)
    for spread in spreads:
        try:
            m = OracleMethod(
                oracle.oracle.with_particle_factor(args.spread_particles).with_speed_spread(spread)
            )
        except EstimationError as e:
            ap.error(str(e))
        m.name = f"oracle speeds +-{spread:g}" + (
            f" x{args.spread_particles:g}" if args.spread_particles != 1 else ""
        )
        methods.append(m)
    methods += [method("knn-kalman", fit_length=args.length), method("match-cv")]
    if args.run:
        methods.append(method(args.run))
    ev = evaluate(
        methods,
        {s: sets[s] for s in splits},
        [args.sigma],
        sets["validation"],
        lengths=[args.length],
        table_length=args.length,
        max_trajectories=args.max,
    )
    print()
    print(f"mean per-trajectory RMSE (m), {args.length} steps, {args.sigma:g} dB")
    print(
        comparison_table(
            ev, "tracking", list(splits), [args.sigma], ("vehicle", "pedestrian", "hybrid", "all")
        )
    )
    print(cost_table(ev))
    floor = {r["split"]: r["mean"] for r in ev.select(method="oracle", kind="all")}
    for m in methods[1:]:
        gap = {r["split"]: r["mean"] / floor[r["split"]] for r in ev.select(method=m.name, kind="all")}
        print(f"{m.name}: " + ", ".join(f"{s} {g:.2f}x the floor" for s, g in gap.items()))


if __name__ == "__main__":
    main()
