"""What tn-match's training adds over its own untrained smoother, with confidence intervals.

Usage: python benchmarks/tn_match_learned.py RUN DATASET [--length 7] [--max 1000] [--sigma 6]

Untrained, ``tn-match`` with the run's motion tables is exactly the sub-cell smoother (the learned
weights start at zero). Both track the same test trajectories from the same noisy fingerprints;
per split (seen area, held-out region) the script prints their mean per-trajectory RMSE and the
mean paired difference (trained minus untrained) with a 95 % bootstrap interval over trajectories.
"""

from __future__ import annotations

import numpy as np
import torch
from _common import run_dataset_parser, test_draws


def main() -> None:
    from estimation import Estimator, trajectory_rmse
    from estimation.adapter import load_splits

    ap = run_dataset_parser(__doc__)
    ap.add_argument("--length", type=int, default=7)
    args = ap.parse_args()
    torch.set_num_threads(2)

    trained = Estimator.load(args.run)
    if trained.name != "tn-match" or trained.config.task != "tracking":
        raise SystemExit(f"{args.run}: not a tn-match tracking run")
    untrained = Estimator(trained.config, trained.n_beams, trained.n_bins, trained.normaliser)
    for name in ("motion", "motion_fine"):  # the measured tables, not the learned weights
        getattr(untrained.net, name).load_state_dict(getattr(trained.net, name).state_dict())
    untrained.net.grid_step.copy_(trained.net.grid_step)
    splits = ("validation", "test/seen", "test/holdout")
    sets, _ = load_splits(args.dataset, splits)
    for est in (trained, untrained):
        est.attach(sets["validation"], args.sigma)
    print(f"{args.run}: {args.length}-step tracks, {args.sigma:g} dB")
    for split in splits[1:]:
        data, bits = test_draws(sets[split], args.max, args.sigma, args.length)
        err = {}
        for label, est in (("trained", trained), ("untrained", untrained)):
            pred = torch.cat([est.predict(est.inputs(bits[a : a + 256])) for a in range(0, data.n, 256)])
            err[label] = trajectory_rmse(pred.numpy(), data.positions)
        diff = err["trained"] - err["untrained"]
        boot = np.random.default_rng(2).integers(0, len(diff), (2000, len(diff)))
        lo, hi = np.percentile(diff[boot].mean(1), [2.5, 97.5])
        print(
            f"  {split}: {data.n} trajectories, trained {err['trained'].mean():.3f} m, untrained "
            f"{err['untrained'].mean():.3f} m, difference {diff.mean():+.3f} m (95 % {lo:+.3f} .. {hi:+.3f})"
        )


if __name__ == "__main__":
    main()
