"""Daylight bakes end to end on the project's example room (configs/scenes/daylit_room.usda: a
6 x 4 x 3 m room with a 2.4 x 1.5 m window of 6 mm clear glass in its south wall):

* daylight factor under the CIE overcast sky: the report's outside illuminance is the configured
  sky's (E_h = 10,000 lux, patch quadrature within 0.5 %), every DF is 100 E / E_h, the scene's
  own sky and sun are named as replaced, and the energy balance closes;
* annual: radiosity is linear in its sources, so an hour of the year from the daylight
  coefficients equals the same hour's sky solved on the same links (to 1e-4), and equals a
  separate point-in-time bake of that hour's Perez sky and sun (its own refinement) within 1 %
  on the grid's mean illuminance;
* bad input: a weather file with a bad line, a missing weather file, an impossible site and a
  missing dome texture stop the bake with the file, the key or the line, and leave no output.
"""

from __future__ import annotations

import csv
import datetime as dt
import importlib
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

_engine = pytest.importorskip("hirad._engine")
pvlib = pytest.importorskip("pvlib")

from hirad_e2e_helpers import assert_no_output, run_cli  # noqa: E402

from hirad.config import load_config  # noqa: E402
from hirad.daylight import annual, study  # noqa: E402
from hirad.daylight.sources import DistantLightSpec  # noqa: E402
from hirad.daylight.weather import read_weather  # noqa: E402
from hirad.engine import display_dict  # noqa: E402

B = importlib.import_module("hirad.bake")
ROOT = Path(__file__).resolve().parents[3]
ROOM = ROOT / "configs" / "daylit_room.yaml"
DF = ROOT / "configs" / "daylight_factor.yaml"
TMY3 = os.path.join(os.path.dirname(pvlib.__file__), "data", "723170TYA.CSV")
Y = np.array([0.2126, 0.7152, 0.0722])
QUIET = ["outputs.lightmaps.enabled=false", "outputs.preview.enabled=false", "outputs.usd=false"]


def _csv(path: Path) -> dict:
    rows = list(csv.reader(path.open()))
    return {h: np.array([float(r[i]) for r in rows[1:]]) for i, h in enumerate(rows[0])}


def test_daylight_factor_bake(tmp_path):
    out = tmp_path / "df"
    r = run_cli("bake", DF, "--set", f"output={out}", *[x for o in QUIET for x in ("--set", o)])
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    info = report["grids"]["daylight_factor"]
    assert info["outside_horizontal_illuminance_lux"] == pytest.approx(10000.0, rel=5e-3)
    table = _csv(out / "grids" / "daylight_factor" / "workplane.csv")
    assert np.allclose(table["df_percent"], 100 * table["lux"] / info["outside_horizontal_illuminance_lux"], rtol=1e-5)
    assert info["grids"]["workplane"]["em"] == pytest.approx(table["df_percent"].mean(), rel=1e-3)
    assert (out / "grids" / "daylight_factor" / "workplane.png").stat().st_size > 0
    warnings = " ".join(report.get("warnings", [])) + r.stderr
    assert "/Room/Sky" in warnings and "/Room/Sun" in warnings
    assert report["energy_balance"]["max_relative_error"] < 1e-3
    # the sky's light falls off away from the window (y = 0) along the room's centre line
    centre = np.abs(table["x"] - 3.125) < 0.2
    y, df = table["y"][centre], table["df_percent"][centre]
    assert np.all(np.diff(df[np.argsort(y)]) < 0)


def _hour_overrides(w, h: int) -> list[str]:
    t = w.times[h] - dt.timedelta(minutes=30)  # the hour's middle (TMY3 labels mark its end)
    return ["daylight.sky.model=perez", f"daylight.sky.dni={float(w.dni[h])}", f"daylight.sky.dhi={float(w.dhi[h])}",
            f"daylight.sky.dew_point={float(w.dew_point[h])}", f"daylight.site.latitude={w.latitude}",
            f"daylight.site.longitude={w.longitude}", f"daylight.site.elevation={w.elevation}",
            f"daylight.site.timezone={float(w.timezone)}", f"daylight.time={t.strftime('%Y-%m-%dT%H:%M:%S')}",
            "daylight.usd_ground=reflectance", "daylight.sun.angular_diameter=0"]


def test_annual_hour_is_linear_on_the_links():
    """The coefficients of the bake's own links, times one hour's sky vector, give that hour's
    sky evaluated on the same solution (direct and indirect) to 1e-4."""
    cfg = load_config(ROOM, overrides=[f"daylight.annual.weather={TMY3}"])
    scene, _ = B.read_inputs(cfg)
    lights, groups = B.daylight_inputs(cfg, scene)
    grid = B._build_config_grids(cfg, scene, None)[0]
    m = B.build_engine(scene)
    m.set_luminaires([l.to_engine() for l in lights])
    m.set_light_groups([[] for _ in groups], [[g.to_engine(interleave=True)] for g in groups])
    r = m.solve_hierarchical(B.hierarchy_options(cfg), _engine.SolveOptions(method="jacobi", tolerance=1e-4))
    m.use_leaves_as_patches()
    pa = m.patch_arrays()
    disp = display_dict(m.display_mesh(cfg.reconstruction.crease_angle))
    faces, nv = np.ascontiguousarray(disp["faces"]), np.ascontiguousarray(disp["face_nv"])
    sky = annual.sky_matrix(read_weather(TMY3), None, patches=1, ground_reflectance=0.2, include_sun=False, up="Z")
    h = int(np.flatnonzero(sky.daytime & (np.asarray(sky.sun.zenith) < 50))[0])
    coef = sky.values[h]
    n = len(coef)
    b = sum(coef[k] * np.asarray(r.groups[k].radiosity) for k in range(n))
    field = _engine.SurfaceField(np.ascontiguousarray(disp["points"][faces]), nv.astype(np.int32),
                                 np.ascontiguousarray((m.vertex_values(b) / np.pi)[faces]), None,
                                 transmittance=np.ascontiguousarray(pa.transmittance[disp["face_patch"]]),
                                 glass_angular=np.asarray(__import__("hirad.daylight.glazing", fromlist=["x"]).angular_table()))
    field.set_luminaires([DistantLightSpec(name=g.name, directions=g.directions, weights=g.weights,
                                           illuminance=g.illuminance * coef[k], colour=g.colour).to_engine()
                          for k, g in enumerate(groups[:n])])
    res = field.illuminance(np.ascontiguousarray(grid.sensor_points), np.ascontiguousarray(grid.sensor_normals),
                            np.zeros((len(faces), 3)), cfg.grid_rays, cfg.seed, 4)
    hour = grid.combine((np.asarray(res.direct) + np.asarray(res.indirect)) @ Y)
    vertex = np.stack([(m.vertex_values(np.asarray(g.radiosity)) / np.pi) @ Y for g in r.groups], axis=1)
    _, total = study.grid_coefficients(field, faces, nv, grid, vertex, groups, cfg.grid_rays, cfg.seed)
    assert hour.min() > 0
    assert np.allclose(total[:, :n] @ coef, hour, rtol=1e-4)


@pytest.fixture(scope="module")
def annual_bake(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("annual")
    fine = ["hierarchy.epsilon=1e-5", "hierarchy.min_area=0.004"]
    res = B.bake(ROOM, overrides=[f"daylight.annual.weather={TMY3}", f"output={tmp / 'annual'}", *QUIET, *fine])
    return tmp, res, fine


def test_annual_bake_writes_metrics(annual_bake):
    tmp, res, _ = annual_bake
    info = json.loads((tmp / "annual" / "report.json").read_text())["grids"]["annual"]
    g = info["grids"]["workplane"]
    assert info["hours"] == 8760 and 4000 < info["daytime_hours"] < 4800
    assert 0 <= g["sDA300/50%"] <= 1 and 0 <= g["ASE1000/250h"] <= 1
    table = _csv(tmp / "annual" / "grids" / "annual" / "workplane.csv")
    assert np.allclose(table["udi_below_100"] + table["udi_100_3000"] + table["udi_above_3000"], 1.0)
    assert g["mean_DA300"] == pytest.approx(table["da300"].mean(), rel=1e-5)  # the CSV keeps 6 digits
    assert info["light_groups"] == 2 * 145 + 1


@pytest.mark.parametrize("which", ["sunny", "overcast"])
def test_annual_hour_equals_a_point_in_time_bake(annual_bake, which):
    tmp, res, fine = annual_bake
    w = read_weather(TMY3)
    sky = annual.sky_matrix(w, None, patches=1, ground_reflectance=0.2, include_sun=False, up="Z")
    day = np.flatnonzero(sky.daytime & (np.asarray(sky.sun.zenith) < 50))
    edn = np.asarray(sky.direct_normal_illuminance)[day]
    h = int(day[np.argmax(edn > 40000)] if which == "sunny" else day[np.argmax((edn < 100) & (w.dhi[day] > 150))])
    z = np.load(tmp / "annual" / "grids" / "annual" / "coefficients.npz")
    cfg = load_config(ROOM)
    scene, _ = B.read_inputs(cfg)
    grid = B._build_config_grids(cfg, scene, None)[0]
    E, _ = study.annual_illuminance(z["dc_sky_workplane"], z["dc_sun_indirect_workplane"], grid, res.field, sky)
    out = tmp / f"hour{h}"
    B.bake(ROOM, overrides=[f"output={out}", *QUIET, *fine, *_hour_overrides(w, h)])
    point = _csv(out / "grids" / "workplane.csv")["E_lx"]
    assert E[h].mean() == pytest.approx(point.mean(), rel=0.01)


def _epw_with_bad_line(path: Path) -> int:
    from test_weather import write_epw

    write_epw(path, read_weather(TMY3))
    lines = path.read_text().splitlines()
    lines[8 + 100] = lines[8 + 100].replace(",", ";", 5)
    path.write_text("\n".join(lines) + "\n")
    return 8 + 100 + 1


def test_bad_weather_file_is_named_with_its_line(tmp_path):
    epw = tmp_path / "bad.epw"
    line = _epw_with_bad_line(epw)
    out = tmp_path / "out"
    r = run_cli("bake", ROOM, "--set", f"output={out}", "--set", f"daylight.annual.weather={epw}",
                *[x for o in QUIET for x in ("--set", o)])
    assert r.returncode == 2  # a bad input file, found before anything runs
    assert f"{epw}:{line}" in r.stderr and "daylight.annual.weather" in r.stderr
    assert_no_output(out)


def test_missing_weather_file_and_impossible_site_are_config_errors(tmp_path):
    out = tmp_path / "out"
    r = run_cli("bake", ROOM, "--set", f"output={out}", "--set", f"daylight.annual.weather={tmp_path / 'none.epw'}")
    assert r.returncode != 0 and "weather file not found" in r.stderr and "daylight.annual.weather" in r.stderr
    cfg = tmp_path / "site.yaml"
    cfg.write_text(ROOM.read_text().replace("scene: scenes/", f"scene: {ROOM.parent}/scenes/")
                   .replace("daylight:\n", "daylight:\n  site: {latitude: 95, longitude: 0}\n"))
    r = run_cli("bake", cfg, "--set", f"output={out}")
    assert r.returncode != 0 and "daylight.site.latitude" in r.stderr and f"{cfg}:" in r.stderr
    assert_no_output(out)


def test_missing_dome_texture_is_named(tmp_path):
    scene = tmp_path / "room.usda"
    text = (ROOT / "configs" / "scenes" / "daylit_room.usda").read_text()
    scene.write_text(text.replace('float inputs:intensity = 3000\n', 'float inputs:intensity = 3000\n'
                                  '        asset inputs:texture:file = @missing_sky.exr@\n', 1))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(ROOM.read_text().replace("scene: scenes/daylit_room.usda", f"scene: {scene}"))
    out = tmp_path / "out"
    r = run_cli("bake", cfg, "--set", f"output={out}")
    assert r.returncode != 0 and "missing_sky.exr" in r.stderr and "/Room/Sky" in r.stderr
    assert_no_output(out)


def test_annual_rerun_from_coefficients_needs_no_solve(annual_bake, tmp_path):
    """`hirad annual COEFFICIENTS WEATHER`: the same weather file gives the bake's metrics again
    (the same products from the stored coefficients, grids and surfaces); an EPW of the same
    year gives them too (its reader and the TMY3 reader agree); a bad line is named."""
    tmp, _, _ = annual_bake
    npz = tmp / "annual" / "grids" / "annual" / "coefficients.npz"
    baked = json.loads((tmp / "annual" / "report.json").read_text())["grids"]["annual"]["grids"]["workplane"]
    out = tmp_path / "again"
    r = run_cli("annual", npz, TMY3, "-o", out)
    assert r.returncode == 0, r.stderr
    again = json.loads((out / "annual.json").read_text())["grids"]["workplane"]
    for key in ("sDA300/50%", "ASE1000/250h", "mean_DA300", "mean_UDI_100_3000"):
        assert again[key] == pytest.approx(baked[key], abs=1e-12), key
    assert (out / "workplane_da300.png").is_file()
    epw = tmp_path / "bad.epw"
    line = _epw_with_bad_line(epw)
    r = run_cli("annual", npz, epw, "-o", tmp_path / "bad")
    assert r.returncode == 2 and f"{epw}:{line}" in r.stderr
    assert_no_output(tmp_path / "bad")


def test_daylit_bake_is_the_same_bits_whatever_the_thread_count(tmp_path):
    """Sky, sun and glass (interleaved sky directions, the glass filter's factors) give the same
    bits on one thread as on two."""
    outs = []
    for threads in (1, 2):
        out = tmp_path / f"t{threads}"
        r = run_cli("bake", ROOM, "--threads", threads, "--set", f"output={out}", "--set", "hierarchy.epsilon=3e-4",
                    *[x for o in QUIET for x in ("--set", o)])
        assert r.returncode == 0, r.stderr
        outs.append((out / "grids" / "workplane.csv").read_bytes())
    assert outs[0] == outs[1]
