"""Tiny canonical scenes with closed-form answers, for physics tests.

Every scene has the transmitter at 10 m and a small receiver grid; lengths in metres.
"""

from __future__ import annotations

import numpy as np
import trimesh

from mmwsim.materials import get_material
from mmwsim.scene import ReceiverGrid, Scene, SceneObject, Transmitter

from .layout import ground_mesh

__all__ = ["free_space", "ground_only", "ground_wall", "street_canyon", "corner_reflector"]

_GRID = ReceiverGrid((-50.0, -50.0), 5.0, (21, 21), 1.5)


def wall(x0: float, y0: float, x1: float, y1: float, height: float) -> trimesh.Trimesh:
    """A vertical rectangle from (x0, y0) to (x1, y1), ``height`` tall: two triangles."""
    v = np.array([[x0, y0, 0.0], [x1, y1, 0.0], [x1, y1, height], [x0, y0, height]], dtype=np.float64)
    return trimesh.Trimesh(v, np.array([[0, 1, 2], [0, 2, 3]]), process=False)


def free_space(tx: tuple[float, float, float] = (0.0, 0.0, 10.0)) -> Scene:
    """No geometry at all: line of sight only."""
    bounds = np.array([[-100.0, -100.0, 0.0], [100.0, 100.0, 50.0]])
    return Scene([], Transmitter(tx), _GRID, name="free_space", source="free_space", bounds=bounds)


def ground_only(tx: tuple[float, float, float] = (0.0, 0.0, 10.0), material: str = "concrete") -> Scene:
    """A 1 km square ground plane at z = 0: line of sight and the two-ray ground reflection."""
    g = SceneObject("ground", ground_mesh(-500.0, -500.0, 500.0, 500.0), get_material(material), "ground")
    return Scene([g], Transmitter(tx), _GRID, name="ground_only", source="ground_only")


def ground_wall(
    tx: tuple[float, float, float] = (0.0, 0.0, 10.0), distance: float = 20.0, material: str = "concrete"
) -> Scene:
    """Ground plus one 30 m tall, 400 m long wall in the plane x = ``distance``."""
    mat = get_material(material)
    objects = [
        SceneObject("ground", ground_mesh(-500.0, -500.0, 500.0, 500.0), mat, "ground"),
        SceneObject("wall", wall(distance, -200.0, distance, 200.0, 30.0), mat, "other"),
    ]
    grid = ReceiverGrid((-50.0, -50.0), 5.0, (int((distance + 45) // 5), 21), 1.5)
    return Scene(objects, Transmitter(tx), grid, name="ground_wall", source="ground_wall")


def street_canyon(
    tx: tuple[float, float, float] = (0.0, 0.0, 10.0), width: float = 20.0, material: str = "concrete"
) -> Scene:
    """Ground and two parallel 25 m walls at y = +-width/2, 300 m long."""
    mat = get_material(material)
    h = width / 2
    objects = [
        SceneObject("ground", ground_mesh(-200.0, -100.0, 200.0, 100.0), mat, "ground"),
        SceneObject("wall_south", wall(-150.0, -h, 150.0, -h, 25.0), mat, "other"),
        SceneObject("wall_north", wall(150.0, h, -150.0, h, 25.0), mat, "other"),
    ]
    grid = ReceiverGrid((-100.0, -h + 1.0), 5.0, (41, max(1, int((width - 2) // 5) + 1)), 1.5)
    return Scene(objects, Transmitter(tx), grid, name="street_canyon", source="street_canyon")


def corner_reflector(tx: tuple[float, float, float] = (10.0, 5.0, 10.0), material: str = "metal") -> Scene:
    """Two perpendicular 40 m walls meeting at the origin (planes x = 0 and y = 0), no ground."""
    mat = get_material(material)
    objects = [
        SceneObject("wall_x", wall(0.0, 0.0, 0.0, 100.0, 40.0), mat, "other"),
        SceneObject("wall_y", wall(100.0, 0.0, 0.0, 0.0, 40.0), mat, "other"),
    ]
    grid = ReceiverGrid((5.0, 5.0), 5.0, (15, 15), 1.5)
    bounds = np.array([[0.0, 0.0, 0.0], [100.0, 100.0, 40.0]])
    return Scene(
        objects, Transmitter(tx), grid, name="corner_reflector", source="corner_reflector", bounds=bounds
    )
