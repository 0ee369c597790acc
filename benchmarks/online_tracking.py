"""tn-match's online candidate filter against the offline smoother it replaced: time and accuracy.

Usage: python benchmarks/online_tracking.py RUN DATASET [--max 1000] [--sigma 6] [--threads 2]

Both start from the same matcher candidates of the same noisy fingerprints (seen area, 7 steps),
and run in turn on each batch of 512 sequences, so that a machine that slows down or speeds up
during the run weighs on both alike:

* offline: the dense smoothers re-run on every prefix (``candidate_features``, ``subcell_mean``:
  ``O(T K^3)`` per prefix), what evaluation did before;
* online: :class:`~estimation.smoothing.online.CandidateFilter`, one forward update per step and
  one backward pass per prefix (all of them through one ``smooth_prefixes`` call, as evaluation
  runs them).

Prints seconds per 1000 sequences (after a warm-up call that compiles the kernels) for the 7-step table (search included, then without it), for
every prefix 2..7 batch by batch, and for one online update per user and step; every prefix as
evaluation runs them now (``NetworkMethod.predict_lengths``: parts of 256 side by side, one per
thread), against the offline path run batch by batch and run the same way; the mean
per-trajectory RMSE of both at 7 steps (vehicle / pedestrian / all), and the error of the
current position (the filter's last step) against the smoothed last step. Then
``OnlineTracker.update`` as a user runs it, with and without its drivers smoothed along their
routes over the last steps (``Estimator.route_tracking``): time per user and step, and the
error of the current positions; and the latency of one update where each tracker holds one
user, as a device tracking itself would run it.
"""

from __future__ import annotations

import time

import numpy as np
import torch
from _common import run_dataset_parser, test_draws

LATENCY_USERS = 50


def main() -> None:
    from estimation import Estimator, summarise_by_kind, trajectory_rmse
    from estimation._parts import map_parts
    from estimation.adapter import load_splits
    from estimation.evaluation import NetworkMethod
    from estimation.smoothing.hmm import candidate_features
    from mmwsim._threads import set_threads

    ap = run_dataset_parser(__doc__)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    set_threads(args.threads)
    est = Estimator.load(args.run)
    if est.name != "tn-match":
        raise SystemExit(f"{args.run}: not a tn-match run")
    sets, _ = load_splits(args.dataset, ("validation", "test/seen"))
    est.attach(sets["validation"], args.sigma)
    data, bits = test_draws(sets["test/seen"], args.max, args.sigma, 7)
    n, per = data.n, 1000.0 / data.n
    net = est.net

    # Steady state: the kernels compiled (or loaded from numba's cache) and torch warmed up first,
    # on users spread over the draws: the test splits are stored kind by kind, and the first 64
    # alone (static users and walkers) left the drivers' kernels to compile inside the timing.
    warm = torch.from_numpy(np.linspace(0, n - 1, min(n, 64)).round().astype(np.int64))
    xy0, score0 = est.search(bits[warm].float())  # drivers among them: the route kernels compile too
    est.predict(est.candidate_filter().run(xy0, score0).smooth())
    kxy, post = candidate_features(xy0, score0, net.k, motion=net.motion)
    est.predict((kxy, post, net.smoothed(kxy, post)))

    t = time.perf_counter()
    found = [est.search(bits[a : a + 512].float()) for a in range(0, n, 512)]
    t_search = time.perf_counter() - t

    def offline(xy: torch.Tensor, score: torch.Tensor, L: int) -> torch.Tensor:
        kxy, post = candidate_features(xy[:, :L], score[:, :L], net.k, motion=net.motion)
        return est.predict((kxy, post, net.smoothed(kxy, post)))

    # Offline and online in turn on each batch, so that both meet the machine in the same state.
    # seconds of: offline 7 steps, offline prefixes, forward filter, online 7 steps, online prefixes
    seconds = np.zeros(5)
    off7, on7, now = [], [], []
    for xy, score in found:
        marks = [time.perf_counter()]
        off7.append(offline(xy, score, 7))
        marks.append(time.perf_counter())
        for L in range(2, 8):
            offline(xy, score, L)
        marks.append(time.perf_counter())
        f = est.candidate_filter().run(xy, score)
        marks.append(time.perf_counter())
        on7.append(est.predict(f.smooth(7)))
        marks.append(time.perf_counter())
        for x in f.smooth_prefixes(list(range(2, 8))):
            est.predict(x)
        marks.append(time.perf_counter())
        seconds += np.diff(marks)
        # as evaluation does, only one batch's filter is held (its stored messages let go)
        now.append(f.positions[-1])
        del f
    t_off7, t_off_all, t_fwd, t_bwd7, t_bwd_all = seconds
    off7, on7 = torch.cat(off7), torch.cat(on7)

    def row(label: str, pred: torch.Tensor) -> str:
        s = summarise_by_kind(trajectory_rmse(pred.numpy(), data.positions), data.kind)
        return f"{label}: vehicle {s['vehicle']['mean']:.3f} / pedestrian {s['pedestrian']['mean']:.3f} / all {s['all']['mean']:.3f} m"

    print(f"{args.run} on {n} seen-area trajectories, 7 steps, {args.sigma:g} dB, {args.threads} threads")
    print(f"search (both): {t_search * per:.2f} s per 1000 sequences")
    print(
        f"7-step table: offline {(t_search + t_off7) * per:.2f} s, online {(t_search + t_fwd + t_bwd7) * per:.2f} s"
        f" per 1000 ({(t_search + t_off7) / (t_search + t_fwd + t_bwd7):.1f}x); without the search"
        f" {t_off7 * per:.2f} s against {(t_fwd + t_bwd7) * per:.2f} s ({t_off7 / (t_fwd + t_bwd7):.1f}x)"
    )
    print(
        f"prefixes 2..7 batch by batch: offline {(t_search + t_off_all) * per:.2f} s, online"
        f" {(t_search + t_fwd + t_bwd_all) * per:.2f} s per 1000 ({(t_search + t_off_all) / (t_search + t_fwd + t_bwd_all):.1f}x)"
    )
    print(f"online update: {(t_search + t_fwd) / 7 * 1e3 / n:.3f} ms per user and step (search included)")

    # Prefixes as evaluation runs them now: parts of 256 side by side, one per thread; and the
    # offline path run the same way, so that the ratio is not the side-by-side parts' alone.
    # Both in turn on each batch of 512, as above.
    lengths = list(range(2, 8))
    method = NetworkMethod(est, "online", 0.0, 0)

    def offline_part(rows: slice) -> list[torch.Tensor]:
        xy, score = est.search(bits[rows].float())
        return [offline(xy, score, L) for L in lengths]

    t_eval = t_off_parts = 0.0
    ev7 = []
    for a in range(0, n, 512):
        b = min(n, a + 512)
        t = time.perf_counter()
        ev7.append(method.predict_lengths(bits[a:b], lengths)[7][0])
        t_eval += time.perf_counter() - t
        t = time.perf_counter()
        map_parts(offline_part, [slice(c, min(b, c + 256)) for c in range(a, b, 256)])
        t_off_parts += time.perf_counter() - t
    same = np.array_equal(np.concatenate(ev7), on7.double().numpy())
    print(
        f"prefixes 2..7 as evaluation runs them (parts of 256 side by side on {args.threads} threads):"
        f" {t_eval * per:.2f} s per 1000, {(t_search + t_off_all) / t_eval:.1f}x the offline path above;"
        f" the offline path run the same way {t_off_parts * per:.2f} s ({t_off_parts / t_eval:.1f}x);"
        f" its 7 steps equal to the batch-by-batch online path's: {same}"
    )
    print(row("offline", off7))
    print(row("online ", on7))
    for routes in (True, False):  # the tracker's current positions, one update per step
        est.route_tracking = routes
        t = time.perf_counter()
        cur = []
        for a in range(0, n, 512):
            tracker = est.tracker()
            cur.append(np.stack([tracker.update(bits[a : a + 512, s]) for s in range(7)], 1))
        t_cur = time.perf_counter() - t
        err = np.sqrt((np.linalg.norm(np.concatenate(cur) - data.positions, axis=-1)[:, 1:] ** 2).mean(1))
        s = summarise_by_kind(err, data.kind)
        print(
            f"OnlineTracker.update{'' if routes else ' without route smoothing'}: {t_cur / 7 * 1e3 / n:.3f} ms"
            f" per user and step (search included); current positions, RMS over steps 2..7: vehicle"
            f" {s['vehicle']['mean']:.3f} / pedestrian {s['pedestrian']['mean']:.3f} / all {s['all']['mean']:.3f} m"
        )
    # one user per tracker, as a device tracking itself runs it: users spread over the draws (the
    # first ones alone are static users and walkers, whose updates skip the route pass)
    spread = np.unique(np.linspace(0, n - 1, min(n, LATENCY_USERS)).round().astype(np.int64))
    for routes in (True, False):
        est.route_tracking = routes
        lat, made = [], []
        for u in spread:
            t = time.perf_counter()
            tracker = est.tracker()
            made.append(time.perf_counter() - t)
            for s in range(7):
                t = time.perf_counter()
                tracker.update(bits[u : u + 1, s])
                lat.append(time.perf_counter() - t)
        lat_ms = np.array(lat) * 1e3
        print(
            f"one user per tracker{'' if routes else ' without route smoothing'}: update median"
            f" {np.median(lat_ms):.1f} ms, 95th percentile {np.percentile(lat_ms, 95):.1f} ms"
            f" ({len(spread)} users of all kinds x 7 steps); a new tracker {np.median(made) * 1e3:.1f} ms"
        )
    est.route_tracking = True
    now = np.concatenate(now)
    err_now = np.linalg.norm(now - data.positions[:, -1], axis=-1).mean()
    err_last = np.linalg.norm(on7[:, -1].numpy() - data.positions[:, -1], axis=-1).mean()
    print(f"current position (filtered last step) {err_now:.3f} m; the network's last step {err_last:.3f} m")


if __name__ == "__main__":
    main()
