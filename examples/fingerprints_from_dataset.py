"""Generate a coarse data set of the default scene, then sample beamformed fingerprints from it.

Run: python examples/fingerprints_from_dataset.py [OUT_DIR]
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

import mmwsim

folder = Path(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp())
folder.mkdir(parents=True, exist_ok=True)
out = folder / "coarse.zarr"
mmwsim.generate_dataset("default", out, spacing=20.0, n_rays=1_000_000, progress=False, resume=True)

ds = mmwsim.Dataset.open(out)
print(ds)
valid = np.flatnonzero(ds.valid)
pdp = ds.pdp[valid[:5]]  # (5, 32 beams, 120 bins) received power, dBm; -inf where no signal
beam_mw = (10.0 ** (pdp.astype(np.float64) / 10.0)).sum(axis=2)  # total power per beam, mW
best_beam = beam_mw.argmax(axis=1)
print("best beam of the first valid receivers:", best_beam.tolist())

# Fresh log-normal noise at every call: two draws of the same receivers differ.
rng = np.random.default_rng(0)
bits = ds.fingerprints(valid[:5], rng)  # (5, 32, 81) uint8
again = ds.fingerprints(valid[:5], rng)
print("fingerprint shape", bits.shape, "ones", int(bits.sum()), "changed bits", int((bits != again).sum()))

# Continuous positions are looked up at the nearest grid point.
index = ds.nearest(np.array([[201.3, 150.2], [40.0, 203.0]]))
print("nearest grid points:", ds.positions[index, :2].tolist())
