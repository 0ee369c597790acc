"""Diffuse scattering (effective roughness) against closed forms: the directive normalisation,
patterns integrating to one, the Lambertian plate, the co/cross split."""

from __future__ import annotations

import numpy as np
import pytest

from mmwsim.constants import SPEED_OF_LIGHT
from mmwsim.materials import get_material
from mmwsim.tracer import Surface
from mmwsim.tracer.fresnel import bounce_matrices, fresnel
from mmwsim.tracer.scattering import diffuse_matrices, directive_normalisation, scattering_pattern

LAM = SPEED_OF_LIGHT / 28e9


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def transverse(rng, k):
    """Random unit vectors perpendicular to each row of k."""
    return unit(np.cross(k, rng.normal(size=k.shape)))


def power(co, cross, e):
    return (np.abs(np.einsum("mij,mj->mi", co, e)) ** 2).sum(1), (
        np.abs(np.einsum("mij,mj->mi", cross, e)) ** 2
    ).sum(1)


@pytest.mark.parametrize(
    "alpha,values",
    [(1, [4.71239, 4.50194, 3.92699, 3.41436]), (4, [2.43473, 2.31941, 1.91932, 1.49428])],
)
def test_directive_normalisation_reference_values(alpha, values):
    cos = np.cos(np.radians([0.0, 30.0, 60.0, 80.0]))
    np.testing.assert_allclose(directive_normalisation(alpha, cos), values, atol=1e-5)
    np.testing.assert_allclose(directive_normalisation(np.full(4, alpha), cos), values, atol=1e-5)


def hemisphere_quadrature(n_mu=160, n_phi=320):
    """Directions over the upper hemisphere (z > 0) and their solid-angle weights (Gauss-Legendre in cos)."""
    mu, w = np.polynomial.legendre.leggauss(n_mu)
    mu, w = (mu + 1) / 2, w / 2
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    mu, phi = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - mu**2)
    dirs = np.stack([s * np.cos(phi), s * np.sin(phi), mu], axis=-1).reshape(-1, 3)
    return dirs, (w[:, None] * np.full(phi.shape, 2 * np.pi / n_phi)).ravel()


@pytest.mark.parametrize("theta_i", [0.0, 30.0, 60.0, 80.0, 89.0])
def test_patterns_integrate_to_one(theta_i):
    dirs, weight = hemisphere_quadrature()
    m = len(dirs)
    t = np.radians(theta_i)
    k_in = np.tile([np.sin(t), 0.0, -np.cos(t)], (m, 1))
    for normal in ([0, 0, 1.0], [0, 0, -1.0]):  # either sign of the normal
        normal = np.tile(normal, (m, 1))
        assert np.sum(scattering_pattern(k_in, dirs, normal, "lambertian") * weight) == pytest.approx(
            1, abs=1e-6
        )
        for alpha in (1, 2, 4, 7, 10):
            f = scattering_pattern(k_in, dirs, normal, "directive", alpha)
            assert np.sum(f * weight) == pytest.approx(1, abs=1e-6), alpha
    # nothing behind the surface
    behind = dirs * [1, 1, -1]
    assert not np.any(
        scattering_pattern(k_in, behind, normal, np.array(["directive", "lambertian"] * (m // 2)))
    )


def test_directive_pattern_peaks_in_the_specular_direction():
    t = np.radians(40.0)
    k_in = np.array([[np.sin(t), 0, -np.cos(t)]] * 3)
    k_out = unit(np.array([[np.sin(t), 0, np.cos(t)], [0.0, 0, 1], [np.sin(t), 0.3, np.cos(t)]]))
    f = scattering_pattern(k_in, k_out, np.tile([0, 0, 1.0], (3, 1)), "directive", 6)
    assert f[0] == pytest.approx(1 / directive_normalisation(6, np.cos(t))) and f[0] > f[1] and f[0] > f[2]


def test_lambertian_plate_total_power():
    """TX = RX at height h on the normal of an infinite plate with Gamma = 1: sum S^2 / (2 h^2)."""
    h, s_coef, kx = 3.0, 0.6, 0.3
    edges = np.linspace(0.0, 40 * h, 16001)  # rings of h/400 out to 40 h, 8 sectors each
    rho = (edges[:-1] + edges[1:]) / 2
    n_sec = 8
    area = np.repeat(np.pi * (edges[1:] ** 2 - edges[:-1] ** 2) / n_sec, n_sec)
    ang = np.tile((np.arange(n_sec) + 0.5) * 2 * np.pi / n_sec, len(rho))
    r = np.repeat(rho, n_sec)
    tiles = np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros_like(r)], axis=1)
    ant = np.array([0.0, 0.0, h])
    leg = tiles - ant
    dist = np.linalg.norm(leg, axis=1)
    k_in = leg / dist[:, None]
    m = len(tiles)
    co, cross = diffuse_matrices(
        k_in, -k_in, np.tile([0, 0, 1.0], (m, 1)), Surface.perfect_conductor(m),
        s_coef, kx, "lambertian", 4, area, LAM,
    )  # fmt: skip
    e_i = transverse(np.random.default_rng(0), k_in) / dist[:, None]  # |E_i| = 1 / r_i at the tile
    p_co, p_cross = power(co, cross, e_i)
    total = np.sum((p_co + p_cross) / dist**2)
    # measured: 6.5e-7 relative (tiles and the 40 h truncation)
    assert total == pytest.approx(s_coef**2 / (2 * h**2), rel=1e-5)
    assert np.sum(p_cross / dist**2) / total == pytest.approx(kx, rel=1e-12)


def random_geometry(rng, m):
    normal = unit(rng.normal(size=(m, 3)))
    k_in = unit(rng.normal(size=(m, 3)))
    k_in = np.where((np.sum(k_in * normal, 1) > 0)[:, None], -k_in, k_in)  # towards the surface
    k_out = unit(rng.normal(size=(m, 3)))
    k_out = np.where((np.sum(k_out * normal, 1) < 0)[:, None], -k_out, k_out)  # away from it
    return k_in, k_out, normal


def test_co_cross_split_and_power():
    rng = np.random.default_rng(1)
    m = 300
    k_in, k_out, normal = random_geometry(rng, m)
    kx = rng.uniform(0, 1, m)
    s_coef = rng.uniform(0, 1, m)
    area = rng.uniform(0.1, 2, m)
    alpha = rng.integers(1, 9, m)
    pattern = np.where(rng.uniform(size=m) < 0.5, "lambertian", "directive")
    conc = Surface.of([get_material("concrete")], 28e9).take(np.zeros(m, dtype=int))
    co, cross = diffuse_matrices(k_in, k_out, normal, conc, s_coef, kx, pattern, alpha, area, LAM)
    cos_i = np.abs(np.sum(k_in * normal, 1))
    f_s = scattering_pattern(k_in, k_out, normal, pattern, alpha)
    # s- and p-polarised incidence: Gamma is the smooth Fresnel coefficient of that polarisation
    e_s = unit(np.cross(k_in, normal))
    e_p = np.cross(k_in, e_s)
    r_te, r_tm = fresnel(conc.eps, cos_i)
    for e, r in ((e_s, r_te), (e_p, r_tm)):
        p_co, p_cross = power(co, cross, e)
        expected = (s_coef * np.abs(r)) ** 2 * f_s * cos_i * area
        np.testing.assert_allclose(p_co + p_cross, expected, rtol=1e-10)
        np.testing.assert_allclose(p_co, (1 - kx) * expected, rtol=1e-10, atol=1e-300)
        np.testing.assert_allclose(p_cross, kx * expected, rtol=1e-10, atol=1e-300)
    # a roughness already on the surface does not reduce the diffuse Gamma (only the specular one)
    rough = Surface(conc.eps, conc.thickness, np.full(m, 0.9))
    co_r, cross_r = diffuse_matrices(k_in, k_out, normal, rough, s_coef, kx, pattern, alpha, area, LAM)
    np.testing.assert_allclose(co_r, co)


def test_power_independent_of_polarisation_when_coefficients_equal():
    rng = np.random.default_rng(2)
    m = 200
    k_in, k_out, normal = random_geometry(rng, m)
    pec = Surface.perfect_conductor(m)  # |r_te| = |r_tm| = 1
    co, cross = diffuse_matrices(k_in, k_out, normal, pec, 0.5, 0.2, "directive", 3, 1.0, LAM)
    expected = (
        0.25 * scattering_pattern(k_in, k_out, normal, "directive", 3) * np.abs(np.sum(k_in * normal, 1))
    )
    for _ in range(3):
        p_co, p_cross = power(co, cross, transverse(rng, k_in))
        np.testing.assert_allclose(p_co + p_cross, expected, rtol=1e-10)
        np.testing.assert_allclose(p_cross, 0.2 * expected, rtol=1e-10)


def test_co_polar_map_is_the_bounce_matrix_in_the_specular_direction():
    rng = np.random.default_rng(4)
    m = 50
    k_in, _, normal = random_geometry(rng, m)
    k_ref = k_in - 2 * np.sum(k_in * normal, 1)[:, None] * normal
    conc = Surface.of([get_material("brick")], 28e9).take(np.zeros(m, dtype=int))
    co, cross = diffuse_matrices(k_in, k_ref, normal, conc, 0.4, 0.0, "lambertian", 4, 2.0, LAM)
    cos_i = np.abs(np.sum(k_in * normal, 1))
    scale = 0.4 * np.sqrt(cos_i / np.pi * cos_i * 2.0)
    bounce = bounce_matrices(k_in, k_ref, normal, *fresnel(conc.eps, cos_i))
    np.testing.assert_allclose(co, scale[:, None, None] * bounce, atol=1e-12)
    assert not np.any(cross)


def test_bad_pattern_and_alpha():
    k = np.array([[0, 0, -1.0]])
    with pytest.raises(ValueError, match="pattern"):
        scattering_pattern(k, -k, np.array([[0, 0, 1.0]]), "glossy")
    with pytest.raises(ValueError, match="alpha_r"):
        directive_normalisation(0, 1.0)
