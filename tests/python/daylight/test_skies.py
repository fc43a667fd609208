"""Sky models against closed forms and independent numerical integration."""

import math

import numpy as np
import pytest

from hirad.daylight import skies

SUN_ZENITH = math.radians(60.0)  # sun elevation 30 degrees
SUN_AZIMUTH = math.radians(135.0)


def midpoint_eh(rel, n_theta=1200, n_phi=2400):
    """Independent oracle: dense midpoint rule in (theta, phi) of rel cos(theta) sin(theta)."""
    th = (np.arange(n_theta) + 0.5) * (math.pi / 2 / n_theta)
    ph = (np.arange(n_phi) + 0.5) * (2 * math.pi / n_phi)
    T, P = np.meshgrid(th, ph, indexing="ij")
    return float(np.sum(rel(T, P) * np.cos(T) * np.sin(T)) * (math.pi / 2 / n_theta) * (2 * math.pi / n_phi))


def cie_closed_form(a, b, c, d, e, zs, azs):
    """L/Lz of ISO 15469 written out independently of the module."""
    def rel(theta, phi):
        cz = np.cos(theta)
        grad = 1 + a * np.exp(b / cz)
        chi = np.arccos(np.clip(cz * math.cos(zs) + np.sin(theta) * math.sin(zs) * np.cos(phi - azs), -1, 1))
        ind = 1 + c * (np.exp(d * chi) - math.exp(d * math.pi / 2)) + e * np.cos(chi) ** 2
        ind_s = 1 + c * (math.exp(d * zs) - math.exp(d * math.pi / 2)) + e * math.cos(zs) ** 2
        return ind * grad / (ind_s * (1 + a * math.exp(b)))
    return rel


def test_table_has_15_types_and_type5_is_uniform():
    assert sorted(skies.CIE_GENERAL_SKIES) == list(range(1, 16))
    a, b, c, d, e = skies.CIE_GENERAL_SKIES[5]
    assert a == 0 and c == 0 and e == 0  # phi == 1, f == 1
    # the standard clear sky (type 12) is gradation V, indicatrix 4
    assert skies.CIE_GENERAL_SKIES[12] == (-1.0, -0.32, 10.0, -3.0, 0.45)


@pytest.mark.parametrize("sky_type", range(1, 16))
def test_cie_general_sky_eh_over_lz(sky_type):
    s = skies.CIEGeneralSky(sky_type, SUN_ZENITH, SUN_AZIMUTH)
    ours = s.relative_horizontal_illuminance()
    oracle = midpoint_eh(cie_closed_form(*skies.CIE_GENERAL_SKIES[sky_type], SUN_ZENITH, SUN_AZIMUTH))
    assert ours == pytest.approx(oracle, rel=2e-4)
    # relative to the zenith: L(0) = Lz
    assert float(s.relative(0.0, 0.0)) == pytest.approx(1.0, abs=1e-12)


def test_uniform_type5_gives_pi_exactly():
    s = skies.CIEGeneralSky(5, SUN_ZENITH, SUN_AZIMUTH, zenith_luminance=1000.0)
    assert s.horizontal_illuminance == pytest.approx(1000.0 * math.pi, rel=1e-9)
    assert skies.horizontal_illuminance(s) == pytest.approx(1000.0 * math.pi, rel=1e-9)


def test_traditional_overcast_7pi_over_9():
    s = skies.CIEOvercastSky(zenith_luminance=1.0)
    assert skies.horizontal_illuminance(s) == pytest.approx(7 * math.pi / 9, abs=1e-6)
    # horizon luminance is a third of the zenith's
    assert float(s.relative(math.pi / 2, 0.0)) == pytest.approx(1 / 3, abs=1e-12)


def test_absolute_from_horizontal_illuminance():
    s = skies.CIEGeneralSky(12, SUN_ZENITH, SUN_AZIMUTH, horizontal_illuminance=10000.0)
    assert skies.horizontal_illuminance(s) == pytest.approx(10000.0, rel=1e-6)
    o = skies.CIEOvercastSky(horizontal_illuminance=10000.0)
    assert o.zenith_luminance == pytest.approx(10000.0 * 9 / (7 * math.pi), rel=1e-12)


def test_clear_sky_brightest_near_sun_type1_azimuthally_uniform():
    s = skies.CIEGeneralSky(12, SUN_ZENITH, SUN_AZIMUTH)
    near = float(s.relative(SUN_ZENITH, SUN_AZIMUTH + 0.05))
    opposite = float(s.relative(SUN_ZENITH, SUN_AZIMUTH + math.pi))
    assert near > 5 * opposite
    o = skies.CIEGeneralSky(1, SUN_ZENITH, SUN_AZIMUTH)
    assert float(o.relative(1.0, SUN_AZIMUTH)) == pytest.approx(float(o.relative(1.0, SUN_AZIMUTH + math.pi)))
    # type 1 is close to the traditional overcast sky: E_h/Lz within 1 % of 7 pi / 9
    assert o.relative_horizontal_illuminance() == pytest.approx(7 * math.pi / 9, rel=0.01)


def test_bad_inputs():
    with pytest.raises(ValueError, match="sky_type"):
        skies.CIEGeneralSky(16, 0.5)
    with pytest.raises(ValueError, match="sun_zenith"):
        skies.CIEGeneralSky(12, 2.0)
    with pytest.raises(ValueError, match="not both"):
        skies.CIEOvercastSky(zenith_luminance=1, horizontal_illuminance=1)
    with pytest.raises(ValueError, match="dhi"):
        skies.PerezSky(100.0, 0.0, 0.5, 0.0, 100)


def test_perez_bins_and_normalisation():
    assert skies.perez_bin(1.0) == 1 and skies.perez_bin(1.07) == 2 and skies.perez_bin(10.0) == 8
    # clearness of a sky with no beam is exactly 1 (bin 1)
    assert skies.perez_clearness(0.0, 120.0, 0.7) == pytest.approx(1.0, abs=1e-15)
    p = skies.PerezSky(0.0, 150.0, math.radians(40), 0.0, 172)
    assert p.bin == 1
    # diffuse illuminance is K_d * DHI with K_d from the Perez 1990 bin-1 formula written out
    m = 1 / (math.cos(math.radians(40)) + 0.15 * (93.885 - 40) ** -1.253)  # Kasten 1966
    assert p.delta == pytest.approx(150.0 * m / p.dhi * p.dhi / skies.extraterrestrial_normal_irradiance(172), rel=1e-3)
    kd = 97.24 - 0.46 * 2.0 + 12.00 * math.cos(math.radians(40)) - 8.91 * math.log(p.delta)
    assert p.diffuse_efficacy == pytest.approx(kd, rel=1e-12)
    assert 100 < p.diffuse_efficacy < 140  # overcast diffuse efficacy in the published range
    assert skies.horizontal_illuminance(p) == pytest.approx(kd * 150.0, rel=1e-6)


def test_perez_overcast_is_smooth_and_zenith_bright():
    """Bin 1 (overcast): an azimuthally near-uniform sky, brighter at the zenith than at the
    horizon, like the CIE overcast sky (Perez 1993: eps -> 1 gives the overcast distribution)."""
    p = skies.PerezSky(0.0, 150.0, math.radians(40), 0.0, 172)
    th = np.linspace(0, math.radians(85), 50)
    toward = p.relative(th, 0.0)
    away = p.relative(th, math.pi)
    assert np.max(np.abs(toward / away - 1)) < 0.5
    assert p.relative(0.0, 0.0) > p.relative(math.radians(85), math.pi)
    ratio = float(p.relative(math.radians(80), math.pi) / p.relative(0.0, 0.0))
    assert 0.2 < ratio < 0.8  # CIE overcast: (1 + 2 cos 80)/3 = 0.45


def test_perez_clear_peaks_near_sun():
    zs, azs = math.radians(35), math.radians(200)
    p = skies.PerezSky(850.0, 90.0, zs, azs, 172)
    assert p.bin == 8
    th, ph = np.meshgrid(np.linspace(0.01, math.pi / 2 - 0.01, 180), np.linspace(0, 2 * math.pi, 361), indexing="ij")
    L = p.relative(th, ph)
    i = np.unravel_index(np.argmax(L), L.shape)
    cosg = math.cos(th[i]) * math.cos(zs) + math.sin(th[i]) * math.sin(zs) * math.cos(ph[i] - azs)
    assert math.degrees(math.acos(min(1, cosg))) < 3.0
    # direct efficacy of a high clear sun: ~100 lm/W (Perez 1990: 95-105 lm/W)
    assert 90 < p.direct_efficacy < 110
    assert p.direct_normal_illuminance == pytest.approx(p.direct_efficacy * 850.0)
