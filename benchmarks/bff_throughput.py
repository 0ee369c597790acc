"""Fingerprints per second: the sparse Bernoulli sampler vs literal float32 Gaussian noise.

Usage: python benchmarks/bff_throughput.py [--dataset STORE] [--spacing M] [--n N]

Without --dataset, traces the default scene at --spacing (8 m: about 1,200 outdoor
receivers) for realistic PDPs. Prints fingerprints per second (32 x 81 bits each).
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def traced_pdps(spacing: float) -> np.ndarray:
    import scenes
    from mmwsim.antennas import RotatingHorn
    from mmwsim.fingerprints import power_delay_profile
    from mmwsim.tracer import Tracer

    scene = scenes.load("default")
    rx = scene.receivers.with_spacing(spacing).positions()
    rx = rx[scene.outdoors(rx)]
    return power_delay_profile(Tracer(scene, None, 3).trace(rx), RotatingHorn(32))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", help="an mmwsim data set (uses its valid receivers)")
    ap.add_argument("--spacing", type=float, default=8.0)
    ap.add_argument("--n", type=int, default=400_000, help="fingerprints per timed call")
    args = ap.parse_args()
    from mmwsim.fingerprints import FingerprintSampler, NoiseModel

    if args.dataset:
        from mmwsim.dataset import Dataset

        ds = Dataset.open(args.dataset)
        pdp = ds.pdp.get_orthogonal_selection((np.flatnonzero(ds.valid),))
    else:
        pdp = traced_pdps(args.spacing)
    t = time.perf_counter()
    sampler = FingerprintSampler(pdp)
    build = time.perf_counter() - t
    active = np.diff(sampler.offsets)
    print(f"{len(pdp)} receivers, {pdp.shape[1]} x 81 bits per fingerprint")
    print(
        f"sampler built in {build:.2f} s, {sampler.nbytes / 1e6:.1f} MB, "
        f"{active.mean():.0f} random-or-sure entries per receiver (of {pdp.shape[1] * 81})"
    )
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(pdp), args.n)
    for threads in (1, 2):
        sampler.sample(idx[:10_000], rng, threads=threads)
        best = min(_timed(lambda th=threads: sampler.sample(idx, rng, threads=th)) for _ in range(3))
        print(f"sampler, {threads} thread(s): {args.n / best / 1e6:.2f} M fingerprints/s")
    sub = np.asarray(pdp[idx[:20_000] % len(pdp)], dtype=np.float32)
    best = min(_timed(lambda: NoiseModel().bits(sub, rng)) for _ in range(2))
    print(f"literal float32 Gaussian noise, 1 thread: {len(sub) / best / 1e6:.3f} M fingerprints/s")


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


if __name__ == "__main__":
    main()
