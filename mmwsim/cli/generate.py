"""``mmwsim generate SCENE``: the beamformed-fingerprint data set of a scene."""

from __future__ import annotations

from .osm_area import add_area_arguments, scene_spec
from .physics import add_physics_arguments


def register(sub) -> None:
    p = sub.add_parser(
        "generate",
        help="trace a scene's receiver grid and write the fingerprint data set (zarr)",
        description="Trace every receiver of the grid in tiles and write per-beam power-delay profiles "
        "and the paths to a zarr store; resumable, same bytes for any number of workers.",
    )
    p.add_argument("scene", help="catalogue name (default, manhattan:seed=3, ...) or a scene file")
    p.add_argument("--tx", help="transmitter position X,Y,Z in metres (default: the scene's)")
    p.add_argument("--out", help="output store directory (default: <scene name>.zarr)")
    p.add_argument("--spacing", type=float, help="receiver spacing in metres (default: the scene's grid)")
    add_physics_arguments(p)
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="local worker processes (default: one per available core, at most 4)",
    )
    p.add_argument("--resume", action="store_true", help="continue an unfinished run of the same config")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run tiles on this Dask scheduler")
    p.add_argument("--rrd", metavar="FILE", help="also write a Rerun recording (.rrd) of the data set")
    p.add_argument("--tile-size", type=int, default=4096, help="receivers per tile (default 4096)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_area_arguments(p)
    p.set_defaults(func=_generate)


def default_workers() -> int:
    """One worker per core this process may run on, at most 4 (each holds a tile, about 1 GB)."""
    from .._threads import cores

    return max(1, min(cores(), 4))


def _default_out(scene: str) -> str:
    import re
    from pathlib import Path

    stem = Path(scene).stem if ("/" in scene or "." in scene) else scene
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", stem) + ".zarr"


def _generate(args) -> int:
    import time

    from ..dataset import Dataset
    from ..dataset.generate import generate
    from . import parse_vector

    scene = scene_spec(args)
    out = args.out or _default_out(args.scene)
    t0 = time.perf_counter()
    path = generate(
        scene,
        out,
        spacing=args.spacing,
        max_reflections=args.max_reflections,
        workers=args.workers if args.workers is not None else default_workers(),
        resume=args.resume,
        scheduler=args.scheduler,
        rrd=args.rrd,
        progress=not args.quiet,
        tile_size=args.tile_size,
        n_rays=args.rays,
        transmitter=parse_vector(args.tx, 3, "--tx") if args.tx else None,
        diffraction=not args.no_diffraction,
        diffuse=args.diffuse,
    )
    ds = Dataset.open(path)
    print(f"wrote {path}: {ds!r} in {time.perf_counter() - t0:.1f} s")
    if args.rrd:
        print(f"wrote {args.rrd}")
    return 0
