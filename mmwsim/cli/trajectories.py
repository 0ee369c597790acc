"""``mmwsim trajectories DATASET ...``: generate user trajectories, split them, store them in the
data set and optionally record them."""

from __future__ import annotations

from pathlib import Path

from ..errors import MmwsimError


def register(sub) -> None:
    p = sub.add_parser(
        "trajectories",
        help="generate user trajectories and store them in a data set",
        description="Generate pedestrian / hybrid / vehicle / static trajectories in the data set's scene, "
        "split them into train / validation / test and store them as trajectories/<split> in the data set.",
    )
    p.add_argument("dataset", help="data set (zarr folder)")
    p.add_argument("--pedestrian", type=int, default=0, metavar="N", help="number of pedestrian trajectories")
    p.add_argument("--vehicle", type=int, default=0, metavar="N", help="number of vehicle trajectories")
    p.add_argument("--hybrid", type=int, default=0, metavar="N", help="number of hybrid trajectories")
    p.add_argument("--static", type=int, default=0, metavar="N", help="number of static trajectories")
    p.add_argument(
        "--length", type=int, default=7, metavar="L", help="samples per trajectory, 3..30 (default 7)"
    )
    p.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    p.add_argument("--rate", type=float, default=1.0, metavar="HZ", help="samples per second (default 1)")
    p.add_argument(
        "--split",
        default="0.8,0.1,0.1",
        metavar="TR,VA,TE",
        help="train,validation,test shares (default 0.8,0.1,0.1)",
    )
    p.add_argument(
        "--holdout-region",
        metavar="X0,Y0,X1,Y1",
        help="rectangle (metres) whose trajectories go only to the test split",
    )
    p.add_argument("--streets", action="store_true", help="vehicles keep to the street network")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KIND.PARAM=VALUE",
        help="override a motion parameter, e.g. vehicle.mean_speed=10 (repeatable)",
    )
    p.add_argument(
        "--scene",
        help="scene (catalogue name or file) when the data set does not name one; with it, a missing "
        "DATASET folder is created holding only the trajectories",
    )
    p.add_argument("--rrd", help="also write a Rerun recording of the trajectories (.rrd)")
    p.add_argument("--show", type=int, default=200, metavar="N", help="trajectories shown in the recording")
    p.set_defaults(func=_run)


def _overrides(items: list[str]) -> dict:
    from ..trajectories import KINDS, motion_model

    models = {}
    for item in items:
        key, sep, value = item.partition("=")
        kind, dot, param = key.partition(".")
        if not sep or not dot or kind not in KINDS:
            raise MmwsimError(
                f"--set {item!r}: expected KIND.PARAM=VALUE with KIND one of {', '.join(KINDS)}"
            )
        model = models.get(kind, motion_model(kind))
        if param not in model.as_dict() or param == "kind":
            raise MmwsimError(f"--set {item!r}: unknown motion parameter {param!r}")
        try:
            number = float(value)
        except ValueError:
            raise MmwsimError(f"--set {item!r}: {value!r} is not a number") from None
        models[kind] = model.replace(**{param: number})
    return models


def _open(args):
    """Scene, coverage mask and store path of DATASET (adapter to mmwsim.dataset)."""
    from ..scene import load_scene
    from ..trajectories import CoverageMask

    path = Path(args.dataset)
    scene = load_scene(args.scene) if args.scene else None
    if not path.exists():
        if scene is None:
            raise MmwsimError(f"{path}: data set not found (give --scene to create a trajectory-only store)")
        return scene, None, path
    if not (path / "zarr.json").exists():
        raise MmwsimError(f"{path}: not a data set (no zarr.json)")
    try:
        from ..dataset import Dataset  # type: ignore[attr-defined]
    except ImportError:
        Dataset = None
    coverage = None
    if Dataset is not None:
        try:
            ds = Dataset.open(path)
        except MmwsimError:
            if scene is None:
                raise
            ds = None
        if ds is not None:
            if scene is None:
                scene = getattr(ds, "scene", None)
                if callable(scene):
                    scene = scene()
            if scene is None and getattr(getattr(ds, "config", None), "scene", None):
                # The resolved generate config names the scene and the transmitter it was traced with.
                cfg = ds.config
                scene = load_scene(cfg.scene, transmitter=getattr(cfg, "transmitter", None))
            if getattr(ds, "valid", None) is not None:
                coverage = CoverageMask(ds.grid, ds.valid)
    if scene is None:
        raise MmwsimError(f"{path}: cannot tell the data set's scene; give --scene")
    return scene, coverage, path


def _run(args) -> int:
    from ..recording import Recording
    from ..trajectories import generate, log_trajectories, split, write_trajectories
    from ..trajectories.splits import check_region
    from . import parse_vector

    fractions = parse_vector(args.split, 3, "--split")
    region = (
        check_region(parse_vector(args.holdout_region, 4, "--holdout-region"))
        if args.holdout_region
        else None
    )
    if args.rrd and not args.rrd.endswith(".rrd"):
        raise MmwsimError(f"{args.rrd}: a recording must end in .rrd")
    counts = {
        "pedestrian": args.pedestrian,
        "vehicle": args.vehicle,
        "hybrid": args.hybrid,
        "static": args.static,
    }
    models = _overrides(args.set)
    scene, coverage, path = _open(args)
    if region is not None:
        (x0, y0), (x1, y1) = scene.receivers.bounds
        if region[2] <= x0 or region[0] >= x1 or region[3] <= y0 or region[1] >= y1:
            raise MmwsimError(
                f"--holdout-region {args.holdout_region}: lies outside the area {x0:g},{y0:g},{x1:g},{y1:g}"
            )
    trajectories = generate(
        scene,
        counts,
        args.length,
        args.seed,
        rate_hz=args.rate,
        coverage=coverage,
        vehicles_on_streets=args.streets,
        models=models,
    )
    parts = split(trajectories, fractions, seed=args.seed, holdout_region=region)
    if args.rrd:
        with Recording(
            args.rrd, "trajectories", families=("trajectories",), config=trajectories.attrs
        ) as rec:
            log_trajectories(rec, trajectories, scene, max_shown=args.show)
    write_trajectories(path, parts)
    sizes = ", ".join(f"{name} {len(t)}" for name, t in parts.items())
    held = int(parts["test"].holdout.sum())
    print(f"wrote {len(trajectories)} trajectories of {args.length} steps to {path}/trajectories: {sizes}")
    if region is not None:
        print(f"hold-out region {region}: {held} trajectories, all in test")
    if args.rrd:
        print(f"wrote {args.rrd}")
    return 0
