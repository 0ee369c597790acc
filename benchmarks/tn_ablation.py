"""Why the paper's transformer was at 7.5 m: train ``tn`` variants under one budget, tabulate.

    python benchmarks/tn_ablation.py DATA.zarr --out DIR [--budget-minutes 8] [--variants ...]
        [--no-diffraction DATA2.zarr] [--max-trajectories 1000]

Each variant changes one thing of ``tn``'s default (or, ``paper``, all of them back to the paper's
configuration) and is trained on the same trajectories under the same wall-clock budget, epochs of
2048 trajectories, crops of 2..7 steps (the default's recipe shortened to the budget, see
``_common.budget_settings``), then evaluated on the same noisy fingerprints of the seen test
trajectories (7 steps, 6 dB). ``no-diffraction`` trains the default on a data set traced without
diffraction (give it with ``--no-diffraction``; same scene, trajectories and splits expected).
Resumable: finished variants are skipped, interrupted ones resume on the rest of their budget.
Writes DIR/ablation.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from _common import budget_settings

# name -> (what it changes, TrainConfig settings, network options)
VARIANTS: dict[str, tuple[str, dict, dict]] = {
    "default": ("tn as it ships", {}, {}),
    "regression": (
        "direct regression of the coordinates, not cells",
        {"loss": "mse"},
        {"head": "regression"},
    ),
    "narrow": ("the paper's width: d 48, 2 heads, feed-forward 96", {}, {"d": 48, "heads": 2, "ff": 96}),
    "factorised": ("the paper's small factorised embedding, not the bag", {}, {"embedding": "factorised"}),
    "no-warmup": ("sequences from the first epoch", {"warmup_epochs": 0}, {}),
    "plateau": ("learning rate halved on plateaus, not cosine", {"schedule": "plateau"}, {}),
    "decoder": ("the paper's parallel decoder after the encoder", {}, {"decoder": "parallel"}),
    "paper": (
        "the paper's configuration: factorised embedding, d 48, 2 heads, encoder-decoder, post-norm, "
        "regression, plateau schedule, no warm-up",
        {"loss": "mse", "warmup_epochs": 0, "schedule": "plateau", "epochs": 1000},
        "PAPER",
    ),
    "no-diffraction": ("the default on fingerprints traced without diffraction", {}, {}),
}


def log(text: str) -> None:
    print(text, flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--out", required=True)
    ap.add_argument("--budget-minutes", type=float, default=8.0)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--no-diffraction", help="data set of the same scene traced without diffraction")
    ap.add_argument(
        "--max-trajectories", type=int, default=1000, help="seen test trajectories (default 1000)"
    )
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)

    import numpy as np
    import torch

    from estimation import TrainConfig, evaluate, method, train
    from estimation.adapter import load_splits
    from estimation.models import PAPER_OPTIONS

    torch.set_num_threads(args.threads)
    out = Path(args.out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    budget = 60.0 * args.budget_minutes
    loaded: dict[str, dict] = {}
    results: dict[str, dict] = {}
    for name in args.variants:
        what, settings, options = VARIANTS[name]
        data = args.dataset
        if name == "no-diffraction":
            if not args.no_diffraction:
                log(f"{name}: skipped (no --no-diffraction data set)")
                continue
            data = args.no_diffraction
        if data not in loaded:
            sets, _ = load_splits(data, ("train", "validation", "test/seen"))
            loaded[data] = sets
        sets = loaded[data]
        options = dict(PAPER_OPTIONS) if options == "PAPER" else dict(options)
        base = budget_settings("tn", args.budget_minutes)
        cfg = TrainConfig(model="tn", epoch_size=2048, max_length=7, options=options, **(base | settings))
        run = out / "runs" / name
        result_file = out / f"{name}.json"
        if result_file.exists():
            results[name] = json.loads(result_file.read_text())
            log(f"{name}: done before")
            continue
        spent = 0.0
        if (run / "checkpoint.pt").exists():
            from estimation.checkpoint import CHECKPOINT_FORMAT, load_checkpoint

            spent = float(
                sum(
                    load_checkpoint(run / "checkpoint.pt", CHECKPOINT_FORMAT, ("history",))["history"][
                        "seconds"
                    ]
                )
            )
        log(
            f"{name}: {what}; training ({cfg.epochs} epochs, {cfg.warmup_epochs} warm-up, {budget - spent:.0f} s left)"
        )
        summary = train(
            sets["train"],
            sets["validation"],
            cfg,
            run,
            resume=True,
            progress=False,
            record=False,
            log=lambda text: None,
            time_limit=max(budget - spent, 0.0),
        )
        test = sets["test/seen"]
        test = test.subset(np.sort(np.random.default_rng(0).permutation(test.n)[: args.max_trajectories]))
        t0 = time.perf_counter()
        ev = evaluate(
            [method(run)],
            {"test/seen": test},
            [6.0],
            sets["validation"],
            lengths=[7],
            n_examples=0,
            progress=False,
            log=lambda text: None,
        )
        rows = {r["kind"]: r["mean"] for r in ev.rows if r["length"] == 7}
        results[name] = {
            "what": what,
            "parameters": summary["parameters"],
            "epochs": summary["epochs"],
            "train_seconds": summary["train_seconds"],
            "best_epoch": summary["best_epoch"],
            "rmse": rows,
            "evaluate_seconds": time.perf_counter() - t0,
        }
        result_file.write_text(json.dumps(results[name], indent=1))
        log(
            f"{name}: vehicle {rows.get('vehicle', float('nan')):.2f} pedestrian {rows.get('pedestrian', float('nan')):.2f} "
            f"all {rows['all']:.2f} m ({summary['epochs']} epochs, {summary['train_seconds']:.0f} s)"
        )
    lines = [
        f"# tn ablation: {args.budget_minutes:g}-minute budget per variant, 7-step seen test trajectories, 6 dB\n",
        "| Variant | What changes | Vehicle (m) | Pedestrian (m) | All (m) | Parameters | Epochs | Training (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        m = r["rmse"]
        lines.append(
            f"| {name} | {r['what']} | {m.get('vehicle', float('nan')):.2f} | {m.get('pedestrian', float('nan')):.2f} "
            f"| {m['all']:.2f} | {r['parameters']:.2g} | {r['epochs']} | {r['train_seconds']:.0f} |"
        )
    (out / "ablation.md").write_text("\n".join(lines) + "\n")
    log(f"wrote {out / 'ablation.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
