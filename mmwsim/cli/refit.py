"""``mmwsim refit RUN --out NEW [--dataset DATASET] [--split SPLIT]``: a trained ``tn-match`` with its
motion tables measured again on other trajectories."""

from __future__ import annotations

import argparse

EPILOG = """\
tn-match's smoothers track with motion tables measured on the training trajectories. This measures
them again on the trajectories of SPLIT (default train) of DATASET (default the data set RUN was
trained on; it must be the same data set, with the same grid), keeps the network, and writes the
run folder NEW (RUN stays as it is). Give it trajectories of your own users, e.g. made with
`mmwsim trajectories DATASET --set pedestrian.mean_speed=0.8 ...`, to track users who move as they
do; or the same data set, to give a run saved by an older version the tables added since.
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
    p.set_defaults(func=_refit)


def _refit(args) -> int:
    from estimation import EstimationError, read_run_info, refit_motion
    from estimation.adapter import load_sets

    info = read_run_info(args.run)
    dataset = args.dataset or info["data"].get("dataset")
    if not dataset:
        raise EstimationError(f"{args.run}: its run.json names no data set; give --dataset")
    sets, data_info = load_sets(dataset, (args.split,))
    motion = refit_motion(
        args.run,
        sets[args.split],
        args.out,
        {"dataset": data_info["dataset"], "content_hash": data_info["content_hash"], "split": args.split},
    )
    print(
        f"measured the motion tables of {args.run} on {motion['trajectories']} trajectories of "
        f"{motion['dataset']} ({args.split}) in {motion['seconds']:.1f} s; wrote {args.out}"
    )
    return 0
