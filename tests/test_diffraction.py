"""Diffraction in the traced field: continuity across shadow boundaries, reciprocity, the knife edge.

These check the tracer end to end (wedges, path search, leg checks, the UTD coefficient and
the geometrical-optics paths it must complement) against properties of the exact field, not
against the code itself; the coefficient alone is checked against closed forms in test_utd.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from mmwsim import Scene, SceneObject, Transmitter, get_material
from mmwsim.constants import SPEED_OF_LIGHT
from mmwsim.tracer import PathKind, Tracer
from scenes.layout import Building, building_mesh

TX = np.array([-20.0, -5.0, 5.0])


def corner(material: str) -> Scene:
    """A 20 m box with a vertical corner edge at the origin, the transmitter off that corner."""
    block = SceneObject("block", building_mesh([Building(0, 0, 20, 20, 30.0)]), get_material(material))
    bounds = np.array([[-60.0, -60.0, 0.0], [60.0, 60.0, 30.0]])
    return Scene([block], Transmitter(tuple(TX)), name="corner", bounds=bounds)


def field(scene: Scene, rx: np.ndarray, pol=(1.0, 0.0)) -> np.ndarray:
    """Total received field (all paths summed coherently with their phase) per receiver."""
    p = Tracer(scene, None, 1, 200_000, min_gain_db=None).trace(rx)
    k = 2 * np.pi * p.frequency / SPEED_OF_LIGHT
    a = np.einsum("pij,j->pi", p.jones, np.asarray(pol)) * np.exp(-1j * k * p.length)[:, None]
    out = np.zeros((len(rx), 2), complex)
    np.add.at(out, p.rx_index, a)
    return out


@pytest.mark.parametrize("material", ["pec", "concrete"])
@pytest.mark.parametrize("boundary", ["incident", "reflection"])
@pytest.mark.parametrize("pol", [(1.0, 0.0), (0.0, 1.0)])
def test_total_field_is_continuous_across_shadow_boundaries(material, boundary, pol):
    # Incident shadow boundary: the ray grazing the south face past the corner (20, 0), at x = 40:
    # y = 2.5. Reflection shadow boundary of the south face at its corner (0, 0): from the image
    # (-20, 5, 5) through the corner, at x = 40: y = -10.
    y0 = 2.5 if boundary == "incident" else -10.0
    d = 2e-5  # metres: 5e-7 rad seen from the corner
    ys = y0 + d * np.array([-3.0, -1.0, 1.0, 3.0])
    rx = np.column_stack([np.full(4, 40.0), ys, np.full(4, 5.0)])
    e = field(corner(material), rx, pol)
    kinds_lost = {"incident": PathKind.LINE_OF_SIGHT, "reflection": PathKind.REFLECTED}[boundary]
    p = Tracer(corner(material), None, 1, 200_000, min_gain_db=None).trace(rx)
    has = [bool(np.any(p.kind()[p.rx_index == i] == kinds_lost)) for i in range(4)]
    assert has[:2] != has[2:], "the receivers must straddle the boundary"
    steps = np.diff(e, axis=0)
    jump = np.linalg.norm(steps[1] - 0.5 * (steps[0] + steps[2])) / np.linalg.norm(e[1])
    assert jump < 1e-3


def test_reciprocity_with_diffraction_for_perfect_conductors():
    scene = corner("pec")
    a = TX
    b = np.array([35.0, -8.0, 1.5])  # sees the south face: line of sight, a reflection, four diffractions
    fwd = Tracer(scene, a, 2, 400_000, min_gain_db=None).trace(b[None])
    rev = Tracer(scene, b, 2, 400_000, min_gain_db=None).trace(a[None])
    assert fwd.n_paths == rev.n_paths
    assert (fwd.kind() == PathKind.DIFFRACTED).sum() >= 3
    fo, ro = np.argsort(fwd.length), np.argsort(rev.length)
    np.testing.assert_allclose(fwd.length[fo], rev.length[ro], rtol=1e-13)
    # Swapping the ends transposes the channel: H_BA = H_AB^T, also with the V/H cross terms.
    np.testing.assert_allclose(
        fwd.jones[fo], np.swapaxes(rev.jones[ro], 1, 2), rtol=1e-9, atol=1e-9 * np.abs(fwd.jones).max()
    )


@pytest.mark.parametrize("material", ["pec", "concrete"])
@pytest.mark.parametrize("y0", [2.5, -10.0], ids=["incident", "reflection"])
def test_a_receiver_exactly_on_a_shadow_boundary_gets_the_continuous_field(material, y0):
    # Exactly on the boundary the grazing geometrical-optics ray counts one half; the field there
    # is the mean of the fields just either side (to the curvature of the field over 2 d).
    d = 2e-5
    rx = np.array([[40.0, y0 - d, 5.0], [40.0, y0, 5.0], [40.0, y0 + d, 5.0]])
    e = field(corner(material), rx)
    mid = 0.5 * (e[0] + e[2])
    assert np.linalg.norm(e[1] - mid) / np.linalg.norm(mid) < 1e-3
