"""Time, peak memory, store size and per-stage shares of `mmwsim generate` on the default scene.

Usage: python benchmarks/generate_grid.py [--spacing M] [--workers N] [--max-reflections K]
                                          [--no-diffraction] [--diffuse S] [--out DIR]

Defaults: the full 1 m grid (160,801 receivers), 32 beams, 3 interactions with diffraction,
2 workers. Targets (issues 17 and 18): <= 60 s without diffraction, <= 90 s with it, <= 4 GB,
on 2 cores. Stage seconds are summed over all processes (the workers run in parallel, so
they add up to more than the wall time); raw embreex throughput is measured in the same run.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path

from _common import raw_embree_rate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacing", type=float, default=1.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--max-reflections", type=int, default=3)
    ap.add_argument("--no-diffraction", action="store_true")
    ap.add_argument("--diffuse", type=float, default=None)
    ap.add_argument("--out", help="store directory (default: a temporary one, removed afterwards)")
    args = ap.parse_args()
    import scenes
    from mmwsim.dataset import Dataset
    from mmwsim.dataset.generate import generate
    from mmwsim.stages import STAGES

    raw = raw_embree_rate(scenes.load("default"))
    tmp = None if args.out else Path(tempfile.mkdtemp(prefix="mmwsim-bench-"))
    out = Path(args.out) if args.out else tmp / "default.zarr"
    STAGES.take()
    t = time.perf_counter()
    generate(
        "default",
        out,
        spacing=args.spacing,
        max_reflections=args.max_reflections,
        workers=args.workers,
        progress=False,
        diffraction=not args.no_diffraction,
        diffuse=args.diffuse,
    )
    wall = time.perf_counter() - t
    stages = STAGES.take()
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    ds = Dataset.open(out)
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6
    n_paths = int(ds.root.attrs["mmwsim"]["n_paths"])
    outdoors = int(ds.outdoors.sum())
    kind = "with diffraction" if not args.no_diffraction else "without diffraction"
    print(
        f"grid {ds.grid.shape[0]} x {ds.grid.shape[1]} = {ds.n_rx} receivers at {args.spacing:g} m, "
        f"{ds.n_beams} beams, {args.max_reflections} interactions {kind}, {args.workers} worker(s)"
    )
    print(f"wall time        {wall:.1f} s ({ds.n_rx / wall:.0f} receivers/s)")
    print(f"valid receivers  {int(ds.valid.sum())} of {outdoors} outdoors")
    print(f"paths            {n_paths} ({n_paths / max(1, outdoors):.1f} per outdoor receiver)")
    print(f"store size       {size / 1e6:.1f} MB")
    print(
        f"peak RSS         main {own:.2f} GB, largest worker {kids:.2f} GB "
        f"(sum bound {own + args.workers * kids:.2f} GB)"
    )
    print(f"raw embreex      {raw / 1e6:.1f} Mrays/s (one core, same run)")
    total = sum(stages.values())
    print(f"{'stage':<24}{'seconds':>9}{'share':>8}   (summed over processes: {total:.1f} s)")
    for name, sec in sorted(stages.items(), key=lambda kv: -kv[1]):
        print(f"{name:<24}{sec:9.1f}{100 * sec / total:7.1f}%")
    if tmp is not None:
        shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
