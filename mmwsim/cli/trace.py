"""``mmwsim trace``: exact paths (line of sight, reflections, diffraction) from a transmitter to receivers."""

from __future__ import annotations

import csv
import gc
import json
import math
import os
import re
from pathlib import Path

import numpy as np

from ..constants import DEFAULT_RAYS
from ..errors import MmwsimError
from ..files import check_suffix, write_text_atomic
from .osm_area import add_area_arguments, scene_spec
from .physics import add_physics_arguments, check_diffuse

_TABLE_LIMIT = 20  # receivers printed in full; more get a summary


def register(sub) -> None:
    p = sub.add_parser(
        "trace",
        help="trace the paths from a transmitter to receivers",
        description="Every path of line of sight, specular reflections, one edge diffraction (with "
        "reflections before and after it) and diffuse scattering off rough surfaces (the last "
        "interaction) up to --max-reflections interactions, solved exactly.",
    )
    p.add_argument("scene", help="catalogue name (default, manhattan:seed=3, ...) or a .toml/.xml/mesh file")
    p.add_argument("--tx", help="transmitter position X,Y,Z in metres (default: the scene's)")
    rx = p.add_mutually_exclusive_group(required=True)
    rx.add_argument("--rx", action="append", help="receiver position X,Y,Z in metres (repeatable)")
    rx.add_argument("--rx-file", help="CSV file of receivers with the header x,y,z")
    add_physics_arguments(p)
    p.add_argument(
        "--min-gain",
        type=float,
        default=-180.0,
        metavar="DB",
        help="drop paths weaker than this for every polarisation pair, dB (default -180)",
    )
    p.add_argument("--json", help="write the paths as JSON to this file")
    p.add_argument("--rrd", help="write a Rerun recording of the paths to this .rrd file")
    # Let "--rx -20,-6,1.5" through: argparse only treats plain numbers as negatives by default.
    p._negative_number_matcher = re.compile(r"^-\.?\d[\d.,eE+-]*$")
    add_area_arguments(p)
    p.set_defaults(func=_run)


def read_receivers(path: str | os.PathLike) -> np.ndarray:
    """Receivers from a CSV file with the header ``x,y,z``; (n, 3) float64, metres."""
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as e:
        raise MmwsimError(f"{path}: cannot read receiver file ({e.strerror})") from None
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows or [c.strip().lower() for c in rows[0]] != ["x", "y", "z"]:
        raise MmwsimError(f"{path}: the first line must be the header x,y,z")
    if len(rows) == 1:
        raise MmwsimError(f"{path}: no receivers after the header")
    out = np.empty((len(rows) - 1, 3))
    for i, row in enumerate(rows[1:]):
        try:
            values = [float(c) for c in row]
        except ValueError:
            raise MmwsimError(
                f"{path}, line {i + 2}: expected three numbers, got {','.join(row)!r}"
            ) from None
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise MmwsimError(f"{path}, line {i + 2}: expected three finite numbers, got {','.join(row)!r}")
        out[i] = values
    return out


def _run(args) -> int:
    from ..scene import load_scene
    from ..tracer import Tracer
    from . import parse_vector

    tx = np.array(parse_vector(args.tx, 3, "--tx")) if args.tx else None
    if args.rx_file:
        rx = read_receivers(args.rx_file)
    else:
        rx = np.array([parse_vector(r, 3, "--rx") for r in args.rx])
    n_rays = DEFAULT_RAYS if args.rays is None else args.rays
    if n_rays < 1:
        raise MmwsimError(f"--rays must be positive, got {n_rays}")
    if not 0 <= args.max_reflections <= 6:
        raise MmwsimError(f"--max-reflections must be from 0 to 6, got {args.max_reflections}")
    for flag, target, suffix in (("--json", args.json, ".json"), ("--rrd", args.rrd, ".rrd")):
        if target:
            t = check_suffix(target, suffix, flag)
            if not t.parent.is_dir() or not os.access(t.parent, os.W_OK):
                raise MmwsimError(f"{flag} {t}: folder {t.parent} does not exist or is not writable")
    diffuse = check_diffuse(args.diffuse)
    scene = load_scene(scene_spec(args))
    if diffuse is not None:
        scene = scene.with_scattering(diffuse)
    if tx is None:
        if scene.transmitter is None:
            raise MmwsimError(f"scene {scene.name!r} has no transmitter; give --tx X,Y,Z")
        tx = scene.transmitter.array
    scene.check_transmitter(tx)
    lo, hi = scene.extent
    off = np.any(rx[:, :2] < lo[:2], axis=1) | np.any(rx[:, :2] > hi[:2], axis=1) | (rx[:, 2] <= lo[2])
    if off.any():
        i = int(np.flatnonzero(off)[0])
        raise MmwsimError(
            f"receiver {i + 1} at ({', '.join(f'{v:g}' for v in rx[i])}) is outside the scene "
            f"(x {lo[0]:g}..{hi[0]:g}, y {lo[1]:g}..{hi[1]:g}, above z {lo[2]:g})"
        )
    outside = ~scene.outdoors(rx)
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        raise MmwsimError(
            f"receiver {i + 1} at ({', '.join(f'{v:g}' for v in rx[i])}) is inside a building"
            + (f" ({int(outside.sum())} receivers are)" if outside.sum() > 1 else "")
        )
    if not math.isfinite(args.min_gain):
        raise MmwsimError(f"--min-gain must be a finite number of dB, got {args.min_gain}")
    tracer = Tracer(
        scene,
        tx,
        args.max_reflections,
        n_rays,
        diffraction=not args.no_diffraction,
        min_gain_db=args.min_gain,
    )
    paths = tracer.trace(rx)
    names = [o.name for o in scene.objects]
    print(_report(paths, names))
    if args.json:
        _write_json(Path(args.json), paths, names)
        print(f"wrote {args.json}")
    if args.rrd:
        # Rerun is loaded only when a recording is asked for.
        from ..recording import Recording, log_scene
        from ..tracer.record import log_candidates, log_path_context, log_paths

        with Recording(
            args.rrd,
            "trace",
            families=("world",),
            extent=scene.extent,
            config={
                "scene": scene.source or scene.name,
                "tx": tx.tolist(),
                "max_reflections": args.max_reflections,
                "diffraction": not args.no_diffraction,
                "diffuse": diffuse,
                "min_gain_db": args.min_gain,
            },
        ) as rec:
            log_scene(rec, scene)
            shown = np.arange(min(len(rx), _TABLE_LIMIT))
            log_paths(rec, paths, shown)
            log_path_context(rec, paths.select(np.isin(paths.rx_index, shown)), tracer.wedges)
            log_candidates(rec, tracer)
        print(f"wrote {args.rrd}")
    return 0


_TYPE_NAMES = ("none", "reflection", "diffraction", "diffuse")


def _write_json(path: Path, paths, names: list[str]) -> None:
    """Paths per receiver as JSON, built as text column by column (no object per path)."""
    # The strings made here hold no cycles; pausing the collector saves a third of the time
    # it would spend walking every object the imports made.
    gc.disable()
    try:
        _write_json_text(path, paths, names)
    finally:
        gc.enable()


def _write_json_text(path: Path, paths, names: list[str]) -> None:
    gain = paths.gain_db("V", "V")
    k = paths.order.astype(np.int64)
    cols = np.arange(paths.faces.shape[1])
    real = cols[None, :] < k[:, None]
    quoted = np.array([json.dumps(n) for n in names] + ['""'], dtype=object)
    kinds = np.array([f'"{t}"' for t in _TYPE_NAMES], dtype=object)
    obj = np.where(real, paths.objects, len(names))
    inter = _join_rows(quoted[obj], real)
    types = _join_rows(kinds[paths.types.astype(np.int64)], real)
    aod, aoa = np.degrees(paths.aod).tolist(), np.degrees(paths.aoa).tolist()
    gains = [repr(g) if math.isfinite(g) else "null" for g in gain.tolist()]
    records = [
        f'{{"delay_s":{d!r},"gain_db":{g},"aod":[{a[0]!r},{a[1]!r}],"aoa":[{b[0]!r},{b[1]!r}],'
        f'"interactions":[{i}],"interaction_types":[{t}]}}'
        for d, g, a, b, i, t in zip(paths.delay.tolist(), gains, aod, aoa, inter, types, strict=True)
    ]
    off = paths.offsets().tolist()
    rx = paths.rx.tolist()
    body = ",\n".join(
        f'{{"position":[{p[0]!r},{p[1]!r},{p[2]!r}],"paths":[{",".join(records[a:b])}]}}'
        for p, a, b in zip(rx, off[:-1], off[1:], strict=True)
    )
    write_text_atomic(path, '{"receivers":[\n' + body + "\n]}\n")


def _join_rows(cells: np.ndarray, real: np.ndarray) -> list[str]:
    """Comma-joined strings of the first ``real`` cells of each row (m, K) of an object array."""
    out = np.full(len(cells), "", dtype=object)
    for j in range(cells.shape[1]):
        sep = np.where(j > 0, ",", "")
        out = np.where(real[:, j], out + sep + cells[:, j], out)
    return out.tolist()


def _report(paths, names: list[str]) -> str:
    counts = paths.count()
    lines = [f"{paths.n_paths} paths to {paths.n_rx} receivers"]
    if paths.n_rx <= _TABLE_LIMIT:
        gain = paths.gain_db("V", "V")
        off = paths.offsets()
        for j in range(paths.n_rx):
            lines.append(
                f"receiver {j + 1} at ({', '.join(f'{v:g}' for v in paths.rx[j])}): {counts[j]} paths"
            )
            if counts[j]:
                lines.append(
                    f"  {'delay ns':>10} {'gain dB':>8} {'AoD th,ph':>13} {'AoA th,ph':>13}  interactions"
                )
            for i in range(off[j], off[j + 1]):
                k = int(paths.order[i])
                inter = " > ".join(
                    names[o] + (" (diffraction)" if t == 2 else " (diffuse)" if t == 3 else "")
                    for o, t in zip(paths.objects[i, :k], paths.types[i, :k], strict=True)
                )
                inter = inter or "line of sight"
                aod, aoa = np.degrees(paths.aod[i]), np.degrees(paths.aoa[i])
                lines.append(
                    f"  {1e9 * paths.delay[i]:10.3f} {gain[i]:8.2f} {aod[0]:6.1f},{aod[1]:6.1f}"
                    f" {aoa[0]:6.1f},{aoa[1]:6.1f}  {inter}"
                )
    else:
        by_order = np.bincount(paths.order, minlength=paths.max_reflections + 1)
        by_kind = np.bincount(paths.kind(), minlength=4)
        lines.append(
            f"  paths per receiver: mean {counts.mean():.2f}, max {counts.max()}; "
            f"receivers without a path: {int((counts == 0).sum())}"
        )
        lines.append("  by interactions: " + ", ".join(f"{k}: {n}" for k, n in enumerate(by_order)))
        lines.append(
            "  by kind: "
            + ", ".join(
                f"{name} {n}"
                for name, n in zip(
                    ("line of sight", "reflected", "diffracted", "diffuse"), by_kind, strict=True
                )
            )
        )
    return "\n".join(lines)
