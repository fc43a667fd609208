"""The daylight results of a bake: daylight factor grids and annual climate-based metrics.

Daylight factor (a sky without sun, usually the CIE overcast sky):

    DF(x) = 100 E(x) / E_h,out

E(x) the illuminance at a grid point (direct sky light through the openings plus the
interreflected light), E_h,out the same sky's illuminance on an unobstructed horizontal plane
outside, computed from the very sky lights the bake used (so the discretisation of the dome into
patches cancels out of the ratio).

Annual (daylight.annual): the sky is cut into patches; each patch of unit luminance and the
ground are light groups solved on the bake's final links, giving the daylight coefficients of
every grid point (hirad.daylight.coefficients). The weather file's hourly Perez skies (with the
sun's light put into the patch that holds it, as Radiance's gendaymtx does) make the sky matrix
(hirad.daylight.annual.sky_matrix); the hourly illuminance is their product. ASE needs the direct
sun alone, and exactly: for every daytime hour the sun's direct normal illuminance times the
transmittance of the ray towards the sun (visibility through the openings and their glazing).
Metrics: DA300, sDA300/50 %, ASE1000/250 h (IES LM-83), UDI 100-3000 lx, EN 17037 provision
(hirad.daylight.annual). A changed weather file or sun orientation needs only the last products:
the coefficients are kept in daylight/coefficients.npz.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import files
from . import annual as _annual
from .coefficients import HitStencil, direct_coefficients

_Y = np.array([0.2126, 0.7152, 0.0722])


def horizontal_illuminance(lights, up_vector) -> float:
    """Y of the unoccluded illuminance the lights give a horizontal plane facing up."""
    up = np.asarray(up_vector, dtype=np.float64).reshape(1, 3)
    return float(sum(float(l.irradiance(up)[0] @ _Y) for l in lights))


def up_vector(up_axis: str) -> np.ndarray:
    return np.array([0.0, 1.0, 0.0]) if str(up_axis).upper() == "Y" else np.array([0.0, 0.0, 1.0])


def grid_table(path: Path, grid, values: dict) -> None:
    """A CSV of the grid's points with one column per named value."""
    lines = ["x,y,z," + ",".join(values)]
    cols = list(values.values())
    for k, p in enumerate(grid.points):
        lines.append(",".join(f"{c:.6g}" for c in p) + "," + ",".join(f"{float(c[k]):.6g}" for c in cols))
    files.write_text(path, "\n".join(lines) + "\n")


def _plane_xy(grid) -> np.ndarray:
    """Grid points as picture coordinates: the two world axes along which the grid's mean normal
    is smallest, in x, y, z order (a Z-up work plane: x, y; a Y-up one: x, z)."""
    p = np.asarray(grid.points, dtype=np.float64)
    n = np.abs(np.asarray(grid.normals, dtype=np.float64).mean(axis=0))
    keep = sorted(np.argsort(n)[:2])
    return p[:, keep]


def daylight_factor(results, lights, up_axis: str, out_dir: Path) -> dict:
    """Daylight factor of every evaluated grid (results: hirad.studies GridResult, lux): per grid a
    CSV, a picture and statistics; returns what report.json says."""
    from ..studies.stats import grid_stats

    eh = horizontal_illuminance(lights, up_vector(up_axis))
    if not eh > 0:
        raise ValueError("daylight factor: the sky gives no horizontal illuminance outside")
    out_dir.mkdir(parents=True, exist_ok=True)
    info = {"outside_horizontal_illuminance_lux": eh, "formula": "DF = 100 E / E_h,out", "grids": {}}
    for r in results:
        df = 100.0 * np.asarray(r.values, dtype=np.float64) / eh
        stats = grid_stats(df, r.grid.weights).as_dict()
        w = np.asarray(r.grid.weights, dtype=np.float64)
        stats["area_fraction_df_2"] = float(w[df >= 2.0].sum() / w.sum()) if w.sum() > 0 else None
        grid_table(out_dir / f"{r.name}.csv", r.grid, {"lux": r.values, "df_percent": df})
        _annual.heatmap_png(out_dir / f"{r.name}.png", df, _plane_xy(r.grid), title=f"Daylight factor: {r.name}",
                            units="DF %")
        info["grids"][r.name] = stats
    return info


def grid_coefficients(field, faces, nv, grid, vertex_luminance: np.ndarray, lights, rays: int,
                      seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(direct, total): (grid points, groups) daylight coefficients of one grid, lux per unit
    luminance (or per lux of a sun bin): every sensor's direct and direct + indirect coefficients
    (hirad.daylight.coefficients), combined into the grid's points by its sensor weights."""
    sp, sn = grid.sensor_points, grid.sensor_normals
    stencil = HitStencil(field, faces, nv, sp, sn, rays, seed)
    direct = direct_coefficients(field, sp, sn, lights)
    total = direct + stencil.apply(vertex_luminance)

    def points(m):
        return np.stack([grid.combine(m[:, g]) for g in range(m.shape[1])], axis=1)
    return points(direct), points(total)


def save_coefficients(path: Path, dc: dict, lights, grids=(), field_faces=None, settings=None) -> None:
    """Everything a new weather file, site or north needs without a new bake (rerun_annual): the
    daylight coefficients (dc_<name>, lux per cd/m^2 or per lux of a sun bin), the lights' names,
    every grid's points and sensors, the surfaces the direct sun is traced against
    (field_faces: corners (F, 4, 3), nv (F,), transmittance (F,)) and the bake's settings."""
    import io
    import json

    arrays = {f"dc_{k}": v for k, v in dc.items()}
    for g in grids:
        for a in ("points", "normals", "weights", "sensor_points", "sensor_normals", "sensor_weights", "sensor_owner"):
            arrays[f"grid_{g.name}__{a}"] = np.asarray(getattr(g, a))
        arrays[f"grid_{g.name}__semi_cylindrical"] = np.array(g.measure.type == "semi_cylindrical")
    if field_faces is not None:
        arrays.update(field_corners=field_faces[0], field_nv=field_faces[1], field_transmittance=field_faces[2])
    buf = io.BytesIO()
    np.savez_compressed(buf, names=np.array([l.name for l in lights]), settings=np.array(json.dumps(settings or {})),
                        **arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    files.write_bytes(path, buf.getvalue())


class StoredGrid:
    """A grid as save_coefficients keeps it: its points, sensors and combine()."""

    def __init__(self, name: str, z, prefix: str):
        self.name = name
        for a in ("points", "normals", "weights", "sensor_points", "sensor_normals", "sensor_weights", "sensor_owner"):
            setattr(self, a, np.asarray(z[f"{prefix}__{a}"]))
        self.semi_cylindrical = bool(z[f"{prefix}__semi_cylindrical"])

    def combine(self, sensor_values) -> np.ndarray:
        e = np.asarray(sensor_values, dtype=np.float64)
        out = np.bincount(self.sensor_owner, weights=self.sensor_weights * e, minlength=len(self.points))
        return np.maximum(out, 0.0) if self.semi_cylindrical else out


def rerun_annual(coefficients: Path, weather: Path, out_dir: Path, *, site=None, north=None,
                 occupied=None, ground_reflectance=None) -> dict:
    """The annual metrics again from a bake's grids/annual/coefficients.npz for another weather
    file, site or north, by matrix products only (no solve): writes into out_dir as the bake does
    and returns the same report part. `north` (a world vector) turns the sky and the sun; the
    coefficients' own sky patches keep their directions, so this is exact for the sky only when
    north is the bake's: a turned building needs its own bake (the report says which north)."""
    import json

    from hirad import _engine
    from hirad.daylight.glazing import angular_table

    z = np.load(coefficients, allow_pickle=False)
    settings = json.loads(str(z["settings"]))
    names = sorted({k[len("grid_"):].split("__")[0] for k in z.files if k.startswith("grid_")})
    grids = {n: StoredGrid(n, z, f"grid_{n}") for n in names}
    tau = np.ascontiguousarray(z["field_transmittance"], dtype=np.float64)
    glass = {"transmittance": tau, "glass_angular": np.asarray(angular_table(), dtype=np.float64)} if np.any(tau > 0) else {}
    field = _engine.SurfaceField(np.ascontiguousarray(z["field_corners"], dtype=np.float64),
                                 np.ascontiguousarray(z["field_nv"], dtype=np.int32), **glass)
    dc_sky = {n: np.asarray(z[f"dc_sky_{n}"]) for n in names}
    sun = {n: np.asarray(z[f"dc_sun_indirect_{n}"]) for n in names}
    north = settings.get("north") if north is None else north
    info = annual_results(dc_sky, sun, grids, str(weather), site, int(settings["patches_mf"]),
                          float(settings["ground_reflectance"] if ground_reflectance is None else ground_reflectance),
                          settings["up_axis"], None if north is None else tuple(north), field, Path(out_dir),
                          occupied=tuple(settings["occupied"]) if occupied is None else tuple(occupied))
    info["coefficients"] = str(coefficients)
    return info


def sun_bins(sky_patches, sun) -> np.ndarray:
    """Per hour the sky patch holding the sun (-1 at night): whose sun-bin solution gives the
    sun's interreflected light."""
    from .sources import patch_index

    alt = np.radians(90.0 - np.asarray(sun.zenith, dtype=np.float64))
    az = np.radians(np.asarray(sun.azimuth, dtype=np.float64))
    return np.where(np.asarray(sun.daytime, bool), patch_index(sky_patches, alt, az), -1)


def annual_illuminance(dc_sky, sun_indirect, grid, field, sky, sensors_direct=None):
    """(hours, points) illuminance of the year and (hours, points) its direct sun alone:

        E(h) = sky_h . DC_sky + E_dn(h) (D_sun(h) + I_bin(h)),

    sky_h the hour's sky-only patch luminances and ground (the sun's light is not put into a
    patch), D_sun the exact direct sun (cos x transmittance towards the sun's true position) and
    I_bin the interreflected light of a 1-lux sun at the centre of the patch that holds it."""
    E = _annual.annual_illuminance(dc_sky, sky)
    day = np.flatnonzero(sky.daytime)
    direct = np.zeros_like(E)
    if len(day):
        edn = np.asarray(sky.direct_normal_illuminance, dtype=np.float64)[day]
        t = field.direct_transmittance(np.ascontiguousarray(grid.sensor_points),
                                       np.ascontiguousarray(grid.sensor_normals),
                                       np.ascontiguousarray(sky.sun_directions()[day])).astype(np.float64)
        d = np.stack([grid.combine(t[:, k]) for k in range(len(day))], axis=0)  # (day hours, points)
        bins = sun_bins(sky.patches, sky.sun)[day]
        ind = np.where((bins >= 0)[:, None], np.asarray(sun_indirect)[:, np.maximum(bins, 0)].T, 0.0)
        direct[day] = edn[:, None] * d
        E[day] += edn[:, None] * (d + ind)
    return E, direct


def annual_results(dc_sky: dict, sun_indirect: dict, grids: dict, weather_path: str, site, patches_mf: int,
                   ground_reflectance: float, up_axis: str, north, field, out_dir: Path,
                   occupied=(8.0, 18.0)) -> dict:
    """The annual metrics of every grid from its sky daylight coefficients `dc_sky[name]`
    (points x (patches + ground)) and its sun bins' interreflected light `sun_indirect[name]`
    (points x patches); writes per grid a CSV and heat maps into out_dir and returns the report's
    part. `field` traces the exact direct sun."""
    import time

    from .weather import read_weather

    t0 = time.perf_counter()
    weather = read_weather(weather_path)
    up = "Y" if str(up_axis).upper() == "Y" else "Z"
    sky = _annual.sky_matrix(weather, site, patches=patches_mf, ground_reflectance=ground_reflectance,
                             include_sun=False, up=up, north=north)
    t_sky = time.perf_counter() - t0
    out_dir.mkdir(parents=True, exist_ok=True)
    info = {"weather": str(weather_path), "hours": int(len(sky.values)), "daytime_hours": int(np.count_nonzero(sky.daytime)),
            "sky_patches": int(sky.patches.count), "method": "sky patches and ground by daylight coefficients; the sun "
            "exact for its direct light, its interreflected light from the sun bin (patch) that holds it",
            "occupied_hours_of_day": list(occupied), "grids": {}, "seconds": {"sky_matrix": t_sky}}
    t_products = t_pictures = 0.0
    for name, coeffs in dc_sky.items():
        grid = grids[name]
        t1 = time.perf_counter()
        E, direct = annual_illuminance(coeffs, sun_indirect[name], grid, field, sky)
        t_products += time.perf_counter() - t1
        m = _annual.annual_metrics(E, sky.times, E_direct=direct,
                                   diffuse_illuminance=sky.diffuse_horizontal_illuminance, weights=grid.weights,
                                   start_hour=occupied[0], end_hour=occupied[1])
        xy = _plane_xy(grid)
        da = m["da300"]
        t1 = time.perf_counter()
        _annual.heatmap_png(out_dir / f"{name}_da300.png", 100 * da, xy, title=f"Daylight autonomy DA300: {name}",
                            units="% of occupied hours")
        _annual.heatmap_png(out_dir / f"{name}_udi.png", 100 * m["udi"].useful, xy,
                            title=f"UDI 100-3000 lx: {name}", units="% of occupied hours")
        _annual.heatmap_png(out_dir / f"{name}_sunlit_hours.png", m["sunlit_hours_1000"], xy,
                            title=f"Direct sun > 1000 lx: {name}", units="occupied hours")
        t_pictures += time.perf_counter() - t1
        grid_table(out_dir / f"{name}.csv", grid, {"da300": da, "udi_below_100": m["udi"].below,
                                                   "udi_100_3000": m["udi"].useful, "udi_above_3000": m["udi"].above,
                                                   "sunlit_hours_1000": m["sunlit_hours_1000"]})
        en = m.get("en17037")
        info["grids"][name] = {
            "points": int(len(grid.points)),
            "occupied_hours": m["occupied_hours"],
            "sDA300/50%": float(m["sda300_50"]),
            "ASE1000/250h": float(m["ase1000_250"]),
            "mean_DA300": float(np.average(da, weights=grid.weights)),
            "mean_UDI_100_3000": float(np.average(m["udi"].useful, weights=grid.weights)),
            "EN17037_level": m.get("en17037_level"),
            "EN17037_minimum_met": None if en is None else bool(en.met),
        }
    info["seconds"]["hourly_products"] = t_products
    info["seconds"]["pictures"] = t_pictures  # the heat maps (matplotlib), outputs like the lightmaps
    return info
