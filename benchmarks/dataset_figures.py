"""What a data set's fingerprints hold: valid receivers, set bits per fingerprint, coverage per beam.

Usage: python benchmarks/dataset_figures.py STORE [STORE ...]

For each store (``mmwsim generate`` output) prints the valid receivers among the outdoor ones, the
expected number of set bits of a fingerprint (the sum of the noise model's bit probabilities over
the 32 beams x 81 bins window, 6 dB noise, -115 dBm) averaged over valid and over outdoor
receivers, and per beam the share of outdoor receivers whose fingerprint has a bit set in that beam
with probability at least one half (smallest, median and largest beam). Expected counts, not one
noisy draw: the figures are the same on every run.
"""

from __future__ import annotations

import argparse

import numpy as np


def figures(path: str, block: int = 8192) -> None:
    from mmwsim.dataset import Dataset

    ds = Dataset.open(path)
    noise = ds.noise()
    outdoors, valid = ds.outdoors, ds.valid
    w = noise.window(ds.pdp.shape[-1])
    bits = np.zeros(ds.n_rx)
    lit = np.zeros((ds.n_rx, ds.n_beams), bool)
    for s in range(0, ds.n_rx, block):
        p = noise.probability(np.asarray(ds.pdp[s : s + block], dtype=np.float32)[..., w])
        bits[s : s + block] = p.sum(axis=(1, 2))
        # P(at least one bit of the beam) >= 1/2
        lit[s : s + block] = 1.0 - np.exp(np.log1p(-np.minimum(p, 1 - 1e-12)).sum(axis=2)) >= 0.5
    n_out, n_valid = int(outdoors.sum()), int(valid.sum())
    cover = lit[outdoors].mean(axis=0)
    print(f"{path}: {ds!r}")
    print(f"  valid receivers          {n_valid} of {n_out} outdoors ({100 * n_valid / n_out:.1f} %)")
    window = ds.n_beams * (w.stop - w.start)
    print(
        f"  set bits per fingerprint {bits[valid].mean():.1f} of {window} on valid receivers, "
        f"{bits[outdoors].mean():.1f} on outdoor ones (expected, 6 dB noise)"
    )
    print(
        f"  coverage per beam        {100 * cover.min():.1f} % / {100 * np.median(cover):.1f} % / "
        f"{100 * cover.max():.1f} % of outdoor receivers (smallest / median / largest beam)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stores", nargs="+")
    for path in ap.parse_args().stores:
        figures(path)


if __name__ == "__main__":
    main()
