"""Table t3 of the paper on the default scene: cost and run time of RRT, RRT*, iRRT* after 1000 iterations.

Start (215, 193), target (177, 46), step 5 m, agent radius 0.5 m; median over 10 seeds, without
and with a corridor around "estimated trajectories" (three noisy, smoothed copies of the exact
shortest path sampled every 1.5 m, as a trajectory estimator would return them). Also the
targets: 1000 iterations of Informed RRT* in <= 50 ms, and cost after 1 s within 1 % of the
exact optimum (with BIT* and AORRTC as references). Timings are wall-clock on a shared machine.

    python benchmarks/plan_table.py [--seeds 10] [--iterations 1000]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import scenes
from planning import AgentSpace, Corridor, plan, planner_label, shortest_path

START, GOAL = (215.0, 193.0), (177.0, 46.0)
PAPER = {"rrt": (210, 14.81), "rrtstar": (192, 24.61), "irrtstar": (178, 11.7)}


def estimated_trajectories(
    path: np.ndarray, n: int = 3, spacing: float = 1.5, sigma: float = 2.0, seed: int = 0
):
    """Noisy, smoothed copies of a polyline: (n, L, 2) metres."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.linspace(0.0, s[-1], int(s[-1] // spacing) + 1)
    base = np.column_stack([np.interp(t, s, path[:, 0]), np.interp(t, s, path[:, 1])])
    rng = np.random.default_rng(seed)
    kernel = np.ones(9) / 9
    out = []
    for _ in range(n):
        noise = rng.normal(0.0, sigma * 3, size=(len(t) + 8, 2))  # x3: smoothing over 9 divides by 3
        smooth = np.column_stack([np.convolve(noise[:, k], kernel, mode="valid") for k in range(2)])
        out.append(base + smooth[: len(t)])
    return np.stack(out)


def table(space: AgentSpace, optimum: float, seeds: int, iterations: int) -> list[str]:
    rows = {}
    for name in ("rrt", "rrtstar", "irrtstar"):
        runs = [
            plan(space, START, GOAL, planner=name, iterations=iterations, step=5.0, seed=s)
            for s in range(seeds)
        ]
        ok = [r for r in runs if r.solved]
        cost = statistics.median(r.length for r in ok) if ok else float("nan")
        rt = statistics.median(r.run_time for r in runs) * 1e3
        exact = sum(r.checks["motions_exact"] for r in runs) / max(1, sum(r.checks["motions"] for r in runs))
        rows[name] = (cost, rt, cost / optimum, len(ok), exact)
    head = "| | " + " | ".join(planner_label(k) for k in rows) + " |"
    lines = [head, "|---" * (len(rows) + 1) + "|"]
    lines.append("| Total path cost (m), median | " + " | ".join(f"{v[0]:.1f}" for v in rows.values()) + " |")
    lines.append("| Ratio to the exact optimum | " + " | ".join(f"{v[2]:.3f}" for v in rows.values()) + " |")
    lines.append("| Run time (ms), median | " + " | ".join(f"{v[1]:.1f}" for v in rows.values()) + " |")
    lines.append("| Solved runs | " + " | ".join(f"{v[3]}/{seeds}" for v in rows.values()) + " |")
    lines.append(
        "| Motions needing the FCL test | " + " | ".join(f"{100 * v[4]:.1f} %" for v in rows.values()) + " |"
    )
    lines.append(
        "| Paper: cost (m) / run time (s) | "
        + " | ".join(f"{PAPER[k][0]} / {PAPER[k][1]}" for k in rows)
        + " |"
    )
    return lines


def anytime(space: AgentSpace, optimum: float, seconds: float, seeds: int) -> list[str]:
    lines = [f"| after {seconds:g} s | median cost (m) | ratio | iterations |", "|---|---|---|---|"]
    for name in ("irrtstar", "bitstar", "aorrtc"):
        runs = [
            plan(space, START, GOAL, planner=name, iterations=None, time_limit=seconds, seed=s)
            for s in range(seeds)
        ]
        ok = [r for r in runs if r.solved]
        cost = statistics.median(r.length for r in ok) if ok else float("nan")
        its = statistics.median(r.iterations for r in runs)
        lines.append(f"| {planner_label(name)} | {cost:.2f} | {cost / optimum:.4f} | {its:.0f} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--iterations", type=int, default=1000)
    ap.add_argument("--anytime-seeds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=1.0)
    args = ap.parse_args()

    scene = scenes.load("default")
    t = time.perf_counter()
    free = AgentSpace(scene)
    t_free = time.perf_counter() - t
    t = time.perf_counter()
    opt = shortest_path(free, START, GOAL)
    t_opt = time.perf_counter() - t
    trajs = estimated_trajectories(opt.path)
    corridor = Corridor.from_array(trajs, 10.0)
    t = time.perf_counter()
    guided = AgentSpace(scene, corridor=corridor)
    t_guided = time.perf_counter() - t
    opt_c = shortest_path(guided, START, GOAL)

    print(
        f"default scene, start {START}, target {GOAL}, step 5 m, radius 0.5 m, {args.iterations} iterations,"
    )
    print(f"median over {args.seeds} seeds; wall-clock times on a shared 2-core machine (noisy).\n")
    print(f"set-up: free space {t_free:.2f} s ({free.summary()}), exact optimum {t_opt:.2f} s")
    print(f"exact optimum {opt.length:.2f} m; straight line {np.hypot(*np.subtract(GOAL, START)):.2f} m\n")
    print("### Whole scene\n")
    print("\n".join(table(free, opt.length, args.seeds, args.iterations)))
    print(
        f"\n### Corridor: 10 m around {len(trajs)} estimated trajectories (noisy copies of the optimum, "
        f"sigma 2 m), set-up {t_guided:.2f} s, exact optimum in the corridor {opt_c.length:.2f} m\n"
    )
    print("\n".join(table(guided, opt_c.length, args.seeds, args.iterations)))
    print(f"\n### Anytime, whole scene (median over {args.anytime_seeds} seeds)\n")
    print("\n".join(anytime(free, opt.length, args.seconds, args.anytime_seeds)))


if __name__ == "__main__":
    main()
