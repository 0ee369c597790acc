"""Sampling-based planners from OMPL over a :class:`AgentSpace`: RRT, RRT*, Informed RRT*, BIT*, AORRTC.

The state space is the plane bounded by the free space's region; validity and motions are
answered by :class:`AgentSpace` (certificate, then FCL). RRT-family planners take no custom
sampler, so a corridor restricts sampling through the bounds (the corridor's bounding box)
and rejection in the motion validator.

A run stops after ``iterations`` planner iterations or ``time_limit`` seconds, whichever
comes first; the termination condition is evaluated once per iteration and also records
the best cost, so the result carries cost against iteration. RRT stops at its first
solution. RRT* and Informed RRT* rewire within a radius (the r-disc variant), capped at
the step: OMPL's default k-nearest rewiring costs about four times as much per iteration
here for the same convergence.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from .errors import PlanningError
from .names import PLANNER_NAMES, PlannerName
from .space import AgentSpace

__all__ = ["PLANNERS", "PlanResult", "Snapshot", "plan", "planner_label", "ompl_seed"]

# name -> (OMPL class, label, uses informed sampling)
PLANNERS: dict[PlannerName, tuple[str, str, bool]] = {
    "rrt": ("RRT", "RRT", False),
    "rrtstar": ("RRTstar", "RRT*", False),
    "irrtstar": ("InformedRRTstar", "Informed RRT*", True),
    "bitstar": ("BITstar", "BIT*", True),
    "aorrtc": ("AORRTC", "AORRTC", True),
}
assert tuple(PLANNERS) == PLANNER_NAMES, "the planners and the OMPL-free list of names differ"


def planner_label(name: str) -> str:
    """Display name of a planner key, e.g. ``irrtstar`` -> ``Informed RRT*``."""
    return PLANNERS[name][1]


@dataclass(frozen=True)
class Snapshot:
    """The search tree at one iteration.

    Attributes
    ----------
    iteration : int
    edges : (n_edges, 2, 2) float64
        Tree edges, metres.
    path : (n, 2) float64 or None
        Best path in the tree at that iteration.
    cost : float
        Best cost so far, metres (inf before the first solution).
    """

    iteration: int
    edges: np.ndarray
    path: np.ndarray | None
    cost: float


@dataclass
class PlanResult:
    """The outcome of one planner run.

    Attributes
    ----------
    planner : str
        Planner key (see :data:`PLANNERS`).
    start, goal : (2,) float64
        Metres.
    solved : bool
        Whether an exact (goal-reaching) path was found within the budget.
    path : (n, 2) float64
        The best path, start to goal, metres (empty if not solved).
    length : float
        Its length, metres (inf if not solved).
    run_time : float
        Seconds spent in the planner (recording snapshots excluded).
    iterations : int
        Planner iterations run.
    cost_curve : (k, 3) float64
        Rows (iteration, seconds, best cost in metres), one per improvement.
    seed : int
    step : float
        Planner range (longest edge), metres.
    checks : dict
        Validity counts: states, motions, and how many of each needed the exact FCL test.
    snapshots : list of Snapshot
        Tree growth, when requested.
    problem : str or None
        Set when the planner claimed a solution that failed the final exact check of every
        step (then ``solved`` is False); seen with OMPL 2.0.1's AORRTC when the first
        solution is the straight line, which it reduces to a zero-length path.
    """

    planner: str
    start: np.ndarray
    goal: np.ndarray
    solved: bool
    path: np.ndarray
    length: float
    run_time: float
    iterations: int
    cost_curve: np.ndarray
    seed: int
    step: float
    checks: dict = field(default_factory=dict)
    snapshots: list[Snapshot] = field(default_factory=list)
    problem: str | None = None

    @property
    def label(self) -> str:
        return planner_label(self.planner)

    def to_dict(self) -> dict:
        """JSON-ready summary (lists of floats)."""
        return {
            "planner": self.planner,
            "label": self.label,
            "start": [float(v) for v in self.start],
            "goal": [float(v) for v in self.goal],
            "solved": self.solved,
            "length_m": self.length if self.solved else None,
            "run_time_s": self.run_time,
            "iterations": self.iterations,
            "seed": self.seed,
            "step_m": self.step,
            "path": self.path.tolist(),
            "cost_curve": [
                {"iteration": int(i), "time_s": float(t), "cost_m": float(c)} for i, t, c in self.cost_curve
            ],
            "checks": dict(self.checks),
            "problem": self.problem,
        }


def ompl_seed(seed: int) -> int:
    """The non-zero 31-bit OMPL seed derived from a user seed (OMPL ignores 0)."""
    return int(np.random.SeedSequence(int(seed)).generate_state(1)[0]) % (2**31 - 1) + 1


def plan(
    space: AgentSpace,
    start,
    goal,
    planner: PlannerName = "irrtstar",
    iterations: int | None = 1000,
    time_limit: float | None = None,
    step: float = 5.0,
    seed: int = 0,
    snapshots: int = 0,
) -> PlanResult:
    """Plan a path from ``start`` to ``goal`` with an OMPL planner.

    Parameters
    ----------
    space : AgentSpace
    start, goal : (2,) float
        Metres; must be valid states (else :class:`PlanningError`).
    planner : str
        One of :data:`PLANNERS`: ``rrt``, ``rrtstar``, ``irrtstar``, ``bitstar``, ``aorrtc``.
    iterations : int, optional
        Iteration budget.
    time_limit : float, optional
        Wall-time budget, seconds. At least one budget must be given.
    step : float
        Longest edge (OMPL range), metres; BIT* has none and ignores it.
    seed : int
        Same seed, same space, same budget in iterations: same path.
    snapshots : int
        Number of tree snapshots to keep for recording (0: none; they cost time, which is
        excluded from ``run_time``).

    Returns
    -------
    PlanResult
        ``solved`` is False when the budget ran out before a path was found.
    """
    _check_budget(planner, iterations, time_limit, step, seed)
    s = np.array(space.check_endpoint(start, "start"))
    g = np.array(space.check_endpoint(goal, "goal"))
    if np.array_equal(s, g):
        raise PlanningError(f"start and goal coincide at ({s[0]:g}, {s[1]:g})")

    import ompl.base as ob
    import ompl.util as ou

    level = ou.getLogLevel()
    # OMPL logs an error when reseeded after its first draw; reseeding still makes the runs
    # that follow deterministic, which is all that is needed here.
    ou.setLogLevel(ou.LOG_NONE)
    try:
        ou.RNG.setSeed(ompl_seed(seed))
        p, pdef, si, validator = _problem(space, planner, s, g, step)
        before = dict(space.stats)
        run = _Monitor(p, ob, si, iterations, time_limit, snapshots, start_goal=(s, g))
        run.t0 = time.perf_counter()
        p.solve(ob.PlannerTerminationCondition(run))
        run_time = time.perf_counter() - run.t0 - run.snap_time
        n_iter = run.iterations()
        if hasattr(p, "numIterations") and planner != "bitstar":
            n_iter = int(p.numIterations())
        solved, path, length, problem = _solution(space, pdef, s, g)
        if solved and (not run.curve or run.curve[-1][2] > length + 1e-9):
            run.curve.append((n_iter, run_time, length))
        if snapshots and (not run.snaps or run.snaps[-1].iteration != n_iter):
            run.snapshot(n_iter, force_cost=length)
        checks = {k: space.stats[k] - before.get(k, 0) for k in space.stats}
        del validator  # kept alive while OMPL held it
    finally:
        ou.setLogLevel(level)
    return PlanResult(
        planner=planner,
        start=s,
        goal=g,
        solved=solved,
        path=path,
        length=length,
        run_time=run_time,
        iterations=n_iter,
        cost_curve=np.array(run.curve, dtype=np.float64).reshape(-1, 3),
        seed=int(seed),
        step=float(step),
        checks=checks,
        snapshots=run.snaps,
        problem=problem,
    )


def _check_budget(planner: str, iterations, time_limit, step: float, seed: int) -> None:
    """One-line errors for an unknown planner or an unusable budget, step or seed."""
    if planner not in PLANNERS:
        raise PlanningError(f"unknown planner {planner!r}; choose from {', '.join(PLANNERS)}")
    if iterations is None and time_limit is None:
        raise PlanningError("give an iteration budget, a time budget or both")
    if iterations is not None and (int(iterations) != iterations or iterations < 1):
        raise PlanningError(f"iterations must be a positive integer, got {iterations!r}")
    if time_limit is not None and not (math.isfinite(time_limit) and time_limit > 0):
        raise PlanningError(f"time limit must be a positive number of seconds, got {time_limit!r}")
    if not (math.isfinite(step) and step > 0):
        raise PlanningError(f"step must be a positive number of metres, got {step!r}")
    if int(seed) != seed or seed < 0:
        raise PlanningError(f"seed must be a non-negative integer, got {seed!r}")


def _problem(space: AgentSpace, planner: str, s: np.ndarray, g: np.ndarray, step: float):
    """The OMPL planner set up on the space's bounds, validity and motion checks, from ``s`` to
    ``g`` minimising path length: ``(planner, problem definition, space information, motion
    validator)``."""
    import ompl.base as ob
    import ompl.geometric as og

    rv = ob.RealVectorStateSpace(2)
    bounds = ob.RealVectorBounds(2)
    for k in range(2):
        bounds.setLow(k, float(space.bounds[0, k]))
        bounds.setHigh(k, float(space.bounds[1, k]))
    rv.setBounds(bounds)
    si = ob.SpaceInformation(rv)
    check_state = space.state_valid
    si.setStateValidityChecker(lambda st: check_state(st[0], st[1]))
    validator = _motion_validator(ob, si, space.motion_valid)
    si.setMotionValidator(validator)
    si.setup()
    pdef = ob.ProblemDefinition(si)
    st_s, st_g = rv.allocState(), rv.allocState()
    st_s[0], st_s[1] = float(s[0]), float(s[1])
    st_g[0], st_g[1] = float(g[0]), float(g[1])
    pdef.setStartAndGoalStates(st_s, st_g)
    pdef.setOptimizationObjective(ob.PathLengthOptimizationObjective(si))
    p = getattr(og, PLANNERS[planner][0])(si)
    if hasattr(p, "setRange"):
        p.setRange(float(step))
    if hasattr(p, "setKNearest"):
        p.setKNearest(False)
    p.setProblemDefinition(pdef)
    p.setup()
    return p, pdef, si, validator


def _solution(space: AgentSpace, pdef, s: np.ndarray, g: np.ndarray):
    """``(solved, path (n, 2), length, problem)`` of the planner's exact solution, after the final
    exact check of every step (a path failing it counts as none, with the reason in ``problem``)."""
    if not pdef.hasExactSolution():
        return False, np.zeros((0, 2)), math.inf, None
    sol = pdef.getSolutionPath()
    path = np.array([[sol.getState(k)[0], sol.getState(k)[1]] for k in range(sol.getStateCount())])
    problem = _path_problem(space, path, s, g)
    if problem is not None:
        return False, np.zeros((0, 2)), math.inf, problem
    return True, path, float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))), None


def _path_problem(space: AgentSpace, path: np.ndarray, s: np.ndarray, g: np.ndarray) -> str | None:
    """Why a returned path is unusable, or None: ends must match and every step pass the exact test."""
    if len(path) < 2 or not (np.allclose(path[0], s, atol=1e-9) and np.allclose(path[-1], g, atol=1e-9)):
        return "the planner returned a path that does not join start and goal"
    for (ax, ay), (bx, by) in zip(path[:-1], path[1:], strict=True):
        if not space.exact_motion_valid(float(ax), float(ay), float(bx), float(by)):
            return f"the planner returned a path with an invalid step ({ax:g}, {ay:g}) -> ({bx:g}, {by:g})"
    return None


def _motion_validator(ob, si, check):
    class _Motion(ob.MotionValidator):
        """Exact motion validation delegated to AgentSpace.motion_valid (swept volume)."""

        def checkMotion(self, s1, s2, *last_valid):
            # The planners used here only call the two-state form.
            return check(s1[0], s1[1], s2[0], s2[1])

    return _Motion(si)


class _Monitor:
    """Termination condition: counts iterations, checks the budgets, records the best cost."""

    def __init__(self, planner, ob, si, iterations, time_limit, snapshots, start_goal):
        self.p = planner
        self.ob = ob
        self.si = si
        self.limit = iterations if iterations is not None else math.inf
        self.time_limit = time_limit if time_limit is not None else math.inf
        self.calls = 0
        self.stopped = False
        self.best = math.inf
        self.curve: list[tuple[int, float, float]] = []
        self.has_cost = hasattr(planner, "bestCost")
        self.t0 = 0.0
        self.snap_time = 0.0
        self.snaps: list[Snapshot] = []
        self.n_snaps = int(snapshots)
        self.next_snap = 0.0
        self.start_goal = start_goal

    def iterations(self) -> int:
        return self.calls - 1 if self.stopped else self.calls

    def __call__(self) -> bool:
        done = self.calls  # iterations completed before this call
        self.calls += 1
        now = time.perf_counter() - self.t0 - self.snap_time
        if self.has_cost:
            c = self.p.bestCost().value()
            if c < self.best - 1e-9 and math.isfinite(c):
                self.best = c
                self.curve.append((done, now, c))
        if self.n_snaps and self._due(done, now):
            self.snapshot(done)
        self.stopped = done >= self.limit or now >= self.time_limit
        return self.stopped

    def _due(self, done: int, now: float) -> bool:
        # Evenly spaced in iterations when there is an iteration budget, else in time.
        if math.isfinite(self.limit):
            progress = done / self.limit
        else:
            progress = now / self.time_limit
        if progress >= self.next_snap:
            self.next_snap = (math.floor(progress * self.n_snaps) + 1) / self.n_snaps
            return True
        return False

    def snapshot(self, iteration: int, force_cost: float | None = None) -> None:
        t = time.perf_counter()
        pd = self.ob.PlannerData(self.si)
        self.p.getPlannerData(pd)
        n = pd.numVertices()
        xy = np.empty((n, 2))
        for k in range(n):
            st = pd.getVertex(k).getState()
            xy[k] = st[0], st[1]
        a, b = [], []
        for k in range(n):
            for e in pd.getEdges(k):
                a.append(k)
                b.append(e)
        edges = np.stack([xy[a], xy[b]], axis=1) if a else np.zeros((0, 2, 2))
        cost = self.best if force_cost is None else force_cost
        path = None
        if math.isfinite(cost) and n and pd.numStartVertices() and pd.numGoalVertices():
            path = _tree_path(n, np.array(a, dtype=np.int64), np.array(b, dtype=np.int64), xy, pd)
        self.snaps.append(Snapshot(int(iteration), edges, path, float(cost)))
        self.snap_time += time.perf_counter() - t


def _tree_path(n: int, a: np.ndarray, b: np.ndarray, xy: np.ndarray, pd) -> np.ndarray | None:
    """Shortest start-to-goal path through the snapshot's edges (any orientation)."""
    if len(a) == 0:
        return None
    w = np.linalg.norm(xy[a] - xy[b], axis=1) + 1e-12
    graph = scipy.sparse.coo_matrix((w, (a, b)), shape=(n, n)).tocsr()
    src = pd.getStartIndex(0)
    dist, pred = scipy.sparse.csgraph.dijkstra(graph, directed=False, indices=src, return_predecessors=True)
    goals = [pd.getGoalIndex(k) for k in range(pd.numGoalVertices())]
    goals = [k for k in goals if np.isfinite(dist[k])]
    if not goals:
        return None
    k = min(goals, key=lambda v: dist[v])
    order = [k]
    while order[-1] != src:
        order.append(int(pred[order[-1]]))
    return xy[order[::-1]]
