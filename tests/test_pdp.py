"""Power-delay profiles against Friis and coherent-sum closed forms."""

import numpy as np
import pytest

from mmwsim.antennas import RotatingHorn
from mmwsim.constants import SPEED_OF_LIGHT
from mmwsim.errors import MmwsimError
from mmwsim.fingerprints import power_delay_profile
from mmwsim.tracer import Paths

F = 28e9
LAM = SPEED_OF_LIGHT / F


def make_paths(lengths, jones_length=None, aod=(np.pi / 2, 0.0), aoa=(np.pi / 2, np.pi), rx_index=None):
    """Line-of-sight-like paths along +x with given unfolded lengths (one receiver unless told)."""
    lengths = np.asarray(lengths, dtype=np.float64)
    n = len(lengths)
    jl = lengths if jones_length is None else np.full(n, float(jones_length))
    jones = (LAM / (4 * np.pi * jl))[:, None, None] * np.diag([1.0, -1.0])[None].astype(complex)
    rx_index = np.zeros(n, np.int64) if rx_index is None else np.asarray(rx_index, np.int64)
    n_rx = int(rx_index.max()) + 1 if n else 1
    return Paths(
        tx=np.array([0.0, 0.0, 10.0]),
        rx=np.tile([100.0, 0.0, 10.0], (n_rx, 1)),
        frequency=F,
        rx_index=rx_index,
        length=lengths,
        jones=jones,
        aod=np.tile(aod, (n, 1)),
        aoa=np.tile(aoa, (n, 1)),
        order=np.zeros(n, np.int8),
        faces=np.full((n, 0), -1, np.int64),
        objects=np.full((n, 0), -1, np.int32),
        points=np.zeros((n, 0, 3)),
    )


@pytest.fixture(scope="module")
def horn():
    return RotatingHorn(32)


def mw(dbm):
    return 10 ** (np.asarray(dbm, dtype=np.float64) / 10)


def friis_dbm(length, gain_tx_dbi=24.5, gain_rx_dbi=10.0, p_dbm=30.0):
    return p_dbm + gain_tx_dbi + gain_rx_dbi + 20 * np.log10(LAM / (4 * np.pi * length))


def test_single_los_path_lands_in_its_bin_with_friis_power(horn):
    length = 100.0  # 333.6 ns: bin 6 of 50 ns
    pdp = power_delay_profile(make_paths([length]), horn)
    assert pdp.shape == (1, 32, 120) and pdp.dtype == np.float32
    assert int(length / SPEED_OF_LIGHT // 50e-9) == 6
    assert pdp[0, 0, 6] == pytest.approx(friis_dbm(length), abs=1e-3)  # -37.4 dBm
    assert np.all(np.isneginf(np.delete(pdp[0], 6, axis=1)))  # no signal elsewhere
    # other beams see the horn's gain towards azimuth 0
    g = horn.gain_dbi(np.pi / 2, 0.0)
    np.testing.assert_allclose(mw(pdp[0, :, 6]), mw(friis_dbm(length, g)), rtol=1e-4, atol=1e-15)
    # 30 dBm + 24.5 dBi + 10 dBi - 101.39 dB free-space loss at 100 m
    assert pdp[0, 0, 6] == pytest.approx(-36.89, abs=0.01)


def test_equal_paths_in_one_bin_add_coherently(horn):
    base = 100.0
    in_phase = power_delay_profile(make_paths([base, base + 10 * LAM], jones_length=base), horn)
    anti = power_delay_profile(make_paths([base, base + 10.5 * LAM], jones_length=base), horn)
    single = friis_dbm(base)
    assert in_phase[0, 0, 6] == pytest.approx(single + 20 * np.log10(2), abs=1e-3)  # +6.02 dB
    assert anti[0, 0, 6] < single - 100  # cancelled
    # 60 ns apart: separate bins, no interference
    apart = power_delay_profile(make_paths([base, base + 18.0]), horn)
    assert apart[0, 0, 6] == pytest.approx(single, abs=1e-3)
    assert apart[0, 0, 7] == pytest.approx(friis_dbm(base + 18.0), abs=1e-3)


def test_receivers_are_kept_apart_and_late_paths_dropped(horn):
    p = make_paths([100.0, 100.0, 1900.0], rx_index=[0, 1, 1])
    pdp = power_delay_profile(p, horn)
    assert pdp.shape == (2, 32, 120)
    np.testing.assert_allclose(pdp[:, 0, 6], friis_dbm(100.0), atol=1e-3)  # no sum across receivers
    assert np.isneginf(pdp[1, 0]).sum() == 119  # the 6.3 us path is beyond the 120 bins


def test_band_limited_profile(horn):
    centre = 6.5 * 50e-9 * SPEED_OF_LIGHT  # a path at the centre of bin 6
    pdp = power_delay_profile(make_paths([centre]), horn, band_limited=True)
    assert pdp[0, 0, 6] == pytest.approx(friis_dbm(centre), abs=1e-3)
    assert np.all(np.delete(pdp[0, 0], 6) < friis_dbm(centre) - 200)
    off = 6.9 * 50e-9 * SPEED_OF_LIGHT
    pdp = power_delay_profile(make_paths([off]), horn, band_limited=True)
    total = 10 * np.log10(np.sum(10 ** (pdp[0, 0].astype(float) / 10)))
    # sinc samples keep the energy (to the truncated tail, under 0.1 dB)
    assert total == pytest.approx(friis_dbm(off), abs=0.1)
    assert np.argmax(pdp[0, 0]) == 6  # nearest bin centre (6.5) to the delay (6.9 bins)


def test_frequency_mismatch_is_an_error(horn):
    p = make_paths([100.0])
    p.frequency = 60e9
    with pytest.raises(MmwsimError, match="GHz"):
        power_delay_profile(p, horn)


def test_free_space_trace_matches_friis(horn):
    import scenes
    from mmwsim.tracer import trace

    scene = scenes.free_space()
    tx = scene.transmitter.array
    rx = np.array([[60.0, 20.0, 1.5], [-30.0, -40.0, 1.5]])
    pdp = power_delay_profile(trace(scene, tx, rx, max_reflections=0), horn)
    d = rx - tx
    length = np.linalg.norm(d, axis=1)
    theta = np.arccos(d[:, 2] / length)
    phi = np.arctan2(d[:, 1], d[:, 0])
    bins = (length / SPEED_OF_LIGHT // 50e-9).astype(int)
    # the V-polarised receiver picks up the theta component of each beam's field
    co_pol = np.abs(horn.field(theta, phi)[..., 0]) ** 2  # (32, 2)
    for r in range(2):
        expected = friis_dbm(length[r], 10 * np.log10(co_pol[:, r]))
        np.testing.assert_allclose(mw(pdp[r, :, bins[r]]), mw(expected), rtol=1e-4, atol=1e-15)
