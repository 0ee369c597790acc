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
        help="scene (catalogue name or file): for a data set, where to load its scene from if not from "
        "the name it stores (it must be the same scene); for a missing DATASET folder, the scene of a new "
        "store holding only trajectories",
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
    """The scene, the data set (None for a trajectory-only store) and the store path of DATASET."""
    from ..dataset import Dataset
    from ..dataset.store import partial_path
    from ..scene import load_scene
    from ..trajectories import is_trajectory_store

    path = Path(args.dataset)
    if not path.exists() or is_trajectory_store(path):
        if partial_path(path).exists():
            raise MmwsimError(
                f"{path}: the data set is not finished ({partial_path(path).name}); "
                "complete it with mmwsim generate --resume"
            )
        if args.scene is None:
            if path.exists():
                raise MmwsimError(f"{path}: holds trajectories only (no data set); give --scene")
            raise MmwsimError(f"{path}: data set not found (give --scene to create a trajectory-only store)")
        return load_scene(args.scene), None, path
    ds = Dataset.open(path)
    try:
        scene = ds.scene(args.scene)
    except MmwsimError as e:
        if args.scene is not None:
            raise
        raise MmwsimError(f"{path}: cannot load the data set's scene: {e} (give --scene)") from None
    return scene, ds, path


def _run(args) -> int:
    from ..files import RECORDING_SUFFIX, check_output_folder, check_suffix, writing
    from ..locks import OutputLock
    from ..recording import Recording
    from ..trajectories import generate_for_dataset, log_trajectories, split, write_trajectories
    from ..trajectories.generate import generate
    from ..trajectories.splits import check_fractions, check_region
    from . import parse_vector

    fractions = parse_vector(args.split, 3, "--split")
    try:
        check_fractions(fractions)
    except MmwsimError as e:
        raise MmwsimError(f"--split {args.split}: {e}") from None
    region = (
        check_region(parse_vector(args.holdout_region, 4, "--holdout-region"))
        if args.holdout_region
        else None
    )
    if args.rrd:
        check_suffix(args.rrd, RECORDING_SUFFIX, "--rrd")
        check_output_folder(args.rrd, "--rrd")
    if args.show < 0:
        raise MmwsimError(f"--show must be >= 0, got {args.show}")
    counts = {
        "pedestrian": args.pedestrian,
        "vehicle": args.vehicle,
        "hybrid": args.hybrid,
        "static": args.static,
    }
    models = _overrides(args.set)
    scene, ds, path = _open(args)
    (x0, y0), (x1, y1) = scene.receivers.bounds if ds is None else ds.grid.bounds
    if region is not None and (region[2] <= x0 or region[0] >= x1 or region[3] <= y0 or region[1] >= y1):
        raise MmwsimError(
            f"--holdout-region {args.holdout_region}: lies outside the area {x0:g},{y0:g},{x1:g},{y1:g}"
        )
    options = dict(rate_hz=args.rate, vehicles_on_streets=args.streets, models=models)
    if ds is None:
        with writing(path.parent):
            path.parent.mkdir(parents=True, exist_ok=True)
    with OutputLock(path, "store"):  # a second writer is refused now, not after the generation
        if ds is None:
            trajectories = generate(scene, counts, args.length, args.seed, **options)
        else:
            trajectories = generate_for_dataset(ds, counts, args.length, args.seed, scene=scene, **options)
        parts = split(trajectories, fractions, seed=args.seed, holdout_region=region)
        write_trajectories(path if ds is None else ds, parts)
    if args.rrd:
        with Recording(
            args.rrd, "trajectories", families=("trajectories",), config=trajectories.attrs
        ) as rec:
            log_trajectories(rec, trajectories, scene, max_shown=args.show)
    sizes = ", ".join(f"{name} {len(t)}" for name, t in parts.items())
    where = (
        "the trajectory-only store" if ds is None else f"the data set ({int(ds.valid.sum())} valid points)"
    )
    print(
        f"wrote {len(trajectories)} trajectories of {args.length} steps to {path}/trajectories "
        f"in {where}: {sizes}"
    )
    if region is not None:
        print(f"hold-out region {region}: {int(parts['test'].holdout.sum())} trajectories, all in test")
    if args.rrd:
        print(f"wrote {args.rrd}")
    return 0
