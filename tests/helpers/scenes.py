"""Builders of small scene folders for tests."""

from __future__ import annotations

import textwrap
from pathlib import Path

import trimesh

from scenes.layout import Building, building_mesh, ground_mesh


def two_buildings() -> trimesh.Trimesh:
    """Two boxes: (10..30, 10..20, 0..15) and (40..50, 30..60, 0..25)."""
    return building_mesh([Building(10, 10, 30, 20, 15.0), Building(40, 30, 50, 60, 25.0)])


def write_scene_folder(folder: Path, toml_body: str | None = None) -> Path:
    """A TOML scene with a ground plane and two buildings; returns the .toml path."""
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    ground_mesh(0, 0, 100, 100).export(folder / "meshes" / "ground.ply")
    two_buildings().export(folder / "meshes" / "buildings.obj")
    body = toml_body or textwrap.dedent(
        """
        name = "tiny"
        frequency_ghz = 28.0

        [materials.tinted]
        permittivity = 6.0
        conductivity = 0.1

        [[objects]]
        name = "ground"
        mesh = "meshes/ground.ply"
        material = "asphalt"
        kind = "ground"

        [[objects]]
        name = "block"
        mesh = "meshes/buildings.obj"
        material = "concrete"
        thickness = 0.3
        split = true

        [transmitter]
        position = [5.0, 5.0, 10.0]

        [receivers]
        origin = [0.0, 0.0]
        spacing = 2.0
        shape = [51, 51]
        height = 1.5
        """
    )
    path = folder / "scene.toml"
    path.write_text(body)
    return path
