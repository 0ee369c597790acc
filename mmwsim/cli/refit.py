"""``mmwsim refit RUN --out NEW [--dataset DATASET] [--split SPLIT] [--unlabelled]``: a trained
``tn-match`` with its motion tables measured again on other trajectories."""

from __future__ import annotations

import argparse

from ..constants import SIGMA_DB

EPILOG = """\
tn-match's smoothers track with motion tables measured on the training trajectories. This measures
them again on the trajectories of SPLIT (default train) of DATASET (default the data set RUN was
trained on; it must be the same data set, with the same grid), keeps the network, and writes the
run folder NEW (RUN stays as it is). Give it trajectories of your own users, e.g. made with
`mmwsim trajectories DATASET --set pedestrian.mean_speed=0.8 ...`, to track users who move as they
do; or the same data set, to give a run saved by an older version the tables added since.
With --unlabelled RUN is adapted to fingerprints drawn along those trajectories instead: tables
measured on its own tracks of them, weighed beside the measured tables (which stay) by each
user's evidence. That is what a deployment that has its users' fingerprint sequences but not
their positions can do.
"""


def register(sub) -> None:
    p = sub.add_parser(
        "refit",
        help="measure a trained tn-match's motion tables again on a data set's trajectories",
        description=__doc__,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("run", help="tn-match run folder (mmwsim train)")
    p.add_argument("--out", required=True, help="run folder to write (missing or empty)")
    p.add_argument("--dataset", help="data set holding the trajectories (default: the run's)")
    p.add_argument("--split", default="train", help="trajectory split to measure on (default train)")
    p.add_argument(
        "--unlabelled",
        action="store_true",
        help="adapt RUN to fingerprints drawn along the trajectories (with --noise) instead: tables "
        "measured on its own tracks of them, beside the measured ones; the positions only make the fingerprints",
    )
    p.add_argument(
        "--noise",
        type=float,
        default=SIGMA_DB,
        help=f"--unlabelled: fingerprint noise, dB (default {SIGMA_DB:g})",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the --unlabelled noise and of the --max-trajectories subset (default 0)",
    )
    p.add_argument(
        "--max-trajectories",
        type=int,
        default=0,
        metavar="N",
        help="at most N trajectories of the split, a seeded subset (default 0 = all; --unlabelled tracks "
        "each, about 30 ms per 15-step trajectory)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar (--unlabelled's tracking)")
    p.set_defaults(func=_refit)


def _refit(args) -> int:
    import math

    import numpy as np

    from estimation import EstimationError, read_run_info, refit_motion
    from estimation.adapter import load_sets

    if not (math.isfinite(args.noise) and args.noise >= 0):
        raise EstimationError(f"--noise must be a finite number of dB >= 0, got {args.noise}")
    if args.max_trajectories < 0:
        raise EstimationError(f"--max-trajectories must be >= 0, got {args.max_trajectories}")
    info = read_run_info(args.run)
    dataset = args.dataset or info["data"].get("dataset")
    if not dataset:
        raise EstimationError(f"{args.run}: its run.json names no data set; give --dataset")
    sets, data_info = load_sets(dataset, (args.split,))
    data = sets[args.split]
    if 0 < args.max_trajectories < data.n:
        rows = np.random.default_rng(args.seed).choice(data.n, args.max_trajectories, replace=False)
        data = data.subset(np.sort(rows))
    motion = refit_motion(
        args.run,
        data,
        args.out,
        {"dataset": data_info["dataset"], "content_hash": data_info["content_hash"], "split": args.split},
        unlabelled_noise=args.noise if args.unlabelled else None,
        seed=args.seed,
        progress=not args.quiet,
    )
    if args.unlabelled:
        done = f"adapted {args.run} to its own tracks of {args.noise:g} dB fingerprints along"
    else:
        done = f"measured the motion tables of {args.run} on the positions of"
    print(
        f"{done} {motion['trajectories']} trajectories of {motion['dataset']} ({args.split}) in "
        f"{motion['seconds']:.1f} s; wrote {args.out}"
    )
    return 0
