"""Sky patches: counts, exact solid angles, directions and patch-mean luminance."""

import math

import numpy as np
import pytest

from hirad.daylight import patches, skies


def test_tregenza_counts_and_solid_angles():
    p = patches.tregenza_patches()
    assert p.count == 145
    assert p.solid_angle.sum() == pytest.approx(2 * math.pi, rel=1e-12)
    assert p.cos_solid_angle.sum() == pytest.approx(math.pi, rel=1e-12)
    # first band: 30 patches of 12 degrees height, Omega = (2 pi / 30) sin 12
    assert p.solid_angle[0] == pytest.approx(2 * math.pi / 30 * math.sin(math.radians(12)), rel=1e-12)
    # zenith cap of 6 degrees radius
    assert p.solid_angle[-1] == pytest.approx(2 * math.pi * (1 - math.cos(math.radians(6))), rel=1e-12)


@pytest.mark.parametrize("mf,count", [(1, 145), (2, 577), (3, 1297), (4, 2305)])
def test_reinhart_counts(mf, count):
    p = patches.reinhart_patches(mf)
    assert p.count == count == 144 * mf * mf + 1
    assert p.solid_angle.sum() == pytest.approx(2 * math.pi, rel=1e-12)


def test_frames_and_directions():
    d, w = patches.patch_arrays(1, up="Y")
    assert d.shape == (145, 3) and w.shape == (145,)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    assert np.all(d[:, 1] > 0)  # all above the horizon, Y up
    assert np.allclose(d[-1], [0, 1, 0])
    # first patch faces north (-Z for Y up), east is +X
    assert d[0] @ np.array([0, 0, -1.0]) > 0.9
    east = patches.directions(0.0, math.pi / 2, up="Y")
    assert np.allclose(east, [1, 0, 0])
    assert np.allclose(patches.directions(0.0, math.pi / 2, up="Z"), [1, 0, 0])
    assert np.allclose(patches.directions(0.0, 0.0, up="Z"), [0, 1, 0])
    alt, az = patches.altitude_azimuth(d, up="Y")
    p = patches.tregenza_patches()
    assert np.allclose(alt, p.altitude) and np.allclose(np.cos(az), np.cos(p.az_center))
    with pytest.raises(ValueError, match="north"):
        patches.frame("Y", north=[0, 1, 0])


def test_patch_mean_uniform_sky_is_exact():
    p = patches.tregenza_patches()
    L = p.mean_luminance(skies.UniformSky(1000.0))
    assert np.allclose(L, 1000.0)
    assert p.horizontal_illuminance(L) == pytest.approx(1000.0 * math.pi, rel=1e-12)


@pytest.mark.parametrize("sky_type", range(1, 16))
def test_mf2_patch_means_reproduce_continuous_eh(sky_type):
    """Patch-mean luminances, each patch uniform, give the continuous E_h within 0.5 % on
    Reinhart MF:2 for every CIE sky at a sun elevation of 30 degrees."""
    s = skies.CIEGeneralSky(sky_type, math.radians(60), math.radians(100), zenith_luminance=5000.0)
    p = patches.reinhart_patches(2)
    eh = p.horizontal_illuminance(p.mean_luminance(s))
    assert eh == pytest.approx(s.horizontal_illuminance, rel=5e-3)


@pytest.mark.parametrize("sky_type", [1, 2, 3, 4, 5])
def test_tregenza_overcast_skies_within_half_percent(sky_type):
    s = skies.CIEGeneralSky(sky_type, math.radians(60), math.radians(100))
    p = patches.tregenza_patches()
    assert p.horizontal_illuminance(p.mean_luminance(s)) == pytest.approx(s.horizontal_illuminance, rel=5e-3)


def test_patch_mean_integrates_luminance():
    """sum L_i Omega_i is the integral of L over the sky (not cos-weighted)."""
    s = skies.CIEGeneralSky(12, math.radians(60), 0.3)
    p = patches.tregenza_patches()
    total = float(np.sum(p.mean_luminance(s, order=12) * p.solid_angle))
    from hirad.daylight.skies import hemisphere_integral
    assert total == pytest.approx(hemisphere_integral(s.luminance, weight_cos=False), rel=1e-4)


def test_ground():
    d, omega, L = patches.ground_patch(20000.0, 0.2, up="Z")
    assert np.allclose(d, [0, 0, -1]) and omega == pytest.approx(2 * math.pi)
    assert L == pytest.approx(0.2 * 20000.0 / math.pi)
    with pytest.raises(ValueError, match="reflectance"):
        patches.ground_luminance(1000.0, 1.5)
