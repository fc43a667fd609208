"""Annual daylight: the hourly sky matrix against hand-computed Perez efficacies and patch
geometry, the annual illuminance product against a loop, the metrics on small matrices whose
answers are counted by hand, the heat-map picture, and a smoke test on pvlib's TMY3 year."""

import math
import os
import struct

import numpy as np
import pandas as pd
import pytest

pvlib = pytest.importorskip("pvlib")
from hirad.daylight import annual, patches, skies, sun, weather  # noqa: E402

TMY3 = os.path.join(os.path.dirname(pvlib.__file__), "data", "723170TYA.CSV")

# ---------------------------------------------------------------------------------------------
# hand oracles (Perez et al. 1990, written out here; coefficients of Table 4, bins 1 and 8)
# ---------------------------------------------------------------------------------------------


def kasten_airmass(zenith_deg):
    return 1.0 / (math.cos(math.radians(zenith_deg)) + 0.15 * (93.885 - zenith_deg) ** -1.253)


def spencer_e0n(doy):
    b = 2 * math.pi * (doy - 1) / 365.0
    return 1367.0 * (1.00011 + 0.034221 * math.cos(b) + 0.00128 * math.sin(b)
                     + 0.000719 * math.cos(2 * b) + 0.000077 * math.sin(2 * b))


def perez_by_hand(dni, dhi, zenith_deg, doy, dew_point):
    """(eps, Delta, K_d, K_b) for bins 1 and 8 only (the test's hours fall in those)."""
    z = math.radians(zenith_deg)
    w = math.exp(0.07 * dew_point - 0.075)
    if dhi > 0:
        eps = ((dhi + dni) / dhi + 1.041 * z ** 3) / (1 + 1.041 * z ** 3)
        delta = dhi * kasten_airmass(zenith_deg) / spencer_e0n(doy)
    else:
        eps, delta = math.inf, 0.0
    if eps < 1.065:  # bin 1
        kd = 97.24 - 0.46 * w + 12.00 * math.cos(z) - 8.91 * math.log(delta)
        kb = 57.20 - 4.55 * w - 2.98 * math.exp(5.73 * z - 5) + 117.12 * delta
    elif eps >= 6.2:  # bin 8
        kd = 152.23 + 0.35 * w - 45.27 * math.cos(z) - 7.98 * math.log(max(delta, 1e-12))
        kb = 101.18 + 1.58 * w - 1.10 * math.exp(5.73 * z - 5) - 8.29 * delta
    else:
        raise AssertionError(f"eps = {eps}: the test's hours should be bin 1 or bin 8")
    return eps, delta, kd, max(kb, 0.0)


# ---------------------------------------------------------------------------------------------
# a synthetic weather file: one summer day at a Colorado site, labels at the hour (centre)
# ---------------------------------------------------------------------------------------------

SITE = sun.Site(39.74, -105.18, 1800.0, -7)
DEW = 8.0
# label: (DNI, DHI) in W/m^2
HOURS = {"2023-06-21 00:00": (0.0, 0.0),      # night
         "2023-06-21 12:00": (0.0, 150.0),    # overcast: no beam, bin 1
         "2023-06-21 13:00": (800.0, 80.0),   # clear: bin 8
         "2023-06-21 14:00": (500.0, 0.0),    # beam without diffuse: no sky, sun only
         "2023-06-21 22:00": (0.0, 20.0)}     # sun below the horizon: night despite DHI > 0


def synthetic_weather():
    times = pd.DatetimeIndex(list(HOURS)).tz_localize("Etc/GMT+7")  # UTC-7
    dni = np.array([v[0] for v in HOURS.values()])
    dhi = np.array([v[1] for v in HOURS.values()])
    return weather.Weather(times, dni, dhi, dni + dhi, np.full(len(HOURS), DEW),
                           SITE.latitude, SITE.longitude, SITE.elevation, -7.0, "synthetic")


def sun_at(label):
    p = sun.sun_position(SITE, label)
    return p.zenith, p.azimuth


@pytest.fixture(scope="module")
def synthetic():
    w = synthetic_weather()
    full = annual.sky_matrix(w, SITE, 1, timestamp_position="center")
    sky_only = annual.sky_matrix(w, SITE, 1, include_sun=False, timestamp_position="center")
    sun_only = annual.sky_matrix(w, SITE, 1, include_sky=False, ground_reflectance=0.0,
                                 timestamp_position="center")
    return w, full, sky_only, sun_only


def test_shape_daytime_and_night_rows(synthetic):
    _, full, _, _ = synthetic
    assert full.values.shape == (5, 145 + 1) and full.ground_index == 145
    assert full.daytime.tolist() == [False, True, True, True, False]
    for i in (0, 4):  # midnight, and 22:00 with the sun below the horizon
        assert np.all(full.values[i] == 0)
        assert np.all(full.sun.direction[i] == 0) and full.sun.direct_normal_illuminance[i] == 0


def test_overcast_hour_integrates_to_diffuse_illuminance(synthetic):
    """DNI = 0: eps = 1 (bin 1), E_vd = K_d DHI with K_d written out. The patch sum
    sum L_i Omega_i cos(theta_centre,i) takes each patch's cosine at its centre; for a uniform
    sky that rule gives sum Omega_i cos(theta_i) / pi - 1 = +0.55 % on Tregenza's patches
    (computed below), and the overcast sky, brighter overhead, less: 1 % allowance."""
    _, full, _, _ = synthetic
    p = patches.tregenza_patches()
    zen, _ = sun_at("2023-06-21 12:00")
    eps, delta, kd, _ = perez_by_hand(0.0, 150.0, zen, 172, DEW)
    assert eps == pytest.approx(1.0, abs=1e-15)
    e_vd = kd * 150.0
    assert full.diffuse_horizontal_illuminance[1] == pytest.approx(e_vd, rel=1e-9)
    centre_rule = p.solid_angle * np.cos(p.zenith)
    uniform_error = centre_rule.sum() / math.pi - 1
    assert 0 < uniform_error < 0.01
    row = full.values[1, :145]
    assert np.sum(row * centre_rule) == pytest.approx(e_vd, rel=0.01)
    # no beam: nothing but the sky; the ground is rho_g E_vd / pi
    assert full.values[1, 145] == pytest.approx(0.2 * e_vd / math.pi, rel=1e-9)
    assert full.direct_normal_illuminance[1] == 0


def test_clear_hour_sun_patch_and_ground(synthetic):
    """DNI 800, DHI 80: bin 8. The sun's share sum_i L_sun,i Omega_i is E_dn = K_b DNI, all in
    the Tregenza patch that holds the sun (band floor(alt / 12 deg), patch round(az / width));
    the ground is rho_g (E_vd + E_dn cos Z) / pi."""
    _, full, sky_only, sun_only = synthetic
    p = patches.tregenza_patches()
    zen, az = sun_at("2023-06-21 13:00")
    eps, delta, kd, kb = perez_by_hand(800.0, 80.0, zen, 172, DEW)
    assert eps > 6.2
    e_dn, e_vd = kb * 800.0, kd * 80.0
    assert full.direct_normal_illuminance[2] == pytest.approx(e_dn, rel=1e-9)
    sun_part = full.values[2, :145] - sky_only.values[2, :145]
    assert np.sum(sun_part * p.solid_angle) == pytest.approx(e_dn, rel=1e-9)
    # the containing patch, by hand
    alt = 90.0 - zen
    band = int(alt // 12)
    counts = (30, 30, 24, 24, 18, 12, 6)
    if band >= 7:
        expected = 144
    else:
        n = counts[band]
        expected = sum(counts[:band]) + int(round(az / (360.0 / n))) % n
    assert np.flatnonzero(sun_part > 1e-9 * sun_part.max()).tolist() == [expected]
    ground = 0.2 * (e_vd + e_dn * math.cos(math.radians(zen))) / math.pi
    assert full.values[2, 145] == pytest.approx(ground, rel=1e-9)
    # the sky-only matrix keeps that ground (lit by the sun too); sky-only + sun-only = full
    assert sky_only.values[2, 145] == pytest.approx(ground, rel=1e-9)
    assert np.allclose(sky_only.values[:, :145] + sun_only.values[:, :145], full.values[:, :145],
                       rtol=1e-12, atol=0)
    assert np.all(sun_only.values[:, 145] == 0)


def test_beam_without_diffuse(synthetic):
    """DHI = 0, DNI 500: no sky; the sun with bin 8's K_b at Delta = 0."""
    _, full, _, _ = synthetic
    p = patches.tregenza_patches()
    zen, _ = sun_at("2023-06-21 14:00")
    _, _, _, kb = perez_by_hand(500.0, 0.0, zen, 172, DEW)
    row = full.values[3, :145]
    assert np.count_nonzero(row) == 1
    assert np.sum(row * p.solid_angle) == pytest.approx(kb * 500.0, rel=1e-9)
    assert full.values[3, 145] == pytest.approx(0.2 * kb * 500.0 * math.cos(math.radians(zen)) / math.pi,
                                                rel=1e-9)


def test_sun_spread_over_four_nearest(synthetic):
    w = synthetic[0]
    s4 = annual.sky_matrix(w, SITE, 1, include_sky=False, ground_reflectance=0.0, sun_spread=4,
                           timestamp_position="center")
    p = patches.tregenza_patches()
    zen, az = sun_at("2023-06-21 13:00")
    row = s4.values[2, :145]
    lit = np.flatnonzero(row > 0)
    d = patches.directions(math.radians(90 - zen), math.radians(az), up="Z")
    nearest = np.argsort(-(p.directions(up="Z") @ d))[:4]
    assert sorted(lit.tolist()) == sorted(nearest.tolist())
    assert np.sum(row * p.solid_angle) == pytest.approx(synthetic[1].direct_normal_illuminance[2], rel=1e-9)
    # shares of E_dn in proportion to 1 / (angle from the sun to the patch centre)
    ang = np.arccos(np.clip(p.directions(up="Z")[nearest] @ d, -1, 1))
    share = (1 / ang) / np.sum(1 / ang)
    assert np.allclose(row[nearest] * p.solid_angle[nearest],
                       share * synthetic[1].direct_normal_illuminance[2], rtol=1e-9, atol=0)


def test_sun_directions_in_both_frames(synthetic):
    w = synthetic[0]
    zen, az = sun_at("2023-06-21 13:00")
    alt, a = math.radians(90 - zen), math.radians(az)
    z_up = synthetic[1].sun.direction[2]
    assert np.allclose(z_up, [math.sin(a) * math.cos(alt), math.cos(a) * math.cos(alt), math.sin(alt)],
                       atol=1e-12)
    y = annual.sun_series(w, SITE, up="Y", timestamp_position="center").direction[2]
    assert np.allclose(y, [math.sin(a) * math.cos(alt), math.sin(alt), -math.cos(a) * math.cos(alt)],
                       atol=1e-12)


def test_hour_end_labels_take_the_sun_at_the_half_hour():
    """Weather files label an hour by its end: the default takes the sun at label - 30 min."""
    w = synthetic_weather()
    s = annual.sun_series(w, SITE)
    zen, az = sun_at("2023-06-21 12:30")
    assert s.zenith[2] == pytest.approx(zen, abs=1e-6) and s.azimuth[2] == pytest.approx(az, abs=1e-6)


def test_agrees_with_skies_perez_sky(synthetic):
    """The patch-quadrature normalisation against skies.PerezSky's adaptive one: the rows
    equal PerezSky's patch means to 2e-4 (measured 1.3e-5 at worst over a TMY3 year sample)."""
    _, _, sky_only, _ = synthetic
    p = patches.tregenza_patches()
    for i, label in ((1, "2023-06-21 12:00"), (2, "2023-06-21 13:00")):
        zen, az = sun_at(label)
        dni, dhi = HOURS[label]
        ps = skies.PerezSky(dni, dhi, math.radians(zen), math.radians(az), 172, DEW)
        assert np.allclose(sky_only.values[i, :145], p.mean_luminance(ps), rtol=2e-4, atol=0)


def test_patch_set_choice():
    w = synthetic_weather()
    s = annual.sky_matrix(w, SITE, "MF:2", timestamp_position="center")
    assert s.values.shape == (5, 577 + 1)
    with pytest.raises(ValueError, match="ground_reflectance"):
        annual.sky_matrix(w, SITE, 1, ground_reflectance=1.5)
    with pytest.raises(ValueError, match="sun_spread"):
        annual.sky_matrix(w, SITE, 1, sun_spread=5)


# ---------------------------------------------------------------------------------------------
# annual illuminance
# ---------------------------------------------------------------------------------------------


def test_annual_illuminance_matches_a_loop():
    rng = np.random.default_rng(7)
    sky = rng.uniform(0, 1000, size=(7, 5))
    sky[[0, 3]] = 0.0
    dc = rng.uniform(0, 0.5, size=(3, 5))
    loop = np.zeros((7, 3))
    for h in range(7):
        for q in range(3):
            for k in range(5):
                loop[h, q] += sky[h, k] * dc[q, k]
    e = annual.annual_illuminance(dc, sky, chunk_hours=3)
    assert e.shape == (7, 3)
    assert np.allclose(e, loop, rtol=1e-13, atol=0)
    with pytest.raises(ValueError, match="columns"):
        annual.annual_illuminance(dc[:, :4], sky)


def test_annual_illuminance_of_a_sky_matrix(synthetic):
    """A point with dc = each patch's cosine-weighted solid angle (an unobstructed horizontal
    plane) and 0 for the ground sees the sky-only matrix's horizontal illuminance, row by row."""
    _, _, sky_only, _ = synthetic
    p = patches.tregenza_patches()
    dc = np.append(p.cos_solid_angle, 0.0)[None, :]
    e = annual.annual_illuminance(dc, sky_only, chunk_hours=2)
    loop = np.array([sum(sky_only.values[h, k] * dc[0, k] for k in range(146)) for h in range(5)])
    assert np.allclose(e[:, 0], loop, rtol=1e-13, atol=0)
    assert e[0, 0] == 0 and e[4, 0] == 0


# ---------------------------------------------------------------------------------------------
# metrics
# ---------------------------------------------------------------------------------------------


def test_occupied_hours_lm83_default():
    """Hour-end labels 01:00 .. 24:00 of one day: the hours whose middle is in [8, 18) are
    labelled 09:00 .. 18:00, ten of them."""
    labels = pd.date_range("2023-01-02 01:00", periods=24, freq="h")
    m = annual.occupied_hours(labels)
    assert m.sum() == 10
    assert [t.hour for t in labels[m]] == list(range(9, 19))
    starts = pd.date_range("2023-01-02 00:00", periods=24, freq="h")
    assert [t.hour for t in starts[annual.occupied_hours(starts, timestamp_position="start")]] == list(range(8, 18))
    # a week from Monday 2 January 2023, weekdays only: 5 days x 10 hours
    week = pd.date_range("2023-01-02 01:00", periods=7 * 24, freq="h")
    assert annual.occupied_hours(week, weekdays=range(5)).sum() == 50
    assert annual.occupied_hours(week).sum() == 70


def test_daylight_autonomy():
    occ = np.array([True] * 10 + [False] * 10)
    e = np.zeros((20, 3))
    e[:6, 0] = 3000.0           # 6 of the 10 occupied hours
    e[10:, 0] = 3000.0          # lit unoccupied hours do not count
    e[:10, 1] = 300.0           # exactly the threshold counts
    e[:10, 2] = 299.999
    da = annual.daylight_autonomy(e, occ, 300.0)
    assert da.tolist() == [0.6, 1.0, 0.0]
    # without a mask every row counts: point 0 is lit in 16 of 20
    assert annual.daylight_autonomy(e)[0] == pytest.approx(0.8)


def test_spatial_daylight_autonomy():
    da = np.array([0.5, 0.49, 0.8, 0.0])
    assert annual.spatial_daylight_autonomy(da) == 0.5                      # points 0 and 2
    assert annual.spatial_daylight_autonomy(da, weights=[1, 1, 2, 0]) == pytest.approx(0.75)
    assert annual.spatial_daylight_autonomy(da, weights=[0, 1, 0, 1]) == 0.0
    assert annual.spatial_daylight_autonomy(da, fraction=0.8) == 0.25


def test_annual_sunlight_exposure_250_vs_251_hours():
    occ = np.array([True] * 300 + [False] * 100)
    e = np.zeros((400, 4))
    e[:250, 0] = 1500.0          # 250 hours: not more than 250
    e[:251, 1] = 1500.0          # 251 hours: counts
    e[:251, 2] = 1000.0          # at 1000 lx, not above it
    e[:250, 3] = 1500.0
    e[300:, 3] = 1500.0          # 100 more, unoccupied
    assert annual.sunlit_hours(e, occ).tolist() == [250, 251, 0, 250]
    assert annual.annual_sunlight_exposure(e, occ) == 0.25
    assert annual.annual_sunlight_exposure(e, occ, weights=[1, 3, 0, 0]) == pytest.approx(0.75)
    assert annual.annual_sunlight_exposure(e, occ, hours=249) == 0.75


def test_useful_daylight_illuminance():
    e = np.array([50, 99.9, 100, 2000, 3000, 3000.1, 10000, 0], dtype=float)
    u = annual.useful_daylight_illuminance(e[:, None])
    assert u.below[0] == pytest.approx(3 / 8)   # 50, 99.9, 0
    assert u.useful[0] == pytest.approx(3 / 8)  # 100, 2000, 3000
    assert u.above[0] == pytest.approx(2 / 8)   # 3000.1, 10000
    occ = np.array([True, True, True, True, False, False, False, False])
    u = annual.useful_daylight_illuminance(e[:, None], occ)
    assert (u.below[0], u.useful[0], u.above[0]) == (0.5, 0.5, 0.0)


def test_en17037_daylight_hours():
    m = annual.en17037_daylight_hours([5, 1, 9, 9, 0, 3])
    assert m.tolist() == [True, False, True, True, False, False]
    # ties go to the earlier hour
    assert annual.en17037_daylight_hours([2, 7, 2, 2], count=2).tolist() == [True, True, False, False]
    assert annual.en17037_daylight_hours(np.arange(8760.0)).sum() == 4380
    # many ties: 143 hours at 1 (every 7th), the rest at 0; of 300 hours, the 143 and then
    # the first 157 zero hours in time order
    d = np.zeros(1000)
    d[::7] = 1.0
    expected = d > 0
    zeros_taken = 0
    for i in range(1000):
        if d[i] == 0 and zeros_taken < 300 - 143:
            expected[i] = True
            zeros_taken += 1
    assert annual.en17037_daylight_hours(d, count=300).tolist() == expected.tolist()


def en_matrix():
    """20 points, 4 daylight hours (rows 0-3) and one bright non-daylight hour (row 4):
    row 0: points 0-9 >= 300, all >= 100; row 1: 0-8 >= 300, 0-18 >= 100;
    row 2: 0-11 >= 300, 0-17 >= 100; row 3: nothing >= 100."""
    e = np.full((5, 20), 50.0)
    for row, n300, n100 in ((0, 10, 20), (1, 9, 19), (2, 12, 18)):
        e[row, :n100] = 150.0
        e[row, :n300] = 400.0
    e[4] = 5000.0
    return e, np.array([True, True, True, True, False])


def test_en17037_provision_by_hand():
    e, dh = en_matrix()
    r = annual.en17037_provision(e, dh)
    assert r.daylight_hours == 4
    assert r.target_area_fraction.tolist() == [0.5, 0.45, 0.6, 0.0]
    assert r.minimum_area_fraction.tolist() == pytest.approx([1.0, 0.95, 0.9, 0.0])
    # target: rows 0 and 2 pass (2 of 4); minimum: rows 0 and 1 (19 of 20 = 95 %) pass
    assert r.target_time_fraction == 0.5 and r.minimum_time_fraction == 0.5
    assert r.target_met and r.minimum_met and r.met
    assert not annual.en17037_provision(e, dh, time=0.75).met
    # point 0 weighs 3 (total 22): row 1 now has (3 + 8)/22 = 50 % >= 300 lx; minimum:
    # row 1 21/22 passes, row 2 20/22 = 90.9 % fails
    w = np.ones(20)
    w[0] = 3.0
    r = annual.en17037_provision(e, dh, weights=w)
    assert r.target_time_fraction == 0.75 and r.minimum_time_fraction == 0.5


@pytest.mark.parametrize("values,level", [([800, 600], "high"), ([800, 450], "medium"),
                                          ([350, 120], "minimum"), ([200, 150], None)])
def test_en17037_levels(values, level):
    e = np.array([values, values], dtype=float)
    assert annual.en17037_level(e, np.array([True, True])) == level


def test_annual_metrics_bundle():
    times = pd.date_range("2023-01-02 01:00", periods=48, freq="h")
    occ = annual.occupied_hours(times)
    e = np.where(occ[:, None], [[500.0, 50.0]], 0.0)
    direct = np.where(occ[:, None], [[2000.0, 0.0]], 0.0)
    m = annual.annual_metrics(e, times, E_direct=direct, diffuse_illuminance=occ * 10000.0)
    assert m["occupied_hours"] == 20
    assert m["da300"].tolist() == [1.0, 0.0] and m["sda300_50"] == 0.5
    assert m["sunlit_hours_1000"].tolist() == [20, 0] and m["ase1000_250"] == 0.0
    assert m["udi"].useful.tolist() == [1.0, 0.0]


# ---------------------------------------------------------------------------------------------
# heat map
# ---------------------------------------------------------------------------------------------


def png_size(path):
    data = open(path, "rb").read(24)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


@pytest.mark.parametrize("grid", [False, True])
def test_heatmap_png(tmp_path, grid):
    x, y = np.meshgrid(np.arange(6) * 0.5, np.arange(4) * 0.5)
    xy = np.column_stack([x.ravel(), y.ravel()])[:-2]  # a grid with two cells missing
    values = xy[:, 0] * 100.0
    out = tmp_path / "da.png"
    annual.heatmap_png(out, values, xy, "DA300", units="%", grid=grid, figsize=(6, 5), dpi=100)
    assert png_size(out) == (600, 500)  # 6 x 5 inches at 100 dpi
    assert [f.name for f in tmp_path.iterdir()] == ["da.png"]  # no temporary left
    with pytest.raises(ValueError, match="xy"):
        annual.heatmap_png(out, values[:-1], xy, "bad")


# ---------------------------------------------------------------------------------------------
# a real year
# ---------------------------------------------------------------------------------------------


def test_tmy3_year_smoke():
    w = weather.read_weather(TMY3)
    s = annual.sky_matrix(w)
    assert s.values.shape == (8760, 146)
    n_day = int(s.daytime.sum())
    assert 4000 < n_day < 4800  # about half the year at 36 N
    assert np.all(np.isfinite(s.values)) and np.all(s.values >= 0)
    assert np.all(s.values[~s.daytime] == 0)
    assert np.all(s.values[s.daytime].sum(axis=1) > 0)
    assert not s.skipped
    occ = annual.occupied_hours(w.times)
    assert occ.sum() == 3650  # 365 days x 10 hours
    dh = annual.en17037_daylight_hours(s.diffuse_horizontal_illuminance)
    assert dh.sum() == 4380 and np.all(s.daytime[dh])
    # sun directions are unit vectors on daytime rows, above the horizon (+Z up)
    d = s.sun.direction[s.daytime]
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0) and np.all(d[:, 2] > 0)


# ---------------------------------------------------------------------------------------------
# the vectorised sky matrix against an hour-by-hour evaluation with the scalar skies API
# ---------------------------------------------------------------------------------------------


def patch_rule(p, n):
    """An n x n Gauss-Legendre rule on every patch, built here from the patch limits: nodes in
    sin(altitude) (d omega = d(sin h) d phi) and in azimuth; theta (N, n, 1), phi (N, 1, n)
    and weights (N, n, n) summing to each patch's solid angle."""
    x, w = np.polynomial.legendre.leggauss(n)
    s0, s1 = np.sin(p.alt_lo)[:, None], np.sin(p.alt_hi)[:, None]
    theta = np.arccos(np.clip(s0 + (s1 - s0) * (x + 1) / 2, -1, 1))
    phi = p.az_center[:, None] + p.az_width[:, None] / 2 * x
    weight = ((s1 - s0) / 2 * w)[:, :, None] * (p.az_width[:, None] / 2 * w)[:, None, :]
    return theta[:, :, None], phi[:, None, :], weight


def patch_integrals(fn, p, n):
    """(integral of fn d omega, integral of fn cos(theta) d omega) over each patch, n x n nodes."""
    theta, phi, weight = patch_rule(p, n)
    f = np.broadcast_to(fn(theta, phi), weight.shape)
    return np.sum(f * weight, axis=(1, 2)), np.sum(f * np.cos(theta) * weight, axis=(1, 2))


def weather_rows(w, rows):
    return weather.Weather(w.times[rows], np.asarray(w.dni)[rows], np.asarray(w.dhi)[rows],
                           np.asarray(w.ghi)[rows], np.asarray(w.dew_point)[rows], w.latitude,
                           w.longitude, w.elevation, w.timezone, w.source)


class _Shape:
    """What skies.PerezSky.relative reads: the distribution's (a..e) and the sun (radians)."""

    def __init__(self, params, zen, az):
        self.params, self.sun_zenith, self.sun_azimuth = params, zen, az


def test_tmy3_sky_rows_equal_perez_sky_hour_by_hour():
    """A handful of TMY3 hours (the brightest diffuse hour of every clearness bin, and the
    highest and lowest sun), each rebuilt alone from its DNI, DHI, sun and dew point with the
    scalar skies API, the steps of skies.PerezSky's constructor (clearness, brightness, bin,
    efficacies, distribution parameters; its adaptive normalisation is left out, it takes
    seconds an hour) and PerezSky.relative for the shape.
    (1) The method on its own terms: each patch's order-8 Gauss-Legendre integral of lv,
    normalised so that the cos-weighted sum is E_vd = K_d DHI, equals the vectorised row to
    rounding (1e-11 of the row's maximum).
    (2) Against the truth: the patch means by 48 x 48 nodes a patch, normalised by their own
    cos-weighted sum. An 8-node rule is exact for polynomials of degree 15 only; the sun's
    patch holds the cone kink of exp(d gamma) at gamma = 0, where Gauss-Legendre converges
    only algebraically, and its error reaches the other patches through the normalisation:
    over 80 random hours of this year the worst patch (the sun's) was off by 7e-4 and the
    others by 2e-4, hence 1e-3."""
    w = weather.read_weather(TMY3)
    s = annual.sky_matrix(w, include_sun=False)
    p, sun = s.patches, s.sun
    dhi, dni, dew = np.asarray(w.dhi), np.asarray(w.dni), np.asarray(w.dew_point)
    rows = np.flatnonzero(sun.daytime & (dhi > 0))
    picks = {int(rows[np.argmax(sun.zenith[rows])]), int(rows[np.argmin(sun.zenith[rows])])}
    for b in range(1, 9):
        in_bin = rows[sun.sky_bin[rows] == b]
        picks.add(int(in_bin[np.argmax(sun.diffuse_horizontal_illuminance[in_bin])]))
    assert len(picks) >= 9
    for i in sorted(picks):
        zen, az = math.radians(sun.zenith[i]), math.radians(sun.azimuth[i])
        eps = skies.perez_clearness(float(dni[i]), float(dhi[i]), zen)
        delta = skies.perez_brightness(float(dhi[i]), zen, int(sun.sample_times[i].day_of_year))
        assert skies.perez_bin(eps) == sun.sky_bin[i]
        kd = skies.perez_efficacies(eps, delta, zen, skies.precipitable_water(float(dew[i])))[0]
        e_vd = kd * dhi[i]
        assert sun.diffuse_horizontal_illuminance[i] == pytest.approx(e_vd, rel=1e-12)
        shape = _Shape(skies.perez_parameters(eps, delta, zen), zen, az)

        def lv(theta, phi):
            return skies.PerezSky.relative(shape, theta, phi)

        row = s.values[i, :p.count]
        rel, rel_cos = patch_integrals(lv, p, 8)
        per_hour = e_vd / rel_cos.sum() * rel / p.solid_angle
        assert np.max(np.abs(row - per_hour)) <= 1e-11 * row.max(), i
        rel, rel_cos = patch_integrals(lv, p, 48)
        truth = e_vd / rel_cos.sum() * rel / p.solid_angle
        assert np.all(np.abs(row - truth) <= 1e-3 * truth), i


def test_sky_rows_and_skipped_hours_against_a_loop():
    """25 days of the TMY3 file put at a site it does not belong to (Sydney, labels taken as
    interval starts), so that the sun is low when the file's diffuse light is high and some
    hours' Perez distributions integrate to <= 0 (or overflow): those hours, and only those,
    are ``skipped`` and have no sky. Every row of the vectorised MF:2 matrix against an
    hour-by-hour loop of skies.perez_parameters and PerezSky.relative on the patches' nodes;
    the same matrix on 1 and 3 threads, bit for bit."""
    w = weather_rows(weather.read_weather(TMY3), slice(0, 600))
    site = sun.Site(-33.9, 151.2, 40.0, 10.0)
    kw = dict(site=site, patches=2, include_sun=False, ground_reflectance=0.0,
              timestamp_position="start")
    s = annual.sky_matrix(w, **kw)
    p, ss = s.patches, s.sun
    th, ph, ww = p.quadrature(8)
    expected = np.zeros_like(s.values)
    skipped = []
    with np.errstate(over="ignore", invalid="ignore"):
        for i in np.flatnonzero(ss.daytime & (np.asarray(w.dhi) > 0)):
            zen, az = math.radians(ss.zenith[i]), math.radians(ss.azimuth[i])
            shape = _Shape(skies.perez_parameters(ss.clearness[i], ss.brightness[i], zen), zen, az)
            lv = skies.PerezSky.relative(shape, th, ph)
            rel_cos = float(np.sum(lv * np.cos(th) * ww))
            if not (rel_cos > 0 and math.isfinite(rel_cos)):
                skipped.append(int(i))
                continue
            expected[i, :p.count] = (ss.diffuse_horizontal_illuminance[i] / rel_cos
                                     * np.sum(lv * ww, axis=1) / p.solid_angle)
    assert len(skipped) >= 3 and s.skipped == skipped
    assert np.all(s.values[skipped] == 0)
    assert np.max(np.abs(s.values - expected)) <= 1e-11 * np.max(expected)
    for threads in (1, 3):
        assert np.array_equal(annual.sky_matrix(w, threads=threads, **kw).values, s.values)
