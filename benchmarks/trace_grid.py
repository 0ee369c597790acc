"""Trace the whole 401 x 401 receiver grid of the default scene: specular, with diffraction, with diffuse.

For each mode prints wall time, peak memory (RSS), paths per outdoor receiver by kind,
receivers without any path, the seconds per stage (shooting, candidate cells, exact solve,
diffraction) and the rays cast per second against raw embreex measured in the same run.
Optionally checks a random sample of receivers against a brute-force image method over every
reflector sequence (specular paths only; slow; ``--check N``).

    python benchmarks/trace_grid.py [--modes specular diffraction diffuse] [--diffuse-s 0.4]
                                    [--spacing 1] [--rays N] [--tile N] [--check N]
"""

from __future__ import annotations

import argparse
import itertools
import resource
import time

import numpy as np
from _common import raw_embree_rate

import scenes
from mmwsim.stages import STAGES
from mmwsim.tracer import DEFAULT_RAYS, PathKind, Paths, Tracer

KINDS = ("line of sight", "reflected", "diffracted", "diffuse")


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def brute_force_missed(tracer: Tracer, paths: Paths, rx_idx: np.ndarray) -> tuple[int, int]:
    """(specular paths found by brute force over all reflector sequences, of which missed) for some receivers."""
    rx = paths.rx[rx_idx]
    fr = tracer.reflectors.face_reflector
    specular = paths.kind() <= PathKind.REFLECTED
    got = set()
    for i in np.flatnonzero(np.isin(paths.rx_index, rx_idx) & specular):
        got.add((int(paths.rx_index[i]), tuple(int(x) for x in fr[paths.faces[i, : paths.order[i]]])))
    ref = {(int(r), ()) for r in paths.rx_index[(paths.order == 0) & np.isin(paths.rx_index, rx_idx)]}
    n_ref = tracer.reflectors.n
    for k in range(1, tracer.max_reflections + 1):
        seqs = np.array(
            [
                s
                for s in itertools.product(range(n_ref), repeat=k)
                if all(a != b for a, b in itertools.pairwise(s))
            ]
        )
        imgs = np.empty((len(seqs), k, 3))
        cur = np.broadcast_to(tracer.tx, (len(seqs), 3))
        for j in range(k):
            cur = tracer.reflectors.mirror(cur, seqs[:, j])
            imgs[:, j] = cur
        step = max(1, 2_000_000 // len(rx))
        for a in range(0, len(seqs), step):
            s = np.arange(a, min(a + step, len(seqs)))
            out = tracer.solver.solve(
                tracer.tx, seqs, imgs, np.repeat(s, len(rx)), np.tile(np.arange(len(rx)), len(s)), rx
            )
            for b in out:
                fr_b = fr[b.faces]
                ref |= {(int(rx_idx[r]), tuple(int(x) for x in q)) for r, q in zip(b.rx, fr_b, strict=True)}
    return len(ref), len(ref - got)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--modes",
        nargs="+",
        default=["specular", "diffraction"],
        choices=["specular", "diffraction", "diffuse"],
    )
    ap.add_argument(
        "--diffuse-s", type=float, default=0.4, help="scattering coefficient of every material (diffuse mode)"
    )
    ap.add_argument("--spacing", type=float, default=1.0)
    ap.add_argument("--max-reflections", type=int, default=3)
    ap.add_argument("--rays", type=int, default=DEFAULT_RAYS)
    ap.add_argument("--tile", type=int, default=16384)
    ap.add_argument("--check", type=int, default=0, help="receivers checked against brute force (slow)")
    args = ap.parse_args()
    base = scenes.load("default")
    grid = base.receivers.with_spacing(args.spacing)
    rx = grid.positions()
    outdoors = base.outdoors(rx)
    rx_out = rx[outdoors]
    raw = raw_embree_rate(base)
    print(
        f"default scene: {base.n_triangles} triangles, {len(rx)} receivers at {args.spacing:g} m ({len(rx_out)} outdoors)"
    )
    print(
        f"raw embreex intersect: {raw / 1e6:.1f} Mrays/s; {args.max_reflections} interactions, {args.rays} rays"
    )
    for mode in args.modes:
        scene = base.with_scattering(args.diffuse_s) if mode == "diffuse" else base
        STAGES.take()
        t0 = time.perf_counter()
        tracer = Tracer(scene, None, args.max_reflections, args.rays, diffraction=mode != "specular")
        parts = [tracer.trace(rx_out[i : i + args.tile]) for i in range(0, len(rx_out), args.tile)]
        paths = Paths.concatenate(parts)
        wall = time.perf_counter() - t0
        stages = STAGES.take()
        counts = paths.count()
        by_kind = np.bincount(paths.kind(), minlength=4) / len(rx_out)
        rate = tracer.rays_cast / wall
        print(f"\n[{mode}] wall {wall:.1f} s, peak RSS {peak_rss_gb():.2f} GB, {paths.n_paths} paths")
        print(
            f"  paths per outdoor receiver {counts.mean():.2f} ("
            + ", ".join(f"{k} {v:.2f}" for k, v in zip(KINDS, by_kind, strict=True))
            + ")"
        )
        print(f"  outdoor receivers without any path: {int((counts == 0).sum())} of {len(rx_out)}")
        print(
            f"  rays cast {tracer.rays_cast / 1e6:.1f} M, {rate / 1e6:.2f} Mrays/s ({100 * rate / raw:.0f} % of raw embreex)"
        )
        for name, sec in sorted(stages.items(), key=lambda kv: -kv[1]):
            print(f"  {name:<24}{sec:8.1f} s {100 * sec / wall:6.1f} %")
        if args.check and mode == "specular":
            rng = np.random.default_rng(0)
            sample = np.sort(rng.choice(len(rx_out), args.check, replace=False))
            n, missed = brute_force_missed(tracer, paths, sample)
            print(f"  brute force on {args.check} outdoor receivers: {n} specular paths, {missed} missed")


if __name__ == "__main__":
    main()
