"""``mmwsim demo [--out DIR] [--rrd FILE] [--tiny] [--seed N]``: the whole chain on the default scene."""

from __future__ import annotations

import argparse
import math

EPILOG = """\
Stages: a coarse data set of the default scene (receivers every 2 m; --tiny: 8 m); 7-step user
trajectories, those touching the hold-out region 0,100,100,200 (a 100 m block, the west end of the
cross street and shadowed side streets, chosen by spatial block cross-validation to be neither
easier nor harder than the whole area) kept for testing only; a short training of the transformer
(tn); the estimate of the held-out trajectories from fresh noisy fingerprints; and an Informed
RRT* path inside the corridor around one estimated trajectory, against the exact shortest path in
that corridor.

DIR receives dataset.zarr (dataset-tiny.zarr), runs/tn (runs/tn-tiny), summary.json and demo.rrd,
whose default blueprint has one tab per stage: scene and rays, coverage per beam, fingerprints over
the steps of the planned-along trajectory, true against estimated trajectories, training curves
(epoch timeline) and the planner's tree growth (iteration timeline). Open it with `rerun DIR/demo.rrd`.
Running again into the same DIR reuses the finished data set and training when their settings
match and replaces them otherwise. Exit status 2: bad input (one line on stderr).
"""


def register(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="run data set -> trajectories -> transformer -> planned path on the default scene, one .rrd",
        description=__doc__,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", default="demo", metavar="DIR", help="output folder (default ./demo)")
    p.add_argument("--rrd", metavar="FILE", help="recording to write (default DIR/demo.rrd)")
    p.add_argument("--tiny", action="store_true", help="the same chain at toy size (well under a minute)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="seed of every random draw (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_demo)


def _demo(args) -> int:
    import time

    from ..demo import check_outputs, demo_config, run_demo

    cfg = demo_config(args.tiny, args.seed)  # bad input fails here, before any work
    check_outputs(args.out, args.rrd)
    t0 = time.perf_counter()
    r = run_demo(args.out, args.rrd, config=cfg, progress=not args.quiet, log=lambda s: print(s, flush=True))
    h = r.holdout_rmse_m
    path = (
        f"{r.path_length_m:.2f} m (exact optimum in the corridor {r.optimum_m:.2f} m)"
        if r.solved
        else f"none found (optimum {r.optimum_m:.2f} m)"
    )
    ratio = f", ratio {r.path_length_m / r.optimum_m:.3f}" if r.solved and math.isfinite(r.optimum_m) else ""
    print(
        f"\ndemo finished in {time.perf_counter() - t0:.0f} s\n"
        f"  held-out trajectory {r.trajectory_id}: estimate RMSE {r.rmse_m:.2f} m "
        f"({h['n']} held-out trajectories: mean {h['mean']:.2f} m, median {h['median']:.2f} m)\n"
        f"  planned path: {path}{ratio}, in the {r.corridor_width_m:g} m corridor around the estimate\n"
        f"    from its first position ({r.start[0]:.1f}, {r.start[1]:.1f}) to {r.target} "
        f"({r.goal[0]:.1f}, {r.goal[1]:.1f})\n"
        f"  data set   {r.dataset}\n"
        f"  model      {r.run} ({r.epochs} epochs)\n"
        f"  summary    {r.summary}\n"
        f"  recording  {r.rrd}   (open with: rerun {r.rrd})"
    )
    return 0
