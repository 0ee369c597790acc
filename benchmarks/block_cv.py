"""Spatial block cross-validation of tn-match, knn-kalman and match-cv, beside the single held-out region.

Usage: python benchmarks/block_cv.py DATASET [--block 100] [--folds 4] [--train-minutes M]
       [--max-trajectories N] [--sigma 6] [--length 7] [--methods tn-match knn-kalman match-cv]
       [--out DIR]

The data set's stored trajectories (all splits) are dealt to ``--folds`` folds of ``--block`` m
squares (:func:`mmwsim.trajectories.block_folds`: a Latin pattern, so every fold mixes streets in
line of sight and shadowed ones). For each fold, tn-match is built on the trajectories that never
touch the fold's blocks (its motion tables measured on them, as training does; with
``--train-minutes`` the network is also trained on them for at most that long) and every method
tracks the fold's trajectories (each trajectory is tested in exactly one fold: the one holding its
middle sample). The same procedure on the data set's own split (train / validation, tested on
``test/seen`` and ``test/holdout``) gives the seen-area and single-region rows.

Prints, per fold and pooled: mean per-trajectory RMSE (vehicle / pedestrian / all, ``--length``
steps at ``--sigma`` dB, the same noise draws for every method), the pooled figure of the
trajectories wholly inside their fold's blocks, and each test set's line-of-sight share (of its
samples' nearest grid points, line of sight = a stored path without interaction) against the whole
area's, and the error split by the trajectories' line-of-sight share. Then it ranks single blocks
as a hold-out region by how close both the mix of the trajectories that touch them (line-of-sight,
street and vehicle shares) and their block-CV error are to the whole area's (how the demo's region
was chosen: a mix that matches is not enough, blocks of the same mix differ by 2x in error).

Resumable: each fold's errors are kept in ``DIR/<fold>.npz`` (with the settings they were made
with) and a killed run redoes only the missing folds; a fold's training run continues from its
checkpoint. ``--max-trajectories N`` evaluates a seeded uniform subset of ``N x folds``
trajectories of the whole set (so folds keep their relative sizes) and at most N of each
stored test split.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

KIND_COLUMNS = ("vehicle", "pedestrian", "all")
STORED = ("train", "validation", "test")


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--block", type=float, default=100.0, help="block side, metres (default 100)")
    ap.add_argument("--folds", type=int, default=4, help="number of folds (default 4)")
    ap.add_argument(
        "--train-minutes",
        type=float,
        default=0.0,
        help="train tn-match's network per fold for at most this long (default 0: motion tables only)",
    )
    ap.add_argument("--max-trajectories", type=int, default=300, metavar="N", help="per fold (default 300)")
    ap.add_argument("--sigma", type=float, default=6.0, help="fingerprint noise, dB (default 6)")
    ap.add_argument("--length", type=int, default=7, help="steps tracked (default 7)")
    ap.add_argument("--methods", nargs="+", default=["tn-match", "knn-kalman", "match-cv"])
    ap.add_argument(
        "--out", default="block-cv", help="folder for per-fold results and runs (default block-cv)"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--region",
        action="append",
        default=[],
        metavar="X0,Y0,X1,Y1",
        help="also redo the data set's split with this hold-out region and test it (repeatable)",
    )
    return ap


def line_of_sight(ds) -> np.ndarray:
    """(n_rx,) bool: whether each grid receiver has a stored path without interaction."""
    p = ds.root["grid/paths"]
    start = np.asarray(p["start"][:], dtype=np.int64)
    count = np.asarray(p["count"][:], dtype=np.int64)
    order = np.asarray(p["order"][:])
    rx = np.repeat(np.arange(len(count)), count)
    slot = np.repeat(start, count) + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    los = np.zeros(len(count), dtype=bool)
    los[rx[order[slot] == 0]] = True
    return los


def street_mask(ds, xy: np.ndarray) -> np.ndarray:
    """(...) bool: points within the street half-width of the scene's vehicle street centre lines."""
    import shapely

    from mmwsim.trajectories import StreetNetwork

    half = 4.0
    net = StreetNetwork.from_scene(ds.scene())
    streets = shapely.union_all(shapely.linestrings(net.lines())).buffer(half)
    shapely.prepare(streets)
    flat = xy.reshape(-1, 2)
    return shapely.contains_xy(streets, flat[:, 0], flat[:, 1]).reshape(xy.shape[:-1])


def _tn_match(train_set, val_set, args, run: Path, log):
    """tn-match fitted on ``train_set``: the trainer's own construction (motion tables measured on
    the training trajectories); trained for ``--train-minutes`` when given."""
    from estimation import Estimator, TrainConfig, train
    from estimation.training import _build_estimator

    cfg = TrainConfig(
        model="tn-match",
        epochs=100,
        patience=4,
        sigma=args.sigma,
        seed=args.seed,
        max_length=args.length,
        epoch_size=2048,
    )
    if args.train_minutes <= 0:
        return _build_estimator(cfg, train_set, val_set), 0
    summary = train(
        train_set,
        val_set,
        cfg,
        run,
        resume=(run / "checkpoint.pt").exists(),
        progress=False,
        record=False,
        log=lambda s: log(f"    {s}"),
        time_limit=60 * args.train_minutes,
    )
    return Estimator.load(run), int(summary["epochs"])


def _errors(methods, est, test_sets, val_set, args, log) -> dict[str, dict[str, np.ndarray]]:
    """Per test set and method: per-trajectory RMSE (n,), metres, on one noise draw per set."""
    from estimation import noisy_bits, trajectory_rmse
    from estimation.evaluation import NetworkMethod, method

    out: dict[str, dict[str, np.ndarray]] = {}
    for si, (name, data) in enumerate(test_sets.items()):
        bits = noisy_bits(data, args.sigma, torch.Generator().manual_seed(args.seed * 1_000_003 + si))
        out[name] = {}
        for m in methods:
            t0 = time.perf_counter()
            meth = NetworkMethod(est, m) if m == "tn-match" else method(m, fit_length=args.length)
            pred = meth.for_sigma(args.sigma, val_set).predict_lengths(bits, [args.length])[args.length][0]
            out[name][m] = trajectory_rmse(pred, data.positions[:, : args.length])
            log(f"    {name}: {m} {out[name][m].mean():.3f} m ({data.n}, {time.perf_counter() - t0:.0f} s)")
    return out


def _row(err: np.ndarray, kind: np.ndarray) -> str:
    from mmwsim.trajectories import KINDS

    parts = []
    for k in KIND_COLUMNS:
        e = err if k == "all" else err[kind == KINDS.index(k)]
        parts.append(f"{e.mean():.3f}" if len(e) else "  -  ")
    return " / ".join(parts)


def _ci(err: np.ndarray, seed: int = 2) -> str:
    boot = np.random.default_rng(seed).integers(0, len(err), (2000, len(err)))
    lo, hi = np.percentile(err[boot].mean(1), [2.5, 97.5])
    return f"{lo:.3f} .. {hi:.3f}"


def rank_blocks(folds, t, sample_los, streets, idx, err) -> tuple[np.ndarray, list]:
    """Single blocks as a hold-out region: for each, the line-of-sight, street and vehicle shares of
    the trajectories touching it (its test set) and the block-CV error of the trajectories whose
    middle sample lies in it, per method; scored by how far both are from the whole area's
    (summed absolute share differences plus the mean absolute log error ratio over the methods)."""
    from mmwsim.trajectories import KINDS, touches_region

    vehicle = t.kind == KINDS.index("vehicle")
    whole = np.array([sample_los.mean(), streets.mean(), vehicle.mean()])
    pooled = np.array([e.mean() for e in err.values()])
    ny, nx = folds.block_fold.shape
    origin = np.asarray(folds.bounds[:2])
    cell = np.floor((t.positions[idx, t.length // 2] - origin) / folds.block).astype(int)
    cell = np.clip(cell, 0, [nx - 1, ny - 1])
    rows = []
    for f in range(folds.n_folds):
        for region in folds.blocks(f):
            hit = touches_region(t.positions, region)
            i, j = np.rint((np.asarray(region[:2]) - origin) / folds.block).astype(int)
            inb = (cell[:, 0] == i) & (cell[:, 1] == j)
            if not hit.any() or not inb.any():
                continue
            mix = np.array([sample_los[hit].mean(), streets[hit].mean(), vehicle[hit].mean()])
            cv = np.array([e[inb].mean() for e in err.values()])
            score = np.abs(mix - whole).sum() + np.abs(np.log(cv / pooled)).mean()
            rows.append((float(score), region, int(hit.sum()), mix, cv, int(inb.sum())))
    rows.sort(key=lambda r: r[0])
    return whole, rows


def main() -> None:
    ap = _parser()
    args = ap.parse_args()
    torch.set_num_threads(1)
    from estimation import GridTable, sequence_set
    from estimation.adapter import dataset_threshold, open_dataset
    from mmwsim.cli import parse_vector
    from mmwsim.errors import MmwsimError
    from mmwsim.trajectories import KINDS, Trajectories, block_folds, read_trajectories, split
    from mmwsim.trajectories.splits import check_region

    if args.max_trajectories < 1 or args.length < 2 or args.train_minutes < 0:
        ap.error("--max-trajectories must be >= 1, --length >= 2 and --train-minutes >= 0")
    try:
        args.region = [check_region(parse_vector(r, 4, "--region")) for r in args.region]
        ds = open_dataset(args.dataset)
        parts = [read_trajectories(ds.path, s) for s in STORED]
        t = Trajectories.concatenate(parts)
        folds = block_folds(t, args.block, args.folds)
    except MmwsimError as e:
        raise SystemExit(f"error: {e}") from None
    if args.length > t.length:
        raise SystemExit(f"error: --length {args.length}: the trajectories have {t.length} steps")
    stored = np.repeat(np.arange(len(STORED)), [len(p) for p in parts])
    holdout = np.concatenate([p.holdout for p in parts])
    los_rx = line_of_sight(ds)
    sample_los = los_rx[ds.nearest(t.positions)]  # (n, L)
    traj_los = sample_los.mean(1)  # share of each trajectory's samples in line of sight

    log = lambda s: print(s, flush=True)  # noqa: E731
    log(
        f"{args.dataset}: {len(t)} trajectories of {t.length} steps; {args.folds} folds of "
        f"{args.block:g} m blocks; tracking {args.length} steps at {args.sigma:g} dB; tn-match "
        + (
            f"trained up to {args.train_minutes:g} min per fold"
            if args.train_minutes
            else "motion tables refit"
        )
    )
    log("fold of each block (rows from the top, y down):")
    for row in folds.block_fold[::-1]:
        log("  " + " ".join(str(v) for v in row))

    table = GridTable(ds)
    everything = sequence_set(table, t.positions, t.kind_names, dataset_threshold(ds))
    pick = np.zeros(len(t), dtype=bool)
    pick[np.random.default_rng(args.seed).permutation(len(t))[: args.max_trajectories * args.folds]] = True
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = {
        k: getattr(args, k)
        for k in ("block", "folds", "train_minutes", "max_trajectories", "sigma", "length", "seed")
    }
    settings |= {"dataset": str(getattr(ds, "content_hash", "")), "methods": args.methods, "n": len(t)}

    def fit_and_test(name: str, train_idx, val_idx, test_sets: dict[str, np.ndarray], region=None):
        path = out / f"{name}.npz"
        mine = settings | {"region": None if region is None else list(region)}
        if path.exists():
            got = np.load(path, allow_pickle=False)
            if json.loads(str(got["settings"])) == mine:
                log(f"  {name}: reusing {path}")
                return {k: {m: got[f"{k}|{m}"] for m in args.methods} for k in test_sets}
        t0 = time.perf_counter()
        train_set, val_set = everything.subset(train_idx), everything.subset(val_idx)
        log(f"  {name}: fitting on {len(train_idx)} trajectories (validation {len(val_idx)})")
        est, epochs = _tn_match(train_set, val_set, args, out / f"run-{name}", log)
        sets = {k: everything.subset(v) for k, v in test_sets.items()}
        errs = _errors(args.methods, est, sets, val_set, args, log)
        flat = {f"{k}|{m}": e for k, d in errs.items() for m, e in d.items()}
        tmp = out / f".{name}.npz"
        np.savez(tmp, settings=json.dumps(mine), **flat)
        tmp.replace(path)
        log(f"  {name}: done in {time.perf_counter() - t0:.0f} s ({epochs} epochs)")
        return errs

    rng = np.random.default_rng(args.seed + 1)
    results: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]] = {}
    for f in range(args.folds):
        free = rng.permutation(folds.train(f))
        n_val = max(1, len(free) // 10)
        test = folds.test(f)
        test = test[pick[test]]
        errs = fit_and_test(f"fold{f}", np.sort(free[n_val:]), np.sort(free[:n_val]), {"test": test})
        results[f"fold {f}"] = (test, errs["test"])

    # Single hold-out regions: the data set's own split, and the same split redone (as the data set's
    # generation did it: its seed and shares, the trajectories in generation order) with each
    # --region held out, fitted and tested the same way as the folds.
    def cap(idx, salt):
        rng_ = np.random.default_rng([args.seed, salt])
        return (
            np.sort(rng_.permutation(idx)[: args.max_trajectories])
            if len(idx) > args.max_trajectories
            else idx
        )

    attrs = parts[2].attrs
    splits = [("split", attrs.get("holdout_region"), stored, holdout)]
    order = np.argsort(t.ids)
    for k, reg in enumerate(args.region):
        redo = split(
            t.subset(order), attrs.get("split_fractions", (0.8, 0.1, 0.1)), attrs.get("split_seed", 0), reg
        )
        where = np.empty(len(t), dtype=np.int64)
        held = np.zeros(len(t), dtype=bool)
        for code, name in enumerate(STORED):
            at = order[np.searchsorted(t.ids[order], redo[name].ids)]
            where[at], held[at] = code, redo[name].holdout
        splits.append((f"region{k}", reg, where, held))
    for name, reg, where, held in splits:
        seen = cap(np.flatnonzero((where == 2) & ~held), 1)
        region = cap(np.flatnonzero((where == 2) & held), 2)
        tests = {"seen": seen, "region": region} if len(region) else {"seen": seen}
        errs = fit_and_test(name, np.flatnonzero(where == 0), np.flatnonzero(where == 1), tests, reg)
        label = ",".join(f"{v:g}" for v in reg) if reg else "none"
        results[f"seen area (hold-out {label})"] = (seen, errs["seen"])
        if len(region):
            results[f"held-out region {label}"] = (region, errs["region"])

    # The tables.
    all_los = sample_los.mean()
    vehicle = KINDS.index("vehicle")
    log(
        f"\nmean per-trajectory RMSE, m (vehicle / pedestrian / all), {args.length} steps, {args.sigma:g} dB; "
        f"line-of-sight share of the test samples (whole area {all_los:.2f}) and vehicle share"
    )
    header = f"{'test set':<34} {'n':>5} {'LOS':>5} {'veh':>5}  " + "  ".join(
        f"{m:<22}" for m in args.methods
    )
    log(header)

    def line(label, idx, err):
        cells = "  ".join(f"{_row(err[m], t.kind[idx]):<22}" for m in args.methods)
        los = sample_los[idx].mean()
        log(f"{label:<34} {len(idx):>5} {los:>5.2f} {(t.kind[idx] == vehicle).mean():>5.2f}  {cells}")

    pooled_idx, pooled = [], {m: [] for m in args.methods}
    for label, (idx, err) in results.items():
        if label.startswith("fold"):
            blocks = folds.blocks(int(label.split()[1]))
            line(f"{label} ({len(blocks)} blocks)", idx, err)
            pooled_idx.append(idx)
            for m in args.methods:
                pooled[m].append(err[m])
    idx = np.concatenate(pooled_idx)
    err = {m: np.concatenate(v) for m, v in pooled.items()}
    line("block CV, pooled", idx, err)
    inside = folds.inside[idx]
    line("block CV, wholly inside the fold", idx[inside], {m: e[inside] for m, e in err.items()})
    for label in [k for k in results if not k.startswith("fold")]:
        line(label, *results[label])

    log("\nmean (95 % bootstrap interval over trajectories), all kinds:")
    others = [k for k in results if not k.startswith("fold")]
    for label, e in [("block CV, pooled", err)] + [(k, results[k][1]) for k in others]:
        log(f"  {label:<40} " + "  ".join(f"{m} {e[m].mean():.3f} ({_ci(e[m])})" for m in args.methods))
    seen_label = next(k for k in others if k.startswith("seen area"))
    log("\nheld-out over seen-area error, all kinds (block CV against the first seen area):")
    for label, e in [("block CV, pooled", err)] + [
        (k, results[k][1]) for k in others if k.startswith("held")
    ]:
        ref = (
            seen_label
            if label.startswith("block")
            else label.replace("held-out region", "seen area (hold-out") + ")"
        )
        log(
            f"  {label:<40} "
            + "  ".join(f"{m} {e[m].mean() / results[ref][1][m].mean():.2f}x" for m in args.methods)
        )
    log("\npooled block CV by the test trajectory's line-of-sight share (all kinds):")
    for lo, hi, label in ((0, 0.5, "mostly shadowed"), (0.5, 1.01, "mostly in line of sight")):
        m_ = (traj_los[idx] >= lo) & (traj_los[idx] < hi)
        log(
            f"  {label:<24} {m_.sum():>5}  " + "  ".join(f"{m} {err[m][m_].mean():.3f}" for m in args.methods)
        )

    streets = street_mask(ds, t.positions)
    whole, ranked = rank_blocks(folds, t, sample_los, streets, idx, err)
    log(
        f"\nsingle blocks as a hold-out region: LOS / street / vehicle share of the trajectories touching it "
        f"(whole area {whole[0]:.2f} / {whole[1]:.2f} / {whole[2]:.2f}) and the block-CV error of those "
        f"with their middle sample in it ({' / '.join(args.methods)}; pooled "
        + " / ".join(f"{e.mean():.2f}" for e in err.values())
        + "), best match first"
    )
    for score, reg, n, mix, cv, n_in in ranked:
        log(
            f"  {','.join(f'{v:g}' for v in reg):<16} {n:>5} touching  {mix[0]:.2f} / {mix[1]:.2f} / {mix[2]:.2f}"
            f"   {n_in:>4} tested  " + " / ".join(f"{v:.2f}" for v in cv) + f"   score {score:.2f}"
        )


if __name__ == "__main__":
    main()
