"""Procedural Manhattan-style cities: a street grid, lots and extruded buildings, seedable."""

from __future__ import annotations

import numpy as np

from mmwsim.materials import get_material
from mmwsim.scene import ReceiverGrid, Scene, SceneObject, Transmitter

from .layout import StreetPlan, building_mesh, ground_mesh, plan_buildings

__all__ = ["manhattan_city", "random_plan", "scene_from_plan"]


def random_plan(
    rng: np.random.Generator,
    size: tuple[float, float] = (400.0, 400.0),
    avenue_spacing: tuple[float, float] = (110.0, 180.0),
    street_spacing: tuple[float, float] = (60.0, 90.0),
    width: tuple[float, float] = (10.0, 30.0),
) -> StreetPlan:
    """A street grid: avenues (along y) and streets (along x) with widths drawn from ``width`` m."""

    def strips(length: float, spacing: tuple[float, float]) -> tuple[tuple[float, float], ...]:
        out, pos = [], rng.uniform(0.3, 0.7) * spacing[0]
        while pos < length - 10.0:
            w = float(np.round(rng.uniform(*width) * 2) / 2)
            out.append((float(np.round(pos * 2) / 2), float(np.round(pos * 2) / 2) + w))
            pos += w + rng.uniform(*spacing)
        return tuple(out)

    return StreetPlan(size, strips(size[0], avenue_spacing), strips(size[1], street_spacing))


def scene_from_plan(plan: StreetPlan, buildings, name: str, tx: tuple[float, float, float] | None) -> Scene:
    """Objects ``ground`` and ``building_NNN`` (concrete) over ``plan.size``, with a 1 m grid."""
    concrete = get_material("concrete")
    objects = [SceneObject("ground", ground_mesh(0.0, 0.0, *plan.size), concrete, "ground")]
    width = len(str(max(len(buildings) - 1, 0)))
    for i, b in enumerate(buildings):
        objects.append(SceneObject(f"building_{i:0{width}d}", building_mesh([b]), concrete, "building"))
    nx, ny = (int(np.floor(s)) + 1 for s in plan.size)
    grid = ReceiverGrid((0.0, 0.0), 1.0, (nx, ny), 1.5)
    return Scene(objects, Transmitter(tx) if tx else None, grid, name=name, source=name)


def manhattan_city(
    seed: int = 0,
    size: tuple[float, float] = (400.0, 400.0),
    median_height: float = 24.0,
    tx_height: float = 10.0,
    tx: tuple[float, float, float] | None = None,
) -> Scene:
    """A random Manhattan-style city.

    Streets are 10-30 m wide, blocks filled with lots of 14-36 m, building heights
    log-normal (median ``median_height``, clipped to 6-150 m). The transmitter
    stands at ``tx_height`` in the intersection nearest the centre.

    Parameters
    ----------
    seed : int
        Same seed, same city (bit for bit).
    size : (2,) float
        Extent in metres.
    """
    rng = np.random.default_rng(seed)
    plan = random_plan(rng, size)
    buildings = [b for blk in plan.blocks() for b in plan_buildings(blk, rng, median_height)]
    cx = min(plan.avenues, key=lambda s: abs(sum(s) / 2 - size[0] / 2), default=(size[0] / 2,) * 2)
    cy = min(plan.streets, key=lambda s: abs(sum(s) / 2 - size[1] / 2), default=(size[1] / 2,) * 2)
    tx = tx or (sum(cx) / 2, sum(cy) / 2, tx_height)
    return scene_from_plan(plan, buildings, f"manhattan:seed={seed}", tx)
