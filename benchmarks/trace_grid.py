"""Trace the whole 401 x 401 receiver grid of the default scene at 1, 2 and 3 reflections.

Prints wall time, peak memory (RSS), paths per receiver, receivers without any
path, and the rays cast per second against raw embreex throughput measured in
the same run. Optionally checks a random sample of receivers against a brute-force
image method over every reflector sequence (slow; ``--check N``).

    python benchmarks/trace_grid.py [--orders 1 2 3] [--rays N] [--tile N] [--check N]
"""

from __future__ import annotations

import argparse
import itertools
import resource
import time

import numpy as np

import scenes
from mmwsim.tracer import DEFAULT_RAYS, Paths, Tracer


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def raw_embree_rate(scene, n: int = 2_000_000) -> float:
    """Rays per second of one bare embreex intersect call (float32 arrays prepared beforehand)."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.tile(scene.transmitter.array.astype(np.float32), (n, 1))
    caster = scene.ray_caster
    t = time.perf_counter()
    caster._scene.run(o, d, output=1)
    return n / (time.perf_counter() - t)


def brute_force_missed(tracer: Tracer, paths: Paths, rx_idx: np.ndarray) -> tuple[int, int]:
    """(paths found by brute force over all reflector sequences, of which missed) for some receivers."""
    rx = paths.rx[rx_idx]
    fr = tracer.reflectors.face_reflector
    got = set()
    for i in np.flatnonzero(np.isin(paths.rx_index, rx_idx)):
        got.add((int(paths.rx_index[i]), tuple(int(x) for x in fr[paths.faces[i, : paths.order[i]]])))
    ref = {(int(r), ()) for r in paths.rx_index[(paths.order == 0) & np.isin(paths.rx_index, rx_idx)]}
    brute = Tracer(tracer.scene, tracer.tx, tracer.max_reflections, 1)
    n_ref = tracer.reflectors.n
    for k in range(1, tracer.max_reflections + 1):
        seqs = np.array(
            [
                s
                for s in itertools.product(range(n_ref), repeat=k)
                if all(a != b for a, b in itertools.pairwise(s))
            ]
        )
        brute.shot.sequences[k] = seqs
        imgs = np.empty((len(seqs), k, 3))
        cur = np.broadcast_to(tracer.tx, (len(seqs), 3))
        for j in range(k):
            cur = tracer.reflectors.mirror(cur, seqs[:, j])
            imgs[:, j] = cur
        brute._images[k] = imgs
        step = max(1, 2_000_000 // len(rx))
        for a in range(0, len(seqs), step):
            s = np.arange(a, min(a + step, len(seqs)))
            out = brute._solve(k, np.repeat(s, len(rx)), np.tile(np.arange(len(rx)), len(s)), rx)
            ref |= {
                (int(rx_idx[r]), tuple(int(x) for x in q))
                for r, q in zip(out["rx"], out["refs"], strict=True)
            }
    return len(ref), len(ref - got)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orders", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--rays", type=int, default=DEFAULT_RAYS)
    ap.add_argument("--tile", type=int, default=65536)
    ap.add_argument("--check", type=int, default=0, help="receivers checked against brute force (slow)")
    args = ap.parse_args()
    scene = scenes.load("default")
    rx = scene.receivers.positions()
    outdoors = scene.outdoors(rx)
    raw = raw_embree_rate(scene)
    print(f"default scene: {scene.n_triangles} triangles, {len(rx)} receivers ({outdoors.sum()} outdoors)")
    print(f"raw embreex intersect: {raw / 1e6:.1f} Mrays/s")
    header = (
        f"{'K':>2} {'shoot s':>8} {'trace s':>8} {'total s':>8} {'peak GB':>8} {'cands':>18} {'paths/rx':>9}"
    )
    header += f" {'out/rx':>7} {'no path':>8} {'no path out':>11} {'Mrays/s':>8} {'% raw':>6}"
    print(header)
    for k in args.orders:
        t0 = time.perf_counter()
        tracer = Tracer(scene, None, k, args.rays)
        t1 = time.perf_counter()
        paths = Paths.concatenate([tracer.trace(rx[i : i + args.tile]) for i in range(0, len(rx), args.tile)])
        t2 = time.perf_counter()
        counts = paths.count()
        rate = tracer.rays_cast / (t2 - t0)
        cands = "/".join(str(c) for c in tracer.n_candidates[1:])
        print(
            f"{k:>2} {t1 - t0:8.1f} {t2 - t1:8.1f} {t2 - t0:8.1f} {peak_rss_gb():8.2f} {cands:>18}"
            f" {counts.mean():9.2f} {counts[outdoors].mean():7.2f} {(counts == 0).sum():8d}"
            f" {(counts[outdoors] == 0).sum():11d} {rate / 1e6:8.2f} {100 * rate / raw:6.0f}",
            flush=True,
        )
        if args.check and k == max(args.orders):
            rng = np.random.default_rng(0)
            sample = np.sort(rng.choice(np.flatnonzero(outdoors), args.check, replace=False))
            n, missed = brute_force_missed(tracer, paths, sample)
            print(f"brute force on {args.check} outdoor receivers, K={k}: {n} paths, {missed} missed")


if __name__ == "__main__":
    main()
