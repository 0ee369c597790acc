"""Antenna patterns and codebooks against aperture theory and closed forms."""

import numpy as np
import pytest

from mmwsim.antennas import (
    Isotropic,
    PlanarArrayCodebook,
    PyramidalHorn,
    RotatingHorn,
    ShortDipole,
    integrate_gain,
    make_codebook,
    phi_hat,
    theta_hat,
    unit_vector,
)
from mmwsim.errors import MmwsimError


def db(x):
    return 10 * np.log10(x)


@pytest.fixture(scope="module")
def horn():
    return PyramidalHorn()


def test_spherical_basis_is_right_handed_orthonormal():
    rng = np.random.default_rng(0)
    th, ph = rng.uniform(0.01, np.pi - 0.01, 50), rng.uniform(-np.pi, np.pi, 50)
    r, t, p = unit_vector(th, ph), theta_hat(th, ph), phi_hat(th, ph)
    for a in (r, t, p):
        np.testing.assert_allclose(np.linalg.norm(a, axis=-1), 1.0)
    np.testing.assert_allclose(np.cross(r, t), p, atol=1e-12)


def test_horn_peak_gain_is_24_5_dbi_at_28_ghz(horn):
    assert horn.directivity_dbi == pytest.approx(24.5, abs=1e-6)
    assert float(horn.gain_dbi(np.pi / 2, 0.0)) == pytest.approx(24.5, abs=1e-6)
    # the boresight field is pure V (theta_hat) polarisation, positive
    f = horn.field(np.pi / 2, 0.0)
    assert f[0].real == pytest.approx(np.sqrt(10**2.45))
    assert abs(f[1]) < 1e-12
    # large-aperture closed form D = 4 pi A 0.81 / lambda^2 agrees to a tenth of a dB
    assert horn.aperture_directivity_dbi() == pytest.approx(24.5, abs=0.1)


@pytest.mark.parametrize(
    "pattern",
    [
        PyramidalHorn(),
        PyramidalHorn(azimuth=2.0, elevation=-0.3),
        PyramidalHorn(gain_dbi=18.0, frequency=60e9),
        ShortDipole(),
        ShortDipole(axis=(1.0, 1.0, 0.0)),
    ],
    ids=["horn", "horn_tilted", "horn_18dBi_60GHz", "dipole", "dipole_tilted"],
)
def test_pattern_integrates_to_its_directivity(pattern):
    # the mean gain over the sphere of a lossless antenna whose peak is its directivity is 1
    assert db(integrate_gain(pattern)) == pytest.approx(0.0, abs=0.05)


def test_isotropic_and_dipole_closed_forms():
    iso = Isotropic(10.0, "V")
    assert integrate_gain(iso, 91, 180) == pytest.approx(10.0, rel=1e-3)
    np.testing.assert_allclose(iso.field(0.3, 1.0), [np.sqrt(10), 0])
    d = ShortDipole()
    th = np.linspace(0, np.pi, 7)
    np.testing.assert_allclose(d.gain(th, 0.4), 1.5 * np.sin(th) ** 2, atol=1e-12)
    np.testing.assert_allclose(d.field(np.pi / 2, 0.0), [np.sqrt(1.5), 0], atol=1e-12)


def test_horn_beamwidths_match_aperture_formulas(horn):
    e_bw, h_bw = horn.half_power_beamwidths()
    e_f, h_f = horn.beamwidth_formulas()
    assert np.degrees(e_bw) == pytest.approx(np.degrees(e_f), rel=0.02)
    assert np.degrees(h_bw) == pytest.approx(np.degrees(h_f), rel=0.02)
    # aperture sized for equal beamwidths, about 11.3 deg, the 32-beam step of 11.25 deg
    assert np.degrees(h_bw) == pytest.approx(11.25, abs=0.3)
    # gain at the half-beamwidth in the horizontal plane is 3 dB down
    assert float(horn.gain_dbi(np.pi / 2, h_bw / 2)) == pytest.approx(24.5 - 3.01, abs=0.01)
    # first null of a cosine aperture at sin(psi) = 3 lambda / (2 a)
    lam = 299792458 / 28e9
    assert float(horn.gain_dbi(np.pi / 2, np.arcsin(1.5 * lam / horn.width))) < -20


def test_rotating_horn_beam_i_is_beam_0_rotated():
    cb = RotatingHorn(n_beams=32, elevation=np.radians(-8.0))
    rng = np.random.default_rng(1)
    th, ph = rng.uniform(0, np.pi, 200), rng.uniform(-np.pi, np.pi, 200)
    f = cb.field(th, ph)
    assert f.shape == (32, 200, 2)
    step = 2 * np.pi / 32
    for i in (1, 5, 17, 31):
        np.testing.assert_allclose(f[i], cb.field(th, ph - i * step)[0], atol=1e-10)
    # peak of each beam at its azimuth, 8 deg down
    g = cb.gain_dbi(np.radians(98.0), cb.azimuths)
    np.testing.assert_allclose(np.diagonal(g), 24.5, atol=1e-6)


def test_dft_codebook_is_unitary_and_steers():
    cb = PlanarArrayCodebook(8, 4)
    np.testing.assert_allclose(cb.weights @ cb.weights.conj().T, np.eye(32), atol=1e-12)
    rng = np.random.default_rng(2)
    th, ph = rng.uniform(0, np.pi, 300), rng.uniform(-np.pi, np.pi, 300)
    # Parseval: the beams' gains add up to N times the (0 dBi) element gain everywhere
    np.testing.assert_allclose(cb.gain(th, ph).sum(axis=0), 32.0, rtol=1e-10)
    for b in (0, 3, 9, 30):
        u, v = cb.beam_directions()[b]
        theta = np.arccos(v)
        phi = np.arcsin(u / np.sin(theta))
        assert float(cb.gain(theta, phi)[b]) == pytest.approx(32.0, rel=1e-9)


def test_make_codebook_and_bad_input():
    assert make_codebook("rotating_horn", n_beams=8).n_beams == 8
    assert make_codebook("planar_array", n_horizontal=4, n_vertical=2).n_beams == 8
    with pytest.raises(MmwsimError, match="unknown codebook"):
        make_codebook("yagi")
    with pytest.raises(MmwsimError):
        RotatingHorn(n_beams=0)
    with pytest.raises(MmwsimError):
        Isotropic(0.0, "X")


@pytest.mark.parametrize("elevation_deg", [0.0, -7.0, 12.0])
def test_rotating_horn_fast_fields_equal_each_rotated_horn(elevation_deg):
    # The codebook's fields by angle (one horn turned by angle-addition steps) against every
    # rotated aperture evaluated on its own.
    from mmwsim.antennas.spherical import spherical_basis

    book = RotatingHorn(32, elevation=np.radians(elevation_deg), azimuth0=0.3)
    rng = np.random.default_rng(7)
    theta, phi = np.arccos(rng.uniform(-1, 1, 500)), rng.uniform(-np.pi, np.pi, 500)
    fast = book.field(theta, phi)
    slow = np.stack([h.field_basis(*spherical_basis(theta, phi)) for h in book.horns])
    np.testing.assert_allclose(fast, slow, atol=1e-10 * np.abs(slow).max())
