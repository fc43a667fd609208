"""Daylight as distant lights (hirad.daylight.sources): the sun's disk, sky patches and the ground,
USD DistantLight and DomeLight prims, the config's daylight section.

Expected values are closed forms: a uniform sky of luminance L gives pi L on an upward plane and
pi L / 2 on a vertical one, the traditional CIE overcast sky 7 pi / 9 Lz, a ground of reflectance
rho under E_h the luminance rho E_h / pi; UsdLux's normalize rule for a DistantLight of half-angle
t makes its perpendicular illuminance intensity x 2^exposure x colour, and without normalize
L pi sin^2 t. Tolerances are the discretisation's (sky patches, sub-directions).

The engine's distant light (hirad._engine.Luminaire.distant) is exercised only by the tests named
test_engine_*; everything else is pure Python.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

from hirad import usd
from hirad.config import ConfigError, config_from_dict, load_config
from hirad.config.schema import DaylightConfig
from hirad.daylight import patches, skies, sources
from hirad.usd.common import SceneError

UP_Y = np.array([0.0, 1.0, 0.0])


# ----------------------------------------------------------------------------------------------
# the sun's disk
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("angle,samples", [(0.53, 16), (0.53, 7), (10.0, 64), (60.0, 33)])
def test_sun_disk_directions_lie_within_half_the_angle_and_weights_sum_to_one(angle, samples):
    centre = np.array([0.3, 0.8, -0.52])
    centre /= np.linalg.norm(centre)
    sun = sources.sun_light(centre, 1000.0, angle, samples=samples)
    assert sun.count == samples
    assert sun.weights.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(sun.weights, 1.0 / samples)
    off = np.degrees(np.arccos(np.clip(sun.directions @ centre, -1, 1)))
    assert off.max() <= angle / 2 + 1e-9
    assert off.max() > 0.5 * angle / 2  # spread over the disk, not bunched at the centre
    # equal solid angle per direction: cos(theta) steps evenly over [cos(a/2), 1], so its mean
    # is (1 + cos(a/2)) / 2, and the illuminance is scaled for a facing plane to get exactly E
    half = math.radians(angle / 2)
    assert float(sun.directions @ centre @ sun.weights) == pytest.approx((1 + math.cos(half)) / 2, rel=1e-12)
    assert sun.illuminance == pytest.approx(1000.0 * 2 / (1 + math.cos(half)), rel=1e-12)
    np.testing.assert_allclose(sun.irradiance(centre), [[1000.0] * 3], rtol=1e-12)
    # balanced around the centre: the mean direction is the centre
    mean = sun.directions.mean(axis=0)
    assert np.degrees(np.arccos(mean @ centre / np.linalg.norm(mean))) < 0.1 * angle / 2


def test_parallel_sun_is_one_direction_with_the_cosine_law():
    d = np.array([0.0, math.sin(math.radians(40)), math.cos(math.radians(40))])
    sun = sources.sun_light(d, 50000.0, angular_diameter_deg=0.0, colour=(1.0, 0.9, 0.8), samples=16)
    assert sun.count == 1 and np.allclose(sun.directions[0], d)
    np.testing.assert_allclose(sun.irradiance(UP_Y)[0], 50000.0 * math.sin(math.radians(40)) * np.array([1, .9, .8]),
                               rtol=1e-12)
    assert sun.irradiance(-UP_Y)[0].max() == 0.0  # facing away


@pytest.mark.parametrize("bad", [dict(illuminance_lux=-1.0), dict(illuminance_lux=math.nan),
                                 dict(angular_diameter_deg=360.0), dict(samples=0),
                                 dict(direction_to_sun=(0, 0, 0))])
def test_sun_light_refuses_bad_values(bad):
    args = dict(direction_to_sun=(0, 1, 0), illuminance_lux=1.0)
    args.update(bad)
    with pytest.raises(sources.DaylightError):
        sources.sun_light(**args)


# ----------------------------------------------------------------------------------------------
# sky patches and the ground
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mf,subdivisions", [(1, 2), (1, 3), (2, 2)])
def test_uniform_sky_gives_pi_l_up_and_half_that_on_a_vertical_plane(mf, subdivisions):
    lum = 1234.0
    sky = sources.sky_lights(skies.UniformSky(lum), mf, up="Y", ground_reflectance=0.0, subdivisions=subdivisions)
    (light,) = sky.combined
    assert light.weights.sum() == pytest.approx(1.0, abs=1e-12)
    # sum of L Omega over the sky hemisphere: 2 pi L (the black ground adds nothing)
    assert light.illuminance == pytest.approx(2 * math.pi * lum, rel=1e-12)
    # upward: exact (the cells' centres sit at the middle of their sin(altitude) range)
    assert light.irradiance(UP_Y)[0, 1] == pytest.approx(math.pi * lum, rel=1e-12)
    assert sky.horizontal_illuminance[1] == pytest.approx(math.pi * lum, rel=1e-12)
    # vertical, facing east, south and in between: pi L / 2 within the patches' discretisation
    for n in ([1, 0, 0], [0, 0, 1], [math.cos(0.3), 0, math.sin(0.3)]):
        assert light.irradiance(n)[0, 1] == pytest.approx(math.pi * lum / 2, rel=2e-3)
    assert light.irradiance(-UP_Y)[0].max() == 0.0


def test_ground_of_a_uniform_sky_has_luminance_rho_l():
    lum, rho = 100.0, 0.3
    sky = sources.sky_lights(np.full(145, lum), "tregenza", up="Z", ground_reflectance=rho, subdivisions=2)
    # E_h = pi L, so the ground's luminance is rho pi L / pi = rho L
    np.testing.assert_allclose(sky.ground_luminance, rho * lum, rtol=1e-12)
    (ground,) = sky.ground
    assert ground.illuminance == pytest.approx(2 * math.pi * rho * lum, rel=1e-12)
    assert np.all(ground.directions[:, 2] < 0)  # below the horizon, Z up
    up = np.array([0.0, 0.0, 1.0])
    # a plane facing down sees only the ground: pi rho L (exact); facing up sees none of it
    assert ground.irradiance(-up)[0, 0] == pytest.approx(math.pi * rho * lum, rel=1e-12)
    assert ground.irradiance(up)[0].max() == 0.0
    (light,) = sky.combined
    assert light.irradiance(-up)[0, 0] == pytest.approx(math.pi * rho * lum, rel=1e-12)
    # vertical: half the sky and half the ground
    assert light.irradiance([0, 1, 0])[0, 0] == pytest.approx(math.pi * lum / 2 * (1 + rho), rel=2e-3)


def test_sun_lights_the_ground_by_its_horizontal_illuminance():
    alt = math.radians(30)
    sun = sources.sun_light([0.0, math.sin(alt), -math.cos(alt)], 80000.0, 0.0)
    sky = sources.sky_lights(np.zeros(145), 1, up="Y", ground_reflectance=0.2, sun=sun)
    # a black sky: the ground gets the sun alone, E_h = 80000 sin 30 = 40000 lux
    np.testing.assert_allclose(sky.ground_luminance, 0.2 * 40000.0 / math.pi, rtol=1e-12)
    np.testing.assert_allclose(sky.ground_illuminance, 40000.0, rtol=1e-12)


def test_traditional_overcast_sky_gives_seven_ninths_pi_lz():
    lz = 3000.0
    sky = sources.sky_lights(skies.CIEOvercastSky(zenith_luminance=lz), 1, ground_reflectance=0.0, subdivisions=2)
    expected = 7 * math.pi / 9 * lz
    assert sky.horizontal_illuminance[0] == pytest.approx(expected, rel=2e-3)
    assert sky.combined[0].irradiance(UP_Y)[0, 0] == pytest.approx(expected, rel=2e-3)
    # finer cells converge on it
    fine = sources.sky_lights(skies.CIEOvercastSky(zenith_luminance=lz), 2, ground_reflectance=0.0, subdivisions=3)
    assert abs(fine.horizontal_illuminance[0] / expected - 1) < abs(sky.horizontal_illuminance[0] / expected - 1)
    # a patch's mean: L is linear in sin(altitude), and d omega = d(sin h) d phi, so the mean over
    # a band patch is Lz (1 + sin h0 + sin h1) / 3 (Tregenza: band 0 is 0-12 degrees, the cap 84-90)
    sin = lambda deg: math.sin(math.radians(deg))  # noqa: E731
    assert sky.patch_luminance[0, 0] == pytest.approx(lz * (1 + sin(0) + sin(12)) / 3, rel=1e-12)
    assert sky.patch_luminance[100, 0] == pytest.approx(lz * (1 + sin(36) + sin(48)) / 3, rel=1e-12)  # band 3
    assert sky.patch_luminance[-1, 0] == pytest.approx(lz * (1 + sin(84) + 1) / 3, rel=1e-12)


def test_patch_lights_add_up_to_the_combined_sky():
    rng = np.random.default_rng(5)
    lum = rng.uniform(0, 10, size=(145, 3))
    sky = sources.sky_lights(lum, 1, up="Y", ground_reflectance=0.25, subdivisions=2)
    assert len(sky.patches) == 145
    assert len(sky.combined) == 1  # patches of different colours: one light, a tint per direction
    assert sky.combined[0].tints is not None
    normals = rng.normal(size=(20, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    total = sum(s.irradiance(normals) for s in sky.patches + sky.ground)
    combined = sum(s.irradiance(normals) for s in sky.combined)
    np.testing.assert_allclose(combined, total, rtol=1e-10)
    for p in (0, 77, 144):  # a patch's light: its luminance times its solid angle
        spec = sky.patches[p]
        np.testing.assert_allclose(spec.rgb_illuminance, lum[p] * patches.tregenza_patches().solid_angle[p],
                                   rtol=1e-12)


def test_daylight_coefficient_groups_are_unit_luminance_patches_and_ground():
    groups = sources.sky_patch_groups("reinhart2", up="Y", subdivisions=1)
    sp = patches.reinhart_patches(2)
    assert len(groups) == sp.count + 1
    np.testing.assert_allclose([g.illuminance for g in groups[:-1]], sp.solid_angle, rtol=1e-12)
    assert groups[-1].kind == "ground" and groups[-1].illuminance == pytest.approx(2 * math.pi)
    # a unit sky and ground as the sum of the groups: pi up and pi down, but for the cap, whose one
    # direction (the zenith) counts its solid angle 2 pi (1 - s) in full instead of its cosine-
    # weighted pi (1 - s^2), s = sin of its lower altitude 14 alpha, alpha = 90 / 14.5 degrees: the
    # excess is pi (1 - s)^2
    s0 = math.sin(math.radians(14 * 90 / 14.5))
    assert sum(g.irradiance(UP_Y)[0, 0] for g in groups) == pytest.approx(math.pi + math.pi * (1 - s0) ** 2,
                                                                           rel=1e-12)
    assert sum(g.irradiance(-UP_Y)[0, 0] for g in groups) == pytest.approx(math.pi + math.pi * (1 - s0) ** 2,
                                                                            rel=1e-12)
    coeff = sources.sky_coefficients(skies.UniformSky(7.0), "reinhart2", ground_reflectance=0.5, subdivisions=1)
    assert coeff.shape == (sp.count + 1, 3)
    np.testing.assert_allclose(coeff[:-1], 7.0, rtol=1e-12)
    assert coeff[-1, 0] == pytest.approx(0.5 * 7.0 * (1 + (1 - s0) ** 2), rel=1e-12)  # rho E_h / pi


def test_the_frame_is_east_north_up_and_right_handed():
    for up in ("Y", "Z"):
        u, n, e = patches.frame(up)
        # x = east, y = north, z = up: east x north = up (right-handed)
        np.testing.assert_allclose(np.cross(e, n), u, atol=1e-15)
        np.testing.assert_allclose(e, [1, 0, 0], atol=1e-15)
    assert np.allclose(patches.frame("Y")[1], [0, 0, -1]) and np.allclose(patches.frame("Z")[1], [0, 1, 0])


def test_sun_of_a_site_at_solar_noon_is_due_south_at_ninety_minus_latitude_plus_declination(tmp_path):
    # longitude 0, 21 June 2024: the equation of time is -1.6 minutes, so solar noon is 12:01:36
    # UTC; the declination 23.44 degrees: elevation 90 - 45 + 23.44, azimuth 180 (south, +Z for Y-up)
    cfg = DaylightConfig(site={"latitude": 45.0, "longitude": 0.0}, time="2024-06-21T12:01:36",
                         sky={"model": "cie_general", "type": 12}, sun={"direct_normal_illuminance": 80000.0,
                                                                        "angular_diameter": 0.0})
    scene = _scene_arrays(tmp_path)
    lights = sources.daylight_luminaires(scene, cfg, warnings=[])
    sun = lights[0]
    assert sun.kind == "sun" and sun.count == 1
    d = sun.directions[0]
    assert math.degrees(math.asin(d[1])) == pytest.approx(90 - 45 + 23.44, abs=0.15)
    assert math.degrees(math.atan2(d[0], -d[2])) % 360 == pytest.approx(180.0, abs=0.3)
    assert d[2] > 0


# ----------------------------------------------------------------------------------------------
# USD prims
# ----------------------------------------------------------------------------------------------

QUAD = """
def Mesh "floor" {
    point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 0, -1), (0, 0, -1)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
}
"""


def _write(tmp_path: Path, body: str, up="Y", name="scene.usda") -> Path:
    path = tmp_path / name
    path.write_text(f'#usda 1.0\n(\n    metersPerUnit = 1\n    upAxis = "{up}"\n)\n' + textwrap.dedent(QUAD + body))
    return path


def _scene_arrays(tmp_path: Path, body: str = "", up="Y"):
    return usd.read_scene(_write(tmp_path, body, up), daylight=True)


def _distant(name, attrs, rotate_x=None):
    xf = (f"float xformOp:rotateX = {rotate_x}\n    uniform token[] xformOpOrder = [\"xformOp:rotateX\"]"
          if rotate_x is not None else "")
    return f"""
def DistantLight "{name}" {{
    {attrs}
    {xf}
}}
"""


def test_distant_light_normalize_rule_round_trips(tmp_path):
    body = (_distant("a", "float inputs:angle = 0.53\n    float inputs:intensity = 50000\n"
                          "    bool inputs:normalize = 1", rotate_x=-60)
            + _distant("b", "float inputs:angle = 10\n    float inputs:intensity = 1000")
            + _distant("c", "float inputs:angle = 0\n    float inputs:intensity = 700")
            + _distant("d", "float inputs:angle = 200\n    float inputs:intensity = 100\n    bool inputs:normalize = 1")
            + _distant("e", "float inputs:angle = 1\n    float inputs:intensity = 30\n    float inputs:exposure = 1\n"
                            "    color3f inputs:color = (1, 0.5, 0.25)\n    bool inputs:normalize = 1"))
    scene = _scene_arrays(tmp_path, body)
    assert scene.warnings == []
    info = {d.path: d for d in scene.daylight}
    assert set(info) == {"/a", "/b", "/c", "/d", "/e"}
    # normalize: the intensity is the perpendicular illuminance, whatever the angle
    np.testing.assert_allclose(info["/a"].illuminance, 50000.0, rtol=1e-6)
    # not normalized: the disk's luminance is the intensity, E = L pi sin^2(angle / 2)
    np.testing.assert_allclose(info["/b"].illuminance, 1000.0 * math.pi * math.sin(math.radians(5)) ** 2, rtol=1e-6)
    np.testing.assert_allclose(info["/b"].luminance, 1000.0, rtol=1e-6)
    # angle 0: a parallel light of illuminance intensity
    np.testing.assert_allclose(info["/c"].illuminance, 700.0, rtol=1e-6)
    assert info["/c"].luminance is None
    # beyond a hemisphere: sizeFactor (2 - sin^2 t) pi, and only the front hemisphere (pi L) lands
    np.testing.assert_allclose(info["/d"].illuminance, 100.0 / (2 - math.sin(math.radians(100)) ** 2), rtol=1e-6)
    np.testing.assert_allclose(info["/e"].illuminance, 60.0 * np.array([1, 0.5, 0.25]), rtol=1e-6)
    # direction: +Z turned by rotateX(-60) (right-handed): (0, -sin(-60), cos(-60))
    np.testing.assert_allclose(info["/a"].direction, [0, math.sin(math.radians(60)), 0.5], atol=1e-7)
    np.testing.assert_allclose(info["/b"].direction, [0, 0, 1], atol=1e-12)
    # as suns: a plane facing each one receives exactly its illuminance
    lights = sources.daylight_luminaires(scene, DaylightConfig(sun={"samples": 9}), warnings=[])
    by = {s.source: s for s in lights}
    assert all(s.kind == "sun" for s in lights) and len(lights) == 5
    for path, d in info.items():
        np.testing.assert_allclose(by[path].irradiance(d.direction)[0], d.illuminance, rtol=1e-6)
        off = np.degrees(np.arccos(np.clip(by[path].directions @ d.direction, -1, 1)))
        assert off.max() <= d.angle / 2 + 1e-9
    assert by["/e"].illuminance * by["/e"].colour @ sources.Y_WEIGHTS == pytest.approx(
        by["/e"].illuminance, rel=1e-12)  # colour carries Y = 1: illuminance is lux


def test_unhonoured_distant_and_dome_attributes_are_named(tmp_path):
    body = (_distant("sun", "float inputs:intensity = 10\n    float inputs:diffuse = 0.5\n"
                            "    bool inputs:shadow:enable = 0")
            + '\ndef DomeLight "sky" {\n    float inputs:specular = 0\n    float inputs:intensity = 2\n}\n')
    scene = _scene_arrays(tmp_path, body)
    sun = [w for w in scene.warnings if w.startswith("/sun:")]
    assert len(sun) == 1 and "inputs:diffuse = 0.5" in sun[0] and "inputs:shadow:enable = False" in sun[0]
    assert "inputs:intensity" not in sun[0]
    assert any(w.startswith("/sky:") and "inputs:specular = 0" in w for w in scene.warnings)
    assert len(scene.daylight) == 2  # read all the same


def test_without_daylight_the_reader_names_them_as_before(tmp_path):
    path = _write(tmp_path, _distant("sun", "float inputs:intensity = 10"))
    scene = usd.read_scene(path)
    assert scene.daylight == []
    assert any(w.startswith("/sun:") and "DistantLight" in w and "ignored" in w for w in scene.warnings)
    with pytest.raises(SceneError):
        usd.read_scene(path, require_emission=True)
    assert usd.read_scene(path, require_emission=True, daylight=True).daylight  # a sun lights the scene


def test_uniform_dome_emits_from_every_direction(tmp_path):
    body = ('\ndef DomeLight "sky" {\n    float inputs:intensity = 3\n    float inputs:exposure = 1\n'
            '    color3f inputs:color = (1, 0.5, 0.5)\n}\n')
    scene = _scene_arrays(tmp_path, body)
    lights = sources.daylight_luminaires(scene, DaylightConfig(), warnings=[])
    (sky,) = lights
    lum = 6.0 * np.array([1, 0.5, 0.5])
    np.testing.assert_allclose(sky.irradiance(UP_Y)[0], math.pi * lum, rtol=1e-12)
    np.testing.assert_allclose(sky.irradiance(-UP_Y)[0], math.pi * lum, rtol=1e-12)
    # usd_ground: reflectance replaces the lower half by rho E_h / pi
    lights = sources.daylight_luminaires(scene, DaylightConfig(usd_ground="reflectance", ground_reflectance=0.1),
                                         warnings=[])
    np.testing.assert_allclose(lights[0].irradiance(-UP_Y)[0], 0.1 * math.pi * lum, rtol=1e-12)


# --- dome textures ------------------------------------------------------------------------------

H, W = 64, 128


def _texel_rows_cols(lat_deg, lon_deg):
    """Rows and columns whose texel centres lie in the given latitude and longitude ranges, by
    the OpenEXR latlong convention: column x runs from longitude +pi (left) to -pi (right), row
    y from latitude +pi/2 (top) to -pi/2 (bottom)."""
    lon = 180.0 - 360.0 * (np.arange(W) + 0.5) / W
    lat = 90.0 - 180.0 * (np.arange(H) + 0.5) / H
    rows = np.nonzero((lat >= lat_deg[0]) & (lat <= lat_deg[1]))[0]
    cols = np.nonzero((lon >= lon_deg[0]) & (lon <= lon_deg[1]))[0]
    return rows, cols


def _exr(path: Path, spots, background=0.0) -> Path:
    import OpenEXR

    rgb = np.full((H, W, 3), background, dtype=np.float32)
    for lat, lon, value in spots:
        r, c = _texel_rows_cols(lat, lon)
        assert len(r) and len(c)
        rgb[np.ix_(r, c)] = value
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {"RGB": rgb}) as f:
        f.write(str(path))
    return path


def _dome(texture, kind="DomeLight", extra="", xform=""):
    return f"""
def {kind} "sky" {{
    asset inputs:texture:file = @{texture}@
    {extra}
    {xform}
}}
"""


def _brightest_direction(tmp_path, body, up="Y"):
    scene = _scene_arrays(tmp_path, body, up)
    (dome,) = scene.daylight
    upper, lower = sources.dome_texture_luminance(dome.texture, 1, up=scene.up_axis, pole_axis=dome.pole_axis,
                                                  rotation=dome.rotation, texture_format=dome.texture_format,
                                                  prim=dome.path)
    lit = np.nonzero(upper[:, 0] > 0)[0]
    assert len(lit) == 1, lit  # the spot falls in one patch
    assert not lower.any()
    return patches.tregenza_patches().directions(scene.up_axis)[lit[0]]


def _horizontal_angle(d, expected, up):
    h = d - (d @ up) * up
    return math.degrees(math.acos(np.clip(h @ np.asarray(expected, float) / np.linalg.norm(h), -1, 1)))


# spots inside one Tregenza patch each: band 0 (0-12 degrees) has 30 patches of 12 degrees centred
# on north, band 2 (24-36 degrees) 24 patches of 15 degrees, so 90 degrees from north is a centre
@pytest.mark.parametrize("lat,lon,expected", [((3, 9), (-2, 2), (0, 0, 1)), ((27, 33), (87, 93), (1, 0, 0)),
                                              ((27, 33), (-93, -87), (-1, 0, 0)), ((3, 9), (177, 180), (0, 0, -1))])
def test_dome_texture_orientation_follows_usdlux(tmp_path, lat, lon, expected):
    """UsdLux (OpenEXR latlong): longitude 0 at the equator is +Z, +pi/2 is +X, +-pi is -Z; a
    spot at latitude `lat` lights the patch in that direction at that altitude."""
    _exr(tmp_path / "sky.exr", [(lat, lon, 50.0)])
    d = _brightest_direction(tmp_path, _dome("sky.exr"))
    assert _horizontal_angle(d, expected, UP_Y) < 0.5  # the patch's centre: the same azimuth
    assert math.degrees(math.asin(d[1])) == pytest.approx(sum(lat) / 2, abs=0.1)  # and altitude (6 or 30)


def test_dome_pole_is_up_and_its_transform_turns_it(tmp_path):
    _exr(tmp_path / "pole.exr", [((85, 90), (-180, 180), 5.0)])
    assert np.allclose(_brightest_direction(tmp_path, _dome("pole.exr")), [0, 1, 0])
    # rotateY(90) (right-handed) takes +Z to +X: longitude 0 now lights the east
    _exr(tmp_path / "sky.exr", [((27, 33), (-3, 3), 50.0)])
    xf = 'float xformOp:rotateY = 90\n    uniform token[] xformOpOrder = ["xformOp:rotateY"]'
    d = _brightest_direction(tmp_path, _dome("sky.exr", xform=xf))
    assert _horizontal_angle(d, (1, 0, 0), UP_Y) < 0.5


@pytest.mark.parametrize("pole", ["scene", "Z"])
def test_dome_light_1_pole_z_puts_longitude_zero_at_minus_y(tmp_path, pole):
    _exr(tmp_path / "sky.exr", [((3, 9), (-2, 2), 50.0)])
    body = _dome("sky.exr", kind="DomeLight_1", extra=f'uniform token poleAxis = "{pole}"')
    d = _brightest_direction(tmp_path, body, up="Z")
    assert _horizontal_angle(d, (0, -1, 0), np.array([0, 0, 1.0])) < 0.5
    assert math.degrees(math.asin(d[2])) == pytest.approx(6.0, abs=0.1)


def test_dome_texture_patch_mean_is_the_solid_angle_weighted_texel_mean(tmp_path):
    """Half the zenith cap's texels (by longitude) at 8, the rest 0: the cap's mean is 4."""
    _exr(tmp_path / "cap.exr", [((84.5, 90), (0, 180), 8.0)])
    upper, lower = sources.dome_texture_luminance(tmp_path / "cap.exr", 1, up="Y")
    # the cap spans altitudes 84..90; texel rows centred above 84.5 are all inside it and the
    # row centred at 84.375 is outside (6 rows of 2.8125 degrees above 84.375 would be 101.25)
    rows, _ = _texel_rows_cols((84.5, 90), (-180, 180))
    assert 90 - 180 * (rows.max() + 1.5) / H < 84  # the next row is not in the cap
    assert upper[-1] == pytest.approx([4.0] * 3, rel=1e-12)


def test_textured_dome_through_daylight_luminaires_scales_by_intensity(tmp_path):
    _exr(tmp_path / "sky.exr", [], background=0.5)
    body = _dome("sky.exr", extra="float inputs:intensity = 4")
    scene = _scene_arrays(tmp_path, body)
    (sky,) = sources.daylight_luminaires(scene, DaylightConfig(), warnings=[])
    # a uniform texture of 0.5 at intensity 4: a uniform dome of 2, pi x 2 on any plane
    np.testing.assert_allclose(sky.irradiance(UP_Y)[0], 2 * math.pi, rtol=1e-6)
    np.testing.assert_allclose(sky.irradiance([1, 0, 0])[0], 2 * math.pi, rtol=2e-3)


def test_radiance_hdr_texture_is_read(tmp_path):
    import OpenImageIO as oiio

    rgb = np.zeros((H, W, 3), dtype=np.float32)
    r, c = _texel_rows_cols((27, 33), (87, 93))
    rgb[np.ix_(r, c)] = (40.0, 20.0, 10.0)
    out = oiio.ImageOutput.create(str(tmp_path / "sky.hdr"))
    assert out.open(str(tmp_path / "sky.hdr"), oiio.ImageSpec(W, H, 3, "float"))
    assert out.write_image(rgb)
    out.close()
    d = _brightest_direction(tmp_path, _dome("sky.hdr"))
    assert _horizontal_angle(d, (1, 0, 0), UP_Y) < 0.5
    back = sources.read_texture(tmp_path / "sky.hdr")
    np.testing.assert_allclose(back[r[0], c[0]], (40, 20, 10), rtol=0.01)  # RGBE: 8-bit mantissas


def test_missing_texture_is_an_error_naming_the_file_and_the_prim(tmp_path):
    path = _write(tmp_path, _dome("nowhere/sky.exr"))
    with pytest.raises(SceneError) as info:
        usd.read_scene(path, daylight=True)
    msg = str(info.value)
    assert msg.startswith(str(path)) and "/sky.inputs:texture:file" in msg
    assert str(tmp_path / "nowhere" / "sky.exr") in msg


def test_corrupt_texture_is_an_error_naming_the_file_and_the_prim(tmp_path):
    (tmp_path / "sky.exr").write_bytes(b"v/1\x01 not an exr file at all" * 10)
    scene = _scene_arrays(tmp_path, _dome("sky.exr"))
    with pytest.raises(SceneError) as info:
        sources.daylight_luminaires(scene, DaylightConfig(), warnings=[])
    msg = str(info.value)
    assert "/sky" in msg and str(tmp_path / "sky.exr") in msg and "cannot read" in msg


def test_texture_format_other_than_latlong_is_an_error(tmp_path):
    _exr(tmp_path / "sky.exr", [], background=1.0)
    path = _write(tmp_path, _dome("sky.exr", extra='token inputs:texture:format = "mirroredBall"'))
    with pytest.raises(SceneError) as info:
        usd.read_scene(path, daylight=True)
    assert "/sky.inputs:texture:format" in str(info.value) and "mirroredBall" in str(info.value)


# ----------------------------------------------------------------------------------------------
# the config's daylight section
# ----------------------------------------------------------------------------------------------


def _config(tmp_path: Path, daylight_yaml: str) -> Path:
    (tmp_path / "scene.usda").write_text("#usda 1.0\n")
    path = tmp_path / "bake.yaml"
    path.write_text("scene: scene.usda\ndaylight:\n" + textwrap.indent(textwrap.dedent(daylight_yaml), "  "))
    return path


def _error(path: Path) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return info.value


def test_latitude_out_of_range_names_the_key_and_line(tmp_path):
    path = _config(tmp_path, """\
        site:
          longitude: 10
          latitude: 95
        """)
    err = _error(path)
    assert (err.line, err.key) == (5, "daylight.site.latitude")
    assert str(err).startswith(f"{path}:5: daylight.site.latitude:") and "90" in err.problem


@pytest.mark.parametrize("yaml_text,line,key,words", [
    ("site: {latitude: 45, longitude: 10}\ntime: 2024-06-21 12:00:00\nsky: {model: cie_general}\n", 5,
     "daylight.sky", "type"),
    ("site: {latitude: 45, longitude: 10, timezone: Mars/Olympus}\n", 3, "daylight.site.timezone", "Mars/Olympus"),
    ("site: {latitude: 45, longitude: 10}\ntime: 2024-06-21\n", 4, "daylight.time", "time of day"),
    ("time: 21.6.2024 noon\n", 3, "daylight.time", "ISO"),
    ("sky: {model: perez, dni: 500}\n", 3, "daylight.sky", "dhi"),
    ("sky: {model: perez, dni: 500, dhi: 100}\n", 3, "daylight.sky", "daylight.site"),
    ("sky: {model: cie_overcast, zenith_luminance: 10, horizontal_illuminance: 10000}\n", 3, "daylight.sky",
     "not both"),
    ("sky: {model: usd}\nsun: {direct_normal_illuminance: 1000}\n", 4, "daylight.sun", "DistantLight"),
    ("sky: {model: cie_overcast}\nsun: {enabled: true}\n", 4, "daylight.sun", "direct_normal_illuminance"),
    ("patches: reinhart0\n", 3, "daylight.patches", "reinhartN"),
    ("ground_reflectance: 1.5\n", 3, "daylight.ground_reflectance", "1"),
    ("north: [0, 0, 0]\n", 3, "daylight.north", "non-zero"),
    ("sky: {model: sunny}\n", 3, "daylight.sky.model", "cie_overcast"),
    ("sun: {samples: 0}\n", 3, "daylight.sun.samples", "1"),
])
def test_daylight_config_errors_are_located(tmp_path, yaml_text, line, key, words):
    err = _error(_config(tmp_path, yaml_text))
    assert (err.key, err.line) == (key, line), str(err)
    assert words in err.problem, str(err)


def test_daylight_config_reads_and_defaults(tmp_path):
    cfg = load_config(_config(tmp_path, """\
        site: {latitude: 52.5, longitude: 13.4, elevation: 34, timezone: Europe/Berlin}
        time: 2024-06-21 12:00:00
        sky: {model: cie_general, type: 12, horizontal_illuminance: 20000}
        sun: {direct_normal_illuminance: 80000}
        patches: reinhart2
        subdivisions: 3
        north: [0, 0, 1]
        """))
    dl = cfg.daylight
    assert dl.reinhart_mf() == 2 and dl.subdivisions == 3 and dl.time == "2024-06-21T12:00:00"
    assert dl.site.timezone == "Europe/Berlin" and dl.north == (0.0, 0.0, 1.0)
    default = config_from_dict({"scene": str(tmp_path / "scene.usda")}).daylight
    assert default.sky.model == "usd" and default.ground_reflectance == 0.2 and default.patches == "tregenza"


def test_config_overcast_sky_replaces_the_scene_dome(tmp_path):
    scene = _scene_arrays(tmp_path, '\ndef DomeLight "sky" {\n    float inputs:intensity = 2\n}\n')
    cfg = DaylightConfig(sky={"model": "cie_overcast", "horizontal_illuminance": 10000.0}, ground_reflectance=0.2)
    warnings: list[str] = []
    (sky,) = sources.daylight_luminaires(scene, cfg, warnings=warnings)
    assert any(w.startswith("/sky:") and "replaced by daylight.sky.model cie_overcast" in w for w in warnings)
    up = sky.irradiance(UP_Y)[0, 0]
    assert up == pytest.approx(10000.0, rel=2e-3)
    assert sky.irradiance(-UP_Y)[0, 0] == pytest.approx(0.2 * up, rel=1e-12)  # rho x E_h, E_h as delivered


def test_perez_sky_at_night_is_an_error_naming_the_time():
    cfg = DaylightConfig(site={"latitude": 45.0, "longitude": 0.0}, time="2024-06-21T00:00:00",
                         sky={"model": "perez", "dni": 0.0, "dhi": 50.0})
    with pytest.raises(sources.DaylightError) as info:
        sources.config_sky(cfg)
    assert "daylight.time" in str(info.value) and "below the horizon" in str(info.value)


def test_perez_sun_carries_k_b_dni():
    cfg = DaylightConfig(site={"latitude": 39.742476, "longitude": -105.1786, "elevation": 1830.14,
                               "timezone": -7.0}, time="2003-10-17T12:30:30",
                         sky={"model": "perez", "dni": 700.0, "dhi": 100.0})
    sky, (sun,) = sources.config_sky(cfg)
    assert sun.irradiance(sun.directions.mean(axis=0) / np.linalg.norm(sun.directions.mean(axis=0)))[0, 0] == \
        pytest.approx(sky.direct_efficacy * 700.0, rel=1e-6)
    # SPA's example instant: topocentric zenith 50.11 degrees
    centre = sun.directions.mean(axis=0)
    assert math.degrees(math.acos(centre[1] / np.linalg.norm(centre))) == pytest.approx(50.11, abs=0.05)


# ----------------------------------------------------------------------------------------------
# the engine (run once hirad._engine.Luminaire.distant exists)
# ----------------------------------------------------------------------------------------------


def test_engine_distant_light_matches_the_unoccluded_formula():
    """hirad._engine.Luminaire.distant: the engine object carries the spec, and its unoccluded
    irradiance is colour x illuminance x sum_k w_k max(0, n . d_k)."""
    from hirad import _engine

    sun = sources.sun_light([0.2, 0.9, -0.4], 60000.0, 0.53, colour=(1.0, 0.95, 0.9), samples=16)
    sky = sources.sky_lights(skies.CIEOvercastSky(horizontal_illuminance=10000.0), 1, ground_reflectance=0.2)
    for spec in [sun] + sky.combined:
        lum = spec.to_engine()
        assert isinstance(lum, _engine.Luminaire)
        assert lum.name == spec.name
        np.testing.assert_allclose(np.asarray(lum.weights).reshape(-1), spec.weights, rtol=1e-12)
        np.testing.assert_allclose(np.asarray(lum.colour).reshape(-1), spec.colour, rtol=1e-12)
        normals = np.array([[0, 1, 0], [0, -1, 0], [1, 0, 0], [0.2, 0.9, -0.4]], dtype=float)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        points = np.zeros_like(normals)
        np.testing.assert_allclose(np.asarray(lum.irradiance(points, normals)), spec.irradiance(normals),
                                   rtol=1e-9, atol=1e-9)
    # closed forms through the engine: the sun on a plane facing it, the overcast sky upward
    facing = np.array([[0.2, 0.9, -0.4]]) / np.linalg.norm([0.2, 0.9, -0.4])
    np.testing.assert_allclose(np.asarray(sun.to_engine().irradiance(np.zeros((1, 3)), facing))[0],
                               60000.0 * np.array([1.0, 0.95, 0.9]), rtol=1e-9)
    up = np.asarray(sky.combined[0].to_engine().irradiance(np.zeros((1, 3)), UP_Y[None, :]))[0]
    np.testing.assert_allclose(up, 10000.0, rtol=2e-3)
