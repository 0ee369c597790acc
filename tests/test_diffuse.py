"""Diffuse scattering in the tracer: closed forms, the specular share, polarisation split, storage."""

from __future__ import annotations

import numpy as np
import pytest

from mmwsim import Scene, SceneObject, Transmitter, get_material
from mmwsim.tracer import Interaction, PathKind, Tracer
from scenes.layout import Building, building_mesh, ground_mesh

H = 10.0


def plate(material, half: float = 400.0) -> Scene:
    """A large plate at z = 0 (the infinite plate of the closed form, to (h / half)^4)."""
    return Scene(
        [SceneObject("plate", ground_mesh(-half, -half, half, half), material, "ground")],
        Transmitter((0.0, 0.0, H)),
        name="plate",
    )


def diffuse_power(paths, rx: int = 0, pol=(1.0, 0.0)) -> float:
    """Sum over diffuse paths to receiver ``rx`` of the received power (both receive polarisations)."""
    d = (paths.kind() == PathKind.DIFFUSE) & (paths.rx_index == rx)
    return float(np.sum(np.abs(paths.jones[d] @ np.asarray(pol)) ** 2))


@pytest.mark.parametrize("s", [0.3, 0.7])
def test_lambertian_plate_scatters_s_squared_over_two_h_squared(s):
    # Gamma = 1 (perfect conductor); transmitter and receiver together at height h on the normal:
    # the sum over the plate of (S Gamma)^2 cos(ti)/pi cos(ti) dA / (r^2 r^2) is S^2 / (2 h^2).
    tracer = Tracer(
        plate(get_material("pec").with_scattering(s)), None, 1, 50_000, diffraction=False, min_gain_db=None
    )
    tracer.diffuse.quality = 8.0
    paths = tracer.trace(np.array([[1e-4, 0.0, H]]))
    expected = (tracer.wavelength / (4 * np.pi)) ** 2 * s**2 / (2 * H * H)
    assert diffuse_power(paths) == pytest.approx(expected, rel=1e-3)
    # Diffuse is always the last interaction.
    d = paths.kind() == PathKind.DIFFUSE
    assert np.all(paths.types[d, paths.order[d] - 1] == Interaction.DIFFUSE)


def test_specular_share_and_cross_polarised_fraction():
    rough = get_material("pec").with_scattering(0.6, xpd=0.25)
    smooth = get_material("pec")
    rx = np.array([[30.0, 0.0, 1.5]])
    p_rough = Tracer(plate(rough), None, 1, 50_000, diffraction=False, min_gain_db=None).trace(rx)
    p_smooth = Tracer(plate(smooth), None, 1, 50_000, diffraction=False, min_gain_db=None).trace(rx)
    # The specular ground reflection keeps sqrt(1 - S^2) of its field.
    g_r = p_rough.amplitude("V", "V")[p_rough.kind() == PathKind.REFLECTED]
    g_s = p_smooth.amplitude("V", "V")[p_smooth.kind() == PathKind.REFLECTED]
    np.testing.assert_allclose(np.abs(g_r), np.sqrt(1 - 0.6**2) * np.abs(g_s), rtol=1e-12)
    assert not (p_smooth.kind() == PathKind.DIFFUSE).any()
    # Co- and cross-polar contributions come in pairs; the cross ones carry Kx of the power.
    d = np.flatnonzero(p_rough.kind() == PathKind.DIFFUSE)
    power = np.sum(np.abs(p_rough.jones[d]) ** 2 @ np.ones(2), axis=1)  # (both pols in) summed
    co, cross = power[0::2], power[1::2]
    assert len(co) == len(cross) > 100
    assert cross.sum() / (co.sum() + cross.sum()) == pytest.approx(0.25, rel=1e-9)


def city(s: float) -> Scene:
    mat = get_material("concrete").with_scattering(s)
    return Scene(
        [
            SceneObject("ground", ground_mesh(-80, -80, 80, 80), mat, "ground"),
            SceneObject("block", building_mesh([Building(20, -10, 40, 10, 15.0)]), mat),
        ],
        Transmitter((0.0, 0.0, 10.0)),
        name="block",
    )


def test_diffuse_lights_the_shadow_deterministically_and_tile_independently():
    scene = city(0.4)
    rx = np.array([[60.0, 0.0, 1.5], [10.0, 40.0, 1.5], [-30.0, -50.0, 1.5]])
    tracer = Tracer(scene, None, 2, 200_000)
    whole = tracer.trace(rx)
    again = Tracer(scene, None, 2, 200_000).trace(rx)
    parts = [tracer.trace(rx[:1]), tracer.trace(rx[1:])]
    for other in (again,):
        np.testing.assert_array_equal(whole.length, other.length)
        np.testing.assert_array_equal(whole.jones, other.jones)
    split = np.concatenate([p.length for p in parts])
    np.testing.assert_array_equal(np.sort(whole.length), np.sort(split))
    # Behind the block (x = 60): no line of sight, but diffuse energy from the lit ground and walls.
    behind = whole.rx_index == 0
    assert not np.any(whole.kind()[behind] == PathKind.LINE_OF_SIGHT)
    assert diffuse_power(whole, 0) > 0
    # One reflection before the scattering is allowed within two interactions.
    d = whole.kind() == PathKind.DIFFUSE
    assert set(whole.order[d].tolist()) == {1, 2}


def test_merged_diffuse_keeps_the_power_for_every_polarisation():
    paths = Tracer(city(0.4), None, 2, 200_000).trace(np.array([[10.0, 40.0, 1.5], [60.0, 0.0, 1.5]]))
    merged = paths.merge_diffuse(50e-9)
    n_before = int((paths.kind() == PathKind.DIFFUSE).sum())
    n_after = int((merged.kind() == PathKind.DIFFUSE).sum())
    assert n_after < n_before / 10
    for pol in ((1.0, 0.0), (0.0, 1.0), (1 / np.sqrt(2), 1j / np.sqrt(2))):
        for rx in (0, 1):
            assert diffuse_power(merged, rx, pol) == pytest.approx(diffuse_power(paths, rx, pol), rel=1e-12)
    # The coherent paths are untouched.
    keep = paths.kind() != PathKind.DIFFUSE
    np.testing.assert_array_equal(
        np.sort(paths.length[keep]), np.sort(merged.length[merged.kind() != PathKind.DIFFUSE])
    )


def test_generate_with_diffuse_stores_the_setting_and_adds_power(tmp_path):
    from mmwsim import Dataset
    from mmwsim.dataset import generate_dataset

    kw = dict(spacing=10.0, max_reflections=2, n_rays=100_000, progress=False)
    plain = Dataset.open(generate_dataset("ground_wall", tmp_path / "plain.zarr", **kw))
    rough = Dataset.open(generate_dataset("ground_wall", tmp_path / "rough.zarr", diffuse=0.5, **kw))
    assert rough.config["diffuse"] == 0.5 and plain.config["diffuse"] is None
    assert rough.content_hash != plain.content_hash
    # Diffuse energy fills delay bins and beams that no specular path reaches.
    lit = lambda ds: int(np.isfinite(np.asarray(ds.pdp[:])).sum())  # noqa: E731
    assert lit(rough) > 1.5 * lit(plain)
    paths = rough.paths(np.flatnonzero(rough.outdoors)[:5])
    assert (paths.kind() == PathKind.DIFFUSE).any()
    assert not (plain.paths(np.flatnonzero(plain.outdoors)[:5]).kind() == PathKind.DIFFUSE).any()


def test_trace_recording_shows_wedges_and_diffuse_tiles(tmp_path):
    from mmwsim.cli import main
    from tests.helpers.rrd import check_blueprint, entity_rows

    toml = tmp_path / "scene.toml"
    toml.write_text(
        "\n".join(
            [
                'name = "rough"',
                "[materials.concrete]",
                "scattering_coefficient = 0.4",
                "[[objects]]",
                'name = "ground"',
                'mesh = "ground.ply"',
                'material = "concrete"',
                'kind = "ground"',
                "[[objects]]",
                'name = "block"',
                'mesh = "block.ply"',
                'material = "concrete"',
                "[transmitter]",
                "position = [0.0, 0.0, 10.0]",
            ]
        )
    )
    ground_mesh(-80, -80, 80, 80).export(tmp_path / "ground.ply")
    building_mesh([Building(20, -10, 40, 10, 15.0)]).export(tmp_path / "block.ply")
    rrd = tmp_path / "t.rrd"
    assert main(["trace", str(toml), "--rx", "60,0,1.5", "--rx", "10,40,1.5", "--rrd", str(rrd)]) == 0
    rows = entity_rows(rrd)
    assert rows["/world/scene/wedges"] >= 1 and rows["/world/rays/diffuse_tiles"] >= 1
    check_blueprint(rrd, ["Scene", "Config"])
