"""``mmwsim scene show|export|record``."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..errors import MmwsimError
from .osm_area import add_area_arguments, scene_spec


def register(sub) -> None:
    p = sub.add_parser("scene", help="inspect, export and record scenes")
    ss = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "scene", help="catalogue name (default, manhattan:seed=3, ...) or a .toml/.xml/mesh file"
    )
    common.add_argument("--tx", help="transmitter position X,Y,Z in metres (overrides the scene's)")
    show = ss.add_parser("show", parents=[common], help="print a summary")
    show.set_defaults(func=_show)
    add_area_arguments(show)
    export = ss.add_parser("export", parents=[common], help="write all meshes as one mesh file")
    export.add_argument("--out", required=True, help="output file; format by suffix (.ply .obj .glb .stl)")
    export.set_defaults(func=_export)
    add_area_arguments(export)
    record = ss.add_parser("record", parents=[common], help="write a Rerun recording of the scene")
    record.add_argument("--rrd", required=True, help="output .rrd file")
    record.set_defaults(func=_record)
    add_area_arguments(record)
    names = ss.add_parser("list", help="list the catalogue")
    names.set_defaults(func=_list)


def _load(args):
    from ..scene import load_scene
    from . import parse_vector

    tx = parse_vector(args.tx, 3, "--tx") if args.tx else None
    return load_scene(scene_spec(args), transmitter=tx)


def _show(args) -> int:
    print(_load(args).summary())
    return 0


def _export(args) -> int:
    out = Path(args.out)
    if out.suffix.lower() not in {".ply", ".obj", ".glb", ".stl", ".off"}:
        raise MmwsimError(f"{out}: unsupported export format {out.suffix!r} (use .ply .obj .glb .stl .off)")
    if not out.parent.is_dir() or not os.access(out.parent, os.W_OK):
        raise MmwsimError(f"{out}: folder {out.parent} does not exist or is not writable")
    from ..files import atomic_path

    scene = _load(args)
    with atomic_path(out) as tmp:
        scene.merged_mesh().export(tmp)
    print(f"wrote {out} ({scene.n_triangles} triangles)")
    return 0


def _record(args) -> int:
    from ..recording import Recording, log_scene

    scene = _load(args)
    with Recording(
        args.rrd,
        "scene",
        families=("world",),
        config={"scene": scene.source or scene.name},
        extent=scene.extent,
    ) as rec:
        log_scene(rec, scene)
    print(f"wrote {args.rrd}")
    return 0


def _list(args) -> int:
    from ..scene.catalogue import scene_names

    for name in scene_names():
        print(name)
    return 0
