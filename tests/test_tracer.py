"""Tracer physics against closed forms: Friis, two-ray, image paths, Fresnel, reciprocity, blockage."""

from __future__ import annotations

import numpy as np
import pytest

import scenes
from mmwsim import Material, MmwsimError, Scene, SceneObject, Transmitter, get_material
from mmwsim.constants import SPEED_OF_LIGHT
from mmwsim.tracer import Paths, Tracer, slab, trace
from mmwsim.tracer.fresnel import fresnel
from scenes.layout import Building, building_mesh, ground_mesh

LAM = SPEED_OF_LIGHT / 28e9
RAYS = 200_000  # plenty for these large, simple reflectors


def _gamma(eps: complex, cos: float) -> tuple[complex, complex]:
    """Textbook half-space coefficients (TE, TM), written out independently of the tracer."""
    sin2 = 1 - cos**2
    root = np.sqrt(eps - sin2)
    return (cos - root) / (cos + root), (eps * cos - root) / (eps * cos + root)


def _only(paths: Paths, interactions: list[str], scene: Scene) -> int:
    names = [o.name for o in scene.objects]
    hits = [
        i
        for i in range(paths.n_paths)
        if [names[o] for o in paths.objects[i, : paths.order[i]]] == interactions
    ]
    assert len(hits) == 1, f"expected one path via {interactions}, got {len(hits)}"
    return hits[0]


def test_free_space_is_friis():
    scene = scenes.load("free_space")
    rx = np.array([[30.0, 40.0, 10.0], [-3.0, 4.0, 22.0]])
    p = trace(scene, rx_positions=rx, n_rays=RAYS)
    assert p.count().tolist() == [1, 1]
    d = np.linalg.norm(rx - scene.transmitter.array, axis=1)
    np.testing.assert_allclose(p.delay, d / SPEED_OF_LIGHT, rtol=1e-14)
    np.testing.assert_allclose(np.abs(p.amplitude()), LAM / (4 * np.pi * d), rtol=1e-12)
    np.testing.assert_allclose(p.jones[0], LAM / (4 * np.pi * d[0]) * np.diag([1, -1]), atol=1e-15)
    # Friis: received / transmitted power for isotropic antennas = (lambda / 4 pi d)^2.
    np.testing.assert_allclose(p.gain_db(), 20 * np.log10(LAM / (4 * np.pi * d)), atol=1e-9)
    np.testing.assert_allclose(p.aod[0], [np.pi / 2, np.arctan2(40, 30)], atol=1e-12)
    np.testing.assert_allclose(p.aoa[0], [np.pi / 2, np.arctan2(-40, -30)], atol=1e-12)
    assert p.order.tolist() == [0, 0] and np.all(p.faces == -1) and np.all(np.isnan(p.points))


@pytest.mark.parametrize("distance", [15.0, 60.0, 250.0])
def test_two_ray_ground_reflection(distance):
    scene = scenes.load("ground_only")
    h1, h2 = 10.0, 1.5
    p = trace(scene, rx_positions=[[distance, 0.0, h2]], n_rays=RAYS)
    assert p.count().tolist() == [2]
    i = _only(p, ["ground"], scene)
    length = np.hypot(distance, h1 + h2)
    assert p.delay[i] == pytest.approx(length / SPEED_OF_LIGHT, rel=1e-14)
    eps = get_material("concrete").complex_permittivity(28e9)
    r_te, r_tm = _gamma(eps, (h1 + h2) / length)
    a = LAM / (4 * np.pi * length)
    # V lies in the plane of incidence (TM), H across it (TE); no cross-polarisation.
    assert p.amplitude("V", "V")[i] == pytest.approx(a * r_tm, rel=1e-12)
    assert p.amplitude("H", "H")[i] == pytest.approx(-a * r_te, rel=1e-12)
    assert abs(p.amplitude("V", "H")[i]) < 1e-15 * a and abs(p.amplitude("H", "V")[i]) < 1e-15 * a
    np.testing.assert_allclose(p.points[i, 0], [distance * h1 / (h1 + h2), 0.0, 0.0], atol=1e-12)
    los = _only(p, [], scene)
    assert p.amplitude("H", "H")[los] == pytest.approx(-LAM / (4 * np.pi * np.hypot(distance, h1 - h2)))


def test_image_path_off_one_wall():
    scene = scenes.load("ground_wall")  # wall in the plane x = 20
    tx = scene.transmitter.array
    rx = np.array([5.0, 30.0, 10.0])  # same height: the wall path is purely TE for V
    p = trace(scene, rx_positions=[rx], n_rays=RAYS)
    i = _only(p, ["wall"], scene)
    image = np.array([40.0 - tx[0], tx[1], tx[2]])
    length = np.linalg.norm(rx - image)
    assert p.length[i] == pytest.approx(length, rel=1e-14)
    cos = abs(rx[0] - image[0]) / length
    r_te, r_tm = _gamma(get_material("concrete").complex_permittivity(28e9), cos)
    a = LAM / (4 * np.pi * length)
    assert p.amplitude("V", "V")[i] == pytest.approx(a * r_te, rel=1e-12)
    assert abs(p.amplitude("H", "H")[i]) == pytest.approx(a * abs(r_tm), rel=1e-12)
    assert p.points[i, 0, 0] == pytest.approx(20.0)
    # LOS, ground, wall and ground-then-wall; wall-then-ground would land behind the wall.
    assert sorted(p.order.tolist()) == [0, 1, 1, 2]


def test_corner_reflector_second_order():
    scene = scenes.load("corner_reflector")  # metal walls x = 0 and y = 0
    tx = scene.transmitter.array
    rx = np.array([30.0, 20.0, 10.0])
    p = trace(scene, rx_positions=[rx], n_rays=RAYS)
    double_image = np.array([-tx[0], -tx[1], tx[2]])
    length = np.linalg.norm(rx - double_image)
    # Both orders share the double image, but the line from the receiver to it crosses the
    # plane x = 0 first (at y = 1.25), so only wall_y-then-wall_x is a path.
    second = np.flatnonzero(p.order == 2)
    assert len(second) == 1
    np.testing.assert_allclose(p.length[second], length, rtol=1e-14)
    names = {tuple(scene.objects[o].name for o in p.objects[i, :2]) for i in second}
    assert names == {("wall_y", "wall_x")}
    np.testing.assert_allclose(p.points[second[0], 1], [0.0, 1.25, 10.0], atol=1e-12)
    eps = get_material("metal").complex_permittivity(28e9)
    for i in second:
        n = [np.array([1.0, 0, 0]), np.array([0, 1.0, 0])]
        if scene.objects[p.objects[i, 0]].name == "wall_y":
            n = n[::-1]
        k0 = p.points[i, 0] - tx
        k1 = p.points[i, 1] - p.points[i, 0]
        c1 = abs(k0 @ n[0]) / np.linalg.norm(k0)
        c2 = abs(k1 @ n[1]) / np.linalg.norm(k1)
        expected = LAM / (4 * np.pi * length) * _gamma(eps, c1)[0] * _gamma(eps, c2)[0]
        assert p.amplitude("V", "V")[i] == pytest.approx(expected, rel=1e-10)
    assert sorted(p.order.tolist()) == [0, 1, 1, 2]


def test_reciprocity():
    scene = scenes.load("street_canyon")
    a, b = np.array([0.0, 0.0, 10.0]), np.array([37.0, 3.0, 1.5])
    fwd = Tracer(scene, a, 3, RAYS).trace(b[None])
    rev = Tracer(scene, b, 3, RAYS).trace(a[None])
    assert fwd.n_paths == rev.n_paths >= 10
    fo, ro = np.argsort(fwd.length), np.argsort(rev.length)
    np.testing.assert_allclose(fwd.delay[fo], rev.delay[ro], rtol=1e-13)
    for pol in ("V", "H"):
        np.testing.assert_allclose(fwd.gain_db(pol, pol)[fo], rev.gain_db(pol, pol)[ro], atol=1e-9)
    np.testing.assert_allclose(fwd.aod[fo], rev.aoa[ro], atol=1e-9)


def test_fresnel_brewster_and_grazing():
    eps = 4.0  # lossless: Brewster angle atan(2)
    brewster = np.arctan(np.sqrt(eps))
    r_te, r_tm = fresnel(eps, np.cos(brewster))
    assert abs(r_tm) < 1e-15 and abs(r_te) > 0.5
    r_te, r_tm = fresnel(get_material("concrete").complex_permittivity(28e9), np.array([1e-4, 1e-6]))
    np.testing.assert_allclose(np.abs(r_te), 1.0, atol=1e-3)
    np.testing.assert_allclose(np.abs(r_tm), 1.0, atol=3e-3)
    # Normal incidence: one coefficient up to the sign of the p basis; metal reflects totally.
    r_te, r_tm = fresnel(eps, 1.0)
    assert r_te == pytest.approx((1 - 2) / (1 + 2)) and r_tm == pytest.approx(-r_te)
    r_te, r_tm = fresnel(get_material("metal").complex_permittivity(28e9), 0.7)
    assert r_te == pytest.approx(-1, abs=2e-3) and r_tm == pytest.approx(1, abs=2e-3)


def test_brewster_angle_through_the_tracer():
    eps = 4.0
    glassy = Material.custom("glassy", eps, 0.0)
    g = SceneObject("ground", ground_mesh(-500, -500, 500, 500), glassy, "ground")
    scene = Scene([g], Transmitter((0.0, 0.0, 10.0)), name="brewster")
    d = (10.0 + 1.5) * np.sqrt(eps)  # tan(incidence) = d / (h1 + h2) = sqrt(eps)
    p = trace(scene, rx_positions=[[0.0, d, 1.5]], n_rays=RAYS)
    i = _only(p, ["ground"], scene)
    a = LAM / (4 * np.pi * p.length[i])
    assert abs(p.amplitude("V", "V")[i]) < 1e-12 * a
    assert abs(p.amplitude("H", "H")[i]) == pytest.approx(a * abs(_gamma(eps, 1 / np.sqrt(1 + eps))[0]))


def test_slab_reflection():
    lam, eps = LAM, 4.0
    # Lossless slab half a wavelength thick inside: transparent at normal incidence.
    r_te, r_tm = slab(eps, 1.0, lam / (2 * np.sqrt(eps)), lam)
    assert abs(r_te) < 1e-12 and abs(r_tm) < 1e-12
    # Quarter-wave slab: maximum reflection 2R'/(1+R'^2).
    r0 = fresnel(eps, 1.0)[0]
    r_te, _ = slab(eps, 1.0, lam / (4 * np.sqrt(eps)), lam)
    assert r_te == pytest.approx(2 * r0 / (1 + r0**2))
    # A thick lossy slab reflects like a half-space; |R| <= 1 always.
    concrete = get_material("concrete").complex_permittivity(28e9)
    cos = np.linspace(0.01, 1, 50)
    np.testing.assert_allclose(slab(concrete, cos, 2.0, lam)[0], fresnel(concrete, cos)[0], atol=1e-9)
    assert np.all(np.abs(slab(eps, cos, 0.013, lam)[1]) <= 1 + 1e-12)


def test_slab_material_changes_the_wall_path():
    thin = get_material("glass", thickness=0.006)
    rx = np.array([5.0, 30.0, 10.0])  # same height as the transmitter: V is TE on the wall
    amps = []
    for mat in (thin, get_material("glass")):
        objs = [SceneObject("wall", scenes.canonical.wall(20, -200, 20, 200, 30), mat, "other")]
        bounds = np.array([[-50.0, -200.0, 0.0], [50.0, 200.0, 30.0]])
        sc = Scene(objs, Transmitter((0.0, 0.0, 10.0)), name="w", bounds=bounds)
        p = trace(sc, rx_positions=[rx], max_reflections=1, n_rays=RAYS)
        i = _only(p, ["wall"], sc)
        amps.append(p.amplitude()[i])
    length = np.hypot(40 - 5, 30)
    r_slab = slab(thin.complex_permittivity(28e9), 35 / length, 0.006, LAM)[0]
    assert amps[0] == pytest.approx(LAM / (4 * np.pi * length) * r_slab, rel=1e-10)
    assert abs(amps[0]) != pytest.approx(abs(amps[1]), rel=1e-3)


def _box_scene(with_box: bool) -> Scene:
    concrete = get_material("concrete")
    objects = [SceneObject("ground", ground_mesh(-100, -100, 100, 100), concrete, "ground")]
    if with_box:
        objects.append(SceneObject("box", building_mesh([Building(20, -10, 30, 10, 20.0)]), concrete))
    return Scene(objects, Transmitter((0.0, 0.0, 10.0)), name="box")


def test_blocked_line_of_sight_disappears():
    rx = [[50.0, 0.0, 1.5], [50.0, 40.0, 1.5]]
    open_ = trace(_box_scene(False), rx_positions=rx, n_rays=RAYS)
    boxed = trace(_box_scene(True), rx_positions=rx, n_rays=RAYS)
    assert 0 in open_.order[open_.rx_index == 0]
    assert 0 not in boxed.order[boxed.rx_index == 0]  # behind the box: no LOS, no ground path
    assert boxed.count()[0] == 0
    assert 0 in boxed.order[boxed.rx_index == 1]  # off to the side: still in view


def test_tiles_and_determinism():
    scene = scenes.load("street_canyon")
    rx = scene.receivers.positions()
    tracer = Tracer(scene, None, 2, RAYS)
    whole = tracer.trace(rx)
    parts = Paths.concatenate([tracer.trace(rx[i : i + 37]) for i in range(0, len(rx), 37)])
    again = Tracer(scene, None, 2, RAYS).trace(rx)
    for name in ("rx_index", "length", "jones", "aod", "aoa", "order", "faces", "objects"):
        np.testing.assert_array_equal(getattr(whole, name), getattr(parts, name))
        np.testing.assert_array_equal(getattr(whole, name), getattr(again, name))
    # Sorted by receiver then delay; interactions padded consistently.
    assert np.all(np.diff(whole.rx_index) >= 0)
    same = np.diff(whole.rx_index) == 0
    assert np.all(np.diff(whole.length)[same] >= 0)
    assert np.all((whole.faces >= 0).sum(axis=1) == whole.order)


def test_bad_input():
    scene = scenes.load("ground_only")
    with pytest.raises(MmwsimError, match="receiver"):
        trace(scene, rx_positions=[[0.0, np.nan, 1.0]], n_rays=1000)
    with pytest.raises(MmwsimError, match="transmitter"):
        Tracer(scene, (0.0, 0.0, np.inf))
    with pytest.raises(MmwsimError, match="max_reflections"):
        Tracer(scene, None, -1)
