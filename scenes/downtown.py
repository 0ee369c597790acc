"""The embedded default scene: a 400 m x 400 m downtown in the spirit of the reference area.

A Manhattan grid around a campus: a 34 m avenue (x 184-218) crossed by a 26 m
street (y 190-216) at the centre, where the transmitter stands on a 10 m mast at
(200, 203) with line of sight down all four arms; narrower avenues and streets
beyond; a campus quad of low buildings and a park. The scene files in
``scenes/default/`` are written by :func:`write_default` and shipped as package data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .layout import Building, StreetPlan, building_mesh, ground_mesh, plan_buildings

__all__ = ["DOWNTOWN_PLAN", "downtown_buildings", "write_default"]

DOWNTOWN_PLAN = StreetPlan(
    size=(400.0, 400.0),
    avenues=((52.0, 74.0), (184.0, 218.0), (318.0, 342.0)),
    streets=((34.0, 52.0), (112.0, 128.0), (190.0, 216.0), (276.0, 292.0), (356.0, 372.0)),
)
CAMPUS_BLOCK = (218.0, 216.0, 318.0, 276.0)
PARK_BLOCK = (74.0, 292.0, 184.0, 356.0)
SEED = 28


def downtown_buildings() -> list[Building]:
    """The buildings of the default scene, deterministic."""
    rng = np.random.default_rng(SEED)
    out: list[Building] = []
    for blk in DOWNTOWN_PLAN.blocks():
        if blk == PARK_BLOCK:
            out.append(Building(120.0, 318.0, 136.0, 330.0, 6.0))  # pavilion
            continue
        if blk == CAMPUS_BLOCK:
            x0, y0, x1, y1 = blk
            out += [
                Building(x0 + 4, y0 + 4, x0 + 34, y0 + 18, 16.0),
                Building(x1 - 30, y0 + 4, x1 - 4, y0 + 22, 20.0),
                Building(x0 + 36, y1 - 16, x1 - 36, y1 - 4, 24.0),  # library on the quad's far side
            ]
            continue
        out += plan_buildings(blk, rng, median_height=26.0)
    return out


SCENE_TOML = """\
# The embedded default scene, written by scenes.downtown.write_default().
name = "default"
description = "400 m x 400 m Manhattan-style downtown around a campus; TX on a 10 m mast at the central intersection"
frequency_ghz = 28.0

[[objects]]
name = "ground"
mesh = "ground.ply"
material = "concrete"
kind = "ground"

[[objects]]
name = "building"
mesh = "buildings.ply"
material = "concrete"
kind = "building"
split = true

[transmitter]
position = [200.0, 203.0, 10.0]
power_dbm = 30.0

[receivers]
origin = [0.0, 0.0]
spacing = 1.0
shape = [401, 401]
height = 1.5
"""


def write_default(folder: str | Path) -> None:
    """Write ``scene.toml``, ``ground.ply`` and ``buildings.ply`` of the default scene to ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    ground_mesh(0.0, 0.0, 400.0, 400.0).export(folder / "ground.ply", encoding="binary")
    building_mesh(downtown_buildings()).export(folder / "buildings.ply", encoding="binary")
    (folder / "scene.toml").write_text(SCENE_TOML)


if __name__ == "__main__":
    write_default(Path(__file__).parent / "default")
