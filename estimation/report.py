"""Outputs of an evaluation: the paper's two tables (Markdown), error-versus-length plots (PNG),
predicted against true trajectories (Rerun) and all numbers (JSON). Every file is written to a
temporary name and renamed into place."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from mmwsim.trajectories.motion import KINDS

from .errors import EstimationError
from .evaluation import Evaluation

__all__ = [
    "accuracy_table",
    "comparison_table",
    "cost_table",
    "plot_error_grid",
    "plot_error_vs_length",
    "write_report",
    "record_estimates",
    "log_estimates",
]

_KIND_ORDER = ("vehicle", "pedestrian", "hybrid", "static", "all")
_KIND_SHORT = {"vehicle": "veh.", "pedestrian": "ped.", "hybrid": "hyb.", "static": "stat."}


def _floor_first(methods: list[str]) -> list[str]:
    """``methods`` with the ``oracle`` floor (:mod:`estimation.oracle`) first, when present, so
    that every table opens with the best error reachable on the data."""
    return sorted(methods, key=lambda m: m != "oracle")


def _fmt(v: float) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.2f}"


def _hms(seconds: float) -> str:
    if seconds is None or math.isnan(seconds):
        return "–"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def accuracy_table(ev: Evaluation, split: str, task: str = "tracking") -> str:
    """Markdown: mean RMSE per kind (and the 95th percentile over all) per method and noise level,
    for ``table_length``-step sequences (tracking) or the forecast setting."""
    rows = [r for r in ev.rows if r["split"] == split and r["task"] == task]
    if task == "tracking":
        rows = (
            [r for r in rows if r["length"] == min(ev.table_length, max(x["length"] for x in rows))]
            if rows
            else []
        )
    if not rows:
        return ""
    kinds = [k for k in _KIND_ORDER if any(r["kind"] == k for r in rows)]
    head = ["Model", "Noise (dB)"] + [f"{k.capitalize()} mean (m)" for k in kinds] + ["All p95 (m)", "n"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    methods = _floor_first(list(dict.fromkeys(r["method"] for r in rows)))
    for m in methods:
        for sigma in sorted({r["sigma"] for r in rows if r["method"] == m}):
            by = {r["kind"]: r for r in rows if r["method"] == m and r["sigma"] == sigma}
            cells = [m, f"{sigma:g}"] + [_fmt(by[k]["mean"]) if k in by else "–" for k in kinds]
            cells += [_fmt(by["all"]["p95"]), str(by["all"]["n"])]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def comparison_table(
    ev: Evaluation,
    task: str,
    splits: list[str],
    noises: list[float],
    kinds: tuple[str, ...] = ("vehicle", "pedestrian", "all"),
    methods: list[str] | None = None,
    split_labels: dict[str, str] | None = None,
) -> str:
    """Markdown: one row per method, one column per (noise level, split, kind) holding the mean
    per-trajectory RMSE (m) at ``table_length`` steps (tracking) or of the forecast setting.

    ``methods`` orders the rows (default: as they appear in ``ev.rows``; a method without a row
    is left out); ``split_labels`` names the splits in the header (default the split names).
    Empty when ``ev`` has no row of ``task``.
    """
    rows = [r for r in ev.rows if r["task"] == task and r["split"] in splits and r["sigma"] in noises]
    if task == "tracking" and rows:
        length = min(ev.table_length, max(r["length"] for r in rows))
        rows = [r for r in rows if r["length"] == length]
    if not rows:
        return ""
    present = list(dict.fromkeys(r["method"] for r in rows))
    order = _floor_first([m for m in (methods or present) if m in present])
    labels = split_labels or {}
    columns = [
        (sigma, split, kind)
        for sigma in noises
        for split in splits
        if any(r["split"] == split and r["sigma"] == sigma for r in rows)
        for kind in kinds
    ]
    head = ["Method"] + [f"{s:g} dB {labels.get(sp, sp)} {_KIND_SHORT.get(k, k)}" for s, sp, k in columns]
    lines = ["| " + " | ".join(head) + " |", "|---|" + "---:|" * len(columns)]
    by = {(r["method"], r["sigma"], r["split"], r["kind"]): r["mean"] for r in rows}
    for m in order:
        cells = [_fmt(by[(m, *c)]) if (m, *c) in by else "–" for c in columns]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def cost_table(ev: Evaluation, extra: dict[str, str] | None = None) -> str:
    """Markdown: learnable parameters, training time and prediction time per method; ``extra``
    maps further keys of ``ev.cost`` entries to column headings (shown as text, ``–`` if absent)."""
    extra = extra or {}
    head = [
        "Model",
        "Parameters",
        "Training time (h:mm:ss)",
        "Epochs",
        f"Prediction time (s per 1000 sequences of {ev.table_length} steps)",
        *extra.values(),
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m in _floor_first(list(ev.cost)):
        c = ev.cost[m]
        more = "".join(f" {c.get(k, '–')} |" for k in extra)
        lines.append(
            f"| {m} | {c['parameters']:.3g} | {_hms(c['train_seconds'])} | {c['epochs'] or '–'} | "
            f"{c['predict_seconds']:.3f} |{more}"
        )
    return "\n".join(lines) + "\n"


def _error_panel(ax, rows: list[dict[str, Any]], kind: str, title: str, p95: bool = True) -> None:
    """One panel of error against sequence length: mean (solid) and, with ``p95``, the 95th
    percentile (dashed) of the tracking rows of ``kind``, one colour per method."""
    methods = list(dict.fromkeys(r["method"] for r in rows))
    for i, m in enumerate(methods):
        rs = sorted((r for r in rows if r["method"] == m and r["kind"] == kind), key=lambda r: r["length"])
        x = [r["length"] for r in rs]
        colour = f"C{i % 10}"
        style = "-o" if i < 10 else "-s"
        ax.plot(x, [r["mean"] for r in rs], style, ms=3, color=colour, label=f"{m} mean" if p95 else m)
        if p95:
            ax.plot(x, [r["p95"] for r in rs], "--", color=colour, alpha=0.7, label=f"{m} p95")
    ax.set_title(title)
    ax.set_xlabel("sequence length (steps)")
    ax.set_ylabel("RMSE (m)")
    ax.grid(alpha=0.3)


def _save_figure(fig, path: str | os.PathLike) -> None:
    import matplotlib.pyplot as plt

    from mmwsim.files import atomic_path

    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)


def plot_error_vs_length(ev: Evaluation, split: str, sigma: float, path: str | os.PathLike) -> bool:
    """PNG: mean (solid) and 95th-percentile (dashed) RMSE against sequence length, one panel per
    kind, one colour per method. Returns False if there is nothing to plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in ev.rows if r["split"] == split and r["sigma"] == sigma and r["task"] == "tracking"]
    kinds = [k for k in _KIND_ORDER if any(r["kind"] == k for r in rows)]
    if not rows:
        return False
    ncols = min(3, len(kinds))
    nrows = -(-len(kinds) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.4 * ncols, 3.5 * nrows), squeeze=False)
    axes = axes.ravel()
    for ax, k in zip(axes, kinds, strict=False):
        _error_panel(ax, rows, k, f"{k} ({split}, {sigma:g} dB)")
    for ax in axes[len(kinds) :]:
        ax.axis("off")
    axes[0].legend(fontsize=7, ncol=1)
    fig.tight_layout()
    _save_figure(fig, path)
    return True


def plot_error_grid(
    ev: Evaluation,
    panels: list[tuple[str, float]],
    path: str | os.PathLike,
    kinds: tuple[str, ...] = ("vehicle", "pedestrian", "all"),
    p95: bool = False,
    methods: list[str] | None = None,
    split_labels: dict[str, str] | None = None,
    log_y: bool = False,
) -> bool:
    """PNG: tracking RMSE against sequence length in a grid of panels, one row per
    ``(split, sigma)`` of ``panels`` and one column per kind; the mean (solid) and, with ``p95``,
    the 95th percentile (dashed); one colour per method, in the order of ``methods`` (default as
    they appear); ``log_y`` for a logarithmic error axis. Rows without data are left out; returns
    False if nothing is plotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in ev.rows if r["task"] == "tracking"]
    if methods is not None:
        rows = sorted((r for r in rows if r["method"] in methods), key=lambda r: methods.index(r["method"]))
    panels = [(sp, s) for sp, s in panels if any(r["split"] == sp and r["sigma"] == s for r in rows)]
    if not panels:
        return False
    labels = split_labels or {}
    fig, axes = plt.subplots(
        len(panels), len(kinds), figsize=(4.4 * len(kinds), 3.3 * len(panels)), squeeze=False
    )
    for (split, sigma), line in zip(panels, axes, strict=True):
        sel = [r for r in rows if r["split"] == split and r["sigma"] == sigma]
        for ax, k in zip(line, kinds, strict=True):
            _error_panel(ax, sel, k, f"{k}, {labels.get(split, split)}, {sigma:g} dB", p95=p95)
            if log_y:
                ax.set_yscale("log")
                ax.grid(alpha=0.3, which="both")
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, loc="upper center", ncol=min(len(names), 6), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / (3.3 * len(panels)) * (1 + (len(names) - 1) // 6)))
    _save_figure(fig, path)
    return True


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in text)


def _write_text(path: Path, text: str) -> None:
    from mmwsim.files import write_text_atomic

    write_text_atomic(path, text)


def write_report(ev: Evaluation, out: str | os.PathLike, noises: list[float]) -> list[Path]:
    """Write ``accuracy.md``, ``cost.md``, ``error_vs_length_<split>_<sigma>dB.png`` and
    ``results.json`` into folder ``out``; returns the written paths."""
    from mmwsim.faults import fault
    from mmwsim.locks import locked_output

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise EstimationError(f"{out}: exists and is not a folder (choose another --out)")
    # One writer per report folder; a folder made here is removed again if writing fails.
    with locked_output(out, "report folder", create=True):
        fault("report.write", out)
        return _write_report(ev, out, noises)


def _write_report(ev: Evaluation, out: Path, noises: list[float]) -> list[Path]:
    splits = list(dict.fromkeys(r["split"] for r in ev.rows))
    written = []
    parts = []
    for split in splits:
        t = accuracy_table(ev, split, "tracking")
        if t:
            parts.append(
                f"## Tracking accuracy, {ev.table_length}-step sequences, split `{split}`\n\n"
                "Mean per-trajectory RMSE by kind; 95th percentile over all kinds.\n\n" + t
            )
        f = accuracy_table(ev, split, "forecasting")
        if f:
            parts.append(f"## Forecasting accuracy, split `{split}`\n\n" + f)
    p = out / "accuracy.md"
    _write_text(p, "# Trajectory estimation accuracy\n\n" + "\n".join(parts))
    written.append(p)
    p = out / "cost.md"
    _write_text(
        p, "# Model size and run time\n\nTimes on this machine; noisy when it is shared.\n\n" + cost_table(ev)
    )
    written.append(p)
    for split in splits:
        for sigma in noises:
            p = out / f"error_vs_length_{_slug(split)}_{sigma:g}dB.png"
            if plot_error_vs_length(ev, split, sigma, p):
                written.append(p)
    p = out / "results.json"
    _write_text(
        p,
        json.dumps(
            {"table_length": ev.table_length, "rows": ev.rows, "cost": ev.cost, "knn_kalman_fit": ev.fitted},
            indent=1,
            default=float,
        ),
    )
    written.append(p)
    return written


def record_estimates(ev: Evaluation, path: str | os.PathLike, footprints=None) -> None:
    """Rerun recording of predicted against true trajectories: ``trajectories/<split>-<i>/{true,<model>}``
    as 2D line strips (static) and the current position on the ``step`` timeline."""
    from mmwsim.recording import Recording

    with Recording(path, "evaluation", families=("trajectories",)) as rec:
        log_estimates(rec, ev, footprints)


def log_estimates(rec: Any, ev: Evaluation, footprints=None) -> None:
    """Log the entities of :func:`record_estimates` into an open ``mmwsim.recording.Recording``.

    True tracks are near-white, each model has a colour of its own (the Trajectories legend says
    which); labels show on hover, as there are many tracks.
    """
    import rerun as rr

    from mmwsim.recording import Entity, log_legend, log_map_context, log_track, north_up

    north_up(rec, Entity.TRAJECTORIES)
    if footprints:
        strips = [np.asarray(p.exterior.coords) for p in footprints]
        north_up(rec, Entity.MAP)
        rec.log(Entity.FOOTPRINTS, rr.LineStrips2D(strips, colors=[(110, 110, 118)], radii=0.3), static=True)
        shown = [
            np.asarray(v, dtype=np.float64).reshape(-1, 2)
            for ex in ev.examples.values()
            for k, v in ex.items()
            if k != "kind"
        ]
        log_map_context(
            rec, Entity.TRAJECTORIES, footprints, np.concatenate(shown) if shown else np.zeros((0, 2))
        )
    colours: dict[str, tuple[int, int, int]] = {}
    for split, ex in ev.examples.items():
        true = ex["true"]
        sources = {"true": true} | {k: v for k, v in ex.items() if k not in ("true", "kind")}
        for j, src in enumerate(sources):
            colours.setdefault(src, TRUE_RGB if src == "true" else _colour(j - 1))
        for i in range(len(true)):
            ident = f"{_slug(split)}-{i}"
            label = KINDS[int(ex["kind"][i])]
            for src, arr in sources.items():
                log_track(
                    rec,
                    Entity.trajectory(ident, src),
                    arr[i],
                    colours[src],
                    f"{split} {i}: {label} {src}",
                    width=2.5 if src == "true" else 1.8,
                    head=5.0,
                )
    log_legend(
        rec,
        "trajectories",
        "sources",
        "tracks (step timeline: dots)",
        [(src if src == "true" else f"{src} estimate", c) for src, c in colours.items()],
    )


TRUE_RGB = (235, 235, 235)
"""True trajectories: near-white on the viewer's dark background."""


def _colour(j: int) -> tuple[int, int, int]:
    """Colour of the j-th model: bright enough for the dark theme, apart from white (true)."""
    palette = [
        (80, 160, 255),
        (255, 150, 50),
        (90, 210, 110),
        (240, 80, 90),
        (190, 130, 255),
        (240, 200, 60),
        (80, 210, 210),
        (255, 120, 200),
    ]
    return palette[j % len(palette)]
