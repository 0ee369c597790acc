"""Training time to early stop and inference throughput per model, on 2 CPU threads.

    python benchmarks/train_models.py                       # synthetic set shaped like the real one
    python benchmarks/train_models.py --dataset data.zarr   # a real data set with trajectories
    python benchmarks/train_models.py --models tn lstm --max-epochs 20

Prints one line per model: parameters, epochs until early stop, training seconds, best validation
RMSE, and inference throughput (7-step sequences per second, batch 512). Timings are noisy on a
shared machine.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import torch

from estimation import MODELS, Estimator, TrainConfig, train
from estimation.adapter import load_sets
from estimation.noise import noisy_bits
from estimation.synthetic import toy_sequence_set


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", help="data set with trajectories (default: synthetic 32 x 81 fingerprints)")
    ap.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    ap.add_argument("--n-train", type=int, default=4000, help="synthetic training trajectories")
    ap.add_argument("--max-epochs", type=int, default=40)
    ap.add_argument("--patience", type=int, default=4)
    ap.add_argument("--epoch-size", type=int, default=0, help="trajectories per epoch (default 0 = all)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    if args.dataset:
        sets, _ = load_sets(args.dataset, ("train", "validation"))
        tr, va = sets["train"], sets["validation"]
    else:
        shape = dict(length=7, nx=64, ny=64, n_beams=32, n_bins=81, grid_seed=0)
        tr = toy_sequence_set(args.n_train, seed=1, **shape)
        va = toy_sequence_set(max(args.n_train // 5, 64), seed=2, **shape)
    print(
        f"{tr.n} training / {va.n} validation trajectories of {tr.length} steps, "
        f"fingerprints {tr.n_beams} x {tr.n_bins}, {args.threads} threads"
    )
    bits = noisy_bits(va.crop(0, min(7, va.length)), 6.0, torch.Generator().manual_seed(0)).float()
    reps = max(1, 2048 // len(bits))
    print(
        f"{'model':8s} {'params':>8s} {'epochs':>6s} {'train s':>8s} {'s/epoch':>8s} {'val RMSE m':>10s} "
        f"{'infer seq/s':>11s}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for m in args.models:
            cfg = TrainConfig(
                model=m, epochs=args.max_epochs, patience=args.patience, epoch_size=args.epoch_size
            )
            s = train(tr, va, cfg, f"{tmp}/{m}", progress=False, record=False, log=lambda *a: None)
            est = Estimator.load(f"{tmp}/{m}").attach(va)
            est.predict(bits[:64])
            t0 = time.perf_counter()
            for _ in range(reps):
                for k in range(0, len(bits), 512):
                    est.predict(bits[k : k + 512])
            rate = reps * len(bits) / (time.perf_counter() - t0)
            print(
                f"{m:8s} {s['parameters']:8d} {s['epochs']:6d} {s['train_seconds']:8.1f} "
                f"{s['train_seconds'] / max(s['epochs'], 1):8.2f} {s['best_val_rmse']:10.2f} {rate:11.0f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
