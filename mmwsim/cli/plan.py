"""``mmwsim plan``: shortest collision-free path over a scene with an OMPL planner."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from planning.names import PLANNER_NAMES

from ..errors import MmwsimError
from ..files import check_suffix, write_text_atomic
from .osm_area import add_area_arguments, scene_spec

_EPILOG = """\
corridor files: .csv with a header naming columns x,y and optionally trajectory (rows of one
trajectory consecutive, in order), .json {"trajectories": [[[x, y], ...], ...]}, or .npy float
array (n, L, 2) / (L, 2); the agent's centre must stay within --corridor-width of a trajectory.

exit status: 0 path found; 2 bad input (start or goal outside the scene, inside a building,
in collision or outside the corridor, unreadable file, ...), one line on stderr; 3 no solution:
the planner found no path within its budget, or none exists (the result files are still
written, with "solved": false).
"""


def register(sub) -> None:
    p = sub.add_parser(
        "plan",
        help="plan a collision-free path (RRT, RRT*, Informed RRT*, BIT*, AORRTC) and compare to the optimum",
        description="Plan a path for a cylinder agent between two points of a scene with an OMPL planner, "
        "optionally inside a corridor around estimated trajectories, and compare its length with "
        "the exact shortest path.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scene", help="catalogue name (default, manhattan:seed=3, ...) or a scene file")
    p.add_argument("--start", required=True, help="start position X,Y in metres")
    p.add_argument("--goal", required=True, help="goal position X,Y in metres")
    p.add_argument(
        "--planner",
        default="irrtstar",
        choices=PLANNER_NAMES,
        help="planner (default irrtstar: Informed RRT*)",
    )
    budget = p.add_mutually_exclusive_group()
    budget.add_argument("--iterations", type=int, help="iteration budget (default 1000)")
    budget.add_argument("--time", type=float, help="time budget in seconds")
    p.add_argument("--step", type=float, default=5.0, help="longest tree edge in metres (default 5)")
    p.add_argument("--radius", type=float, default=0.5, help="agent radius in metres (default 0.5)")
    p.add_argument("--corridor", help="estimated trajectories (.csv, .json or .npy) to plan within")
    p.add_argument(
        "--corridor-width", type=float, default=10.0, help="corridor half-width in metres (default 10)"
    )
    p.add_argument(
        "--resolution", type=float, default=0.25, help="clearance raster spacing in metres (default 0.25)"
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--no-optimum", action="store_true", help="skip the exact shortest path")
    p.add_argument("--json", help="write the result (path, cost curve, optimum) to this .json file")
    p.add_argument("--rrd", help="write a Rerun recording of the search to this .rrd file")
    add_area_arguments(p)
    p.set_defaults(func=_plan)


def _writable(path: str, suffix: str, what: str) -> Path:
    out = check_suffix(path, suffix, what)
    if not out.parent.is_dir() or not os.access(out.parent, os.W_OK):
        raise MmwsimError(f"{out}: folder {out.parent} does not exist or is not writable")
    return out


def _plan(args) -> int:
    from ..scene import load_scene
    from . import EXIT_NO_SOLUTION, parse_vector

    start = parse_vector(args.start, 2, "--start")
    goal = parse_vector(args.goal, 2, "--goal")
    json_out = _writable(args.json, ".json", "--json") if args.json else None
    if args.rrd:
        _writable(args.rrd, ".rrd", "--rrd")
    iterations = args.iterations if args.time is None else None
    if iterations is None and args.time is None:
        iterations = 1000
    # Cheap checks before the scene is loaded; plan() repeats them for library callers.
    if iterations is not None and iterations < 1:
        raise MmwsimError(f"--iterations must be a positive integer, got {iterations}")
    if args.time is not None and not args.time > 0:
        raise MmwsimError(f"--time must be a positive number of seconds, got {args.time:g}")
    for flag, value in (
        ("--step", args.step),
        ("--radius", args.radius),
        ("--corridor-width", args.corridor_width),
    ):
        if not value > 0:
            raise MmwsimError(f"{flag} must be a positive number of metres, got {value:g}")

    import planning

    scene = load_scene(scene_spec(args))
    corridor = planning.load_corridor(args.corridor, args.corridor_width) if args.corridor else None
    space = planning.AgentSpace(scene, radius=args.radius, corridor=corridor, resolution=args.resolution)
    result = planning.plan(
        space,
        start,
        goal,
        planner=args.planner,
        iterations=iterations,
        time_limit=args.time,
        step=args.step,
        seed=args.seed,
        snapshots=50 if args.rrd else 0,
    )
    optimum = None if args.no_optimum else planning.shortest_path(space, result.start, result.goal)

    print(space.summary())
    budget = f"{iterations} iterations" if iterations is not None else f"{args.time:g} s"
    if result.solved:
        print(
            f"{result.label}: path of {result.length:.2f} m, {len(result.path)} vertices, "
            f"{result.iterations} iterations in {result.run_time * 1e3:.1f} ms (seed {result.seed})"
        )
    checks = result.checks
    print(
        f"checks: {checks['motions']} motions ({checks['motions_exact']} by the exact FCL test), "
        f"{checks['states']} states ({checks['states_exact']} exact)"
    )
    if optimum is not None:
        ratio = f", ratio {result.length / optimum.length:.4f}" if result.solved else ""
        print(f"optimum: {optimum.length:.2f} m ({optimum.n_nodes} graph nodes){ratio}")
    elif not args.no_optimum:
        print("optimum: no collision-free path exists between start and goal")

    config = {
        "scene": scene.source or scene.name,
        "start": list(start),
        "goal": list(goal),
        "planner": args.planner,
        "iterations": iterations,
        "time_s": args.time,
        "step_m": args.step,
        "radius_m": args.radius,
        "corridor": str(args.corridor) if args.corridor else None,
        "corridor_width_m": args.corridor_width if args.corridor else None,
        "resolution_m": args.resolution,
        "seed": args.seed,
    }
    if json_out is not None:
        doc = {"config": config, **result.to_dict()}
        doc["optimum"] = (
            {"length_m": optimum.length, "path": optimum.path.tolist()} if optimum is not None else None
        )
        doc["ratio"] = result.length / optimum.length if (optimum is not None and result.solved) else None
        write_text_atomic(json_out, json.dumps(doc, indent=1) + "\n")
        print(f"wrote {json_out}")
    if args.rrd:
        from ..recording import Recording

        with Recording(args.rrd, "plan", families=("planner",), config=config) as rec:
            planning.log_plan(rec, space, result, optimum)
        print(f"wrote {args.rrd}")
    if not result.solved:
        reason = "" if optimum is not None or args.no_optimum else " (none exists)"
        if result.problem:
            reason = f" ({result.problem})"
        print(f"mmwsim: no solution: {result.label} found no path within {budget}{reason}", file=sys.stderr)
        return EXIT_NO_SOLUTION
    return 0
