"""Memory and time of one ``Estimator.predict`` call on a whole test set, as a library user makes it.

    python benchmarks/predict_memory.py RUN DATASET [--n 4000] [--length 15] [--sigma 6]

The first ``--n`` test trajectories of ``DATASET`` (all kinds, both regions), cropped to
``--length`` steps, their fingerprints drawn from the stored PDPs with fresh noise
(``Dataset.fingerprints``) as uint8, then one ``predict`` call over all of them. Prints the peak
resident memory before the call (the data set, the model and the bits) and after it, the growth
the call caused, and its wall time. Peak resident memory only grows within a process, so run
one call per process.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time

import numpy as np
from _common import stored_bits


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # kB on Linux


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="training run folder (or model.pt)")
    ap.add_argument("dataset", help="the data set (zarr) with its test trajectories")
    ap.add_argument("--n", type=int, default=4000, help="test trajectories (default 4000)")
    ap.add_argument("--length", type=int, default=15, help="steps per sequence (default 15)")
    ap.add_argument("--sigma", type=float, default=6.0, help="fingerprint noise, dB (default 6)")
    args = ap.parse_args(argv)
    if args.n < 1 or args.length < 1:
        ap.error("--n and --length must be >= 1")

    import torch

    from estimation import Estimator
    from mmwsim import Dataset, read_trajectories
    from mmwsim.errors import MmwsimError

    try:
        ds = Dataset.open(args.dataset)
        est = Estimator.load(args.run).attach(ds, sigma=args.sigma)
        test = read_trajectories(ds, "test")
    except MmwsimError as e:
        ap.error(str(e))
    length = min(args.length, test.length)
    pos = test.positions[: args.n, :length, :2].astype(np.float64)
    bits, _ = stored_bits(ds, pos, seed=3)
    bits = bits.to(torch.uint8)
    before = _peak_gb()
    t0 = time.perf_counter()
    out = est.predict(bits)
    seconds = time.perf_counter() - t0
    after = _peak_gb()
    print(
        f"{est.name}: predict of {len(pos)} sequences x {length} steps in one call: peak resident "
        f"memory {before:.2f} GB before, {after:.2f} GB after (+{after - before:.2f} GB), {seconds:.1f} s"
    )
    assert out.shape[0] == len(pos)
    return 0


if __name__ == "__main__":
    sys.exit(main())
