"""``mmwsim train DATASET --model tn|lstm|gru|rnn|tcn|conv1d --out RUN``: train a trajectory estimator."""

from __future__ import annotations

import argparse

from estimation.names import LOSSES, MODEL_NAMES, SCHEDULES, TASKS

from ..constants import SIGMA_DB

EPILOG = """\
The run folder RUN receives run.json (settings and data description), checkpoint.pt (after every
epoch), model.pt (best weights by validation loss) and training.rrd (training curves on the epoch
timeline). A killed run continues with --resume and ends with the same weights as an uninterrupted
one. DATASET is a data set holding trajectories (mmwsim generate + mmwsim trajectories), or
toy[:n=N,length=L,seed=S] for a small synthetic one.
"""


def register(sub) -> None:
    p = sub.add_parser(
        "train",
        help=f"train a trajectory-estimation network ({', '.join(MODEL_NAMES)})",
        description=__doc__,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("dataset", help="data set (zarr store with trajectories) or toy[:n=N,length=L,seed=S]")
    p.add_argument("--model", required=True, choices=MODEL_NAMES, help="network to train")
    p.add_argument("--out", required=True, help="run folder to write")
    p.add_argument(
        "--epochs",
        type=int,
        help="maximum epochs, warm-up included (default: the model's own, 200 for the sequence networks, 100 for tn-match; early "
        "stopping may end sooner)",
    )
    p.add_argument("--resume", action="store_true", help="continue from RUN/checkpoint.pt")
    p.add_argument(
        "--seed", type=int, default=0, help="seed of initialisation, order, crops and noise (default 0)"
    )
    p.add_argument("--task", choices=TASKS, default="tracking")
    p.add_argument("--sigma", type=float, default=SIGMA_DB, help=f"training noise, dB (default {SIGMA_DB:g})")
    p.add_argument("--min-length", type=int, default=2, help="tracking: shortest training crop (default 2)")
    p.add_argument(
        "--max-length",
        type=int,
        default=0,
        help="tracking: longest training crop (default 0 = trajectory length)",
    )
    p.add_argument("--t-obs", type=int, default=5, help="forecasting: observed steps (default 5)")
    p.add_argument("--horizon", type=int, default=2, help="forecasting: predicted steps (default 2)")
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument(
        "--lr", type=float, help="learning rate (default: 3e-4 for the sequence networks, 1e-3 for tn-match)"
    )
    p.add_argument("--warmup-lr", type=float, help="learning rate of the warm-up epochs (default 3e-3)")
    p.add_argument(
        "--schedule",
        choices=SCHEDULES,
        help="learning rate: plateau (halved after 3 epochs without improvement) or cosine "
        "(each phase down to zero by its last epoch); default cosine for the sequence networks, plateau for tn-match",
    )
    p.add_argument("--patience", type=int, default=8, help="early-stopping patience, epochs (default 8)")
    p.add_argument(
        "--min-delta",
        type=float,
        help="relative fall of the validation loss that counts as an improvement (default: 0 for the "
        "sequence networks, 1e-3 for tn-match)",
    )
    p.add_argument(
        "--epoch-size",
        type=int,
        default=0,
        help="trajectories per epoch, a fresh random subset each epoch (default 0 = all)",
    )
    p.add_argument(
        "--warmup-epochs",
        type=int,
        help="tracking: epochs of single fingerprints (every step of the epoch's trajectories on its "
        "own) before sequences (default: the model's own, 24 of 200 for the sequence networks, "
        "0 for tn-match)",
    )
    p.add_argument(
        "--loss",
        choices=LOSSES,
        help="mse (the paper's), rmse (mean per-trajectory RMSE) or cells (a cell head's own); "
        "default rmse for tn-match, else cells",
    )
    p.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="network constructor option, e.g. d=64 (repeatable)",
    )
    p.add_argument(
        "--time-limit", type=float, metavar="MIN", help="start no new epoch after MIN minutes (resumable)"
    )
    p.add_argument("--train-split", default="train")
    p.add_argument("--val-split", default="validation")
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch intra-op threads (default 1: batches with fresh noise are drawn on a second core "
        "meanwhile, which for these small models beats two threads per operation)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_train)


def _option(text: str) -> tuple[str, object]:
    from ..errors import MmwsimError

    key, sep, value = text.partition("=")
    if not sep or not key:
        raise MmwsimError(f"--option {text!r}: expected KEY=VALUE")
    for cast in (int, float):
        try:
            number = cast(value)
        except ValueError:
            continue
        if number != number or number in (float("inf"), float("-inf")):
            raise MmwsimError(f"--option {text!r}: {value!r} is not a finite number")
        return key, number
    return key, value


def _train(args) -> int:
    import math

    import torch

    from ..errors import MmwsimError
    from . import check_threads

    if args.time_limit is not None and not (math.isfinite(args.time_limit) and args.time_limit >= 0):
        raise MmwsimError(f"--time-limit must be a finite number of minutes >= 0, got {args.time_limit}")

    from estimation import EstimationError, TrainConfig, build_network, train
    from estimation.adapter import load_sets

    torch.set_num_threads(check_threads(args.threads))
    cfg = TrainConfig(
        model=args.model,
        task=args.task,
        sigma=args.sigma,
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        patience=args.patience,
        min_delta=args.min_delta,
        min_length=args.min_length,
        max_length=args.max_length,
        t_obs=args.t_obs,
        horizon=args.horizon,
        seed=args.seed,
        epoch_size=args.epoch_size,
        warmup_epochs=args.warmup_epochs,
        warmup_lr=args.warmup_lr,
        schedule=args.schedule,
        loss=args.loss,
        options=dict(_option(o) for o in args.option),
    )
    try:  # reject a bad --option before reading the data
        build_network(cfg.model, 2, 2, cfg.task, cfg.horizon, cfg.dropout, **cfg.options)
    except (TypeError, ValueError, RuntimeError) as e:  # torch refuses bad sizes with RuntimeError
        raise EstimationError(f"--option: {' '.join(str(e).split())[:200]}") from None
    sets, info = load_sets(args.dataset, (args.train_split, args.val_split))
    info["train_split"], info["val_split"] = args.train_split, args.val_split
    summary = train(
        sets[args.train_split],
        sets[args.val_split],
        cfg,
        args.out,
        resume=args.resume,
        data_info=info,
        progress=not args.quiet,
        log=lambda text: print(text, flush=True),
        time_limit=None if args.time_limit is None else 60.0 * args.time_limit,
    )
    print(
        f"{args.model}: {summary['epochs']} epochs, best validation RMSE {summary['best_val_rmse']:.2f} m "
        f"at epoch {summary['best_epoch']}, {summary['parameters']} parameters, "
        f"{summary['train_seconds']:.0f} s; wrote {args.out}"
    )
    return 0
