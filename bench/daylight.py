"""hirad and Radiance side by side on daylight (issue 16): daylight factor and annual daylight of
the example room configs/scenes/daylit_room.usda, time and agreement, in one run.

    python bench/daylight.py [--quick] [--only df|annual] [--processes 2] [--keep DIR]
        [--ab 12] [--ad 4096 --as 1024 --aa 0.1 --ar 256 --lw-rtrace 1e-4] [--dc-ad 16384 --lw 3e-5]

The room (6 x 4 x 3 m, Z up, north +Y, a 2.4 x 1.5 m south window of 6 mm clear glass) is read
with hirad's own reader (`hirad.usd.read_scene(daylight=True)`) and written as a Radiance scene:
one `polygon` per face, `plastic` (no specular, roughness 0) of the face's RGB reflectance for
opaque faces (two-sided, unlike hirad's faces; nothing outside the room sees their backs),
Radiance `glass` for the faces with a transmittance Tn > 0, of transmissivity
tn = (sqrt(0.8402528435 + 0.0072522239 Tn^2) - 0.9166530661) / 0.0036261119 / Tn (Tn = 0.88 ->
tn = 0.9584). Radiance's glass takes its angular transmittance from Fresnel's equations and
reflects specularly; hirad's from the Tregenza-Sharples polynomial, reflecting its 0.08 diffusely.

1. Daylight factor (configs/daylight_factor.yaml: CIE overcast sky, 10,000 lx, ground 0.2).
   hirad: `hirad bake configs/daylight_factor.yaml` (a child process, timed whole), its
   grids/daylight_factor/workplane.csv (240 points: work plane 0.8 m, 0.5 m border, 0.25 m
   cells) and report.json's grids.daylight_factor. Radiance: `gensky 3 21 12 -c -B E_h/179`
   (CIE overcast; -B is the horizontal diffuse irradiance in W/m^2, 179 lm/W; gensky's ground
   of reflectance 0.2) with the usual `skyfunc glow` hemispheres up (sky) and down (ground), and
   `rtrace -I -h` at the same points facing up (one ambient file shared by -n processes; -lr -12:
   Russian roulette below -lw). E = 179 (0.265 R + 0.670 G + 0.065 B) and DF = 100 E / E_h,out,
   E_h,out the same sky's illuminance on an unobstructed horizontal plane, computed by rtrace on
   the sky alone (hirad divides by its own sky's E_h,out too; gensky's skybright blends sky and
   ground within a few degrees of the horizon, so the Radiance sky's E_h is not exactly the
   nominal 10,000 lx: both are printed, and DF with Rec.709 weights).
2. Annual (configs/daylit_room.yaml with daylight.annual.weather = pvlib's TMY3 723170TYA.CSV,
   Greensboro NC). hirad: `hirad bake` (a child process, timed whole; its lightmaps and preview
   stay on, as the config has them), report.json's grids.annual (sDA, ASE, mean DA300, seconds)
   and timings, grids/annual/workplane.csv (DA300 per point) and the daylight coefficients it
   keeps (grids/annual/coefficients.npz). Radiance, the two-phase method: the weather file as a
   .wea written here from hirad.daylight.weather.read_weather (place/latitude/longitude/time_zone/
   site_elevation header, west positive; then month day hour DNI DHI, the hour the middle of
   the file's hour in local standard time), `gendaymtx -m 1 -c 1 1 1` (Tregenza: 145 patches +
   the ground, a grey sky like hirad's; dew point 11 C as a .wea has none; the sun spread over
   its nearest patches; no -r: both frames are +X east, +Y north, +Z up), the daylight
   coefficients by `rcontrib -I+ -e MF:1 -f reinhart.cal -b rbin -bn Nrbins -m sky_glow` with
   sky and ground hemispheres of one `glow` modifier of unit radiance (ground = bin 0), then
   `dctimestep | rmtxop -c 47.435 119.93 11.635` -> hourly illuminance (8760 x 240). DA300 and
   sDA300/50 % of both through the same code (hirad.daylight.annual: occupied_hours 8:00-18:00
   local standard time, daylight_autonomy, spatial_daylight_autonomy).
   Cross-checks that locate a difference: hirad's sky coefficients times the Radiance sky matrix
   (the same sky and sun-in-patches: the transport alone differs), the illuminance under a
   uniform sky of unit luminance (sum of the sky-patch coefficients), and that sum split into
   the patches centred on a multiple of 45 degrees of azimuth and the others.
Prints the wall time of each part (hirad: the bake, the stages of report.json; Radiance:
rtrace for DF; gendaymtx + rcontrib + dctimestep | rmtxop for annual), the ratios and the
agreement. Every timing line states the 1-minute load average at its start (the machine may be
shared). --quick: rtrace -ad 512 -as 128 -ar 128, rcontrib -ad 1024 -lw 5e-4 (same -ab).
Radiance's binaries come with PyPI `pyradiance` (the bench extra), located, not imported
(bench/radiance.py's radiance_env).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from grids import ROOT, load  # noqa: E402  (the project root and the load line of bench/grids.py)
from radiance import radiance_env  # noqa: E402  (pyradiance's binaries on PATH, RAYPATH its lib)

SCENE = ROOT / "configs/scenes/daylit_room.usda"
DF_CONFIG = ROOT / "configs/daylight_factor.yaml"
ANNUAL_CONFIG = ROOT / "configs/daylit_room.yaml"
RAD_RGB = np.array([0.265, 0.670, 0.065])  # Radiance's photometric weights (x 179 lm/W)
REC709 = np.array([0.2126, 0.7152, 0.0722])  # hirad's
EFFICACY = 179.0


def radiance_tn(tn_normal: float) -> float:
    """Radiance glass transmissivity for a normal transmittance Tn (n = 1.52, the manual's form)."""
    t = float(tn_normal)
    return (np.sqrt(0.8402528435 + 0.0072522239 * t * t) - 0.9166530661) / 0.0036261119 / t


def write_room(scene, path: Path) -> dict:
    """The scene's faces as a Radiance file: plastic of the face reflectance, glass where the
    face transmits. Returns counts."""
    counts = scene.face_vertex_counts
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tau = np.zeros(scene.num_faces) if scene.face_transmittance is None else scene.face_transmittance
    mats: dict[tuple, str] = {}
    out = []
    n_glass = 0
    for f in range(scene.num_faces):
        if tau[f] > 0:
            tn = radiance_tn(tau[f])
            key = ("glass", round(tn, 6))
            if key not in mats:
                mats[key] = f"glass{len(mats)}"
                out.append(f"void glass {mats[key]}\n0\n0\n3 {tn:.6f} {tn:.6f} {tn:.6f}\n")
            n_glass += 1
        else:
            rho = tuple(round(float(x), 6) for x in scene.face_reflectance[f])
            key = ("plastic",) + rho
            if key not in mats:
                mats[key] = f"mat{len(mats)}"
                out.append(f"void plastic {mats[key]}\n0\n0\n5 {rho[0]:g} {rho[1]:g} {rho[2]:g} 0 0\n")
        poly = scene.points[scene.face_vertex_indices[starts[f]:starts[f] + counts[f]]]
        out.append(f"{mats[key]} polygon face{f}\n0\n0\n{3 * len(poly)} "
                   + " ".join(f"{v:.9g}" for v in np.asarray(poly, dtype=np.float64).ravel()) + "\n")
    path.write_text("".join(out))
    return {"faces": int(scene.num_faces), "glass": n_glass, "materials": len(mats)}


def run(cmd: list[str], env: dict, cwd: Path, stdin: bytes | None = None, stdout=subprocess.PIPE) -> bytes:
    r = subprocess.run(cmd, input=stdin, stdout=stdout, stderr=subprocess.PIPE, env=env, cwd=cwd, check=False)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd[:3])} ... failed ({r.returncode}): {r.stderr.decode(errors='replace')[-2000:]}")
    return r.stdout if stdout is subprocess.PIPE else b""


def oconv(files: list[Path], octree: Path, env: dict, cwd: Path) -> None:
    with open(octree, "wb") as f:
        run(["oconv", "-f", *map(str, files)], env, cwd, stdout=f)


def rtrace_irradiance(env: dict, tmp: Path, octree: str, opts: list[str], stdin: bytes, count: int,
                      processes: int) -> tuple[np.ndarray, float]:
    """`rtrace -I+` with `opts` and a fresh ambient file tmp/df.amb shared by `processes`: the (count, 3)
    RGB irradiance at the points of `stdin`, and the wall time."""
    amb = tmp / "df.amb"
    if amb.exists():
        amb.unlink()
    t0 = time.perf_counter()
    raw = run(["rtrace", "-h", "-I+", "-fad", *opts, "-af", str(amb), "-n", str(processes), str(tmp / octree)],
              env, tmp, stdin=stdin)
    seconds = time.perf_counter() - t0
    rgb = np.frombuffer(raw, dtype=np.float64).reshape(-1, 3)
    if len(rgb) != count:
        raise SystemExit(f"rtrace returned {len(rgb)} values for {count} points")
    return rgb, seconds


def points_text(pts: np.ndarray) -> bytes:
    return "".join(f"{x:.9g} {y:.9g} {z:.9g} 0 0 1\n" for x, y, z in pts).encode()


def read_matrix(data: bytes) -> tuple[dict, np.ndarray]:
    """A Radiance matrix (header, blank line, binary float64 or float32 data): (header fields, data)."""
    end = data.index(b"\n\n")
    head = {}
    for line in data[:end].decode(errors="replace").splitlines():
        if "=" in line:
            k, v = line.split("=", 1)
            head[k.strip()] = v.strip()
    fmt = head.get("FORMAT", "")
    dt = np.float64 if fmt == "double" else np.float32 if fmt == "float" else None
    if dt is None:
        raise SystemExit(f"unexpected matrix format {fmt!r}")
    return head, np.frombuffer(data[end + 2:], dtype=dt)


def hirad_bake(config: Path, out: Path, sets: list[str]) -> float:
    exe = Path(sys.executable).parent / "hirad"
    cmd = [str(exe), "bake", str(config), "--set", f"output={out}"] + [a for s in sets for a in ("--set", s)]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, check=False)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"hirad bake {config.name} failed ({r.returncode}): {r.stderr.decode(errors='replace')[-2000:]}")
    return dt


def read_csv(path: Path) -> dict:
    lines = path.read_text().splitlines()
    names = lines[0].split(",")
    a = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:] if ln.strip()])
    return {n: a[:, i] for i, n in enumerate(names)}


def rel_stats(h: np.ndarray, r: np.ndarray) -> str:
    rel = (h - r) / r
    return (f"relative difference hirad vs Radiance per point: mean {rel.mean():+.2%}, RMS "
            f"{np.sqrt(np.mean(rel ** 2)):.2%}, largest |.| {np.abs(rel).max():.2%}")


# ---------------------------------------------------------------------------------------------
# daylight factor
# ---------------------------------------------------------------------------------------------


def daylight_factor(args, env: dict, tmp: Path, room: Path) -> None:
    print("== Daylight factor: CIE overcast sky (configs/daylight_factor.yaml) ==")
    out = tmp / "df"
    ld = load()
    t_bake = hirad_bake(DF_CONFIG, out, [])
    rep = json.loads((out / "report.json").read_text())
    info = rep["grids"]["daylight_factor"]
    eh_h = float(info["outside_horizontal_illuminance_lux"])
    tab = read_csv(out / "grids/daylight_factor/workplane.csv")
    pts = np.stack([tab["x"], tab["y"], tab["z"]], axis=1)
    df_h = tab["df_percent"]
    timings = rep.get("timings_s", {})
    print(f"hirad bake: {t_bake:.1f} s wall ({ld}; stages: solve {timings.get('hierarchical solve', 0):.1f} s, "
          f"grids {timings.get('grids', 0):.1f} s, daylight factor {timings.get('daylight factor', 0):.2f} s, "
          f"total {timings.get('total', 0):.1f} s), {len(pts)} points, E_h,out {eh_h:.1f} lx")

    eh_nominal = 10000.0
    b = eh_nominal / EFFICACY
    sky_txt = run(["gensky", "3", "21", "12", "-c", "-B", f"{b:.6f}"], env, tmp).decode()
    (tmp / "overcast.rad").write_text(
        sky_txt + "\nskyfunc glow sky_glow\n0\n0\n4 1 1 1 0\n\nsky_glow source sky\n0\n0\n4 0 0 1 180\n\n"
        "skyfunc glow ground_glow\n0\n0\n4 1 1 1 0\n\nground_glow source ground\n0\n0\n4 0 0 -1 180\n")
    oconv([room, tmp / "overcast.rad"], tmp / "df.oct", env, tmp)
    oconv([tmp / "overcast.rad"], tmp / "sky_only.oct", env, tmp)
    # the sky's own horizontal illuminance (nothing in the way): one point, -ab 1 sees the glow
    e_out = np.frombuffer(run(["rtrace", "-h", "-I+", "-ab", "1", "-ad", "65536", "-aa", "0", "-lw", "1e-6",
                               "-fad", str(tmp / "sky_only.oct")], env, tmp,
                              stdin=b"0 0 0 0 0 1\n"), dtype=np.float64)
    eh_r = EFFICACY * float(e_out @ RAD_RGB)

    opts = ["-ab", str(args.ab), "-ad", str(args.ad), "-as", str(args.as_), "-aa", f"{args.aa:g}",
            "-ar", str(args.ar), "-lw", f"{args.lw_rtrace:g}", "-lr", "-12", "-dj", "0", "-st", "0"]
    ld = load()
    rgb, t_rtrace = rtrace_irradiance(env, tmp, "df.oct", opts, points_text(pts), len(pts), args.processes)
    e_r = EFFICACY * rgb @ RAD_RGB
    df_r = 100.0 * e_r / eh_r
    df_r709 = 100.0 * EFFICACY * (rgb @ REC709) / (EFFICACY * float(e_out @ REC709))
    print(f"Radiance: gensky -c -B {b:.4f} (zenith {sky_txt.split()[-2]} W/(m^2 sr), ground {sky_txt.split()[-1]}), "
          f"E_h,out by rtrace on the sky alone {eh_r:.1f} lx (nominal {eh_nominal:.0f})")
    print(f"rtrace -I {' '.join(opts)} -n {args.processes}: {t_rtrace:.1f} s wall ({ld})")
    print(f"{'':10s} {'mean DF %':>10s} {'min DF %':>9s} {'max DF %':>9s} {'wall s':>8s}")
    print(f"{'hirad':10s} {df_h.mean():10.3f} {df_h.min():9.3f} {df_h.max():9.3f} {t_bake:8.1f}   (the whole bake)")
    print(f"{'Radiance':10s} {df_r.mean():10.3f} {df_r.min():9.3f} {df_r.max():9.3f} {t_rtrace:8.1f}   (rtrace only)")
    print(rel_stats(df_h, df_r))
    y = pts[:, 1]
    parts = []
    for lo, hi in ((0.0, 1.5), (1.5, 2.5), (2.5, 4.0)):
        m = (y >= lo) & (y < hi)
        parts.append(f"y {lo:g}-{hi:g} m ({int(m.sum())}): {np.mean(df_h[m] / df_r[m] - 1):+.2%}")
    print("mean relative difference by distance from the window: " + ", ".join(parts))
    print(f"Radiance with Rec.709 weights instead of (0.265, 0.670, 0.065): mean DF {df_r709.mean():.3f} % "
          f"({df_r709.mean() / df_r.mean() - 1:+.2%}); with the nominal 10,000 lx: mean DF "
          f"{100 * e_r.mean() / eh_nominal:.3f} %")
    print(f"speed: rtrace takes {t_rtrace / t_bake:.2f}x the wall time of hirad's whole bake (both on "
          f"{os.cpu_count()} cores)")
    np.save(tmp / "df_radiance.npy", df_r)
    print()


# ---------------------------------------------------------------------------------------------
# annual
# ---------------------------------------------------------------------------------------------


def write_wea(weather, path: Path) -> int:
    """A .wea of the weather (DNI, DHI W/m^2); the hour is the middle of each hour of the file,
    local standard time (the file labels an hour by its end). Radiance's longitude and time zone
    are positive west."""
    from hirad.daylight.annual import sample_times

    mid = sample_times(weather.times, "end")
    name = Path(weather.source).stem.replace(" ", "_")
    lines = [f"place {name}_site", f"latitude {weather.latitude:.4f}", f"longitude {-weather.longitude:.4f}",
             f"time_zone {-15.0 * weather.timezone:.1f}", f"site_elevation {weather.elevation:.1f}",
             "weather_data_file_units 1"]
    hour = mid.hour.to_numpy() + mid.minute.to_numpy() / 60.0
    dni = np.nan_to_num(np.clip(weather.dni, 0, None))
    dhi = np.nan_to_num(np.clip(weather.dhi, 0, None))
    for mo, da, hr, a, d in zip(mid.month.to_numpy(), mid.day.to_numpy(), hour, dni, dhi):
        lines.append(f"{mo} {da} {hr:.3f} {a:.0f} {d:.0f}")
    path.write_text("\n".join(lines) + "\n")
    return len(lines) - 6


def annual(args, env: dict, tmp: Path, room: Path) -> None:
    import pvlib

    from hirad.daylight import annual as ann
    from hirad.daylight.weather import read_weather

    print("== Annual daylight: TMY3 723170TYA (pvlib), configs/daylit_room.yaml ==")
    tmy = Path(os.path.join(os.path.dirname(pvlib.__file__), "data", "723170TYA.CSV"))
    out = tmp / "annual"
    ld = load()
    t_bake = hirad_bake(ANNUAL_CONFIG, out, [f"daylight.annual.weather={tmy}"])
    rep = json.loads((out / "report.json").read_text())
    a = rep["grids"]["annual"]
    g = a["grids"]["workplane"]
    sec = a["seconds"]
    st = rep.get("timings_s", {})
    t_annual = float(st.get("annual daylight", 0.0))
    t_groups = float(sec.get("group_solves", 0.0))
    # the heat-map pictures are outputs (like the lightmaps): timed apart from the computation
    t_pictures = float(sec.get("pictures", 0.0))
    t_annual -= t_pictures
    tab = read_csv(out / "grids/annual/workplane.csv")
    pts = np.stack([tab["x"], tab["y"], tab["z"]], axis=1)
    da_h = tab["da300"]
    outputs_s = sum(float(st.get(k, 0.0)) for k in ("lightmaps", "preview", "write USD"))
    print(f"hirad bake: {t_bake:.1f} s wall ({ld}); report: total {st.get('total', 0):.1f} s, hierarchical solve "
          f"{st.get('hierarchical solve', 0):.1f} s (of which the {a.get('light_groups')} light groups' solves "
          f"{t_groups:.1f} s), annual daylight stage {t_annual:.1f} s (sky matrix {sec.get('sky_matrix', 0):.1f}, "
          f"coefficients {sec.get('coefficients', 0):.2f}, hourly products {sec.get('hourly_products', 0):.2f}; "
          f"without its heat-map pictures, {t_pictures:.2f} s), "
          f"outputs the comparison does not need (lightmaps, preview, USD) {outputs_s:.1f} s")
    print(f"hirad: {g['points']} points, {g['occupied_hours']} occupied hours, mean DA300 {g['mean_DA300']:.4f}, "
          f"sDA300/50% {g['sDA300/50%']:.4f}, ASE1000/250h {g['ASE1000/250h']:.4f}, "
          f"{a['daytime_hours']} daytime hours of {a['hours']}")

    weather = read_weather(tmy)
    hours = write_wea(weather, tmp / "site.wea")
    occ = ann.occupied_hours(weather.times, 8.0, 18.0)
    (tmp / "sky_dc.rad").write_text("void glow sky_glow\n0\n0\n4 1 1 1 0\n\nsky_glow source sky\n0\n0\n4 0 0 1 180\n\n"
                                    "sky_glow source ground\n0\n0\n4 0 0 -1 180\n")
    oconv([room, tmp / "sky_dc.rad"], tmp / "dc.oct", env, tmp)

    ld = load()
    t0 = time.perf_counter()
    with open(tmp / "sky.mtx", "wb") as f:
        gd = subprocess.run(["gendaymtx", "-m", "1", "-c", "1", "1", "1", "-of", str(tmp / "site.wea")], stdout=f,
                            stderr=subprocess.PIPE, env=env, cwd=tmp, check=False)
    t_gendaymtx = time.perf_counter() - t0
    if gd.returncode != 0:
        raise SystemExit(f"gendaymtx failed: {gd.stderr.decode(errors='replace')[-2000:]}")
    n_bright = gd.stderr.decode(errors="replace").count("unusually bright")
    dc_opts = ["-ab", str(args.ab), "-ad", str(args.dc_ad), "-lw", f"{args.lw:g}", "-lr", "-12", "-dj", "0", "-st", "0"]
    ld_rc = load()
    t0 = time.perf_counter()
    raw = run(["rcontrib", "-h", "-I+", "-fad", *dc_opts, "-n", str(args.processes), "-e", "MF:1", "-f",
               "reinhart.cal", "-b", "rbin", "-bn", "Nrbins", "-m", "sky_glow", str(tmp / "dc.oct")], env, tmp,
              stdin=points_text(pts))
    t_rcontrib = time.perf_counter() - t0
    dc = np.frombuffer(raw, dtype=np.float64)
    n_bins = dc.size // (3 * len(pts))
    dc = dc.reshape(len(pts), n_bins, 3)
    # the coefficients as a Radiance matrix for dctimestep
    with open(tmp / "dc.mtx", "wb") as f:
        f.write(f"#?RADIANCE\nNROWS={len(pts)}\nNCOLS={n_bins}\nNCOMP=3\nFORMAT=double\n\n".encode())
        f.write(np.ascontiguousarray(dc).tobytes())
    ld_ts = load()
    t0 = time.perf_counter()
    ts = subprocess.Popen(["dctimestep", "-od", str(tmp / "dc.mtx"), str(tmp / "sky.mtx")], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, env=env, cwd=tmp)
    mx = subprocess.run(["rmtxop", "-fd", "-c", "47.435", "119.93", "11.635", "-"], stdin=ts.stdout,
                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=tmp, check=False)
    ts.stdout.close()
    ts_err = ts.stderr.read()
    if ts.wait() != 0 or mx.returncode != 0:
        raise SystemExit(f"dctimestep | rmtxop failed: {ts_err.decode(errors='replace')[-1000:]} "
                         f"{mx.stderr.decode(errors='replace')[-1000:]}")
    t_ts = time.perf_counter() - t0
    head, e = read_matrix(mx.stdout)
    E_r = e.reshape(int(head["NROWS"]), int(head["NCOLS"])).T  # hours x points
    if E_r.shape != (hours, len(pts)):
        raise SystemExit(f"dctimestep | rmtxop gave {E_r.shape}, expected ({hours}, {len(pts)})")
    t_rad = t_gendaymtx + t_rcontrib + t_ts
    print(f"Radiance: .wea of {hours} hours; gendaymtx -m 1 -c 1 1 1: {t_gendaymtx:.1f} s ({ld}; it warned of "
          f"{n_bright} hours with direct light while the sun is below the horizon at mid-hour); "
          f"rcontrib -I+ {' '.join(dc_opts)} -n {args.processes} -e MF:1 -f reinhart.cal -b rbin -bn Nrbins "
          f"-m sky_glow ({n_bins} bins): {t_rcontrib:.1f} s ({ld_rc}); dctimestep | rmtxop -c 47.435 119.93 11.635: "
          f"{t_ts:.1f} s ({ld_ts})")

    da_r = ann.daylight_autonomy(E_r, occ, 300.0)
    sda_r = ann.spatial_daylight_autonomy(da_r, 0.5)
    sda_h = ann.spatial_daylight_autonomy(da_h, 0.5)
    # cross product: hirad's daylight coefficients (145 patches + ground; lux per cd/m^2) times
    # the Radiance sky (ground first, then the patches; W/(m^2 sr), grey): the same sky, so the
    # transport alone differs
    head_s, s = read_matrix((tmp / "sky.mtx").read_bytes())
    sky = s.reshape(int(head_s["NROWS"]), int(head_s["NCOLS"]), 3)[:, :, 1].astype(np.float64)  # patches x hours
    dcz = np.load(out / "grids/annual/coefficients.npz")
    dc_h = dcz["dc_sky_workplane"]
    dc_h_rad = np.concatenate([dc_h[:, -1:], dc_h[:, :-1]], axis=1)  # ground first, as Radiance
    E_c = EFFICACY * (sky.T @ dc_h_rad.T)
    da_c = ann.daylight_autonomy(E_c, occ, 300.0)
    sda_c = ann.spatial_daylight_autonomy(da_c, 0.5)
    dc_r_y = dc @ RAD_RGB  # points x bins
    u_h = dc_h_rad[:, 1:].sum(axis=1)
    u_r = dc_r_y[:, 1:].sum(axis=1)

    def pp(x, y):
        return 100.0 * np.abs(x - y).mean()

    print(f"{'':34s} {'mean DA300':>10s} {'sDA300/50%':>10s} {'min DA':>7s} {'max DA':>7s}")
    for label, da, sda in (("hirad (its bake)", da_h, sda_h), ("Radiance two-phase", da_r, sda_r),
                           ("hirad DC x Radiance sky matrix", da_c, sda_c)):
        print(f"{label:34s} {da.mean():10.4f} {sda:10.4f} {da.min():7.4f} {da.max():7.4f}")
    print(f"per-point DA300 mean |difference|: hirad vs Radiance {pp(da_h, da_r):.2f} pp (largest "
          f"{100 * np.abs(da_h - da_r).max():.2f} pp); hirad DC x Radiance sky vs Radiance {pp(da_c, da_r):.2f} pp")
    m_r, m_c = E_r[occ].mean(axis=0), E_c[occ].mean(axis=0)
    print(f"mean illuminance over the occupied hours, same sky matrix: hirad DC {m_c.mean():.1f} lx, Radiance DC "
          f"{m_r.mean():.1f} lx; {rel_stats(m_c, m_r)}")
    print(f"uniform sky of unit luminance (sum of the sky-patch coefficients): hirad {u_h.mean():.4f}, Radiance "
          f"{u_r.mean():.4f} (lx per cd/m^2); {rel_stats(u_h, u_r)}; ground coefficient hirad "
          f"{dc_h_rad[:, 0].mean():.4f}, Radiance {dc_r_y[:, 0].mean():.4f}")
    # the window (in the y = 0 wall, facing south) cannot pass a direction of the northern half of
    # the sky; with nothing outside but the ground, those patches' coefficients must be 0
    from hirad.daylight.patches import tregenza_patches

    tp = tregenza_patches()
    lo = np.mod(np.degrees(tp.az_center - tp.az_width / 2), 360.0)
    hi = lo + np.degrees(tp.az_width)
    north = ((lo >= 270.0 - 1e-9) & (hi <= 450.0 + 1e-9)) | (hi <= 90.0 + 1e-9)
    north[-1] = False  # the zenith cap spans every azimuth
    print(f"the {int(north.sum())} sky patches wholly in the northern half (no path through the south window): "
          f"sum of their coefficients hirad {dc_h[:, :-1][:, north].sum(axis=1).mean():.4f}, Radiance "
          f"{dc_r_y[:, 1:][:, north].sum(axis=1).mean():.4f} (mean over points; largest hirad "
          f"{dc_h[:, :-1][:, north].sum(axis=1).max():.4f})")
    # by the patch centre's azimuth: on a multiple of 45 degrees (the sky cells' middle direction
    # is then parallel to the room's axes or diagonals, and to the element grid) or not
    on45 = np.isclose(np.mod(np.degrees(tp.az_center) + 1e-9, 45.0), 0.0, atol=1e-6)
    on45[-1] = False
    uh, ur = dc_h[:, :-1][:, on45].sum(axis=1), dc_r_y[:, 1:][:, on45].sum(axis=1)
    print(f"the {int(on45.sum())} sky patches centred on a multiple of 45 deg azimuth: sum of their coefficients "
          f"hirad {uh.mean():.4f}, Radiance {ur.mean():.4f} (ratio of the means {uh.mean() / ur.mean():.3f})")
    uh, ur = dc_h[:, :-1][:, ~on45].sum(axis=1), dc_r_y[:, 1:][:, ~on45].sum(axis=1)
    print(f"the other {int((~on45).sum())} sky patches (zenith cap included): sum of their coefficients hirad "
          f"{uh.mean():.4f}, Radiance {ur.mean():.4f}; {rel_stats(uh, ur)}")
    print(f"wall time: hirad annual part {t_annual + t_groups:.1f} s (annual stage {t_annual:.1f} s without its "
          f"pictures + light-group "
          f"solves {t_groups:.1f} s; whole bake {t_bake:.1f} s, {t_bake - outputs_s:.1f} s without lightmaps, preview "
          f"and USD); Radiance gendaymtx + rcontrib + dctimestep {t_rad:.1f} s (+ oconv, .wea)")
    print(f"speed: hirad's annual part takes {(t_annual + t_groups) / t_rad:.2f}x the wall time of Radiance's "
          f"gendaymtx + rcontrib + dctimestep; the whole bake {t_bake / t_rad:.2f}x, the bake without the "
          f"outputs {(t_bake - outputs_s) / t_rad:.2f}x (both on {os.cpu_count()} cores)")
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a smoke run: rtrace -ad 512 -as 128 -ar 128, "
                                                         "rcontrib -ad 1024 -lw 5e-4")
    ap.add_argument("--only", choices=("df", "annual"), default=None)
    ap.add_argument("--ab", type=int, default=12, help="-ab of rtrace and rcontrib")
    ap.add_argument("--ad", type=int, default=4096, help="rtrace -ad (daylight factor)")
    ap.add_argument("--as", dest="as_", type=int, default=1024)
    ap.add_argument("--aa", type=float, default=0.1)
    ap.add_argument("--ar", type=int, default=256)
    ap.add_argument("--lw-rtrace", type=float, default=1e-4, help="rtrace -lw (Russian roulette below it, -lr -12)")
    ap.add_argument("--dc-ad", type=int, default=16384, help="rcontrib -ad (daylight coefficients)")
    ap.add_argument("--lw", type=float, default=3e-5, help="rcontrib -lw (Russian roulette below it, -lr -12)")
    ap.add_argument("--processes", type=int, default=os.cpu_count() or 1, help="rtrace/rcontrib -n")
    ap.add_argument("--keep", type=Path, default=None, help="work in this directory and keep it")
    args = ap.parse_args()
    if args.quick:
        args.ad, args.as_, args.ar, args.dc_ad, args.lw = 512, 128, 128, 1024, 5e-4

    from hirad import usd

    env = radiance_env()
    version = subprocess.run(["rtrace", "-version"], capture_output=True, env=env, text=True).stdout.strip()
    with open("/proc/loadavg") as f:
        loadavg = f.read().split()[:3]
    print(f"machine: nproc {os.cpu_count()}, load average {' '.join(loadavg)} at the start; {version}")
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = args.keep if args.keep is not None else Path(tmp_)
        tmp.mkdir(parents=True, exist_ok=True)
        scene = usd.read_scene(str(SCENE), daylight=True)
        room = tmp / "room.rad"
        c = write_room(scene, room)
        tau = scene.face_transmittance[scene.face_transmittance > 0]
        print(f"Radiance room: {c['faces']} polygons ({c['glass']} glass, Tn {tau[0]:.3f} -> tn "
              f"{radiance_tn(tau[0]):.4f}), {c['materials']} materials, from hirad.usd.read_scene of {SCENE.name}")
        print()
        if args.only in (None, "df"):
            daylight_factor(args, env, tmp, room)
        if args.only in (None, "annual"):
            annual(args, env, tmp, room)
    print(f"total wall time {time.perf_counter() - t_all:.1f} s; load average at the end "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
