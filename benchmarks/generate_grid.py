"""Time, peak memory and store size of `mmwsim generate` on the default scene.

Usage: python benchmarks/generate_grid.py [--spacing M] [--workers N] [--max-reflections K] [--out DIR]

Defaults: the full 1 m grid (160,801 receivers), 32 beams, 3 reflections, 2 workers.
Targets: <= 90 s and <= 4 GB on 2 cores, store < 1 GB.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacing", type=float, default=1.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--max-reflections", type=int, default=3)
    ap.add_argument("--out", help="store directory (default: a temporary one, removed afterwards)")
    args = ap.parse_args()
    from mmwsim.dataset import Dataset, generate

    tmp = None if args.out else Path(tempfile.mkdtemp(prefix="mmwsim-bench-"))
    out = Path(args.out) if args.out else tmp / "default.zarr"
    t = time.perf_counter()
    generate("default", out, spacing=args.spacing, max_reflections=args.max_reflections, workers=args.workers)
    wall = time.perf_counter() - t
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    ds = Dataset.open(out)
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6
    n_paths = int(ds.root.attrs["mmwsim"]["n_paths"])
    print(
        f"grid {ds.grid.shape[0]} x {ds.grid.shape[1]} = {ds.n_rx} receivers at {args.spacing:g} m, "
        f"{ds.n_beams} beams, {args.max_reflections} reflections, {args.workers} worker(s)"
    )
    print(f"wall time        {wall:.1f} s ({ds.n_rx / wall:.0f} receivers/s)")
    print(f"valid receivers  {int(ds.valid.sum())}")
    print(f"paths            {n_paths} ({n_paths / max(1, int(ds.outdoors.sum())):.1f} per outdoor receiver)")
    print(f"store size       {size / 1e6:.1f} MB")
    print(
        f"peak RSS         main {own:.2f} GB, largest worker {kids:.2f} GB "
        f"(sum bound {own + args.workers * kids:.2f} GB)"
    )
    if tmp is not None:
        shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
