"""Diffracting wedges from meshes: which edges diffract, their frame, and merged collinear pieces."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from mmwsim import Scene, SceneObject, get_material
from mmwsim.tracer.wedges import find_wedges
from scenes.canonical import wall
from scenes.layout import Building, building_mesh, ground_mesh

CONCRETE = get_material("concrete")


def scene_of(*meshes: trimesh.Trimesh, ground: bool = False) -> Scene:
    objects = [SceneObject(f"o{i}", m, CONCRETE) for i, m in enumerate(meshes)]
    if ground:
        objects.append(SceneObject("ground", ground_mesh(-100, -100, 100, 100), CONCRETE, "ground"))
    return Scene(objects, name="wedges")


def box(x0, y0, x1, y1, h) -> trimesh.Trimesh:
    return building_mesh([Building(x0, y0, x1, y1, h)])


def test_a_cube_has_twelve_right_angle_wedges_with_a_consistent_frame():
    w = find_wedges(scene_of(box(0, 0, 10, 10, 10)))
    assert w.count == 12
    np.testing.assert_allclose(w.n, 1.5)
    np.testing.assert_allclose(w.length, 10.0)
    # t0 = n0 x e lies in the 0-face, points into it, and the exterior spans n pi from t0 to tn.
    np.testing.assert_allclose(np.cross(w.n0, w.edge), w.t0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", w.t0, w.n0), 0.0, atol=1e-12)
    phi = w.n * np.pi
    rotated = np.cos(phi)[:, None] * w.t0 + np.sin(phi)[:, None] * w.n0
    np.testing.assert_allclose(rotated, w.tn, atol=1e-12)
    centre = np.array([5.0, 5.0, 5.0])
    mid = w.origin + 0.5 * w.length[:, None] * w.edge
    assert np.all(np.einsum("ij,ij->i", w.t0, centre - mid) > 0)  # into the solid's face


def test_ground_seams_diagonals_and_rims_do_not_diffract():
    # On the ground: the four bottom edges lie on the ground plane (a concave seam in reality).
    w = find_wedges(scene_of(box(0, 0, 10, 10, 10), ground=True))
    assert w.count == 8
    assert np.all(w.origin[:, 2] + np.minimum(w.edge[:, 2], 0) * w.length >= -1e-9)
    assert not np.any(np.isclose(w.origin[:, 2], 0.0) & np.isclose(np.abs(w.edge[:, 2]), 0.0))
    # A lone wall (two triangles): its diagonal is flat, its rim is a free boundary.
    assert find_wedges(scene_of(wall(0, 0, 20, 0, 10))).count == 0
    # A ground plane alone: diagonal and rim only.
    assert find_wedges(scene_of(ground_mesh(0, 0, 50, 50))).count == 0


def test_touching_buildings_merge_collinear_edges_and_hide_shared_walls():
    same = find_wedges(scene_of(box(0, 0, 10, 10, 10), box(10, 0, 20, 10, 10), ground=True))
    # One 20 x 10 x 10 block: 4 vertical corners, 4 roof edges of which two run the whole 20 m.
    assert same.count == 8
    assert sorted(np.round(same.length, 9)) == [10.0] * 6 + [20.0] * 2
    taller = find_wedges(scene_of(box(0, 0, 10, 10, 10), box(10, 0, 20, 10, 20), ground=True))
    seg = np.round(taller.segments(), 6)
    # The tall block's corners above the low roof diffract from 10 m up only.
    low_corner = [s for s in seg if np.allclose(s[:, :2], [[10, 0], [10, 0]])]
    assert len(low_corner) == 1 and sorted(low_corner[0][:, 2].tolist()) == [10.0, 20.0]
    # No wedge along the seam where the low roof meets the tall wall (x = 10 at z = 10, along y).
    seam = [s for s in seg if np.allclose(s[:, 0], 10) and np.allclose(s[:, 2], 10)]
    assert not seam


@pytest.mark.parametrize("angle_deg", [0.5, 3.0])
def test_nearly_flat_edges_are_left_out_below_one_degree(angle_deg):
    # A roof folded by angle_deg along its ridge.
    a = np.radians(angle_deg)
    ridge = 5.0 * np.tan(a)
    v = np.array(
        [[0, 0, 10], [5, 0, 10 + ridge], [10, 0, 10], [0, 10, 10], [5, 10, 10 + ridge], [10, 10, 10]], float
    )
    roof = trimesh.Trimesh(v, [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]], process=False)
    w = find_wedges(scene_of(roof))
    assert w.count == (1 if angle_deg > 1.0 else 0)
