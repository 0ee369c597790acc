"""How a trained model tracks users whose motion is not ours, through the public library API.

    python benchmarks/foreign_motion.py RUN DATASET [METHOD ...] [--n 1000] [--length 7] [--noise 6]
        [--vehicle-speeds 7.5,9.5] [--pedestrian-speeds 1.0,1.8] [--hybrid-speeds 2.6,4.4]
        [--oracle [--speed-spread 0.1]] [--adapt N [--adapt-length 15]]

Others evaluate our models on trajectories of their own generators. This script makes two such
generators that share nothing with :mod:`mmwsim.trajectories` but the free space:

* ``smooth``: velocity as a mean-reverting random process (Ornstein-Uhlenbeck on speed, heading a
  random walk): pedestrians at 0.6-2.2 m/s with 25 degrees of heading noise per second, vehicles at
  5-16 m/s with 8 degrees, anywhere in the free space (no street network), occasional sharp turns;
* ``events``: our own event model with other habits: pedestrians faster and turning four times as
  often by 30 degrees, vehicles off the streets at 11 m/s mean (up to 16) turning by 15 degrees;
* ``lanes`` (vehicles only): the street network's vehicles with those habits (11 m/s mean, up to
  16, stopping more than twice as often), each keeping to a lane 1 to 2.5 m right of the
  centre line that our own vehicles drive on (nearer where the street is too narrow for it).

``--vehicle-speeds 7.5,8.8,9.5`` adds, per value, our own street vehicles with only their speeds
changed: the generator's model with that mean speed (the maximum shifted with it), so they drive at
three exact speeds as ours do, but not at ours. ``--pedestrian-speeds`` and ``--hybrid-speeds`` do
the same for our pedestrians and cyclists.

``smooth`` and ``events`` vehicles roam off the streets and, at 5-16 m/s in a dense city, bounce
off buildings with lateral accelerations no car reaches (over 10 m/s^2 within 7 s in 53 to 65 %
of them): hard cases for any motion prior. ``lanes`` is how a car moves.

All start anywhere in the area (the hold-out region included), step at 1 Hz and bounce off
buildings by drawing a new heading. Fingerprints are drawn from the stored PDPs of the nearest
grid point with fresh noise (``Dataset.fingerprints``); the model is loaded with
``Estimator.load(run).attach(ds)`` and asked with ``predict``, as a user would. Printed beside the
same model's error on the data set's own ``test/seen`` trajectories (same noise, same length),
and beside ``cell``: the error of the grid points the fingerprints were drawn at (a fingerprint
tells its grid point at best, so only a motion prior gets below it; our own vehicles drive on
centre lines that run along grid lines and sit lower).
METHOD names classical trackers to evaluate on the same draws too (``match-cv``, ``knn-kalman``).
``--oracle`` adds the floor of every set our generator made (``events``, our vehicles at other
speeds, our own test users): the oracle of that very generator
(:meth:`estimation.oracle.Oracle.from_trajectories`; the foreign sets' generators made one kind
each, so their oracles know it), so that a model's error on motion that is not ours reads against
what any tracker could reach on it. ``--speed-spread S`` adds, beside each such floor, that oracle
reading every user's speeds within +-S instead of knowing them
(:meth:`estimation.oracle.Oracle.with_speed_spread`, 4x the particles). ``--adapt N`` adds the
model adapted to each generator from fingerprints alone: :meth:`Estimator.adapt_motion` on its own
tracks of N more users per kind of that generator (a fresh draw, not the users it is then scored
on; for our own test users, the validation split's).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np
from _common import predict_batched, stored_bits

KINDS = ("pedestrian", "vehicle")
# kinds whose mean speed --KIND-speeds shifts, with an example for the help
SHIFTED = {"vehicle": "7.5,8.8,9.5", "pedestrian": "1.0,1.8", "hybrid": "2.6,4.4"}


def smooth_walks(fs, kind: str, n: int, length: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, length, 2)`` positions of Ornstein-Uhlenbeck walkers in the free space ``fs``."""
    if kind == "pedestrian":
        lo, hi, sd_speed, sd_heading, p_sharp = 0.6, 2.2, 0.25, math.radians(25), 0.03
    else:
        lo, hi, sd_speed, sd_heading, p_sharp = 5.0, 16.0, 1.5, math.radians(8), 0.05
    pos = fs.sample(n, rng)
    mean = rng.uniform(lo, hi, n)
    speed = mean.copy()
    heading = rng.uniform(0, 2 * np.pi, n)
    out = np.empty((n, length, 2))
    out[:, 0] = pos
    for t in range(1, length):
        speed = np.clip(speed + 0.3 * (mean - speed) + sd_speed * rng.normal(size=n), 0.2 * lo, 1.2 * hi)
        sharp = rng.random(n) < p_sharp
        heading = heading + sd_heading * rng.normal(size=n) + sharp * rng.choice([-1, 1], n) * np.pi / 2
        nxt = pos + speed[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        for _ in range(30):  # bounce: a new heading until the step is free
            bad = ~fs.segments_ok(pos, nxt)
            if not bad.any():
                break
            heading[bad] = rng.uniform(0, 2 * np.pi, int(bad.sum()))
            nxt[bad] = pos[bad] + speed[bad, None] * np.column_stack(
                [np.cos(heading[bad]), np.sin(heading[bad])]
            )
        bad = ~fs.segments_ok(pos, nxt)
        nxt[bad] = pos[bad]  # boxed in: stands still
        pos = nxt
        out[:, t] = pos
    return out


# The ``events`` and ``lanes`` generators' habits: our event model with other parameters.
EVENT_HABITS = {
    "pedestrian": dict(mean_speed=1.6, max_speed=2.4, turn_rate=30.0, p_turn=0.2, p_stop=0.05),
    "vehicle": dict(mean_speed=11.0, max_speed=16.0, turn_rate=15.0, p_turn=0.15, p_stop=0.05),
}


def _habit_walks(ds, kind: str, n: int, length: int, seed: int, on_streets: bool, habits: dict | None = None):
    """Our generator's ``kind`` with ``habits`` (default :data:`EVENT_HABITS`) changed: its
    ``Trajectories``, whose ``attrs`` say how they were made (the oracle of that generator reads
    them)."""
    from mmwsim.trajectories import generate_for_dataset, motion_model

    model = motion_model(kind).replace(**(EVENT_HABITS[kind] if habits is None else habits))
    return generate_for_dataset(
        ds, {kind: n}, length, seed, models={kind: model}, vehicles_on_streets=on_streets
    )


def event_walks(ds, kind: str, n: int, length: int, seed: int):
    """Trajectories (positions ``(n, length, 2)``) of our event model with other parameters
    (vehicles off the street network)."""
    return _habit_walks(ds, kind, n, length, seed, on_streets=False)


def lane_walks(ds, n: int, length: int, seed: int) -> np.ndarray:
    """``(n, length, 2)`` positions of vehicles on the street network with the ``events``
    habits, each ``U(1, 2.5)`` m right of the centre line (of its direction of travel; a
    stopped vehicle keeps its last direction)."""
    centre = _habit_walks(ds, "vehicle", n, length, seed, on_streets=True).positions
    step = np.diff(centre, axis=1)
    step = np.concatenate([step[:, :1], step], axis=1)  # the first sample heads as the first step
    moving = np.linalg.norm(step, axis=-1) > 1e-6
    # each sample's direction: its last move's, before the first move that first move's
    last = np.maximum.accumulate(np.where(moving, np.arange(length), -1), axis=1)
    src = np.where(last >= 0, last, np.argmax(moving, axis=1)[:, None])
    d = np.take_along_axis(step, src[..., None], axis=1)
    heading = np.arctan2(d[..., 1], d[..., 0])
    offset = np.random.default_rng(seed).uniform(1.0, 2.5, n)[:, None]
    right = np.stack([np.sin(heading), -np.cos(heading)], -1)
    out = centre.copy()
    valid = np.asarray(ds.valid)
    for share in (0.0, 1 / 3, 2 / 3, 1.0):  # where the street is narrower, the lane is nearer the centre
        pos = centre + (share * offset)[..., None] * right
        out = np.where(valid[ds.nearest(pos)][..., None], pos, out)
    return out


def shifted_walks(ds, n: int, length: int, seed: int, mean_speed: float, kind: str = "vehicle"):
    """Trajectories (positions ``(n, length, 2)``) of our own users of ``kind`` (vehicles on the
    street network) with the mean speed ``mean_speed`` m/s (and the maximum moved by as much): our
    habits at other speeds."""
    from mmwsim.trajectories import motion_model

    base = motion_model(kind)
    habits = dict(mean_speed=mean_speed, max_speed=base.max_speed + mean_speed - base.mean_speed)
    return _habit_walks(ds, kind, n, length, seed, on_streets=True, habits=habits)


def draw_sets(ds, fs, n: int, length: int, seed: int, shifted: dict[str, list[float]]):
    """Every foreign set, ``n`` users per kind of ``length`` steps: ``{set: {kind: positions (n,
    length, 2)}}`` and ``{(set, kind): attrs}`` of those our generator made."""
    rng = np.random.default_rng(seed)
    sets: dict[str, dict[str, np.ndarray]] = {"smooth": {}, "events": {}}
    made = {}  # (set, kind) -> how our generator made it: the oracle of that generator reads it
    for k in KINDS:
        sets["smooth"][k] = smooth_walks(fs, k, n, length, rng)
        t = event_walks(ds, k, n, length, seed + 1)
        sets["events"][k], made["events", k] = t.positions, t.attrs
    sets["lanes"] = {"vehicle": lane_walks(ds, n, length, seed + 2)}
    for kind, speeds in shifted.items():
        for v in speeds:
            t = shifted_walks(ds, n, length, seed + 3, v, kind)
            sets.setdefault(f"own at {v:g} m/s", {})[kind] = t.positions
            made[f"own at {v:g} m/s", kind] = t.attrs
    return sets, made


def load_model(args, ds):
    """The run as the options ask, attached to ``ds`` at the benchmark's noise."""
    from estimation import Estimator

    est = Estimator.load(args.run).attach(ds, sigma=args.noise)
    est.robust_motion = not args.measured_motion_only
    est.street_lanes = not args.measured_lanes
    est.route_tracking = not args.no_routes
    return est


def adapted_models(args, ds, shifted, validation, fs) -> dict:
    """``{set: Estimator}``: the model with its motion tables measured on its own tracks of
    ``args.adapt`` fresh unlabelled users per kind of that set's generator
    (:meth:`Estimator.adapt_motion`); for our own test users, on the validation split's."""

    pool, _ = draw_sets(ds, fs, args.adapt, args.adapt_length, args.seed + 1000, shifted)
    ours = validation.positions[: args.adapt * len(KINDS), : args.adapt_length].astype(np.float64)
    pool["own test/seen"] = {"all": ours}
    out = {}
    for gen, per_kind in pool.items():
        pos = np.concatenate(list(per_kind.values()))
        b, _ = stored_bits(ds, pos, args.seed + 1007)
        est = load_model(args, ds)
        t0 = time.perf_counter()
        out[gen] = est.adapt_motion(b)
        print(
            f"  adapted to {gen}: {len(pos)} unlabelled users of {pos.shape[1]} steps, "
            f"{time.perf_counter() - t0:.0f} s",
            flush=True,
        )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="training run folder (or model.pt)")
    ap.add_argument("dataset", help="the data set it was trained on (zarr)")
    ap.add_argument("methods", nargs="*", help="classical trackers to compare (match-cv, knn-kalman)")
    ap.add_argument("--n", type=int, default=1000, help="trajectories per kind and generator (default 1000)")
    ap.add_argument("--length", type=int, default=7)
    ap.add_argument("--noise", type=float, default=6.0, help="dB (default 6)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--measured-motion-only",
        action="store_true",
        help="without the broadened alternative motion (Estimator.robust_motion = False)",
    )
    ap.add_argument(
        "--measured-lanes",
        action="store_true",
        help="lanes measured on the training trajectories, not the street map (Estimator.street_lanes = False)",
    )
    ap.add_argument(
        "--no-routes",
        action="store_true",
        help="drivers on the street map not smoothed along their routes (Estimator.route_tracking = False)",
    )
    for kind, example in SHIFTED.items():
        ap.add_argument(
            f"--{kind}-speeds",
            default="",
            metavar="S1,S2",
            help=f"add our own {kind}s at these mean speeds, m/s (e.g. {example})",
        )
    ap.add_argument(
        "--oracle",
        action="store_true",
        help="print the floor of every set our generator made (events, own at other speeds, own test/seen)",
    )
    ap.add_argument(
        "--speed-spread",
        type=float,
        metavar="S",
        help="with --oracle, also the oracle of each set reading its users' speeds within +-S (particles x4)",
    )
    ap.add_argument(
        "--adapt",
        type=int,
        default=0,
        metavar="N",
        help="also the model adapted to each generator: its motion tables measured on its own tracks of N "
        "fresh unlabelled users per kind (Estimator.adapt_motion; our own test users: the validation split's)",
    )
    ap.add_argument("--adapt-length", type=int, default=15, help="steps of the --adapt users (default 15)")
    args = ap.parse_args(argv)
    if args.adapt < 0 or args.adapt_length < 3:
        ap.error("--adapt must be >= 0 and --adapt-length >= 3")
    if args.speed_spread is not None and not args.oracle:
        ap.error("--speed-spread needs --oracle")
    shifted = {}  # kind -> mean speeds, m/s
    for kind, example in SHIFTED.items():
        given = getattr(args, f"{kind}_speeds")
        try:
            shifted[kind] = [float(v) for v in given.split(",") if v.strip()]
        except ValueError:
            ap.error(f"--{kind}-speeds {given!r}: give mean speeds in m/s, e.g. {example}")
        if not all(math.isfinite(v) and v > 0 for v in shifted[kind]):
            ap.error(f"--{kind}-speeds {given!r}: speeds must be positive numbers")

    from estimation import EstimationError, method
    from estimation.adapter import load_splits
    from estimation.metrics import trajectory_rmse
    from mmwsim import Dataset, FreeSpace
    from mmwsim.errors import MmwsimError
    from mmwsim.geometry.freespace import CoverageMask

    ds = Dataset.open(args.dataset)
    est = load_model(args, ds)
    fs = FreeSpace.from_scene(
        ds.scene(), clearance=0.5, coverage=CoverageMask.from_dataset(ds), bounds=ds.grid.bounds
    )
    try:
        sets, made = draw_sets(ds, fs, args.n, args.length, args.seed, shifted)
    except MmwsimError as e:  # a speed the generator's model cannot keep
        ap.error(f"--KIND-speeds: {e}")
    own, _ = load_splits(args.dataset, ("validation", "test/seen"), dataset=ds)
    seen = own["test/seen"]
    kinds = np.asarray(["static", "pedestrian", "hybrid", "vehicle"])[seen.kind]
    sets["own test/seen"] = {
        k: seen.positions[kinds == k][: args.n, : args.length].astype(np.float64) for k in KINDS
    }
    floors = {}  # (set, kind) -> the oracle of the generator that made it
    readers = {}  # (set, kind) -> that oracle reading the users' speeds (--speed-spread)
    if args.oracle:
        from estimation import Oracle, OracleMethod

        ours = OracleMethod(Oracle.from_dataset(ds)).for_sigma(args.noise, own["validation"])
        for k in KINDS:  # our own test users: the data set's generator, every kind in its proportions
            floors["own test/seen", k] = ours
        for key, attrs in made.items():
            floors[key] = OracleMethod(Oracle.from_trajectories(ds, attrs))
            floors[key].matcher = ours.matcher  # the same likelihood: built once
        if args.speed_spread is not None:
            for key, floor in floors.items():
                try:
                    oracle = floor.oracle.with_particle_factor(4).with_speed_spread(args.speed_spread)
                except EstimationError as e:
                    ap.error(str(e))
                readers[key] = OracleMethod(oracle)
                readers[key].matcher, readers[key].name = ours.matcher, "reading speeds"

    others = [method(name).for_sigma(args.noise, own["validation"]) for name in args.methods]
    adapted = adapted_models(args, ds, shifted, own["validation"], fs) if args.adapt else {}

    print(
        f"{args.run}: {args.length} steps, {args.noise:g} dB, mean per-trajectory RMSE in metres (median, p95)"
    )
    for gen, per_kind in sets.items():
        for k, pos in per_kind.items():
            b, idx = stored_bits(ds, pos, args.seed + 7)
            t0 = time.perf_counter()
            pred = predict_batched(est, b)
            r = trajectory_rmse(pred, pos)
            cell = trajectory_rmse(ds.positions[idx][:, :2].reshape(pos.shape), pos)
            line = (
                f"  {gen:14s} {k:10s} {est.name}: {r.mean():.2f} ({np.median(r):.2f}, {np.quantile(r, 0.95):.2f})"
                f"  [{time.perf_counter() - t0:.0f} s]  cell {cell.mean():.2f}"
            )
            if gen in adapted:
                ra = trajectory_rmse(predict_batched(adapted[gen], b), pos)
                line += f"  adapted: {ra.mean():.2f} ({np.median(ra):.2f}, {np.quantile(ra, 0.95):.2f})"
            for m in others + [f[gen, k] for f in (floors, readers) if (gen, k) in f]:
                p2 = m.predict_lengths(b.bool(), [args.length])[args.length][0]
                r2 = trajectory_rmse(p2, pos)
                line += f"  {m.name}: {r2.mean():.2f} ({np.median(r2):.2f})"
                if m is floors.get((gen, k)):
                    line += f" -> {est.name} {r.mean() / r2.mean():.2f}x the floor"
                elif m is readers.get((gen, k)):
                    line += f" -> {est.name} {r.mean() / r2.mean():.2f}x it"
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
