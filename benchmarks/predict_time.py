"""Prediction time of a training run on the seen-area test set: seconds per 1000 sequences and the
mean per-trajectory RMSE.

Usage: python benchmarks/predict_time.py RUN DATASET [--max 1000] [--sigma 6] [--steps 7]
[--threads 1] [--repeat 3]

One ``Estimator.predict`` call over all the drawn sequences (7 steps, 6 dB by default), after a
warm-up call on every 20th of them (kernels compiled or loaded from numba's cache, torch warmed
up); the least of ``--repeat`` timings is printed. To compare two versions, run this from each
checkout in turn (``PYTHONPATH=OTHER_CHECKOUT python benchmarks/predict_time.py ...``), alternated,
so that a machine that slows down weighs on both alike.
"""

from __future__ import annotations

import time

import numpy as np
import torch
from _common import run_dataset_parser, test_draws


def main() -> None:
    import estimation
    from estimation import Estimator, summarise_by_kind, trajectory_rmse
    from estimation.adapter import load_splits

    ap = run_dataset_parser(__doc__)
    ap.add_argument("--steps", type=int, default=7)
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1, the protocol's)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)  # the compiled kernels keep their threads, as in paper_table.py
    sets, _ = load_splits(args.dataset, ("validation", "test/seen"))
    est = Estimator.load(args.run).attach(sets["validation"], args.sigma)
    data, bits = test_draws(sets["test/seen"], args.max, args.sigma, args.steps)
    est.predict(bits[::20])
    seconds = []
    for _ in range(max(args.repeat, 1)):
        t = time.perf_counter()
        pred = est.predict(bits)
        seconds.append(time.perf_counter() - t)
    s = summarise_by_kind(trajectory_rmse(np.asarray(pred, np.float64), data.positions), data.kind)
    per = 1000.0 / data.n
    print(
        f"{est.name} from {estimation.__file__}, {data.n} seen-area sequences, {args.steps} steps, {args.sigma:g} dB, {args.threads} torch thread(s)"
    )
    print(
        f"prediction {min(seconds) * per:.2f} s per 1000 (least of {len(seconds)}:"
        f" {', '.join(f'{x * per:.2f}' for x in seconds)}); mean RMSE vehicle {s['vehicle']['mean']:.4f}"
        f" / pedestrian {s['pedestrian']['mean']:.4f} / all {s['all']['mean']:.4f} m"
    )


if __name__ == "__main__":
    main()
