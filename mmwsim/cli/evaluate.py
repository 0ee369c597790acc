"""``mmwsim evaluate RUN... [--noise 6 9] [--rrd FILE]``: accuracy tables, plots and recordings."""

from __future__ import annotations

import argparse

from estimation.names import CLASSICAL_NAMES, TASKS

from ..constants import SIGMA_DB

EPILOG = """\
Each RUN is a folder written by `mmwsim train`, or the name of a classical tracker that needs no
training: knn-kalman (the paper's baseline: nearest-fingerprint matching on the data-set grid plus a
constant-velocity Kalman smoother, fitted per noise level on the validation split) or match-cv (the
most likely grid points of every step smoothed by a hidden-Markov constant-velocity model: tn-match
before training), or oracle: the floor, a particle smoother that knows the generator's motion model
and the exact fingerprint likelihood (needs a data set with generated trajectories; its row comes
first). The data set is the one the first run was trained on unless --dataset is given (required
when only classical trackers are named).

Examples:
  mmwsim evaluate runs/tn runs/lstm knn-kalman --noise 6 9 --out report --rrd report/trajectories.rrd
  mmwsim evaluate knn-kalman match-cv --dataset data.zarr
  mmwsim evaluate runs/tn-match oracle --noise 6 --max-trajectories 500

By default the test split is evaluated as test/seen (trajectories outside the spatial hold-out
region) and test/holdout (those touching it); empty parts are skipped. Writes into --out:
accuracy.md (mean RMSE per kind and noise, 95th percentile, for --table-length steps), cost.md
(parameters, training and prediction time), error_vs_length_<split>_<noise>dB.png and results.json.
"""


def register(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="evaluate trained runs and the classical trackers",
        description=__doc__,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "runs", nargs="+", metavar="RUN", help=f"run folder, or one of {', '.join(CLASSICAL_NAMES)}"
    )
    p.add_argument("--dataset", help="data set (or toy spec) to evaluate on (default: the first run's)")
    p.add_argument(
        "--noise",
        type=float,
        nargs="+",
        default=[SIGMA_DB, 9.0],
        help=f"noise levels, dB (default {SIGMA_DB:g} 9)",
    )
    p.add_argument(
        "--split",
        nargs="+",
        default=["test/seen", "test/holdout"],
        help="splits to evaluate (SPLIT, SPLIT/seen, SPLIT/holdout; default test/seen test/holdout)",
    )
    p.add_argument("--val-split", default="validation", help="split the knn-kalman baseline is fitted on")
    p.add_argument("--lengths", type=int, nargs="+", help="tracking sequence lengths (default 2..L)")
    p.add_argument(
        "--table-length", type=int, default=7, help="sequence length of the accuracy table (default 7)"
    )
    p.add_argument(
        "--max-trajectories",
        type=int,
        default=2000,
        help="at most this many trajectories per split (seeded subset; default 2000, 0 = all)",
    )
    p.add_argument(
        "--task",
        choices=TASKS,
        default="tracking",
        help="task of the classical trackers knn-kalman and oracle (networks use their own; default tracking)",
    )
    p.add_argument("--t-obs", type=int, default=5, help="knn-kalman and oracle forecasting: observed steps")
    p.add_argument(
        "--horizon", type=int, default=2, help="knn-kalman and oracle forecasting: predicted steps"
    )
    p.add_argument("--out", default="evaluation", help="report folder (default ./evaluation)")
    p.add_argument("--rrd", help="write predicted vs true trajectories to this .rrd")
    p.add_argument("--seed", type=int, default=0, help="seed of the evaluation noise (default 0)")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    p.add_argument("--quiet", action="store_true", help="no progress bar (shown only on a terminal)")
    p.set_defaults(func=_evaluate)


def _evaluate(args) -> int:
    import math
    from pathlib import Path

    import torch

    from estimation import EstimationError

    from ..files import RECORDING_SUFFIX, check_output_folder, check_suffix
    from ..locks import locked_output
    from . import check_threads

    torch.set_num_threads(check_threads(args.threads))
    if not all(math.isfinite(n) and n >= 0 for n in args.noise):
        raise EstimationError(
            f"--noise {' '.join(map(str, args.noise))}: noise levels must be finite and >= 0 dB"
        )
    if args.lengths and min(args.lengths) < 1:
        raise EstimationError(f"--lengths {' '.join(map(str, args.lengths))}: sequence lengths must be >= 1")
    if args.table_length < 1 or args.max_trajectories < 0 or args.t_obs < 1 or args.horizon < 1:
        raise EstimationError("--table-length, --t-obs and --horizon must be >= 1, --max-trajectories >= 0")
    if args.rrd:
        check_suffix(args.rrd, RECORDING_SUFFIX, "--rrd")
        if Path(args.rrd).parent != Path(args.out):  # the report folder is made later
            check_output_folder(args.rrd, "--rrd")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise EstimationError(f"--out {out}: exists and is not a folder")
    with locked_output(out, "report folder"):  # a second evaluation into it is refused now
        return _run(args, out)


def _run(args, out) -> int:
    from pathlib import Path

    from estimation import EstimationError, NetworkMethod, evaluate, method, record_estimates, write_report
    from estimation.adapter import load_sets, scene_footprints

    classical = dict(
        task=args.task, t_obs=args.t_obs, horizon=args.horizon, fit_length=args.table_length, seed=args.seed
    )
    methods = [method(run, **classical) for run in args.runs]
    dataset = args.dataset or next((m.dataset for m in methods if getattr(m, "dataset", None)), None)
    if not dataset:
        raise EstimationError("no data set: give --dataset (needed when only classical trackers are named)")
    names = tuple(dict.fromkeys([*args.split, args.val_split]))
    for m in methods:
        if hasattr(m, "use_dataset"):  # the oracle knows the data set's generator
            m.use_dataset(dataset)
    sets, _ = load_sets(dataset, names)
    first = next(iter(sets.values()))
    for m in methods:
        if isinstance(m, NetworkMethod) and (m.est.n_beams, m.est.n_bins) != (first.n_beams, first.n_bins):
            raise EstimationError(
                f"{m.name}: trained on {m.est.n_beams} x {m.est.n_bins} fingerprints, "
                f"{dataset} has {first.n_beams} x {first.n_bins}"
            )
    test = {k: sets[k] for k in args.split}
    ev = evaluate(
        methods,
        test,
        list(args.noise),
        sets[args.val_split],
        lengths=args.lengths,
        table_length=args.table_length,
        max_trajectories=args.max_trajectories or None,
        seed=args.seed,
        progress=not args.quiet,
    )
    written = write_report(ev, out, list(args.noise))
    if args.rrd:
        record_estimates(ev, args.rrd, footprints=scene_footprints(dataset))
        written.append(Path(args.rrd))
    print((out / "accuracy.md").read_text())
    print((out / "cost.md").read_text())
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
